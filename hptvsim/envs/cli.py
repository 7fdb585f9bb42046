"""Commands of the environments: ``hptvsim bench env``."""

from __future__ import annotations

import click

__all__ = ["register"]


def register(main: click.Group, bench: click.Group) -> None:
    """Add the environments' commands."""

    @bench.command("env")
    @click.option("--quick", is_flag=True, help="About 15 s instead of a minute.")
    @click.option("--scenario", default="source", show_default=True, help="Scenario of our rows.")
    @click.option("--json", "as_json", is_flag=True, help="Print JSON instead of a table.")
    def bench_env_cmd(quick: bool, scenario: str, as_json: bool) -> None:
        """env-steps/s of the 3-vs-1 game: FMU backend, batched B = 1, 64, 1024, mpe2 and VMAS."""
        from hptvsim.bench.env import bench_env
        from hptvsim.cli import emit
        from hptvsim.envs.core import planar_scenario
        from hptvsim.world.scenario import ScenarioError

        try:
            planar_scenario(scenario, "hptvsim bench env --scenario (its 3-D rows always run dive_flat)")
        except (ScenarioError, ValueError) as exc:
            raise click.BadParameter(str(exc), param_hint="--scenario") from None
        emit(bench_env(quick=quick, scenario=scenario), as_json)
