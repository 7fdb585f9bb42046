"""The Gymnasium ids of the games and their default arguments (data only: importing it is cheap)."""

from __future__ import annotations

from typing import Any

ENV_IDS: dict[str, dict[str, Any]] = {
    "hptvsim/UPEG-Pursuer-v0": {"scenario": "source", "agent": "pursuer_0", "task": "pursuit"},
    "hptvsim/UPEG-Evader-v0": {"scenario": "source", "agent": "evader_0", "task": "pursuit"},
    "hptvsim/Goto-v0": {"scenario": "goto_tiny", "task": "goto"},
}
"""Registered Gymnasium ids of the planar game and their default arguments."""

ENV_IDS_3D: dict[str, dict[str, Any]] = {
    "hptvsim/UPEG3D-Pursuer-v0": {"scenario": "dive_flat", "agent": "pursuer_0", "task": "pursuit"},
    "hptvsim/UPEG3D-Evader-v0": {"scenario": "dive_flat", "agent": "evader_0", "task": "pursuit"},
    "hptvsim/UPEG3D-Goto-v0": {"scenario": "dive_goto", "task": "goto"},
}
"""Registered Gymnasium ids of the 3-D game and their default arguments."""
