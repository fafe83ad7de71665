"""External trajectories in place of the log's own GPS: RTKLIB `.pos` and Applanix SBET.

- **RTKLIB `.pos`** (rnx2rtkp / rtkpost output): antenna phase-centre positions, so they are
  fused with the log's INS attitude and velocities exactly as the log's NMEA fixes are
  (`postproc.georef.navigation.fuse_ins_gps`). Read as RTKLIB writes it: `%` header lines, then one
  solution per line: time as `yyyy/mm/dd hh:mm:ss.sss` or `week tow`, on the scale the column
  header names (GPST; UTC or JST converted with the leap-second count: given, or else told by
  the flight log's receiver messages, `leap_seconds_from_log`), position as
  latitude/longitude (degrees, or `ddd mm ss.sssss`) and ellipsoidal height, or ECEF x/y/z; then
  Q, ns, three standard deviations and more columns (ignored). Files with geoid heights, the
  Tokyo datum or e/n/u baselines are refused. The file may be UTF-8 (with or without a BOM),
  Latin-1 or UTF-16 with a BOM: only its `%` comments may hold other than ASCII.
- **Applanix SBET** (`sbet_*.out`): little-endian records of 17 float64 — time (GPS seconds of
  week), latitude, longitude (rad), ellipsoidal height (m), x/y/z velocity (wander frame),
  roll, pitch, platform heading, wander angle (rad), x/y/z body acceleration, x/y/z body
  angular rate. True heading = platform heading − wander angle. An SBET is a full navigation
  solution of the INS centre (pass `reference_offset_m` if yours refers to another point);
  attitude goes through a rotation spline, position through a cubic spline of ECEF (so the SBET
  must keep its native rate, ≥ 50 Hz, for millimetre positions; its velocities are not used;
  records further apart than `max_gap_s`, default 0.25 s, are a gap, never interpolated).
  The GPS week is not in the file: each record gets the week that puts the first record within
  ±3.5 days of a reference GPS time (the flight log's first time), and a later drop of more
  than half a week is a week rollover.
"""

from __future__ import annotations

import datetime as dt
import math
import re
import warnings
from collections import Counter
from collections.abc import Callable, Collection
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt
from scipy.interpolate import make_interp_spline
from scipy.spatial.transform import Rotation, RotationSpline

from postproc.georef.navigation import (
    MIN_RECORDS,
    AntennaFixes,
    Columns,
    NavConfig,
    Piece,
    PiecewiseTrajectory,
    Trajectory,
    fuse_ins_gps,
    geodetic_to_ecef,
    ins_samples_from_columns,
    r_ecef_from_ned,
    runs,
    vector3,
)
from postproc.sync import InsTimes, TimeStatus
from recorder.messages import Topic
from sisa.core.errors import InputError
from sisa.core.frames import body_to_ned_matrix
from sisa.core.nmea import checksum
from sisa.core.timescale import (
    NS_PER_DAY,
    NS_PER_S,
    NS_PER_WEEK,
    gps_ns_from_datetime,
    seconds_since,
)

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]

RTK_Q_ALL: Final = (1, 2, 3, 4, 5, 6)  # fix, float, sbas, dgps, single, ppp
RTK_NS_MAX: Final = 255  # RTKLIB holds the satellite count in a byte
WEEK_S: Final = NS_PER_WEEK // NS_PER_S
JST_OFFSET_NS: Final = 9 * 3600 * NS_PER_S
SBET_FIELDS: Final = (
    "time_s", "lat_rad", "lon_rad", "height_m", "vel_x_mps", "vel_y_mps", "vel_z_mps",
    "roll_rad", "pitch_rad", "platform_heading_rad", "wander_rad",
    "acc_x_mps2", "acc_y_mps2", "acc_z_mps2", "rate_x_rps", "rate_y_rps", "rate_z_rps")
SBET_DTYPE: Final = np.dtype([(name, "<f8") for name in SBET_FIELDS])
# the fields as Applanix's SBET documentation names them, and their units, for messages
_SBET_LABELS: Final = (
    ("time", "s of week"), ("latitude", "rad"), ("longitude", "rad"),
    ("ellipsoidal height", "m"), ("x velocity", "m/s"), ("y velocity", "m/s"),
    ("z velocity", "m/s"), ("roll", "rad"), ("pitch", "rad"), ("platform heading", "rad"),
    ("wander angle", "rad"), ("x acceleration", "m/s^2"), ("y acceleration", "m/s^2"),
    ("z acceleration", "m/s^2"), ("x angular rate", "rad/s"), ("y angular rate", "rad/s"),
    ("z angular rate", "rad/s"))
