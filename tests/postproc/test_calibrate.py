"""Calibration adjustment (postproc.calibration.adjust) on a synthetic block with its own forward
model.

The block here is built independently of the emulators and of postproc's model: straight
strips at constant speed over a tangent plane, wavy attitude, points on a bilinear DEM, and a
forward projection written out by hand from docs/conventions.md (pixel j looks along
(x0+δx0, (j−c)·pitch+y0+δy0, −(f+δf)); R_c^b = diag(1,−1,−1)·Rx(ω)·Ry(φ)·Rz(κ)), solved for the
line time by Newton. Injected values must come back within 3σ, and σ must be small enough for
that to mean something.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from pyproj import Transformer

from postproc.calibration import (
    CalibrationInput,
    CalibrationOptions,
    GroundPoints,
    Group,
    ImageObservations,
    PriorSigmas,
    SegmentClock,
    calibrate,
    join_flights,
    load_check,
    parse_groups,
    read_ground_points,
    read_observations,
    report_json,
    sensor_toml,
    sweep_delay,
    write_observations,
)
from postproc.calibration.model import boresight_matrix, rot_xyz
from postproc.georef import Dem, Pose, SensorModel
from sisa.core.errors import ConfigError, InputError
from sisa.core.sensor import Mounting, ScannerGeometry, rot_x, rot_y, rot_z

AS = math.pi / (180 * 3600)
LAT0, LON0, H_GROUND = 42.15, 2.50, 500.0
T0_NS = 1_300_000_000 * 1_000_000_000
UTM = 32631


def _rx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], float)


def _ry(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], float)


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], float)


def _ecef(lat: np.ndarray, lon: np.ndarray, h: np.ndarray) -> np.ndarray:
    x, y, z = Transformer.from_crs(4979, 4978, always_xy=True).transform(lon, lat, h)
    return np.stack([x, y, z], axis=-1)


ORIGIN = _ecef(np.array([LAT0]), np.array([LON0]), np.array([H_GROUND]))[0]
_sl, _cl = math.sin(math.radians(LAT0)), math.cos(math.radians(LAT0))
_so, _co = math.sin(math.radians(LON0)), math.cos(math.radians(LON0))
R_NED = np.array([[-_sl * _co, -_so, -_cl * _co], [-_sl * _so, _co, -_cl * _so],
                  [_cl, 0.0, -_sl]])  # columns: north, east, down in ECEF


@dataclass
class Block:
    """Alternating N/S strips over a tangent plane at the origin (NED metres)."""

    strips: int = 4
    height_m: float = 2160.0
    speed_mps: float = 73.0
    length_m: float = 9000.0
    spacing_m: float = 1000.0
    period_ns: int = 48_000_000
    turn_ns: int = 60_000_000_000
    wave_deg: tuple[float, float, float] = (0.3, 0.2, 0.1)
    antenna_error_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # g_true − g_file
    ins_error_arcsec: dict[int, tuple[float, float, float]] = field(default_factory=dict)
    t_start_ns: int = T0_NS
    t0: list[int] = field(default_factory=list)

    def __post_init__(self) -> None:
        dur = round(self.length_m / self.speed_mps * 1e9)
        self.duration_ns = dur
        self.t0 = [self.t_start_ns + k * (dur + self.turn_ns) for k in range(self.strips)]

    def lines(self) -> int:
        return self.duration_ns // self.period_ns

    def strip_of(self, t: np.ndarray) -> np.ndarray:
        k = np.clip((t - self.t_start_ns) // (self.duration_ns + self.turn_ns), 0,
                    self.strips - 1)
        return np.asarray(k, np.int64)

    def state(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(INS ECEF, R_b^e, valid) of the TRUE flight."""
        t = np.asarray(t, np.int64)
        k = self.strip_of(t)
        tau = (t - np.asarray(self.t0)[k]).astype(float) * 1e-9
        valid = (tau >= -5.0) & (tau <= self.duration_ns * 1e-9 + 5.0)
        south = k % 2 == 1
        east = (k - (self.strips - 1) / 2) * self.spacing_m
        north = np.where(south, self.length_m / 2 - self.speed_mps * tau,
                         -self.length_m / 2 + self.speed_mps * tau)
        ned = np.stack([north, east, np.full_like(north, -self.height_m)], axis=1)
        pos = ORIGIN + ned @ R_NED.T
        wr, wp, wh = (math.radians(w) for w in self.wave_deg)
        roll = wr * np.sin(tau / 7.0 + k)
        pitch = wp * np.sin(tau / 11.0 + 2 * k)
        head = np.where(south, math.pi, 0.0) + wh * np.sin(tau / 13.0)
        r_bn = np.array([_rz(h) @ _ry(p) @ _rx(r) for r, p, h in zip(roll, pitch, head,
                                                                     strict=True)])
        return pos, R_NED @ r_bn, valid


