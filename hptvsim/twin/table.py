"""A log as plain arrays: reading the fit CSV and turning its columns into a plant's inputs.

The CSV has a header row and one row per sample (``NaN`` or an empty field where a value was not
logged). Columns (SI units):

* ``time`` [s], increasing;
* measured states: planar ``x, y, psi, u, v, r``; 6-DOF ``x, y, z, phi, theta, psi, u, v, w, p,
  q, r`` [m, rad, m/s, rad/s]; any may be missing or ``NaN``, at least one must be there;
* inputs, one set of: body forces ``tau_X, tau_Y, tau_N`` [N, N, N m] (6-DOF also ``tau_Z`` [N],
  ``tau_K, tau_M`` [N m]); commands ``v_cmd, omega_cmd`` [m/s, rad/s] (6-DOF also ``w_z_cmd``
  [m/s]) through the built-in controller; or thruster PWM ``pwm_1 .. pwm_8`` [us] through the
  BlueROV2 Heavy's thrusters (:mod:`hptvsim.twin.thrusters`);
* optional: ``current_x, current_y`` [m/s] (ocean current in {n}); ``armed`` (0/1: rows with 0
  are not used).

``hptvsim twin replay LOG --csv OUT.csv`` writes such a file from a MAVLink log.
"""

from __future__ import annotations

import csv
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np

from hptvsim.twin.plant import (
    ANGLE_NAMES,
    PLANAR_MEASURED,
    SIXDOF_MEASURED,
    TAU_NAMES_3,
    TAU_NAMES_6,
    InputKind,
    Plant,
)

__all__ = [
    "PWM_NAMES",
    "LogError",
    "LogTable",
    "Runs",
    "default_sigma",
    "infer_dof",
    "input_kind",
    "measured_matrix",
    "plant_inputs",
    "read_log_csv",
    "split_runs",
]

PWM_NAMES: Final = tuple(f"pwm_{i}" for i in range(1, 9))
_GAP_FACTOR: Final = 5.0  # a step longer than this many median steps breaks a run


class LogError(ValueError):
    """A log table is missing a column, or a column is invalid (the message names it)."""


@dataclass(frozen=True)
class LogTable:
    """A log as arrays: ``time`` [s] and the other columns by name (``NaN`` where not logged).

    Attributes:
        time: Sample times [s], strictly increasing.
        columns: Every other column, each as long as ``time``.
        source: Where it came from (for messages).
    """

    time: np.ndarray
    columns: Mapping[str, np.ndarray]
    source: str = "<log>"

    def __post_init__(self) -> None:
        t = np.asarray(self.time, dtype=float)
        if t.ndim != 1 or t.size < 3:
            raise LogError(f"{self.source}: column 'time' needs at least 3 samples")
        if not np.all(np.isfinite(t)):
            raise LogError(f"{self.source}: column 'time' has missing or non-finite values")
        if not np.all(np.diff(t) > 0):
            raise LogError(f"{self.source}: column 'time' must increase strictly [s]")
        for name, col in self.columns.items():
            if np.shape(col) != t.shape:
                raise LogError(f"{self.source}: column {name!r} has {np.size(col)} values, 'time' {t.size}")

    def has(self, name: str) -> bool:
        """Whether the column is there with at least one finite value."""
        col = self.columns.get(name)
        return col is not None and bool(np.any(np.isfinite(col)))

    def column(self, name: str) -> np.ndarray:
        """A column (all ``NaN`` when missing)."""
        col = self.columns.get(name)
        return np.full(self.time.shape, np.nan) if col is None else np.asarray(col, dtype=float)

    def slice(self, rows: np.ndarray) -> LogTable:
        """The rows selected by a boolean mask or an index array."""
        return LogTable(
            time=self.time[rows], columns={k: v[rows] for k, v in self.columns.items()}, source=self.source
        )


