"""The line-scanner observation model that calibration adjusts (docs/calibration.md), on a
pose model it shares with the frame camera's (`framemodel`).

For an observation at fractional line ℓ of segment s:
    t      = t_s(ℓ) + τ                               (line time, interpolated, plus the delay)
    R_b^e' = R_b^e(t)·A_s(t)                          (A: per-strip attitude offset and drift)
    r_pc   = r_INS(t) + R_b^e'·a^b − R_b^e(t)·Δg^b + Δr_gps + e_nav(t)   (ECEF)
    p^c    = (R_b^e'·R_c^b)ᵀ·(X − r_pc)               (the point in the camera frame)
    u = −f'·p_x/p_z,  v = −f'·p_y/p_z                 (focal-plane coordinates, f' = f + δf)
Across track the predicted pixel is c + (v − y0')/pitch. Along track a pushbroom line sees only
u = x0' (x0' = x0 + δx0, y0' = y0 + δy0): the misclosure u − x0' at the observed line, divided by
the focal-plane motion per line du/dℓ (taken from the trajectory at ±1 line), is the equivalent
line offset. Residuals are observed − modelled, in lines (along) and pixels (across).
e_nav(t) is the navigation model's GPS error at t, interpolated between its knots
(postproc.calibration.navigation); zero without one.

When the delay is estimated, the pose at t + τ is interpolated linearly in τ between the poses
at whole multiples of DELAY_GRID_MS (t + k·h and t + (k + 1)·h), so that what the adjustment
learns about τ comes from how the aircraft moves over h, not from the INS's record-to-record
noise. Sampled exactly, the attitude spline through noisy INS records (2–3″ white noise at
64 Hz) turns a little with every record; its rate, noise included, is then taken as
information on τ, and the cost wiggles at the record spacing: over 100 independent flights
the delay's z RMS was 1.17–1.22, and with the INS's white noise switched off the same flights'
σ grew by 7 % and their errors moved by 5.2 ms RMS (docs/calibration.md). Over h = 50 ms (3.2
records at 64 Hz) the rate's noise is ~√2·σ_att/h, a quarter of the spline's, and the
interpolation leaves ≤ ~1.5″ of the aircraft's own turning out (turbulence of 0.3° with periods
of seconds), ≤ 0.005 px at 2160 m. With the delay fixed the pose is sampled at t + τ exactly.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Final, NamedTuple

import numpy as np
import numpy.typing as npt

from postproc.calibration.navigation import NavWeights
from postproc.calibration.params import State
from postproc.georef import SensorModel, Trajectory
from sisa.core.frames import ned_to_ecef_matrix
from sisa.core.sensor import ARCSEC_RAD, R_NOMINAL_C_TO_B, rot_x, rot_y, rot_z

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Bool = npt.NDArray[np.bool_]

DELAY_GRID_MS: Final = 50.0  # pose interpolation step in τ when the delay is estimated
ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def r_ecef_from_enu(ecef_m: F64) -> F64:
    """R from local east-north-up at an ECEF point to ECEF (3, 3)."""
    x, y, z = (float(v) for v in ecef_m)
    lon = np.arctan2(y, x)
    lat = np.arctan2(z, np.hypot(x, y) * (1.0 - 6.69437999014e-3))  # geodetic, to ~1e-6 rad
    return np.asarray(ned_to_ecef_matrix(lat, lon) @ ENU_TO_NED, np.float64)


def rot_xyz(angles_rad: F64) -> F64:
    """Rx(a0)·Ry(a1)·Rz(a2) for (N, 3) angles → (N, 3, 3)."""
    a, b, c = angles_rad[:, 0], angles_rad[:, 1], angles_rad[:, 2]
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    m = np.empty((angles_rad.shape[0], 3, 3))
    m[:, 0, 0], m[:, 0, 1], m[:, 0, 2] = cb * cc, -cb * sc, sb
    m[:, 1, 0] = sa * sb * cc + ca * sc
    m[:, 1, 1] = -sa * sb * sc + ca * cc
    m[:, 1, 2] = -sa * cb
    m[:, 2, 0] = -ca * sb * cc + sa * sc
    m[:, 2, 1] = ca * sb * sc + sa * cc
    m[:, 2, 2] = ca * cb
    return m


def boresight_matrix(boresight_arcsec: F64) -> F64:
    """R_c^b = R_nom·Rx(ω)·Ry(φ)·Rz(κ), as sisa.core.sensor.Mounting."""
    return mounted(R_NOMINAL_C_TO_B, boresight_arcsec)


def mounted(r_nominal: F64, boresight_arcsec: F64) -> F64:
    """R_c^b = R_nom·Rx(ω)·Ry(φ)·Rz(κ) for a camera's nominal mounting (the scanner's, or
    the frame camera's sisa.core.framecamera.R_NOMINAL_K_TO_B)."""
    w, p, k = (float(a) * ARCSEC_RAD for a in boresight_arcsec)
    return np.asarray(r_nominal @ rot_x(w) @ rot_y(p) @ rot_z(k), np.float64)


