"""Swath footprints as GeoJSON (RFC 7946): one Feature per segment.

The outline runs along the first valid pixel of every line, across the last line, back along
the last valid pixel of every line and across the first line; each side is thinned by
Douglas–Peucker to `tolerance_m`, so the polygon holds every IGM position to within that
distance while staying small. Coordinates are WGS 84 longitude/latitude, exterior ring
counter-clockwise, as RFC 7946 requires.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from postproc.products.igm import IgmSource, iter_igm_blocks, projected_crs
from sisa.core.errors import InputError
from sisa.core.outdir import write_whole

F64 = npt.NDArray[np.float64]

TOLERANCE_M: Final = 0.5
COORD_DECIMALS: Final = 9  # degrees: 0.1 mm


@dataclass(frozen=True)
class Footprint:
    ring_m: F64  # (k, 2) easting/northing, closed, counter-clockwise; empty if < 2 lines
    lines: int
    first_line: int  # 0-based, first line with a ground position (-1 if none)
    last_line: int


class _Edges:
    """The two long sides of the outline (first and last valid pixel of every line) and the
    first and last lines whole. Where the edge pixel steps inwards or outwards from one line to
    the next, a corner is added on the line that reaches further out, so the pixels exposed by
    the step (e.g. beside a DEM miss) stay inside."""

    def __init__(self) -> None:
        self.left: list[F64] = []
        self.right: list[F64] = []
        self.first_xy: F64 = np.zeros((0, 2))
        self.last_xy: F64 = np.zeros((0, 2))
        self.first = self.last = -1
        self.lines = 0
        self._prev: tuple[F64, F64, npt.NDArray[np.bool_]] | None = None  # last valid line

    def add(self, lo: int, blk: F64) -> None:
        e, n = blk[:, 0], blk[:, 1]
        ok = np.isfinite(e) & np.isfinite(n)
        self.lines = lo + blk.shape[0]
        rows = np.flatnonzero(ok.any(axis=1))
        if rows.size == 0:
            return
        if self.first < 0:
            self.first = lo + int(rows[0])
            self.first_xy = np.stack([e[rows[0]], n[rows[0]]], axis=1)[ok[rows[0]]]
        self.last = lo + int(rows[-1])
        self.last_xy = np.stack([e[rows[-1]], n[rows[-1]]], axis=1)[ok[rows[-1]]]
        e, n, ok = e[rows], n[rows], ok[rows]
        fresh = 0
        if self._prev is not None:  # carry the previous block's last valid line
            e, n, ok = (np.concatenate([p[None], a]) for p, a in zip(self._prev, (e, n, ok),
                                                                      strict=True))
            fresh = 1
        self._prev = (e[-1], n[-1], ok[-1])
        jf = np.argmax(ok, axis=1)
        jl = ok.shape[1] - 1 - np.argmax(ok[:, ::-1], axis=1)
        self.left.append(_side(e, n, ok, jf, inward=1, skip=fresh))
        self.right.append(_side(e, n, ok, jl, inward=-1, skip=fresh))


def _side(e: F64, n: F64, ok: npt.NDArray[np.bool_], j: npt.NDArray[np.intp], *, inward: int,
          skip: int) -> F64:
    """Edge point of each line (edge pixel j), preceded by the corner of the step from the
    line before where j changes; the first `skip` lines' points are left out."""
    m = j.size
    lines = np.arange(m)
    edge = np.stack([e[lines, j], n[lines, j]], axis=1)
    corner = np.full((m, 2), np.nan)
    if m > 1:
        a, b = lines[:-1], lines[1:]
        step_in = (j[1:] - j[:-1]) * inward > 0  # the next line starts further in
        at_line = np.where(step_in, a, b)
        at_pix = np.where(step_in, j[1:], j[:-1])
        good = ok[at_line, at_pix] & (j[1:] != j[:-1])
        corner[1:][good] = np.stack([e[at_line, at_pix], n[at_line, at_pix]], axis=1)[good]
    both: F64 = np.stack([corner, edge], axis=1).reshape(-1, 2)
    keep = np.isfinite(both).all(axis=1) & (np.repeat(lines, 2) >= skip)
    out: F64 = both[keep]
    return out