SBET_RECORD_BYTES: Final = SBET_DTYPE.itemsize  # 136
SBET_MAX_GAP_S: Final = 0.25
# ellipsoidal heights an airborne trajectory can hold; beyond them a value is damage (1e300 m
# overflowed the Earth-centred coordinates into a spline's traceback)
TRAJECTORY_HEIGHTS_M: Final = (-10_000.0, 100_000.0)
_EARTH_RADII_M: Final = (6_356_752.3, 6_378_137.0)  # polar, equatorial (WGS 84)
# (field index, low, high) of the SBET fields used: beyond them a value is damage (a heading of
# 1e300 rad gave a wrong IGM without a word)
_SBET_RANGES: Final = (
    (0, 0.0, float(WEEK_S)), (1, -np.pi / 2, np.pi / 2), (2, -2 * np.pi, 2 * np.pi),
    (3, *TRAJECTORY_HEIGHTS_M), (7, -np.pi, np.pi), (8, -np.pi / 2, np.pi / 2),
    (9, -2 * np.pi, 2 * np.pi), (10, -2 * np.pi, 2 * np.pi))
# the fastest any aircraft flies between two fixes, plus what a fix may be off: beyond, a fix is
# bad (one wrong digit moved the images by kilometres without a word)
MAX_GROUND_SPEED_MPS: Final = 400.0  # jets cruise at ~250 m/s, survey aircraft at ~60-100
MAX_VERTICAL_SPEED_MPS: Final = 100.0  # climb or descent; airliners < 30 m/s
POS_FIX_ERROR_M: Final = 100.0  # a single-point (Q 5) solution can be tens of metres off
SBET_STEP_ERROR_M: Final = 10.0  # a smoothed solution: no record steps off its neighbours more
LEAP_SECONDS_RANGE: Final = (0, 60)  # GPS − UTC: 0 in 1980, 18 since 2017
LEAP_HINT: Final = "--leap-seconds N: GPS - UTC, 18 s since 2017"
TIME_SCALES: Final = ("GPST", "UTC", "JST")
# what `leap_seconds_from_log` reads: the receiver's PTT tags (GPS) and GGA/RMC/ZDA bytes (UTC)
TRAJ_WANTED: Final[dict[str, tuple[str, ...]]] = {
    Topic.GPS_RAW: ("t_host_ns", "data"), Topic.GPS_TIME_TAG: ("t_host_ns", "kind", "t_gps_ns")}
_NMEA_UTC: Final = re.compile(  # the UTC time of a GGA/RMC/ZDA: $, body (checksummed), *hh
    rb"\$((?:GP|GN|GL|GA|GB|BD)(?:GGA|RMC|ZDA),(\d{2})(\d{2})(\d{2})(?:\.(\d+))?,[^*$]*)"
    rb"\*([0-9A-Fa-f]{2})")
_NMEA_MAX_BYTES: Final = 256  # an unfinished sentence kept between reads (NMEA: 82)
_UTF8_BOM: Final = b"\xef\xbb\xbf"
_UTF16_BOMS: Final = (b"\xff\xfe", b"\xfe\xff")
_TEXT_PROBE_BYTES: Final = 4096
# bytes a text file never holds: C0 controls other than tab, LF, VT, FF, CR, and DEL
_NOT_TEXT: Final = bytes(b for b in range(32) if b not in b"\t\n\x0b\x0c\r") + b"\x7f"
_LAYOUTS: Final = (("latitude(d'\")", "dms"), ("latitude(deg)", "deg"), ("x-ecef(m)", "xyz"))
_DATE: Final = re.compile(r"(\d{2,4})/(\d{1,2})/(\d{1,2})")
_CLOCK: Final = re.compile(r"(\d{1,2}):(\d{1,2}):(\d{1,2})(?:\.(\d{0,9}))?")
_SECONDS: Final = re.compile(r"(\d+)(?:\.(\d{0,9}))?")
_COUNT: Final = re.compile(r"\d{1,3}")  # Q and ns: RTKLIB prints them %3d


# --- RTKLIB .pos ------------------------------------------------------------------------------

@dataclass(frozen=True)
class RtkPos:
    """The solutions of a `.pos` file, in file order (times strictly increasing)."""

    t_gps_ns: I64
    ecef_m: F64  # (N, 3) antenna phase centre
    q: I64  # 1 fix, 2 float, 3 sbas, 4 dgps, 5 single, 6 ppp
    ns: I64  # satellites (-1 if absent)
    sigma_m: F64  # (N, 3): sdn, sde, sdu (lat/lon files) or sdx, sdy, sdz (ECEF); NaN if absent
    line: I64  # line number in the file (1-based)


@dataclass
class _PosFormat:
    layout: str = ""  # "deg" | "dms" | "xyz"; "" until the column header line
    sep: str = " "
    offset_ns: int = 0  # added to the file's times to get GPS time


