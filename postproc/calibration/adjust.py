"""System calibration of the line scanner from ground control (docs/calibration.md).

    inp = CalibrationInput(traj, SegmentClock.from_line_times(sync.lines), points, obs, sensor,
                           dem)
    result = calibrate(inp, CalibrationOptions(groups=parse_groups("boresight,selfcal,delay")))
    result.sensor          # the calibrated SensorModel: `sisa georef --sensor` takes it
    report_json(result)    # estimates, σ, correlations, residuals, check points, blunders

A least-squares adjustment (seed 000 §5.4, GeoTeX-like) of the pushbroom model with the
navigation solution as given: image observations of control points (with their survey σ), tie
points between strips and, optionally, DEM surface control of the tie points' heights. Blunders
are found by data snooping: after each adjustment the observation (or control point) with the
largest standardised residual w = v / (σ·√r), r its redundancy number, is rejected if |w|
exceeds k (4 by default, with σ rescaled by a robust σ0 when the stated precision is too
optimistic), and the adjustment is repeated. Nothing here reads simulation truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Final

import numpy as np
import numpy.typing as npt
from pydantic import ValidationError

from postproc.calibration.check import (
    CheckSetup,
    check_rows,
    check_summary,
    control_rms_m,
    ground_errors,
    predicted_variance,
)
from postproc.calibration.data import GroundPoints, ImageObservations, SegmentClock
from postproc.calibration.model import DELAY_GRID_MS, CameraModel, line_model
from postproc.calibration.navigation import (
    Navigation,
    NavKnots,
    build_knots,
    per_segment,
)
from postproc.calibration.params import (
    DEFAULT_GROUPS,
    Group,
    Layout,
    PriorSigmas,
    State,
    build_layout,
)
from postproc.calibration.problem import CONTROL, IMAGE_ACROSS, IMAGE_ALONG, Problem
from postproc.calibration.setup import (
    Notes,
    check_sensor_fits,
    line_geometry,
    mean_height,
    observation_names,
    point_set,
    split_points,
    start_coordinates,
    usable_observations,
)
from postproc.calibration.solve import Solution, covariance, gauss_newton, leverages
from postproc.calibration.surface import DemSurface, Surface
from postproc.georef import CALIBRATED_SUFFIX, Dem, SensorModel, Trajectory
from sisa.core.errors import ConfigError, InputError
from sisa.core.sensor import validation_text

F64 = npt.NDArray[np.float64]
MAD_TO_SIGMA: Final = 1.4826


@dataclass(frozen=True)
class CalibrationOptions:
    groups: tuple[Group, ...] = DEFAULT_GROUPS
    gcp_sigma_m: tuple[float, float] = (0.5, 0.5)  # survey σ horizontal, vertical
    dem_sigma_m: float = 2.0
    dem_control: bool = True  # DEM height rows for tie points (when a DEM is given)
    check_heights: bool = False  # check points in the adjustment, height only (seed 000)
    priors: PriorSigmas = field(default_factory=PriorSigmas)
    snooping_k: float = 4.0
    max_blunder_fraction: float = 0.2

    def __post_init__(self) -> None:
        if not (min(self.gcp_sigma_m) > 0 and self.dem_sigma_m > 0 and self.snooping_k > 0):
            raise ConfigError("calibration: σ of control points and DEM and the snooping "
                              "threshold must be > 0")


@dataclass(frozen=True)
class CalibrationInput:
    traj: Trajectory
    clock: SegmentClock
    points: GroundPoints  # control, check and tie points
    obs: ImageObservations
    sensor: SensorModel  # the starting values (and everything not estimated)
    dem: Dem | Surface | None = None  # a Surface: several flights' DEMs (calib_flights)
    # the trajectory's stated accuracy (one, or per segment); None: σ leave navigation out
    navigation: Navigation = None


@dataclass
class Adjustment:
    """One built problem and what it was built from."""

    problem: Problem
    layout: Layout
    x0: F64
    adj_points: GroundPoints
    obs: ImageObservations  # the adjustment's observations (control + tie)
    check: CheckSetup | None
    check_ids: npt.NDArray[np.str_]
    surface: Surface | None
    notes: Notes


@dataclass
class CalibrationResult:
    layout: Layout
    theta: F64
    state: State
    sigma: F64  # a-posteriori σ of θ
    correlation: F64
    covariance: F64  # σ0²·Q
    sigma0: float
    dof: int
    iterations: int
    sensor: SensorModel
    residuals: list[dict[str, Any]]
    blunders: list[dict[str, Any]]
    points: list[dict[str, Any]]
    check: dict[str, Any] | None
    check_list: list[dict[str, Any]]
    counts: dict[str, int]
    notes: list[str]
    sigma_share: F64 | None = None  # (G, 3): observations, navigation, priors
    navigation: dict[str, Any] | None = None  # the navigation model's summary
    conditioning: dict[str, Any] = field(default_factory=dict)  # conditioning.assess


def build(inp: CalibrationInput, opt: CalibrationOptions) -> Adjustment:
    """Select observations and points, lay out θ, and start the tie points."""
    notes = Notes()
    sensor = inp.sensor
    check_sensor_fits(sensor, inp.obs)
    obs = usable_observations(inp.obs, inp.points, inp.clock, inp.traj, sensor.time_delay_ms,
                              notes)
    adj_pts, chk_pts = split_points(obs, inp.points, notes, opt.check_heights)
    in_adj = np.isin(obs.point_id, adj_pts.ids)
    in_chk = np.isin(obs.point_id, chk_pts.ids)
    a_obs = obs.select(in_adj)
    segments = sorted(set(a_obs.segment.tolist()))
    c_obs = obs.select(in_chk & np.isin(obs.segment, segments))
    knots = _knots(inp, segments, a_obs, c_obs, notes)
    layout = build_layout(opt.groups, segments, sensor, opt.priors, knots)
    origin = np.mean(adj_pts.ecef_m[adj_pts.kind == "control"], axis=0)
    geom = line_geometry(a_obs, inp.clock, adj_pts.index_of(a_obs.point_id, "observations"),
                         layout.seg_index(a_obs.segment), knots)
    model = CameraModel(inp.traj, sensor, geom, origin,
                        DELAY_GRID_MS if Group.DELAY in opt.groups else None)
    surface: Surface | None = (None if inp.dem is None else DemSurface(inp.dem)
                               if isinstance(inp.dem, Dem) else inp.dem)
    ps = point_set(adj_pts, origin, opt.gcp_sigma_m, opt.dem_control and surface is not None)
    x0 = start_coordinates(model, layout.base, ps, surface, mean_height(adj_pts))
    if surface is not None and ps.dem_control.any():
        _, hs = surface.heights(x0[ps.dem_control] + origin)
        off = ~np.isfinite(hs)
        notes.add(int(off.sum()), "tie points off the DEM: no surface control for them",
                  ps.ids[ps.dem_control][off].tolist())
        dem_ctl = ps.dem_control.copy()
        dem_ctl[np.flatnonzero(ps.dem_control)[off]] = False
        ps = replace(ps, dem_control=dem_ctl)
    problem = Problem(model, layout, ps, surface, opt.dem_sigma_m)
    unchecked = in_chk & ~np.isin(obs.segment, segments)
    notes.add(int(unchecked.sum()), "check observations in a segment without control: not "
              "checked", observation_names(obs, unchecked))
    check = None
    if len(c_obs):
        cgeom = line_geometry(c_obs, inp.clock, np.zeros(len(c_obs), np.int64),
                              layout.seg_index(c_obs.segment), knots)
        rows = chk_pts.index_of(c_obs.point_id, "observations")
        check = CheckSetup(CameraModel(inp.traj, sensor, cgeom, origin),
                           chk_pts.ecef_m[rows], surface, opt.gcp_sigma_m[0],
                           opt.dem_sigma_m if surface is not None else opt.gcp_sigma_m[1])
    return Adjustment(problem, layout, x0, adj_pts, a_obs, check, c_obs.point_id, surface,
                      notes)


def _knots(inp: CalibrationInput, segments: list[int], a_obs: ImageObservations,
           c_obs: ImageObservations, notes: Notes) -> NavKnots | None:
    """The navigation model's knots over each segment's observations (adjustment and check),
    from the trajectory's stated accuracy; None (and a note) without one."""
    accuracy = per_segment(inp.navigation, segments)
    if not accuracy:
        notes.add(1, "trajectory without a stated accuracy: σ leave out the navigation's own "
                  "error (give --nav-sigma-m)")
        return None
    spans: dict[int, tuple[int, int]] = {}
    for o in (a_obs, c_obs):
        t = inp.clock.time_of(o.segment, o.line)
        for s in np.unique(o.segment[t >= 0]).tolist():
            ts = t[(o.segment == s) & (t >= 0)]
            lo, hi = spans.get(int(s), (int(ts.min()), int(ts.max())))
            spans[int(s)] = (min(lo, int(ts.min())), max(hi, int(ts.max())))
    return build_knots(accuracy, spans)


