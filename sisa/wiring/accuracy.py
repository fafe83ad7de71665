"""Accuracy of a simulated run's georeferencing against its truth — the only place where the
post-processor's products meet the emulator's forward model.

Every pixel: the emulator's own ray casting (emulators.render, a different solver and frame
from postproc.georef.raycast) at the TRUE mid-exposure time and pose gives where the pixel really
looked; the IGM gives where georeferencing put it. Check points: each surveyed check point is
found in the image through the truth (sub-pixel line and pixel), the IGM is interpolated there
and compared with the surveyed coordinates — what a user measures with check points.

Errors are split along track (direction of flight), across track (to the right) and in height,
in metres and in pixels (the segment's median pixel spacing across and along track).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final, TypeVar, cast

import numba
import numpy as np
import numpy.typing as npt
from pyproj import Transformer

from emulators.gps import antenna_fix_ecef_m
from emulators.render import GroundIntersector, camera_pose_ecef
from emulators.scenario import Scenario
from emulators.terrain import Terrain
from emulators.trajectory import TruthTrajectory
from emulators.truth import read_truth_csv
from postproc.calibration import read_ground_points
from postproc.georef import (
    AntennaFixes,
    SegmentResult,
    ecef_to_geodetic,
    fixes_from_columns,
)
from postproc.products import open_igm
from recorder.columns import read_topics
from recorder.messages import Topic
from sisa.core.errors import InputError
from sisa.core.timescale import gps_span_label

F64 = npt.NDArray[np.float64]
_Fn = TypeVar("_Fn", bound=Callable[..., Any])
BLOCK_LINES: Final = 2048
SAMPLE_PER_BLOCK: Final = 4000  # pixels kept per block for the report's histograms
COMPONENTS: Final = ("along", "across", "height")
FIX_FIELDS: Final = ("t_gps_ns", "lat_deg", "lon_deg", "height_m", "quality")
FIX_AGREEMENT_M: Final = 0.05  # a fix against its truth: NMEA rounds to ~2 mm, far from this


@dataclass
class ErrorStats:
    """Running moments of along/across/height errors (m) over many pixels."""

    n: int = 0
    sum_m: F64 = field(default_factory=lambda: np.zeros(3))
    sumsq_m: F64 = field(default_factory=lambda: np.zeros(3))
    max_abs_m: F64 = field(default_factory=lambda: np.zeros(3))
    max_abs_px: F64 = field(default_factory=lambda: np.zeros(3))
    sumsq_px: F64 = field(default_factory=lambda: np.zeros(3))
    sample_px: list[F64] = field(default_factory=list)

    def add(self, err_m: F64, px_m: F64, rng: np.random.Generator) -> None:
        """err_m (k, 3) along/across/height; px_m (3,) pixel size for each component."""
        err_m = np.ascontiguousarray(err_m, dtype=np.float64)
        ok = np.empty(err_m.shape[0], dtype=np.bool_)
        block = np.zeros((5, 3))
        n = _error_moments(err_m, np.ascontiguousarray(px_m, dtype=np.float64), ok, block)
        if not n:
            return
        self.n += n
        self.sum_m += block[0]
        self.sumsq_m += block[1]
        self.sumsq_px += block[2]
        self.max_abs_m = np.maximum(self.max_abs_m, block[3])
        self.max_abs_px = np.maximum(self.max_abs_px, block[4])
        keep = np.flatnonzero(ok)[rng.choice(n, min(SAMPLE_PER_BLOCK, n), replace=False)]
        self.sample_px.append(err_m[keep] / px_m)

    def merge(self, other: ErrorStats) -> None:
        self.n += other.n
        self.sum_m += other.sum_m
        self.sumsq_m += other.sumsq_m
        self.sumsq_px += other.sumsq_px
        self.max_abs_m = np.maximum(self.max_abs_m, other.max_abs_m)
        self.max_abs_px = np.maximum(self.max_abs_px, other.max_abs_px)
        self.sample_px += other.sample_px

    def summary(self) -> dict[str, Any]:
        n = max(self.n, 1)
        out: dict[str, Any] = {"pixels": self.n}
        for i, c in enumerate(COMPONENTS):
            out[c] = {"rms_m": math.sqrt(self.sumsq_m[i] / n), "mean_m": self.sum_m[i] / n,
                      "max_abs_m": float(self.max_abs_m[i]),
                      "rms_px": math.sqrt(self.sumsq_px[i] / n),
                      "max_abs_px": float(self.max_abs_px[i])}
        return out


@cast(Callable[[_Fn], _Fn], numba.njit(cache=True))
def _error_moments(err_m: F64, px_m: F64, ok: npt.NDArray[np.bool_], out: F64) -> int:
    """One pass over a block's pixels: ok[i] = all three components finite; of those, out[0]
    Σe, out[1] Σe², out[2] Σ(e/px)², out[3] max|e|, out[4] max|e/px| per component (out
    zeroed by the caller), summed in row order as numpy's axis-0 reductions are, at a tenth
    of their time (five passes and three temporaries of 25 MB a block before); the count."""
    n = 0
    for i in range(err_m.shape[0]):
        a, b, c = err_m[i, 0], err_m[i, 1], err_m[i, 2]
        ok[i] = math.isfinite(a) and math.isfinite(b) and math.isfinite(c)
        if not ok[i]:
            continue
        n += 1
        for k in range(3):
            e = err_m[i, k]
            p = e / px_m[k]
            out[0, k] += e
            out[1, k] += e * e
            out[2, k] += p * p
            out[3, k] = max(out[3, k], abs(e))
            out[4, k] = max(out[4, k], abs(p))
    return n


def along_across_axes(east_m: F64, north_m: F64) -> tuple[F64, F64]:
    """Unit along-track (E, N) per line from the centre pixel's track, and the across-track
    unit vector to the right of it."""
    mid = east_m.shape[1] // 2
    de = np.gradient(east_m[:, mid]) if east_m.shape[0] > 1 else np.zeros(1)
    dn = np.gradient(north_m[:, mid]) if east_m.shape[0] > 1 else np.ones(1)
    norm = np.hypot(de, dn)
    norm[norm == 0] = np.nan
    along = np.stack([de / norm, dn / norm], axis=1)
    right = np.stack([along[:, 1], -along[:, 0]], axis=1)
    return along, right


def decompose(d_e: F64, d_n: F64, d_h: F64, along: F64, right: F64) -> F64:
    """(lines, pixels) error components → (lines·pixels, 3) along/across/height."""
    a = d_e * along[:, :1] + d_n * along[:, 1:]
    c = d_e * right[:, :1] + d_n * right[:, 1:]
    return np.stack([a.ravel(), c.ravel(), d_h.ravel()], axis=1)


def run_trajectory(run: Path, scn: Scenario, t_frames_gps_ns: npt.NDArray[np.int64],
                   log_fixes: AntennaFixes | None = None, *, check_log: bool = True
                   ) -> TruthTrajectory:
    """The scenario's true trajectory, checked against the run's truth frames: a scenario.toml
    changed after the run (another preset) put the frames outside it, a traceback later; and
    with `check_log` against the log's GPS fixes (`check_against_fixes`)."""
    traj = TruthTrajectory.from_scenario(scn)
    t = np.asarray(t_frames_gps_ns, dtype=np.int64)
    if t.size and (t.min() < traj.t_start_ns or t.max() > traj.t_end_ns):
        raise InputError(f"{run / 'scenario.toml'}: its flight "
                         f"({gps_span_label(traj.t_start_ns, traj.t_end_ns)}) does not hold the "
                         f"run's truth frames ({gps_span_label(int(t.min()), int(t.max()))}): "
                         "not the scenario this run was made from")
    if check_log:
        check_against_fixes(run, scn, traj, log_fixes)
    return traj


