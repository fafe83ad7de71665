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
from pyproj import CRS, Transformer
from pyproj.exceptions import CRSError

from postproc.georef import PLAUSIBLE_HEIGHTS_M, ecef_to_geodetic, geodetic_to_ecef
from postproc.sync import FRAME_COUNTER_MAX, SEGMENT_MAX, LineTimes, TimeStatus
from sisa.core.errors import InputError, one_line_text_problem

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
Str = npt.NDArray[np.str_]

KINDS: Final = ("control", "check", "tie")
OBS_COLUMNS: Final = ("id", "segment", "line", "pixel", "sigma_px")
OBS_HEADER: Final = (
    "# SISA image observations of ground points (postproc.calibration.data; docs/calibration.md).\n"
    "# id: ground point id (the ground points file); segment: recording segment (one per strip)\n"
    "# line: 0-based image line of the segment, fractional (line k = mid-exposure of line k)\n"
    "# pixel: 0-based pixel across track, fractional (pixel j = centre of element j)\n"
    "# sigma_px: stated precision of both coordinates, pixels\n")
# A measurement's σ: below 1/1000 px no image measurement is that good (and the weights 1/σ²
# overflow the normal equations); above 100 px it does not say where in the line the point is.
SIGMA_PX_RANGE: Final = (1e-3, 100.0)
# |pixel|: sisa.core.sensor allows at most 65 536 pixels a line; beyond this no sensor file can fit.
PIXEL_LIMIT: Final = 100_000.0
# |line|: a segment has at most as many lines as the frame counter counts (u32).
LINE_LIMIT: Final = float(FRAME_COUNTER_MAX)
LAT_LIMIT_DEG: Final = 90.0
LON_LIMIT_DEG: Final = 180.0
EPSG_DIGITS_MAX: Final = 9  # no EPSG code has more; int() of thousands of digits is refused


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
            may_be_nan: npt.NDArray[np.bool_] | None = None,
            limits: tuple[float, float] | None = None, why: str = "") -> F64:
    """A numeric column; every value finite and within limits (the error says why), except
    where may_be_nan (tie points, whose coordinates are not used)."""
    col = header.index(name)
    values = np.empty(len(data), dtype=np.float64)
    for k, r in enumerate(data):
        try:
            values[k] = float(r[col])
        except ValueError:
            raise InputError(f"{path}: column {name}, row {k + 1}: {r[col].strip()[:40]!r} is "
                             "not a number") from None
    checked = np.ones(values.size, dtype=np.bool_) if may_be_nan is None else ~may_be_nan
    bad = ~np.isfinite(values) & checked
    if np.any(bad):
        raise InputError(f"{path}: column {name}, row {int(np.argmax(bad)) + 1}: not a finite "
                         "number")
    if limits is not None:
        lo, hi = limits
        out = checked & ~((values >= lo) & (values <= hi))
        if np.any(out):
            k = int(np.argmax(out))
            raise InputError(f"{path}: column {name}, row {k + 1}: {values[k]:g} is outside "
                             f"{lo:g}..{hi:g}" + (f" ({why})" if why else ""))
    return values


def _ids(path: Path, header: list[str], data: list[list[str]], name: str) -> Str:
    """An id column, stripped. An empty id or one with a control character is refused: it
    could not be told apart or shown in messages and outputs."""
    col = header.index(name)
    ids = [r[col].strip() for r in data]
    for k, i in enumerate(ids):
        if not i:
            raise InputError(f"{path}: column {name}, row {k + 1}: empty")
        if (problem := one_line_text_problem(i)) is not None:
            raise InputError(f"{path}: column {name}, row {k + 1}: {i[:40]!r} {problem}")
    return np.array(ids, dtype=np.str_)


def _projected_crs(path: Path, digits: str) -> int:
    """The EPSG code of the file's `#` comment, for easting_m/northing_m: a projected CRS in
    metres, since a geographic one would take metres for degrees and a foot one be 3.3× off."""
    said = f"{path}: EPSG:{digits[:EPSG_DIGITS_MAX + 3]} (from its # comment)"
    if len(digits) > EPSG_DIGITS_MAX:
        raise InputError(f"{said} is not a known CRS")
    try:
        crs = CRS.from_epsg(int(digits))
    except CRSError:
        raise InputError(f"{said} is not a known CRS") from None
    if not crs.is_projected:
        raise InputError(f"{said} is {crs.name}, not a projected CRS: easting_m and northing_m "
                         "need one (or give lat_deg and lon_deg)")
    units = {a.unit_name for a in crs.axis_info if a.unit_conversion_factor != 1.0}
    if units:
        raise InputError(f"{said} has axes in {', '.join(sorted(units))}: easting_m and "
                         "northing_m are metres")
    return int(digits)