def _standardised(sol: Solution) -> F64:
    cov = covariance(sol.norm)
    h = leverages(sol.lin, cov)
    return np.asarray(sol.lin.r / np.sqrt(np.maximum(1.0 - h, 1e-6)), np.float64)


def _worst(sol: Solution, k: float) -> tuple[int, int, float] | None:
    """(row kind, item, |w|/scale) of the worst observation or control point above k."""
    w = _standardised(sol)
    lin = sol.lin
    img = (lin.row_kind == IMAGE_ALONG) | (lin.row_kind == IMAGE_ACROSS)
    scale = max(1.0, MAD_TO_SIGMA * float(np.median(np.abs(w[img])))) if img.any() else 1.0
    cand = img | (lin.row_kind == CONTROL)
    if not cand.any():
        return None
    t = np.where(cand, np.abs(w) / scale, 0.0)
    i = int(np.argmax(t))
    if t[i] <= k:
        return None
    kind = CONTROL if lin.row_kind[i] == CONTROL else IMAGE_ALONG
    return kind, int(lin.row_item[i]), float(t[i])


def _reject(adj: Adjustment, kind: int, item: int, w: float, sol: Solution
            ) -> dict[str, Any]:
    """Switch the item off; drop points its loss leaves undetermined."""
    pb = adj.problem
    entry: dict[str, Any]
    if kind == CONTROL:
        pb.gcp_active[item] = False
        entry = {"kind": "control coordinates", "id": str(pb.points.ids[item]), "w": w}
    else:
        pb.obs_active[item] = False
        o = adj.obs
        entry = {"kind": "image", "id": str(o.point_id[item]), "segment": int(o.segment[item]),
                 "line": float(o.line[item]), "pixel": float(o.pixel[item]), "w": w}
    obs_in = pb.obs_in()
    dropped = []
    for p in np.flatnonzero(pb.point_active).tolist():
        segs = np.unique(pb.model.obs.seg_k[obs_in & (pb.model.obs.point == p)])
        held = bool(pb.gcp_active[p]) and (str(pb.points.kind[p]) == "control"
                                           or segs.size >= 1)
        if not held and segs.size < 2:
            pb.point_active[p] = False
            dropped.append(str(pb.points.ids[p]))
    # two rays of a tie point share a blunder's residual equally: the point goes, whichever
    # of its rays was wrong
    entry["points_dropped"] = dropped
    return entry


