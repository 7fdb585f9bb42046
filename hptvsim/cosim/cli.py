"""Command line of the co-simulation layer: ``hptvsim cosim run`` and ``hptvsim bench cosim``."""

from __future__ import annotations

from pathlib import Path

import click

__all__ = ["register"]


def register(main: click.Group, bench: click.Group) -> None:
    """Add ``hptvsim cosim ...`` to ``main`` and ``hptvsim bench cosim`` to ``bench``."""

    @main.group("cosim")
    def cosim() -> None:
        """Co-simulate FMI 2.0 CS FMUs wired by a graph file."""

    @cosim.command("run")
    @click.argument("graph_file", type=click.Path(exists=True, dir_okay=False, path_type=Path))
    @click.option("--stop-time", type=float, default=10.0, show_default=True, help="Simulated seconds.")
    @click.option(
        "--out",
        "out_file",
        type=click.Path(dir_okay=False, path_type=Path),
        default=None,
        help="CSV file for the external outputs over time (default: <graph>.csv beside the graph).",
    )
    @click.option(
        "--set",
        "settings",
        multiple=True,
        metavar="INPUT=VALUE",
        help="Hold an external input at a value (repeatable).",
    )
    def cosim_run(
        graph_file: Path, stop_time: float, out_file: Path | None, settings: tuple[str, ...]
    ) -> None:
        """Run GRAPH_FILE (.toml or .json) to --stop-time and write its outputs as CSV."""
        import numpy as np
        from tqdm import tqdm

        from hptvsim.cosim.graph import GraphError, load_graph
        from hptvsim.cosim.orchestrator import Orchestrator

        try:
            graph = load_graph(graph_file)
        except GraphError as exc:
            raise click.ClickException(str(exc)) from None
        steps = round(stop_time / graph.step_size)
        if steps < 1 or abs(steps * graph.step_size - stop_time) > 1e-9 * max(1.0, stop_time):
            raise click.BadParameter(
                f"{stop_time} s is not a positive multiple of the graph's step_size {graph.step_size} s",
                param_hint="--stop-time",
            )
        target = out_file if out_file is not None else graph_file.with_suffix(".csv")
        held: list[tuple[str, float]] = []
        for item in settings:
            name, eq, value = item.partition("=")
            if not eq:
                raise click.BadParameter(f"{item!r} is not INPUT=VALUE", param_hint="--set")
            try:
                held.append((name.strip(), float(value)))
            except ValueError:
                raise click.BadParameter(f"{item!r}: {value!r} is not a number", param_hint="--set") from None
        try:
            orch = Orchestrator(graph)
        except GraphError as exc:
            raise click.ClickException(str(exc)) from None
        with orch:
            for name, number in held:
                try:
                    orch.set_input(name, number)
                except (KeyError, ValueError) as exc:  # str() of a KeyError is the repr of its message
                    message = str(exc.args[0]) if exc.args else repr(exc)
                    raise click.BadParameter(message, param_hint="--set") from None
            rows = np.empty((steps + 1, 1 + len(orch.outputs)))
            rows[0, 0] = 0.0
            rows[0, 1:] = orch.outputs
            for k in tqdm(range(steps), desc=graph.name, unit="step", disable=steps < 10_000):
                rows[k + 1, 1:] = orch.step()
                rows[k + 1, 0] = orch.time
        header = ",".join(["time", *orch.output_names])
        tmp = target.with_name(target.name + ".tmp")
        np.savetxt(tmp, rows, delimiter=",", header=header, comments="", fmt="%.17g")
        tmp.replace(target)
        click.echo(f"{steps} steps of {graph.step_size} s; outputs: {target.resolve()}")

    @bench.command("cosim")
    @click.option("--quick", is_flag=True, help="About a second instead of several.")
    @click.option(
        "--h-max",
        type=click.FloatRange(min=0.0, min_open=True),
        default=0.05,
        show_default=True,
        help="Largest internal RK4 step [s] for every row (the FMUs default to 0.01).",
    )
    @click.option("--json", "as_json", is_flag=True, help="Print JSON instead of a table.")
    def bench_cosim_cmd(quick: bool, h_max: float, as_json: bool) -> None:
        """Vehicle-steps/s: FMPy, the orchestrator, the batched backend (B = 1, 64, 1024), the C floor."""
        from hptvsim.bench.cosim import bench_cosim
        from hptvsim.cli import emit

        emit(bench_cosim(quick=quick, h_max=h_max), as_json)
