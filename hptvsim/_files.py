"""Files written whole or not at all: the one way every layer replaces a file in place.

A writer fills a temporary file beside the target and renames it over the target (``rename`` is
atomic within a file system), so a reader sees the old file or the whole new one, never a part.
If the writing fails (a full disk, a file-size limit, an exception of the writer) the temporary
file is removed and the target is left as it was: a failed write leaves nothing behind.
"""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Iterator
from pathlib import Path

__all__ = ["atomic_path", "write_atomic"]


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str], *, suffix: str = ".tmp") -> Iterator[Path]:
    """A temporary path beside ``path`` that replaces ``path`` when the block ends without error.

    Args:
        path: The file to write.
        suffix: The temporary file's ending (some writers choose a format by it, e.g. ``.npz``
            or ``.png``).

    Yields:
        A fresh path in ``path``'s folder, named after it, for the caller's writer to create
        and fill. On an exception it is removed (if it was created) and the exception goes on.
    """
    target = Path(path)
    # a name no other writer (process or thread) picks; the writer creates the file, so it gets
    # the umask's permissions (mkstemp's would be 0600)
    tmp = target.with_name(f".{target.name}.{os.getpid()}.{secrets.token_hex(4)}{suffix}")
    try:
        yield tmp
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def write_atomic(path: str | os.PathLike[str], data: str | bytes) -> None:
    """Write ``data`` (text as UTF-8) to ``path`` whole or not at all (see the module)."""
    raw = data.encode() if isinstance(data, str) else data
    with atomic_path(path) as tmp:
        tmp.write_bytes(raw)
