"""Make the real-bathymetry sample files of the ``salish_sea`` scenarios from matplotlib's data.

Source: ``mpl-data/sample_data/topobathy.npz`` in the matplotlib wheel on PyPI (matplotlib
licence, a BSD-style licence that permits redistribution with its notice; see
``scenarios/data/README.md``). It is a topography/bathymetry grid of the Salish Sea (British
Columbia and Washington): longitude 234.0-238.0 E, latitude 48.0-50.0 N, 120 x 91 cells of
2 x 1.34 arc-minutes, elevation in metres (negative below sea level). Cells of exactly -1 m
(1897 of 10920, almost all on land) are a fill value of the dataset, not soundings; they are
written as nodata so the importer fills them by interpolation.

Outputs (run from the repository root: ``python scenarios/data/make_salish_sea.py``):

* ``salish_sea.tif``: the crop longitude -124.10 .. -123.30, latitude 48.95 .. 49.55 (the Strait
  of Georgia between Vancouver Island and the mainland) as a float32 GeoTIFF in WGS84
  (EPSG:4326), elevation [m], nodata -9999;
* ``salish_sea.000``: the same crop as a small S-57 chart written by GDAL's S-57 driver: every
  valid sea cell as a sounding (SOUNDG, depth = -elevation), the 50, 100, 200 and 300 m depth
  contours (DEPCNT), depth areas between them (DEPARE, 0-50-100-200-300-500 m) and land areas
  (LNDARE), traced by matplotlib on the crop with its fill cells interpolated.

``tests/world/test_shipped_data.py`` re-runs this crop and checks the shipped files still match.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

LON_RANGE = (-124.10, -123.30)  # deg
LAT_RANGE = (48.95, 49.55)  # deg
FILL = -1.0  # m, the dataset's fill value
NODATA = -9999.0
CONTOURS = (50.0, 100.0, 200.0, 300.0)  # m, depth contours written to the chart
BANDS = (0.0, 50.0, 100.0, 200.0, 300.0, 500.0)  # m, depth areas written to the chart


def crop() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return ``(lon (n,), lat (m,), elevation (m, n))`` of the crop, ascending axes, NaN = fill."""
    import matplotlib

    data = np.load(os.path.join(matplotlib.get_data_path(), "sample_data", "topobathy.npz"))
    lon = data["longitude"].astype(np.float64) - 360.0
    lat = data["latitude"].astype(np.float64)
    topo = data["topo"].astype(np.float64)
    i = (lat >= LAT_RANGE[0]) & (lat <= LAT_RANGE[1])
    j = (lon >= LON_RANGE[0]) & (lon <= LON_RANGE[1])
    elev = topo[np.ix_(i, j)]
    elev[elev == FILL] = np.nan
    return lon[j], lat[i], elev


def write_geotiff(path: Path) -> None:
    """Write the crop as a GeoTIFF (north-up, cell edges half way between the cell centres)."""
    import rasterio
    from rasterio.transform import Affine

    lon, lat, elev = crop()
    dlon = float(np.mean(np.diff(lon)))
    dlat = float(np.mean(np.diff(lat)))
    transform = Affine(dlon, 0.0, lon[0] - 0.5 * dlon, 0.0, -dlat, lat[-1] + 0.5 * dlat)  # west, north edges
    band = np.where(np.isfinite(elev), elev, NODATA)[::-1].astype(np.float32)  # north row first
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        height=band.shape[0],
        width=band.shape[1],
        count=1,
        dtype="float32",
        crs="EPSG:4326",
        transform=transform,
        nodata=NODATA,
    ) as dst:
        dst.write(band, 1)
        dst.update_tags(
            SOURCE="matplotlib mpl-data/sample_data/topobathy.npz (Salish Sea), crop "
            f"lon {LON_RANGE}, lat {LAT_RANGE}; -1 m fill cells as nodata",
            VALUES="elevation in metres, negative below sea level",
        )


def _filled(lon: np.ndarray, lat: np.ndarray, elev: np.ndarray) -> np.ndarray:
    """The elevation with its fill cells interpolated (linear, nearest outside)."""
    from scipy.interpolate import griddata

    lon2, lat2 = np.meshgrid(lon, lat)
    ok = np.isfinite(elev)
    pts = np.column_stack([lon2[ok], lat2[ok]])
    out = elev.copy()
    holes = ~ok
    out[holes] = griddata(pts, elev[ok], (lon2[holes], lat2[holes]), method="linear")
    still = ~np.isfinite(out)
    out[still] = griddata(pts, elev[ok], (lon2[still], lat2[still]), method="nearest")
    return out


def _polygons(rings: list[np.ndarray]) -> list[tuple[np.ndarray, list[np.ndarray]]]:
    """Group closed rings into (exterior, holes) by how deeply each is nested in the others."""
    from matplotlib.path import Path as MplPath

    def area(r: np.ndarray) -> float:
        x, y = r[:, 0], r[:, 1]
        return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))

    rings = sorted((r for r in rings if len(r) >= 4 and area(r) > 0.0), key=area, reverse=True)
    parents: list[int] = []
    for k, r in enumerate(rings):
        inside = [i for i in range(k) if MplPath(rings[i]).contains_point(r[0])]
        parents.append(inside[-1] if inside else -1)

    def depth(k: int) -> int:
        return 0 if parents[k] < 0 else 1 + depth(parents[k])

    polys: dict[int, tuple[np.ndarray, list[np.ndarray]]] = {}
    for k, r in enumerate(rings):
        if depth(k) % 2 == 0:
            polys[k] = (r, [])
        else:
            polys[parents[k]][1].append(r)
    return list(polys.values())


def write_chart(path: Path) -> None:
    """Write the crop as an S-57 chart: soundings, contours, depth areas and land."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hptvsim.world.s57 import ChartArea, ChartContour, ChartLand, write_s57_chart

    lon, lat, elev = crop()
    lon2, lat2 = np.meshgrid(lon, lat)
    sea = np.isfinite(elev) & (elev < 0.0)
    soundings = np.column_stack([lon2[sea], lat2[sea], -elev[sea]])
    depth = -_filled(lon, lat, elev)
    fig, ax = plt.subplots()
    cs = ax.contour(lon, lat, depth, levels=list(CONTOURS))
    contours = []
    for level, segs in zip(cs.levels, cs.allsegs, strict=True):
        contours += [ChartContour(lonlat=seg, depth=float(level)) for seg in segs if len(seg) >= 2]
    levels = [-1e4, *BANDS]
    fs = ax.contourf(lon, lat, depth, levels=levels)
    areas: list[ChartArea] = []
    land: list[ChartLand] = []
    for k, band_path in enumerate(fs.get_paths()):
        rings = [np.asarray(r, dtype=np.float64) for r in band_path.to_polygons(closed_only=True)]
        for ring, holes in _polygons(rings):
            if k == 0:
                land.append(ChartLand(ring=ring, holes=tuple(holes)))
            else:
                areas.append(ChartArea(ring=ring, holes=tuple(holes), drval1=levels[k], drval2=levels[k + 1]))
    plt.close(fig)
    write_s57_chart(path, soundings=soundings, contours=contours, areas=areas, land=land)


if __name__ == "__main__":
    here = Path(__file__).resolve().parent
    write_geotiff(here / "salish_sea.tif")
    write_chart(here / "salish_sea.000")
    print("wrote", here / "salish_sea.tif", "and", here / "salish_sea.000")