def adjust(adj: Adjustment, opt: CalibrationOptions) -> tuple[Solution, list[dict[str, Any]]]:
    """Gauss–Newton, then data snooping until no standardised residual exceeds k."""
    sol = gauss_newton(adj.problem, adj.problem.theta0.copy(), adj.x0.copy())
    blunders: list[dict[str, Any]] = []
    limit = math.floor(opt.max_blunder_fraction * len(adj.obs))
    while len(blunders) < limit:
        worst = _worst(sol, opt.snooping_k)
        if worst is None:
            break
        blunders.append(_reject(adj, *worst, sol))
        sol = gauss_newton(adj.problem, sol.theta, sol.x_m)
    return sol, blunders


def calibrated_sensor(sensor: SensorModel, st: State) -> SensorModel:
    """The sensor file with the estimated values (antenna offset = file's + Δg), checked as a
    sensor file is read: an adjustment gone astray (a boresight beyond 180°, a focal length
    below zero) is an error naming the value, not a file `sisa georef` would refuse."""
    g = np.asarray(sensor.mounting.antenna_offset_m) + st.antenna_delta_m
    table = sensor.model_dump(mode="json")
    table["mounting"].update(antenna_offset_m=[float(v) for v in g],
                             boresight_arcsec=[float(a) for a in st.boresight_arcsec])
    table["scanner"].update(delta_focal_mm=float(st.selfcal[0]),
                            delta_principal_point_um=[float(st.selfcal[1]),
                                                      float(st.selfcal[2])])
    table["time_delay_ms"] = float(st.delay_ms)
    if not sensor.name.endswith(CALIBRATED_SUFFIX):
        table["name"] = sensor.name + CALIBRATED_SUFFIX
    try:
        return SensorModel.model_validate(table)
    except ValidationError as exc:
        raise InputError(f"the adjustment's sensor is no sensor: {validation_text(exc)}: it "
                         "did not converge to a plausible sensor; look for blunders among the "
                         "observations, or leave that group out of --estimate") from None


