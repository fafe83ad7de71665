"""From files to the least-squares problem: which observations and points take part, their
geometry, the origin, and starting coordinates for tie points.

Rules (each dropped item is named in the notes, never silently lost):
- an observation needs a known point, a timed line (both neighbours of a fractional line) and
  a navigation pose at its time;
- control points take part with one observation or more (their coordinates are observed);
- tie points need observations in two segments or more; with one ray a tie point is free;
- check points are kept to test the adjustment; with `check_heights` (seed 000's procedure)
  they also enter it with only their surveyed height observed, so their horizontal position is
  estimated from the images alone and compared with the survey.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from postproc.calibration.data import GroundPoints, ImageObservations, SegmentClock
from postproc.calibration.model import ObsGeometry, PoseModel
from postproc.calibration.navigation import NavKnots
from postproc.calibration.params import State
from postproc.calibration.problem import PointSet
from postproc.calibration.surface import GivenHeights, Surface, intersect_rays
from postproc.georef import SensorModel, Trajectory, ecef_to_geodetic
from sisa.core.errors import InputError, shown_value

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Bool = npt.NDArray[np.bool_]

HEIGHT_ONLY_SIGMA_M = 1e9  # a check point's horizontal "observation": no weight at all
SENSOR_FIT_MARGIN_PX = 3.0  # measurements this far past the detector's ends are noise
NOTE_EXAMPLES = 3  # items a note names; the count says how many more there are


@dataclass
class Notes:
    """What was left out and why, one line per reason (calibration.json's notes, and the
    command's warnings)."""

    lines: list[str] = field(default_factory=list)

    def add(self, count: int, text: str, examples: list[str] | None = None) -> None:
        """`count` items, naming the first few of `examples` so they can be found."""
        if not count:
            return
        named = (examples or [])[:NOTE_EXAMPLES]
        more = f", and {count - len(named)} more" if named and count > len(named) else ""
        self.lines.append(f"{count} {text}" + (f" ({', '.join(named)}{more})" if named else ""))


def observation_names(obs: ImageObservations, which: Bool) -> list[str]:
    """The first few observations of a note, as their file gives them."""
    return [f"{obs.point_id[k]} in segment {obs.segment[k]} at line {obs.line[k]:g}"
            for k in np.flatnonzero(which)[:NOTE_EXAMPLES].tolist()]


def line_geometry(obs: ImageObservations, clock: SegmentClock, point_row: I64,
                  seg_k: I64, knots: NavKnots | None = None) -> ObsGeometry:
    t = clock.time_of(obs.segment, obs.line)
    mid = {s: _segment_mid_ns(clock, s) for s in np.unique(obs.segment).tolist()}
    t_mid = np.array([mid[int(s)] for s in obs.segment.tolist()], dtype=np.int64)
    period = np.array([clock.line_period_ns(int(s)) for s in obs.segment.tolist()])
    nav = None if knots is None else knots.weights(obs.segment, t)
    return ObsGeometry(point_row, seg_k, t, (t - t_mid).astype(np.float64) * 1e-9, period,
                       obs.line, obs.pixel, obs.sigma_px, nav)


def _segment_mid_ns(clock: SegmentClock, segment: int) -> int:
    t = clock.t_by_segment[segment]
    t = t[t >= 0]
    return int(t[0] + (t[-1] - t[0]) // 2) if t.size else 0


def usable_observations(obs: ImageObservations, points: GroundPoints, clock: SegmentClock,
                        traj: Trajectory, delay_ms: float, notes: Notes) -> ImageObservations:
    """Observations with a known point, a timed line and a pose (at the starting delay)."""
    points.index_of(obs.point_id, "observations")
    known_seg = np.array([int(s) in clock.t_by_segment for s in obs.segment.tolist()],
                         dtype=np.bool_)
    notes.add(int((~known_seg).sum()), "observations in a segment the recording does not have",
              observation_names(obs, ~known_seg))
    t = clock.time_of(obs.segment, obs.line)
    timed = known_seg & (t >= 0)
    notes.add(int((known_seg & ~timed).sum()), "observations on an untimed line or off the "
              "image: left out", observation_names(obs, known_seg & ~timed))
    posed = np.zeros(len(obs), dtype=np.bool_)
    if timed.any():
        posed[timed] = traj.pose_at(t[timed] + np.int64(round(delay_ms * 1e6))).valid
    notes.add(int((timed & ~posed).sum()), "observations outside the navigation solution: "
              "left out", observation_names(obs, timed & ~posed))
    return obs.select(posed)


def split_points(obs: ImageObservations, points: GroundPoints, notes: Notes,
                 check_heights: bool = False) -> tuple[GroundPoints, GroundPoints]:
    """(points of the adjustment: control, tie (and check), check points that were
    observed)."""
    idx = points.index_of(obs.point_id, "observations")
    n_obs = np.bincount(idx, minlength=len(points))
    n_seg = np.array([np.unique(obs.segment[idx == p]).size for p in range(len(points))])
    ctl = (points.kind == "control") & (n_obs >= 1)
    tie = (points.kind == "tie") & (n_seg >= 2)
    chk = (points.kind == "check") & (n_obs >= 1)
    unseen = (points.kind == "control") & (n_obs == 0)
    notes.add(int(unseen.sum()), "control points without an observation: not used",
              points.ids[unseen].tolist())
    lone = (points.kind == "tie") & (n_seg < 2)
    notes.add(int(lone.sum()), "tie points seen in fewer than two segments: left out",
              points.ids[lone].tolist())
    if not ctl.any():
        why = f" ({'; '.join(notes.lines)})" if notes.lines else ""
        raise InputError(f"no control point is observed: calibration needs ground control{why}")
    return points.select(ctl | tie | (chk & check_heights)), points.select(chk)


def point_set(adj: GroundPoints, origin: F64, sigma_hv_m: tuple[float, float],
              dem_control: bool) -> PointSet:
    ctl = adj.kind != "tie"
    surveyed = np.where(ctl[:, None], adj.ecef_m - origin, np.nan)
    h, v = sigma_hv_m
    sig = np.tile([h, h, v], (len(adj), 1)).astype(np.float64)
    sig[adj.kind == "check", :2] = HEIGHT_ONLY_SIGMA_M
    return PointSet(adj.ids, adj.kind, surveyed, sig, (adj.kind == "tie") & dem_control)


def start_coordinates(model: PoseModel, st: State, ps: PointSet, surface: Surface | None,
                      mean_height_m: float) -> F64:
    """Control points at their survey; tie points where their first ray meets the surface (the
    DEM, else the control points' mean height); check points on their surveyed height."""
    x = np.where(ps.kind[:, None] == "control", ps.surveyed_m, 0.0)
    free = np.flatnonzero(ps.kind != "control")
    if free.size == 0:
        return np.asarray(x, np.float64)
    first = np.array([int(np.flatnonzero(model.obs.point == p)[0]) for p in free.tolist()])
    centre, d = model.ray(st, model.pose_at_delay(st.delay_ms))
    c_ecef, d = centre[first] + model.origin, d[first]
    ground = np.full((free.size, 3), np.nan)
    tie = ps.kind[free] == "tie"
    if surface is not None and tie.any():
        ground[tie] = intersect_rays(surface, c_ecef[tie], d[tie])
    _, _, h_chk = ecef_to_geodetic(ps.surveyed_m[free] + model.origin)
    h = np.where(tie, mean_height_m, h_chk)
    flat = ~np.isfinite(ground).all(axis=1)
    if flat.any():
        ground[flat] = intersect_rays(GivenHeights(h[flat]), c_ecef[flat], d[flat])
    x[free] = ground - model.origin
    return np.asarray(x, np.float64)


def mean_height(points: GroundPoints) -> float:
    _, _, h = ecef_to_geodetic(points.ecef_m[points.kind == "control"])
    return float(np.mean(h))


def check_sensor_fits(sensor: SensorModel, obs: ImageObservations,
                      margin_px: float = SENSOR_FIT_MARGIN_PX) -> None:
    """Measurements beyond the detector's ends (more than a few pixels of noise) mean a
    sensor file for another instrument."""
    px = sensor.scanner.pixels
    off = (obs.pixel < -0.5 - margin_px) | (obs.pixel > px - 0.5 + margin_px)
    if off.any():
        k = int(np.argmax(off))
        raise InputError(f"observation of {obs.point_id[k]} at pixel {obs.pixel[k]:g}, but the "
                         f"sensor file {shown_value(sensor.name)} has {px} pixels: wrong sensor "
                         "file?")
