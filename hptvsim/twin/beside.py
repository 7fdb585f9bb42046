"""The twin beside the vehicle: a vehicle's FMU driven by the logged commands, and its errors.

While the vehicle is armed, the twin (the vehicle file's planar FMU, stepped through the project's
FMI layer, :mod:`hptvsim.cosim.fmu_model`) gets the same inputs on the log's grid, held over each
step: body forces ``tau_X, tau_Y, tau_N`` (the FMU in raw mode, ``control_mode = 1``, actuator
limits lifted), thruster PWM through :mod:`hptvsim.twin.thrusters`, or commands ``v_cmd,
omega_cmd`` through the FMU's own controller. It starts from the measured state at the start of
each armed run and is re-synchronised to the measured state every ``resync_s`` seconds (FMU reset
and initialised at the measured pose and velocities; the controller's integrators restart at zero:
the FMU has no start values for them, so with commands the first steps after a re-synchronisation
carry the integrators' error, which the k-step errors include).

The k-step prediction error (k = 1, 10, 100 steps of the log's grid), the way BlueROV2
identification work reports it: from start samples spread over the runs, the FMU is initialised
at the measured state and run k steps on the logged inputs; the RMSE per state is over the
starts (angles modulo 2 pi). Nothing here reads files; :func:`write_beside_report` writes the
tables and figures.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np

from hptvsim._files import write_atomic
from hptvsim.dynamics import VehicleType
from hptvsim.twin.plant import ANGLE_NAMES, PLANAR_MEASURED, TAU_NAMES_3
from hptvsim.twin.table import LogError, LogTable, Runs, input_kind, split_runs

__all__ = ["HORIZONS", "TwinResult", "run_beside", "write_beside_report"]

HORIZONS: Final = (1, 10, 100)
_UNITS: Final = {"x": "m", "y": "m", "psi": "rad", "u": "m/s", "v": "m/s", "r": "rad/s"}
_COLORS: Final = {
    "x": "#1b6ac9",
    "y": "#d95f02",
    "psi": "#7570b3",
    "u": "#1b9e77",
    "v": "#e7298a",
    "r": "#66a61e",
}
_INIT: Final = {"x": "x_0", "y": "y_0", "psi": "psi_0", "u": "u_0", "v": "v_0", "r": "r_0"}
_NO_LIMIT: Final = 1e9  # N, N m


@dataclass(frozen=True)
class TwinResult:
    """The twin run beside a log.

    Attributes:
        time: Sample times [s].
        measured: Measured states (samples x :data:`PLANAR_MEASURED`), ``NaN`` where missing.
        twin: The twin's states, re-synchronised every ``resync_s`` (``NaN`` outside the runs).
        resync_s: Re-synchronisation period [s] (``None``: only at the start of each run).
        runs: The armed runs.
        rmse: ``{k: {state: rmse}}`` of the k-step predictions.
        rmse_twin: RMSE of the re-synchronised twin per state.
        n_starts: Start samples of the k-step predictions.
        inputs: ``"tau"``, ``"pwm"`` or ``"cmd"``.
    """

    time: np.ndarray
    measured: np.ndarray
    twin: np.ndarray
    resync_s: float | None
    runs: Runs
    rmse: dict[int, dict[str, float]]
    rmse_twin: dict[str, float]
    n_starts: int
    inputs: str


class _Twin:
    """One FMU instance of a vehicle, set up for the log's inputs."""

    def __init__(self, fmu: Path, vehicle: VehicleType, kind: str, overrides: Mapping[str, float]) -> None:
        from hptvsim.cosim.fmu_model import load_model

        self.inst = load_model(fmu).instantiate("twin")
        self.kind = kind
        params: dict[str, float] = dict(overrides)
        if kind == "tau":
            params |= {"tau_X_max": _NO_LIMIT, "tau_Y_max": _NO_LIMIT, "tau_N_max": _NO_LIMIT}
        self.params = params
        self.control_mode = 1 if kind == "tau" else 0
        self.inst.initialize(self._values(np.zeros(6)))
        names = [*TAU_NAMES_3] if kind == "tau" else ["v_cmd", "omega_cmd"]
        self.names_in = [f"{n}_cmd" for n in names] if kind == "tau" else names
        self.u = self.inst.bind_inputs([*self.names_in, "current_x", "current_y"])
        self.inst.bind_outputs(list(PLANAR_MEASURED))

    def _values(self, x0: np.ndarray) -> dict[str, Any]:
        vals: dict[str, Any] = {name: float(v) for name, v in self.params.items()}
        vals["control_mode"] = self.control_mode
        for j, name in enumerate(PLANAR_MEASURED):
            vals[_INIT[name]] = float(x0[j])
        return vals

    def restart(self, x0: np.ndarray) -> None:
        """Reset and initialise at a state ``[x, y, psi, u, v, r]``."""
        self.inst.reset()
        self.inst.initialize(self._values(x0))

    def step(self, u: np.ndarray, h: float) -> np.ndarray:
        """One communication step of ``h`` [s] with inputs ``u`` held; returns the six states."""
        self.u[:] = u
        return np.asarray(self.inst.step(h)).copy()

    def close(self) -> None:
        self.inst.terminate()
        self.inst.free()


