"""The navigation solution: pose of the INS centre at any GPS instant, from the flight log.

    cols = read_topics(paths, NAV_WANTED)           # or merged with the sync topics: one pass
    traj = nav_from_columns(cols, sync_result.ins, antenna_offset_m=mounting.antenna_offset_m)
    pose = traj.pose_at(t_line_gps_ns)              # INS centre (ECEF), R_b^e, valid

How, and why:
- **Attitude** is interpolated on SO(3) (scipy `RotationSpline`, C² in the rotation vector) over
  the INS records (64 Hz): no Euler angle is ever interpolated, so heading wraps (359° → 1°)
  cost nothing. A record is used only if time synchronisation timed it (TimeStatus.OK) and the
  INS says it is navigating (status bit NAVIGATING, not ALIGNING; docs/protocols.md).
- **Position**: each GPS fix (antenna phase centre at exactly its t_gps_ns, quality > 0) minus
  R_b^e·g^b is the INS centre at the fix epoch. The INS NED velocities carry the motion between
  fixes: rotated to ECEF with the local R_n^e and integrated exactly as a cubic spline's
  antiderivative; a PCHIP correction through (fix − integrated track) at the fix epochs is added
  (local, C¹, no overshoot; across an outage it follows the chord between the two fixes). Two
  passes: the first takes R_n^e from positions interpolated between fixes, the second from the
  first pass's track.
- **Gaps**: GPS outages up to `NavConfig.max_gps_gap_s` (30 s by default) are bridged by the INS
  track (its velocity error, nearly constant over such a gap, integrates to a drift the
  correction removes); INS gaps longer than `max_ins_gap_s` split the solution into pieces.
  Outside the pieces, inside a longer GPS gap, or before the first / after the last fix of a
  piece, a pose is invalid (NaN): nothing is ever extrapolated.

Float seconds appear only relative to the trajectory's own epoch (`sisa.core.timescale`); ECEF
positions inside the models are offsets from a local origin. Every ellipsoid transform goes
through pyproj. Nothing here reads simulation truth.
"""

from __future__ import annotations

import itertools
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache
from typing import Any, Final, NamedTuple, Protocol

import numpy as np
import numpy.typing as npt
from pyproj import Transformer
from scipy.interpolate import PchipInterpolator, make_interp_spline
from scipy.spatial.transform import Rotation, RotationSpline

from postproc.sync import AMBIGUOUS_HINT, InsTimes, TimeStatus
from recorder.columns import read_topics
from recorder.framing import Paths
from recorder.messages import Topic
from sisa.core.errors import ConfigError, InputError
from sisa.core.frames import body_to_ned_matrix, ned_to_ecef_matrix
from sisa.core.timescale import NS_PER_S, seconds_since

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]
Columns = dict[str, npt.NDArray[Any]]

ALIGNING_BIT: Final = 0x01  # INS status: static alignment running, attitude not yet valid
NAVIGATING_BIT: Final = 0x02  # INS status: aligned, navigating
MIN_RECORDS: Final = 4  # a cubic spline needs four samples
POSITION_PASSES: Final = 2
GAP_OF_SPACING: Final = 1.5  # a fix interval this many times the usual one is an outage

NAV_WANTED: Final[dict[str, tuple[str, ...]]] = {
    Topic.GPS_FIX: ("t_gps_ns", "lat_deg", "lon_deg", "height_m", "quality"),
    Topic.INS_RECORD: ("status", "roll_rad", "pitch_rad", "heading_rad",
                       "vel_n_mps", "vel_e_mps", "vel_d_mps"),
}


MAX_GAP_LIMIT_S: Final = 86_400  # a "gap" longer than a day bridges nothing a flight holds


@dataclass(frozen=True)
class NavConfig:
    """Which gaps the solution bridges (seconds)."""

    max_gps_gap_s: float = 30.0  # longest GPS outage bridged by the INS track
    max_ins_gap_s: float = 0.25  # longest run of missing/unusable INS records inside a piece

    def __post_init__(self) -> None:
        if not all(0 < g <= MAX_GAP_LIMIT_S for g in (self.max_gps_gap_s, self.max_ins_gap_s)):
            raise ConfigError("navigation config: max_gps_gap_s and max_ins_gap_s must be > 0 "
                              f"and at most {MAX_GAP_LIMIT_S} s")