class NavTrajectory:
    """What the adjustment gets: the INS positions the navigation derived with the sensor
    file's antenna offset (so an antenna-offset error shifts them by R_b^e·(g_true − g_file))."""

    def __init__(self, block: Block) -> None:
        self.block = block

    @property
    def span_ns(self) -> tuple[int, int]:
        return self.block.t0[0], self.block.t0[-1] + self.block.duration_ns

    def pose_at(self, t_gps_ns: npt.ArrayLike) -> Pose:
        t = np.atleast_1d(np.asarray(t_gps_ns, np.int64))
        pos, r_be, valid = self.block.state(t)
        pos = pos + r_be @ np.asarray(self.block.antenna_error_m)
        k = self.block.strip_of(t)
        for strip, (a, b, c) in self.block.ins_error_arcsec.items():
            err = _rx(a * AS) @ _ry(b * AS) @ _rz(c * AS)  # the INS's attitude is off by err
            r_be[k == strip] = r_be[k == strip] @ err.T
        return Pose(t, np.where(valid[:, None], pos, np.nan),
                    np.where(valid[:, None, None], r_be, np.nan), valid)


@dataclass(frozen=True)
class Truth:
    boresight_arcsec: tuple[float, float, float] = (1742.0, -2.0, -74.0)
    delta_focal_mm: float = 0.6496
    delta_pp_um: tuple[float, float] = (12.74, 64.52)
    delay_ms: float = 0.0
    lever_m: tuple[float, float, float] = (0.0, 0.0, 0.3)


GEOM = ScannerGeometry(pixels=512, pixel_pitch_um=15.0, focal_length_mm=9.33)


def project(block: Block, truth: Truth, x_ecef: np.ndarray, strip: int
            ) -> tuple[float, float] | None:
    """(line, pixel) of a point in a strip, by hand from the conventions; None if unseen."""
    f = (GEOM.focal_length_mm + truth.delta_focal_mm) * 1e-3
    x0 = truth.delta_pp_um[0] * 1e-6
    y0 = truth.delta_pp_um[1] * 1e-6
    w, p, k = (a * AS for a in truth.boresight_arcsec)
    r_cb = np.diag([1.0, -1.0, -1.0]) @ _rx(w) @ _ry(p) @ _rz(k)

    def cam(t_ns: int) -> np.ndarray:
        pos, r_be, _ = block.state(np.array([t_ns]))
        centre = pos[0] + r_be[0] @ np.asarray(truth.lever_m)
        return np.asarray((r_be[0] @ r_cb).T @ (x_ecef - centre))

    def g(t_ns: int) -> float:
        pc = cam(t_ns)
        return float(-f * pc[0] / pc[2] - x0)

    t0 = block.t0[strip]
    # along-track distance from the strip start: a first guess, then Newton on the time
    _, r_be0, _ = block.state(np.array([t0]))
    pos0, _, _ = block.state(np.array([t0]))
    fwd = r_be0[0][:, 0]
    t = t0 + round(float(fwd @ (x_ecef - pos0[0])) / block.speed_mps * 1e9)
    for _ in range(20):
        h = 1_000_000
        d = (g(t + h) - g(t - h)) / (2 * h)
        step = -g(t) / d
        t += round(step)
        if abs(step) < 1:
            break
    pc = cam(t)
    pixel = GEOM.centre_pixel + (-f * pc[1] / pc[2] - y0) / (GEOM.pixel_pitch_um * 1e-6)
    line = (t - round(truth.delay_ms * 1e6) - t0) / block.period_ns
    if not (0 <= pixel <= GEOM.pixels - 1 and 0 <= line <= block.lines() - 1):
        return None
    return line, pixel


