"""Small C kernels compiled at first use and cached per user (the sonar, the task layer, benches).

A kernel's source ships inside the package, beside the module that calls it. :func:`compile_c`
compiles it once with the system's C compiler into ``$XDG_CACHE_HOME/hptvsim`` (default
``~/.cache/hptvsim``; a per-user temporary folder if that is not writable), named by a hash of
the source and the flags, so a changed source or flag is a new library and concurrent first uses
never see half a file. :func:`load_library` is the one way a kernel is loaded: compiled once,
opened once with :mod:`ctypes` and its functions' types declared once, under a lock, whatever
the number of threads asking.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
import threading
from collections.abc import Callable, Sequence
from pathlib import Path

__all__ = ["cache_dir", "compile_c", "load_library"]

_LOCK = threading.Lock()
_LIBRARIES: dict[tuple[str, tuple[str, ...]], ctypes.CDLL] = {}


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
    source: Path,
    *,
    flags: Sequence[str],
    libs: Sequence[str] = ("-lm",),
    include_dirs: Sequence[Path] = (),
    executable: bool = False,
    what: str | None = None,
    hint: str = "",
) -> Path:
    """Compile a C source shipped in the package once; return the cached library or program.

    Args:
        source: The source file (``Path(__file__).with_name("sonar_kernel.c")``).
        flags: Compiler flags (``-shared -fPIC`` for a library).
        libs: Libraries to link, after the source.
        include_dirs: Extra ``-I`` folders.
        executable: Build a program instead of a shared library (no suffix).
        what: How error messages name the kernel (default: the file name).
        hint: Appended to the missing-compiler error (e.g. a slower fallback to use instead).

    Raises:
        RuntimeError: No C compiler, or it failed (the message holds its output).
    """
    src = source.read_text()
    filename = source.name
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


def load_library(
    source: Path,
    *,
    flags: Sequence[str],
    declare: Callable[[ctypes.CDLL], None],
    what: str | None = None,
    hint: str = "",
) -> ctypes.CDLL:
    """A C kernel as a loaded library: compiled once (:func:`compile_c`), opened once, typed once.

    Thread-safe: the first caller compiles and opens it under a lock; later callers get the same
    :class:`ctypes.CDLL`.

    Args:
        source: The kernel's source file, shipped beside the module that calls it.
        flags: Compiler flags (``-shared -fPIC`` among them).
        declare: Sets the ``argtypes`` and ``restype`` of the functions the caller uses; runs
            once, before any caller sees the library.
        what: How error messages name the kernel (default: the file name).
        hint: Appended to the missing-compiler error.

    Raises:
        RuntimeError: No C compiler, or it failed (see :func:`compile_c`).
    """
    key = (str(source), tuple(flags))
    lib = _LIBRARIES.get(key)  # the hot path: loaded already (a dict read is atomic)
    if lib is not None:
        return lib
    with _LOCK:
        lib = _LIBRARIES.get(key)
        if lib is None:
            lib = ctypes.CDLL(str(compile_c(source, flags=flags, what=what, hint=hint)))
            declare(lib)
            _LIBRARIES[key] = lib
        return lib