class Pose(NamedTuple):
    """Navigation at N instants; rows with valid False are NaN."""

    t_gps_ns: I64
    ins_ecef_m: F64  # (N, 3) INS centre, WGS84 ECEF
    r_ecef_from_body: F64  # (N, 3, 3) R_b^e = R_n^e(lat, lon) · R_b^n
    valid: Bool


class Trajectory(Protocol):
    """What georeferencing samples; implemented by every navigation source."""

    @property
    def span_ns(self) -> tuple[int, int]:
        """First and last GPS ns with a valid pose (there may be invalid gaps inside)."""
        ...

    def pose_at(self, t_gps_ns: npt.ArrayLike) -> Pose:
        """Pose at GPS instants (int64 ns, any order)."""
        ...


# --- geodesy (pyproj) ------------------------------------------------------------------------

@cache
def transformer(src: int, dst: int) -> Transformer:
    """pyproj's transformer between two EPSG codes (x = longitude or easting), built once."""
    return Transformer.from_crs(src, dst, always_xy=True)


def geodetic_to_ecef(lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike,
                     height_m: npt.ArrayLike) -> F64:
    """WGS84 ECEF metres, shape (..., 3), of geodetic points (ellipsoidal heights)."""
    x, y, z = transformer(4979, 4978).transform(np.asarray(lon_deg, np.float64),
                                                 np.asarray(lat_deg, np.float64),
                                                 np.asarray(height_m, np.float64))
    return np.stack([np.asarray(x), np.asarray(y), np.asarray(z)], axis=-1)


def ecef_to_geodetic(ecef_m: npt.ArrayLike) -> tuple[F64, F64, F64]:
    """(lat_deg, lon_deg, height_m) of ECEF points, shape (..., 3)."""
    p = np.asarray(ecef_m, np.float64)
    lon, lat, h = transformer(4978, 4979).transform(p[..., 0], p[..., 1], p[..., 2])
    return np.asarray(lat), np.asarray(lon), np.asarray(h)


def r_ecef_from_ned(ecef_m: F64) -> F64:
    """R_n^e at ECEF points, shape (N, 3, 3)."""
    lat, lon, _ = ecef_to_geodetic(ecef_m)
    return ned_to_ecef_matrix(np.radians(lat), np.radians(lon))


def vector3(value: npt.ArrayLike, name: str) -> F64:
    """A finite 3-vector parameter, or ConfigError."""
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ConfigError(f"{name} must be three finite numbers (x, y, z), got {value!r}")
    return v


def gps_times(t_gps_ns: npt.ArrayLike) -> I64:
    """A 1-D int64 array of GPS ns (TypeError for floats: no float times)."""
    t = np.atleast_1d(np.asarray(t_gps_ns))
    if t.ndim != 1 or not (np.issubdtype(t.dtype, np.integer) or t.size == 0):
        raise TypeError("t_gps_ns must be a 1-D array of integer GPS nanoseconds")
    return t.astype(np.int64)


# --- the piecewise trajectory every source builds ---------------------------------------------

class PositionModel(Protocol):
    def __call__(self, t_s: F64) -> F64:
        """ECEF offset (N, 3) from the trajectory's origin at seconds since its epoch."""
        ...


@dataclass(frozen=True)
class Piece:
    """A stretch of continuous data: models valid on [t0_ns, t1_ns] except inside the holes."""

    t0_ns: int
    t1_ns: int
    attitude: Any  # scipy RotationSpline of R_b^n over seconds since the epoch
    position: PositionModel
    holes_ns: I64 = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))  # open

    def covers(self, t_ns: I64) -> Bool:
        inside = (t_ns >= self.t0_ns) & (t_ns <= self.t1_ns)
        for a, b in self.holes_ns.tolist():
            inside &= ~((t_ns > a) & (t_ns < b))
        return inside