def terrain_dem() -> Dem:
    """A bilinear DEM (UTM 31N) with 300 m of relief around the origin."""
    to_utm = Transformer.from_crs(4326, UTM, always_xy=True)
    e0, n0 = to_utm.transform(LON0, LAT0)
    cell = 50.0
    cols = rows = 500
    first_e, first_n = e0 - cols / 2 * cell, n0 + rows / 2 * cell
    ee = first_e + np.arange(cols) * cell
    nn = first_n - np.arange(rows) * cell
    e, n = np.meshgrid(ee, nn)
    h = H_GROUND + 150 * np.sin((e - e0) / 1700.0) * np.cos((n - n0) / 2300.0) + 0.01 * (e - e0)
    return Dem(h.astype(np.float32), float(first_e), float(first_n), cell, cell, UTM)


@dataclass
class Scene:
    block: Block
    truth: Truth
    points: GroundPoints
    obs: ImageObservations
    clock: SegmentClock
    dem: Dem
    true_ecef: dict[str, np.ndarray]


def make_scene(block: Block, truth: Truth, *, n_control: int = 40, n_check: int = 30,
               n_tie: int = 0, noise_px: float = 0.3, seed: int = 1,
               blunders: dict[int, float] | None = None) -> Scene:
    rng = np.random.default_rng(seed)
    dem = terrain_dem()
    to_geo = Transformer.from_crs(UTM, 4326, always_xy=True)
    to_utm = Transformer.from_crs(4326, UTM, always_xy=True)
    e0, n0 = to_utm.transform(LON0, LAT0)
    half_w = (block.strips - 1) / 2 * block.spacing_m + 500.0
    kinds = ["control"] * n_control + ["check"] * n_check + ["tie"] * n_tie
    n = len(kinds)
    e = e0 + rng.uniform(-half_w, half_w, n)
    nn = n0 + rng.uniform(-block.length_m / 2 + 600, block.length_m / 2 - 600, n)
    h = dem.height_at(e, nn)
    lon, lat = to_geo.transform(e, nn)
    xyz = _ecef(np.asarray(lat), np.asarray(lon), h)
    ids = np.array([f"{k[0].upper()}{i:03d}" for i, k in enumerate(kinds)])
    rows: list[tuple[str, int, float, float]] = []
    for i in range(n):
        for s in range(block.strips):
            lp = project(block, truth, xyz[i], s)
            if lp is not None:
                rows.append((str(ids[i]), s, *lp))
    line = np.array([r[2] for r in rows]) + rng.normal(0, noise_px, len(rows))
    pixel = np.array([r[3] for r in rows]) + rng.normal(0, noise_px, len(rows))
    for k, off in (blunders or {}).items():
        pixel[k] += off
    obs = ImageObservations(np.array([r[0] for r in rows]), np.array([r[1] for r in rows]),
                            line, pixel, np.full(len(rows), max(noise_px, 0.05)))
    t_lines = {s: block.t0[s] + np.arange(block.lines(), dtype=np.int64) * block.period_ns
               for s in range(block.strips)}
    ecef = np.where(np.array(kinds)[:, None] == "tie", np.nan, xyz)
    pts = GroundPoints(ids, np.array(kinds), ecef, UTM)
    return Scene(block, truth, pts, obs, SegmentClock(t_lines), dem,
                 {str(i): x for i, x in zip(ids, xyz, strict=True)})


def nominal_sensor(**mounting: object) -> SensorModel:
    m = Mounting(lever_arm_m=(0.0, 0.0, 0.3), antenna_offset_m=(0.0, 0.0, -1.5),
                 **mounting)
    return SensorModel(name="test", scanner=GEOM, mounting=m)


def run(scene: Scene, groups: str, *, dem: bool = False, sensor: SensorModel | None = None,
        **opt: object) -> object:
    inp = CalibrationInput(NavTrajectory(scene.block), scene.clock, scene.points, scene.obs,
                           sensor or nominal_sensor(), scene.dem if dem else None)
    return calibrate(inp, CalibrationOptions(groups=parse_groups(groups), **opt))  # type: ignore[arg-type]


def estimate(res: object, name: str) -> tuple[float, float]:
    rows = report_json(res)["parameters"]  # type: ignore[arg-type]
    row = next(r for r in rows if r["name"] == name and r["segment"] is None)
    return float(row["estimate"]), float(row["sigma"])


# --- fixtures ---------------------------------------------------------------------------------

TRUE_SENSOR_KW = {"boresight_arcsec": Truth().boresight_arcsec}