def check_against_fixes(run: Path, scn: Scenario, traj: TruthTrajectory,
                         fixes: AntennaFixes | None) -> None:
    """The flight a scenario.toml rebuilds against the run's own log: each logged GPS fix less
    the error the emulator recorded adding to it (truth/gps_fixes.csv) is where the rebuilt
    flight puts the antenna, to NMEA's rounding. A scenario edited after the run (another
    place, another seed: the same times) rebuilds another flight, and every error judged
    against it would be that flight's (found by a bad-input sweep: 8 px for a changed seed)."""
    from recorder.parts import flight_parts

    truth_csv = run / "truth" / "gps_fixes.csv"
    if not truth_csv.is_file():
        return  # a run without it cannot be checked; the frames' times were
    errors = read_truth_csv(truth_csv)
    if fixes is None:  # not read already (sisa process passes georef's)
        fixes = fixes_from_columns(read_topics(flight_parts([run / "flight.mcap"]),
                                               {Topic.GPS_FIX: FIX_FIELDS}, notes=[]))
    t, at_log, at_truth = np.intersect1d(fixes.t_gps_ns, errors["t_gps_ns"],
                                         return_indices=True)
    if t.size == 0:
        return  # no fix (an outage, a log without GPS): nothing to compare
    error_ned_m = np.stack([errors[f"error_{c}_m"] for c in "ned"], axis=1)[at_truth]
    truth_m = antenna_fix_ecef_m(traj.state(np.clip(t, traj.t_start_ns, traj.t_end_ns)),
                                 scn.mounting.antenna_offset_m, error_ned_m)
    apart_m = float(np.median(np.linalg.norm(fixes.ecef_m[at_log] - truth_m, axis=1)))
    if not apart_m <= FIX_AGREEMENT_M:
        raise InputError(f"{run / 'scenario.toml'}: the flight it describes passes "
                         f"{apart_m:.3g} m (median over {t.size} fixes) from the run's GPS "
                         "fixes less their recorded errors: not the scenario this run was made "
                         "from (edited after the run?)")