def _seconds_ns(text: str, pattern: re.Pattern[str] = _SECONDS) -> int:
    m = pattern.fullmatch(text)
    if m is None:
        raise ValueError(f"not a time {text!r}")
    whole, frac = m.group(1), m.group(2) or ""
    return int(whole) * NS_PER_S + int((frac + "000000000")[:9])


def _time_ns(date_or_week: str, clock_or_tow: str) -> int:
    """ns on the file's own scale, exactly (no float)."""
    day = _DATE.fullmatch(date_or_week)
    if day is None:
        if not date_or_week.isdigit():
            raise ValueError(f"not a date or GPS week {date_or_week!r}")
        tow_ns = _seconds_ns(clock_or_tow)
        if tow_ns >= NS_PER_WEEK:  # else it would fall in the next week, and be blamed there
            raise ValueError(f"time of week {clock_or_tow} s is not 0 to {WEEK_S} s")
        return int(date_or_week) * NS_PER_WEEK + tow_ns
    m = _CLOCK.fullmatch(clock_or_tow)
    if m is None:
        raise ValueError(f"not a time of day {clock_or_tow!r}")
    if int(m.group(3)) >= 60:  # else it runs into the next minute, and the next line is blamed
        raise ValueError(f"time of day {clock_or_tow!r}: second {m.group(3)} is not 0 to 59 "
                         "(RTKLIB never writes a leap second :60)")
    year, month, mday = (int(x) for x in day.groups())
    year += 0 if year >= 100 else (2000 if year < 80 else 1900)  # as RTKLIB reads 2-digit years
    hour, minute = int(m.group(1)), int(m.group(2))
    start = gps_ns_from_datetime(dt.datetime(year, month, mday, hour, minute))
    return start + _seconds_ns(f"{m.group(3)}.{m.group(4) or ''}")


def _header(fmt: _PosFormat, text: str, where: str, leap_seconds: int | None) -> None:
    """Take what a `%` line says about the format; refuse what we cannot use."""
    if "height=" in text and "geodetic" in text:
        raise InputError(f"{where}: heights are geodetic (above a geoid): export ellipsoidal")
    if "lat/lon/height=Tokyo" in text:
        raise InputError(f"{where}: Tokyo datum: export in WGS84")
    if "e-baseline(m)" in text:
        raise InputError(f"{where}: e/n/u baselines are not supported: export lat/lon/height")
    for label, layout in _LAYOUTS:
        at = text.find(label)
        if at < 0:
            continue
        fmt.layout = layout
        after = text[at + len(label):at + len(label) + 1]
        fmt.sep = after if after and not after.isspace() else " "
        scale = _scale_of(text)
        if scale not in TIME_SCALES:
            raise InputError(f"{where}: unknown time scale {scale!r} (GPST, UTC or JST)")
        if scale != "GPST" and leap_seconds is None:
            raise InputError(f"{where}: times are {scale}: give the leap-second count "
                             f"({LEAP_HINT})")
        leap_ns = (leap_seconds or 0) * NS_PER_S
        fmt.offset_ns = {"GPST": 0, "UTC": leap_ns, "JST": leap_ns - JST_OFFSET_NS}[scale]
        return


def _scale_of(column_header: str) -> str:
    words = column_header[1:].split()
    return words[0] if words else ""


def _decode_text(raw: bytes) -> str:
    """The text of a `.pos` file: UTF-8 (a BOM dropped), UTF-16 with a BOM, else Latin-1 (a
    Windows path in a comment line); RTKLIB's own lines are ASCII in all of them."""
    if raw.startswith(_UTF16_BOMS):
        return raw.decode("utf-16")
    body = raw.removeprefix(_UTF8_BOM)
    try:
        return body.decode("utf-8")
    except UnicodeDecodeError:
        return body.decode("latin-1")


def pos_time_scale(path: Path | str) -> str | None:
    """The time scale a `.pos` file's column header names (GPST, UTC, JST), None without one."""
    path = Path(path)
    try:
        text = _decode_text(path.read_bytes())
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a readable text file: {exc}") from None
    for raw in text.splitlines():
        line = raw.strip()
        if not line.startswith("%"):
            if line:
                break
            continue
        if any(label in line for label, _ in _LAYOUTS):
            return _scale_of(line)
    return None


def _dms_deg(d: str, m: str, s: str) -> float:
    sign = -1.0 if d.strip().startswith("-") else 1.0
    return sign * (abs(float(d)) + float(m) / 60.0 + float(s) / 3600.0)


def _count(text: str, name: str, low: int, high: int) -> int:
    """A Q or ns column: a whole number in range (a 20-digit one overflowed int64 into a
    traceback; Q 9 would be dropped as if of a quality not accepted)."""
    if _COUNT.fullmatch(text) is None or not low <= int(text) <= high:
        raise ValueError(f"{name} {text!r} is not a whole number {low} to {high}")
    return int(text)