def true_sensor(truth: Truth) -> SensorModel:
    geom = GEOM.model_copy(update={"delta_focal_mm": truth.delta_focal_mm,
                                   "delta_principal_point_um": truth.delta_pp_um})
    return nominal_sensor(boresight_arcsec=truth.boresight_arcsec).model_copy(
        update={"scanner": geom})


@pytest.fixture(scope="module")
def plain() -> Scene:
    return make_scene(Block(), Truth(), n_control=40, n_check=30, seed=3)


@pytest.fixture(scope="module")
def delayed() -> Scene:
    return make_scene(Block(), Truth(delay_ms=85.0), n_control=40, n_check=10, n_tie=150,
                      seed=4)


@pytest.fixture(scope="module")
def offset() -> Scene:
    return make_scene(Block(antenna_error_m=(1.5, 0.0, 0.0)), Truth(), n_control=40,
                      n_check=10, n_tie=150, seed=5)


def within(res: object, name: str, truth: float, k: float = 3.0) -> tuple[float, float]:
    est, sig = estimate(res, name)
    assert abs(est - truth) <= k * sig, f"{name}: {est:.4f} ± {sig:.4f}, truth {truth}"
    return est, sig


# --- conventions ------------------------------------------------------------------------------

def test_rotation_helpers_match_the_sensor_model() -> None:
    ang = np.array([[0.01, -0.02, 0.03], [-0.3, 0.2, 1.1]])
    for a, m in zip(ang, rot_xyz(ang), strict=True):
        np.testing.assert_allclose(m, rot_x(a[0]) @ rot_y(a[1]) @ rot_z(a[2]), atol=1e-15)
    b = (1742.0, -2.0, -74.0)
    np.testing.assert_allclose(boresight_matrix(np.array(b)),
                               Mounting(boresight_arcsec=b).boresight_matrix(), atol=1e-15)


def test_model_puts_a_point_right_of_track_below_the_centre_pixel() -> None:
    """Hand case: level flight north at 2160 m over the tangent plane, a point 100 m east of
    the track. Body y is right (east), camera y is left, so the pixel is c − 100/2159.7·f/pitch
    (the lever arm puts the camera 0.3 m lower); the line is when the aircraft is abeam."""
    block = Block(strips=1, wave_deg=(0.0, 0.0, 0.0))
    north = 1234.0
    x = ORIGIN + R_NED @ np.array([north, 100.0, 0.0])
    line = (north + block.length_m / 2) / block.speed_mps * 1e9 / block.period_ns
    pixel = GEOM.centre_pixel - 100.0 / 2159.7 * 9.33e-3 / 15e-6
    pts = GroundPoints(np.array(["C1", "C2"]), np.array(["control", "control"]),
                       np.stack([x, x + R_NED @ np.array([500.0, 0.0, 0.0])]), UTM)
    obs = ImageObservations(np.array(["C1", "C2"]), np.array([0, 0]),
                            np.array([line, line + 500 / 73.0 / 0.048]),
                            np.array([pixel, pixel]), np.array([0.3, 0.3]))
    clock = SegmentClock({0: block.t0[0] + np.arange(block.lines(), dtype=np.int64)
                          * block.period_ns})
    from postproc.calibration.adjust import build

    adj = build(CalibrationInput(NavTrajectory(block), clock, pts, obs, nominal_sensor()),
                CalibrationOptions(groups=(Group.DELAY,)))
    pb = adj.problem
    pb.update_rates(pb.theta0, adj.x0)
    r = pb.image_residuals(pb.layout.unpack(pb.theta0), adj.x0) * 0.3
    np.testing.assert_allclose(r, 0.0, atol=2e-3)
    assert pixel < GEOM.centre_pixel - 28.0


# --- recovery ---------------------------------------------------------------------------------

def test_boresight_and_selfcal_come_back_within_3_sigma(plain: Scene) -> None:
    res = run(plain, "boresight,selfcal")
    t = plain.truth
    for name, value in zip(("omega", "phi", "kappa"), t.boresight_arcsec, strict=True):
        within(res, name, value)
    _, sig_f = within(res, "delta_focal", t.delta_focal_mm)
    within(res, "delta_x0", t.delta_pp_um[0])
    within(res, "delta_y0", t.delta_pp_um[1])
    assert sig_f < 0.01
    assert estimate(res, "kappa")[1] < 120.0
    rep = report_json(res)  # type: ignore[arg-type]
    assert 0.7 < rep["sigma0"] < 1.3
    assert rep["blunders"] == []