class TruthGround:
    """True ground position of every pixel of a segment, block by block. Built without the
    log (`check_log` False: `check_against_fixes` once it is read) and without the output CRS
    (`use_crs` once it is known), it can cast blocks ahead (`cast_ahead`) while the log is
    read."""

    def __init__(self, scn: Scenario, run: Path, out_epsg: int | None,
                 log_fixes: AntennaFixes | None = None, *, check_log: bool = True) -> None:
        self.scn = scn
        frames = read_truth_csv(run / "truth" / "frames.csv")
        self.traj = run_trajectory(run, scn, frames["t_mid_gps_ns"], log_fixes,
                                   check_log=check_log)
        self.terrain = Terrain.from_scenario(scn)
        self.intersector = GroundIntersector(self.terrain)
        self.look = scn.scanner.look_vectors_camera()
        kept = frames["line_index"] >= 0
        self.frames = {k: v[kept] for k, v in frames.items()}
        self._to_out: Transformer | None = None
        self._ahead: dict[tuple[int, int], tuple[npt.NDArray[np.int64], F64]] = {}
        if out_epsg is not None:
            self.use_crs(out_epsg)

    def use_crs(self, out_epsg: int) -> None:
        """The output CRS `ground` gives (E, N) in."""
        self._to_out = (None if out_epsg == self.terrain.epsg else
                        Transformer.from_crs(self.terrain.epsg, out_epsg, always_xy=True))

    def segment_lines(self) -> dict[int, int]:
        """segment → its lines as the truth knows them (an image may hold fewer)."""
        lines: dict[int, int] = {}
        for s, i in zip(self.frames["segment"].tolist(), self.frames["line_index"].tolist(),
                        strict=True):
            lines[s] = max(lines.get(s, 0), i + 1)
        return dict(sorted(lines.items()))

    def line_times(self, segment: int, lines: int) -> npt.NDArray[np.int64]:
        """The true time of each of the segment's first `lines` lines (an image cut short is
        georeferenced over the lines it holds; truth knows them all)."""
        sel = (self.frames["segment"] == segment) & (self.frames["line_index"] < lines)
        t = np.full(lines, -1, dtype=np.int64)
        t[self.frames["line_index"][sel]] = self.frames["t_mid_gps_ns"][sel]
        return t

    def cast_ahead(self, segment: int, first_line: int, t_ns: npt.NDArray[np.int64]) -> int:
        """Cast the block of the segment's lines from first_line at times t_ns now, for
        `ground` to take later; its bytes."""
        grid = self._cast(t_ns)
        self._ahead[(segment, first_line)] = (t_ns.copy(), grid)
        return grid.nbytes

    def ground(self, t_ns: npt.NDArray[np.int64], block: tuple[int, int] | None = None
               ) -> tuple[F64, F64, F64]:
        """(E, N, h) (lines, pixels) in the output CRS; NaN rows where t < 0. `block`
        (segment, first line): cast ahead at these very times, taken (the same numbers)."""
        ahead = self._ahead.pop(block, None) if block is not None else None
        out = ahead[1] if ahead is not None and np.array_equal(ahead[0], t_ns) else \
            self._cast(t_ns)
        e, n, h = out[..., 0], out[..., 1], out[..., 2]
        if self._to_out is not None:
            e, n = (np.asarray(v) for v in self._to_out.transform(e, n))
        return e, n, h

    def drop_ahead(self, before_segment: int) -> None:
        """Blocks cast ahead for segments before this one, never asked for (skipped)."""
        for key in [k for k in self._ahead if k[0] < before_segment]:
            del self._ahead[key]

    def _cast(self, t_ns: npt.NDArray[np.int64]) -> F64:
        """(lines, pixels, 3) ground in the terrain's CRS."""
        ok = t_ns >= 0
        out = np.full((t_ns.size, self.look.shape[1], 3), np.nan)
        if ok.any():
            centre, r_ce = camera_pose_ecef(self.traj.state(t_ns[ok]), self.scn.mounting)
            out[ok] = self.intersector.intersect_lines(centre, r_ce, self.look)
        return out


