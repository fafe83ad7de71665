"""Calibration of the frame camera: its boresight (and, if asked, focal length, principal point,
delay, antenna offset) from image measurements of ground control in its photos, in the line
scanner's adjustment (docs/calibration.md, "The frame camera").

    inp = PhotoCalibrationInput(traj, times, points, obs, camera, dem)
    result = calibrate_photos(inp, CalibrationOptions(groups=(Group.BORESIGHT,)))
    result.camera            # the calibrated FrameCamera
    photo_report_json(result)

The observations are `ImageObservations` read the frame camera's way: `segment` is the photo
number, `line` its row and `pixel` its column (0-based, pixel centres, rows down). A photo is
timed by the photo times table; everything else is the scanner's: the same points (control,
tie seen in two photos, check), the same rows (image, control, DEM, priors), the same
Gauss–Newton with the points eliminated, the same data snooping and σ. Per-strip groups
(`gps_strip`, `attitude`, `drift`) are per photo here. The trajectory's stated accuracy
(`navigation`) becomes the scanner's Gauss–Markov model of the GPS error, one chain of knots
over the photos' times: at 900 m a 3 cm GPS error turns a ray by 7″, which the σ of a few
tens of photos must carry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from pydantic import ValidationError

from postproc.calibration.adjust import Adjustment, CalibrationOptions, adjust
from postproc.calibration.data import GroundPoints, ImageObservations
from postproc.calibration.framemodel import FrameCameraModel
from postproc.calibration.model import DELAY_GRID_MS, ObsGeometry
from postproc.calibration.navigation import NavigationAccuracy, NavKnots, build_knots
from postproc.calibration.params import Group, Layout, State, build_layout
from postproc.calibration.problem import Problem
from postproc.calibration.setup import (
    Notes,
    mean_height,
    point_set,
    split_points,
    start_coordinates,
)
from postproc.calibration.solve import posterior, reported
from postproc.calibration.surface import DemSurface, Surface
from postproc.georef import Dem, PhotoTimes, Trajectory
from sisa.core.errors import InputError
from sisa.core.framecamera import FrameCamera
from sisa.core.sensor import validation_text

F64 = npt.NDArray[np.float64]

NOTE_EXAMPLES = 3


@dataclass(frozen=True)
class PhotoCalibrationInput:
    traj: Trajectory
    times: PhotoTimes  # photo number → mid-exposure GPS ns
    points: GroundPoints  # control, check and tie points
    obs: ImageObservations  # segment = photo number, line = row, pixel = col
    camera: FrameCamera  # the starting values (and everything not estimated)
    dem: Dem | Surface | None = None
    time_delay_ms: float = 0.0  # a photo's true exposure is this much after its time
    # the trajectory's stated accuracy; None: σ leave the navigation's own error out
    navigation: NavigationAccuracy | None = None


@dataclass
class PhotoCalibrationResult:
    layout: Layout
    theta: F64
    state: State
    sigma: F64  # a-posteriori σ of θ
    correlation: F64
    sigma0: float
    dof: int
    iterations: int
    camera: FrameCamera
    residual_rms_px: tuple[float, float]  # (row, col) of the measurements used
    counts: dict[str, int]
    blunders: list[dict[str, Any]]
    notes: list[str] = field(default_factory=list)


def start_state(camera: FrameCamera, delay_ms: float, n_photos: int, n_knots: int = 0
                ) -> State:
    """The camera file's boresight and delay; self-calibration and every correction zero."""
    z = np.zeros((n_photos, 3))
    return State(np.array(camera.mounting.boresight_arcsec, np.float64), np.zeros(3),
                 float(delay_ms), np.zeros(3), np.zeros(3), z, z.copy(), z.copy(),
                 np.zeros((n_knots, 3)))


def _knots(inp: PhotoCalibrationInput, t_ns: npt.NDArray[np.int64], notes: Notes
           ) -> NavKnots | None:
    """The navigation model's knots over the photos' times: one chain of the stated accuracy
    from the first photo to the last (the photos are one 'segment' to it: the GPS error of
    photos seconds apart is one process, whichever strip they are on)."""
    if inp.navigation is None or not inp.navigation.modelled or t_ns.size == 0:
        notes.add(1, "trajectory without a stated accuracy: σ leave out the navigation's own "
                  "error (give --nav-sigma-m)")
        return None
    return build_knots({0: inp.navigation}, {0: (int(t_ns.min()), int(t_ns.max()))})


def _usable(inp: PhotoCalibrationInput, notes: Notes) -> ImageObservations:
    """Observations of known points in timed photos with a pose, inside the frame."""
    obs = inp.obs
    inp.points.index_of(obs.point_id, "observations")
    iop = inp.camera.interior
    inside = ((obs.pixel >= -0.5) & (obs.pixel <= iop.width_px - 0.5)
              & (obs.line >= -0.5) & (obs.line <= iop.height_px - 0.5))
    notes.add(int((~inside).sum()), "observations outside the photo's frame: left out",
              _names(obs, ~inside))
    t = inp.times.time_of(obs.segment)
    timed = inside & (t >= 0)
    notes.add(int((inside & ~timed).sum()), "observations in a photo without a time: left out",
              _names(obs, inside & ~timed))
    posed = np.zeros(len(obs), np.bool_)
    if timed.any():
        posed[timed] = inp.traj.pose_at(
            t[timed] + np.int64(round(inp.time_delay_ms * 1e6))).valid
    notes.add(int((timed & ~posed).sum()), "observations outside the navigation solution: "
              "left out", _names(obs, timed & ~posed))
    return obs.select(posed)


def _names(obs: ImageObservations, which: npt.NDArray[np.bool_]) -> list[str]:
    return [f"{obs.point_id[k]} in photo {obs.segment[k]}"
            for k in np.flatnonzero(which)[:NOTE_EXAMPLES].tolist()]


