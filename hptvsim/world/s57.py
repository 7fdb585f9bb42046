"""Writing small S-57 electronic navigational charts with GDAL's own S-57 writer.

Reading charts needs only pyogrio (see :mod:`hptvsim.world.importers`). Writing them is for
tests, examples and shipped sample charts: GDAL's S-57 driver can create a chart (it writes the
ISO 8211 data descriptive record and the feature and vector records), but pyogrio cannot drive
it, because the driver pre-creates one layer per S-57 object class instead of letting callers
create layers. So this module calls the few GDAL C functions it needs through :mod:`ctypes`,
on the GDAL library that pyogrio's wheel bundles (or a system ``libgdal``).

What :func:`write_s57_chart` writes, in the chain-node topology of S-57 ed. 3.1 (IHO S-57,
Part 3, ch. 4 and 7):

* ``SOUNDG`` soundings: one isolated node holding a 3-D coordinate array (``SG3D``, depth in
  metres, positive down) and a point feature pointing at it;
* ``DEPCNT`` depth contours: each line an edge between two connected nodes, a line feature
  with its ``VALDCO`` (contour depth [m]);
* ``DEPARE`` depth areas: each ring one closed edge, an area feature with ``DRVAL1`` and
  ``DRVAL2`` (shallowest and deepest depth in the area [m]);
* ``LNDARE`` land areas: like depth areas, without depths.

Coordinates are WGS84 longitude/latitude [deg] (S-57 ENCs always are), stored as integers
scaled by ``COMF = 1e7`` (1e-7 deg, about 1 cm); soundings by ``SOMF = 10`` (0.1 m), so a
written depth reads back within 0.05 m.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import glob
import os
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["ChartArea", "ChartContour", "ChartLand", "S57WriteError", "gdal_library", "write_s57_chart"]

F64 = npt.NDArray[np.float64]

# S-57 record names (RCNM) and object classes (OBJL), IHO S-57 Appendix A
_RCNM_VI, _RCNM_VC, _RCNM_VE = 110, 120, 130
_OBJL = {"DEPARE": 42, "DEPCNT": 43, "LNDARE": 71, "SOUNDG": 129}
_PRIM_POINT, _PRIM_LINE, _PRIM_AREA = 1, 2, 3
_AGEN = 550  # producing agency code used for the sample charts (IHO agency list: "US" is 550)


class S57WriteError(RuntimeError):
    """GDAL could not be found or failed to write the chart."""


@dataclass(frozen=True, kw_only=True)
class ChartContour:
    """A depth contour: a line of equal depth.

    Attributes:
        lonlat: ``(n, 2)`` vertices, longitude and latitude [deg].
        depth: Contour depth ``VALDCO`` [m], positive down.
    """

    lonlat: F64
    depth: float


@dataclass(frozen=True, kw_only=True)
class ChartArea:
    """A depth area: the seabed within it lies between two depths.

    Attributes:
        ring: ``(n, 2)`` vertices of the closed boundary, longitude and latitude [deg] (the
            last vertex may repeat the first).
        drval1: Shallowest depth in the area [m].
        drval2: Deepest depth in the area [m].
    """

    ring: F64
    drval1: float
    drval2: float
    holes: tuple[F64, ...] = field(default=())


@dataclass(frozen=True, kw_only=True)
class ChartLand:
    """A land area (above the sea surface).

    Attributes:
        ring: ``(n, 2)`` vertices of the closed boundary, longitude and latitude [deg].
        holes: Rings of water inside the land (lakes, lagoons), same form.
    """

    ring: F64
    holes: tuple[F64, ...] = field(default=())


def _candidate_libraries() -> list[str]:
    found: list[str] = []
    try:
        import pyogrio

        base = Path(pyogrio.__file__).resolve().parent
        for pattern in (
            "../pyogrio.libs/libgdal*",
            ".dylibs/libgdal*",
            "../pyogrio.libs/gdal*.dll",
            "gdal*.dll",
        ):
            found += sorted(glob.glob(str(base / pattern)))
    except ImportError:
        pass
    system = ctypes.util.find_library("gdal")
    if system:
        found.append(system)
    return found


_LIB: Any = None


def gdal_library() -> Any:
    """Load (once) the GDAL C library with the prototypes this module uses.

    Raises:
        S57WriteError: No GDAL library with the S-57 driver was found.
    """
    global _LIB
    if _LIB is not None:
        return _LIB
    with contextlib.suppress(ImportError):
        import pyogrio  # noqa: F401  (loads its GDAL and sets GDAL_DATA, which S-57 needs)
    errors = []
    for path in _candidate_libraries():
        try:
            lib = ctypes.CDLL(path)
        except OSError as exc:
            errors.append(f"{path}: {exc}")
            continue
        _prototype(lib)
        lib.GDALAllRegister()
        if lib.GDALGetDriverByName(b"S57"):
            _LIB = lib
            return lib
        errors.append(f"{path}: no S57 driver")
    tried = "; ".join(errors) if errors else "no libgdal found next to pyogrio or on the system"
    raise S57WriteError(f"cannot write S-57 charts: {tried} (install pyogrio: pip install 'hptvsim[world]')")


def _prototype(lib: Any) -> None:
    vp = ctypes.c_void_p
    sigs: dict[str, tuple[Any, list[Any]]] = {
        "GDALAllRegister": (None, []),
        "GDALGetDriverByName": (vp, [ctypes.c_char_p]),
        "GDALCreate": (
            vp,
            [vp, ctypes.c_char_p, ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_void_p],
        ),
        "GDALDatasetGetLayerByName": (vp, [vp, ctypes.c_char_p]),
        "GDALClose": (ctypes.c_int, [vp]),
        "OGR_L_GetLayerDefn": (vp, [vp]),
        "OGR_FD_GetFieldIndex": (ctypes.c_int, [vp, ctypes.c_char_p]),
        "OGR_F_Create": (vp, [vp]),
        "OGR_F_SetFieldInteger": (None, [vp, ctypes.c_int, ctypes.c_int]),
        "OGR_F_SetFieldDouble": (None, [vp, ctypes.c_int, ctypes.c_double]),
        "OGR_F_SetFieldIntegerList": (None, [vp, ctypes.c_int, ctypes.c_int, ctypes.POINTER(ctypes.c_int)]),
        "OGR_G_CreateFromWkb": (ctypes.c_int, [ctypes.c_char_p, vp, ctypes.POINTER(vp), ctypes.c_int]),
        "OGR_F_SetGeometryDirectly": (ctypes.c_int, [vp, vp]),
        "OGR_L_CreateFeature": (ctypes.c_int, [vp, vp]),
        "OGR_F_Destroy": (None, [vp]),
        "CPLGetLastErrorMsg": (ctypes.c_char_p, []),
    }
    for name, (restype, argtypes) in sigs.items():
        fn = getattr(lib, name)
        fn.restype = restype
        fn.argtypes = argtypes


def _wkb_point(x: float, y: float) -> bytes:
    return struct.pack("<BIdd", 1, 1, x, y)


def _wkb_multipoint_z(pts: F64) -> bytes:
    parts = [struct.pack("<BII", 1, 1004, len(pts))]
    parts += [struct.pack("<BIddd", 1, 1001, float(x), float(y), float(z)) for x, y, z in pts]
    return b"".join(parts)


def _wkb_linestring(pts: F64) -> bytes:
    return struct.pack("<BII", 1, 2, len(pts)) + np.ascontiguousarray(pts, dtype="<f8").tobytes()


class _ChartWriter:
    def __init__(self, lib: Any, path: Path) -> None:
        self.lib = lib
        driver = lib.GDALGetDriverByName(b"S57")
        self.ds = lib.GDALCreate(driver, os.fsencode(path), 0, 0, 0, 0, None)
        if not self.ds:
            raise S57WriteError(f"GDAL could not create {path}: {self._last_error()}")
        self.next_rcid = {"node": 1, "edge": 1, "feature": 1}

    def _last_error(self) -> str:
        msg = self.lib.CPLGetLastErrorMsg()
        return msg.decode(errors="replace") if msg else "no message"

    def rcid(self, what: str) -> int:
        value = self.next_rcid[what]
        self.next_rcid[what] += 1
        return value

    def add(self, layer: str, values: dict[str, int | float | list[int]], wkb: bytes | None = None) -> None:
        lib = self.lib
        lyr = lib.GDALDatasetGetLayerByName(self.ds, layer.encode())
        if not lyr:
            raise S57WriteError(f"the S-57 driver has no layer {layer!r}")
        defn = lib.OGR_L_GetLayerDefn(lyr)
        feat = lib.OGR_F_Create(defn)
        try:
            for name, value in values.items():
                idx = lib.OGR_FD_GetFieldIndex(defn, name.encode())
                if idx < 0:
                    raise S57WriteError(f"S-57 layer {layer!r} has no field {name!r}")
                if isinstance(value, list):
                    arr = (ctypes.c_int * len(value))(*value)
                    lib.OGR_F_SetFieldIntegerList(feat, idx, len(value), arr)
                elif isinstance(value, float):
                    lib.OGR_F_SetFieldDouble(feat, idx, value)
                else:
                    lib.OGR_F_SetFieldInteger(feat, idx, int(value))
            if wkb is not None:
                geom = ctypes.c_void_p()
                if lib.OGR_G_CreateFromWkb(wkb, None, ctypes.byref(geom), len(wkb)) != 0:
                    raise S57WriteError(f"GDAL rejected a geometry for {layer}: {self._last_error()}")
                lib.OGR_F_SetGeometryDirectly(feat, geom)
            if lib.OGR_L_CreateFeature(lyr, feat) != 0:
                raise S57WriteError(f"GDAL failed to write a {layer} record: {self._last_error()}")
        finally:
            lib.OGR_F_Destroy(feat)

    def feature(
        self, objl: str, prim: int, refs: list[tuple[int, int, int, int]], attrs: dict[str, float]
    ) -> None:
        rcid = self.rcid("feature")
        values: dict[str, int | float | list[int]] = {
            "RCID": rcid,
            "PRIM": prim,
            "GRUP": 2 if objl == "SOUNDG" else 1,
            "OBJL": _OBJL[objl],
            "AGEN": _AGEN,
            "FIDN": rcid,
            "FIDS": 1,
            "NAME_RCNM": [r[0] for r in refs],
            "NAME_RCID": [r[1] for r in refs],
            "ORNT": [r[2] for r in refs],
            "USAG": [r[3] for r in refs],
            "MASK": [255] * len(refs),
        }
        values.update(attrs)
        self.add(objl, values)

    def edge(self, pts: F64, closed: bool) -> int:
        """Write the nodes and the edge of a line (or a closed ring); return the edge RCID."""
        start = self.rcid("node")
        self.add("ConnectedNode", {"RCNM": _RCNM_VC, "RCID": start}, _wkb_point(*pts[0]))
        if closed:
            end, interior = start, pts[1:-1]
        else:
            end = self.rcid("node")
            self.add("ConnectedNode", {"RCNM": _RCNM_VC, "RCID": end}, _wkb_point(*pts[-1]))
            interior = pts[1:-1]
        rcid = self.rcid("edge")
        links: dict[str, int | float | list[int]] = {"RCNM": _RCNM_VE, "RCID": rcid}
        for k, node in ((0, start), (1, end)):
            links.update(
                {
                    f"NAME_RCNM_{k}": _RCNM_VC,
                    f"NAME_RCID_{k}": node,
                    f"ORNT_{k}": 255,
                    f"USAG_{k}": 255,
                    f"TOPI_{k}": 1 + k,  # beginning node, end node
                    f"MASK_{k}": 255,
                }
            )
        self.add("Edge", links, _wkb_linestring(interior) if len(interior) else None)
        return rcid

    def close(self) -> None:
        if self.ds:
            self.lib.GDALClose(self.ds)
            self.ds = None


def _area_edges(writer: _ChartWriter, rings: Sequence[F64]) -> list[tuple[int, int, int, int]]:
    refs = []
    for k, ring_in in enumerate(rings):
        ring = np.asarray(ring_in, dtype=np.float64)
        if ring.ndim != 2 or ring.shape[1] != 2 or len(ring) < 3:
            raise ValueError(f"an area ring needs an (n >= 3, 2) array of lon/lat, got {ring.shape}")
        if not np.array_equal(ring[0], ring[-1]):
            ring = np.vstack([ring, ring[:1]])
        edge = writer.edge(ring, closed=True)
        refs.append((_RCNM_VE, edge, 1, 1 if k == 0 else 2))  # USAG 1 exterior, 2 interior
    return refs


def write_s57_chart(
    path: str | Path,
    *,
    soundings: npt.ArrayLike | None = None,
    contours: Sequence[ChartContour] = (),
    areas: Sequence[ChartArea] = (),
    land: Sequence[ChartLand] = (),
) -> Path:
    """Write an S-57 chart (``.000``) with soundings, depth contours and depth areas.

    Args:
        path: Output file (conventionally ``<cell name>.000``); overwritten.
        soundings: ``(n, 3)`` longitude [deg], latitude [deg], depth [m, positive down].
        contours: Depth contour lines.
        areas: Depth areas.
        land: Land areas.

    Returns:
        The path written.

    Raises:
        S57WriteError: GDAL is missing or rejected the data.
        ValueError: Malformed input (the message says which).
    """
    path = Path(path)
    lib = gdal_library()
    if path.exists():
        path.unlink()
    writer = _ChartWriter(lib, path)
    try:
        if soundings is not None:
            pts = np.asarray(soundings, dtype=np.float64)
            if pts.ndim != 2 or pts.shape[1] != 3:
                raise ValueError(f"soundings must have shape (n, 3) [lon, lat, depth], got {pts.shape}")
            if len(pts):
                node = writer.rcid("node")
                writer.add("IsolatedNode", {"RCNM": _RCNM_VI, "RCID": node}, _wkb_multipoint_z(pts))
                writer.feature("SOUNDG", _PRIM_POINT, [(_RCNM_VI, node, 255, 255)], {})
        for c in contours:
            line = np.asarray(c.lonlat, dtype=np.float64)
            if line.ndim != 2 or line.shape[1] != 2 or len(line) < 2:
                raise ValueError(f"a contour needs an (n >= 2, 2) array of lon/lat, got {line.shape}")
            edge = writer.edge(line, closed=False)
            writer.feature("DEPCNT", _PRIM_LINE, [(_RCNM_VE, edge, 1, 255)], {"VALDCO": float(c.depth)})
        for a in areas:
            refs = _area_edges(writer, (a.ring, *a.holes))
            writer.feature("DEPARE", _PRIM_AREA, refs, {"DRVAL1": float(a.drval1), "DRVAL2": float(a.drval2)})
        for land_area in land:
            writer.feature("LNDARE", _PRIM_AREA, _area_edges(writer, (land_area.ring, *land_area.holes)), {})
    finally:
        writer.close()
    return path