def _inputs(table: LogTable) -> tuple[str, np.ndarray]:
    """The FMU inputs per sample: ``(kind label, samples x (2 or 3 + 2 currents))``."""
    kind, cols, from_pwm = input_kind(table, 3)
    n = table.time.size
    cur = np.stack([np.nan_to_num(table.column(c)) for c in ("current_x", "current_y")], axis=1)
    if from_pwm:
        from hptvsim.twin.table import PWM_NAMES
        from hptvsim.twin.thrusters import NEUTRAL_PWM, pwm_to_tau

        pwm = np.stack([table.column(c) for c in PWM_NAMES], axis=1)
        pwm = np.where(np.isfinite(pwm), pwm, NEUTRAL_PWM)
        tau = pwm_to_tau(pwm)[:, [0, 1, 5]]
        return "pwm", np.concatenate([tau, cur], axis=1)
    U = np.stack([table.column(c) for c in cols], axis=1)
    bad = ~np.isfinite(U)
    if bad.any():
        j = int(np.argwhere(bad)[0][1])
        raise LogError(f"{table.source}: column {cols[j]!r} has missing values; the twin needs every row")
    assert U.shape[0] == n
    return kind, np.concatenate([U, cur], axis=1)


def _start_state(Y: np.ndarray, i: int, fallback: np.ndarray) -> np.ndarray:
    x = Y[i].copy()
    return np.where(np.isfinite(x), x, fallback)


def _wrap(e: np.ndarray) -> np.ndarray:
    return np.asarray((e + math.pi) % (2 * math.pi) - math.pi)