def _solution(fmt: _PosFormat, text: str) -> tuple[int, list[float], int, int, list[float]]:
    """(time ns on GPST, position values, Q, ns, sigmas) of one data line; ValueError if bad."""
    fields = [text] if fmt.sep == " " else text.split(fmt.sep)
    tok = [t for f in fields for t in f.split()]
    n_pos = 7 if fmt.layout == "dms" else 3
    if len(tok) < 3 + n_pos:
        raise ValueError(f"{len(tok)} fields, need at least {3 + n_pos} (time, position, Q)")
    t_ns = _time_ns(tok[0], tok[1]) + fmt.offset_ns
    if not 0 <= t_ns < 2**63:
        raise ValueError(f"time {tok[0]} {tok[1]} is outside GPS time as nanoseconds hold it "
                         "(1980-01-06 to 2272)")
    vals = [float(x) for x in tok[2:2 + n_pos]]
    if fmt.layout == "dms":
        vals = [_dms_deg(*tok[2:5]), _dms_deg(*tok[5:8]), vals[6]]
    q = _count(tok[2 + n_pos], "Q (solution quality)", RTK_Q_ALL[0], RTK_Q_ALL[-1])
    ns = _count(tok[3 + n_pos], "ns (satellites)", 0, RTK_NS_MAX) if len(tok) > 3 + n_pos else -1
    sig = [float(x) for x in tok[4 + n_pos:7 + n_pos]]
    return t_ns, vals, q, ns, sig + [np.nan] * (3 - len(sig))


def _check_position(layout: str, vals: list[float]) -> None:
    if not all(np.isfinite(vals)):
        raise ValueError("non-finite position")
    low, high = TRAJECTORY_HEIGHTS_M
    if layout == "xyz":
        radius = math.hypot(*vals)
        if not _EARTH_RADII_M[0] + low <= radius <= _EARTH_RADII_M[1] + high:
            raise ValueError(f"ECEF position {radius:.6g} m from the Earth's centre, not within "
                             f"{low:g} to {high:g} m of its surface")
        return
    if not (-90.0 <= vals[0] <= 90.0 and -180.0 <= vals[1] <= 360.0):
        raise ValueError(f"latitude/longitude out of range: {vals[0]}, {vals[1]}")
    if not low <= vals[2] <= high:
        raise ValueError(f"ellipsoidal height {vals[2]:g} m outside {low:g} to {high:g} m")


def _check_motion(t_ns: I64, ecef_m: F64, error_m: float, where: Callable[[int], str]) -> None:
    """InputError at the first step between consecutive fixes (times strictly increasing) that
    no aircraft flies: over MAX_GROUND_SPEED_MPS across or MAX_VERTICAL_SPEED_MPS up or down,
    plus `error_m` the fixes may be off. Across and up split at the WGS 84 normal midway; a
    gap in time allows a longer step. `where(i)`: the file and line or record of fix i.
    Vectorised: a trajectory holds 10^5-10^6 fixes."""
    if t_ns.size < 2:
        return
    step_m = np.diff(ecef_m, axis=0)
    dt_s = np.diff(t_ns).astype(np.float64) / NS_PER_S
    polar, equatorial = _EARTH_RADII_M
    up = (ecef_m[1:] + ecef_m[:-1]) / np.array([equatorial**2, equatorial**2, polar**2])
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    rise_m = np.abs(np.einsum("ij,ij->i", step_m, up))
    across_m = np.sqrt(np.maximum(np.einsum("ij,ij->i", step_m, step_m) - rise_m**2, 0.0))
    too_far = across_m > MAX_GROUND_SPEED_MPS * dt_s + error_m
    too_steep = rise_m > MAX_VERTICAL_SPEED_MPS * dt_s + error_m
    bad = np.flatnonzero(too_far | too_steep)
    if not bad.size:
        return
    k = int(bad[0])
    if too_far[k]:
        what, dist_m = "the position jumps", float(across_m[k])
        limit = f"an aircraft flies < {MAX_GROUND_SPEED_MPS:g} m/s"
    else:
        what, dist_m = "the height changes", float(rise_m[k])
        limit = f"an aircraft climbs or descends < {MAX_VERTICAL_SPEED_MPS:g} m/s"
    dist = f"{_figure(dist_m / 1000)} km" if dist_m >= 1000 else f"{_figure(dist_m)} m"
    raise InputError(f"{where(k + 1)}: {what} {dist} in {_figure(dt_s[k])} s from the fix "
                     f"before ({dist_m / dt_s[k]:,.0f} m/s; {limit}): a bad fix?")


