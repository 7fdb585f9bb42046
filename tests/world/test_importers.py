"""Terrain importers: each format round-trips a known analytic surface within a stated tolerance.

The surface is ``f(x, y) = 50 + 8 sin(2 pi x / 160) cos(2 pi y / 120) + 0.05 x`` [m depth] over
x (north) in [-100, 100] m and y (east) in [-75, 75] m. Rasters sample it every 4 m; bilinear
interpolation of such a surface errs by at most ``h^2/8 (|f_xx| + |f_yy|) = 0.07 m``, so raster
formats are held to 0.08 m (plus their quantisation). Scattered soundings are held to an RMS
error and a looser maximum (their triangles are irregular).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hptvsim.world.geo import LocalProjection
from hptvsim.world.grid import GridGeometry
from hptvsim.world.importers import (
    ImportOptions,
    TerrainImportError,
    detect_format,
    import_heightmap,
    import_terrain,
    save_heightmap,
)
from hptvsim.world.terrain import HeightMap

LON0, LAT0 = -123.7, 49.25  # deg, a point in the Strait of Georgia
RASTER_TOL = 0.08  # m, bilinear interpolation bound of the surface at 4 m cells (see module doc)

TARGET = GridGeometry(origin=(-87.5, -67.5), resolution=5.0, shape=(36, 28))  # non-square


def surface(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return 50.0 + 8.0 * np.sin(2 * np.pi * x / 160.0) * np.cos(2 * np.pi * y / 120.0) + 0.05 * x


def truth(geometry: GridGeometry = TARGET) -> np.ndarray:
    x, y = geometry.centres()
    return surface(x[:, None], y[None, :])


def raster_axes(step: float = 4.0) -> tuple[np.ndarray, np.ndarray]:
    """Cell centres north (ascending) and east, symmetric about 0."""
    return np.arange(-100.0, 100.0 + 1e-9, step), np.arange(-76.0, 76.0 + 1e-9, step)


def proj_aeqd_metres(lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reference local metres from PROJ's ellipsoidal azimuthal equidistant projection."""
    from rasterio.crs import CRS
    from rasterio.warp import transform

    crs = CRS.from_proj4(f"+proj=aeqd +lat_0={LAT0} +lon_0={LON0} +x_0=0 +y_0=0 +ellps=WGS84 +units=m")
    east, north = transform(CRS.from_epsg(4326), crs, list(np.ravel(lon)), list(np.ravel(lat)))
    return np.reshape(north, np.shape(lon)), np.reshape(east, np.shape(lon))


def proj_aeqd_lonlat(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from rasterio.crs import CRS
    from rasterio.warp import transform

    crs = CRS.from_proj4(f"+proj=aeqd +lat_0={LAT0} +lon_0={LON0} +x_0=0 +y_0=0 +ellps=WGS84 +units=m")
    lon, lat = transform(crs, CRS.from_epsg(4326), list(np.ravel(y)), list(np.ravel(x)))
    return np.reshape(lon, np.shape(x)), np.reshape(lat, np.shape(x))


# --- projection ---------------------------------------------------------------------------------


@pytest.mark.parametrize(("radius", "tol"), [(5_000.0, 0.03), (20_000.0, 0.5)])
def test_local_projection_matches_proj_azimuthal_equidistant(radius: float, tol: float) -> None:
    rng = np.random.default_rng(0)
    x = rng.uniform(-radius, radius, 500)
    y = rng.uniform(-radius, radius, 500)
    lon, lat = proj_aeqd_lonlat(x, y)
    px, py = LocalProjection(lon0=LON0, lat0=LAT0).forward(lon, lat)
    assert np.hypot(px - x, py - y).max() < tol  # m, the bound geo.py states
    back_lon, back_lat = LocalProjection(lon0=LON0, lat0=LAT0).inverse(px, py)
    np.testing.assert_allclose(back_lon, lon, atol=1e-10)
    np.testing.assert_allclose(back_lat, lat, atol=1e-10)


# --- rasters --------------------------------------------------------------------------------------


def write_geotiff(path: Path, values_north_up: np.ndarray, transform: Any, crs: str) -> None:
    import rasterio

    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        height=values_north_up.shape[0],
        width=values_north_up.shape[1],
        count=1,
        dtype="float64",
        crs=crs,
        transform=transform,
    ) as dst:
        dst.write(values_north_up, 1)