@dataclass(frozen=True)
class ObsGeometry:
    """The fixed part of every observation (one row each)."""

    point: I64  # row of the point in the problem's point arrays
    seg_k: I64  # index into the layout's segments
    t_line_ns: I64  # interpolated tag time of the observed line
    dt_mid_s: F64  # seconds from the strip's mid time (drift)
    period_ns: F64  # local line period
    line: F64
    pixel: F64
    sigma_px: F64
    nav: NavWeights | None = None  # the navigation model's knots around each row


class Projection(NamedTuple):
    u_m: F64
    v_m: F64
    p_cam_m: F64  # (N, 3)
    r_ecef_from_camera: F64  # (N, 3, 3)
    centre_m: F64  # (N, 3) perspective centre, local (ECEF − origin)
    focal_m: float


class Pose(NamedTuple):
    ins_m: F64  # (N, 3) ECEF − origin
    r_ecef_from_body: F64
    valid: Bool


class PoseModel(ABC):
    """What every observation model shares: the pose at each observation's time (plus the
    delay), the perspective centre and the camera's rotation with every correction of the
    state applied, and the point in the camera frame. A line scanner (`CameraModel`) and a
    frame camera (`postproc.calibration.framemodel.FrameCameraModel`) add their projection:
    the residuals (observed − modelled) of each row's two image coordinates, their derivatives
    by the point, and each observation's ray."""

    def __init__(self, traj: Trajectory, obs: ObsGeometry, origin_ecef_m: F64,
                 lever_arm_m: tuple[float, float, float], r_nominal_c_to_b: F64,
                 delay_grid_ms: float | None = None) -> None:
        self.traj = traj
        self.delay_grid_ms = delay_grid_ms  # None: the pose at t + τ exactly (module doc)
        self.obs = obs
        self.origin = np.asarray(origin_ecef_m, np.float64)
        self.r_enu = r_ecef_from_enu(self.origin)
        self.lever = np.asarray(lever_arm_m, np.float64)
        self.r_nominal = np.asarray(r_nominal_c_to_b, np.float64)
        self._cache: dict[int, Pose] = {}

    def pose(self, t_ns: I64) -> Pose:
        p = self.traj.pose_at(t_ns)
        return Pose(p.ins_ecef_m - self.origin, p.r_ecef_from_body, p.valid)

    def pose_at_delay(self, delay_ms: float) -> Pose:
        """Pose at every observation's line time + delay: exact, or with a delay grid
        linear in τ between the grid's poses (module docstring)."""
        h = self.delay_grid_ms
        if h is None:
            return self._pose_at_offset_ns(round(delay_ms * 1e6))
        k = math.floor(delay_ms / h)
        a = delay_ms / h - k
        p0 = self._pose_at_offset_ns(round(k * h * 1e6))
        if a == 0.0:
            return p0
        p1 = self._pose_at_offset_ns(round((k + 1) * h * 1e6))
        # a chord between rotations ~0.03° apart on a strip: off the arc by ~1e-8, left so
        ins = (1.0 - a) * p0.ins_m + a * p1.ins_m
        rot = (1.0 - a) * p0.r_ecef_from_body + a * p1.r_ecef_from_body
        off = ~(p0.valid & p1.valid)
        if not off.any():
            return Pose(ins, rot, p0.valid)
        # a node beyond the navigation's span or in a gap: those rows sampled exactly
        ex = self._pose_at_offset_ns(round(delay_ms * 1e6))
        return Pose(np.where(off[:, None], ex.ins_m, ins),
                    np.where(off[:, None, None], ex.r_ecef_from_body, rot),
                    np.where(off, ex.valid, p0.valid))

    def _pose_at_offset_ns(self, offset_ns: int) -> Pose:
        """Pose at every observation's line time + offset (cached per whole ns)."""
        if offset_ns not in self._cache:
            if len(self._cache) > 8:
                self._cache.clear()
            self._cache[offset_ns] = self.pose(self.obs.t_line_ns + np.int64(offset_ns))
        return self._cache[offset_ns]

    def camera_frame(self, st: State, x_m: F64, pose: Pose) -> tuple[F64, F64, F64]:
        """(the points x_m (N, 3, ECEF − origin) in the camera frame, R_c^e (N, 3, 3), the
        perspective centres (N, 3, local)) with every correction of `st` applied."""
        k = self.obs.seg_k
        ang = (st.attitude_arcsec[k] + st.drift_arcsec_per_s[k] * self.obs.dt_mid_s[:, None])
        r_be = pose.r_ecef_from_body
        r_be_att = r_be @ rot_xyz(ang * ARCSEC_RAD)
        enu = st.gps_block_enu_m + st.gps_strip_enu_m[k]
        if self.obs.nav is not None and st.nav_enu_m.shape[0]:
            enu = enu + self.obs.nav.error(st.nav_enu_m)
        shift = self.r_enu @ enu.T
        centre = (pose.ins_m + r_be_att @ self.lever - r_be @ st.antenna_delta_m + shift.T)
        r_ce = r_be_att @ mounted(self.r_nominal, st.boresight_arcsec)
        p = np.einsum("nji,nj->ni", r_ce, x_m - centre)
        return p, r_ce, centre

    @abstractmethod
    def rates(self, st: State, x_m: F64) -> F64:
        """What divides the first coordinate's misclosure (a line scanner's du/dℓ)."""

    @abstractmethod
    def residuals(self, st: State, x_m: F64, pose: Pose, rate: F64) -> tuple[F64, F64]:
        """(first, second) image coordinate of every row, observed − modelled."""

    @abstractmethod
    def point_jacobian(self, st: State, x_m: F64, pose: Pose, rate: F64) -> F64:
        """d(residuals)/dX, shape (N, 2, 3)."""

    @abstractmethod
    def ray(self, st: State, pose: Pose) -> tuple[F64, F64]:
        """Perspective centre (local) and unit ECEF direction of every observation."""