def test_the_images_fix_the_look_offsets_even_where_angles_trade_off(plain: Scene) -> None:
    """φ ≡ −δx0/f' exactly and ω ≈ δy0/f': the correlations are ±1, the sums are tight."""
    res = run(plain, "boresight,selfcal")
    rep = report_json(res)  # type: ignore[arg-type]
    corr = {(h["a"], h["b"]): h["r"] for h in rep["high_correlations"]}
    assert corr[("phi", "delta_x0")] > 0.99
    assert corr[("omega", "delta_y0")] < -0.95
    t = plain.truth
    f_um = (9.33 + t.delta_focal_mm) * 1e3
    truth = {"along_um": t.delta_pp_um[0] - f_um * t.boresight_arcsec[1] * AS,
             "across_um": t.delta_pp_um[1] + f_um * t.boresight_arcsec[0] * AS}
    for key, value in truth.items():
        got = rep["look_offsets"][key]
        assert got["sigma"] < 3.0
        assert abs(got["value"] - value) < 3 * got["sigma"], (key, got, value)


def test_delay_is_recovered_when_the_boresight_is_known(delayed: Scene) -> None:
    res = run(delayed, "delay", dem=True, sensor=true_sensor(delayed.truth))
    _, sig = within(res, "time_delay", 85.0)
    assert sig < 1.0


def test_delay_trades_off_against_phi_when_both_are_free(delayed: Scene) -> None:
    res = run(delayed, "boresight,delay", dem=True, sensor=true_sensor(delayed.truth))
    corr = {frozenset((h["a"], h["b"])): h["r"]
            for h in report_json(res)["high_correlations"]}  # type: ignore[arg-type]
    assert abs(corr[frozenset(("phi", "time_delay"))]) > 0.9
    assert estimate(res, "time_delay")[1] > 3.0


def test_the_seeds_sweep_finds_the_delay(delayed: Scene) -> None:
    inp = CalibrationInput(NavTrajectory(delayed.block), delayed.clock, delayed.points,
                           delayed.obs, true_sensor(delayed.truth), None)
    sw = sweep_delay(inp, CalibrationOptions(groups=(Group.DELAY,)),
                     np.arange(-100.0, 100.1, 10.0))
    assert abs(sw["best_ms"] - 85.0) < 5.0
    assert sw["rms_m"][0] > 2 * min(sw["rms_m"])


def test_two_flights_at_different_speed_and_height_part_delay_from_phi(delayed: Scene
                                                                      ) -> None:
    """v·τ and H·φ look alike in one flight; a second flight with another v/H parts them."""
    low = make_scene(Block(height_m=1080.0, speed_mps=111.0, spacing_m=500.0,
                           t_start_ns=T0_NS + 3 * 3600 * 10**9),
                     Truth(delay_ms=85.0), n_control=40, n_check=10, n_tie=150, seed=6)
    groups = parse_groups("boresight,delay")
    sensor = nominal_sensor(boresight_arcsec=(1700.0, 0.0, -50.0)).model_copy(
        update={"scanner": true_sensor(delayed.truth).scanner})
    inputs = [CalibrationInput(NavTrajectory(sc.block), sc.clock, sc.points, sc.obs, sensor,
                               sc.dem) for sc in (delayed, low)]
    alone = calibrate(inputs[0], CalibrationOptions(groups=groups))
    joint = calibrate(join_flights(inputs), CalibrationOptions(groups=groups))
    _, sig_alone = estimate(alone, "time_delay")
    _, sig = within(joint, "time_delay", 85.0)
    within(joint, "phi", -2.0)
    assert sig < sig_alone / 10
    assert joint.counts["strips"] == 8
    with pytest.raises(InputError, match="overlap in GPS time"):
        join_flights([inputs[0], inputs[0]])


def test_an_unapplied_antenna_offset_shows_as_opposite_strip_shifts(offset: Scene) -> None:
    res = run(offset, "gps_strip", dem=True, sensor=true_sensor(offset.truth))
    rows = [r for r in report_json(res)["parameters"]  # type: ignore[arg-type]
            if r["name"] == "gps_north"]
    north = np.array([r["estimate"] for r in rows])
    heading_sign = np.array([1.0, -1.0, 1.0, -1.0])  # strips fly N, S, N, S
    # the navigation put the INS 1.5 m ahead of where it was (it took g 1.5 m too far back):
    # the shifts that repair it point backwards along every strip, north then south
    np.testing.assert_allclose(north * heading_sign, -1.5, atol=0.3)


