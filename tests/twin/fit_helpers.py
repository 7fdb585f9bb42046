"""Logs simulated from the models, for the fit and twin tests (shared by tests/twin/test_*.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hptvsim.cosim.vehicles import load_vehicle_file
from hptvsim.dynamics import VehicleParameters
from hptvsim.twin.fit import simulate
from hptvsim.twin.plant import Plant
from hptvsim.twin.table import LogTable

ROOT = Path(__file__).resolve().parents[2]
BLUEROV2_FILE = ROOT / "scenarios" / "vehicles" / "bluerov2_heavy.toml"

# Measurement noise (standard deviations) added to the simulated logs.
NOISE_SIGMA = {
    "x": 0.01,  # m
    "y": 0.01,  # m
    "z": 0.01,  # m
    "phi": 0.005,  # rad
    "theta": 0.005,  # rad
    "psi": 0.005,  # rad
    "u": 0.005,  # m/s
    "v": 0.005,  # m/s
    "w": 0.005,  # m/s
    "p": 0.005,  # rad/s
    "q": 0.005,  # rad/s
    "r": 0.005,  # rad/s
}


def bluerov2() -> VehicleParameters:
    return load_vehicle_file(BLUEROV2_FILE).parameters


def multisine(time: np.ndarray, amplitude: float, periods: tuple[float, ...], phase: float) -> np.ndarray:
    """A sum of sines (a persistently exciting input) scaled to ``amplitude`` at most."""
    s = sum(np.sin(2 * np.pi * time / T + phase * (i + 1)) for i, T in enumerate(periods))
    return amplitude * np.asarray(s) / len(periods)


def simulated_log(
    plant: Plant,
    p_true: np.ndarray,
    inputs: np.ndarray,
    time: np.ndarray,
    *,
    x0: np.ndarray | None = None,
    seed: int = 0,
    noise: bool = True,
) -> tuple[LogTable, np.ndarray]:
    """Simulate ``plant`` with ``p_true`` and write its measured states (with noise) as a log.

    Returns:
        The log (the plant's input columns and its measured states) and the true states.
    """
    X = simulate(plant, p_true, np.zeros(plant.nx) if x0 is None else x0, inputs, time)
    rng = np.random.default_rng(seed)
    cols: dict[str, np.ndarray] = {}
    for j, name in enumerate(plant.measured):
        sig = NOISE_SIGMA[name] if noise else 0.0
        value = X[:, j] + sig * rng.standard_normal(time.size)
        if name in ("phi", "theta", "psi"):
            value = (value + np.pi) % (2 * np.pi) - np.pi  # logs wrap angles
        cols[name] = value
    for j, name in enumerate(plant.input_names):
        cols[name] = inputs[:, j]
    return LogTable(time=time, columns=cols, source="<simulated>"), X