def check_points(adj: Adjustment, theta: F64, cov: F64
                 ) -> tuple[dict[str, Any] | None, list[dict[str, Any]]]:
    if adj.check is None:
        return None, []
    err = ground_errors(adj.check, adj.layout, theta)
    var_a, var_c = predicted_variance(adj.check, adj.layout, theta, cov, err)
    return (check_summary(err, var_a, var_c, adj.check_ids),
            check_rows(adj.check, err, var_a, var_c, adj.check_ids))


def sweep_delay(inp: CalibrationInput, opt: CalibrationOptions, delays_ms: F64
                ) -> dict[str, Any]:
    """The seed's sweep (seed 003 §5): for each trial delay, adjust the other groups with the
    delay held, georeference the control observations onto their surveyed heights and take the
    horizontal RMS; the minimum (a parabola through the best three) is the delay."""
    groups = tuple(g for g in opt.groups if g is not Group.DELAY)
    rms: list[float] = []
    for d in delays_ms.tolist():
        sensor = inp.sensor.model_copy(update={"time_delay_ms": float(d)})
        trial = build(replace(inp, sensor=sensor), replace(opt, groups=groups))
        sol = gauss_newton(trial.problem, trial.problem.theta0.copy(), trial.x0.copy())
        rms.append(control_rms_m(control_setup(trial, inp), trial.layout, sol.theta))
    r = np.asarray(rms)
    i = int(np.clip(np.nanargmin(r), 1, r.size - 2))
    x, y = delays_ms[i - 1:i + 2], r[i - 1:i + 2]
    a, b, _ = np.polyfit(x, y, 2)
    best = float(-b / (2 * a)) if a > 0 else float(delays_ms[int(np.nanargmin(r))])
    return {"delays_ms": delays_ms.tolist(), "rms_m": r.tolist(), "best_ms": best}


def control_setup(adj: Adjustment, inp: CalibrationInput) -> CheckSetup:
    """The control observations as if they were check points, cast on surveyed heights."""
    m = line_model(adj.problem.model)
    rows = inp.points.index_of(adj.obs.point_id, "observations")
    return CheckSetup(m, inp.points.ecef_m[rows], None, 0.0, 0.0)
