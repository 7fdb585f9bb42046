"""Open a recording (``.rrd``) in the rerun viewer: the native one, or the web viewer (offline).

rerun 0.41 has no ``rr.serve_web``: the web viewer is :func:`rerun.serve_grpc` (a gRPC server
that holds the recording) plus :func:`rerun.serve_web_viewer` (the viewer's static files, served
from the pip install, pointed at that server). Nothing is downloaded.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["ServedRecording", "native_command", "replay_native", "replay_web", "serve_recording"]


def _check(path: str | Path) -> Path:
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"no recording at {p}")
    if p.suffix != ".rrd":
        raise ValueError(f"{p} is not a rerun recording (.rrd)")
    return p


def native_command(path: str | Path) -> list[str]:
    """The command that opens ``path`` in the native rerun viewer (the pip install's ``rerun``)."""
    p = _check(path)
    exe = Path(sys.executable).with_name("rerun")
    if exe.is_file():
        return [str(exe), str(p)]
    found = shutil.which("rerun")
    return [found, str(p)] if found else [sys.executable, "-m", "rerun", str(p)]


def replay_native(path: str | Path) -> int:
    """Open ``path`` in the native viewer and wait until it is closed; returns its exit code."""
    return subprocess.call(native_command(path))


@dataclass
class ServedRecording:
    """A recording served to the web viewer.

    Attributes:
        grpc_url: Where the viewer reads the data (``rerun+http://.../proxy``).
        web_url: The web viewer's page, already pointed at ``grpc_url``.
        stream: The recording stream that holds the data (keep it alive while serving).
    """

    grpc_url: str
    web_url: str
    stream: Any

    def stop(self) -> None:
        """Stop serving the data (the web viewer's file server lives as long as the process)."""
        self.stream.disconnect()


def serve_recording(
    path: str | Path, *, grpc_port: int = 9876, web_port: int = 9090, open_browser: bool = False
) -> ServedRecording:
    """Serve ``path`` over gRPC and the web viewer over HTTP, from this process (returns at once).

    Raises:
        FileNotFoundError: No such file.
        ValueError: Not a ``.rrd`` file, or not a readable recording.
    """
    import rerun as rr
    from rerun.chunk import RrdReader

    from hptvsim.viz.recording import blueprint, recording_static

    p = _check(path)
    static = recording_static(p)  # its game chooses the layout (a depth plot in the 3-D game)
    reader = RrdReader(str(p))
    try:
        entries = reader.recordings()
    except Exception as exc:  # rerun's own error types for damaged files
        raise ValueError(f"{p} is not a readable rerun recording: {exc}") from exc
    if not entries:
        raise ValueError(f"{p} holds no recording")
    entry = entries[0]
    rec = rr.RecordingStream(entry.application_id, recording_id=entry.recording_id)
    layout = blueprint(static.game if static is not None else "planar")
    grpc_url = rec.serve_grpc(grpc_port=grpc_port, default_blueprint=layout)
    rec.send_chunks(reader.stream())
    rec.flush(timeout_sec=30.0)
    rr.serve_web_viewer(web_port=web_port, open_browser=open_browser, connect_to=grpc_url)
    web_url = f"http://127.0.0.1:{web_port}/?url={grpc_url}"
    return ServedRecording(grpc_url=grpc_url, web_url=web_url, stream=rec)


def replay_web(
    path: str | Path, *, web_port: int = 9090, grpc_port: int = 9876, open_browser: bool = True
) -> None:  # pragma: no cover - blocks until Ctrl-C; serve_recording is what the tests run
    """Serve ``path`` to the web viewer and block until Ctrl-C."""
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    served = serve_recording(path, grpc_port=grpc_port, web_port=web_port, open_browser=open_browser)
    print(f"rerun web viewer: {served.web_url}  (Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        served.stop()