def run_beside(
    table: LogTable,
    vehicle: VehicleType,
    *,
    fmu: Path | None = None,
    resync_s: float | None = 10.0,
    horizons: Sequence[int] = HORIZONS,
    max_starts: int = 300,
    parameters: Mapping[str, float] | None = None,
) -> TwinResult:
    """Run the vehicle's FMU beside a log (see the module docstring).

    Args:
        table: The log (time, measured planar states, inputs; ``armed`` optional).
        vehicle: The vehicle type (its FMU: :func:`hptvsim.fmu.fmu_for`, unless ``fmu`` is given).
        fmu: The FMU to run (default: the vehicle's).
        resync_s: Re-synchronise the twin to the measurement every this many seconds.
        horizons: Prediction horizons [steps].
        max_starts: At most this many start samples for the k-step predictions.
        parameters: Parameter values set in the FMU over its start values.

    Raises:
        LogError: The log lacks inputs or measured states, or has no armed run.
    """
    if fmu is None:
        from hptvsim.fmu import fmu_for

        fmu = fmu_for(vehicle)
    label, U = _inputs(table)
    kind = "cmd" if label == "cmd" else "tau"
    Y = np.stack([table.column(n) for n in PLANAR_MEASURED], axis=1)
    if not np.isfinite(Y).any():
        raise LogError(
            f"{table.source}: no measured state; give at least one of {', '.join(PLANAR_MEASURED)}"
        )
    j_psi = PLANAR_MEASURED.index("psi")
    ok = np.isfinite(Y[:, j_psi])
    if ok.any():
        Y[ok, j_psi] = np.unwrap(Y[ok, j_psi])
    runs = split_runs(table)
    if not runs.spans:
        raise LogError(f"{table.source}: no armed stretch of at least 3 samples")
    t = table.time
    twin = _Twin(fmu, vehicle, kind, parameters or {})
    try:
        X = np.full(Y.shape, np.nan)
        for a, b in runs.spans:
            last = np.zeros(6)
            next_sync = t[a]
            for i in range(a, b + 1):
                if i == a or (resync_s is not None and t[i] >= next_sync - 1e-9):
                    x0 = _start_state(Y, i, last if i > a else np.zeros(6))
                    twin.restart(x0)
                    X[i] = x0
                    next_sync = t[i] + (resync_s if resync_s is not None else math.inf)
                if i < b:
                    last = twin.step(U[i], float(t[i + 1] - t[i]))
                    # the FMU's yaw is wrapped; keep the twin's continuous like the measurement's
                    last[j_psi] = X[i, j_psi] + _wrap(np.asarray(last[j_psi] - X[i, j_psi]))
                    X[i + 1] = last
        # k-step predictions from spread start samples
        used = np.concatenate([np.arange(a, b) for a, b in runs.spans])
        starts = used[np.linspace(0, used.size - 1, min(max_starts, used.size)).astype(int)]
        run_end = np.zeros(t.size, dtype=int)
        for a, b in runs.spans:
            run_end[a : b + 1] = b
        k_max = max(horizons)
        errs: dict[int, list[np.ndarray]] = {k: [] for k in horizons}
        for s in np.unique(starts):
            twin.restart(_start_state(Y, int(s), np.zeros(6)))
            for k in range(1, k_max + 1):
                i = int(s) + k
                if i > run_end[s]:
                    break
                x = twin.step(U[i - 1], float(t[i] - t[i - 1]))
                if k in errs:
                    errs[k].append(x - Y[i])
    finally:
        twin.close()
    rmse: dict[int, dict[str, float]] = {}
    for k in horizons:
        row: dict[str, float] = {}
        if errs[k]:
            E = np.array(errs[k])
            for j, name in enumerate(PLANAR_MEASURED):
                e = _wrap(E[:, j]) if name in ANGLE_NAMES else E[:, j]
                e = e[np.isfinite(e)]
                if e.size:
                    row[name] = float(np.sqrt(np.mean(e**2)))
        rmse[k] = row
    rmse_twin: dict[str, float] = {}
    for j, name in enumerate(PLANAR_MEASURED):
        e = X[:, j] - Y[:, j]
        e = _wrap(e) if name in ANGLE_NAMES else e
        e = e[np.isfinite(e)]
        if e.size:
            rmse_twin[name] = float(np.sqrt(np.mean(e**2)))
    return TwinResult(
        time=t,
        measured=Y,
        twin=X,
        resync_s=resync_s,
        runs=runs,
        rmse=rmse,
        rmse_twin=rmse_twin,
        n_starts=int(np.unique(starts).size),
        inputs=label,
    )


