"""The ``hptvsim`` command line: the top layer, which registers every layer's commands.

Each command imports what it needs when it runs, so ``hptvsim --help`` stays fast. A package
adds its commands through its ``cli`` module's ``register(main)`` (the co-simulation, world,
sensors and visualisation layers; the experiments, which hold the training and offline-RL
commands that start from the policy zoo's names; the service), imported here; the benchmarks,
each of which measures a lower layer, are registered from the top as well
(:mod:`hptvsim.bench.cli`), and the service adds ``hptvsim bench service``.

A user error (an unknown name, a missing file, a bad number) ends a command with one line,
``Error: ...``, naming the bad value and the valid ones, never a traceback: each command turns
the errors its inputs can cause into click errors.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

import click

from hptvsim import __version__
from hptvsim._output import check_choice
from hptvsim.bench import cli as bench_cli
from hptvsim.cosim import cli as cosim_cli
from hptvsim.experiments import cli as experiments_cli
from hptvsim.export import cli as export_cli
from hptvsim.sensors import cli as sensors_cli
from hptvsim.service import cli as service_cli
from hptvsim.twin import cli as twin_cli
from hptvsim.twin import fit_cli as twin_fit_cli
from hptvsim.twin import sitl_cli as twin_sitl_cli
from hptvsim.viz import cli as viz_cli
from hptvsim.world import cli as world_cli


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="hptvsim")
def main() -> None:
    """hptvsim: underwater pursuit-evasion simulator, FMUs, environments, training, service."""
    from hptvsim._process import torch_threads_setting

    try:  # a bad $HPTVSIM_TORCH_THREADS is refused before any command runs, not at a policy's load
        torch_threads_setting()
    except ValueError as exc:
        raise click.ClickException(str(exc)) from None


# --- fmu --------------------------------------------------------------------------------------


@main.group()
def fmu() -> None:
    """Build and check the vehicle FMUs (FMI 2.0 Co-Simulation)."""


@fmu.command("build")
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Folder for the .fmu files (default: the repository's fmus/).",
)
@click.option("--type", "vehicle_types", multiple=True, help="Vehicle type(s) to build (default: all).")
@click.option(
    "--vehicle-file",
    "vehicle_files",
    multiple=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="Your own vehicle type's file (TOML, Fossen parameters); needs --out.",
)
@click.option(
    "--platform",
    "platforms",
    multiple=True,
    help="FMI platform(s) to compile for (default: this machine's and win64, cross-compiled with MinGW-w64).",
)
def fmu_build(
    out_dir: Path | None,
    vehicle_types: tuple[str, ...],
    vehicle_files: tuple[Path, ...],
    platforms: tuple[str, ...],
) -> None:
    """Generate C from the CasADi models, compile it and pack the FMUs (3-DOF and 6-DOF per type)."""
    from hptvsim._paths import checkout_dir
    from hptvsim.cosim.vehicles import ExternalVehicleType, VehicleFileError, load_vehicle_file
    from hptvsim.dynamics import VEHICLE_TYPES, VehicleType
    from hptvsim.fmu import fmu_dir
    from hptvsim.fmu.build import FmuBuildError, build_fmu

    if vehicle_files and out_dir is None:
        raise click.UsageError("give the output folder with --out when building from a vehicle file")
    if out_dir is None and checkout_dir() is None and not os.environ.get("HPTVSIM_FMU_DIR"):
        raise click.UsageError("this is an installed copy, not a checkout: give the output folder with --out")
    for vt in vehicle_types:
        _check_vehicle_type(vt)
    todo: list[str | VehicleType] = []
    for f in vehicle_files:
        try:
            loaded = load_vehicle_file(f)
        except VehicleFileError as exc:
            raise click.BadParameter(str(exc), param_hint="--vehicle-file") from None
        if isinstance(loaded, ExternalVehicleType):
            raise click.BadParameter(
                f"{f} brings its own FMU ({loaded.fmu}); there is nothing to generate",
                param_hint="--vehicle-file",
            )
        todo.append(loaded)
    jobs: list[tuple[str | VehicleType, int]] = [(vt, 3) for vt in todo]
    if not vehicle_files or vehicle_types:
        jobs += [(vt, dof) for dof in (3, 6) for vt in (vehicle_types or tuple(VEHICLE_TYPES))]
    target = out_dir if out_dir is not None else fmu_dir()
    for item, dof in jobs:
        try:
            path = build_fmu(item, target, platforms=platforms or None, dof=dof)
        except FmuBuildError as exc:
            raise click.ClickException(str(exc)) from None
        click.echo(f"built {path}")


def _check_vehicle_type(vehicle_type: str) -> None:
    from hptvsim.dynamics import VEHICLE_TYPES

    check_choice(vehicle_type, VEHICLE_TYPES, what="vehicle type", param_hint="--type")


@fmu.command("check")
@click.option(
    "--dir",
    "fmu_folder",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Folder holding the .fmu files (default: the repository's fmus/).",
)
def fmu_check(fmu_folder: Path | None) -> None:
    """Fail when an FMU's sources drift from what the model generates, or it fails validation.

    Validation: FMPy's checks of the model description, and every Windows DLL's export table
    (a 64-bit x86 DLL exporting every FMI 2.0 Co-Simulation function).
    """
    from fmpy.validation import validate_fmu

    from hptvsim.dynamics import FMU_NAMES, SIXDOF_FMU_NAMES
    from hptvsim.fmu import fmu_dir
    from hptvsim.fmu.build import check_binaries, check_fmu

    folder = fmu_folder if fmu_folder is not None else fmu_dir()
    every = [(vt, ident, 3) for vt, ident in FMU_NAMES.items()]
    every += [(vt, ident, 6) for vt, ident in SIXDOF_FMU_NAMES.items()]
    missing = [f"{ident}.fmu" for _, ident, _ in every if not (folder / f"{ident}.fmu").is_file()]
    if missing:
        raise click.ClickException(
            f"{folder} has no {', '.join(missing)}; build them with `hptvsim fmu build --out {folder}`"
        )
    bad = False
    for vt, ident, dof in every:
        path = folder / f"{ident}.fmu"
        drift = check_fmu(vt, path, dof=dof)
        problems = validate_fmu(str(path))
        click.echo(str(drift))
        for p in problems:
            click.echo(f"  validation: {p}")
        binaries = check_binaries(path)
        for p in binaries:
            click.echo(f"  binaries: {p}")
        bad = bad or not drift.ok or bool(problems) or bool(binaries)
    if bad:
        sys.exit(1)


# --- demo -------------------------------------------------------------------------------------


@main.command()
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("hptvsim-out"),
    show_default=True,
    help="Folder for the plot.",
)
@click.option(
    "--duration",
    type=click.FloatRange(min=0.0, min_open=True),
    default=120.0,
    show_default=True,
    help="Simulated seconds.",
)
@click.option("--no-episode", is_flag=True, help="Skip the pursuit-evasion episode.")
@click.option(
    "--scenario",
    default="target",
    show_default=True,
    help="Shipped scenario of the episode (a 3-D one, e.g. ridge_3d, adds a depth plot).",
)
def demo(out_dir: Path, duration: float, no_episode: bool, scenario: str) -> None:
    """The vehicles through their FMUs, then one pursuit episode with the default policies."""
    from hptvsim.demo import plot_episode, run_demo
    from hptvsim.world.scenario import list_scenarios

    if scenario not in list_scenarios():
        raise click.BadParameter(
            f"no shipped scenario {scenario!r}; valid: {', '.join(list_scenarios())}", param_hint="--scenario"
        )
    path = run_demo(out_dir, duration=duration)
    click.echo(f"trajectory plot: {path.resolve()}")
    if not no_episode:
        click.echo(f"episode plot: {plot_episode(out_dir, scenario=scenario).resolve()}")


def _store_twin(*args: Any, **kwargs: Any) -> str:
    from hptvsim.service.twin import store_twin_episode

    return store_twin_episode(*args, **kwargs)


def _register() -> None:
    cosim_cli.register(main)
    world_cli.register(main)
    experiments_cli.register(main)
    export_cli.register(main)  # hptvsim policy export
    sensors_cli.register(main)
    viz_cli.register(main)
    twin_cli.register(main, store=_store_twin)  # --store: the service layer's, passed down
    twin_fit_cli.register(main)  # hptvsim vehicle fit, hptvsim twin predict
    twin_sitl_cli.register(main)  # hptvsim vehicle sitl
    bench = bench_cli.register(main)
    service_cli.register(main, bench)  # the layer above the benchmarks adds its own


_register()

if __name__ == "__main__":
    main()
