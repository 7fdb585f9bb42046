"""The archive of finished runs' results: CSV files gzipped, other files as they are, read transparently.

``hptvsim reproduce`` keeps what its report reads of every finished run and DT step in a folder
committed beside the report (:func:`hptvsim.experiments.reproduce.archive_finished`,
:func:`hptvsim.experiments.repro_dt.archive_dt`). The CSV logs are most of it (the scaled
plan's 90 runs: 36 MB of ``episodes.csv`` and ``curve.csv``), and they compress about tenfold,
so the archive holds each ``<name>.csv`` as ``<name>.csv.gz``: gzip with its header's time set
to 0 and no file name, so archiving the same results again gives the same bytes (and git sees no
change). Restoring an archived run writes the plain CSV back into its run folder, where every
reader finds it as a training run wrote it.

An archive written by an older hptvsim holds plain CSV files, and an older sweep still running
may add plain files beside gzipped ones: both are read. Where a file is there both ways, the
plain one is the one read (only an older hptvsim writes it, after the gzipped one), and the next
archiving replaces it by its gzipped form.
"""

from __future__ import annotations

import gzip
import shutil
from collections.abc import Iterable
from pathlib import Path
from typing import IO

__all__ = [
    "GZIP_SUFFIX",
    "archive_files",
    "archived_path",
    "gzip_bytes",
    "is_packed",
    "open_text",
    "present",
    "read_archived",
    "restore_files",
]

GZIP_SUFFIX = ".gz"
GZIP_LEVEL = 9  # zlib's best compression: written once, read rarely


def is_packed(rel: str | Path) -> bool:
    """Whether the archive holds ``rel`` gzipped (a CSV file)."""
    return str(rel).endswith(".csv")


def gzip_bytes(data: bytes) -> bytes:
    """``data`` gzipped with the same bytes every time: header time 0, no file name."""
    return gzip.compress(data, compresslevel=GZIP_LEVEL, mtime=0)


def archived_path(folder: Path, rel: str | Path) -> Path | None:
    """Where ``folder`` holds ``rel``: the plain file, else its gzipped form (a CSV); ``None`` if neither."""
    plain = folder / rel
    if plain.is_file():
        return plain
    packed = folder / f"{rel}{GZIP_SUFFIX}"
    return packed if is_packed(rel) and packed.is_file() else None


def present(folder: Path, files: Iterable[str | Path]) -> list[Path]:
    """The names of ``files`` that ``folder`` holds either way (plain or gzipped), as given."""
    return [Path(f) for f in files if archived_path(folder, f) is not None]


def read_archived(folder: Path, rel: str | Path) -> bytes | None:
    """The content of ``rel`` in ``folder`` (decompressed when gzipped); ``None`` when it is not there."""
    path = archived_path(folder, rel)
    if path is None:
        return None
    data = path.read_bytes()
    return gzip.decompress(data) if path.name.endswith(GZIP_SUFFIX) else data


def open_text(path: Path) -> IO[str]:
    """Open a text file for reading, or its gzipped form ``<path>.gz`` when only that is there.

    Raises:
        OSError: Neither is there (the plain path's ``FileNotFoundError``).
    """
    packed = path.with_name(path.name + GZIP_SUFFIX)
    if not path.is_file() and packed.is_file():
        return gzip.open(packed, "rt", newline="")
    return path.open(newline="")


def _write(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (a temporary file beside it, then renamed)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    tmp.replace(path)


def archive_files(src: Path, dst: Path, files: Iterable[str | Path]) -> bool:
    """Copy ``files`` present in ``src`` into the archive folder ``dst``; whether anything changed.

    A CSV file goes in gzipped (:func:`gzip_bytes`) and a plain copy of it there (an older
    archive's) is removed; every other file is copied as it is. A file whose content is already
    there is not written again. Each file is written atomically, in the order given.
    """
    changed = False
    for rel in files:
        a = src / rel
        if not a.is_file():
            continue
        data = a.read_bytes()
        plain = dst / rel
        if not is_packed(rel):
            if plain.is_file() and plain.read_bytes() == data:
                continue
            plain.parent.mkdir(parents=True, exist_ok=True)
            tmp = plain.with_name(plain.name + ".tmp")
            shutil.copyfile(a, tmp)
            tmp.replace(plain)
            changed = True
            continue
        packed = dst / f"{rel}{GZIP_SUFFIX}"
        if not (packed.is_file() and gzip.decompress(packed.read_bytes()) == data):
            _write(packed, gzip_bytes(data))
            changed = True
        if plain.is_file():
            plain.unlink()
            changed = True
    return changed


def restore_files(src: Path, dst: Path, files: Iterable[str | Path], *, missing_only: bool = False) -> bool:
    """Write ``files`` archived in ``src`` (plain or gzipped) into the run folder ``dst`` as plain files.

    Args:
        src: The archive folder of one run or DT step.
        dst: Its run folder.
        files: The names to restore (a CSV by its plain name, ``episodes.csv``).
        missing_only: Write only the files ``dst`` lacks (a finished run folder whose own files
            are newer than the archive's, but some are missing there).

    Returns:
        Whether anything was written.
    """
    changed = False
    for rel in files:
        data = read_archived(src, rel)
        if data is None:
            continue
        b = dst / rel
        if b.is_file() and (missing_only or b.read_bytes() == data):
            continue
        _write(b, data)
        changed = True
    return changed