def _figure(value: float) -> str:
    """3 significant digits, a large value in full (12,000 km, not 1.2e+04)."""
    return f"{value:.3g}" if abs(value) < 1000 else f"{value:,.0f}"


def read_rtklib_pos(path: Path | str, *, leap_seconds: int | None = None) -> RtkPos:
    """Every solution of an RTKLIB `.pos` file; InputError (file:line: problem) if malformed."""
    path = Path(path)
    try:
        text = _decode_text(path.read_bytes())
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a readable text file: {exc}") from None
    fmt = _PosFormat()
    rows: list[tuple[int, list[float], int, int, list[float], int]] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if line.startswith("%"):
            _header(fmt, line, f"{path}:{number}", leap_seconds)
            continue
        if not line:
            continue
        if not fmt.layout:
            raise InputError(f"{path}:{number}: a solution before the column header line "
                             "('%  GPST  latitude(deg) ...'): not an RTKLIB .pos file?")
        try:
            t_ns, vals, q, ns, sig = _solution(fmt, line)
            _check_position(fmt.layout, vals)
        except ValueError as exc:
            raise InputError(f"{path}:{number}: {exc}") from None
        if rows and t_ns <= rows[-1][0]:
            raise InputError(f"{path}:{number}: time does not increase after line {rows[-1][5]}")
        rows.append((t_ns, vals, q, ns, sig, number))
    if not rows:
        raise InputError(f"{path}: no solution lines")
    pos = np.array([r[1] for r in rows], dtype=np.float64)
    ecef = pos if fmt.layout == "xyz" else geodetic_to_ecef(pos[:, 0], pos[:, 1], pos[:, 2])
    times_ns = np.array([r[0] for r in rows], dtype=np.int64)
    numbers = np.array([r[5] for r in rows], dtype=np.int64)
    _check_motion(times_ns, ecef, POS_FIX_ERROR_M, lambda i: f"{path}:{numbers[i]}")
    return RtkPos(times_ns, ecef, np.array([r[2] for r in rows], dtype=np.int64),
                  np.array([r[3] for r in rows], dtype=np.int64),
                  np.array([r[4] for r in rows], dtype=np.float64), numbers)


def rtklib_trajectory(path: Path | str, columns: dict[str, Columns], ins_times: InsTimes, *,
                      antenna_offset_m: npt.ArrayLike, leap_seconds: int | None = None,
                      accept_q: Collection[int] = RTK_Q_ALL, config: NavConfig | None = None
                      ) -> PiecewiseTrajectory:
    """The log's INS (attitude, velocity) fused with the antenna positions of a `.pos` file
    whose quality Q is in `accept_q`."""
    pos = read_rtklib_pos(path, leap_seconds=leap_seconds)
    keep = np.isin(pos.q, np.asarray(list(accept_q), dtype=np.int64))
    fixes = AntennaFixes(pos.t_gps_ns[keep], pos.ecef_m[keep])
    return fuse_ins_gps(ins_samples_from_columns(columns, ins_times), fixes,
                        antenna_offset_m=antenna_offset_m, config=config, source=str(path))


# --- Applanix SBET ----------------------------------------------------------------------------

class PartialRecordWarning(UserWarning):
    """A trajectory file ends in part of a record, left out."""


@dataclass(frozen=True)
class Sbet:
    """SBET records with their full GPS times."""

    t_gps_ns: I64
    records: npt.NDArray[np.void]  # structured, SBET_DTYPE fields
    cut_note: str | None = None  # said when the file ends in part of a record (left out)


def _sbet_name(path: Path) -> str:
    """The file as SBET messages name it: one named `.pos` but binary (or empty) says how it
    was read, else its messages of SBET records puzzle."""
    if path.suffix.lower() == ".pos":
        return f"{path} (read as an Applanix SBET: binary, not RTKLIB text)"
    return str(path)


def _sbet_values(path: Path) -> tuple[npt.NDArray[np.void], str | None]:
    name = _sbet_name(path)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise InputError(f"{name}: unreadable: {exc}") from None
    whole, rest = divmod(size, SBET_RECORD_BYTES)
    if whole == 0:
        raise InputError(f"{name}: {size} bytes is not a whole number of {SBET_RECORD_BYTES}-byte"
                         " SBET records (17 little-endian float64)")
    note = None  # a file cut while written: its whole records are still good
    if rest:
        note = (f"{name}: the last {rest} bytes are not a whole {SBET_RECORD_BYTES}-byte SBET "
                f"record (a file cut while written?): read the {whole} records before them")
    rec = np.fromfile(path, dtype=SBET_DTYPE, count=whole)
    values = rec.view("<f8").reshape(-1, len(SBET_FIELDS))
    bad = np.argwhere(~np.isfinite(values))
    if bad.size:
        i, j = (int(x) for x in bad[0])
        label, unit = _SBET_LABELS[j]
        raise InputError(f"{name}: record {i} (byte {i * SBET_RECORD_BYTES}): "
                         f"{label} ({unit}) is not finite")
    for j, low, high in _SBET_RANGES:
        out = np.flatnonzero((values[:, j] < low) | (values[:, j] > high))
        if out.size:
            i = int(out[0])
            label, unit = _SBET_LABELS[j]
            raise InputError(f"{name}: record {i}: {label} {values[i, j]:g} {unit} outside "
                             f"{low:g} to {high:g} {unit}")
    return rec, note