@dataclass
class CheckPoint:
    id: str
    segment: int
    line: float
    pixel: float
    err_m: F64  # along, across, height
    err_px: F64


def _bilinear(grid: F64, line: float, pixel: float) -> F64:
    """grid (lines, k, pixels) at a fractional (line, pixel)."""
    i0 = min(max(math.floor(line), 0), grid.shape[0] - 2)
    j0 = min(max(math.floor(pixel), 0), grid.shape[2] - 2)
    u, v = line - i0, pixel - j0
    g = np.asarray(grid[i0:i0 + 2, :, j0:j0 + 2], dtype=np.float64)
    return np.asarray((1 - u) * ((1 - v) * g[0, :, 0] + v * g[0, :, 1])
                      + u * ((1 - v) * g[1, :, 0] + v * g[1, :, 1]))


def _invert(te: F64, tn: F64, e: float, n: float, i: int, j: int) -> tuple[float, float]:
    """Sub-pixel (line, pixel) where the bilinear truth grid equals (e, n): Newton from the
    nearest pixel (i, j)."""
    li, pj = float(i), float(j)
    stack = np.stack([te, tn], axis=1)
    for _ in range(8):
        i0 = min(max(math.floor(li), 0), te.shape[0] - 2)
        j0 = min(max(math.floor(pj), 0), te.shape[1] - 2)
        u, v = li - i0, pj - j0
        g = stack[i0:i0 + 2, :, j0:j0 + 2]
        p = (1 - u) * ((1 - v) * g[0, :, 0] + v * g[0, :, 1]) + u * (
            (1 - v) * g[1, :, 0] + v * g[1, :, 1])
        d_du = (1 - v) * (g[1, :, 0] - g[0, :, 0]) + v * (g[1, :, 1] - g[0, :, 1])
        d_dv = (1 - u) * (g[0, :, 1] - g[0, :, 0]) + u * (g[1, :, 1] - g[1, :, 0])
        jac = np.stack([d_du, d_dv], axis=1)
        try:
            step = np.linalg.solve(jac, np.array([e, n]) - p)
        except np.linalg.LinAlgError:  # degenerate pixels (a missed ray): not found here
            return math.nan, math.nan
        li, pj = li + float(step[0]), pj + float(step[1])
        if abs(step[0]) + abs(step[1]) < 1e-9:
            break
    return li, pj


