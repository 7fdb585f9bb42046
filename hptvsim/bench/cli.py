"""``hptvsim bench ...``: every benchmark's command, registered from the top of the command line.

Each benchmark measures one layer from above it (the layers never import their benchmarks);
the service adds ``hptvsim bench service`` itself (:mod:`hptvsim.service.cli`, the one layer
above this package). Each command imports what it measures when it runs, so ``hptvsim --help``
stays fast.
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from hptvsim._output import check_choice, emit

__all__ = ["bench", "register"]

_JSON = click.option("--json", "as_json", is_flag=True, help="Print JSON instead of a table.")


@click.group()
def bench() -> None:
    """Benchmarks: each prints costs and ratios to a floor or peer measured in the same run."""


def register(main: click.Group) -> click.Group:
    """Add the ``bench`` group to ``main``; returns it (for the service's benchmark)."""
    main.add_command(bench)
    return bench


@bench.command("dynamics")
@click.option("--quick", is_flag=True, help="Seconds instead of a minute.")
@click.option("--type", "vehicle_type", default="work_class", show_default=True)
@_JSON
def bench_dynamics_cmd(quick: bool, vehicle_type: str, as_json: bool) -> None:
    """µs per vehicle-step: FMPy high-level calls, the lean hot path, the compiled C floor."""
    from hptvsim.bench.dynamics import bench_dynamics
    from hptvsim.dynamics import VEHICLE_TYPES

    check_choice(vehicle_type, VEHICLE_TYPES, what="vehicle type", param_hint="--type")
    emit(bench_dynamics(quick=quick, vehicle_type=vehicle_type), as_json)


@bench.command("cosim")
@click.option("--quick", is_flag=True, help="About a second instead of several.")
@click.option(
    "--h-max",
    type=click.FloatRange(min=0.0, min_open=True),
    default=0.05,
    show_default=True,
    help="Largest internal RK4 step [s] for every row (the FMUs default to 0.01).",
)
@_JSON
def bench_cosim_cmd(quick: bool, h_max: float, as_json: bool) -> None:
    """Vehicle-steps/s: FMPy, the orchestrator, the batched backend (B = 1, 64, 1024), the C floor."""
    from hptvsim.bench.cosim import bench_cosim

    emit(bench_cosim(quick=quick, h_max=h_max), as_json)


@bench.command("world")
@click.option("--quick", is_flag=True, help="Seconds instead of a minute.")
@_JSON
def bench_world_cmd(quick: bool, as_json: bool) -> None:
    """µs per point of the per-step world queries (distance, occupancy, depth, currents)."""
    from hptvsim.bench.world import bench_world

    emit(bench_world(quick=quick), as_json)


@bench.command("sensors")
@click.option("--quick", is_flag=True, help="Seconds instead of a minute.")
@_JSON
def bench_sensors_cmd(quick: bool, as_json: bool) -> None:
    """Geometric sonar rays/s (B = 1, 64, 1024 x 4 agents) and matched-filter estimates/s."""
    from hptvsim.bench.sensors import bench_sensors

    emit(bench_sensors(quick=quick), as_json)


@bench.command("env")
@click.option("--quick", is_flag=True, help="About 15 s instead of a minute.")
@click.option("--scenario", default="source", show_default=True, help="Scenario of our rows.")
@_JSON
def bench_env_cmd(quick: bool, scenario: str, as_json: bool) -> None:
    """env-steps/s of the 3-vs-1 game: FMU backend, batched B = 1, 64, 1024, mpe2 and VMAS."""
    from hptvsim.bench.env import bench_env
    from hptvsim.envs.core import planar_scenario
    from hptvsim.world.scenario import ScenarioError

    try:
        planar_scenario(scenario, "hptvsim bench env --scenario (its 3-D rows always run dive_flat)")
    except (ScenarioError, ValueError) as exc:
        raise click.BadParameter(str(exc), param_hint="--scenario") from None
    emit(bench_env(quick=quick, scenario=scenario), as_json)


@bench.command("train")
@click.option("--quick", is_flag=True, help="Seconds instead of minutes.")
@_JSON
@click.option(
    "--env",
    "env_kind",
    type=click.Choice(["auto", "toy", "hptvsim", "3d"]),
    default="auto",
    show_default=True,
    help="Game to step: the 3-vs-1 underwater game when available, else the toy game; 3d: the "
    "3-D game (6-DOF vehicles that dive, dive_flat scenario).",
)
@click.option(
    "--algo",
    type=click.Choice(["maisac", "ippo"]),
    default="maisac",
    show_default=True,
    help="maisac: plain SB3 vs the batched update backends; ippo: today's one-game IPPO vs the fast "
    "preset on batched games (planar game only).",
)
def bench_train_cmd(quick: bool, as_json: bool, env_kind: str, algo: str) -> None:
    """Env steps/s of 4-learner training, today's path vs the batched one, in the same run."""
    from hptvsim.bench.train import bench_train, bench_train_ippo

    if algo == "ippo":
        if env_kind not in ("auto", "hptvsim"):
            raise click.BadParameter(
                f"--algo ippo runs on the planar game; got --env {env_kind}", param_hint="--env"
            )
        emit(bench_train_ippo(quick=quick), as_json)
        return
    emit(bench_train(quick=quick, env_kind=env_kind), as_json)


@bench.command("learn")
@click.option("--quick", is_flag=True, help="Target capture 0.2, 3-minute caps, 40 episodes (CI-sized).")
@click.option(
    "--trainer",
    "trainers",
    multiple=True,
    help="Rows to run (repeat; default all): 'fast ippo', 'fast maisac', 'sb3 one game', 'benchmarl isac'.",
)
@click.option("--cap", "cap_min", type=float, default=None, help="Training-time cap per row [min].")
@click.option("--target", type=float, default=None, help="Capture rate of competence (default 0.70).")
@click.option(
    "--jobs",
    type=click.IntRange(1, 4),
    default=1,
    show_default=True,
    help="Rows trained at once, each in its own process on one thread (2 uses both cores here).",
)
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("hptvsim-out/bench-learn"),
    show_default=True,
    help="Folder of learn.csv, learn.json and learn.png.",
)
@click.option(
    "--seeds-throughput",
    "seeds_s",
    type=float,
    default=None,
    help="Instead: game steps/s of 10 seeds in one process against 10 processes, this many seconds each.",
)
@_JSON
def bench_learn_cmd(
    quick: bool,
    trainers: tuple[str, ...],
    cap_min: float | None,
    target: float | None,
    jobs: int,
    out: Path,
    seeds_s: float | None,
    as_json: bool,
) -> None:
    """Time to competence from scratch: fast IPPO/MAISAC, today's SB3 path, BenchMARL ISAC."""
    from hptvsim.bench.learn import TRAINERS, bench_learn, bench_seeds, table

    if seeds_s is not None:
        result = bench_seeds(seconds=seeds_s)
        if as_json:
            click.echo(json.dumps(result, indent=2))
        else:
            one, many = result["one_process"], result["separate_processes"]
            click.echo(
                f"{result['seeds']} seeds, fast IPPO, {result['num_envs']} games each: one process "
                f"{one['steps_per_s']:,.0f} game steps/s ({one['steps_per_cpu_s']:,.0f} per CPU-s); "
                f"{result['seeds']} processes {many['steps_per_s']:,.0f}/s ({many['steps_per_cpu_s']:,.0f} "
                f"per CPU-s); ratio per CPU-second {result['ratio_per_cpu_s']:.2f}x, per wall-second "
                f"{result['ratio_per_wall_s']:.2f}x"
            )
        return
    for t in trainers:
        check_choice(t, TRAINERS, what="trainer", param_hint="--trainer")
    report = bench_learn(
        out,
        quick=quick,
        trainers=trainers or TRAINERS,
        cap_s=None if cap_min is None else 60.0 * cap_min,
        target=target,
        jobs=jobs,
    )
    if as_json:
        click.echo(json.dumps(report, indent=2))
    else:
        click.echo(table(report))
        click.echo(f"curves: {out / 'learn.csv'}, figure: {out / 'learn.png'}")