def sbet_times_ns(tow_s: F64, reference_gps_ns: int) -> I64:
    """Full GPS ns of SBET seconds-of-week (see the module docstring for the week)."""
    tow_ns = np.rint(tow_s * NS_PER_S).astype(np.int64)
    half = NS_PER_WEEK // 2
    start = reference_gps_ns // NS_PER_WEEK * NS_PER_WEEK
    first = start + int(tow_ns[0])
    start += NS_PER_WEEK if reference_gps_ns - first > half else 0
    start -= NS_PER_WEEK if first - reference_gps_ns > half else 0
    rollover = np.concatenate([[0], np.cumsum(np.diff(tow_ns) < -half)])
    return np.asarray(start + tow_ns + rollover * NS_PER_WEEK, np.int64)


def read_sbet(path: Path | str, reference_gps_ns: int) -> Sbet:
    """An SBET file, checked: size, finite values, ranges, strictly increasing times, steps an
    aircraft can fly (`_check_motion`)."""
    path = Path(path)
    name = _sbet_name(path)
    rec, note = _sbet_values(path)
    t = sbet_times_ns(np.asarray(rec["time_s"], np.float64), reference_gps_ns)
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        i = int(back[0]) + 1
        raise InputError(f"{name}: record {i}: time {float(rec['time_s'][i]):.6f} s of week does"
                         " not increase")
    ecef = geodetic_to_ecef(np.degrees(rec["lat_rad"]), np.degrees(rec["lon_rad"]),
                            rec["height_m"])
    _check_motion(t, ecef, SBET_STEP_ERROR_M, lambda i: f"{name}: record {i}")
    return Sbet(t, rec, note)


@dataclass(frozen=True)
class _SplinePosition:
    spline: Any  # BSpline of ECEF offsets over seconds since the epoch

    def __call__(self, t_s: F64) -> F64:
        return np.asarray(self.spline(t_s), np.float64)


def sbet_trajectory(path: Path | str, reference_gps_ns: int, *,
                    reference_offset_m: npt.ArrayLike = (0.0, 0.0, 0.0),
                    max_gap_s: float = SBET_MAX_GAP_S,
                    report: dict[str, Any] | None = None) -> PiecewiseTrajectory:
    """The INS-centre trajectory of an SBET. `reference_offset_m`: INS centre → the point the
    SBET refers to, body frame (zero for an SBET of the INS centre). A file cut mid-record is
    said in `report["warnings"]` when a report is given, else as a PartialRecordWarning."""
    sb = read_sbet(path, reference_gps_ns)
    if sb.cut_note is not None and report is not None:
        report.setdefault("warnings", []).append(sb.cut_note)
    elif sb.cut_note is not None:
        warnings.warn(sb.cut_note, PartialRecordWarning, stacklevel=2)
    r = sb.records
    r_bn = body_to_ned_matrix(r["roll_rad"], r["pitch_rad"],
                              r["platform_heading_rad"] - r["wander_rad"])
    ref = geodetic_to_ecef(np.degrees(r["lat_rad"]), np.degrees(r["lon_rad"]), r["height_m"])
    ins = ref - (r_ecef_from_ned(ref) @ r_bn) @ vector3(reference_offset_m, "reference_offset_m")
    epoch = int(sb.t_gps_ns[0]) // NS_PER_S * NS_PER_S
    origin = ins[0].copy()
    t_s = seconds_since(sb.t_gps_ns, epoch)
    pieces = [Piece(int(sb.t_gps_ns[lo]), int(sb.t_gps_ns[hi - 1]),
                    RotationSpline(t_s[lo:hi], Rotation.from_matrix(r_bn[lo:hi])),
                    _SplinePosition(make_interp_spline(t_s[lo:hi], ins[lo:hi] - origin, k=3)))
              for lo, hi in runs(sb.t_gps_ns, max_gap_s) if hi - lo >= MIN_RECORDS]
    if not pieces:
        rate = _median_rate_hz(sb.t_gps_ns)
        raise InputError(f"{_sbet_name(Path(path))}: no {MIN_RECORDS} records without a gap "
                         f"over {max_gap_s:g} s (records at {rate:.3g} Hz): is it decimated? An "
                         "SBET should keep its native rate (>= 50 Hz); --max-gap-s S bridges "
                         "longer gaps, less accurately")
    return PiecewiseTrajectory(epoch, origin, pieces)


