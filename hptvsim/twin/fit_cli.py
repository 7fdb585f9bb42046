"""Command line of the calibration: ``hptvsim vehicle fit`` (and ``hptvsim twin predict``).

``hptvsim vehicle fit LOG.csv --vehicle TYPE_OR_FILE --free P1,P2,... --out FITTED.toml`` fits the
free parameters to the log (:mod:`hptvsim.twin.fit`) and writes the fitted vehicle file and, beside
it, a report folder (``FITTED_report/``: Markdown, JSON, figure).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click

if TYPE_CHECKING:
    from hptvsim.dynamics import SixDofControllerParameters, SixDofParameters, VehicleType

__all__ = ["register", "resolve_vehicle", "sixdof_base"]


def resolve_vehicle(spec: str) -> tuple[VehicleType, str]:
    """A built-in vehicle type by name, or a vehicle file; and how to name it in reports.

    Raises:
        click.BadParameter: Neither (the message lists the built-in types).
    """
    from hptvsim.cosim.vehicles import ExternalVehicleType, VehicleFileError, load_vehicle_file
    from hptvsim.dynamics import BUILTIN_VEHICLES

    if spec in BUILTIN_VEHICLES:
        return BUILTIN_VEHICLES[spec], spec
    path = Path(spec)
    if not path.exists():
        raise click.BadParameter(
            f"{spec!r} is neither a vehicle type ({', '.join(BUILTIN_VEHICLES)}) nor an existing "
            "vehicle file",
            param_hint="--vehicle",
        )
    try:
        vt = load_vehicle_file(path)
    except VehicleFileError as exc:
        raise click.BadParameter(str(exc), param_hint="--vehicle") from None
    if isinstance(vt, ExternalVehicleType):
        raise click.BadParameter(
            f"{spec} brings its own FMU; only a vehicle file of Fossen parameters can be fitted",
            param_hint="--vehicle",
        )
    return vt, str(path)


def sixdof_base(vt: VehicleType) -> tuple[SixDofParameters, SixDofControllerParameters]:
    """The 6-DOF model and controller parameters a vehicle starts a 6-DOF fit from.

    Built-in types: their 6-DOF sets. A vehicle file (planar): its parameters mapped by
    :func:`~hptvsim.dynamics.sixdof_from_planar`, with roll and pitch inertia set to the yaw
    inertia (a placeholder: free ``I_x``, ``I_y`` to fit them) and the 6-DOF-only terms zero.
    """
    from hptvsim.dynamics import (
        SIXDOF_CONTROLLER_TYPES,
        SIXDOF_VEHICLE_TYPES,
        sixdof_controller_from_planar,
        sixdof_from_planar,
    )

    if vt.builtin:
        return SIXDOF_VEHICLE_TYPES[vt.name], SIXDOF_CONTROLLER_TYPES[vt.name]
    p = vt.parameters
    return sixdof_from_planar(p, I_x=p.I_z, I_y=p.I_z), sixdof_controller_from_planar(p)


def _fit(
    log: Path,
    vehicle: str,
    free: str,
    out: Path,
    report_dir: Path | None,
    dof: int | None,
    segment_steps: int,
    profile: bool,
) -> None:
    from hptvsim.dynamics import ParameterError
    from hptvsim.twin.fit import FitError, FitOptions, fit_log
    from hptvsim.twin.fit_report import write_fit_report, write_vehicle_file
    from hptvsim.twin.plant import make_plant
    from hptvsim.twin.table import LogError, infer_dof, input_kind, read_log_csv

    vt, source = resolve_vehicle(vehicle)
    names = [n.strip() for n in free.split(",") if n.strip()]
    try:
        table = read_log_csv(log)
        n_dof = dof or infer_dof(table)
        kind, _, from_pwm = input_kind(table, n_dof)
        if n_dof == 3:
            plant = make_plant(kind, planar=vt.parameters)
        else:
            plant = make_plant(kind, sixdof=sixdof_base(vt))
        click.echo(
            f"fitting {', '.join(names)} of the {n_dof}-DOF model to {log} "
            f"({'thruster PWM' if from_pwm else kind} inputs) ..."
        )
        result = fit_log(
            table,
            plant,
            names,
            from_pwm=from_pwm,
            options=FitOptions(segment_steps=segment_steps, profile_check=profile),
        )
    except (LogError, FitError) as exc:
        raise click.ClickException(str(exc)) from None
    try:
        write_vehicle_file(result, vt, out, log_source=str(log), vehicle_source=source)
    except ParameterError as exc:
        raise click.ClickException(f"the fitted vehicle is invalid: {exc}") from None
    folder = report_dir if report_dir is not None else out.with_name(out.stem + "_report")
    paths = write_fit_report(result, folder, log_source=str(log), vehicle_source=source, vehicle_file=out)
    for e in result.estimates:
        ci = f"[{e.low:.4g}, {e.high:.4g}]" if e.std < float("inf") else "undetermined"
        click.echo(f"  {e.name} = {e.estimate:.4g} {e.unit}, 95 % {ci}: {e.verdict}")
    if not result.identifiable:
        click.echo("NOT IDENTIFIABLE from this log (see the report): those parameters keep their values.")
    click.echo(f"wrote {out} and {paths['markdown']}")


def _predict(log: Path, vehicle: str, resync_s: float | None, out_dir: Path) -> None:
    from hptvsim.twin.beside import run_beside, write_beside_report
    from hptvsim.twin.table import LogError, read_log_csv

    vt, source = resolve_vehicle(vehicle)
    try:
        result = run_beside(read_log_csv(log), vt, resync_s=resync_s)
    except LogError as exc:
        raise click.ClickException(str(exc)) from None
    paths = write_beside_report(result, out_dir, log_source=str(log), vehicle_source=source)
    for k, row in sorted(result.rmse.items()):
        click.echo(f"  {k:>3}-step RMSE: " + ", ".join(f"{n} {v:.3g}" for n, v in row.items()))
    click.echo(f"wrote {paths['markdown']}")


def register(main: click.Group) -> None:
    """Add ``hptvsim vehicle fit`` and ``hptvsim twin predict`` (groups created when not there)."""
    group = main.commands.get("vehicle")
    if not isinstance(group, click.Group):

        @main.group("vehicle")
        def vehicle_group() -> None:
            """Vehicle types: calibrate one from a log."""

        group = vehicle_group

    @group.command("fit")
    @click.argument("log", type=click.Path(dir_okay=False, exists=True, path_type=Path))
    @click.option(
        "--vehicle", required=True, help="Starting vehicle: a built-in type or a vehicle file (TOML)."
    )
    @click.option("--free", required=True, help="Parameters to fit, comma-separated (e.g. X_udot,X_u,X_uu).")
    @click.option(
        "--out", required=True, type=click.Path(dir_okay=False, path_type=Path), help="Fitted vehicle file."
    )
    @click.option(
        "--report",
        "report_dir",
        type=click.Path(file_okay=False, path_type=Path),
        default=None,
        help="Report folder (default: OUT's name + _report beside it).",
    )
    @click.option(
        "--dof",
        type=click.Choice(["3", "6"]),
        default=None,
        help="Model (default: 6 when the log has tau_Z/tau_K/tau_M or w_z_cmd, else 3).",
    )
    @click.option("--segment-steps", type=click.IntRange(1, 10_000), default=20, show_default=True)
    @click.option("--no-profile", is_flag=True, help="Skip the profile-likelihood check of each interval.")
    def vehicle_fit(
        log: Path,
        vehicle: str,
        free: str,
        out: Path,
        report_dir: Path | None,
        dof: str | None,
        segment_steps: int,
        no_profile: bool,
    ) -> None:
        """Fit a vehicle's parameters to a log CSV (time, measured states, forces/commands/PWM)."""
        _fit(log, vehicle, free, out, report_dir, int(dof) if dof else None, segment_steps, not no_profile)

    twin = main.commands.get("twin")
    if not isinstance(twin, click.Group):

        @main.group("twin")
        def twin_group() -> None:
            """The twin of a real vehicle: its logs, and the model beside them."""

        twin = twin_group

    @twin.command("predict")
    @click.argument("log", type=click.Path(dir_okay=False, exists=True, path_type=Path))
    @click.option("--vehicle", required=True, help="A built-in type or a vehicle file (TOML).")
    @click.option(
        "--resync-s",
        type=click.FloatRange(min=0.0, min_open=True),
        default=10.0,
        show_default=True,
        help="Re-synchronise the twin to the measured state every this many seconds.",
    )
    @click.option(
        "--out",
        "out_dir",
        type=click.Path(file_okay=False, path_type=Path),
        default=Path("twin_report"),
        show_default=True,
        help="Folder for the report and figures.",
    )
    def twin_predict(log: Path, vehicle: str, resync_s: float, out_dir: Path) -> None:
        """Run a vehicle's FMU beside a log CSV: k-step prediction errors (1, 10, 100 steps), figures."""
        _predict(log, vehicle, resync_s, out_dir)
