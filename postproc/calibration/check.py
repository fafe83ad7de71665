"""Check points: georeference every check-point observation with the calibrated model and
compare it with the survey, beside the error the noise predicts.

Each observed (line, pixel) of a check point is cast as a ray onto the surface (the DEM, or
without one the point's surveyed height, as seed 000 did) and the ground point is compared with
the surveyed one along track (the body x axis, horizontal) and across track (to its right). The
prediction per observation sums: the image noise carried to the ground through the same ray
(finite differences in line and pixel, so oblique rays and slopes count), the calibrated
parameters' covariance carried the same way (with the navigation model's knots, when the
trajectory's accuracy is stated: the GPS error at the check observation as the adjustment
knows it, plus the variance between the knots), the survey σ of the check point, and, across
track, the height σ of the surface times the tangent of the view angle.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from postproc.calibration.model import CameraModel
from postproc.calibration.params import Layout, State
from postproc.calibration.surface import GivenHeights, Surface, intersect_rays
from postproc.georef import ecef_to_geodetic

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class CheckSetup:
    model: CameraModel  # over the check observations
    surveyed_ecef_m: F64  # (N, 3) per observation
    surface: Surface | None
    sigma_h_m: float  # survey σ of the points, horizontal
    sigma_surface_m: float  # σ of the height the rays are cast onto


@dataclass(frozen=True)
class GroundErrors:
    along_m: F64
    across_m: F64
    line_m: F64  # along-track ground size of a line
    pixel_m: F64  # across-track ground size of a pixel
    tan_view: F64


def _surface(cs: CheckSetup) -> Surface:
    if cs.surface is not None:
        return cs.surface
    _, _, h = ecef_to_geodetic(cs.surveyed_ecef_m)
    return GivenHeights(h)


def ground_errors(cs: CheckSetup, layout: Layout, theta: F64) -> GroundErrors:
    """Georeferenced − surveyed, along and across track, for every check observation."""
    return state_ground_errors(cs, layout.unpack(theta))


def state_ground_errors(cs: CheckSetup, st: State) -> GroundErrors:
    m = cs.model
    pose = m.pose_at_delay(st.delay_ms)
    centre, d = m.ray(st, pose)
    ground = intersect_rays(_surface(cs), centre + m.origin, d)
    lat, lon, _ = ecef_to_geodetic(cs.surveyed_ecef_m)
    la, lo = np.radians(lat), np.radians(lon)
    east = np.stack([-np.sin(lo), np.cos(lo), np.zeros_like(lo)], axis=1)
    north = np.stack([-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)], axis=1)
    fwd = pose.r_ecef_from_body[:, :, 0]
    a_en = np.stack([np.einsum("ni,ni->n", fwd, east), np.einsum("ni,ni->n", fwd, north)], 1)
    a_en /= np.linalg.norm(a_en, axis=1, keepdims=True)
    err = ground - cs.surveyed_ecef_m
    e_en = np.stack([np.einsum("ni,ni->n", err, east), np.einsum("ni,ni->n", err, north)], 1)
    along = np.einsum("ni,ni->n", e_en, a_en)
    across = e_en[:, 0] * a_en[:, 1] - e_en[:, 1] * a_en[:, 0]  # to the right of the track
    x_loc = cs.surveyed_ecef_m - m.origin
    pr = m.project(st, x_loc, pose)
    depth = np.abs(pr.p_cam_m[:, 2])
    rate = np.abs(m.rates(st, x_loc))
    _, y0 = m.principal_point_m(st)
    tan_view = np.abs((m.obs.pixel - m.centre_px) * m.pitch_m + y0) / pr.focal_m
    return GroundErrors(along, across, depth * rate / pr.focal_m,
                        depth * m.pitch_m / pr.focal_m, tan_view)


def _shifted(cs: CheckSetup, d_line: float, d_pixel: float) -> CheckSetup:
    """The same rays from a (line, pixel) moved by a fraction of a line / pixel."""
    o = cs.model.obs
    t = o.t_line_ns + np.rint(d_line * o.period_ns).astype(np.int64)
    obs = replace(o, t_line_ns=t, line=o.line + d_line, pixel=o.pixel + d_pixel)
    m = cs.model
    return replace(cs, model=CameraModel(m.traj, m.sensor, obs, m.origin))


def image_noise_variance(cs: CheckSetup, layout: Layout, theta: F64) -> tuple[F64, F64]:
    """σ_px² times the squared ground motion per line and per pixel, along and across."""
    var_a = np.zeros(cs.model.obs.line.size)
    var_c = np.zeros_like(var_a)
    for dl, dp in ((0.5, 0.0), (0.0, 0.5)):
        hi = ground_errors(_shifted(cs, dl, dp), layout, theta)
        lo = ground_errors(_shifted(cs, -dl, -dp), layout, theta)
        var_a += (hi.along_m - lo.along_m) ** 2
        var_c += (hi.across_m - lo.across_m) ** 2
    s2 = cs.model.obs.sigma_px**2
    return np.asarray(s2 * var_a, np.float64), np.asarray(s2 * var_c, np.float64)


def predicted_variance(cs: CheckSetup, layout: Layout, theta: F64, cov_theta: F64,
                       base: GroundErrors) -> tuple[F64, F64]:
    """(along, across) predicted error variance per observation, m²."""
    img_a, img_c = image_noise_variance(cs, layout, theta)
    var_a = img_a + cs.sigma_h_m**2
    var_c = img_c + cs.sigma_h_m**2 + (cs.sigma_surface_m * base.tan_view) ** 2
    if theta.size:
        ja = np.zeros((base.along_m.size, theta.size))
        jc = np.zeros_like(ja)
        nav_cols = layout.nav_columns
        if nav_cols.size:
            bridge_a, bridge_c = _navigation_columns(cs, layout, theta, nav_cols, ja, jc)
            var_a, var_c = var_a + bridge_a, var_c + bridge_c
        skip = set(nav_cols.tolist())
        for j, h in enumerate(layout.steps().tolist()):
            if j in skip:
                continue
            tp, tm = theta.copy(), theta.copy()
            tp[j] += h
            tm[j] -= h
            ep, em = ground_errors(cs, layout, tp), ground_errors(cs, layout, tm)
            ja[:, j] = (ep.along_m - em.along_m) / (2 * h)
            jc[:, j] = (ep.across_m - em.across_m) / (2 * h)
        var_a = var_a + np.einsum("ng,gh,nh->n", ja, cov_theta, ja)
        var_c = var_c + np.einsum("ng,gh,nh->n", jc, cov_theta, jc)
    return np.asarray(var_a, np.float64), np.asarray(var_c, np.float64)


def _navigation_columns(cs: CheckSetup, layout: Layout, theta: F64, nav_cols: npt.NDArray[
        np.int64], ja: F64, jc: F64) -> tuple[F64, F64]:
    """Fill the navigation knots' columns of the ground errors' Jacobian (a knot moves the
    perspective centre: the ray cast for a shift of every centre by a metre east, north, up,
    times the knot's weight) and return the bridge variance carried the same way."""
    nav = cs.model.obs.nav
    n = ja.shape[0]
    if nav is None:
        return np.zeros(n), np.zeros(n)
    st = layout.unpack(theta)
    d_a, d_c = np.zeros((n, 3)), np.zeros((n, 3))
    h = 0.5
    for c in range(3):
        hi, lo = st.copy(), st.copy()
        hi.gps_block_enu_m[c] += h
        lo.gps_block_enu_m[c] -= h
        eh, el = state_ground_errors(cs, hi), state_ground_errors(cs, lo)
        d_a[:, c] = (eh.along_m - el.along_m) / (2 * h)
        d_c[:, c] = (eh.across_m - el.across_m) / (2 * h)
    rows = np.arange(n)
    for idx, w in ((nav.i0, nav.w0), (nav.i1, nav.w1)):
        for c in range(3):
            cols = nav_cols[3 * idx + c]
            np.add.at(ja, (rows, cols), d_a[:, c] * w)
            np.add.at(jc, (rows, cols), d_c[:, c] * w)
    return (np.einsum("nc,nc->n", d_a * d_a, nav.bridge_var_m2),
            np.einsum("nc,nc->n", d_c * d_c, nav.bridge_var_m2))


def _rms(x: F64) -> float:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x * x))) if x.size else float("nan")


