"""What calibration measures: ground points, image observations of them, and line times.

    points = read_ground_points(Path("terrain/ground_points.csv"))   # control | check (| tie)
    obs = read_observations(Path("observations.csv"))                # id, segment, line, pixel
    clock = SegmentClock.from_line_times(sync_result.lines)          # t(segment, line)

Conventions: a line is the 0-based line of its segment's image and its time is the line's
mid-exposure; a fractional line is timed by linear interpolation between its two neighbouring
lines (both must be timed). A pixel is 0-based with pixel j the CENTRE of detector element j, so
the image edge is at −0.5. Ground points are WGS84 (lat/lon/ellipsoidal height, or a UTM
easting/northing with the EPSG named in a `#` comment) and held as ECEF metres.
"""

from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt
from pyproj import Transformer

from postproc.navigation import ecef_to_geodetic, geodetic_to_ecef
from postproc.sync import LineTimes
from postproc.syncconfig import TimeStatus
from sisa.errors import InputError

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
Str = npt.NDArray[np.str_]

KINDS: Final = ("control", "check", "tie")
OBS_COLUMNS: Final = ("id", "segment", "line", "pixel", "sigma_px")
OBS_HEADER: Final = (
    "# SISA image observations of ground points (postproc.calib_data; docs/calibration.md).\n"
    "# id: ground point id (the ground points file); segment: recording segment (one per strip)\n"
    "# line: 0-based image line of the segment, fractional (line k = mid-exposure of line k)\n"
    "# pixel: 0-based pixel across track, fractional (pixel j = centre of element j)\n"
    "# sigma_px: stated precision of both coordinates, pixels\n")


@dataclass(frozen=True)
class GroundPoints:
    """Surveyed (control, check) or unknown (tie: NaN coordinates) points, ECEF metres."""

    ids: Str
    kind: Str
    ecef_m: F64  # (P, 3)
    epsg: int | None = None  # the file's projected CRS, if it named one

    def __len__(self) -> int:
        return int(self.ids.size)

    def select(self, keep: npt.NDArray[np.bool_]) -> GroundPoints:
        return GroundPoints(self.ids[keep], self.kind[keep], self.ecef_m[keep], self.epsg)

    def index_of(self, ids: Str, where: str) -> I64:
        """Row of every id, or InputError naming the first unknown one."""
        lookup = {str(k): i for i, k in enumerate(self.ids.tolist())}
        missing = [str(i) for i in ids.tolist() if str(i) not in lookup]
        if missing:
            raise InputError(f"{where}: point '{missing[0]}' is not in the ground points file "
                             f"({len(missing)} unknown ids)")
        return np.array([lookup[str(i)] for i in ids.tolist()], dtype=np.int64)

    @staticmethod
    def concat(a: GroundPoints, b: GroundPoints) -> GroundPoints:
        dup = set(a.ids.tolist()) & set(b.ids.tolist())
        if dup:
            raise InputError(f"ground point id '{sorted(dup)[0]}' appears twice")
        return GroundPoints(np.concatenate([a.ids, b.ids]), np.concatenate([a.kind, b.kind]),
                            np.concatenate([a.ecef_m, b.ecef_m]), a.epsg or b.epsg)


@dataclass(frozen=True)
class ImageObservations:
    """One row per measurement of a point in a segment's image."""

    point_id: Str
    segment: I64
    line: F64
    pixel: F64
    sigma_px: F64

    def __len__(self) -> int:
        return int(self.point_id.size)

    def select(self, keep: npt.NDArray[np.bool_] | I64) -> ImageObservations:
        return ImageObservations(self.point_id[keep], self.segment[keep], self.line[keep],
                                 self.pixel[keep], self.sigma_px[keep])