class CameraModel(PoseModel):
    """Projection of points into the observed lines, for a given parameter state."""

    def __init__(self, traj: Trajectory, sensor: SensorModel, obs: ObsGeometry,
                 origin_ecef_m: F64, delay_grid_ms: float | None = None) -> None:
        super().__init__(traj, obs, origin_ecef_m, sensor.mounting.lever_arm_m,
                         R_NOMINAL_C_TO_B, delay_grid_ms)
        self.sensor = sensor
        sc = sensor.scanner
        self.pitch_m = sc.pixel_pitch_um * 1e-6
        self.centre_px = sc.centre_pixel

    def project(self, st: State, x_m: F64, pose: Pose) -> Projection:
        """x_m: (N, 3) the observed point of every row, ECEF − origin."""
        p, r_ce, centre = self.camera_frame(st, x_m, pose)
        f = (self.sensor.scanner.focal_length_mm + st.selfcal[0]) * 1e-3
        return Projection(-f * p[:, 0] / p[:, 2], -f * p[:, 1] / p[:, 2], p, r_ce, centre, f)

    def principal_point_m(self, st: State) -> tuple[float, float]:
        x0, y0 = self.sensor.scanner.principal_point_um
        return (x0 + st.selfcal[1]) * 1e-6, (y0 + st.selfcal[2]) * 1e-6

    def rates(self, st: State, x_m: F64) -> F64:
        """du/dℓ (m per line) at every observation, from the poses one line either side."""
        half = np.rint(self.obs.period_ns).astype(np.int64)
        t = self.obs.t_line_ns + np.int64(round(st.delay_ms * 1e6))
        u1 = self.project(st, x_m, self.pose(t + half)).u_m
        u0 = self.project(st, x_m, self.pose(t - half)).u_m
        return np.asarray((u1 - u0) / 2.0, np.float64)

    def residuals(self, st: State, x_m: F64, pose: Pose, rate: F64) -> tuple[F64, F64]:
        """(along in lines, across in pixels), observed − modelled."""
        pr = self.project(st, x_m, pose)
        x0, y0 = self.principal_point_m(st)
        along = (pr.u_m - x0) / rate
        across = self.obs.pixel - (self.centre_px + (pr.v_m - y0) / self.pitch_m)
        return along, across

    def point_jacobian(self, st: State, x_m: F64, pose: Pose, rate: F64) -> F64:
        """d(along, across)/dX, shape (N, 2, 3)."""
        pr = self.project(st, x_m, pose)
        p, f = pr.p_cam_m, pr.focal_m
        z = p[:, 2]
        du = -f * np.stack([1.0 / z, np.zeros_like(z), -p[:, 0] / z**2], axis=1)
        dv = -f * np.stack([np.zeros_like(z), 1.0 / z, -p[:, 1] / z**2], axis=1)
        rt = np.swapaxes(pr.r_ecef_from_camera, 1, 2)  # dp/dX
        d_along = np.einsum("ni,nij->nj", du, rt) / rate[:, None]
        d_across = -np.einsum("ni,nij->nj", dv, rt) / self.pitch_m
        return np.stack([d_along, d_across], axis=1)

    def ray(self, st: State, pose: Pose) -> tuple[F64, F64]:
        """Perspective centre (local) and unit ECEF direction of every observed (line, pixel)."""
        dummy = np.zeros((self.obs.line.size, 3))
        pr = self.project(st, dummy, pose)
        x0, y0 = self.principal_point_m(st)
        look = np.stack([np.full(self.obs.pixel.size, x0),
                         (self.obs.pixel - self.centre_px) * self.pitch_m + y0,
                         np.full(self.obs.pixel.size, -pr.focal_m)], axis=1)
        d = np.einsum("nij,nj->ni", pr.r_ecef_from_camera, look)
        return pr.centre_m, d / np.linalg.norm(d, axis=1, keepdims=True)


def line_model(model: PoseModel) -> CameraModel:
    """The line scanner's model of a problem built for one (the scanner's report and check
    points read its projection); TypeError for another camera's."""
    if not isinstance(model, CameraModel):
        raise TypeError(f"a line scanner's model was expected, not {type(model).__name__}")
    return model
