"""Files written whole or not at all (:mod:`hptvsim._files`): a failed write leaves nothing behind.

The failure is a real one: a child process with a file-size limit (``RLIMIT_FSIZE``, the kernel
refuses the write past it with ``EFBIG``, as a full disk refuses it with ``ENOSPC``) writes
through each writer the service uses.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from hptvsim._files import atomic_path, write_atomic

CHILD = textwrap.dedent(
    """
    import json, resource, signal, sys
    from pathlib import Path

    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # the write fails with EFBIG instead of a kill
    resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
    folder, writer = Path(sys.argv[1]), sys.argv[2]
    big = {"data": "x" * 100_000}
    try:
        if writer == "write_atomic":
            from hptvsim._files import write_atomic
            write_atomic(folder / "static.json", json.dumps(big))
        elif writer == "write_json_atomic":
            from hptvsim.service.engine import write_json_atomic
            write_json_atomic(folder / "static.json", big)
        elif writer == "atomic_write_text":
            from hptvsim.train.common import atomic_write_text
            atomic_write_text(folder / "static.json", json.dumps(big))
    except OSError as exc:
        print("refused", exc.errno)
    else:
        print("written")
    """
)


@pytest.mark.parametrize("writer", ["write_atomic", "write_json_atomic", "atomic_write_text"])
def test_a_write_the_disk_refuses_leaves_the_old_file_and_no_temporary(tmp_path: Path, writer: str) -> None:
    (tmp_path / "static.json").write_text('{"old": true}')
    out = subprocess.run(
        [sys.executable, "-c", CHILD, str(tmp_path), writer], capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["refused", "27"], out.stdout  # 27: EFBIG
    assert json.loads((tmp_path / "static.json").read_text()) == {"old": True}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["static.json"]


def test_a_whole_write_replaces_the_file(tmp_path: Path) -> None:
    target = tmp_path / "a.json"
    write_atomic(target, '{"a": 1}')
    write_atomic(target, b'{"a": 2}')
    assert json.loads(target.read_text()) == {"a": 2}
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]


def test_an_exception_of_the_writer_removes_its_file(tmp_path: Path) -> None:
    target = tmp_path / "table.parquet"
    target.write_bytes(b"old")

    def half_way() -> None:
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"new, half")
            raise RuntimeError("half way")

    with pytest.raises(RuntimeError, match="half way"):
        half_way()
    assert target.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["table.parquet"]
    with atomic_path(target, suffix=".tmp.png") as tmp:
        assert tmp.name.endswith(".tmp.png") and tmp.parent == tmp_path and not tmp.exists()
        tmp.write_bytes(b"new")
    assert target.read_bytes() == b"new"
