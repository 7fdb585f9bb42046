"""The world commands: hptvsim scenario validate/show/list/schema, terrain import, bench world."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from click.testing import CliRunner, Result

from hptvsim.cli import main
from hptvsim.world.scenario import scenario_dir
from hptvsim.world.terrain import HeightMap


def run(*args: str) -> Result:
    return CliRunner().invoke(main, list(args), catch_exceptions=False)


def test_validate_reports_ok_and_fails_with_the_clear_error(tmp_path: Path) -> None:
    ok = run("scenario", "validate", "source", str(scenario_dir() / "target.toml"))
    assert ok.exit_code == 0, ok.output
    assert "ok: " in ok.output and "pursuer_0, pursuer_1, pursuer_2, evader_0" in ok.output
    bad = tmp_path / "bad.toml"
    bad.write_text((scenario_dir() / "source.toml").read_text().replace("radius = 30.0", "radius = -30.0"))
    res = run("scenario", "validate", "source", str(bad))
    assert res.exit_code == 1
    assert (
        f"Error: {bad}: vehicles[1].spawn.radius: -30.0 m is out of range (valid: in (0, 100000])"
        in res.output
    )


def test_show_renders_a_north_up_map(tmp_path: Path) -> None:
    from PIL import Image

    out = tmp_path / "map.png"
    res = run("scenario", "show", "target", "--out", str(out))
    assert res.exit_code == 0, res.output
    assert res.output.strip() == str(out.resolve())
    with Image.open(out) as im:
        assert im.format == "PNG"
        w, h = im.size
        assert h > w  # the 400 m (north) side is drawn vertically
        rgb = np.asarray(im.convert("RGB")).astype(int)
    # the map holds obstacle brown, water blue and the evader's amber region
    brown = (abs(rgb[..., 0] - 0x7A) < 40) & (abs(rgb[..., 1] - 0x5C) < 40) & (abs(rgb[..., 2] - 0x3A) < 40)
    blue = rgb[..., 2] > rgb[..., 0] + 40
    assert brown.mean() > 0.02 and blue.mean() > 0.1


def test_a_3d_scenario_is_shown_with_depth_contours_not_planar_obstacles(tmp_path: Path) -> None:
    """In the 3-D game the ridge is passable: no obstacle overlay, labelled depth contours instead."""
    import matplotlib.pyplot as plt

    from hptvsim.world.render import scenario_figure
    from hptvsim.world.scenario import load_scenario

    res = run("scenario", "show", "ridge_3d", "--out", str(tmp_path / "ridge.png"))
    assert res.exit_code == 0, res.output
    figures = {}
    for game in ("3d", "planar"):
        fig = scenario_figure(load_scenario("ridge_3d").with_overrides({"simulation": {"game": game}}))
        ax = fig.axes[0]
        figures[game] = (
            len(ax.images),  # the relief, plus the obstacle overlay in the planar game
            sorted(t.get_text() for t in ax.texts),  # contour labels [m]
            [t.get_text() for t in ax.get_legend().get_texts()],
            ax.get_title(),
        )
        plt.close(fig)
    images, labels, legend, title = figures["3d"]
    assert images == 1 and figures["planar"][0] == 2
    assert {"30", "40", "50"} <= set(labels) and not figures["planar"][1]
    assert legend[:2] == [
        "pursuer x3 (work_class), start 20-40 m deep",
        "evader x1 (spherical), start 25-45 m deep",
    ]
    assert title.startswith("ridge_3d: 3-D game, pursuit, seabed 25-60 m deep")
    assert "obstacles" in figures["planar"][3] and "obstacles" not in title
    out = run("scenario", "validate", "ridge_3d", "target").output
    assert "ridge_3d: pursuit" in out and "3-D game (the vehicles dive)" in out
    assert "% obstacles at 30 m" in out  # the planar target scenario


def test_list_and_schema() -> None:
    res = run("scenario", "list")
    assert res.exit_code == 0
    for name in ("source", "transition", "target", "goto_tiny", "salish_sea"):
        assert name in res.output
    schema = run("scenario", "schema").output
    for key in (
        "operating_depth",
        "direction | direction_deg",
        "delta_E2",
        "h_max",
        "anchor_lonlat",
        "fov | fov_deg",
    ):
        assert key in schema


def test_terrain_import_turns_a_chart_into_a_heightmap_and_preview(tmp_path: Path) -> None:
    out = tmp_path / "strait.npz"
    res = run(
        "terrain",
        "import",
        str(scenario_dir() / "data" / "salish_sea.000"),
        "--out",
        str(out),
        "--resolution",
        "500",
    )
    assert res.exit_code == 0, res.output
    assert "S-57 chart salish_sea.000 (319 soundings" in res.output
    hm = HeightMap.load(out)
    assert hm.geometry.resolution == 500.0
    assert 400.0 < hm.depth.max() < 430.0 and hm.depth.min() < 0.0  # deep channel, land
    assert (tmp_path / "strait.png").stat().st_size > 10_000
    tif = tmp_path / "strait.tif"
    res = run("terrain", "import", str(out), "--out", str(tif))  # .npz -> GeoTIFF
    assert res.exit_code == 0, res.output
    back = run("terrain", "import", str(tif), "--out", str(tmp_path / "again.npz"))
    assert back.exit_code == 0, back.output
    np.testing.assert_allclose(HeightMap.load(tmp_path / "again.npz").depth, hm.depth, atol=1e-3)


def test_terrain_import_errors_are_one_line(tmp_path: Path) -> None:
    (tmp_path / "x.png").write_bytes(b"not a png")
    res = run(
        "terrain", "import", str(tmp_path / "x.png"), "--out", str(tmp_path / "o.npz"), "--pixel-size", "1"
    )
    assert res.exit_code == 1 and res.output.startswith("Error: ") and "not a readable image" in res.output


def test_bench_world_quick_reports_ratios() -> None:
    res = run("bench", "world", "--quick", "--json")
    assert res.exit_code == 0, res.output
    data = json.loads(res.output)
    names = [r["name"] for r in data["rows"]]
    assert data["floor"] in names and "OccupancyGrid.distance B=1024" in names
    assert all(r["us_per_unit"] > 0.0 for r in data["rows"])


def test_show_puts_north_up_and_east_right(tmp_path: Path) -> None:
    """A seamount in the north-west corner of a PNG height map lands top left in the picture
    (a transposed map would put it bottom right, a flipped one bottom left)."""
    from PIL import Image

    grey = np.zeros((120, 90), dtype=np.uint8)  # rows: north (top) to south; columns: west to east
    grey[10:40, 5:30] = 255  # north-west: shallow
    Image.fromarray(grey).save(tmp_path / "ne.png")
    (tmp_path / "ne.toml").write_text(
        'name = "ne"\n'
        "[site]\nsize = [400.0, 300.0]\noperating_depth = 30.0\n"
        '[terrain]\nkind = "file"\npath = "ne.png"\nvertical_scale = 50.0\nvertical_offset = 60.0\n'
        '[[vehicles]]\nrole = "evader"\ntype = "spherical"\n'
        'spawn = {kind = "circle", centre = [50.0, 50.0], radius = 10.0}\n'
        '[task]\nkind = "goto"\ngoal = {position = [200.0, 150.0]}\n'
    )
    res = run("scenario", "show", str(tmp_path / "ne.toml"), "--out", str(tmp_path / "ne_map.png"))
    assert res.exit_code == 0, res.output
    with Image.open(tmp_path / "ne_map.png") as im:
        rgb = np.asarray(im.convert("RGB")).astype(int)
    brown = (abs(rgb[..., 0] - 0x7A) < 30) & (abs(rgb[..., 1] - 0x5C) < 30) & (abs(rgb[..., 2] - 0x3A) < 30)
    rows, cols = np.nonzero(brown)
    assert rows.size > 100
    h, w = brown.shape
    assert rows.mean() < 0.4 * h and cols.mean() < 0.4 * w  # top left