class PiecewiseTrajectory:
    """Pieces of navigation on one local epoch and origin; invalid between and outside them."""

    def __init__(self, epoch_ns: int, origin_ecef_m: F64, pieces: Sequence[Piece]) -> None:
        if not pieces:
            raise ValueError("a trajectory needs at least one piece")
        self.epoch_ns = epoch_ns
        self.origin_ecef_m = np.asarray(origin_ecef_m, np.float64)
        self.pieces = tuple(sorted(pieces, key=lambda p: p.t0_ns))

    @property
    def span_ns(self) -> tuple[int, int]:
        return self.pieces[0].t0_ns, max(p.t1_ns for p in self.pieces)

    def gaps_ns(self) -> list[tuple[int, int]]:
        """Invalid stretches inside the span: holes and the spaces between pieces."""
        out = [(int(a), int(b)) for p in self.pieces for a, b in p.holes_ns.tolist()]
        out += [(a.t1_ns, b.t0_ns) for a, b in itertools.pairwise(self.pieces)
                if b.t0_ns > a.t1_ns]
        return sorted(out)

    def pose_at(self, t_gps_ns: npt.ArrayLike) -> Pose:
        t = gps_times(t_gps_ns)
        pos = np.full((t.size, 3), np.nan)
        rot = np.full((t.size, 3, 3), np.nan)
        valid = np.zeros(t.size, dtype=np.bool_)
        for piece in self.pieces:
            sel = piece.covers(t) & ~valid
            if not sel.any():
                continue
            t_s = seconds_since(t[sel], self.epoch_ns)
            ecef = piece.position(t_s) + self.origin_ecef_m
            r_bn = np.asarray(piece.attitude(t_s).as_matrix(), np.float64).reshape(-1, 3, 3)
            pos[sel] = ecef
            rot[sel] = r_ecef_from_ned(ecef) @ r_bn
            valid[sel] = True
        return Pose(t, pos, rot, valid)


def runs(t_ns: I64, max_gap_s: float) -> list[tuple[int, int]]:
    """[lo, hi) index ranges of sorted times with no step longer than max_gap_s."""
    if t_ns.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(t_ns) > round(max_gap_s * NS_PER_S)) + 1
    edges = [0, *breaks.tolist(), int(t_ns.size)]
    return list(itertools.pairwise(edges))


def sorted_unique(t_ns: I64) -> I64:
    """Indices that sort the times, keeping the first of equal times."""
    order = np.argsort(t_ns, kind="stable")
    if order.size == 0:
        return order
    return np.asarray(order[np.concatenate([[True], np.diff(t_ns[order]) > 0])], np.int64)


# --- INS + GPS fusion -------------------------------------------------------------------------

@dataclass(frozen=True)
class InsSamples:
    """Usable INS records, time-sorted: attitude and NED velocity of the INS centre."""

    t_gps_ns: I64
    r_ned_from_body: F64  # (N, 3, 3) R_b^n
    vel_ned_mps: F64  # (N, 3)
    left_out: str = ""  # why the log's other records are not here (for an error when too few)


@dataclass(frozen=True)
class AntennaFixes:
    """Antenna phase-centre positions, time-sorted, all usable."""

    t_gps_ns: I64
    ecef_m: F64  # (N, 3)


@dataclass(frozen=True)
class _FusedPosition:
    """Integrated INS velocity plus the smooth correction that ties it to the fixes."""

    track: Any  # BSpline: ∫ v^e dt, (N, 3)
    correction: Any  # PchipInterpolator over the fix epochs, (N, 3)

    def __call__(self, t_s: F64) -> F64:
        return np.asarray(self.track(t_s) + self.correction(t_s), np.float64)


def _clamped_interp(t_s: F64, tf_s: F64, values: F64) -> F64:
    return np.stack([np.interp(t_s, tf_s, values[:, k]) for k in range(3)], axis=-1)


def _chord_filled(tf_s: F64, d: F64, max_gap_s: float) -> tuple[F64, F64]:
    """Across a bridged outage the correction is the chord between its two fixes: nodes on the
    chord at the usual fix spacing keep PCHIP from bending the noisy slopes at the outage's
    edges into millimetres over its length."""
    dt = np.diff(tf_s)
    step = float(np.median(dt))
    gaps = np.flatnonzero((dt > GAP_OF_SPACING * step) & (dt <= max_gap_s))
    if gaps.size == 0:
        return tf_s, d
    extra_t = [tf_s[k] + step * np.arange(1, int(dt[k] / step - 0.5) + 1) for k in gaps]
    extra_d = [d[k] + (t - tf_s[k])[:, None] / dt[k] * (d[k + 1] - d[k])
               for k, t in zip(gaps, extra_t, strict=True)]
    t_all = np.concatenate([tf_s, *extra_t])
    order = np.argsort(t_all, kind="stable")
    return t_all[order], np.concatenate([d, *extra_d])[order]