def test_geotiff_projected_round_trip(tmp_path: Path) -> None:
    from rasterio.transform import Affine

    xs, ys = raster_axes()
    e0, n0 = 480_000.0, 5_450_000.0  # m, UTM zone 10N easting/northing of the data's centre
    elev = -surface(xs[:, None], ys[None, :])  # elevation = -depth
    transform = Affine(4.0, 0.0, e0 + ys[0] - 2.0, 0.0, -4.0, n0 + xs[-1] + 2.0)  # west, north edges
    write_geotiff(tmp_path / "utm.tif", elev[::-1], transform, "EPSG:32610")
    res = import_terrain(tmp_path / "utm.tif", TARGET)  # GeoTIFF default: elevation
    assert np.abs(res.heightmap.depth - truth()).max() < RASTER_TOL
    assert res.coverage == 1.0 and res.holes_filled == 0
    assert "EPSG:32610" in res.description


def test_geotiff_geographic_round_trip(tmp_path: Path) -> None:
    """Cells on a lon/lat grid whose values come from PROJ's metres: the importer's own
    projection must put every value back where PROJ says it belongs."""
    from rasterio.transform import Affine

    lon_c = np.linspace(LON0 - 0.0015, LON0 + 0.0015, 61)  # ~3.6 m cells east
    lat_c = np.linspace(LAT0 - 0.001, LAT0 + 0.001, 61)  # ~3.7 m cells north
    lon2, lat2 = np.meshgrid(lon_c, lat_c)
    x, y = proj_aeqd_metres(lon2, lat2)
    elev = -surface(x, y)  # rows: ascending latitude
    dlon, dlat = lon_c[1] - lon_c[0], lat_c[1] - lat_c[0]
    transform = Affine(dlon, 0.0, lon_c[0] - dlon / 2, 0.0, -dlat, lat_c[-1] + dlat / 2)
    write_geotiff(tmp_path / "wgs84.tif", elev[::-1], transform, "EPSG:4326")
    g = GridGeometry(origin=(-67.5, -52.5), resolution=5.0, shape=(28, 22))
    hm = import_heightmap(tmp_path / "wgs84.tif", g, options=ImportOptions(anchor_lonlat=(LON0, LAT0)))
    assert np.abs(hm.depth - truth(g)).max() < RASTER_TOL


def write_esri_ascii(
    path: Path,
    values_north_up: np.ndarray,
    x0: float,
    y0: float,
    cell: float,
    nodata: float | None = None,
    centre: bool = False,
) -> None:
    nrows, ncols = values_north_up.shape
    lines = [f"ncols {ncols}", f"nrows {nrows}"]
    kind = "center" if centre else "corner"
    lines += [f"xll{kind} {x0}", f"yll{kind} {y0}", f"cellsize {cell}"]
    if nodata is not None:
        lines.append(f"NODATA_value {nodata}")
    lines += [" ".join(f"{v:.6f}" for v in row) for row in values_north_up]
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("centre", [False, True], ids=["xllcorner", "xllcenter"])
def test_esri_ascii_round_trip(tmp_path: Path, centre: bool) -> None:
    xs, ys = raster_axes()
    elev = -surface(xs[:, None], ys[None, :])
    x0 = 700.0 + ys[0] - (0.0 if centre else 2.0)  # easting of the lower-left cell centre/corner
    y0 = 9_000.0 + xs[0] - (0.0 if centre else 2.0)
    write_esri_ascii(tmp_path / "grid.asc", elev[::-1], x0, y0, 4.0, centre=centre)
    assert detect_format(tmp_path / "grid.asc") == "esri_ascii"
    hm = import_heightmap(tmp_path / "grid.asc", TARGET)
    assert np.abs(hm.depth - truth()).max() < RASTER_TOL


