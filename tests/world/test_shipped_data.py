"""The real-bathymetry files in scenarios/data match their stated source, and agree with each other."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from hptvsim.world.scenario import load_scenario, scenario_dir

DATA = scenario_dir() / "data"


def _maker() -> ModuleType:
    spec = importlib.util.spec_from_file_location("make_salish_sea", DATA / "make_salish_sea.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_geotiff_is_the_stated_crop_of_matplotlibs_topobathy() -> None:
    import rasterio

    lon, lat, elev = _maker().crop()
    with rasterio.open(DATA / "salish_sea.tif") as src:
        band = src.read(1, masked=True)
        assert src.crs.to_epsg() == 4326
        left, bottom, right, top = src.bounds
        assert "topobathy.npz" in src.tags()["SOURCE"]
    assert band.shape == elev.shape == (27, 24)
    expected = elev[::-1]  # north row first
    np.testing.assert_array_equal(np.ma.getmaskarray(band), ~np.isfinite(expected))
    np.testing.assert_allclose(band.filled(np.nan), expected.astype(np.float32), equal_nan=True)
    dlon, dlat = np.diff(lon).mean(), np.diff(lat).mean()
    assert left == pytest.approx(lon[0] - dlon / 2) and top == pytest.approx(lat[-1] + dlat / 2)
    assert bottom == pytest.approx(lat[0] - dlat / 2, abs=1e-4) and right == pytest.approx(
        lon[-1] + dlon / 2, abs=1e-4
    )


def test_chart_holds_the_crops_soundings_contours_depth_areas_and_land() -> None:
    import pyogrio
    from pyogrio import raw

    from hptvsim.world._wkb import parse_wkb

    lon, lat, elev = _maker().crop()
    layers = {str(n) for n, _ in pyogrio.list_layers(DATA / "salish_sea.000")}
    assert {"SOUNDG", "DEPCNT", "DEPARE", "LNDARE"} <= layers
    _, _, geoms, _ = raw.read(DATA / "salish_sea.000", layer="SOUNDG")
    pts = np.concatenate([p for g in geoms for p in parse_wkb(g).points])
    lon2, lat2 = np.meshgrid(lon, lat)
    sea = np.isfinite(elev) & (elev < 0.0)
    expected = np.column_stack([lon2[sea], lat2[sea], -elev[sea]])
    order = np.lexsort((pts[:, 1], pts[:, 0]))
    order_e = np.lexsort((expected[:, 1], expected[:, 0]))
    np.testing.assert_allclose(pts[order, :2], expected[order_e, :2], atol=2e-7)  # COMF 1e7
    np.testing.assert_allclose(pts[order, 2], expected[order_e, 2], atol=0.051)  # SOMF 10
    meta, _, _, fields = raw.read(DATA / "salish_sea.000", layer="DEPCNT")
    valdco = set(fields[list(meta["fields"]).index("VALDCO")])
    assert valdco == {50.0, 100.0, 200.0, 300.0}


def test_raster_and_chart_give_the_same_channel() -> None:
    """Two importers, two formats, one real seabed: the obstacle maps at 150 m agree."""
    tif = load_scenario("salish_sea").build_world().obstacles.occupied
    chart = load_scenario("salish_sea_chart").build_world().obstacles.occupied
    assert tif.shape == chart.shape
    assert (tif == chart).mean() > 0.95
    assert 0.3 < tif.mean() < 0.6  # banks on both sides of a deep channel


def test_readme_states_source_licence_and_scale() -> None:
    text = (DATA / "README.md").read_text()
    for words in ("topobathy.npz", "LICENSE-matplotlib.txt", "horizontal_scale", "not for navigation"):
        assert words in text
    assert Path(DATA / "LICENSE-matplotlib.txt").read_text().startswith("License agreement for matplotlib")
    for name in ("salish_sea", "salish_sea_chart"):
        toml = (scenario_dir() / f"{name}.toml").read_text()
        assert "topobathy.npz" in toml and "HORIZONTAL SCALE" in toml