def _figures(result: TwinResult, out_dir: Path) -> dict[str, Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = {"states": out_dir / "twin_states.png", "errors": out_dir / "twin_errors.png"}
    names = [n for n in PLANAR_MEASURED if n in result.rmse_twin]
    t = result.time - result.time[0]
    fig, axes = plt.subplots(3, 2, figsize=(12, 8), sharex=True, squeeze=False)
    for ax, name in zip(axes.T.ravel(), PLANAR_MEASURED, strict=True):
        if name not in names:
            ax.set_visible(False)
            continue
        j = PLANAR_MEASURED.index(name)
        ax.plot(t, result.measured[:, j], ".", color="0.5", markersize=2.5, label="measured")
        ax.plot(t, result.twin[:, j], "-", color=_COLORS[name], linewidth=1.2, label="twin")
        ax.set_ylabel(f"{name} [{_UNITS[name]}]")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    t0 = float(t[result.runs.spans[0][0]])
    t1 = float(t[result.runs.spans[-1][1]])
    margin = 0.05 * (t1 - t0) + 1.0  # s
    for ax in axes.ravel():
        ax.set_xlim(max(float(t[0]), t0 - margin), min(float(t[-1]), t1 + margin))  # the armed runs
        for a, b in result.runs.spans:
            ax.axvspan(float(t[a]), float(t[b]), color="#f2e6a0", alpha=0.35, linewidth=0)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    sync = (
        "only at the start of each armed run" if result.resync_s is None else f"every {result.resync_s:g} s"
    )
    fig.suptitle(
        f"The twin beside the vehicle ({result.inputs} inputs; re-synchronised {sync}; shaded: armed)"
    )
    fig.tight_layout()
    fig.savefig(paths["states"], dpi=110)
    plt.close(fig)

    groups = (
        ("position", ("x", "y"), "m"),
        ("yaw", ("psi",), "rad"),
        ("velocity", ("u", "v"), "m/s"),
        ("yaw rate", ("r",), "rad/s"),
    )
    fig, axes2 = plt.subplots(1, 4, figsize=(13, 3.6), squeeze=False)
    ks = sorted(result.rmse)
    for ax, (title, members, unit) in zip(axes2[0], groups, strict=True):
        for name in members:
            vals = [result.rmse[k].get(name, np.nan) for k in ks]
            ax.plot(ks, vals, "o-", color=_COLORS[name], label=name)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xticks(ks, [str(k) for k in ks])
        ax.set_xlabel("prediction horizon [steps]")
        ax.set_ylabel(f"RMSE [{unit}]")
        ax.set_title(title)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.suptitle(f"k-step-ahead prediction error of the twin ({result.n_starts} start samples)")
    fig.tight_layout()
    fig.savefig(paths["errors"], dpi=110)
    plt.close(fig)
    return paths


def write_beside_report(
    result: TwinResult, out_dir: Path, *, log_source: str, vehicle_source: str
) -> dict[str, Path]:
    """Write ``twin_report.md``, ``twin_report.json`` and the two figures into ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = _figures(result, out_dir)
    names = [n for n in PLANAR_MEASURED if n in result.rmse_twin]
    lines = [
        "# The twin beside the vehicle",
        "",
        f"Log: `{log_source}`; vehicle: `{vehicle_source}`; inputs: {result.inputs}; "
        f"{len(result.runs.spans)} armed run(s); re-synchronised "
        + ("only at run starts." if result.resync_s is None else f"every {result.resync_s:g} s."),
        "",
        "| horizon | " + " | ".join(f"{n} [{_UNITS[n]}]" for n in names) + " |",
        "|---|" + "---|" * len(names),
    ]
    for k in sorted(result.rmse):
        lines.append(
            f"| {k} step{'s' if k > 1 else ''} | "
            + " | ".join(f"{result.rmse[k].get(n, math.nan):.4g}" for n in names)
            + " |"
        )
    lines.append(
        "| twin (re-synchronised) | " + " | ".join(f"{result.rmse_twin[n]:.4g}" for n in names) + " |"
    )
    lines += ["", f"![states]({paths['states'].name})", "", f"![errors]({paths['errors'].name})", ""]
    md = out_dir / "twin_report.md"
    write_atomic(md, "\n".join(lines))
    data = {
        "log": log_source,
        "vehicle": vehicle_source,
        "inputs": result.inputs,
        "resync_s": result.resync_s,
        "rmse": {str(k): v for k, v in result.rmse.items()},
        "rmse_twin": result.rmse_twin,
        "n_starts": result.n_starts,
    }
    js = out_dir / "twin_report.json"
    write_atomic(js, json.dumps(data, indent=2) + "\n")
    return {"markdown": md, "json": js, **paths}
