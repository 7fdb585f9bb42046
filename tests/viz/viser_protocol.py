"""A client of viser's own WebSocket protocol, as a browser (or an attacker) would speak it.

Server -> client frames: ``[8 bytes raw size][8 bytes zstd size][zstd(msgpack)][binary buffers]``,
the msgpack holding ``{"messages": [...]}``; client -> server: one msgpack dict per message
(``{"type": "GuiUpdateMessage", "uuid": ..., "updates": {...}}``). Used by the security tests
to send what viser's own web client would never send (a dropdown value not among its options).
"""

from __future__ import annotations

import time
from typing import Any

import msgspec.msgpack
import viser
import zstandard
from websockets.sync.client import ClientConnection, connect


class ViserClient:
    """A connected viser client that records the GUI elements the server creates.

    Args:
        url: ``ws://host:port`` (or ``http://``; the scheme is swapped).
        headers: Extra HTTP headers of the WebSocket handshake (e.g. ``Cookie``, ``Origin``).
    """

    def __init__(self, url: str, headers: dict[str, str] | None = None, origin: str | None = None) -> None:
        ws_url = url.replace("http://", "ws://").replace("https://", "wss://")
        self.ws: ClientConnection = connect(
            ws_url,
            subprotocols=[f"viser-v{viser.__version__}"],  # type: ignore[list-item]  # a Subprotocol str
            additional_headers=headers or {},
            origin=origin,  # type: ignore[arg-type]  # an Origin str
            open_timeout=30,
            max_size=None,
        )
        self.gui: dict[str, dict[str, Any]] = {}  # label -> {"uuid", "type", "options", "value"}
        self.messages: list[dict[str, Any]] = []  # every message received, in order
        self._zstd = zstandard.ZstdDecompressor()
        # viser counts a client as connected (and runs its GUI callbacks) after its first camera
        self.send(
            {
                "type": "ViewerCameraMessage",
                "wxyz": (1.0, 0.0, 0.0, 0.0),
                "position": (0.0, 0.0, -100.0),
                "fov": 1.0,
                "near": 0.5,
                "far": 20000.0,
                "image_height": 480,
                "image_width": 640,
                "look_at": (0.0, 0.0, 0.0),
                "up_direction": (0.0, 0.0, -1.0),
            }
        )

    def send(self, message: dict[str, Any]) -> None:
        """Send one message (a dict with its ``type``) as viser's web client does."""
        self.ws.send(msgspec.msgpack.encode(message))

    def _decode(self, frame: bytes) -> list[dict[str, Any]]:
        raw = int.from_bytes(frame[0:8], "little")
        size = int.from_bytes(frame[8:16], "little")
        inner = self._zstd.decompress(frame[16 : 16 + size], max_output_size=raw)
        data: dict[str, Any] = msgspec.msgpack.decode(inner)
        return list(data.get("messages", []))

    def pump(self, seconds: float = 1.0) -> None:
        """Read what the server sends for ``seconds``, recording GUI elements."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                frame = self.ws.recv(timeout=max(0.01, end - time.monotonic()))
            except TimeoutError:
                return
            if not isinstance(frame, bytes):
                continue
            for m in self._decode(frame):
                self.messages.append(m)
                kind = str(m.get("type", ""))
                props = m.get("props")
                if kind.startswith("Gui") and isinstance(props, dict) and "label" in props:
                    self.gui[str(props["label"])] = {
                        "uuid": m["uuid"],
                        "type": kind,
                        "options": props.get("options"),
                        "value": m.get("value"),
                    }

    def received(self, kind: str) -> list[dict[str, Any]]:
        """The messages of type ``kind`` received so far (call :meth:`pump` first)."""
        return [m for m in self.messages if m.get("type") == kind]

    def wait_for(self, label: str, timeout: float = 30.0) -> dict[str, Any]:
        """The GUI element labelled ``label`` once the server has sent it."""
        end = time.monotonic() + timeout
        while label not in self.gui and time.monotonic() < end:
            self.pump(0.2)
        if label not in self.gui:
            raise AssertionError(f"no GUI element {label!r}; seen: {sorted(self.gui)}")
        return self.gui[label]

    def update(self, label: str, **updates: Any) -> None:
        """Send a ``GuiUpdateMessage`` for the element ``label`` (any property, any value)."""
        uuid = self.wait_for(label)["uuid"]
        self.send({"type": "GuiUpdateMessage", "uuid": uuid, "updates": updates})

    def click(self, label: str) -> None:
        """Press a button."""
        self.update(label, value=True)

    def close(self) -> None:
        """Disconnect."""
        self.ws.close()