def build_photos(inp: PhotoCalibrationInput, opt: CalibrationOptions) -> Adjustment:
    """The adjustment of the frame camera's observations (no check-point setup)."""
    notes = Notes()
    obs = _usable(inp, notes)
    adj_pts, _ = split_points(obs, inp.points, notes, opt.check_heights)
    a_obs = obs.select(np.isin(obs.point_id, adj_pts.ids))
    photos = sorted(set(a_obs.segment.tolist()))
    t_obs = inp.times.time_of(a_obs.segment)
    knots = _knots(inp, t_obs, notes)
    n_knots = 0 if knots is None else knots.count
    layout = build_layout(opt.groups, photos, start_state(inp.camera, inp.time_delay_ms,
                                                          len(photos), n_knots),
                          opt.priors, knots)
    origin = np.mean(adj_pts.ecef_m[adj_pts.kind == "control"], axis=0)
    n = len(a_obs)
    nav = None if knots is None else knots.weights(np.zeros(n, np.int64), t_obs)
    geom = ObsGeometry(adj_pts.index_of(a_obs.point_id, "observations"),
                       layout.seg_index(a_obs.segment), t_obs, np.zeros(n), np.ones(n),
                       a_obs.line, a_obs.pixel, a_obs.sigma_px, nav)
    model = FrameCameraModel(inp.traj, inp.camera, geom, origin,
                             DELAY_GRID_MS if Group.DELAY in opt.groups else None)
    surface: Surface | None = (None if inp.dem is None else DemSurface(inp.dem)
                               if isinstance(inp.dem, Dem) else inp.dem)
    ps = point_set(adj_pts, origin, opt.gcp_sigma_m, opt.dem_control and surface is not None)
    x0 = start_coordinates(model, layout.base, ps, surface, mean_height(adj_pts))
    problem = Problem(model, layout, ps, surface, opt.dem_sigma_m)
    return Adjustment(problem, layout, x0, adj_pts, a_obs, None, np.array([], np.str_),
                      surface, notes)


def calibrated_camera(camera: FrameCamera, st: State) -> FrameCamera:
    """The camera file with the estimates, checked as a camera file is read (InputError for
    an adjustment gone astray)."""
    iop = camera.interior
    table = camera.model_dump(mode="json")
    table["mounting"]["boresight_arcsec"] = [float(a) for a in st.boresight_arcsec]
    table["interior"]["focal_length_mm"] = iop.focal_length_mm + float(st.selfcal[0])
    table["interior"]["principal_point_px"] = [
        iop.principal_point_px[0] + float(st.selfcal[1]) / iop.pixel_pitch_um,
        iop.principal_point_px[1] + float(st.selfcal[2]) / iop.pixel_pitch_um]
    try:
        return FrameCamera.model_validate(table)
    except ValidationError as exc:
        raise InputError(f"the adjustment's camera is no camera: {validation_text(exc)}: it "
                         "did not converge to a plausible camera; look for blunders among "
                         "the observations, or estimate fewer groups") from None


def calibrate_photos(inp: PhotoCalibrationInput, opt: CalibrationOptions | None = None
                     ) -> PhotoCalibrationResult:
    """Build, solve with data snooping, and report the frame camera's calibration."""
    opt = opt or CalibrationOptions(groups=(Group.BORESIGHT,))
    adj = build_photos(inp, opt)
    sol, blunders = adjust(adj, opt)
    pb = adj.problem
    sigma0, cov_all, _ = posterior(sol)
    keep = pb.layout.reported
    _, sig, corr = reported(cov_all, keep)
    st = pb.layout.unpack(sol.theta)
    used = pb.obs_in()
    res = pb.image_residuals(st, sol.x_m) * pb.row_sigma
    rms = np.sqrt(np.mean(res[used] ** 2, axis=0)) if used.any() else np.full(2, math.nan)
    counts = {"observations": len(inp.obs), "observations_in_adjustment": len(adj.obs),
              "observations_used": int(used.sum()),
              "photos": len(pb.layout.segments),
              "control_points": int(((pb.points.kind == "control") & pb.point_active).sum()),
              "tie_points": int(((pb.points.kind == "tie") & pb.point_active).sum()),
              "parameters": int(sol.theta.size), "rows": int(sol.lin.r.size)}
    dof = int(sol.lin.r.size - sol.theta.size - 3 * int(pb.point_active.sum()))
    return PhotoCalibrationResult(pb.layout.only_reported(), sol.theta[keep], st, sig, corr,
                                  sigma0, dof,
                                  sol.iterations, calibrated_camera(inp.camera, st),
                                  (float(rms[0]), float(rms[1])), counts, blunders,
                                  adj.notes.lines)


def photo_report_json(res: PhotoCalibrationResult) -> dict[str, Any]:
    """What the frame camera's calibration found, for calibration.json's `camera`."""
    start = res.layout.start()
    return {
        "parameters": [{"name": p.label, "group": p.group.value, "unit": p.unit,
                        "estimate": float(res.theta[i]), "sigma": float(res.sigma[i]),
                        "start": float(start[i]), "prior_sigma": p.prior_sigma}
                       for i, p in enumerate(res.layout.params)],
        "correlation": {"labels": res.layout.labels,
                        "matrix": np.round(res.correlation, 6).tolist()},
        "sigma0": res.sigma0, "dof": res.dof, "iterations": res.iterations,
        "residual_rms_px": {"row": res.residual_rms_px[0], "col": res.residual_rms_px[1]},
        "counts": res.counts, "blunders": res.blunders, "notes": res.notes,
        "camera": res.camera.model_dump(mode="json"),
    }