def segment_accuracy(truth: TruthGround, seg: SegmentResult, points: dict[str, Any],
                     seed: int = 0, stop: threading.Event | None = None
                     ) -> tuple[ErrorStats, list[CheckPoint]]:
    """One segment against truth, the truth cast once per block of lines: every pixel (IGM
    minus truth, along/across/height) and the check points inside its swath (found in the image
    through the truth, the IGM interpolated there, compared with the surveyed coordinates).
    `stop` set: the blocks left are not judged (a command stopped: its figures are dropped)."""
    igm = open_igm(seg.igm)
    t = truth.line_times(seg.segment, seg.lines)
    px = np.array([seg.gsd_along_m, seg.gsd_across_m, seg.gsd_across_m])
    stats = ErrorStats()
    rng = np.random.default_rng(seed)
    found: list[CheckPoint] = []
    for lo in range(0, seg.lines, BLOCK_LINES):
        if stop is not None and stop.is_set():
            break
        hi = min(lo + BLOCK_LINES + 1, seg.lines)  # one line of overlap between blocks
        own = min(BLOCK_LINES, hi - lo)  # the lines this block reports pixels for
        te, tn, th = truth.ground(t[lo:hi], (seg.segment, lo))
        blk = np.asarray(igm[lo:hi])
        along, right = along_across_axes(te, tn)
        err = decompose(blk[:own, 0] - te[:own], blk[:own, 1] - tn[:own],
                        blk[:own, 2] - th[:own], along[:own], right[:own])
        stats.add(err, px, rng)
        for pid, line, pixel, err_m in _check_points_in_block(te, tn, blk, points,
                                                              last=hi >= seg.lines):
            if not any(c.id == pid for c in found):
                found.append(CheckPoint(pid, seg.segment, lo + line, pixel, err_m, err_m / px))
    return stats, found