def _median_rate_hz(t_ns: I64) -> float:
    step = np.diff(t_ns)
    return NS_PER_S / float(np.median(step)) if step.size else 0.0


# --- either, for the pipeline -----------------------------------------------------------------

def _reference_gps_ns(columns: dict[str, Columns], ins_times: InsTimes) -> int:
    timed = ins_times.t_gps_ns[(ins_times.status == TimeStatus.OK) & (ins_times.t_gps_ns >= 0)]
    if timed.size:
        return int(timed.min())
    fixes = np.asarray(columns.get(Topic.GPS_FIX, {}).get("t_gps_ns", []), np.int64)
    if fixes.size:
        return int(fixes.min())
    raise InputError("flight log: no GPS time at all (no timed INS record, no fix): cannot "
                     "place the SBET's seconds of week")


def _is_text(path: Path) -> bool:
    """Text (a `.pos`) or binary (an SBET: 136-byte records of float64, whose bytes hold
    every value, control bytes among them). Text: a BOM (UTF-8 or UTF-16), or else no control
    byte other than tab/CR/LF/FF/VT and lines (a line end in the first 4 KB, unless the file is
    shorter). Bytes over 127 are allowed: UTF-8 or Latin-1 comments."""
    try:
        with path.open("rb") as fh:
            head = fh.read(_TEXT_PROBE_BYTES + 1)
    except OSError as exc:
        raise InputError(f"{path}: unreadable: {exc}") from None
    if head.startswith((_UTF8_BOM, *_UTF16_BOMS)):
        return True
    if not head or any(b in _NOT_TEXT for b in head):
        return False
    return b"\n" in head or b"\r" in head or len(head) <= _TEXT_PROBE_BYTES


