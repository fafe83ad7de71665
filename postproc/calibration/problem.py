"""The least-squares problem: image rows, control-point rows, DEM rows and parameter priors,
each divided by its σ, linearised for the Gauss–Newton solver.

Unknowns: the estimated calibration parameters θ (calib_params) and the ground coordinates X of
every point in the adjustment (control and tie; ECEF − origin, metres). Rows:
- image: along (lines) and across (pixels) of every active observation, / σ (σ_px, and the
  navigation model's bridge variance carried into the image: `row_sigma`);
- control: X − X_surveyed in local east, north, up, / σ (horizontal, vertical);
- DEM: h(X) − DEM(X), / σ_DEM, for tie points when surface control is on;
- priors: (θ − θ_start) / σ for groups that have a prior;
- navigation: the whitened Gauss–Markov prior of the navigation model's knots
  (postproc.calibration.navigation), when the trajectory's accuracy is stated.
Derivatives: analytic for X and for the navigation knots (image rows: a knot moves the
perspective centre, which is −X), central differences for the other θ and the DEM rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from postproc.calibration.model import Pose, PoseModel
from postproc.calibration.params import Group, Layout, State
from postproc.calibration.surface import Surface

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Bool = npt.NDArray[np.bool_]

DEM_STEP_M = 1.0


@dataclass(frozen=True)
class PointSet:
    """The points in the adjustment; ECEF − origin."""

    ids: npt.NDArray[np.str_]
    kind: npt.NDArray[np.str_]  # control | tie | check (only its height is observed)
    surveyed_m: F64  # (P, 3); NaN for tie points
    sigma_enu_m: F64  # (P, 3) σ of the surveyed coordinates (check points: 1e9 horizontally)
    dem_control: Bool  # a DEM row for this point


@dataclass
class Linear:
    """Weighted residuals and Jacobians of every row (M rows, G parameters)."""

    r: F64
    jg: F64  # (M, G)
    jp: F64  # (M, 3)
    pidx: I64  # point of the row, −1 for none
    row_kind: I64  # 0 image along, 1 image across, 2 control, 3 DEM, 4 prior, 5 navigation
    row_item: I64  # observation, point or parameter index of the row


IMAGE_ALONG, IMAGE_ACROSS, CONTROL, DEM, PRIOR, NAV_PRIOR = range(6)
DATA_ROWS = (IMAGE_ALONG, IMAGE_ACROSS, CONTROL, DEM)  # observations; the rest are priors


class Problem:
    """The rows of one adjustment; `obs_active` and `gcp_active` are switched off by snooping."""

    def __init__(self, model: PoseModel, layout: Layout, points: PointSet,
                 surface: Surface | None, dem_sigma_m: float) -> None:
        self.model = model
        self.layout = layout
        self.points = points
        self.surface = surface
        self.dem_sigma_m = dem_sigma_m
        self.obs_active = np.ones(model.obs.line.size, dtype=np.bool_)
        self.gcp_active: Bool = np.asarray(np.isfinite(points.surveyed_m).all(axis=1),
                                           dtype=np.bool_)
        self.point_active = np.ones(points.ids.size, dtype=np.bool_)
        self.r_enu = model.r_enu
        self.theta0 = layout.start()
        self.rate: F64 = np.ones(model.obs.line.size)
        self.row_sigma: F64 = np.repeat(model.obs.sigma_px[:, None], 2, axis=1)
        self._priors = [(i, p.prior_sigma) for i, p in enumerate(layout.params)
                        if p.prior_sigma is not None]
        self._nav_cols = layout.nav_columns
        self._fd_cols = np.array([i for i in range(layout.size)
                                  if i not in set(self._nav_cols.tolist())], np.int64)
        self._nav_prior = layout.knots.prior_rows() if layout.knots is not None else None

    # -- which rows are in --------------------------------------------------------------

    def obs_in(self) -> Bool:
        return np.asarray(self.obs_active & self.point_active[self.model.obs.point], np.bool_)

    def gcp_in(self) -> Bool:
        return np.asarray(self.gcp_active & self.point_active, np.bool_)

    def dem_in(self) -> Bool:
        if self.surface is None:
            return np.zeros(self.points.ids.size, dtype=np.bool_)
        return np.asarray(self.points.dem_control & self.point_active, np.bool_)

    # -- pieces ---------------------------------------------------------------------------

    def pose_for(self, st: State) -> Pose:
        return self.model.pose_at_delay(st.delay_ms)

    def update_rates(self, theta: F64, x_m: F64) -> None:
        """du/dℓ at every observation, and its σ (the image σ plus the navigation model's
        bridge variance carried into lines and pixels), at the current estimate."""
        st = self.layout.unpack(theta)
        xo = x_m[self.model.obs.point]
        rate = self.model.rates(st, xo)
        self.rate = np.where(np.abs(rate) > 1e-12, rate, 1e-12)
        nav = self.model.obs.nav
        if nav is not None and self._nav_cols.size:
            j = self.model.point_jacobian(st, xo, self.pose_for(st), self.rate) @ self.r_enu
            extra = np.einsum("nrc,nc->nr", j * j, nav.bridge_var_m2)
            self.row_sigma = np.sqrt(self.model.obs.sigma_px[:, None] ** 2 + extra)

    def image_residuals(self, st: State, x_m: F64) -> F64:
        """(N, 2) weighted along/across of every observation (active or not)."""
        along, across = self.model.residuals(st, x_m[self.model.obs.point], self.pose_for(st),
                                             self.rate)
        return np.stack([along, across], axis=1) / self.row_sigma

    def control_residuals(self, x_m: F64) -> F64:
        """(P, 3) weighted east/north/up of X − surveyed."""
        d = (x_m - self.points.surveyed_m) @ self.r_enu
        return np.asarray(d / self.points.sigma_enu_m, np.float64)

    def dem_residuals(self, x_m: F64) -> F64:
        sel = self.dem_in()
        if self.surface is None or not sel.any():
            return np.zeros(0)
        hp, hs = self.surface.heights(x_m[sel] + self.model.origin)
        return np.asarray((hp - hs) / self.dem_sigma_m, np.float64)

    def cost(self, theta: F64, x_m: F64) -> float:
        return float(np.sum(self.all_residuals(theta, x_m) ** 2))

    def all_residuals(self, theta: F64, x_m: F64) -> F64:
        st = self.layout.unpack(theta)
        img = self.image_residuals(st, x_m)[self.obs_in()].ravel()
        ctl = self.control_residuals(x_m)[self.gcp_in()].ravel()
        pri = np.array([(theta[i] - self.theta0[i]) / s for i, s in self._priors])
        return np.concatenate([img, ctl, self.dem_residuals(x_m), pri, self._nav_values(theta)])

    def _nav_values(self, theta: F64) -> F64:
        if self._nav_prior is None:
            return np.zeros(0)
        c_self, prev, col, c_prev = self._nav_prior
        e = theta[self._nav_cols]
        return np.asarray(c_self * e[col] + np.where(prev >= 0, c_prev * e[prev], 0.0),
                          np.float64)

    # -- linearisation --------------------------------------------------------------------

    def linearise(self, theta: F64, x_m: F64) -> Linear:
        parts = [self._image_rows(theta, x_m), self._control_rows(x_m), self._dem_rows(x_m),
                 self._prior_rows(theta), self._nav_rows(theta)]
        return Linear(*(np.concatenate([getattr(p, f) for p in parts]) for f in
                        ("r", "jg", "jp", "pidx", "row_kind", "row_item")))

    def _image_rows(self, theta: F64, x_m: F64) -> Linear:
        obs = self.model.obs
        act = np.flatnonzero(self.obs_in())
        st = self.layout.unpack(theta)
        r = self.image_residuals(st, x_m)[act]
        g = theta.size
        jg = np.zeros((act.size, 2, g))
        steps = self.layout.steps()
        for j in self._fd_cols.tolist():
            h = float(steps[j])
            tp, tm = theta.copy(), theta.copy()
            tp[j] += h
            tm[j] -= h
            rp = self.image_residuals(self.layout.unpack(tp), x_m)[act]
            rm = self.image_residuals(self.layout.unpack(tm), x_m)[act]
            jg[:, :, j] = (rp - rm) / (2.0 * h)
        xo = x_m[obs.point]
        jp = self.model.point_jacobian(st, xo, self.pose_for(st), self.rate)[act]
        jp /= self.row_sigma[act, :, None]
        if self._nav_cols.size and obs.nav is not None:
            self._nav_image_columns(jg, jp, act)
        n = act.size
        return Linear(r.ravel(), jg.reshape(2 * n, g), jp.reshape(2 * n, 3),
                      np.repeat(obs.point[act], 2), np.tile([IMAGE_ALONG, IMAGE_ACROSS], n),
                      np.repeat(act, 2))

    def _control_rows(self, x_m: F64) -> Linear:
        idx = np.flatnonzero(self.gcp_in())
        r = self.control_residuals(x_m)[idx]
        jp = self.r_enu.T[None, :, :] / self.points.sigma_enu_m[idx][:, :, None]
        n = idx.size
        return Linear(r.ravel(), np.zeros((3 * n, self.layout.size)), jp.reshape(3 * n, 3),
                      np.repeat(idx, 3), np.full(3 * n, CONTROL), np.repeat(idx, 3))

    def _dem_rows(self, x_m: F64) -> Linear:
        idx = np.flatnonzero(self.dem_in())
        r = self.dem_residuals(x_m)
        jp = np.zeros((idx.size, 3))
        for k in range(3):
            xp, xm = x_m.copy(), x_m.copy()
            xp[:, k] += DEM_STEP_M
            xm[:, k] -= DEM_STEP_M
            jp[:, k] = (self.dem_residuals(xp) - self.dem_residuals(xm)) / (2 * DEM_STEP_M)
        return Linear(r, np.zeros((idx.size, self.layout.size)), jp, idx,
                      np.full(idx.size, DEM), idx)

    def _nav_image_columns(self, jg: F64, jp: F64, act: I64) -> None:
        """d(row)/d(knot): a knot's ENU shift w·e moves the perspective centre, as −X."""
        nav = self.model.obs.nav
        if nav is None:
            return
        d_enu = -jp @ self.r_enu  # (n, 2, 3) per metre east, north, up at the centre
        rows = np.arange(act.size)
        for idx, w in ((nav.i0[act], nav.w0[act]), (nav.i1[act], nav.w1[act])):
            for c in range(3):
                cols = self._nav_cols[3 * idx + c]
                for r in (0, 1):  # along, across
                    np.add.at(jg[:, r, :], (rows, cols), d_enu[:, r, c] * w)

    def _nav_rows(self, theta: F64) -> Linear:
        if self._nav_prior is None:
            return Linear(np.zeros(0), np.zeros((0, self.layout.size)), np.zeros((0, 3)),
                          np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64))
        c_self, prev, col, c_prev = self._nav_prior
        n = col.size
        jg = np.zeros((n, self.layout.size))
        rows = np.arange(n)
        jg[rows, self._nav_cols[col]] = c_self
        has = prev >= 0
        jg[rows[has], self._nav_cols[prev[has]]] = c_prev[has]
        return Linear(self._nav_values(theta), jg, np.zeros((n, 3)), np.full(n, -1),
                      np.full(n, NAV_PRIOR), self._nav_cols[col])

    def _prior_rows(self, theta: F64) -> Linear:
        n = len(self._priors)
        jg = np.zeros((n, self.layout.size))
        r = np.zeros(n)
        for row, (i, s) in enumerate(self._priors):
            jg[row, i] = 1.0 / s
            r[row] = (theta[i] - self.theta0[i]) / s
        return Linear(r, jg, np.zeros((n, 3)), np.full(n, -1), np.full(n, PRIOR),
                      np.array([i for i, _ in self._priors], dtype=np.int64))

    def has_delay(self) -> bool:
        return Group.DELAY in self.layout.groups
