"""Seabed from data: GeoTIFF, ESRI ASCII grid, PNG height map, XYZ/CSV soundings, S-57 charts.

This is the paper's chart -> raster -> height-map pipeline (section III-B) as one function,
:func:`import_terrain`: read the source, bring it into local metres, grid it onto the requested
:class:`~hptvsim.world.grid.GridGeometry` and fill its holes by interpolation.

**Reading.** Each format gives either a raster (a regular grid in the file's own coordinates,
holes as NaN) or scattered points (soundings), plus, for charts, depth areas and land areas:

=============  =========================================================  ===============
format         what is read                                               values default
=============  =========================================================  ===============
``geotiff``    band 1 (rasterio), nodata as holes, georeferenced by CRS   elevation
``esri_ascii`` ESRI ASCII grid (``.asc``), ``NODATA_value`` as holes      elevation
``png``        greyscale 8/16 bit, 0..1 of full scale; transparent = hole  elevation
``xyz``        columns x y z (comma, semicolon or whitespace separated)   depth
``s57``        SOUNDG soundings, DEPCNT contours (VALDCO), DEPARE areas   depth
               (DRVAL1/DRVAL2) and LNDARE land, read with pyogrio
``npz``        a height map written by :meth:`HeightMap.save`             depth
=============  =========================================================  ===============

**Values to depth.** ``depth = vertical_offset + vertical_scale * s * value`` [m, positive
down] with ``s = +1`` for depths and ``s = -1`` for elevations (positive up). For a PNG,
``value`` is the grey level as a fraction of full scale (0 black .. 1 white), so e.g.
``vertical_scale = 40, vertical_offset = 70`` maps black to 70 m and white to 30 m.

**Coordinates.** Geographic sources (longitude/latitude: S-57 always, GeoTIFF with a
geographic CRS, ASCII grids with a geographic ``.prj``, XYZ when told) are projected to local
metres with :class:`~hptvsim.world.geo.LocalProjection` (azimuthal equidistant, WGS84 scales) about
the anchor (``anchor_lonlat``, default the data's centre). Projected sources are shifted so the
anchor (``anchor`` [m] from the data's centre, default the centre) is the origin. Metres are
then multiplied by ``horizontal_scale`` and the anchor is placed at a chosen point of the
target grid (the site's centre, for scenarios).

**Gridding and holes.** Rasters: holes are filled by linear interpolation from the valid cells
around each hole (Delaunay, :func:`scipy.interpolate.griddata`), rasters much finer than the
target are low-pass filtered (Gaussian, against aliasing), then sampled bilinearly at each
target cell centre mapped back into the file's coordinates (inverse projection). Points:
linear interpolation over their Delaunay triangulation. Target cells outside the data take
the nearest value. Chart depth areas then clamp each cell to its area's ``[DRVAL1, DRVAL2]``
(or give the area's middle depth where no soundings exist), and land areas are set 1 m above
the sea surface.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import numpy.typing as npt
from scipy import interpolate, ndimage

from hptvsim.world._schema import check_bounds, spec
from hptvsim.world.geo import LocalProjection
from hptvsim.world.grid import GridGeometry
from hptvsim.world.terrain import HEIGHTMAP_FORMAT, HeightMap

__all__ = [
    "FORMATS",
    "ImportOptions",
    "ImportResult",
    "TerrainImportError",
    "detect_format",
    "import_heightmap",
    "import_terrain",
    "save_heightmap",
]

F64 = npt.NDArray[np.float64]
Format = Literal["auto", "geotiff", "esri_ascii", "png", "xyz", "s57", "npz"]

FORMATS: dict[str, tuple[str, ...]] = {
    "geotiff": (".tif", ".tiff", ".gtiff"),
    "esri_ascii": (".asc",),
    "png": (".png",),
    "xyz": (".xyz", ".csv", ".txt"),
    "s57": (".000",),
    "npz": (".npz",),
}
"""Formats and the file suffixes that select them when ``format = "auto"``."""

_DEFAULT_VALUES = {
    "geotiff": "elevation",
    "esri_ascii": "elevation",
    "png": "elevation",
    "xyz": "depth",
    "s57": "depth",
    "npz": "depth",
}

LAND_DEPTH = -1.0  # m, depth given to chart land areas (1 m above the sea surface)


class TerrainImportError(ValueError):
    """A terrain source cannot be read or does not cover the requested grid."""


@dataclass(frozen=True, kw_only=True)
class ImportOptions:
    """How to turn a terrain source into depths in the site frame (see the module docs)."""

    values: Literal["auto", "depth", "elevation"] = spec(
        "auto",
        doc="what the source's numbers are: 'depth' (positive down), 'elevation' (positive up), "
        "'auto' (the format's default)",
    )
    vertical_scale: float = spec(
        1.0, doc="multiplies the source values (PNG: metres per full scale)", gt=0.0, le=1e6
    )
    vertical_offset: float = spec(0.0, doc="added after scaling", unit="m", ge=-1e5, le=1e5)
    horizontal_scale: float = spec(1.0, doc="site metres per source metre", gt=0.0, le=1e6)
    anchor: tuple[float, float] | None = spec(
        None,
        doc="point of a projected source (x north, y east from its centre) put at the site centre",
        unit="m",
        ge=-1e8,
        le=1e8,
    )
    anchor_lonlat: tuple[float, float] | None = spec(
        None,
        doc="point of a geographic source (longitude in [-180, 180], latitude in (-90, 90)) put at the "
        "site centre",
        unit="deg",
        ge=-180.0,
        le=180.0,
    )
    pixel_size: float | None = spec(
        None, doc="PNG: metres per pixel (default: stretch the image over the site)", unit="m", gt=0.0, le=1e5
    )
    geographic: bool | None = spec(
        None, doc="whether coordinates are longitude/latitude (default: from the CRS or .prj; XYZ: no)"
    )

    def __post_init__(self) -> None:
        check_bounds(self)
        if self.anchor is not None and self.anchor_lonlat is not None:
            raise ValueError("give either 'anchor' (metres) or 'anchor_lonlat' (degrees), not both")
        if self.anchor_lonlat is not None:
            lon, lat = self.anchor_lonlat
            if not (-180.0 <= lon <= 180.0 and -90.0 < lat < 90.0):
                raise ValueError(
                    f"anchor_lonlat must be (longitude, latitude) in degrees, got {self.anchor_lonlat}"
                )


@dataclass
class _Raster:
    """A raster in its own coordinates, with the maps to and from local metres.

    ``values[i, j]`` sits at native ``(u[i], v[j])``: ``u`` the northward axis (latitude or
    northing), ``v`` the eastward one (longitude or easting), both ascending.
    """

    u: F64
    v: F64
    values: F64
    to_native: Callable[[F64, F64], tuple[F64, F64]]  # local (x, y) [m] -> (u, v)
    to_local: Callable[[F64, F64], tuple[F64, F64]]  # (u, v) -> local (x, y) [m]

    def local_centres(self) -> tuple[F64, F64]:
        """Local ``(x, y)`` [m] of every cell centre, each of shape ``(nu, nv)``."""
        uu, vv = np.meshgrid(self.u, self.v, indexing="ij")
        return self.to_local(uu, vv)


@dataclass
class _Source:
    """A source: a raster, or points in local metres about the anchor (before scaling)."""

    kind: Literal["raster", "points"]
    values_kind: str  # "depth" or "elevation"
    description: str
    raster: _Raster | None = None
    x: F64 = field(default_factory=lambda: np.zeros(0))  # points: (n,) north [m]
    y: F64 = field(default_factory=lambda: np.zeros(0))  # points: (n,) east [m]
    values: F64 = field(default_factory=lambda: np.zeros(0))  # points: (n,)
    areas: list[tuple[list[F64], float, float]] = field(default_factory=list)  # rings (local m), lo, hi
    land: list[list[F64]] = field(default_factory=list)


@dataclass(frozen=True, kw_only=True)
class ImportResult:
    """What :func:`import_terrain` produced.

    Attributes:
        heightmap: The gridded, hole-free seabed.
        coverage: Fraction of target cells inside the data (the rest took the nearest value).
        holes_filled: Number of source raster cells that were holes and got interpolated.
        description: One line: file, format, projection, scale.
    """

    heightmap: HeightMap
    coverage: float
    holes_filled: int
    description: str


def detect_format(path: str | Path) -> str:
    """Name the format of a file from its suffix.

    Raises:
        TerrainImportError: The suffix is not one of :data:`FORMATS` (the message lists them).
    """
    suffix = Path(path).suffix.lower()
    for name, suffixes in FORMATS.items():
        if suffix in suffixes:
            return name
    known = ", ".join(f"{s} ({n})" for n, ss in FORMATS.items() for s in ss)
    raise TerrainImportError(
        f"cannot tell the terrain format of {Path(path).name!r}; known suffixes: {known}"
    )


# --- readers ------------------------------------------------------------------------------------


def _centre_shift(x: F64, y: F64, options: ImportOptions) -> tuple[float, float]:
    """Return the point of a projected source (its units) that becomes the local origin."""
    cx = 0.5 * (float(np.nanmin(x)) + float(np.nanmax(x)))
    cy = 0.5 * (float(np.nanmin(y)) + float(np.nanmax(y)))
    if options.anchor is not None:
        cx += options.anchor[0]
        cy += options.anchor[1]
    return cx, cy


def _projection(lon: F64, lat: F64, options: ImportOptions) -> LocalProjection:
    if options.anchor is not None:
        raise TerrainImportError("this source is geographic: place it with 'anchor_lonlat', not 'anchor'")
    if options.anchor_lonlat is not None:
        lon0, lat0 = options.anchor_lonlat
    else:
        lon0 = 0.5 * (float(np.nanmin(lon)) + float(np.nanmax(lon)))
        lat0 = 0.5 * (float(np.nanmin(lat)) + float(np.nanmax(lat)))
    if np.nanmax(np.abs(lat)) > 90.0:
        raise TerrainImportError(
            "coordinates are not longitude/latitude (|latitude| > 90); set 'geographic = false'"
        )
    return LocalProjection(lon0=lon0, lat0=lat0)


def _raster(
    east: F64, north: F64, values: F64, options: ImportOptions, geographic: bool
) -> tuple[_Raster, str]:
    """A raster from its cell-centre coordinates (columns along ``east``, rows along ``north``)."""
    if north[0] > north[-1]:
        north, values = north[::-1], values[::-1, :]
    if east[0] > east[-1]:
        east, values = east[::-1], values[:, ::-1]
    u = np.ascontiguousarray(north, dtype=np.float64)
    v = np.ascontiguousarray(east, dtype=np.float64)
    vals = np.ascontiguousarray(values, dtype=np.float64)
    if geographic:
        proj = _projection(v, u, options)

        def to_local(uu: F64, vv: F64) -> tuple[F64, F64]:
            return proj.forward(vv, uu)

        def to_native(x: F64, y: F64) -> tuple[F64, F64]:
            lon, lat = proj.inverse(x, y)
            return lat, lon

        how = f"azimuthal equidistant projection about {proj.lon0:.5f} E, {proj.lat0:.5f} N"
    else:
        cx, cy = _centre_shift(u, v, options)

        def to_local(uu: F64, vv: F64) -> tuple[F64, F64]:
            return uu - cx, vv - cy

        def to_native(x: F64, y: F64) -> tuple[F64, F64]:
            return x + cx, y + cy

        how = "projected metres"
    return _Raster(u=u, v=v, values=vals, to_native=to_native, to_local=to_local), how


def _read_geotiff(path: Path, options: ImportOptions) -> _Source:
    try:
        import rasterio
    except ImportError as exc:  # pragma: no cover - the world extra installs it
        raise TerrainImportError("reading GeoTIFF needs rasterio: pip install 'hptvsim[world]'") from exc
    try:
        with rasterio.open(path) as src:
            band = src.read(1, masked=True)
            values = np.ma.filled(band.astype(np.float64), np.nan)
            t = src.transform
            crs = src.crs
            tags = src.tags()
    except rasterio.errors.RasterioIOError as exc:
        raise TerrainImportError(f"{path}: not a readable GeoTIFF ({exc})") from None
    if abs(t.b) > 0.0 or abs(t.d) > 0.0:
        raise TerrainImportError(f"{path}: rotated rasters are not supported (transform {tuple(t)[:6]})")
    nrows, ncols = values.shape
    east = t.c + t.a * (np.arange(ncols) + 0.5)
    north = t.f + t.e * (np.arange(nrows) + 0.5)
    geographic = options.geographic
    if geographic is None:
        geographic = bool(crs is not None and crs.is_geographic)
    if crs is not None and crs.is_projected and not geographic:
        _unit_name, factor = crs.linear_units_factor
        east, north = east * factor, north * factor
    raster, how = _raster(east, north, values, options, geographic)
    values_kind = "depth" if tags.get("HPTVSIM_VALUES") == "depth" else _DEFAULT_VALUES["geotiff"]
    crs_text = crs.to_string() if crs is not None else "no CRS"
    return _Source("raster", values_kind, f"GeoTIFF {path.name} ({crs_text}; {how})", raster=raster)


def _read_esri_ascii(path: Path, options: ImportOptions) -> _Source:
    text = path.read_text()
    lines = text.splitlines()
    header: dict[str, float] = {}
    n_header = 0
    for line in lines:
        parts = line.split()
        if len(parts) == 2 and re.fullmatch(r"[A-Za-z_]+", parts[0]):
            try:
                header[parts[0].lower()] = float(parts[1])
            except ValueError:
                raise TerrainImportError(f"{path}: header line {line!r} has no number") from None
            n_header += 1
        else:
            break
    for key in ("ncols", "nrows"):
        if key not in header:
            raise TerrainImportError(f"{path}: not an ESRI ASCII grid (no '{key}' in the header)")
    ncols, nrows = int(header["ncols"]), int(header["nrows"])
    if "cellsize" in header:
        dx = dy = header["cellsize"]
    elif "dx" in header and "dy" in header:
        dx, dy = header["dx"], header["dy"]
    else:
        raise TerrainImportError(f"{path}: the header needs 'cellsize' (or 'dx' and 'dy')")
    if "xllcenter" in header:
        x0 = header["xllcenter"]
    elif "xllcorner" in header:
        x0 = header["xllcorner"] + 0.5 * dx
    else:
        raise TerrainImportError(f"{path}: the header needs 'xllcorner' or 'xllcenter'")
    if "yllcenter" in header:
        y0 = header["yllcenter"]
    elif "yllcorner" in header:
        y0 = header["yllcorner"] + 0.5 * dy
    else:
        raise TerrainImportError(f"{path}: the header needs 'yllcorner' or 'yllcenter'")
    try:
        data = np.array(" ".join(lines[n_header:]).split(), dtype=np.float64)
    except ValueError as exc:
        raise TerrainImportError(f"{path}: the grid holds a value that is not a number ({exc})") from None
    if data.size != nrows * ncols:
        raise TerrainImportError(
            f"{path}: the header says {nrows} x {ncols} values, the file holds {data.size}"
        )
    values = data.reshape(nrows, ncols)  # first row is the northernmost
    if "nodata_value" in header:
        values[values == header["nodata_value"]] = np.nan
    east = x0 + dx * np.arange(ncols)
    north = y0 + dy * np.arange(nrows)[::-1]
    geographic = options.geographic
    prj = path.with_suffix(".prj")
    if geographic is None:
        geographic = prj.is_file() and "GEOGCS" in prj.read_text() and "PROJCS" not in prj.read_text()
    raster, how = _raster(
        np.asarray(east, np.float64), np.asarray(north, np.float64), values, options, geographic
    )
    return _Source(
        "raster", _DEFAULT_VALUES["esri_ascii"], f"ESRI ASCII grid {path.name} ({how})", raster=raster
    )


def _read_png(path: Path, options: ImportOptions, target: GridGeometry | None, scale: float) -> _Source:
    try:
        from PIL import Image
    except ImportError as exc:  # pragma: no cover - the world extra installs it
        raise TerrainImportError(
            "reading PNG height maps needs pillow: pip install 'hptvsim[world]'"
        ) from exc
    try:
        with Image.open(path) as im:
            mode = im.mode
            arr = np.asarray(im)
    except OSError as exc:
        raise TerrainImportError(f"{path}: not a readable image ({exc})") from None
    alpha = None
    if mode.startswith("I;16") or mode == "I":
        full = 65535.0
        grey = arr.astype(np.float64)
    elif mode == "L":
        full, grey = 255.0, arr.astype(np.float64)
    elif mode == "LA":
        full, grey, alpha = 255.0, arr[..., 0].astype(np.float64), arr[..., 1]
    elif mode in ("RGB", "RGBA"):
        rgb = arr[..., :3].astype(np.float64)
        if not (np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 0], rgb[..., 2])):
            raise TerrainImportError(
                f"{path}: the image has colours; a height map must be greyscale (8 or 16 bit)"
            )
        full, grey = 255.0, rgb[..., 0]
        alpha = arr[..., 3] if mode == "RGBA" else None
    else:
        raise TerrainImportError(f"{path}: image mode {mode!r} is not a greyscale height map (use L or I;16)")
    values = grey / full
    if alpha is not None:
        values[alpha == 0] = np.nan
    nrows, ncols = values.shape
    if options.pixel_size is not None:
        px = py = options.pixel_size
        how = f"{options.pixel_size:g} m per pixel"
    elif target is not None:
        x_min, x_max, y_min, y_max = target.extent
        px = (x_max - x_min) / nrows / scale
        py = (y_max - y_min) / ncols / scale
        how = "stretched over the site"
    else:
        raise TerrainImportError(f"{path}: a PNG has no georeference; give its pixel size in metres")
    north = px * (np.arange(nrows)[::-1] - 0.5 * (nrows - 1))
    east = py * (np.arange(ncols) - 0.5 * (ncols - 1))
    raster, _ = _raster(east, north, values, options, False)
    bits = 16 if full > 255 else 8
    return _Source("raster", _DEFAULT_VALUES["png"], f"PNG {path.name} ({bits}-bit, {how})", raster=raster)


_X_NAMES = ("x", "lon", "long", "longitude", "easting", "east", "e")
_Y_NAMES = ("y", "lat", "latitude", "northing", "north", "n")
_Z_NAMES = ("z", "depth", "elevation", "elev", "height", "value", "h", "d")


def _read_xyz(path: Path, options: ImportOptions) -> _Source:
    lines = [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise TerrainImportError(f"{path}: no data lines")
    first = lines[0]
    delim: str | None = "," if "," in first else (";" if ";" in first else None)

    def split(line: str) -> list[str]:
        return [p.strip() for p in (line.split(delim) if delim else line.split())]

    cols = (0, 1, 2)
    header_geo = False
    try:
        [float(v) for v in split(first)]
        body = lines
    except ValueError:
        names = [n.lower() for n in split(first)]
        body = lines[1:]

        def find(cands: tuple[str, ...], what: str) -> int:
            for c in cands:
                if c in names:
                    return names.index(c)
            raise TerrainImportError(
                f"{path}: header {split(first)} has no {what} column (tried {', '.join(cands)})"
            )

        cols = (
            find(_X_NAMES, "x/longitude"),
            find(_Y_NAMES, "y/latitude"),
            find(_Z_NAMES, "depth/elevation"),
        )
        header_geo = names[cols[0]] in ("lon", "long", "longitude")
        header_values = "elevation" if names[cols[2]] in ("elevation", "elev", "height", "h") else "depth"
    else:
        header_values = _DEFAULT_VALUES["xyz"]
    try:
        rows = np.array([[float(split(ln)[c]) for c in cols] for ln in body], dtype=np.float64)
    except (ValueError, IndexError) as exc:
        raise TerrainImportError(f"{path}: a data line is not {len(cols)} numbers ({exc})") from None
    if len(rows) < 3:
        raise TerrainImportError(f"{path}: {len(rows)} sounding(s); gridding needs at least 3")
    east, north, z = rows[:, 0], rows[:, 1], rows[:, 2]
    geographic = options.geographic if options.geographic is not None else header_geo
    if geographic:
        proj = _projection(east, north, options)
        x, y = proj.forward(east, north)
        how = f"azimuthal equidistant projection about {proj.lon0:.5f} E, {proj.lat0:.5f} N"
    else:
        cx, cy = _centre_shift(north, east, options)
        x, y = north - cx, east - cy
        how = "projected metres"
    desc = f"soundings {path.name} ({len(rows)} points; {how})"
    return _Source("points", header_values, desc, x=x, y=y, values=z)


def _read_s57(path: Path, options: ImportOptions, spacing: float) -> _Source:
    try:
        import pyogrio
        from pyogrio import raw
    except ImportError as exc:  # pragma: no cover - the world extra installs it
        raise TerrainImportError("reading S-57 charts needs pyogrio: pip install 'hptvsim[world]'") from exc
    from hptvsim.world._wkb import Shapes, parse_wkb

    try:
        layers = {str(name) for name, _ in pyogrio.list_layers(path)}
    except Exception as exc:  # pyogrio raises its own DataSourceError family
        raise TerrainImportError(f"{path}: not a readable S-57 chart ({exc})") from None

    def read(layer: str, fields: tuple[str, ...]) -> list[tuple[Shapes, dict[str, float]]]:
        if layer not in layers:
            return []
        meta, _, geoms, data = raw.read(path, layer=layer)
        names = [str(n) for n in meta["fields"]]
        out = []
        for k, g in enumerate(geoms):
            attrs = {}
            for f in fields:
                if f in names:
                    v = data[names.index(f)][k]
                    attrs[f] = float(v) if v is not None and not np.ma.is_masked(v) else math.nan
            out.append((parse_wkb(g), attrs))
        return out

    soundings = read("SOUNDG", ())
    contours = read("DEPCNT", ("VALDCO",))
    areas = read("DEPARE", ("DRVAL1", "DRVAL2"))
    land = read("LNDARE", ())
    lon: list[F64] = []
    lat: list[F64] = []
    for shapes, _ in soundings + contours + areas + land:
        for arr in [*shapes.points, *shapes.lines, *(r for p in shapes.polygons for r in p)]:
            lon.append(arr[:, 0])
            lat.append(arr[:, 1])
    if not lon:
        raise TerrainImportError(
            f"{path}: the chart has no SOUNDG, DEPCNT, DEPARE or LNDARE features "
            f"(layers: {', '.join(sorted(layers))})"
        )
    proj = _projection(np.concatenate(lon), np.concatenate(lat), options)

    pts: list[F64] = []  # rows (x, y, depth)
    for shapes, _ in soundings:
        for p in shapes.points:
            if p.shape[1] == 3:
                x, y = proj.forward(p[:, 0], p[:, 1])
                pts.append(np.column_stack([x, y, p[:, 2]]))
    n_soundings = sum(len(p) for p in pts)
    n_contours = 0
    for shapes, attrs in contours:
        depth = attrs.get("VALDCO", math.nan)
        if not math.isfinite(depth):
            continue
        for line in shapes.lines:
            x, y = proj.forward(line[:, 0], line[:, 1])
            xd, yd = _densify(x, y, spacing)
            pts.append(np.column_stack([xd, yd, np.full(len(xd), depth)]))
            n_contours += 1
    area_list: list[tuple[list[F64], float, float]] = []
    for shapes, attrs in areas:
        lo, hi = attrs.get("DRVAL1", math.nan), attrs.get("DRVAL2", math.nan)
        if not math.isfinite(lo):
            continue
        hi = hi if math.isfinite(hi) else lo
        for poly in shapes.polygons:
            rings = [np.column_stack(proj.forward(r[:, 0], r[:, 1])) for r in poly]
            area_list.append((rings, lo, hi))
    land_list: list[list[F64]] = []
    for shapes, _ in land:
        for poly in shapes.polygons:
            land_list.append([np.column_stack(proj.forward(r[:, 0], r[:, 1])) for r in poly])
    cloud = np.concatenate(pts) if pts else np.zeros((0, 3))
    how = f"azimuthal equidistant projection about {proj.lon0:.5f} E, {proj.lat0:.5f} N"
    desc = (
        f"S-57 chart {path.name} ({n_soundings} soundings, {n_contours} contours, "
        f"{len(area_list)} depth areas, {len(land_list)} land areas; {how})"
    )
    return _Source(
        "points",
        "depth",
        desc,
        x=cloud[:, 0],
        y=cloud[:, 1],
        values=cloud[:, 2],
        areas=area_list,
        land=land_list,
    )


def _densify(x: F64, y: F64, spacing: float) -> tuple[F64, F64]:
    """Vertices of a polyline with extra points so none are more than ``spacing`` apart."""
    xs, ys = [x[:1]], [y[:1]]
    for k in range(1, len(x)):
        seg = math.hypot(x[k] - x[k - 1], y[k] - y[k - 1])
        n = max(1, math.ceil(seg / spacing))
        t = np.arange(1, n + 1) / n
        xs.append(x[k - 1] + (x[k] - x[k - 1]) * t)
        ys.append(y[k - 1] + (y[k] - y[k - 1]) * t)
    return np.concatenate(xs), np.concatenate(ys)


def _read_npz(path: Path, options: ImportOptions) -> _Source:
    try:
        hm = HeightMap.load(path)
    except (ValueError, KeyError) as exc:
        raise TerrainImportError(str(exc)) from None
    x, y = hm.geometry.centres()
    raster, _ = _raster(y, x, np.array(hm.depth), options, False)
    return _Source("raster", "depth", f"height map {path.name} ({hm.source})", raster=raster)


# --- gridding -----------------------------------------------------------------------------------


def _nearest_fill(values: F64) -> F64:
    """Replace NaN cells by the value of the nearest finite cell."""
    holes = ~np.isfinite(values)
    if not holes.any():
        return values
    idx = ndimage.distance_transform_edt(holes, return_distances=False, return_indices=True)
    result: F64 = values[tuple(idx)]
    return result


def _fill_raster_holes(x: F64, y: F64, values: F64) -> tuple[F64, int]:
    """Fill NaN cells by linear interpolation from the valid cells bordering the holes.

    ``x`` and ``y`` are the local coordinates [m] of every cell, shaped like ``values``.
    """
    holes = ~np.isfinite(values)
    n = int(holes.sum())
    if n == 0:
        return values, 0
    if n == values.size:
        raise TerrainImportError("the source holds no valid values (every cell is nodata)")
    border = ndimage.binary_dilation(holes, structure=np.ones((3, 3), dtype=bool)) & ~holes
    bi, bj = np.nonzero(border)
    hi, hj = np.nonzero(holes)
    out = values.copy()
    try:
        filled = interpolate.griddata(
            np.column_stack([x[bi, bj], y[bi, bj]]),
            values[bi, bj],
            np.column_stack([x[hi, hj], y[hi, hj]]),
            method="linear",
        )
        out[hi, hj] = filled
    except (ValueError, RuntimeError):  # too few or collinear border cells: nearest only
        pass
    return _nearest_fill(out), n


def _rings_mask(rings: list[F64], px: F64, py: F64) -> npt.NDArray[np.bool_]:
    from matplotlib.path import Path as MplPath

    pts = np.column_stack([px, py])
    inside = MplPath(rings[0][:, :2]).contains_points(pts)
    for hole in rings[1:]:
        inside &= ~MplPath(hole[:, :2]).contains_points(pts)
    return inside


def _extents(src: _Source, target: GridGeometry, anchor_at: tuple[float, float], scale: float) -> str:
    """Where the data and the grid lie, in grid coordinates, as text."""
    if src.raster is not None:
        lx, ly = src.raster.local_centres()
    else:
        lx, ly = src.x, src.y
    x0, x1 = anchor_at[0] + scale * float(np.min(lx)), anchor_at[0] + scale * float(np.max(lx))
    y0, y1 = anchor_at[1] + scale * float(np.min(ly)), anchor_at[1] + scale * float(np.max(ly))
    gx0, gx1, gy0, gy1 = target.extent
    return (
        f"data x {x0:.0f}..{x1:.0f} m, y {y0:.0f}..{y1:.0f} m; "
        f"grid x {gx0:.0f}..{gx1:.0f} m, y {gy0:.0f}..{gy1:.0f} m"
    )


def _grid_source(
    src: _Source, target: GridGeometry, anchor_at: tuple[float, float], scale: float
) -> tuple[F64, float, int, npt.NDArray[np.bool_]]:
    """Grid a source onto ``target``.

    Returns:
        Raw values ``(nx, ny)``, coverage, number of holes filled, and the land mask.
    """
    gx, gy = target.centres()
    sx = (gx - anchor_at[0]) / scale  # source-local coordinates of the target cell centres
    sy = (gy - anchor_at[1]) / scale
    holes = 0
    qx, qy = np.meshgrid(sx, sy, indexing="ij")
    if src.raster is not None:
        r = src.raster
        if len(r.u) < 2 or len(r.v) < 2:
            raise TerrainImportError(f"{src.description}: the raster must have at least 2 x 2 cells")
        cx, cy = r.local_centres()
        vals, holes = _fill_raster_holes(cx, cy, r.values)
        # low-pass a raster much finer than the target (anti-aliasing)
        dx_src = float(np.median(np.hypot(np.diff(cx, axis=0), np.diff(cy, axis=0)))) * scale
        dy_src = float(np.median(np.hypot(np.diff(cx, axis=1), np.diff(cy, axis=1)))) * scale
        sigma = (
            0.5 * target.resolution / dx_src if target.resolution > 1.5 * dx_src else 0.0,
            0.5 * target.resolution / dy_src if target.resolution > 1.5 * dy_src else 0.0,
        )
        if max(sigma) > 0.0:
            vals = ndimage.gaussian_filter(vals, sigma=sigma, mode="nearest")
        rgi = interpolate.RegularGridInterpolator(
            (r.u, r.v), vals, method="linear", bounds_error=False, fill_value=np.nan
        )
        qu, qv = r.to_native(qx, qy)
        out = rgi(np.stack([qu, qv], axis=-1))
    else:
        if len(src.x) >= 3:
            try:
                out = interpolate.griddata(
                    np.column_stack([src.x, src.y]), src.values, (qx, qy), method="linear"
                )
            except (ValueError, RuntimeError):  # collinear soundings: nearest only
                out = interpolate.griddata(
                    np.column_stack([src.x, src.y]), src.values, (qx, qy), method="nearest"
                )
        elif src.areas:
            out = np.full(qx.shape, np.nan)
        else:
            raise TerrainImportError(f"{src.description}: fewer than 3 depth values to grid")
    coverage = float(np.isfinite(out).mean())
    if src.areas:
        lo = np.full(out.shape, -np.inf)
        hi = np.full(out.shape, np.inf)
        mid = np.full(out.shape, np.nan)
        for rings, d1, d2 in src.areas:
            inside = _rings_mask(rings, qx.ravel(), qy.ravel()).reshape(out.shape)
            lo[inside] = d1
            hi[inside] = d2
            mid[inside] = 0.5 * (d1 + d2)
        # areas inform the coverage, give depth where there are no soundings, and bound it
        coverage = float((np.isfinite(out) | np.isfinite(mid)).mean())
        out = np.where(np.isfinite(out), out, mid)
        out = np.clip(out, lo, hi)
    if coverage == 0.0:
        raise TerrainImportError(
            f"{src.description}: the data do not overlap the grid at all "
            f"({_extents(src, target, anchor_at, scale)}); move the anchor or change horizontal_scale"
        )
    out = _nearest_fill(out)
    land = np.zeros(out.shape, dtype=np.bool_)
    for rings in src.land:
        land |= _rings_mask(rings, qx.ravel(), qy.ravel()).reshape(out.shape)
    return out, coverage, holes, land


def _read(
    path: Path, fmt: str, options: ImportOptions, target: GridGeometry | None, spacing: float
) -> _Source:
    if fmt == "geotiff":
        return _read_geotiff(path, options)
    if fmt == "esri_ascii":
        return _read_esri_ascii(path, options)
    if fmt == "png":
        return _read_png(path, options, target, options.horizontal_scale)
    if fmt == "xyz":
        return _read_xyz(path, options)
    if fmt == "s57":
        return _read_s57(path, options, spacing)
    if fmt == "npz":
        return _read_npz(path, options)
    raise TerrainImportError(f"unknown terrain format {fmt!r}; valid: auto, {', '.join(FORMATS)}")


def _to_depth(raw: F64, values_kind: str, options: ImportOptions) -> F64:
    sign = 1.0 if values_kind == "depth" else -1.0
    result: F64 = options.vertical_offset + options.vertical_scale * sign * raw
    return result


def import_terrain(
    path: str | Path,
    geometry: GridGeometry | None = None,
    *,
    resolution: float | None = None,
    format: Format = "auto",
    options: ImportOptions | None = None,
    anchor_at: tuple[float, float] | None = None,
    min_coverage: float = 0.5,
) -> ImportResult:
    """Read a terrain source and grid it into a hole-free :class:`HeightMap`.

    Args:
        path: The source file.
        geometry: The grid to fill (a scenario's site). ``None``: a grid covering the whole
            source (in local metres about its anchor, times ``horizontal_scale``) at
            ``resolution``.
        resolution: Cell size [m] when ``geometry`` is ``None`` (default: the source raster's
            own cell size, or for points the size that gives about one cell per sounding).
        format: One of :data:`FORMATS` or ``"auto"`` (by suffix).
        options: Value and coordinate conversion (see :class:`ImportOptions`).
        anchor_at: Where on the grid the source's anchor lands [m] (default: the grid's
            centre, or ``(0, 0)`` when the grid is made to fit the source).
        min_coverage: Smallest fraction of the grid the data must cover (the rest is filled
            with the nearest value); below it the import fails.

    Raises:
        FileNotFoundError: The file does not exist.
        TerrainImportError: Unreadable file, bad content, or too little coverage.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"terrain file {path} does not exist")
    opts = options if options is not None else ImportOptions()
    fmt = detect_format(path) if format == "auto" else format
    if fmt not in FORMATS:
        raise TerrainImportError(f"unknown terrain format {fmt!r}; valid: auto, {', '.join(FORMATS)}")
    spacing_hint = (
        geometry.resolution if geometry is not None else (resolution or 1.0)
    ) / opts.horizontal_scale
    if fmt == "png" and geometry is None and opts.pixel_size is None:
        raise TerrainImportError(f"{path}: a PNG has no georeference; give its pixel size in metres")
    src = _read(path, fmt, opts, geometry, spacing_hint)
    values_kind = src.values_kind if opts.values == "auto" else opts.values
    scale = opts.horizontal_scale
    if geometry is None:
        if src.raster is not None:
            cx, cy = src.raster.local_centres()
            native = scale * min(
                float(np.median(np.hypot(np.diff(cx, axis=0), np.diff(cy, axis=0)))),
                float(np.median(np.hypot(np.diff(cx, axis=1), np.diff(cy, axis=1)))),
            )
            x_lo, x_hi, y_lo, y_hi = float(cx.min()), float(cx.max()), float(cy.min()), float(cy.max())
        else:
            allx = np.concatenate([src.x, *[r[:, 0] for a in src.areas for r in a[0]]])
            ally = np.concatenate([src.y, *[r[:, 1] for a in src.areas for r in a[0]]])
            x_lo, x_hi, y_lo, y_hi = (
                float(allx.min()),
                float(allx.max()),
                float(ally.min()),
                float(ally.max()),
            )
            n = max(len(src.x), 1)
            native = math.sqrt(max((x_hi - x_lo) * (y_hi - y_lo), 1e-9) / n) * scale
        res = float(resolution) if resolution is not None else native
        if not (res > 0.0 and math.isfinite(res)):
            raise TerrainImportError(f"resolution must be a positive number of metres, got {res}")
        nx = max(2, math.floor((x_hi - x_lo) * scale / res) + 1)
        ny = max(2, math.floor((y_hi - y_lo) * scale / res) + 1)
        if nx * ny > 50_000_000:
            raise TerrainImportError(f"a {nx} x {ny} grid is too large; choose a coarser resolution")
        geometry = GridGeometry(origin=(x_lo * scale, y_lo * scale), resolution=res, shape=(nx, ny))
        at = anchor_at if anchor_at is not None else (0.0, 0.0)
    else:
        x_min, x_max, y_min, y_max = geometry.extent
        at = anchor_at if anchor_at is not None else (0.5 * (x_min + x_max), 0.5 * (y_min + y_max))
    raw, coverage, holes, land = _grid_source(src, geometry, at, scale)
    if coverage < min_coverage:
        raise TerrainImportError(
            f"{src.description}: the data cover only {100 * coverage:.0f}% of the grid (need "
            f"{100 * min_coverage:.0f}%: {_extents(src, geometry, at, scale)}); "
            "move the anchor or change horizontal_scale"
        )
    depth = _to_depth(raw, values_kind, opts)
    depth[land] = np.minimum(depth[land], LAND_DEPTH)
    scale_text = f", horizontal scale {scale:g}" if scale != 1.0 else ""
    sign = "-" if values_kind == "elevation" else ""
    if opts.vertical_scale == 1.0 and opts.vertical_offset == 0.0:
        vert = ", depth = -elevation" if sign else ""
    else:
        vert = f", depth = {opts.vertical_offset:g} + {opts.vertical_scale:g} x {sign}value"
    description = f"{src.description}{scale_text}{vert}"
    hm = HeightMap(geometry=geometry, depth=depth, source=description)
    return ImportResult(heightmap=hm, coverage=coverage, holes_filled=holes, description=description)


