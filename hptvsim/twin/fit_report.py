"""What a fit writes: the fitted vehicle file, the report (Markdown and JSON) and its figure."""

from __future__ import annotations

import json
import math
import re
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Final

import numpy as np

from hptvsim._files import write_atomic
from hptvsim._toml import toml_value
from hptvsim.dynamics import PARAMETER_SPECS, VehicleParameters, VehicleType
from hptvsim.dynamics.vehicles import BUILTIN_VEHICLES
from hptvsim.twin.fit import FitResult, k_step_predictions
from hptvsim.twin.plant import ANGLE_NAMES

__all__ = ["fitted_parameters", "vehicle_name", "write_fit_report", "write_vehicle_file"]

_UNITS: Final = {
    "x": "m",
    "y": "m",
    "z": "m",
    "phi": "rad",
    "theta": "rad",
    "psi": "rad",
    "u": "m/s",
    "v": "m/s",
    "w": "m/s",
    "p": "rad/s",
    "q": "rad/s",
    "r": "rad/s",
}
_PLOT_HORIZON: Final = 10  # steps: the figure shows the 10-step-ahead prediction


def vehicle_name(out: Path) -> str:
    """A vehicle type name from the output file's name (lower case, digits, ``_``; not a built-in)."""
    name = re.sub(r"[^a-z0-9_]+", "_", out.stem.lower()).strip("_") or "fitted"
    if not name[0].isalpha():
        name = "v_" + name
    name = name[:56]
    return name + "_fitted" if name in BUILTIN_VEHICLES else name


def fitted_parameters(result: FitResult, base: VehicleParameters) -> tuple[VehicleParameters, list[str]]:
    """The planar vehicle's parameters with the fit's written values; and what could not be kept.

    A 6-DOF fit's parameters that the planar set shares (same name and meaning) are taken over;
    the 6-DOF-only ones are listed (a vehicle file holds the planar model).
    """
    planar_names = set(VehicleParameters.names())
    values: dict[str, float] = {}
    dropped: list[str] = []
    for e in result.estimates:
        if e.name in planar_names:
            values[e.name] = e.written
        else:
            dropped.append(e.name)
    return base.replace(**values), dropped


def write_vehicle_file(
    result: FitResult, base: VehicleType, out: Path, *, log_source: str, vehicle_source: str
) -> VehicleType:
    """Write the fitted vehicle file (the format of ``scenarios/vehicles/*.toml``) and check it.

    Returns:
        The vehicle type as the loader reads it back.
    """
    params, dropped = fitted_parameters(result, base.parameters)
    name = vehicle_name(out)
    identifier = "".join(w.capitalize() for w in name.split("_"))
    when = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        f"# Fitted by `hptvsim vehicle fit` from {Path(log_source).name} on {when},",
        f"# starting from {vehicle_source}. Free: {', '.join(result.free)}.",
        "# Verdicts (95 % intervals in the report): "
        + "; ".join(f"{e.name} {e.verdict}" for e in result.estimates)
        + ".",
    ]
    if not result.identifiable:
        lines.append("# NOT IDENTIFIABLE from this log: the parameters so marked keep their starting values.")
    if dropped:
        lines.append(f"# 6-DOF-only parameters fitted but not in this (planar) file: {', '.join(dropped)}.")
    lines += [
        "",
        f"name = {toml_value(name)}",
        f"identifier = {toml_value(identifier)}",
        f"description = {toml_value(('Fitted from a log: ' + base.description)[:500])}",
        f"radius = {base.radius!r}  # m",
        "",
        "[parameters]",
    ]
    for spec in PARAMETER_SPECS:
        if spec.name == "control_mode":
            continue
        value = float(getattr(params, spec.name))
        lines.append(f"{spec.name} = {value!r}  # {spec.unit}")
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, "\n".join(lines) + "\n")
    from hptvsim.cosim.vehicles import load_vehicle_file

    return load_vehicle_file(out)


