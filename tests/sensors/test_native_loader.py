"""The one C-kernel loader (:func:`hptvsim.native.load_library`): compiled, opened and typed once."""

from __future__ import annotations

import ctypes
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from hptvsim.native import load_library
from hptvsim.sensors import measured, sonar, sonar3d


def test_a_kernel_is_compiled_loaded_and_typed_once_whatever_the_threads(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    source = tmp_path / "twice.c"
    source.write_text("int hptv_twice(int x) { return 2 * x; }\n")
    declared: list[ctypes.CDLL] = []

    def declare(lib: ctypes.CDLL) -> None:
        declared.append(lib)
        lib.hptv_twice.argtypes = [ctypes.c_int]
        lib.hptv_twice.restype = ctypes.c_int

    def load(_: int) -> ctypes.CDLL:
        return load_library(source, flags=("-O2", "-fPIC", "-shared"), declare=declare, what="a test kernel")

    with ThreadPoolExecutor(4) as pool:
        libs = list(pool.map(load, range(16)))
    assert len(declared) == 1 and all(lib is declared[0] for lib in libs)
    assert libs[0].hptv_twice(21) == 42


def test_the_kernels_of_the_package_load_through_it() -> None:
    """The sonar, the 3-D sonar and the error kernel: the same library on every call."""
    for kernel in (sonar._kernel, sonar3d._kernel, measured._errors_kernel):
        assert kernel() is kernel()
    assert sonar._kernel().hptv_sonar_cast.restype is ctypes.c_int