@bench.command("dt")
@click.option("--quick", is_flag=True, help="Seconds instead of a minute.")
@_JSON
def bench_dt_cmd(quick: bool, as_json: bool) -> None:
    """DT training updates/s and inference actions/s, each against a peer measured in the same run."""
    from hptvsim.bench.dt import bench_dt

    for result in bench_dt(quick=quick):
        emit(result, as_json)


@bench.command("policy")
@click.option("--quick", is_flag=True, help="Seconds instead of a minute.")
@_JSON
def bench_policy_cmd(quick: bool, as_json: bool) -> None:
    """One exported policy call on one core (onnxruntime) against SB3's torch predict, same run."""
    from hptvsim.bench.policy import bench_policy

    for result in bench_policy(quick=quick):
        emit(result, as_json)


@bench.command("episode")
@click.option("--quick", is_flag=True, help="Seconds instead of a minute.")
@click.option("--scenario", default="target", show_default=True)
@_JSON
def bench_episode_cmd(quick: bool, scenario: str, as_json: bool) -> None:
    """µs per episode step: bare GameCore, + frames, + rerun recording (ratios to the bare core)."""
    from hptvsim.viz.cli import check_scenario_arg

    check_scenario_arg(scenario)
    from hptvsim.bench.episode import bench_episode

    emit(bench_episode(quick=quick, scenario=scenario), as_json)


@bench.command("threads")
@click.option(
    "--quick",
    is_flag=True,
    help="300 steps and one run per row (default: whole episodes, best of two).",
)
@click.option("--scenario", default="target", show_default=True)
@_JSON
def bench_threads_cmd(quick: bool, scenario: str, as_json: bool) -> None:
    """`hptvsim episode` wall time alone and beside two busy processes: torch default threads vs one."""
    from hptvsim.viz.cli import check_scenario_arg

    check_scenario_arg(scenario)
    from hptvsim.bench.threads import bench_threads

    emit(bench_threads(quick=quick, scenario=scenario), as_json)