def _fmt(value: float) -> str:
    return "inf" if not math.isfinite(value) else f"{value:.4g}"


def _rmse_table(result: FitResult) -> list[str]:
    names = [n for n in result.plant.measured if n in result.sigma]
    head = "| horizon | " + " | ".join(f"{n} [{_UNITS[n]}] before / after" for n in names) + " |"
    rows = [head, "|---|" + "---|" * len(names)]
    for k in sorted(result.rmse_before):
        cells = []
        for n in names:
            b = result.rmse_before[k].get(n, math.nan)
            a = result.rmse_after[k].get(n, math.nan)
            cells.append(f"{_fmt(b)} / {_fmt(a)}")
        rows.append(f"| {k} step{'s' if k > 1 else ''} | " + " | ".join(cells) + " |")
    return rows


def _figure(result: FitResult, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [n for n in result.plant.measured if n in result.sigma]
    k = _PLOT_HORIZON
    preds = {
        label: k_step_predictions(
            result.plant, p, result.time, result.inputs, result.measured, result.states, result.runs, k
        )[k]
        for label, p in (("before", result.plant.base), ("after", result.p_written))
    }
    ncol = 2 if len(names) > 3 else 1
    nrow = math.ceil(len(names) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(6.5 * ncol, 2.3 * nrow + 0.8), sharex=True, squeeze=False)
    t = result.time - result.time[0]
    for ax, name in zip(axes.ravel(), names, strict=False):
        c = result.plant.measured.index(name)
        y = result.measured[:, c]
        ax.plot(t, y, ".", color="0.45", markersize=2.5, label="measured")
        for label, color, style in (("before", "#d95f02", "--"), ("after", "#1b6ac9", "-")):
            pr = preds[label][:, c]
            if name in ANGLE_NAMES:
                pr = y + ((pr - y + math.pi) % (2 * math.pi) - math.pi)
            ax.plot(t, pr, style, color=color, linewidth=1.1, label=f"{k}-step prediction, {label}")
        ax.set_ylabel(f"{name} [{_UNITS[name]}]")
        ax.grid(alpha=0.3)
    t0 = float(result.time[result.runs.spans[0][0]] - result.time[0])
    t1 = float(result.time[result.runs.spans[-1][1]] - result.time[0])
    margin = 0.05 * (t1 - t0) + 1.0  # s
    for ax in axes.ravel()[: len(names)]:
        ax.set_xlim(max(float(t[0]), t0 - margin), min(float(t[-1]), t1 + margin))  # the armed runs
        for a, b in result.runs.spans:
            ax.axvspan(float(t[a]), float(t[b]), color="#f2e6a0", alpha=0.35, linewidth=0)
    for ax in axes.ravel()[len(names) :]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    axes[0, 0].legend(loc="upper right", fontsize=8)
    verdict = "all free parameters identified" if result.identifiable else "NOT IDENTIFIABLE"
    fig.suptitle(
        f"Measured and {k}-step-ahead predicted states, before and after the fit ({verdict}; "
        "shaded: the armed runs used)"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _json(result: FitResult, **extra: Any) -> dict[str, Any]:
    def num(x: float) -> float | str:
        return x if math.isfinite(x) else ("inf" if x > 0 else "-inf")

    return {
        **extra,
        "dof": result.plant.dof,
        "inputs": result.plant.kind,
        "identifiable": result.identifiable,
        "parameters": [
            {
                "name": e.name,
                "unit": e.unit,
                "initial": e.initial,
                "estimate": e.estimate,
                "std": num(e.std),
                "ci95": [num(e.low), num(e.high)],
                "verdict": e.verdict,
                "reason": e.reason,
                "written": e.written,
                "profile_rise": list(e.profile_rise),
            }
            for e in result.estimates
        ],
        "noise_sigma": result.sigma,
        "relative_singular_values": [float(s) for s in result.relative_singular_values],
        "n_observations": result.n_observations,
        "runs": [[float(result.time[a]), float(result.time[b])] for a, b in result.runs.spans],
        "solver": {"status": result.solver_status, "iterations": result.iterations},
        "rmse_before": {str(k): v for k, v in result.rmse_before.items()},
        "rmse_after": {str(k): v for k, v in result.rmse_after.items()},
    }


def write_fit_report(
    result: FitResult, out_dir: Path, *, log_source: str, vehicle_source: str, vehicle_file: Path | None
) -> dict[str, Path]:
    """Write ``fit_report.md``, ``fit_report.json`` and ``fit_predictions.png`` into ``out_dir``.

    Returns:
        The paths written, by kind (``markdown``, ``json``, ``figure``).
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {
        "markdown": out_dir / "fit_report.md",
        "json": out_dir / "fit_report.json",
        "figure": out_dir / "fit_predictions.png",
    }
    _figure(result, paths["figure"])
    duration = sum(float(result.time[b] - result.time[a]) for a, b in result.runs.spans)
    dt = float(np.median(np.diff(result.time)))
    lines = [
        "# Vehicle fit",
        "",
        f"Log: `{log_source}`; starting vehicle: `{vehicle_source}`; model: {result.plant.dof}-DOF, "
        f"inputs: {'body forces' if result.plant.kind == 'tau' else 'commands through the controller'}.",
        f"Used: {len(result.runs.spans)} armed run(s), {duration:.1f} s, median step {dt:.3g} s, "
        f"{result.n_observations} measured values.",
        "",
    ]
    if result.identifiable:
        lines.append("**Verdict: every free parameter is identified from this log.**")
    else:
        bad = [e.name for e in result.estimates if not e.identifiable]
        lines.append(
            f"**Verdict: NOT IDENTIFIABLE from this log: {', '.join(bad)}.** The log does not excite "
            "the vehicle enough to determine them; they keep their starting values in the vehicle file, "
            "and their estimates below are not results. Log more varied motion (surge, sway and yaw "
            "steps and sweeps in both directions, at several speeds) and fit again."
        )
    lines += [
        "",
        "| parameter | unit | start | estimate | 95 % interval | verdict | written |",
        "|---|---|---|---|---|---|---|",
    ]
    for e in result.estimates:
        ci = f"[{_fmt(e.low)}, {_fmt(e.high)}]" if math.isfinite(e.std) else "undetermined"
        why = f" ({e.reason})" if e.reason else ""
        lines.append(
            f"| {e.name} | {e.unit} | {_fmt(e.initial)} | {_fmt(e.estimate)} | {ci} | {e.verdict}{why} | "
            f"{_fmt(e.written)} |"
        )
    lines += [
        "",
        "## Prediction RMSE (k steps of the log's grid ahead)",
        "",
        "From every sample the model starts at the measured state and runs k steps on the logged "
        "inputs; before: the starting vehicle; after: the vehicle file written.",
        "",
        *_rmse_table(result),
        "",
        "Noise estimated from the residuals: "
        + ", ".join(f"{n} {s:.3g} {_UNITS[n]}" for n, s in result.sigma.items())
        + ".",
        "",
        f"Solver: IPOPT, {result.solver_status}, {result.iterations} iterations. Smallest relative singular "
        f"value of the reduced residual Jacobian: {_fmt(float(result.relative_singular_values[-1]))}.",
        "",
        f"![measured and predicted]({paths['figure'].name})",
        "",
    ]
    if vehicle_file is not None:
        lines.insert(4, f"Vehicle file written: `{vehicle_file}`.")
    write_atomic(paths["markdown"], "\n".join(lines))
    data = _json(
        result,
        log=log_source,
        vehicle=vehicle_source,
        vehicle_file=None if vehicle_file is None else str(vehicle_file),
    )
    write_atomic(paths["json"], json.dumps(data, indent=2) + "\n")
    return paths