def read_ground_points(path: Path) -> GroundPoints:
    """Columns id, kind and either lat_deg, lon_deg, height_m (WGS84, ellipsoidal) or
    easting_m, northing_m, height_m with 'EPSG:nnnnn' (projected, metres) in a `#` comment.
    Surveyed values outside what the Earth has are refused with their row (a point at
    height 1e300 was silently never measured)."""
    header, data, comments = _rows(path, "ground points file")
    for need in ("id", "kind", "height_m"):
        if need not in header:
            raise InputError(f"{path}: no column '{need}' (need id, kind, lat_deg, lon_deg, "
                             "height_m)")
    m = re.search(r"EPSG:(\d+)", comments)
    ids = _ids(path, header, data, "id")
    kind = np.array([r[header.index("kind")].strip().lower() for r in data])
    bad_kind = [k for k, x in enumerate(kind.tolist()) if x not in KINDS]
    if bad_kind:
        raise InputError(f"{path}: column kind, row {bad_kind[0] + 1}: kind "
                         f"{kind[bad_kind[0]][:40]!r} is not one of {', '.join(KINDS)}")
    first: dict[str, int] = {}
    for k, i in enumerate(ids.tolist()):
        if i in first:
            raise InputError(f"{path}: column id, rows {first[i] + 1} and {k + 1}: point "
                             f"'{i}' appears twice")
        first[i] = k
    tie = kind == "tie"
    h = _floats(path, header, data, "height_m", tie, PLAUSIBLE_HEIGHTS_M,
                "heights the Earth's surface has")
    epsg = None
    if "lat_deg" in header and "lon_deg" in header:
        lat = _floats(path, header, data, "lat_deg", tie, (-LAT_LIMIT_DEG, LAT_LIMIT_DEG))
        lon = _floats(path, header, data, "lon_deg", tie, (-LON_LIMIT_DEG, LON_LIMIT_DEG))
        epsg = int(m.group(1)) if m and len(m.group(1)) <= EPSG_DIGITS_MAX else None
    elif "easting_m" in header and "northing_m" in header and m is not None:
        epsg = _projected_crs(path, m.group(1))
        to_geo = Transformer.from_crs(epsg, 4326, always_xy=True)
        lon, lat = (np.asarray(v, np.float64) for v in to_geo.transform(
            _floats(path, header, data, "easting_m", tie),
            _floats(path, header, data, "northing_m", tie)))
        off = ~tie & ~(np.isfinite(lat) & np.isfinite(lon))
        if np.any(off):
            raise InputError(f"{path}: columns easting_m, northing_m, row {int(np.argmax(off)) + 1}"
                             f": not a place in EPSG:{epsg}")
    else:
        raise InputError(f"{path}: need lat_deg and lon_deg, or easting_m and northing_m with "
                         "'EPSG:nnnnn' in a # comment")
    ecef = geodetic_to_ecef(np.where(tie, 0.0, lat), np.where(tie, 0.0, lon),
                            np.where(tie, 0.0, h))
    ecef[tie] = np.nan  # a tie point's coordinates are unknowns, whatever the file says
    return GroundPoints(ids, kind, ecef, epsg)


POINTS_HEADER: Final = (
    "# SISA ground points (postproc.calibration.data). lat_deg, lon_deg: WGS 84 geodetic, degrees; "
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
    """The observations CSV (OBS_COLUMNS), each value checked with its row: a segment a frame
    header can hold, line and pixel of a possible image, σ in SIGMA_PX_RANGE, and one
    measurement of a point per segment (a repeated row would silently double its weight)."""
    header, data, _ = _rows(path, "observations file")
    missing = [c for c in OBS_COLUMNS if c not in header]
    if missing:
        raise InputError(f"{path}: no column '{missing[0]}' (need {', '.join(OBS_COLUMNS)})")
    ids = _ids(path, header, data, "id")
    seg = _floats(path, header, data, "segment")
    bad = (seg != np.round(seg)) | (seg < 0) | (seg > SEGMENT_MAX)
    if np.any(bad):
        k = int(np.argmax(bad))
        raise InputError(f"{path}: column segment, row {k + 1}: {seg[k]:g} is not a whole "
                         f"number in 0..{SEGMENT_MAX} (what a frame header holds)")
    segment = seg.astype(np.int64)
    line = _floats(path, header, data, "line", limits=(-LINE_LIMIT, LINE_LIMIT),
                   why="a segment has no more lines than a frame counter counts")
    pixel = _floats(path, header, data, "pixel", limits=(-PIXEL_LIMIT, PIXEL_LIMIT),
                    why="no line scanner has that many pixels")
    sigma = _floats(path, header, data, "sigma_px", limits=SIGMA_PX_RANGE,
                    why="pixels: below, the weights overflow; above, it is no measurement")
    first: dict[tuple[str, int], int] = {}
    for k, key in enumerate(zip(ids.tolist(), segment.tolist(), strict=True)):
        if key in first:
            raise InputError(f"{path}: rows {first[key] + 1} and {k + 1} both measure point "
                             f"'{key[0]}' in segment {key[1]}: give one row (the mean of "
                             "repeated measurements); two would count as independent")
        first[key] = k
    return ImageObservations(ids, segment, line, pixel, sigma)


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