def test_raster_holes_are_filled_by_interpolation_exactly_on_a_plane(tmp_path: Path) -> None:
    xs, ys = raster_axes()
    plane = 40.0 + 0.1 * xs[:, None] - 0.07 * ys[None, :]
    elev = -plane
    elev[10:20, 5:15] = -9999.0  # a 40 m x 40 m hole
    elev[30, 30] = -9999.0
    write_esri_ascii(tmp_path / "holes.asc", elev[::-1], ys[0] - 2.0, xs[0] - 2.0, 4.0, nodata=-9999)
    res = import_terrain(tmp_path / "holes.asc", TARGET)
    x, y = TARGET.centres()
    np.testing.assert_allclose(res.heightmap.depth, 40.0 + 0.1 * x[:, None] - 0.07 * y[None, :], atol=1e-9)
    assert res.holes_filled == 101


@pytest.mark.parametrize(("bits", "tol"), [(16, RASTER_TOL + 0.001), (8, RASTER_TOL + 0.08)])
def test_png_round_trip_with_vertical_scale_and_offset(tmp_path: Path, bits: int, tol: float) -> None:
    from PIL import Image

    xs, ys = raster_axes()
    full = 2**bits - 1
    grey = (70.0 - surface(xs[:, None], ys[None, :])) / 40.0  # white = 30 m, black = 70 m
    pixels = np.round(grey * full).astype(np.uint16 if bits == 16 else np.uint8)
    Image.fromarray(pixels[::-1]).save(tmp_path / "hm.png")  # top row = north
    opts = ImportOptions(vertical_scale=40.0, vertical_offset=70.0, pixel_size=4.0)
    hm = import_heightmap(tmp_path / "hm.png", TARGET, options=opts)
    assert np.abs(hm.depth - truth()).max() < tol  # interpolation + half a grey level (40 m / full / 2)


def test_png_without_pixel_size_is_stretched_over_the_grid(tmp_path: Path) -> None:
    from PIL import Image

    g = GridGeometry(origin=(2.0, 2.0), resolution=4.0, shape=(50, 38))  # covers [0, 200] x [0, 152]
    x, y = g.centres()
    grey = (x[:, None] + 0.0 * y[None, :]) / 200.0  # brightens northwards
    Image.fromarray(np.round(grey * 65535).astype(np.uint16)[::-1]).save(tmp_path / "ramp.png")
    hm = import_heightmap(
        tmp_path / "ramp.png", g, options=ImportOptions(values="depth", vertical_scale=200.0)
    )
    np.testing.assert_allclose(hm.depth, np.broadcast_to(x[:, None], g.shape), atol=0.01)


def test_colour_png_is_rejected(tmp_path: Path) -> None:
    from PIL import Image

    rgb = np.zeros((10, 10, 3), dtype=np.uint8)
    rgb[..., 0] = 200
    Image.fromarray(rgb).save(tmp_path / "colour.png")
    with pytest.raises(TerrainImportError, match="greyscale"):
        import_heightmap(tmp_path / "colour.png", TARGET, options=ImportOptions(pixel_size=1.0))


# --- scattered soundings ---------------------------------------------------------------------------