def _fused_position(t_s: F64, vel_ned: F64, tf_s: F64, p_fix: F64, origin: F64,
                    max_gap_s: float) -> _FusedPosition:
    """The position model of one piece (offsets from origin); see the module docstring."""
    def one_pass(approx: F64) -> _FusedPosition:
        v_ecef = np.einsum("nij,nj->ni", r_ecef_from_ned(approx + origin), vel_ned)
        track = make_interp_spline(t_s, v_ecef, k=3).antiderivative()
        nodes, d = _chord_filled(tf_s, p_fix - track(tf_s), max_gap_s)
        return _FusedPosition(track, PchipInterpolator(nodes, d, extrapolate=False))

    model = one_pass(_clamped_interp(t_s, tf_s, p_fix))
    for _ in range(POSITION_PASSES - 1):
        model = one_pass(model(np.clip(t_s, tf_s[0], tf_s[-1])))
    return model


def _fix_holes(tf_ns: I64, max_gap_s: float) -> I64:
    gap = np.flatnonzero(np.diff(tf_ns) > round(max_gap_s * NS_PER_S))
    return np.stack([tf_ns[gap], tf_ns[gap + 1]], axis=-1).reshape(-1, 2)


def _fused_piece(ins: InsSamples, lo: int, hi: int, fixes: AntennaFixes, g_b: F64,
                 origin: F64, epoch_ns: int, cfg: NavConfig) -> Piece | None:
    t_ns = ins.t_gps_ns[lo:hi]
    inside = (fixes.t_gps_ns >= t_ns[0]) & (fixes.t_gps_ns <= t_ns[-1])
    if t_ns.size < MIN_RECORDS or inside.sum() < 2:
        return None
    tf_ns = fixes.t_gps_ns[inside]
    t_s, tf_s = seconds_since(t_ns, epoch_ns), seconds_since(tf_ns, epoch_ns)
    attitude = RotationSpline(t_s, Rotation.from_matrix(ins.r_ned_from_body[lo:hi]))
    ant = fixes.ecef_m[inside]
    r_eb = r_ecef_from_ned(ant) @ np.asarray(attitude(tf_s).as_matrix(), np.float64)
    p_fix = ant - origin - r_eb @ g_b  # INS centre at the fix epochs
    position = _fused_position(t_s, ins.vel_ned_mps[lo:hi], tf_s, p_fix, origin,
                               cfg.max_gps_gap_s)
    return Piece(int(tf_ns[0]), int(tf_ns[-1]), attitude, position,
                 _fix_holes(tf_ns, cfg.max_gps_gap_s))


def fuse_ins_gps(ins: InsSamples, fixes: AntennaFixes, *, antenna_offset_m: npt.ArrayLike,
                 config: NavConfig | None = None, source: str = "flight log"
                 ) -> PiecewiseTrajectory:
    """INS-centre trajectory from INS attitude and velocity and GPS antenna fixes; g^b is the
    antenna offset (INS centre → antenna, body frame)."""
    cfg = config or NavConfig()
    g_b = vector3(antenna_offset_m, "antenna_offset_m")
    if ins.t_gps_ns.size < MIN_RECORDS:
        why = f" ({ins.left_out})" if ins.left_out else ""
        raise InputError(f"{source}: {ins.t_gps_ns.size} usable INS records (timed and "
                         f"navigating){why}: no attitude to georeference with")
    if fixes.t_gps_ns.size < 2:
        raise InputError(f"{source}: {fixes.t_gps_ns.size} usable GPS fixes: need at least 2")
    epoch_ns = int(ins.t_gps_ns[0]) // NS_PER_S * NS_PER_S
    origin = fixes.ecef_m[0].copy()
    pieces = [p for lo, hi in runs(ins.t_gps_ns, cfg.max_ins_gap_s)
              if (p := _fused_piece(ins, lo, hi, fixes, g_b, origin, epoch_ns, cfg)) is not None]
    if not pieces:
        raise InputError(f"{source}: no stretch of usable INS records holds two GPS fixes")
    return PiecewiseTrajectory(epoch_ns, origin, pieces)


# --- from the flight log ----------------------------------------------------------------------

