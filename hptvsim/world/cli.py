"""Command line of the world package: ``hptvsim scenario``, ``hptvsim terrain``.

Heavy modules are imported inside the commands so ``hptvsim --help`` stays fast.
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

__all__ = ["register"]


def register(main: click.Group) -> None:
    """Add the ``scenario`` and ``terrain`` groups to ``main``."""
    main.add_command(scenario)
    main.add_command(terrain)


# --- scenario ------------------------------------------------------------------------------------


@click.group()
def scenario() -> None:
    """Scenario files: validate, render, list, describe the schema."""


@scenario.command("validate")
@click.argument("files", nargs=-1, required=True)
def scenario_validate(files: tuple[str, ...]) -> None:
    """Check scenario FILES (paths or shipped names); exit 1 on the first error of each."""
    from hptvsim.world.scenario import ScenarioError, load_scenario

    failed = 0
    for f in files:
        try:
            s = load_scenario(f)
        except ScenarioError as exc:
            click.echo(f"Error: {exc}", err=True)  # click's prefix; every other file is still checked
            failed += 1
            continue
        world = s.build_world()
        occ = world.obstacles.occupied
        lo, hi = world.heightmap.depth_range
        where = (
            "3-D game (the vehicles dive)"
            if s.simulation.game == "3d"
            else f"{100.0 * occ.mean():.1f}% obstacles at {s.site.operating_depth:g} m"
        )
        click.echo(
            f"ok: {s.source} ({s.name}: {s.task.kind}, {len(s.agents)} agent(s) "
            f"[{', '.join(s.agent_names)}], seabed {lo:.1f}..{hi:.1f} m, {where})"
        )
    if failed:
        sys.exit(1)


@scenario.command("show")
@click.argument("file")
@click.option(
    "--out",
    "out",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="PNG to write (default: <scenario name>.png in the current folder).",
)
def scenario_show(file: str, out: Path | None) -> None:
    """Render a scenario's map (depth, obstacles, spawn regions, goals, currents) to a PNG."""
    from hptvsim.world.render import render_scenario
    from hptvsim.world.scenario import ScenarioError, load_scenario

    try:
        s = load_scenario(file)
    except ScenarioError as exc:
        raise click.ClickException(str(exc)) from None
    path = render_scenario(s, out if out is not None else Path(f"{s.name}.png"))
    click.echo(str(path.resolve()))


@scenario.command("list")
def scenario_list() -> None:
    """List the shipped scenarios with their descriptions."""
    from hptvsim.world.scenario import list_scenarios, scenario_dir, scenario_path

    names = list_scenarios()
    if not names:
        click.echo(f"no scenarios in {scenario_dir()}")
        return
    import tomllib

    width = max(len(n) for n in names)
    for n in names:
        try:
            with scenario_path(n).open("rb") as fh:
                desc = str(tomllib.load(fh).get("description", ""))
        except (OSError, tomllib.TOMLDecodeError):
            desc = "(unreadable)"
        first = desc.strip().splitlines()[0] if desc.strip() else ""
        click.echo(f"{n:<{width}}  {first}")
    click.echo(f"({scenario_dir()})")


@scenario.command("schema")
@click.option(
    "--json",
    "as_json",
    is_flag=True,
    help="Print the JSON Schema (draft 2020-12, as in OpenAPI 3.1) of a scenario document instead.",
)
def scenario_schema(as_json: bool) -> None:
    """Print every key a scenario file may hold, with unit, valid range, default and meaning."""
    if as_json:
        import json

        from hptvsim.world.scenario import scenario_json_schema

        click.echo(json.dumps(scenario_json_schema(), indent=2))
        return
    from hptvsim.world.schema_doc import schema_text

    click.echo(schema_text())


# --- terrain -------------------------------------------------------------------------------------


@click.group()
def terrain() -> None:
    """Seabed height maps: import charts, rasters, images and soundings."""


@terrain.command("import")
@click.argument("source", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option(
    "--out",
    "out",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="Height map to write: .npz (for scenarios) or .tif (GeoTIFF, local metres). PNG preview beside it.",
)
@click.option("--resolution", type=float, default=None, help="Cell size [m] (default: the source's own).")
@click.option(
    "--format",
    "fmt",
    type=click.Choice(["auto", "geotiff", "esri_ascii", "png", "xyz", "s57", "npz"]),
    default="auto",
    show_default=True,
)
@click.option(
    "--values",
    type=click.Choice(["auto", "depth", "elevation"]),
    default="auto",
    show_default=True,
    help="What the source's numbers are (auto: the format's default).",
)
@click.option("--vertical-scale", type=float, default=1.0, show_default=True, help="Multiplies the values.")
@click.option("--vertical-offset", type=float, default=0.0, show_default=True, help="Added to depths [m].")
@click.option(
    "--horizontal-scale", type=float, default=1.0, show_default=True, help="Output metres per source metre."
)
@click.option("--pixel-size", type=float, default=None, help="PNG: metres per pixel.")
@click.option("--anchor-lonlat", type=(float, float), default=None, help="Projection centre LON LAT [deg].")
@click.option(
    "--geographic/--projected",
    "geographic",
    default=None,
    help="Force coordinates to be read as lon/lat or metres (default: from the file).",
)
def terrain_import(
    source: Path,
    out: Path,
    resolution: float | None,
    fmt: str,
    values: str,
    vertical_scale: float,
    vertical_offset: float,
    horizontal_scale: float,
    pixel_size: float | None,
    anchor_lonlat: tuple[float, float] | None,
    geographic: bool | None,
) -> None:
    """Chart -> raster -> height map in one step (the paper's section III-B pipeline).

    Reads SOURCE (S-57 chart .000, GeoTIFF, ESRI ASCII .asc, PNG, XYZ/CSV soundings, .npz),
    projects geographic coordinates to local metres about the data's centre, grids the data,
    fills holes by interpolation, and writes the height map and a PNG preview.
    """
    from hptvsim.world.importers import ImportOptions, TerrainImportError, import_terrain, save_heightmap
    from hptvsim.world.render import render_heightmap

    try:
        options = ImportOptions(
            values=values,  # type: ignore[arg-type]  # click.Choice guarantees a valid literal
            vertical_scale=vertical_scale,
            vertical_offset=vertical_offset,
            horizontal_scale=horizontal_scale,
            pixel_size=pixel_size,
            anchor_lonlat=anchor_lonlat,
            geographic=geographic,
        )
        result = import_terrain(source, resolution=resolution, format=fmt, options=options)  # type: ignore[arg-type]
        path = save_heightmap(result.heightmap, out)
    except (TerrainImportError, ValueError, FileNotFoundError) as exc:
        raise click.ClickException(str(exc)) from None
    hm = result.heightmap
    preview = render_heightmap(hm, out.with_suffix(".png"), title=f"{source.name} -> {out.name}")
    g = hm.geometry
    lo, hi = hm.depth_range
    x_min, x_max, y_min, y_max = g.extent
    click.echo(f"source:     {result.description}")
    click.echo(
        f"grid:       {g.shape[0]} x {g.shape[1]} cells of {g.resolution:g} m, "
        f"x {x_min:.1f}..{x_max:.1f} m, y {y_min:.1f}..{y_max:.1f} m"
    )
    click.echo(f"depth:      {lo:.2f} .. {hi:.2f} m (positive down); {result.holes_filled} hole cells filled")
    click.echo(f"height map: {path.resolve()}")
    click.echo(f"preview:    {preview.resolve()}")