def _check_points_in_block(te: F64, tn: F64, blk: F64, points: dict[str, Any], *, last: bool
                           ) -> list[tuple[str, float, float, F64]]:
    """(id, line in the block, pixel, along/across/height error in m) of the check points whose
    nearest pixel lies inside this block."""
    out: list[tuple[str, float, float, F64]] = []
    if not np.isfinite(te).any():
        return out
    pe, pn, ph = points["easting_m"], points["northing_m"], points["height_m"]
    inside = ((pe > np.nanmin(te)) & (pe < np.nanmax(te)) & (pn > np.nanmin(tn))
              & (pn < np.nanmax(tn)))
    boxes = _row_boxes(te, tn) if inside.any() else np.zeros((4, 0))
    for k in np.flatnonzero(inside):
        if (nearest := _nearest_pixel(te, tn, boxes, float(pe[k]), float(pn[k]))) is None:
            continue
        i, j = nearest
        if (i in (0, te.shape[0] - 1) and not last) or j in (0, te.shape[1] - 1):
            continue  # on a block edge or the swath edge: not inside this block
        li, pj = _invert(te, tn, float(pe[k]), float(pn[k]), int(i), int(j))
        if not (0 <= li <= te.shape[0] - 1 and 0 <= pj <= te.shape[1] - 1):
            continue
        est = _bilinear(blk, li, pj)
        along, right = along_across_axes(te[max(int(li) - 2, 0):int(li) + 3],
                                         tn[max(int(li) - 2, 0):int(li) + 3])
        a, r = along[len(along) // 2], right[len(right) // 2]
        de, dn, dh = est[0] - pe[k], est[1] - pn[k], est[2] - ph[k]
        err = np.array([de * a[0] + dn * a[1], de * r[0] + dn * r[1], dh])
        out.append((str(points["id"][k]), li, pj, err))
    return out


def _row_boxes(te: F64, tn: F64) -> F64:
    """(4, lines): each line's least and greatest easting and northing, NaN for a line of
    NaN only (fmin/fmax: NaN pixels left out, without numpy's all-NaN warning)."""
    return np.stack([np.fmin.reduce(te, axis=1), np.fmax.reduce(te, axis=1),
                     np.fmin.reduce(tn, axis=1), np.fmax.reduce(tn, axis=1)])


def _nearest_pixel(te: F64, tn: F64, boxes: F64, e: float, n: float
                   ) -> tuple[int, int] | None:
    """(line, pixel) of the first pixel nearest (e, n), as np.nanargmin over the whole block
    finds it; None if no pixel is finite. Only the lines whose box can hold it are searched:
    a line's bound (its box's distance², each step monotonic in floating point) is never
    above any of its pixels' d², so a line left out holds no pixel as near as one found."""
    de = np.maximum(np.maximum(boxes[0] - e, e - boxes[1]), 0.0)
    dn = np.maximum(np.maximum(boxes[2] - n, n - boxes[3]), 0.0)
    bound = de ** 2 + dn ** 2
    if not np.isfinite(bound).any():
        return None
    first = int(np.nanargmin(bound))
    near = ((te[first] - e) ** 2 + (tn[first] - n) ** 2)
    if not np.isfinite(near).any():  # a line of eastings without northings: search all
        rows = np.arange(te.shape[0])
    else:
        rows = np.flatnonzero(bound <= np.nanmin(near))
    d2 = (te[rows] - e) ** 2 + (tn[rows] - n) ** 2
    if not np.isfinite(d2).any():
        return None
    i, j = np.unravel_index(int(np.nanargmin(d2)), d2.shape)
    return int(rows[i]), int(j)


def check_points(path: Path, epsg: int) -> dict[str, Any]:
    """The check points of a ground points file (calib_data's reader: one-line errors for a
    damaged file), as id, easting_m, northing_m, height_m (ellipsoidal) in `epsg`, and ecef_m."""
    points = read_ground_points(path)
    check = points.kind == "check"
    lat, lon, h = ecef_to_geodetic(points.ecef_m[check])
    east, north = Transformer.from_crs(4326, epsg, always_xy=True).transform(lon, lat)
    return {"id": points.ids[check], "easting_m": np.asarray(east, dtype=np.float64),
            "northing_m": np.asarray(north, dtype=np.float64), "height_m": h,
            "ecef_m": points.ecef_m[check]}


def check_point_summary(points: list[CheckPoint]) -> dict[str, Any]:
    """RMS of the check points on georeferenced lines; those seen on a line left without a
    time or pose (no position: NaN) are counted apart, not averaged in."""
    measured = [p for p in points if np.isfinite(p.err_m).all()]
    missing = len(points) - len(measured)
    if not measured:
        return {"points": 0, "not_georeferenced": missing}
    e_m = np.array([p.err_m for p in measured])
    e_px = np.array([p.err_px for p in measured])
    out: dict[str, Any] = {"points": len(measured),
                           "distinct": len({p.id for p in measured}),
                           "not_georeferenced": missing}
    for i, c in enumerate(COMPONENTS):
        out[c] = {"rms_m": float(np.sqrt(np.mean(e_m[:, i] ** 2))),
                  "mean_m": float(np.mean(e_m[:, i])),
                  "rms_px": float(np.sqrt(np.mean(e_px[:, i] ** 2))),
                  "max_abs_px": float(np.abs(e_px[:, i]).max())}
    return out


def no_check_points() -> dict[str, Any]:
    """`check_points`' columns for a run without a ground points file."""
    return {"id": np.zeros(0, str), "easting_m": np.zeros(0), "northing_m": np.zeros(0),
            "height_m": np.zeros(0), "ecef_m": np.zeros((0, 3))}


class RunAccuracy:
    """A run's accuracy summed segment by segment, in the order they are added (the order
    fixes the float sums): a caller may add each segment as soon as its IGM is written."""

    def __init__(self, scn: Scenario, run: Path, epsg: int,
                 log_fixes: AntennaFixes | None = None, truth: TruthGround | None = None
                 ) -> None:
        """`truth`: built before (without the log's check or the CRS: both done here)."""
        if truth is None:
            truth = TruthGround(scn, run, epsg, log_fixes)
        else:
            check_against_fixes(run, scn, truth.traj, log_fixes)
            truth.use_crs(epsg)
        self.truth = truth
        gp_csv = run / "terrain" / "ground_points.csv"
        self.points = check_points(gp_csv, epsg) if gp_csv.is_file() else no_check_points()
        self.total = ErrorStats()
        self.per_segment: list[dict[str, Any]] = []
        self.checks: list[CheckPoint] = []

    def add(self, seg: SegmentResult, stop: threading.Event | None = None) -> None:
        self.truth.drop_ahead(seg.segment)
        stats, found = segment_accuracy(self.truth, seg, self.points, seed=seg.segment,
                                        stop=stop)
        self.per_segment.append({"segment": seg.segment, **stats.summary()})
        self.total.merge(stats)
        self.checks += found

    def summary(self) -> dict[str, Any]:
        """accuracy.json's figures, and the report's sample of pixel errors (`_sample_px`)."""
        checks, sample = self.checks, self.total.sample_px
        return {"pixels": self.total.summary(), "segments": self.per_segment,
                "check_points": check_point_summary(checks),
                "check_point_list": [{"id": c.id, "segment": c.segment, "line": c.line,
                                      "pixel": c.pixel, "err_m": c.err_m.tolist(),
                                      "err_px": c.err_px.tolist()} for c in checks],
                "_sample_px": np.concatenate(sample) if sample else np.zeros((0, 3))}
