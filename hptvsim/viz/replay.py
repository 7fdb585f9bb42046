"""Open a recording (``.rrd``) in the rerun viewer: the native one, or the web viewer (offline).

The web viewer is served by the pip install's ``rerun`` program, run as a child process:
``rerun --serve-web --bind HOST ... FILE LAYOUT.rbl`` serves the recording over gRPC and the
viewer's static files over HTTP, both on ``HOST`` only (by default ``127.0.0.1``: this machine
alone; rerun's Python API binds every interface, 0.0.0.0, with no way to choose). Being a child
in its own session, it stops as soon as this process stops it (Ctrl-C). Nothing is downloaded.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = [
    "DEFAULT_HOST",
    "ServedRecording",
    "native_command",
    "replay_native",
    "replay_web",
    "serve_recording",
]

DEFAULT_HOST = "127.0.0.1"
"""Where ``hptvsim replay --web`` listens unless told otherwise: this machine only."""

_START_TIMEOUT_S = 60.0  # s, for rerun to load the recording and listen
_STOP_TIMEOUT_S = 2.0  # s, for rerun to exit after SIGTERM before it is killed


def _check(path: str | Path) -> Path:
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"no recording at {p}")
    if p.suffix != ".rrd":
        raise ValueError(f"{p} is not a rerun recording (.rrd)")
    return p


def _rerun_program() -> list[str]:
    """The pip install's ``rerun`` program (as a command's first words)."""
    exe = Path(sys.executable).with_name("rerun")
    if exe.is_file():
        return [str(exe)]
    found = shutil.which("rerun")
    return [found] if found else [sys.executable, "-m", "rerun"]


def _rerun_server_program() -> list[str]:
    """The ``rerun`` binary itself where the pip install has it (not its launcher), else the launcher.

    Run directly, the one process that serves is the child :func:`serve_recording` stops (and
    that ends with this process, on Linux); a launcher would leave its own child behind.
    """
    import importlib.util

    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin is not None and sys.platform.startswith("linux"):
        binary = Path(spec.origin).with_name("rerun")
        if binary.is_file():
            return [str(binary)]
    return _rerun_program()


def _end_with_parent() -> None:  # pragma: no cover - runs in the child before exec
    """In the child, on Linux: receive SIGTERM when the process that started it ends."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6").prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


def native_command(path: str | Path) -> list[str]:
    """The command that opens ``path`` in the native rerun viewer (the pip install's ``rerun``)."""
    return [*_rerun_program(), str(_check(path))]


def replay_native(path: str | Path) -> int:
    """Open ``path`` in the native viewer and wait until it is closed; returns its exit code."""
    return subprocess.call(native_command(path))