def simplify(points: F64, tolerance_m: float) -> F64:
    """Douglas–Peucker: keep the ends and every point needed to stay within tolerance."""
    n = points.shape[0]
    if n <= 2:
        return points
    keep = np.zeros(n, dtype=bool)
    keep[[0, -1]] = True
    stack = [(0, n - 1)]
    while stack:
        a, b = stack.pop()
        if b <= a + 1:
            continue
        chord = points[b] - points[a]
        rel = points[a + 1:b] - points[a]
        length = math.hypot(*chord)
        dist = (np.abs(chord[0] * rel[:, 1] - chord[1] * rel[:, 0]) / length if length > 0
                else np.hypot(rel[:, 0], rel[:, 1]))
        k = int(np.argmax(dist))
        if dist[k] > tolerance_m:
            m = a + 1 + k
            keep[m] = True
            stack += [(a, m), (m, b)]
    return points[keep]


def signed_area(ring: F64) -> float:
    """Shoelace area of a closed ring (n + 1, 2), first point repeated last: > 0 when it runs
    counter-clockwise (RFC 7946's exterior rings)."""
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]))


def footprint_polygon(igm: IgmSource, *, tolerance_m: float = TOLERANCE_M) -> Footprint:
    """The swath outline of an IGM (file, read by blocks, or array (lines, 3, pixels))."""
    if not tolerance_m > 0:
        raise InputError(f"footprint tolerance must be positive, got {tolerance_m} m")
    edges = _Edges()
    for lo, blk in iter_igm_blocks(igm):
        edges.add(lo, blk)
    if edges.first < 0 or edges.first == edges.last:
        return Footprint(np.zeros((0, 2)), edges.lines, edges.first, edges.last)
    sides = [simplify(np.concatenate(edges.left), tolerance_m),
             simplify(edges.last_xy, tolerance_m),
             simplify(np.concatenate(edges.right)[::-1], tolerance_m),
             simplify(edges.first_xy[::-1], tolerance_m)]
    ring = np.concatenate([s[:-1] for s in sides] + [sides[0][:1]])
    if signed_area(ring) < 0:
        ring = ring[::-1].copy()
    return Footprint(ring, edges.lines, edges.first, edges.last)


def footprint_feature(igm: IgmSource, epsg: int, *, properties: Mapping[str, Any] | None = None,
                      tolerance_m: float = TOLERANCE_M) -> dict[str, Any]:
    """A GeoJSON Feature of the swath: lon/lat polygon (null if fewer than two lines have
    positions) and properties lines, first_line, last_line, area_m2 (on the WGS 84
    ellipsoid), then `properties`; with t_first_gps_ns/t_last_gps_ns ≥ 0 also duration_s."""
    projected_crs(epsg)  # a projected CRS, or the InputError saying why not
    fp = footprint_polygon(igm, tolerance_m=tolerance_m)
    props: dict[str, Any] = {"lines": fp.lines, "first_line": fp.first_line,
                             "last_line": fp.last_line, "area_m2": 0.0}
    geometry: dict[str, Any] | None = None
    if fp.ring_m.shape[0] >= 4:
        # here, not at the top: every user of postproc.products imports this module, and
        # pyproj's import cost `sisa ortho`, which never needs it, ~0.05 s
        from pyproj import Geod, Transformer

        to_geo = Transformer.from_crs(int(epsg), 4326, always_xy=True)
        lon, lat = to_geo.transform(fp.ring_m[:, 0], fp.ring_m[:, 1])
        lon = np.round(np.asarray(lon), COORD_DECIMALS)
        lat = np.round(np.asarray(lat), COORD_DECIMALS)
        if signed_area(np.stack([lon, lat], axis=1)) < 0:
            lon, lat = lon[::-1], lat[::-1]
        area, _ = Geod(ellps="WGS84").polygon_area_perimeter(lon[:-1], lat[:-1])
        props["area_m2"] = round(abs(float(area)), 1)
        geometry = {"type": "Polygon",
                    "coordinates": [[[float(a), float(b)] for a, b in zip(lon, lat, strict=True)]]}
    props.update(properties or {})
    t0, t1 = props.get("t_first_gps_ns"), props.get("t_last_gps_ns")
    if isinstance(t0, int) and isinstance(t1, int) and 0 <= t0 <= t1:
        props["duration_s"] = (t1 - t0) / 1e9
    return {"type": "Feature", "geometry": geometry, "properties": props}


def write_footprints_geojson(path: Path, features: Sequence[Mapping[str, Any]]) -> None:
    """A FeatureCollection (no `crs` member: RFC 7946 is always WGS 84), written whole."""
    for f in features:
        if f.get("type") != "Feature":
            raise InputError(f"{path}: not a GeoJSON Feature: {str(f)[:80]}")
    doc = {"type": "FeatureCollection", "features": [_json_safe(dict(f)) for f in features]}
    path = Path(path)
    write_whole(path, json.dumps(doc, allow_nan=False) + "\n")


def _json_safe(value: Any) -> Any:
    """NaN and infinities have no JSON form: they become null."""
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value
