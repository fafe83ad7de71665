"""The navigation model of calibration (postproc.calibration.navigation) and σ that priors set.

The knots' weights and prior are checked against Gaussian conditioning and inversion done by
hand on the process's covariance σ²·exp(−|Δt|/τ) (numpy.linalg, no shared code); the model
is checked on the synthetic block of test_calibrate with a Gauss–Markov GPS error added to its
navigation; a prior's σ is checked not to follow σ̂0.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from postproc.calibration import (
    CalibrationInput,
    CalibrationOptions,
    NavigationAccuracy,
    calibrate,
    parse_groups,
    report_json,
)
from postproc.calibration.navigation import build_knots
from postproc.georef import Pose
from sisa.core.errors import ConfigError
from tests.postproc.test_calibrate import (
    R_NED,
    Block,
    NavTrajectory,
    Scene,
    Truth,
    make_scene,
    nominal_sensor,
)

S = 1_000_000_000
T0 = 1_300_000_000 * S


def _cov(t_s: npt.NDArray[np.float64], sigma: float, tau: float) -> npt.NDArray[np.float64]:
    return np.asarray(sigma**2 * np.exp(-np.abs(t_s[:, None] - t_s[None, :]) / tau))


def test_weights_are_the_conditional_mean_and_variance_of_the_process() -> None:
    acc = NavigationAccuracy((1.0, 1.5), 60.0)
    knots = build_knots({0: acc, 1: acc}, {0: (T0, T0 + 100 * S), 1: (T0 + 250 * S,
                                                                    T0 + 300 * S)})
    assert knots is not None
    tk = (knots.t_ns - T0) / S
    t_obs = np.array([0.0, 7.3, 33.3, 99.9, 100.0, 251.0, 280.5, 300.0])
    seg = np.array([0, 0, 0, 0, 0, 1, 1, 1])
    w = knots.weights(seg, T0 + np.rint(t_obs * S).astype(np.int64))
    for axis, sigma in ((0, 1.0), (2, 1.5)):
        # E[e(t) | all knots] and its variance, by conditioning on every knot
        both = np.concatenate([tk, t_obs])
        c = _cov(both, sigma, 60.0)
        k = tk.size
        gain = c[k:, :k] @ np.linalg.inv(c[:k, :k])
        dense = np.zeros((t_obs.size, k))
        np.add.at(dense, (np.arange(t_obs.size), w.i0), w.w0)
        np.add.at(dense, (np.arange(t_obs.size), w.i1), w.w1)
        np.testing.assert_allclose(dense, gain, atol=1e-9)
        left = np.diag(c[k:, k:] - gain @ c[:k, k:])
        np.testing.assert_allclose(w.bridge_var_m2[:, axis], left, atol=1e-9)
    assert w.bridge_var_m2[0].max() < 1e-12  # on a knot nothing is left
    assert knots.spacing_s == pytest.approx(20.0)


def test_the_prior_rows_whiten_the_knots_covariance() -> None:
    code = NavigationAccuracy((1.0, 1.5), 60.0)
    phase = NavigationAccuracy((0.03, 0.05), 60.0)
    knots = build_knots({0: code, 1: code, 5: phase},
                        {0: (T0, T0 + 70 * S), 1: (T0 + 200 * S, T0 + 260 * S),
                         5: (T0 + 90 * S, T0 + 130 * S)})
    assert knots is not None
    c_self, prev, col, c_prev = knots.prior_rows()
    n = 3 * knots.count
    j = np.zeros((n, n))
    j[np.arange(n), col] = c_self
    has = prev >= 0
    j[np.arange(n)[has], prev[has]] = c_prev[has]
    cov = np.zeros((n, n))
    for c in np.unique(knots.chain).tolist():
        kk = np.flatnonzero(knots.chain == c)
        t = (knots.t_ns[kk] - T0) / S
        for axis in range(3):
            idx = 3 * kk + axis
            cov[np.ix_(idx, idx)] = _cov(t, float(knots.sigma_enu_m[kk[0], axis]), 60.0)
    np.testing.assert_allclose(j.T @ j @ cov, np.eye(n), atol=1e-8)


def test_a_stated_accuracy_is_checked() -> None:
    with pytest.raises(ConfigError):
        NavigationAccuracy((-1.0, 1.0))
    with pytest.raises(ConfigError):
        NavigationAccuracy((1.0, 1.0), 0.0)
    with pytest.raises(ConfigError, match="navigation"):
        parse_groups("boresight,navigation")


class GpsErrorTrajectory(NavTrajectory):
    """The block's navigation with a Gauss–Markov GPS error (σ 1 m, τ 60 s; 1 Hz, linear
    between): what a code solution gives."""

    def __init__(self, block: Block, seed: int, sigma_m: float = 1.0) -> None:
        super().__init__(block)
        rng = np.random.default_rng(seed)
        lo, hi = self.span_ns
        self.t = np.arange(lo - 10 * S, hi + 10 * S, S, dtype=np.int64)
        phi = math.exp(-1.0 / 60.0)
        e = np.empty((self.t.size, 3))
        e[0] = rng.normal(0.0, sigma_m, 3)
        drive = rng.normal(0.0, sigma_m * math.sqrt(1 - phi * phi), (self.t.size, 3))
        for k in range(1, self.t.size):
            e[k] = phi * e[k - 1] + drive[k]
        self.err_ned = e

    def pose_at(self, t_gps_ns: npt.ArrayLike) -> Pose:
        p = super().pose_at(t_gps_ns)
        t = p.t_gps_ns.astype(np.float64)
        ned = np.stack([np.interp(t, self.t.astype(np.float64), self.err_ned[:, k])
                        for k in range(3)], axis=1)
        return Pose(p.t_gps_ns, p.ins_ecef_m + ned @ R_NED.T, p.r_ecef_from_body, p.valid)


@pytest.fixture(scope="module")
def scene() -> Scene:
    return make_scene(Block(), Truth(), n_control=40, n_check=20, n_tie=60, seed=11)


def _run(scene: Scene, nav: NavigationAccuracy | None, seed: int = 2) -> dict[str, object]:
    inp = CalibrationInput(GpsErrorTrajectory(scene.block, seed), scene.clock, scene.points,
                           scene.obs, nominal_sensor(), scene.dem, nav)
    res = calibrate(inp, CalibrationOptions(groups=parse_groups("boresight,selfcal"),
                                            gcp_sigma_m=(0.05, 0.05)))
    return report_json(res)


def _row(rep: dict[str, object], name: str) -> dict[str, object]:
    rows = rep["parameters"]
    assert isinstance(rows, list)
    return next(r for r in rows if r["name"] == name)


def test_the_navigation_model_carries_the_gps_error_into_sigma(scene: Scene) -> None:
    """Left out, a 1 m GPS error inflates σ̂0 as if it were image noise (and scales every σ
    alike); modelled, σ̂0 is the images' again and the GPS error's share of each variance is
    where the geometry puts it (δf, the swath's scale, takes much of it)."""
    without = _run(scene, None)
    with_model = _run(scene, NavigationAccuracy((1.0, 1.0), 60.0))
    assert "σ leave out" in " ".join(without["notes"])  # type: ignore[arg-type]
    assert float(without["sigma0"]) > 1.15  # type: ignore[arg-type]
    assert 0.8 < float(with_model["sigma0"]) < 1.1  # type: ignore[arg-type]
    nav = with_model["navigation_model"]
    assert isinstance(nav, dict)
    assert nav["knots"] > 4 * 6
    t = Truth()
    for name, truth, share in (("kappa", t.boresight_arcsec[2], 0.02),
                               ("delta_focal", t.delta_focal_mm, 0.2)):
        b = _row(with_model, name)
        got = b["sigma_share"]
        assert isinstance(got, dict)
        assert got["navigation"] > share
        assert abs(float(b["estimate"]) - truth) < 3 * float(b["sigma"])  # type: ignore[arg-type]
    # the parameters are reported, the knots are not
    labels = with_model["correlation"]["labels"]  # type: ignore[index]
    assert not any(str(x).startswith("nav_") for x in labels)


def test_a_prior_sets_sigma_whatever_the_data_fit(scene: Scene) -> None:
    """δx0's σ is its prior's (20 µm), not 20 µm·σ̂0, and δx0 and φ are reported as set by
    the prior; κ, measured by the images, is not."""
    from dataclasses import replace

    loose = replace(scene, obs=replace(scene.obs, sigma_px=scene.obs.sigma_px / 2))
    for sc in (scene, loose):
        inp = CalibrationInput(NavTrajectory(sc.block), sc.clock, sc.points, sc.obs,
                               nominal_sensor(), sc.dem)
        rep = report_json(calibrate(inp, CalibrationOptions(
            groups=parse_groups("boresight,selfcal"), gcp_sigma_m=(0.05, 0.05))))
        x0, phi, kappa = (_row(rep, n) for n in ("delta_x0", "phi", "kappa"))
        assert float(x0["sigma"]) == pytest.approx(20.0, rel=2e-3)  # type: ignore[arg-type]
        assert x0["set_by_prior"]
        assert phi["set_by_prior"]
        assert not kappa["set_by_prior"]
    assert float(rep["sigma0"]) > 1.7  # type: ignore[arg-type]


def test_the_delay_grid_blends_the_poses_of_its_nodes() -> None:
    """With the delay estimated, the pose at t + τ is linear in τ between the poses at
    t + k·h and t + (k + 1)·h (so the INS's record-to-record noise is not read as information
    on τ); on a node, and with the delay fixed, it is the pose at t + τ itself."""
    from postproc.calibration.model import DELAY_GRID_MS, CameraModel, ObsGeometry

    block = Block()
    traj = NavTrajectory(block)
    t = np.array([block.t0[0] + 5 * S, block.t0[1] + 7 * S + 123_457], np.int64)
    n = t.size
    zi, zf = np.zeros(n, np.int64), np.zeros(n)
    geom = ObsGeometry(zi, zi, t, zf, np.full(n, 48e6), zf, zf, np.ones(n))
    origin = traj.pose_at(t[:1]).ins_ecef_m[0]
    h = DELAY_GRID_MS
    grid = CameraModel(traj, nominal_sensor(), geom, origin, h)
    exact = CameraModel(traj, nominal_sensor(), geom, origin)
    p1, p2 = (exact.pose_at_delay(k * h) for k in (1, 2))
    got = grid.pose_at_delay(1.3 * h)
    np.testing.assert_allclose(got.ins_m, 0.7 * p1.ins_m + 0.3 * p2.ins_m, atol=1e-9)
    np.testing.assert_allclose(got.r_ecef_from_body,
                               0.7 * p1.r_ecef_from_body + 0.3 * p2.r_ecef_from_body,
                               atol=1e-12)
    np.testing.assert_allclose(grid.pose_at_delay(2 * h).ins_m, p2.ins_m, atol=1e-9)
    tau_ms = 1.3 * h
    at = traj.pose_at(t + round(tau_ms * 1e6))
    sampled = exact.pose_at_delay(tau_ms)
    np.testing.assert_allclose(sampled.ins_m, at.ins_ecef_m - origin, atol=1e-6)
    # over 50 ms the block's smooth motion is a straight chord to well under a millimetre
    assert float(np.max(np.abs(got.ins_m - sampled.ins_m))) < 1e-3
    assert float(np.max(np.abs(got.r_ecef_from_body - sampled.r_ecef_from_body))) < 1e-7


def test_the_delay_grid_samples_exactly_where_a_node_has_no_navigation() -> None:
    """A grid node past the trajectory's end does not make a timed observation untimed: that
    row is sampled at t + τ exactly."""
    from postproc.calibration.model import DELAY_GRID_MS, CameraModel, ObsGeometry

    block = Block()
    end = block.t0[0] + 10 * S

    class Ending(NavTrajectory):
        def pose_at(self, t_gps_ns: npt.ArrayLike) -> Pose:
            p = super().pose_at(t_gps_ns)
            ok = p.valid & (p.t_gps_ns <= end)
            return Pose(p.t_gps_ns, np.where(ok[:, None], p.ins_ecef_m, np.nan),
                        np.where(ok[:, None, None], p.r_ecef_from_body, np.nan), ok)

    traj = Ending(block)
    t = np.array([end - 40_000_000, block.t0[0] + 5 * S], np.int64)  # 40 ms before the end
    assert not traj.pose_at(t[:1] + 50_000_000).valid.any()  # the node at +50 ms: none
    n = t.size
    zi, zf = np.zeros(n, np.int64), np.zeros(n)
    geom = ObsGeometry(zi, zi, t, zf, np.full(n, 48e6), zf, zf, np.ones(n))
    origin = traj.pose_at(t[1:]).ins_ecef_m[0]
    grid = CameraModel(traj, nominal_sensor(), geom, origin, DELAY_GRID_MS)
    exact = CameraModel(traj, nominal_sensor(), geom, origin)
    got, want = grid.pose_at_delay(20.0), exact.pose_at_delay(20.0)
    assert got.valid.all()
    np.testing.assert_allclose(got.ins_m[0], want.ins_m[0], atol=1e-9)