@dataclass
class ServedRecording:
    """A recording served to the web viewer by a ``rerun`` child process.

    Attributes:
        grpc_url: Where the viewer reads the data (``rerun+http://HOST:PORT/proxy``).
        web_url: The web viewer's page, already pointed at ``grpc_url``.
        process: The ``rerun`` child process serving both.
        host: The address both servers listen on.
    """

    grpc_url: str
    web_url: str
    process: subprocess.Popen[bytes]
    host: str
    _folder: Any = None  # the TemporaryDirectory holding the layout (.rbl) while serving

    def stop(self) -> None:
        """Stop serving: SIGTERM to ``rerun``, SIGKILL if it is still there after 2 s."""
        if self.process.poll() is None:
            _signal_group(self.process, signal.SIGTERM)  # the `rerun` launcher and its viewer
            try:
                self.process.wait(timeout=_STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                _signal_group(self.process, signal.SIGKILL)
                self.process.wait()
        _signal_group(self.process, signal.SIGKILL)  # whatever of its session is left
        if self._folder is not None:
            self._folder.cleanup()
            self._folder = None


def _signal_group(process: subprocess.Popen[bytes], signum: int) -> None:
    """Send ``signum`` to the session ``process`` leads (it was started in a new one)."""
    with contextlib.suppress(ProcessLookupError, PermissionError):  # gone already
        os.killpg(process.pid, signum)


def _url_host(host: str) -> str:
    """The address a browser on this machine uses for a server bound to ``host``."""
    if host in ("0.0.0.0", "::", ""):  # every interface: this machine is one of them
        return "127.0.0.1"
    return f"[{host}]" if ":" in host else host


def _wait_listening(process: subprocess.Popen[bytes], host: str, ports: tuple[int, ...], log: Path) -> None:
    """Wait until ``rerun`` listens on every port, or say why it stopped (its last output)."""
    deadline = time.monotonic() + _START_TIMEOUT_S
    waiting = list(ports)
    while waiting:
        if process.poll() is not None:
            tail = log.read_text(errors="replace").strip().splitlines()[-3:]
            raise RuntimeError(
                f"rerun stopped (exit {process.returncode}) before serving on {host}, ports "
                f"{', '.join(map(str, ports))}: {' | '.join(tail) or 'no output'}"
            )
        try:
            with socket.create_connection((_url_host(host).strip("[]"), waiting[0]), timeout=1.0):
                waiting.pop(0)
        except OSError:
            if time.monotonic() > deadline:
                raise RuntimeError(
                    f"rerun did not listen on {host}:{waiting[0]} within {_START_TIMEOUT_S:g} s"
                ) from None
            time.sleep(0.1)


def serve_recording(
    path: str | Path,
    *,
    grpc_port: int = 9876,
    web_port: int = 9090,
    host: str = DEFAULT_HOST,
    open_browser: bool = False,
) -> ServedRecording:
    """Serve ``path`` over gRPC and the web viewer over HTTP, on ``host`` only; returns once both listen.

    Args:
        path: The recording (``.rrd``).
        grpc_port: The data's port.
        web_port: The web viewer's port.
        host: The address to listen on (``127.0.0.1``: this machine only; ``0.0.0.0``: every
            interface, for other machines too).
        open_browser: Open the viewer in the default browser.

    Raises:
        FileNotFoundError: No such file.
        ValueError: Not a ``.rrd`` file, or not a readable recording.
        RuntimeError: ``rerun`` could not serve it (a port in use, an address not of this machine).
    """
    from rerun.chunk import RrdReader

    from hptvsim.viz.recording import blueprint, recording_static

    p = _check(path)
    static = recording_static(p)  # its game chooses the layout (a depth plot in the 3-D game)
    try:
        entries = RrdReader(str(p)).recordings()
    except Exception as exc:  # rerun's own error types for damaged files
        raise ValueError(f"{p} is not a readable rerun recording: {exc}") from exc
    if not entries:
        raise ValueError(f"{p} holds no recording")
    folder = tempfile.TemporaryDirectory(prefix="hptvsim-replay-")
    layout = Path(folder.name) / "layout.rbl"
    blueprint(static.game if static is not None else "planar").save(entries[0].application_id, layout)
    log = Path(folder.name) / "rerun.log"
    command = [
        *_rerun_server_program(),
        "--web-viewer" if open_browser else "--serve-web",
        "--bind",
        host,
        "--port",
        str(grpc_port),
        "--web-viewer-port",
        str(web_port),
        str(p),
        str(layout),
    ]
    with log.open("wb") as out:
        process = subprocess.Popen(
            command,
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=subprocess.STDOUT,
            env={**os.environ, "RERUN_ANALYTICS": "0"},
            start_new_session=True,  # Ctrl-C reaches this process, which stops rerun at once
            preexec_fn=_end_with_parent if sys.platform.startswith("linux") else None,
        )
    served = ServedRecording(
        grpc_url=f"rerun+http://{_url_host(host)}:{grpc_port}/proxy",
        web_url=f"http://{_url_host(host)}:{web_port}/?url=rerun+http://{_url_host(host)}:{grpc_port}/proxy",
        process=process,
        host=host,
        _folder=folder,
    )
    try:
        _wait_listening(process, host, (grpc_port, web_port), log)
    except BaseException:
        served.stop()
        raise
    return served


def replay_web(
    path: str | Path,
    *,
    web_port: int = 9090,
    grpc_port: int = 9876,
    host: str = DEFAULT_HOST,
    open_browser: bool = True,
) -> int:
    """Serve ``path`` to the web viewer until Ctrl-C (SIGINT) or SIGTERM; stops within about 2 s.

    Returns:
        0 after Ctrl-C or SIGTERM; ``rerun``'s exit code if it stopped by itself.

    Raises:
        FileNotFoundError, ValueError, RuntimeError: As :func:`serve_recording`.
    """
    # Ctrl-C (even where a shell started this in the background, with SIGINT ignored) and `kill`
    # both stop it at once
    previous = {
        sig: signal.signal(sig, signal.default_int_handler) for sig in (signal.SIGINT, signal.SIGTERM)
    }
    try:
        served = serve_recording(
            path, grpc_port=grpc_port, web_port=web_port, host=host, open_browser=open_browser
        )
        try:
            print(f"rerun web viewer: {served.web_url}  (listening on {host}; Ctrl-C to stop)", flush=True)
            return served.process.wait()
        finally:
            served.stop()
    except KeyboardInterrupt:
        return 0
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