def test_antenna_offset_is_recovered(offset: Scene) -> None:
    res = run(offset, "antenna", dem=True, sensor=true_sensor(offset.truth))
    _, sig = within(res, "antenna_dx", 1.5)
    assert sig < 0.1
    within(res, "antenna_dy", 0.0)


def test_per_strip_attitude_offsets_are_recovered() -> None:
    errors = {0: (60.0, -40.0, 80.0), 1: (-50.0, 30.0, -60.0), 2: (0.0, 0.0, 0.0),
              3: (40.0, 50.0, -90.0)}
    scene = make_scene(Block(ins_error_arcsec=errors), Truth(), n_control=40, n_check=0,
                       n_tie=150, seed=8)
    res = run(scene, "attitude", dem=True, sensor=true_sensor(scene.truth),
              priors=PriorSigmas(attitude_arcsec=200.0))
    rows = report_json(res)["parameters"]  # type: ignore[arg-type]
    for r in rows:
        want = errors[r["segment"]][["att_x", "att_y", "att_z"].index(r["name"])]
        assert abs(r["estimate"] - want) < 3 * r["sigma"], r
        # roll and pitch move whole strips; yaw only shears them (±half a swath)
        assert r["sigma"] < (40.0 if r["name"] != "att_z" else 150.0)


def test_blunders_are_found_and_reported() -> None:
    scene = make_scene(Block(), Truth(), n_control=40, n_check=10, seed=6,
                       blunders={3: 12.0, 20: -15.0, 41: 18.0})
    res = run(scene, "boresight,selfcal")
    rep = report_json(res)  # type: ignore[arg-type]
    found = {(b["id"], round(b["line"], 3)) for b in rep["blunders"]}
    want = {(str(scene.obs.point_id[k]), round(float(scene.obs.line[k]), 3))
            for k in (3, 20, 41)}
    assert want <= found
    assert len(found) <= 4
    within(res, "delta_focal", scene.truth.delta_focal_mm)


def test_dem_control_fixes_tie_point_heights(delayed: Scene) -> None:
    sensor = true_sensor(delayed.truth)
    up = {}
    for dem in (False, True):
        res = run(delayed, "delay", dem=dem, sensor=sensor)
        pts = [p for p in report_json(res)["points"]  # type: ignore[arg-type]
               if p["kind"] == "tie" and p["used"]]
        up[dem] = float(np.median([p["sigma_enu_m"][2] for p in pts]))
    assert up[True] < 2.0 < up[False]


def test_check_points_meet_their_prediction(plain: Scene) -> None:
    res = run(plain, "boresight,selfcal", gcp_sigma_m=(0.01, 0.01))
    chk = report_json(res)["check_points"]  # type: ignore[arg-type]
    assert chk["points"] >= 25
    for axis in ("along", "across"):
        ratio = chk[f"rms_{axis}_m"] / chk[f"predicted_rms_{axis}_m"]
        assert 0.75 < ratio < 1.25, (axis, chk)


def test_groups_that_cannot_be_separated_are_named(plain: Scene) -> None:
    with pytest.raises(InputError, match="cannot separate"):
        run(plain, "gps_block,gps_strip")
    with pytest.raises(InputError, match=r"cannot separate.*(phi|delta_x0)"):
        run(plain, "boresight,selfcal", priors=PriorSigmas(principal_point_x_um=None))


def test_the_calibration_file_is_a_sensor_file(plain: Scene, tmp_path: Path) -> None:
    res = run(plain, "boresight,selfcal")
    text = sensor_toml(res)  # type: ignore[arg-type]
    (tmp_path / "cal.toml").write_text(text)
    back = SensorModel.load(tmp_path / "cal.toml")
    assert back == load_check(text)
    assert back.mounting.boresight_arcsec[0] == pytest.approx(estimate(res, "omega")[0])
    assert back.scanner.delta_focal_mm == pytest.approx(estimate(res, "delta_focal")[0])
    assert "± " in text.splitlines()[2]


# --- inputs -----------------------------------------------------------------------------------