def leap_seconds_from_log(columns: dict[str, Columns], *, enough: int = 300) -> int | None:
    """GPS − UTC in whole seconds, as the receiver states it in the flight log: each PTT time
    tag (the PPS, in GPS time) against the nearest whole-second GGA/RMC/ZDA of its raw bytes
    (UTC), their host receive times taking out which epochs they are; None unless at least 3
    pairs agree, 90 % of them on one count in 0–60. The first `enough` tags decide if they
    agree, else all of them (`TRAJ_WANTED` holds the columns it reads)."""
    tags = columns.get(Topic.GPS_TIME_TAG, {})
    is_ptt = np.asarray(tags.get("kind", np.zeros(0, str))) == "PTT"
    tag_host = np.asarray(tags.get("t_host_ns", np.zeros(0, np.int64)), np.int64)[is_ptt]
    tag_gps = np.asarray(tags.get("t_gps_ns", np.zeros(0, np.int64)), np.int64)[is_ptt]
    keep = tag_gps >= 0
    second = (tag_gps[keep] + NS_PER_S // 2) // NS_PER_S * NS_PER_S
    ptt = list(zip(tag_host[keep].tolist(), (second % NS_PER_DAY).tolist(), strict=True))
    utc = _utc_epochs(columns.get(Topic.GPS_RAW, {}))
    if len(ptt) > enough and (verdict := _leap_vote(ptt[:enough], utc)) is not None:
        return verdict
    return _leap_vote(ptt, utc)


def _utc_epochs(raw: Columns) -> list[tuple[int, int]]:
    """(host ns, UTC ns of day) of every whole-second GGA/RMC/ZDA in the raw GPS bytes, with a
    good checksum; a sentence's host time is that of the read that completed it."""
    hosts: npt.NDArray[Any] = raw.get("t_host_ns", np.zeros(0, np.int64))
    chunks: npt.NDArray[Any] = raw.get("data", np.zeros(0, object))
    out: list[tuple[int, int]] = []
    pending = b""
    for t_host, data in zip(hosts, chunks, strict=True):
        *lines, pending = (pending + bytes(data)).split(b"\n")
        pending = pending[-_NMEA_MAX_BYTES:]
        for line in lines:
            m = _NMEA_UTC.search(line)
            if m is None or checksum(m.group(1)) != int(m.group(6), 16):
                continue
            hh, mm, ss = int(m.group(2)), int(m.group(3)), int(m.group(4))
            if hh < 24 and mm < 60 and ss < 60 and not (m.group(5) or b"0").strip(b"0"):
                out.append((int(t_host), (hh * 3600 + mm * 60 + ss) * NS_PER_S))
    return out


def _leap_vote(ptt: list[tuple[int, int]], utc: list[tuple[int, int]]) -> int | None:
    if len(ptt) < 3 or not utc:
        return None
    u_host = np.array([h for h, _ in utc], np.int64)
    u_tod = np.array([t for _, t in utc], np.int64)
    order = np.argsort(u_host, kind="stable")
    u_host, u_tod = u_host[order], u_tod[order]
    votes: list[int] = []
    for h, s in ptt:
        k = int(np.searchsorted(u_host, h))
        j = min((i for i in (k - 1, k) if 0 <= i < u_host.size),
                key=lambda i: abs(int(u_host[i]) - h))
        dh = h - int(u_host[j])
        if abs(dh) > 2 * NS_PER_S:
            continue
        d = (s - int(u_tod[j]) - dh + NS_PER_DAY // 2) % NS_PER_DAY - NS_PER_DAY // 2
        leap = round(d / NS_PER_S)
        if abs(d - leap * NS_PER_S) < 0.3 * NS_PER_S:
            votes.append(leap)
    if len(votes) < 3:
        return None
    leap, count = Counter(votes).most_common(1)[0]
    lo, hi = LEAP_SECONDS_RANGE
    return leap if count >= 0.9 * len(votes) and lo <= leap <= hi else None


def _leap_for(path: Path, columns: dict[str, Columns], leap_seconds: int | None,
              fallback_leap_seconds: int | None, report: dict[str, Any]) -> int | None:
    """The leap-second count a `.pos` on UTC or JST needs: given, else the log's, else the
    fallback (a scenario's); None for GPST (or when none is known: the reader then says so)."""
    scale = pos_time_scale(path)
    report["time_scale"] = scale
    if scale in (None, "GPST"):
        return leap_seconds
    from_log = leap_seconds_from_log(columns)
    if leap_seconds is not None:
        report.update(leap_seconds=leap_seconds, leap_seconds_from="--leap-seconds")
        if from_log is not None and from_log != leap_seconds:
            report.setdefault("warnings", []).append(
                f"{path}: times are {scale}: using {leap_seconds} leap seconds as given, but "
                f"the flight log's receiver messages say {from_log}")
        return leap_seconds
    if from_log is not None:
        report.update(leap_seconds=from_log,
                      leap_seconds_from="flight log (receiver PTT against GGA/RMC/ZDA)")
        return from_log
    if fallback_leap_seconds is not None:
        report.update(leap_seconds=fallback_leap_seconds, leap_seconds_from="scenario")
        return fallback_leap_seconds
    return None


def read_trajectory_file(path: Path | str, columns: dict[str, Columns], ins_times: InsTimes, *,
                         antenna_offset_m: npt.ArrayLike, leap_seconds: int | None = None,
                         sbet_offset_m: npt.ArrayLike = (0.0, 0.0, 0.0),
                         config: NavConfig | None = None, max_gap_s: float | None = None,
                         fallback_leap_seconds: int | None = None,
                         report: dict[str, Any] | None = None) -> Trajectory:
    """An RTKLIB `.pos` (text) or an SBET (binary), told apart by their content.

    `max_gap_s`: the longest gap bridged, between SBET records or (for a `.pos`, by the INS)
    between GPS solutions. A `.pos` on UTC or JST takes `leap_seconds` if given, else the count
    the log's receiver messages state (`columns` with `TRAJ_WANTED`), else
    `fallback_leap_seconds`. `report`, if given, is filled with what was read and how (format,
    time scale, leap seconds and where they came from, `warnings`)."""
    path = Path(path)
    info: dict[str, Any] = report if report is not None else {}
    if _is_text(path):
        info["format"] = "RTKLIB .pos"
        leap = _leap_for(path, columns, leap_seconds, fallback_leap_seconds, info)
        if max_gap_s is not None:
            config = NavConfig(max_gps_gap_s=max_gap_s,
                               max_ins_gap_s=(config or NavConfig()).max_ins_gap_s)
        return rtklib_trajectory(path, columns, ins_times, antenna_offset_m=antenna_offset_m,
                                 leap_seconds=leap, config=config)
    info["format"] = "Applanix SBET"
    return sbet_trajectory(path, _reference_gps_ns(columns, ins_times),
                           reference_offset_m=sbet_offset_m,
                           max_gap_s=SBET_MAX_GAP_S if max_gap_s is None else max_gap_s,
                           report=info)


__all__ = ["LEAP_SECONDS_RANGE", "RTK_Q_ALL", "SBET_DTYPE", "SBET_FIELDS", "TRAJ_WANTED",
           "RtkPos", "Sbet", "leap_seconds_from_log", "pos_time_scale", "read_rtklib_pos",
           "read_sbet", "read_trajectory_file", "rtklib_trajectory", "sbet_times_ns",
           "sbet_trajectory"]
