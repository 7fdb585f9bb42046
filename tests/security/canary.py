"""Canary files for the security tests: loading them would leave a marker on disk.

* :func:`sb3_canary`: a zip laid out as a stable-baselines3 checkpoint whose ``data`` entry holds
  a cloudpickled object; ``SAC.load`` (or any unpickling of it) creates ``marker``.
* :func:`scenario_canary`: a valid scenario file of a distinctive name, outside the shipped
  folder; if the service ran an episode of it, it read a file a client named.
"""

from __future__ import annotations

import base64
import builtins
import json
import pickle
import zipfile
from pathlib import Path
from typing import Any


class _Marker:
    """Unpickling this opens (creates) the marker file: code ran."""

    def __init__(self, path: Path) -> None:
        self.path = str(path)

    def __reduce__(self) -> tuple[Any, ...]:
        return (builtins.open, (self.path, "w"))


def sb3_canary(folder: Path, marker: Path) -> Path:
    """A fake SB3 checkpoint at ``folder/canary.zip`` whose loading creates ``marker``."""
    payload = base64.b64encode(pickle.dumps(_Marker(marker))).decode()
    data = {"policy_class": {":type:": "<class 'canary'>", ":serialized:": payload}}
    path = folder / "canary.zip"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("data", json.dumps(data))
        z.writestr("_stable_baselines3_version", "2.9.2")
    return path


def scenario_canary(folder: Path, name: str = "canary_scenario") -> Path:
    """A valid scenario file (the shipped goto_tiny under another name) outside the shipped folder."""
    from hptvsim.world.scenario import scenario_path

    text = scenario_path("goto_tiny").read_text()
    lines = [f'name = "{name}"' if line.startswith("name =") else line for line in text.splitlines()]
    path = folder / f"{name}.toml"
    path.write_text("\n".join(lines) + "\n")
    return path