def test_unknown_point_and_groups_are_one_line_errors(plain: Scene) -> None:
    obs = plain.obs
    bad = ImageObservations(np.concatenate([obs.point_id, ["NOPE"]]),
                            np.concatenate([obs.segment, [0]]), np.concatenate([obs.line, [1.0]]),
                            np.concatenate([obs.pixel, [1.0]]),
                            np.concatenate([obs.sigma_px, [0.3]]))
    inp = CalibrationInput(NavTrajectory(plain.block), plain.clock, plain.points, bad,
                           nominal_sensor())
    with pytest.raises(InputError, match="'NOPE' is not in the ground points"):
        calibrate(inp)
    with pytest.raises(ConfigError, match="unknown group 'bore'"):
        parse_groups("bore,selfcal")


def test_segment_clock_interpolates_and_refuses_untimed_neighbours() -> None:
    t = np.array([100, 200, -1, 400], dtype=np.int64)
    clock = SegmentClock({0: t})
    got = clock.time_of(np.array([0, 0, 0, 0, 0, 1]), np.array([0.0, 0.25, 1.5, 3.0, 3.5, 0.0]))
    np.testing.assert_array_equal(got, [100, 125, -1, 400, -1, -1])


def test_ground_points_and_observations_files(tmp_path: Path) -> None:
    gp = tmp_path / "gp.csv"
    gp.write_text("# ground points, EPSG:32631\nid,kind,easting_m,northing_m,height_m\n"
                  "A,control,465000.0,4669000.0,400.0\nB,check,465100.0,4669100.0,410.0\n"
                  "T1,tie,nan,nan,nan\n")
    pts = read_ground_points(gp)
    lon, lat = Transformer.from_crs(UTM, 4326, always_xy=True).transform(465000.0, 4669000.0)
    np.testing.assert_allclose(pts.ecef_m[0], _ecef(np.array([lat]), np.array([lon]),
                                                    np.array([400.0]))[0], atol=1e-6)
    assert list(pts.kind) == ["control", "check", "tie"]
    assert np.isnan(pts.ecef_m[2]).all()
    gp.write_text("id,kind,lat_deg,lon_deg,height_m\nA,survey,42.0,2.0,1.0\n")
    with pytest.raises(InputError, match="kind 'survey'"):
        read_ground_points(gp)
    gp.write_text("id,kind,lat_deg,lon_deg,height_m\nA,control,42.0,x,1.0\n")
    with pytest.raises(InputError, match="column lon_deg, row 1: 'x' is not a number"):
        read_ground_points(gp)
    obs = ImageObservations(np.array(["A", "B"]), np.array([0, 3]), np.array([1.25, 7.5]),
                            np.array([100.125, 3.5]), np.array([0.3, 0.5]))
    path = tmp_path / "obs.csv"
    write_observations(path, obs)
    back = read_observations(path)
    np.testing.assert_array_equal(back.segment, obs.segment)
    np.testing.assert_allclose(back.line, obs.line)
    np.testing.assert_allclose(back.pixel, obs.pixel)
    path.write_text("id,segment,line,pixel\nA,0,1,2\n")
    with pytest.raises(InputError, match="no column 'sigma_px'"):
        read_observations(path)
    path.write_text("id,segment,line,pixel,sigma_px\nA,0,1,2,0\n")
    with pytest.raises(InputError, match="column sigma_px, row 1: 0 is outside"):
        read_observations(path)


def test_weights_beyond_double_precision_are_one_line_errors(plain: Scene) -> None:
    """σ = 1e-300 (past the file reader's floor) made the normal equations overflow: numpy
    RuntimeWarnings, then 'not determined', which blamed the points."""
    obs = plain.obs
    tiny = ImageObservations(obs.point_id, obs.segment, obs.line, obs.pixel,
                             np.full(len(obs), 1e-300))
    inp = CalibrationInput(NavTrajectory(plain.block), plain.clock, plain.points, tiny,
                           nominal_sensor())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputError, match="the normal equations overflow: a stated σ"):
            calibrate(inp, CalibrationOptions(groups=parse_groups("boresight")))


def test_a_sensor_file_for_another_scanner_is_refused(plain: Scene) -> None:
    small = nominal_sensor().model_copy(update={"scanner": GEOM.model_copy(
        update={"pixels": 256})})
    with pytest.raises(InputError, match="has 256 pixels: wrong sensor file"):
        run(plain, "boresight", sensor=small)