def scattered(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    x = np.concatenate([rng.uniform(-100.0, 100.0, n), [-100, -100, 100, 100]])
    y = np.concatenate([rng.uniform(-76.0, 76.0, n), [-76, 76, -76, 76]])
    return x, y


def test_xyz_round_trip_projected_whitespace(tmp_path: Path) -> None:
    x, y = scattered(6000)
    e0, n0 = 300_000.0, 4_000_000.0
    lines = [f"{e0 + yy:.3f} {n0 + xx:.3f} {surface(xx, yy):.4f}" for xx, yy in zip(x, y, strict=True)]
    (tmp_path / "soundings.xyz").write_text("\n".join(lines))
    hm = import_heightmap(tmp_path / "soundings.xyz", TARGET, options=ImportOptions(anchor=(0.0, 0.0)))
    err = hm.depth - truth()
    assert np.sqrt(np.mean(err**2)) < 0.05 and np.abs(err).max() < 0.3


def test_csv_round_trip_geographic_with_header(tmp_path: Path) -> None:
    x, y = scattered(6000, seed=1)
    lon, lat = proj_aeqd_lonlat(x, y)
    rows = ["longitude,latitude,elevation"]
    rows += [
        f"{lo:.9f},{la:.9f},{-surface(xx, yy):.4f}" for lo, la, xx, yy in zip(lon, lat, x, y, strict=True)
    ]
    (tmp_path / "soundings.csv").write_text("\n".join(rows))
    res = import_terrain(
        tmp_path / "soundings.csv", TARGET, options=ImportOptions(anchor_lonlat=(LON0, LAT0))
    )
    err = res.heightmap.depth - truth()
    assert np.sqrt(np.mean(err**2)) < 0.05 and np.abs(err).max() < 0.3
    assert "azimuthal equidistant" in res.description


# --- S-57 charts -------------------------------------------------------------------------------------


def test_s57_soundings_and_contours_round_trip(tmp_path: Path) -> None:
    """A chart the test writes with GDAL's S-57 driver, read back through pyogrio."""
    from hptvsim.world.s57 import ChartContour, write_s57_chart

    x, y = scattered(4000, seed=2)
    lon, lat = proj_aeqd_lonlat(x, y)
    depth = surface(x, y)
    # contours: the 50 m isobath of the surface, traced along x = 0 +- ... as a line of points
    cy = np.linspace(-76.0, 76.0, 40)
    cx = np.zeros_like(cy)  # f(0, y) = 50 exactly
    clon, clat = proj_aeqd_lonlat(cx, cy)
    chart = write_s57_chart(
        tmp_path / "TEST0001.000",
        soundings=np.column_stack([lon, lat, depth]),
        contours=[ChartContour(lonlat=np.column_stack([clon, clat]), depth=50.0)],
    )
    res = import_terrain(chart, TARGET, options=ImportOptions(anchor_lonlat=(LON0, LAT0)))
    assert "4004 soundings, 1 contours" in res.description
    err = res.heightmap.depth - truth()
    # soundings are stored to 0.1 m (SOMF = 10): add 0.05 m to the gridding error
    assert np.sqrt(np.mean(err**2)) < 0.08 and np.abs(err).max() < 0.35


def test_s57_depth_areas_and_land_shape_the_seabed(tmp_path: Path) -> None:
    """Without soundings a depth area gives its middle depth; land rises above the sea."""
    from hptvsim.world.s57 import ChartArea, ChartLand, write_s57_chart

    def ring(x0: float, x1: float, y0: float, y1: float) -> np.ndarray:
        xs = np.array([x0, x0, x1, x1, x0])
        ys = np.array([y0, y1, y1, y0, y0])
        lon, lat = proj_aeqd_lonlat(xs, ys)
        return np.column_stack([lon, lat])

    chart = write_s57_chart(
        tmp_path / "AREAS001.000",
        areas=[
            ChartArea(ring=ring(-100, 100, -80, 0), drval1=10.0, drval2=20.0),  # west half
            ChartArea(ring=ring(-100, 100, 0, 80), drval1=30.0, drval2=50.0),  # east half
        ],
        land=[ChartLand(ring=ring(20, 60, 20, 60), holes=(ring(35, 45, 35, 45),))],
    )
    hm = import_heightmap(chart, TARGET, options=ImportOptions(anchor_lonlat=(LON0, LAT0)))
    x, y = TARGET.centres()
    xx, yy = np.meshgrid(x, y, indexing="ij")
    on_land = (xx > 21) & (xx < 59) & (yy > 21) & (yy < 59) & ~((xx > 34) & (xx < 46) & (yy > 34) & (yy < 46))
    lagoon = (xx > 36) & (xx < 44) & (yy > 36) & (yy < 44)
    west = (yy < -1) & ~on_land
    east = (yy > 1) & ~on_land & ~lagoon
    np.testing.assert_allclose(hm.depth[west], 15.0)
    np.testing.assert_allclose(hm.depth[east], 40.0)
    assert (hm.depth[on_land] < 0.0).all()  # land is above the sea: always an obstacle
    np.testing.assert_allclose(hm.depth[lagoon], 40.0)  # the hole in the land is water


def test_s57_soundings_are_bounded_by_their_depth_area(tmp_path: Path) -> None:
    from hptvsim.world.s57 import ChartArea, write_s57_chart

    x, y = scattered(500, seed=3)
    lon, lat = proj_aeqd_lonlat(x, y)
    rx = np.array([-120, -120, 120, 120, -120.0])
    ry = np.array([-90, 90, 90, -90, -90.0])
    rlon, rlat = proj_aeqd_lonlat(rx, ry)
    chart = write_s57_chart(
        tmp_path / "CLAMP001.000",
        soundings=np.column_stack([lon, lat, surface(x, y)]),  # 42 .. 63 m
        areas=[ChartArea(ring=np.column_stack([rlon, rlat]), drval1=45.0, drval2=55.0)],
    )
    hm = import_heightmap(chart, TARGET, options=ImportOptions(anchor_lonlat=(LON0, LAT0)))
    assert hm.depth.min() >= 45.0 and hm.depth.max() <= 55.0
    inside = (truth() > 46.0) & (truth() < 54.0)
    assert np.abs(hm.depth - truth())[inside].mean() < 0.3  # 500 soundings: coarse triangles


# --- own formats and errors ---------------------------------------------------------------------------


@pytest.mark.parametrize("suffix", [".npz", ".tif"])
def test_saved_heightmaps_import_unchanged(tmp_path: Path, suffix: str) -> None:
    hm = HeightMap(geometry=TARGET, depth=truth())
    path = save_heightmap(hm, tmp_path / f"hm{suffix}")
    back = import_heightmap(path, TARGET, options=ImportOptions(anchor=(0.0, 0.0)))
    tol = 1e-12 if suffix == ".npz" else 1e-5  # the GeoTIFF stores float32
    np.testing.assert_allclose(back.depth, hm.depth, atol=tol * 60.0)


def test_import_without_a_target_grid_covers_the_source(tmp_path: Path) -> None:
    xs, ys = raster_axes()
    write_esri_ascii(tmp_path / "g.asc", -surface(xs[:, None], ys[None, :])[::-1], ys[0] - 2, xs[0] - 2, 4.0)
    res = import_terrain(tmp_path / "g.asc")  # the source's own 4 m cells
    g = res.heightmap.geometry
    assert g.resolution == pytest.approx(4.0)
    assert g.shape == (51, 39)
    x, y = g.centres()
    np.testing.assert_allclose(res.heightmap.depth, surface(x[:, None], y[None, :]), atol=1e-6)
    scaled = import_terrain(tmp_path / "g.asc", options=ImportOptions(horizontal_scale=0.5), resolution=2.0)
    assert scaled.heightmap.geometry.extent[1] - scaled.heightmap.geometry.extent[0] == pytest.approx(102.0)


def test_import_errors_name_the_problem(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="does not exist"):
        import_heightmap(tmp_path / "missing.tif", TARGET)
    (tmp_path / "terrain.obj").write_text("v 0 0 0")
    with pytest.raises(TerrainImportError, match=r"known suffixes: .*\.asc"):
        import_heightmap(tmp_path / "terrain.obj", TARGET)
    xs, ys = raster_axes()
    write_esri_ascii(
        tmp_path / "far.asc", -surface(xs[:, None], ys[None, :])[::-1], ys[0] - 2, xs[0] - 2, 4.0
    )
    far = ImportOptions(anchor=(1000.0, 0.0))
    with pytest.raises(TerrainImportError, match=r"do not overlap the grid at all \(data x -1100..-900 m"):
        import_heightmap(tmp_path / "far.asc", TARGET, options=far)
    aside = ImportOptions(anchor=(-150.0, 0.0))  # data x 50..250 m over a grid up to x = 90 m
    with pytest.raises(TerrainImportError, match=r"cover only 22% of the grid \(need 50%: data x 50..250 m"):
        import_heightmap(tmp_path / "far.asc", TARGET, options=aside)
    (tmp_path / "bad.asc").write_text("ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2 3\n")
    with pytest.raises(TerrainImportError, match="says 2 x 2 values, the file holds 3"):
        import_heightmap(tmp_path / "bad.asc", TARGET)
    with pytest.raises(ValueError, match="not both"):
        ImportOptions(anchor=(0.0, 0.0), anchor_lonlat=(0.0, 0.0))
    from PIL import Image

    Image.fromarray(np.zeros((4, 4), dtype=np.uint8)).save(tmp_path / "a.png")
    with pytest.raises(TerrainImportError, match="pixel size"):
        import_terrain(tmp_path / "a.png")