def import_heightmap(
    path: str | Path,
    geometry: GridGeometry | None = None,
    *,
    resolution: float | None = None,
    format: Format = "auto",
    options: ImportOptions | None = None,
    anchor_at: tuple[float, float] | None = None,
) -> HeightMap:
    """Shorthand for ``import_terrain(...).heightmap`` (see :func:`import_terrain`)."""
    return import_terrain(
        path, geometry, resolution=resolution, format=format, options=options, anchor_at=anchor_at
    ).heightmap


def save_heightmap(heightmap: HeightMap, path: str | Path) -> Path:
    """Write a height map as ``.npz`` (:meth:`HeightMap.save`) or GeoTIFF (``.tif``).

    The GeoTIFF holds depth [m, positive down] as float32 in local metres (no CRS; the tag
    ``HPTVSIM_VALUES=depth`` tells :func:`import_terrain` the values are depths).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".npz":
        return heightmap.save(path)
    if suffix not in FORMATS["geotiff"]:
        raise ValueError(f"height maps are written as .npz or .tif, got {path.name!r}")
    import rasterio
    from rasterio.transform import Affine

    g = heightmap.geometry
    _x_min, x_max, y_min, _y_max = g.extent
    transform = Affine(g.resolution, 0.0, y_min, 0.0, -g.resolution, x_max)  # west edge, north edge
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        height=g.shape[0],
        width=g.shape[1],
        count=1,
        dtype="float32",
        transform=transform,
    ) as dst:
        dst.write(heightmap.depth[::-1, :].astype(np.float32), 1)
        dst.update_tags(HPTVSIM_VALUES="depth", HPTVSIM_FORMAT=HEIGHTMAP_FORMAT, SOURCE=heightmap.source)
    return path