def check_summary(err: GroundErrors, var_a: F64, var_c: F64, ids: npt.NDArray[np.str_]
                  ) -> dict[str, Any]:
    ok = np.isfinite(err.along_m) & np.isfinite(err.across_m)
    return {
        "observations": int(ok.sum()), "points": int(np.unique(ids[ok]).size),
        "rms_along_m": _rms(err.along_m[ok]), "rms_across_m": _rms(err.across_m[ok]),
        "rms_along_px": _rms(err.along_m[ok] / err.line_m[ok]),
        "rms_across_px": _rms(err.across_m[ok] / err.pixel_m[ok]),
        "predicted_rms_along_m": float(np.sqrt(np.mean(var_a[ok]))) if ok.any() else None,
        "predicted_rms_across_m": float(np.sqrt(np.mean(var_c[ok]))) if ok.any() else None,
        "mean_along_m": float(np.mean(err.along_m[ok])) if ok.any() else None,
        "mean_across_m": float(np.mean(err.across_m[ok])) if ok.any() else None,
    }


def check_rows(cs: CheckSetup, err: GroundErrors, var_a: F64, var_c: F64,
               ids: npt.NDArray[np.str_]) -> list[dict[str, Any]]:
    o = cs.model.obs
    segs = o.seg_k
    return [{"id": str(ids[i]), "segment_index": int(segs[i]), "line": float(o.line[i]),
             "pixel": float(o.pixel[i]), "along_m": float(err.along_m[i]),
             "across_m": float(err.across_m[i]),
             "along_px": float(err.along_m[i] / err.line_m[i]),
             "across_px": float(err.across_m[i] / err.pixel_m[i]),
             "predicted_sigma_along_m": float(np.sqrt(var_a[i])),
             "predicted_sigma_across_m": float(np.sqrt(var_c[i]))}
            for i in range(ids.size)]


def control_rms_m(cs: CheckSetup, layout: Layout, theta: F64) -> float:
    """Horizontal RMS of georeferenced − surveyed (the delay sweep's figure of merit)."""
    e = ground_errors(cs, layout, theta)
    return float(np.sqrt(np.nanmean(e.along_m**2 + e.across_m**2)))