def _rows(path: Path, what: str) -> tuple[list[str], list[list[str]], str]:
    """Header names, data rows and the comment text of a `#`-commented CSV."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise InputError(f"{path}: cannot read the {what}: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file ({what})") from None
    comments = "\n".join(ln for ln in text.splitlines() if ln.startswith("#"))
    body = [ln for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    if not body:
        raise InputError(f"{path}: empty {what}")
    rows = list(csv.reader(io.StringIO("\n".join(body))))
    header = [h.strip() for h in rows[0]]
    data = rows[1:]
    bad = next((k for k, r in enumerate(data) if len(r) != len(header)), None)
    if bad is not None:
        raise InputError(f"{path}: row {bad + 1} has {len(data[bad])} fields, the header "
                         f"{len(header)}")
    return header, data, comments


def _floats(path: Path, header: list[str], data: list[list[str]], name: str,
            may_be_nan: npt.NDArray[np.bool_] | None = None) -> F64:
    """A numeric column; every value finite except where may_be_nan (tie points)."""
    col = header.index(name)
    try:
        values = np.array([float(r[col]) for r in data], dtype=np.float64)
    except ValueError:
        raise InputError(f"{path}: column {name} holds a value that is not a number") from None
    bad = ~np.isfinite(values) & (True if may_be_nan is None else ~may_be_nan)
    if np.any(bad):
        raise InputError(f"{path}: column {name}, row {int(np.argmax(bad)) + 1}: not a finite "
                         "number")
    return values


def read_ground_points(path: Path) -> GroundPoints:
    """Columns id, kind and either lat_deg, lon_deg, height_m (WGS84, ellipsoidal) or
    easting_m, northing_m, height_m with 'EPSG:nnnnn' in a `#` comment."""
    header, data, comments = _rows(path, "ground points file")
    for need in ("id", "kind", "height_m"):
        if need not in header:
            raise InputError(f"{path}: no column '{need}' (need id, kind, lat_deg, lon_deg, "
                             "height_m)")
    m = re.search(r"EPSG:(\d+)", comments)
    epsg = int(m.group(1)) if m else None
    ids = np.array([r[header.index("id")].strip() for r in data])
    kind = np.array([r[header.index("kind")].strip().lower() for r in data])
    bad_kind = [k for k in kind.tolist() if k not in KINDS]
    if bad_kind:
        raise InputError(f"{path}: kind '{bad_kind[0]}' is not one of {', '.join(KINDS)}")
    if len(set(ids.tolist())) != ids.size:
        raise InputError(f"{path}: a point id appears twice")
    tie = kind == "tie"
    h = _floats(path, header, data, "height_m", tie)
    if "lat_deg" in header and "lon_deg" in header:
        lat = _floats(path, header, data, "lat_deg", tie)
        lon = _floats(path, header, data, "lon_deg", tie)
    elif "easting_m" in header and "northing_m" in header and epsg is not None:
        to_geo = Transformer.from_crs(epsg, 4326, always_xy=True)
        lon, lat = (np.asarray(v) for v in to_geo.transform(
            _floats(path, header, data, "easting_m", tie),
            _floats(path, header, data, "northing_m", tie)))
    else:
        raise InputError(f"{path}: need lat_deg and lon_deg, or easting_m and northing_m with "
                         "'EPSG:nnnnn' in a # comment")
    if np.any(np.abs(lat[~tie]) > 90.0):
        raise InputError(f"{path}: a latitude is outside ±90°")
    ecef = geodetic_to_ecef(lat, lon, h)
    ecef[tie] = np.nan  # a tie point's coordinates are unknowns, whatever the file says
    return GroundPoints(ids, kind, ecef, epsg)


POINTS_HEADER: Final = (
    "# SISA ground points (postproc.calib_data). lat_deg, lon_deg: WGS 84 geodetic, degrees; "
    "height_m: WGS 84 ellipsoidal, metres; kind: control | check | tie (tie: coordinates "
    "unknown, nan).\n")


def write_ground_points(path: Path, points: GroundPoints) -> None:
    lat, lon, h = ecef_to_geodetic(points.ecef_m)
    rows = [f"{i},{k},{a:.9f},{b:.9f},{c:.3f}" for i, k, a, b, c in zip(
        points.ids.tolist(), points.kind.tolist(), lat.tolist(), lon.tolist(), h.tolist(),
        strict=True)]
    Path(path).write_text(POINTS_HEADER + "id,kind,lat_deg,lon_deg,height_m\n"
                          + "".join(r + "\n" for r in rows), encoding="utf-8")


def read_observations(path: Path) -> ImageObservations:
    """The observations CSV (OBS_COLUMNS); sigma_px must be > 0."""
    header, data, _ = _rows(path, "observations file")
    missing = [c for c in OBS_COLUMNS if c not in header]
    if missing:
        raise InputError(f"{path}: no column '{missing[0]}' (need {', '.join(OBS_COLUMNS)})")
    seg = _floats(path, header, data, "segment")
    if np.any(seg != np.round(seg)) or np.any(seg < 0):
        raise InputError(f"{path}: segment must be a whole number ≥ 0")
    sigma = _floats(path, header, data, "sigma_px")
    if np.any(sigma <= 0):
        raise InputError(f"{path}: sigma_px must be > 0")
    return ImageObservations(np.array([r[header.index("id")].strip() for r in data]),
                             seg.astype(np.int64), _floats(path, header, data, "line"),
                             _floats(path, header, data, "pixel"), sigma)


def write_observations(path: Path, obs: ImageObservations) -> None:
    rows = [f"{i},{s},{ln:.4f},{px:.4f},{sg:.3f}" for i, s, ln, px, sg in zip(
        obs.point_id.tolist(), obs.segment.tolist(), obs.line.tolist(), obs.pixel.tolist(),
        obs.sigma_px.tolist(), strict=True)]
    Path(path).write_text(OBS_HEADER + ",".join(OBS_COLUMNS) + "\n"
                          + "".join(r + "\n" for r in rows), encoding="utf-8")


@dataclass(frozen=True)
class SegmentClock:
    """GPS time of every image line, per segment (−1 where the line has no time)."""

    t_by_segment: dict[int, I64]

    @classmethod
    def from_line_times(cls, lines: LineTimes) -> SegmentClock:
        out: dict[int, I64] = {}
        ok = (lines.status == TimeStatus.OK) & (lines.t_gps_ns >= 0) & (lines.line >= 0)
        for s in np.unique(lines.segment).tolist():
            sel = (lines.segment == s) & ok
            t = np.full(int(lines.line[lines.segment == s].max()) + 1, -1, dtype=np.int64)
            t[lines.line[sel]] = lines.t_gps_ns[sel]
            out[int(s)] = t
        return cls(out)

    def line_period_ns(self, segment: int) -> float:
        t = self.t_by_segment[segment]
        idx = np.flatnonzero(t >= 0)
        if idx.size < 2:
            return math.nan
        return float(np.median(np.diff(t[idx]) / np.diff(idx)))

    def time_of(self, segment: I64, line: F64) -> I64:
        """Interpolated GPS ns of fractional lines; −1 off the image or next to an untimed
        line."""
        out = np.full(segment.size, -1, dtype=np.int64)
        for s in np.unique(segment).tolist():
            sel = np.flatnonzero(segment == s)
            t = self.t_by_segment.get(int(s))
            if t is None or t.size < 2:
                continue
            ln = line[sel]
            inside = (ln >= 0.0) & (ln <= t.size - 1)
            i0 = np.floor(np.where(inside, ln, 0.0)).astype(np.int64)
            i1 = np.minimum(i0 + 1, t.size - 1)
            frac = np.where(inside, ln, 0.0) - i0
            t0, t1 = t[i0], t[i1]
            good = inside & (t0 >= 0) & ((frac == 0.0) | (t1 >= 0))
            out[sel[good]] = t0[good] + np.rint(frac[good] * (t1[good] - t0[good])).astype(
                np.int64)
        return out