def ins_samples_from_columns(columns: dict[str, Columns], ins_times: InsTimes,
                             source: str = "flight log") -> InsSamples:
    """The usable INS records of the log: timed by sync, navigating, finite."""
    rec = columns[Topic.INS_RECORD]
    status = np.asarray(rec["status"], np.int64)
    if ins_times.t_gps_ns.size != status.size:
        raise InputError(f"{source}: {status.size} INS records but the time synchronisation "
                         f"has {ins_times.t_gps_ns.size}: not the same log")
    att = np.stack([np.asarray(rec[k], np.float64)
                    for k in ("roll_rad", "pitch_rad", "heading_rad")], axis=-1)
    vel = np.stack([np.asarray(rec[k], np.float64)
                    for k in ("vel_n_mps", "vel_e_mps", "vel_d_mps")], axis=-1)
    t = np.asarray(ins_times.t_gps_ns, np.int64)
    use = ((np.asarray(ins_times.status) == TimeStatus.OK) & (t >= 0)
           & ((status & NAVIGATING_BIT) != 0) & ((status & ALIGNING_BIT) == 0)
           & np.isfinite(att).all(axis=1) & np.isfinite(vel).all(axis=1))
    idx = np.flatnonzero(use)
    idx = idx[sorted_unique(t[idx])]
    return InsSamples(t[idx], body_to_ned_matrix(att[idx, 0], att[idx, 1], att[idx, 2]),
                      vel[idx], _left_out(ins_times.status, t, status) if idx.size < MIN_RECORDS
                      else "")


def _left_out(time_status: npt.ArrayLike, t_gps_ns: I64, status: I64) -> str:
    """Of the log's INS records, how many sync could not time (and why) and how many were not
    navigating: the reason an error gives when too few are usable."""
    timed = (np.asarray(time_status) == TimeStatus.OK) & (t_gps_ns >= 0)
    said = [f"{status.size} in the log"]
    if (~timed).any():
        why = Counter(TimeStatus(int(v)).name.lower() for v in np.asarray(time_status)[~timed])
        said.append(f"{int((~timed).sum())} not timed by sync ("
                    + ", ".join(f"{k} {v}" for k, v in why.most_common()) + ")")
        if set(why) == {"ambiguous"}:
            said[-1] += f": {AMBIGUOUS_HINT}"
    navigating = ((status & NAVIGATING_BIT) != 0) & ((status & ALIGNING_BIT) == 0)
    if (timed & ~navigating).any():
        said.append(f"{int((timed & ~navigating).sum())} timed but not navigating (aligning)")
    return ", ".join(said)


def fixes_from_columns(columns: dict[str, Columns]) -> AntennaFixes:
    """The log's GPS fixes with quality > 0 and finite values."""
    fix = columns[Topic.GPS_FIX]
    t = np.asarray(fix["t_gps_ns"], np.int64)
    llh = np.stack([np.asarray(fix[k], np.float64) for k in ("lat_deg", "lon_deg", "height_m")],
                   axis=-1)
    use = (np.asarray(fix["quality"], np.int64) > 0) & (t >= 0) & np.isfinite(llh).all(axis=1)
    idx = np.flatnonzero(use)
    idx = idx[sorted_unique(t[idx])]
    return AntennaFixes(t[idx], geodetic_to_ecef(llh[idx, 0], llh[idx, 1], llh[idx, 2]))


def nav_from_columns(columns: dict[str, Columns], ins_times: InsTimes, *,
                     antenna_offset_m: npt.ArrayLike, config: NavConfig | None = None
                     ) -> PiecewiseTrajectory:
    """The navigation solution from `read_topics(paths, NAV_WANTED)` (or a superset of it) and
    the sync result's per-record INS times (log order)."""
    return fuse_ins_gps(ins_samples_from_columns(columns, ins_times), fixes_from_columns(columns),
                        antenna_offset_m=antenna_offset_m, config=config)


def nav_from_log(paths: Paths, ins_times: InsTimes, *, antenna_offset_m: npt.ArrayLike,
                 config: NavConfig | None = None) -> PiecewiseTrajectory:
    """`nav_from_columns` on a log read from disk (a pass of its own: prefer merging
    NAV_WANTED with the sync topics and reading once)."""
    return nav_from_columns(read_topics(paths, NAV_WANTED), ins_times,
                            antenna_offset_m=antenna_offset_m, config=config)