def read_log_csv(path: str | Path) -> LogTable:
    """Read a log CSV (see the module docstring).

    Raises:
        LogError: The file cannot be read, has no ``time`` column or a non-numeric value.
    """
    p = Path(path)
    try:
        with open(p, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except OSError as exc:
        raise LogError(f"{p}: cannot be read: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise LogError(
            f"{p}: not a CSV text file ({exc}); expected a header row starting with 'time'"
        ) from None
    if not rows:
        raise LogError(f"{p}: empty file; expected a header row starting with 'time'")
    header = [h.strip() for h in rows[0]]
    if "time" not in header:
        raise LogError(f"{p}: no 'time' column [s]; the header has {', '.join(header[:12])}")
    data = np.full((len(rows) - 1, len(header)), np.nan)
    for i, row in enumerate(rows[1:]):
        if len(row) != len(header):
            raise LogError(f"{p}: row {i + 2} has {len(row)} fields, the header {len(header)}")
        for j, field in enumerate(row):
            text = field.strip()
            if text == "" or text.lower() == "nan":
                continue
            try:
                data[i, j] = float(text)
            except ValueError:
                raise LogError(f"{p}: row {i + 2}, column {header[j]!r}: {text!r} is not a number") from None
    cols = {name: data[:, j] for j, name in enumerate(header) if name != "time"}
    return LogTable(time=data[:, header.index("time")], columns=cols, source=str(p))


def infer_dof(table: LogTable) -> int:
    """6 when the log has a 6-DOF input (``tau_Z, tau_K, tau_M`` or ``w_z_cmd``), else 3."""
    six = ("tau_Z", "tau_K", "tau_M", "w_z_cmd")
    return 6 if any(table.has(name) for name in six) else 3


def input_kind(table: LogTable, dof: int) -> tuple[InputKind, tuple[str, ...], bool]:
    """Which input set the log provides: ``(kind, columns, from_pwm)``.

    Forces first, then commands, then PWM (forces through the thruster model).

    Raises:
        LogError: None of the sets is complete (the message names what is missing).
    """
    taus = TAU_NAMES_3 if dof == 3 else TAU_NAMES_6
    cmds = ("v_cmd", "omega_cmd") if dof == 3 else ("v_cmd", "omega_cmd", "w_z_cmd")
    if all(table.has(n) for n in taus):
        return "tau", taus, False
    if all(table.has(n) for n in cmds):
        return "cmd", cmds, False
    if any(table.has(n) for n in PWM_NAMES):
        return "tau", taus, True
    missing_tau = [n for n in taus if not table.has(n)]
    missing_cmd = [n for n in cmds if not table.has(n)]
    raise LogError(
        f"{table.source}: no complete input set; missing {', '.join(missing_tau)} (body forces), or "
        f"{', '.join(missing_cmd)} (commands), or pwm_1..pwm_8 (thruster PWM [us])"
    )


def plant_inputs(table: LogTable, plant: Plant, *, from_pwm: bool) -> np.ndarray:
    """The plant's input matrix ``U`` (samples x inputs), held over each step.

    PWM goes through :func:`hptvsim.twin.thrusters.pwm_to_tau` (missing PWM or ``armed = 0``:
    neutral, 1500 us). Missing currents are zero.

    Raises:
        LogError: A force or command column has a missing value (the message gives the row).
    """
    n = table.time.size
    U = np.zeros((n, plant.nu))
    if from_pwm:
        from hptvsim.twin.thrusters import NEUTRAL_PWM, pwm_to_tau

        pwm = np.stack([table.column(name) for name in PWM_NAMES], axis=1)
        pwm = np.where(np.isfinite(pwm), pwm, NEUTRAL_PWM)
        if table.has("armed"):
            pwm[table.column("armed") < 0.5] = NEUTRAL_PWM
        tau6 = pwm_to_tau(pwm)  # N, N m: samples x 6
        if plant.dof == 3:
            U[:, 0:3] = tau6[:, [0, 1, 5]]
        else:
            U[:, 0:6] = tau6
    for j, name in enumerate(plant.input_names):
        if from_pwm and name.startswith("tau_"):
            continue
        col = table.column(name)
        if name.startswith("current_"):
            U[:, j] = np.where(np.isfinite(col), col, 0.0)
            continue
        bad = np.flatnonzero(~np.isfinite(col))
        if bad.size:
            raise LogError(
                f"{table.source}: column {name!r} has {bad.size} missing value(s) (first at time "
                f"{table.time[bad[0]]:.6g} s); give every row a value or drop the rows"
            )
        U[:, j] = col
    return U


def measured_matrix(table: LogTable, plant: Plant) -> np.ndarray:
    """The measured states (samples x ``plant.measured``), ``NaN`` where missing; angles unwrapped.

    Raises:
        LogError: No measured state is there (the message lists the valid names).
    """
    names = PLANAR_MEASURED if plant.dof == 3 else SIXDOF_MEASURED
    Y = np.stack([table.column(name) for name in names], axis=1)
    if not np.any(np.isfinite(Y)):
        raise LogError(f"{table.source}: no measured state; give at least one of {', '.join(names)}")
    for j, name in enumerate(names):
        if name in ANGLE_NAMES:
            ok = np.isfinite(Y[:, j])
            if ok.any():
                Y[ok, j] = np.unwrap(Y[ok, j])
    return Y


@dataclass(frozen=True)
class Runs:
    """Contiguous stretches of a log that a simulation may cross: ``(first, last)`` row indices."""

    spans: tuple[tuple[int, int], ...]


def split_runs(table: LogTable, *, min_samples: int = 3) -> Runs:
    """Split a log where it is disarmed (``armed = 0``) or has a gap (a step over 5 median steps)."""
    t = table.time
    use = np.ones(t.size, dtype=bool)
    if table.has("armed"):
        armed = table.column("armed")
        use = np.isfinite(armed) & (armed >= 0.5)
    dt = np.diff(t)
    gap = dt > _GAP_FACTOR * float(np.median(dt))
    spans: list[tuple[int, int]] = []
    start: int | None = None
    for i in range(t.size):
        if use[i] and start is None:
            start = i
        end_here = start is not None and (not use[i] or (i < t.size - 1 and (gap[i] or not use[i + 1])))
        if start is not None and (end_here or i == t.size - 1):
            last = i if use[i] else i - 1
            if last - start + 1 >= min_samples:
                spans.append((start, last))
            start = None
    return Runs(spans=tuple(spans))


def default_sigma(name: str) -> float:
    """A starting guess of a measured state's noise (m, rad, m/s, rad/s); the fit re-estimates it."""
    if name in ANGLE_NAMES:
        return 0.02  # rad
    if name in ("x", "y", "z"):
        return 0.05  # m
    if name in ("u", "v", "w"):
        return 0.02  # m/s
    return 0.01  # rad/s (p, q, r)
