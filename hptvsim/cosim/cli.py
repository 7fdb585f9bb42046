"""Command line of the co-simulation layer: ``hptvsim cosim run`` and ``hptvsim cosim export-ssp``."""

from __future__ import annotations

from pathlib import Path

import click

__all__ = ["DEFAULT_OUT_DIR", "register"]

DEFAULT_OUT_DIR = Path("hptvsim-out") / "cosim"
"""Where ``hptvsim cosim run`` writes ``<graph name>.csv`` without ``--out`` (the working
directory's ``hptvsim-out/``, as every command's outputs; never beside the graph file, which may
be in the source tree)."""


def _write(
    target: Path,
    names: tuple[str, ...],
    types: tuple[str, ...],
    rows: list[list[object]],
    units: tuple[tuple[str | None, str | None], ...] = (),
) -> None:
    """Write ``time`` and the outputs: CSV (Reals to 17 digits, Booleans as true/false) or Parquet.

    The trajectory schema's ``wide`` layout (:mod:`hptvsim.cosim.trajectory`): its ``time`` column
    [s], then one column per output, named as the graph's outputs: the CSV header is the plain
    names (``time,sphere_x,...``; no units), the Parquet fields carry the units as metadata.
    Parquet columns carry the FMI types: float64 (Real, Float64), float32, int32 (Integer), the
    FMI 3 integer types as they are (its Enumerations as int64), bool (Boolean), string (String).
    Parquet fields carry each output's ``unit`` and ``display_unit`` as metadata (``time``: s).
    Written to a temporary file first, then renamed.
    """
    import csv

    from hptvsim.cosim.trajectory import TIME, field_metadata

    out_units = [units[k] if k < len(units) else (None, None) for k in range(len(names))]

    tmp = target.with_name(target.name + ".tmp")
    if target.suffix == ".parquet":
        import pyarrow as pa
        import pyarrow.parquet as pq

        kinds = {"Real": pa.float64(), "Float64": pa.float64(), "Float32": pa.float32()}
        kinds |= {
            "Integer": pa.int32(),
            "Enumeration": pa.int32(),
            "Boolean": pa.bool_(),
            "String": pa.string(),
        }
        for t in ("Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32"):
            kinds[t] = getattr(pa, t.lower())()
        kinds |= {"Int64": pa.int64(), "UInt64": pa.uint64()}
        fields = [pa.field(TIME.name, pa.float64(), metadata=field_metadata(TIME.unit))]
        arrays = [pa.array([r[0] for r in rows], pa.float64())]
        for k, (name, vtype) in enumerate(zip(names, types, strict=True)):
            fields.append(pa.field(name, kinds[vtype], metadata=field_metadata(*out_units[k])))
            arrays.append(pa.array([r[k + 1] for r in rows], kinds[vtype]))
        pq.write_table(pa.Table.from_arrays(arrays, schema=pa.schema(fields)), tmp)
    else:

        def cell(value: object) -> str:
            if isinstance(value, bool):
                return "true" if value else "false"
            if isinstance(value, float):
                return f"{value:.17g}"
            return str(value)

        with tmp.open("w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow([TIME.name, *names])  # plain names, as every release wrote them
            writer.writerows([[cell(v) for v in r] for r in rows])
    tmp.replace(target)


def register(main: click.Group) -> None:
    """Add ``hptvsim cosim ...`` to ``main``."""

    @main.group("cosim")
    def cosim() -> None:
        """Co-simulate FMI 2.0 and 3.0 CS FMUs wired by a graph file."""

    @cosim.command("run")
    @click.argument("graph_file", type=click.Path(exists=True, dir_okay=False, path_type=Path))
    @click.option("--stop-time", type=float, default=10.0, show_default=True, help="Simulated seconds.")
    @click.option(
        "--out",
        "out_file",
        type=click.Path(dir_okay=False, path_type=Path),
        default=None,
        help="Outputs over time: .csv, or .parquet with each column in its FMI type "
        "(default: hptvsim-out/cosim/<graph file's name>.csv).",
    )
    @click.option(
        "--set",
        "settings",
        multiple=True,
        metavar="INPUT=VALUE",
        help="Start an external input at a value in its type (number, true/false, an Enumeration "
        "item's name, text), from t = 0 on (repeatable).",
    )
    @click.option(
        "--step-size",
        type=click.FloatRange(min=0.0, min_open=True),
        default=None,
        help="Macro step [s] for an .ssp that states none (its own step size wins).",
    )
    def cosim_run(
        graph_file: Path,
        stop_time: float,
        out_file: Path | None,
        settings: tuple[str, ...],
        step_size: float | None,
    ) -> None:
        """Run GRAPH_FILE (.toml, .json or an SSP 1.0 .ssp) to --stop-time and write its outputs.

        A component that ends the simulation itself stops the run cleanly: every row up to the
        last complete communication point is written and the reason printed.
        """
        import dataclasses

        from hptvsim._output import progress_bar
        from hptvsim.cosim.fmi import FmuError
        from hptvsim.cosim.graph import GraphError, load_graph
        from hptvsim.cosim.orchestrator import Orchestrator, SimulationFailedError, SimulationTerminated

        try:
            if graph_file.suffix.lower() == ".ssp":
                from hptvsim.cosim.ssp import load_ssp

                graph = load_ssp(graph_file, step_size=step_size)
            elif step_size is not None:
                raise click.BadParameter("only for an .ssp graph", param_hint="--step-size")
            else:
                graph = load_graph(graph_file)
        except GraphError as exc:
            raise click.ClickException(str(exc)) from None
        steps = round(stop_time / graph.step_size)
        if steps < 1 or abs(steps * graph.step_size - stop_time) > 1e-9 * max(1.0, stop_time):
            raise click.BadParameter(
                f"{stop_time} s is not a positive multiple of the graph's step_size {graph.step_size} s",
                param_hint="--stop-time",
            )
        target = out_file if out_file is not None else DEFAULT_OUT_DIR / f"{graph_file.stem}.csv"
        if target.suffix not in (".csv", ".parquet"):
            raise click.BadParameter(
                f"{target.name}: valid suffixes are .csv and .parquet", param_hint="--out"
            )
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise click.BadParameter(
                f"cannot create {target.parent}: {exc.strerror}", param_hint="--out"
            ) from None
        held: dict[str, str] = {}
        names = [i.name for i in graph.inputs]
        for item in settings:
            name, eq, value = item.partition("=")
            name = name.strip()
            if not eq:
                raise click.BadParameter(f"{item!r} is not INPUT=VALUE", param_hint="--set")
            if name not in names:
                raise click.BadParameter(
                    f"no external input named {name!r}; inputs: {', '.join(names) or '(none)'}",
                    param_hint="--set",
                )
            held[name] = value
        # --set values are the inputs' start values: they reach initialisation and the t = 0 row
        graph = dataclasses.replace(
            graph,
            inputs=tuple(dataclasses.replace(i, start=held.get(i.name, i.start)) for i in graph.inputs),
        )
        rows: list[list[object]] = []
        reason = ""
        try:
            orch = Orchestrator(graph)
        except (GraphError, FmuError, SimulationFailedError, FileNotFoundError) as exc:
            raise click.ClickException(str(exc)) from None
        except KeyError as exc:  # an unknown shipped vehicle (vehicle:<type>)
            raise click.ClickException(str(exc.args[0]) if exc.args else repr(exc)) from None
        except ValueError as exc:  # an unreadable FMU (FmuLoadError), a value that does not fit its type
            raise click.ClickException(str(exc)) from None
        with orch:
            rows.append([0.0, *orch.output_values()])
            try:
                for _ in progress_bar(range(steps), desc=graph.name, unit="step", disable=steps < 10_000):
                    orch.step()
                    rows.append([orch.time, *orch.output_values()])
            except SimulationTerminated as exc:
                reason = str(exc)
            except FmuError as exc:
                _write(target, orch.output_names, orch.output_fmi_types, rows, orch.output_units)
                raise click.ClickException(
                    f"{exc} (rows up to t = {orch.time:g} s are in {target})"
                ) from None
            names_out, types_out, units_out = orch.output_names, orch.output_fmi_types, orch.output_units
        _write(target, names_out, types_out, rows, units_out)
        done = len(rows) - 1
        if reason:
            click.echo(f"stopped early: {reason}")
        click.echo(f"{done} steps of {graph.step_size} s; outputs: {target.resolve()}")

    @cosim.command("export-ssp")
    @click.argument("graph_file", type=click.Path(exists=True, dir_okay=False, path_type=Path))
    @click.option(
        "--out",
        "out_file",
        type=click.Path(dir_okay=False, path_type=Path),
        default=None,
        help="The .ssp to write (default: <graph>.ssp beside the graph).",
    )
    @click.option(
        "--libcosim",
        is_flag=True,
        help="Write what OSP libcosim runs: no connections to system connectors (the wiring then "
        "lives in the hptvsim annotation only) and no Enumeration connectors (libcosim aborts on "
        "them; a graph that connects, sets or drives an Enumeration is refused).",
    )
    def cosim_export_ssp(graph_file: Path, out_file: Path | None, libcosim: bool) -> None:
        """Write GRAPH_FILE (.toml or .json) as an SSP 1.0 archive with its FMUs."""
        from hptvsim.cosim.graph import GraphError, load_graph
        from hptvsim.cosim.ssp import export_ssp

        target = out_file if out_file is not None else graph_file.with_suffix(".ssp")
        if target.suffix.lower() != ".ssp":
            raise click.BadParameter(f"{target.name}: the suffix must be .ssp", param_hint="--out")
        try:
            export_ssp(load_graph(graph_file), target, libcosim=libcosim)
        except GraphError as exc:
            raise click.ClickException(str(exc)) from None
        click.echo(f"wrote {target.resolve()}")
