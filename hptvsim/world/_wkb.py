"""A small reader of Well-Known Binary geometries (OGC 06-103r4, ISO and EWKB flavours).

pyogrio returns feature geometries as WKB; the chart importer needs only their coordinates,
so this reads points, line strings and polygons (and their multi- and collection forms) into
numpy arrays without a geometry library.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

__all__ = ["Shapes", "parse_wkb"]

F64 = npt.NDArray[np.float64]

_EWKB_Z = 0x80000000
_EWKB_M = 0x40000000
_EWKB_SRID = 0x20000000


@dataclass
class Shapes:
    """Coordinates of the parts of a geometry, by kind.

    Attributes:
        points: ``(n, d)`` arrays, one per point (``d`` = 2 or 3; z when the geometry has it).
        lines: ``(n, d)`` vertex arrays, one per line string.
        polygons: one list of rings per polygon (first ring exterior, then holes), each
            ring an ``(n, d)`` array.
    """

    points: list[F64] = field(default_factory=list)
    lines: list[F64] = field(default_factory=list)
    polygons: list[list[F64]] = field(default_factory=list)


class _Reader:
    def __init__(self, buf: bytes) -> None:
        self.buf = memoryview(buf)
        self.pos = 0

    def byte_order(self) -> str:
        order = self.buf[self.pos]
        self.pos += 1
        if order not in (0, 1):
            raise ValueError(f"bad WKB byte-order mark {order} at offset {self.pos - 1}")
        return "<" if order == 1 else ">"

    def uint32(self, endian: str) -> int:
        (value,) = struct.unpack_from(endian + "I", self.buf, self.pos)
        self.pos += 4
        return int(value)

    def coords(self, endian: str, n: int, dims: int) -> F64:
        count = n * dims
        arr = np.frombuffer(self.buf, dtype=endian + "f8", count=count, offset=self.pos)
        self.pos += 8 * count
        return arr.reshape(n, dims).astype(np.float64)


def _geometry(r: _Reader, out: Shapes) -> None:
    endian = r.byte_order()
    code = r.uint32(endian)
    has_z = bool(code & _EWKB_Z)
    has_m = bool(code & _EWKB_M)
    if code & _EWKB_SRID:
        r.uint32(endian)
    code &= 0x0FFFFFFF
    base = code % 1000
    iso_dims = code // 1000  # ISO: 1 Z, 2 M, 3 ZM
    has_z = has_z or iso_dims in (1, 3)
    has_m = has_m or iso_dims in (2, 3)
    dims = 2 + int(has_z) + int(has_m)
    keep = 3 if has_z else 2  # drop M

    def take(a: F64) -> F64:
        return np.ascontiguousarray(a[:, :keep])

    if base == 1:  # Point
        out.points.append(take(r.coords(endian, 1, dims)))
    elif base == 2:  # LineString
        n = r.uint32(endian)
        out.lines.append(take(r.coords(endian, n, dims)))
    elif base == 3:  # Polygon
        rings = []
        for _ in range(r.uint32(endian)):
            n = r.uint32(endian)
            rings.append(take(r.coords(endian, n, dims)))
        out.polygons.append(rings)
    elif base in (4, 5, 6, 7):  # Multi*, GeometryCollection: nested full geometries
        for _ in range(r.uint32(endian)):
            _geometry(r, out)
    else:
        raise ValueError(f"unsupported WKB geometry type {code}")


def parse_wkb(buf: bytes | None, into: Shapes | None = None) -> Shapes:
    """Read one WKB geometry (``None`` gives nothing) into ``into`` (or a new :class:`Shapes`)."""
    out = into if into is not None else Shapes()
    if buf is not None:
        _geometry(_Reader(bytes(buf)), out)
    return out
