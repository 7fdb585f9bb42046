"""Small C kernels compiled at first use and cached per user (the sonar, the task layer, benches).

A kernel's source ships inside the package. :func:`compile_c` compiles it once with the
system's C compiler into ``$XDG_CACHE_HOME/hptvsim`` (default ``~/.cache/hptvsim``; a per-user
temporary folder if that is not writable), named by a hash of the source and the flags, so a
changed source or flag is a new library and concurrent first uses never see half a file.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from importlib import resources
from pathlib import Path

__all__ = ["cache_dir", "compile_c"]


def cache_dir() -> Path:
    """``$XDG_CACHE_HOME/hptvsim`` (default ``~/.cache/hptvsim``), else a per-user temp folder."""
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "hptvsim"
    try:
        base.mkdir(parents=True, exist_ok=True)
        if os.access(base, os.W_OK):
            return base
    except OSError:
        pass
    fallback = Path(tempfile.gettempdir()) / f"hptvsim-cache-{os.getuid()}"
    fallback.mkdir(mode=0o700, parents=True, exist_ok=True)
    return fallback


def compile_c(
    package: str,
    filename: str,
    *,
    flags: Sequence[str],
    libs: Sequence[str] = ("-lm",),
    include_dirs: Sequence[Path] = (),
    executable: bool = False,
    what: str | None = None,
    hint: str = "",
) -> Path:
    """Compile a C source shipped in ``package`` once; return the cached library or program.

    Args:
        package: Package holding the source (e.g. ``"hptvsim.sensors"``).
        filename: The source file's name in that package.
        flags: Compiler flags (``-shared -fPIC`` for a library).
        libs: Libraries to link, after the source.
        include_dirs: Extra ``-I`` folders.
        executable: Build a program instead of a shared library (no suffix).
        what: How error messages name the kernel (default: the file name).
        hint: Appended to the missing-compiler error (e.g. a slower fallback to use instead).

    Raises:
        RuntimeError: No C compiler, or it failed (the message holds its output).
    """
    src = resources.files(package).joinpath(filename).read_text()
    cc = os.environ.get("CC", "gcc")
    key = "\0".join([src, *flags, *libs, *map(str, include_dirs)])
    digest = hashlib.sha256(key.encode()).hexdigest()[:16]
    stem = Path(filename).stem
    target = cache_dir() / (f"{stem}-{digest}" + ("" if executable else ".so"))
    if target.exists():
        return target
    label = what or filename
    if shutil.which(cc) is None:
        raise RuntimeError(
            f"{label} needs a C compiler and {cc!r} was not found on PATH: install gcc "
            f"(e.g. `apt-get install gcc`) or point CC at a compiler{hint}"
        )
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        c_path = Path(tmp) / filename
        c_path.write_text(src)
        out = Path(tmp) / target.name
        cmd = [cc, *flags, *(f"-I{d}" for d in include_dirs), str(c_path), "-o", str(out), *libs]
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            raise RuntimeError(f"compiling {label} with {cc} failed:\n{proc.stderr.strip()}")
        os.replace(out, target)  # atomic
    return target
