"""The truth trajectory against independent oracles: finite differences of its own position and
attitude, pyproj for the geodesy, circle fits for the turns, and the planned strip lines."""

from __future__ import annotations

import csv
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pyproj import Transformer

from emulators.block import STANDARD_GRAVITY_MPS2, StripKind, strip_lines
from emulators.localplane import LocalPlane
from emulators.scenario import Scenario, load_scenario, scenario_from_table
from emulators.trajectory import (
    CSV_COLUMNS,
    KERNEL_HALF_WIDTH_S,
    FlownStrip,
    TruthTrajectory,
    _dubins,
    _Pose,
)
from sisa.core.frames import body_to_ned_matrix, ned_to_ecef_matrix

H_NS = 1_000_000  # 1 ms finite-difference step
CALM = {"turbulence_attitude_deg": 0.0, "turbulence_height_m": 0.0}


def bench_with(**tables: dict[str, Any]) -> Scenario:
    return scenario_from_table({"base": "bench", **tables})


@pytest.fixture(scope="module")
def bench() -> tuple[Scenario, TruthTrajectory]:
    scn = load_scenario("bench")
    return scn, TruthTrajectory.from_scenario(scn)


@pytest.fixture(scope="module")
def calm() -> tuple[Scenario, TruthTrajectory]:
    scn = bench_with(flight=CALM)
    return scn, TruthTrajectory.from_scenario(scn)


def phase_times(traj: TruthTrajectory, name: str, n: int, seed: int) -> np.ndarray:
    """Random instants inside every phase of that name, at least 1 ms from its edges."""
    rng = np.random.default_rng(seed)
    spans = [(p.t_start_ns + H_NS, p.t_end_ns - H_NS) for p in traj.phases if p.name == name]
    assert spans, f"no phase {name!r}"
    return np.concatenate([rng.integers(a, b, n) for a, b in spans])


def test_phases_are_contiguous_and_complete(bench: tuple[Scenario, TruthTrajectory]) -> None:
    _, traj = bench
    names = [p.name for p in traj.phases]
    assert names[:4] == ["static", "takeoff", "climb", "figure_eight"]
    assert {"transit", "run_in", "strip", "run_out", "turn"} <= set(names)
    assert traj.phases[0].t_start_ns == traj.t_start_ns
    assert traj.phases[-1].t_end_ns == traj.t_end_ns
    for a, b in zip(traj.phases, traj.phases[1:], strict=False):
        assert a.t_end_ns == b.t_start_ns
        assert a.t_end_ns > a.t_start_ns


def sample_times(traj: TruthTrajectory) -> np.ndarray:
    rng = np.random.default_rng(7)
    uniform = rng.integers(traj.t_start_ns + H_NS, traj.t_end_ns - H_NS, 300)
    special = [phase_times(traj, name, 40, 1) for name in ("takeoff", "climb", "turn",
                                                           "figure_eight", "transit")]
    return np.concatenate([uniform, *special])


def ecef_to_ned(state_lat_deg: np.ndarray, state_lon_deg: np.ndarray,
                v_ecef: np.ndarray) -> np.ndarray:
    r_ne = ned_to_ecef_matrix(np.radians(state_lat_deg), np.radians(state_lon_deg))
    return np.asarray(np.einsum("nji,nj->ni", r_ne, v_ecef))


def ned_to_ecef(lat_deg: np.ndarray, lon_deg: np.ndarray, v_ned: np.ndarray) -> np.ndarray:
    r_ne = ned_to_ecef_matrix(np.radians(lat_deg), np.radians(lon_deg))
    return np.asarray(np.einsum("nij,nj->ni", r_ne, v_ned))


def test_velocity_and_acceleration_are_derivatives(bench: tuple[Scenario, TruthTrajectory]
                                                   ) -> None:
    _, traj = bench
    t = sample_times(traj)
    mid, plus, minus = traj.state(t), traj.state(t + H_NS), traj.state(t - H_NS)
    h_s = 2 * H_NS / 1e9
    vel_num = ecef_to_ned(mid.lat_deg, mid.lon_deg, (plus.ecef_m - minus.ecef_m) / h_s)
    np.testing.assert_allclose(vel_num, mid.vel_ned_mps, atol=1e-4, rtol=0)  # brief: 1e-3
    v_plus = ned_to_ecef(plus.lat_deg, plus.lon_deg, plus.vel_ned_mps)
    v_minus = ned_to_ecef(minus.lat_deg, minus.lon_deg, minus.vel_ned_mps)
    acc_num = ecef_to_ned(mid.lat_deg, mid.lon_deg, (v_plus - v_minus) / h_s)
    np.testing.assert_allclose(acc_num, mid.acc_ned_mps2, atol=1e-4, rtol=0)
    assert np.abs(mid.acc_ned_mps2).max() > 1.0  # the sample holds real manoeuvres


def skew(w: np.ndarray) -> np.ndarray:
    z = np.zeros(len(w))
    return np.stack([np.stack([z, -w[:, 2], w[:, 1]], -1),
                     np.stack([w[:, 2], z, -w[:, 0]], -1),
                     np.stack([-w[:, 1], w[:, 0], z], -1)], axis=1)


def test_body_rates_are_the_attitude_derivative(bench: tuple[Scenario, TruthTrajectory]) -> None:
    _, traj = bench
    t = sample_times(traj)
    mid, plus, minus = traj.state(t), traj.state(t + H_NS), traj.state(t - H_NS)

    def r_bn(s: Any) -> np.ndarray:
        return body_to_ned_matrix(s.roll_rad, s.pitch_rad, s.heading_rad)

    d_r = (r_bn(plus) - r_bn(minus)) / (2 * H_NS / 1e9)
    omega_num = np.einsum("nji,njk->nik", r_bn(mid), d_r)  # R^T dR/dt = [ω×]
    np.testing.assert_allclose(omega_num, skew(mid.body_rate_rps), atol=1e-6, rtol=0)
    assert np.abs(mid.body_rate_rps).max() > 0.05
    assert np.all((mid.heading_rad >= 0) & (mid.heading_rad < 2 * np.pi))


def test_geodetic_and_ecef_agree_with_pyproj(bench: tuple[Scenario, TruthTrajectory]) -> None:
    _, traj = bench
    s = traj.state(sample_times(traj))
    to_ecef = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    x, y, z = to_ecef.transform(s.lon_deg, s.lat_deg, s.height_m)
    np.testing.assert_allclose(np.stack([x, y, z], -1), s.ecef_m, atol=1e-4, rtol=0)


def test_eastbound_strip_points_east_with_crab() -> None:
    scn = bench_with(block={"first_strip_heading_deg": 90.0, "strips": 1}, flight=CALM)
    traj = TruthTrajectory.from_scenario(scn)
    (strip,) = traj.strips
    assert strip.heading_deg == 90.0
    s = traj.state(np.linspace(strip.t_start_ns, strip.t_end_ns, 50).astype(np.int64))
    speed = scn.block.ground_speed_mps
    assert np.all(s.vel_ned_mps[:, 1] > 0.99 * speed)
    assert np.abs(s.vel_ned_mps[:, 0]).max() < 0.001 * speed
    heading_deg = np.degrees(s.heading_rad)
    np.testing.assert_allclose(heading_deg, 90.0 + scn.flight.crab_deg, atol=0.05)
    assert np.all(np.diff(s.lon_deg) > 0)


def test_northbound_strip_climbs_in_latitude(bench: tuple[Scenario, TruthTrajectory]) -> None:
    _, traj = bench
    north = [f for f in traj.strips if f.heading_deg == 0.0]
    south = [f for f in traj.strips if f.heading_deg == 180.0]
    assert north
    assert south
    for strips, sign in ((north, 1.0), (south, -1.0)):
        for f in strips:
            s = traj.state(np.linspace(f.t_start_ns, f.t_end_ns, 20).astype(np.int64))
            assert np.all(sign * np.diff(s.lat_deg) > 0)
            assert np.all(sign * s.vel_ned_mps[:, 0] > 0)


def test_right_turn_rolls_right_wing_down(calm: tuple[Scenario, TruthTrajectory]) -> None:
    _, traj = calm
    t = np.concatenate([phase_times(traj, name, 400, 3)
                        for name in ("figure_eight", "turn", "transit")])
    mid, plus, minus = traj.state(t), traj.state(t + 100 * H_NS), traj.state(t - 100 * H_NS)
    course_rate = np.angle(np.exp(1j * (np.arctan2(plus.vel_ned_mps[:, 1], plus.vel_ned_mps[:, 0])
                                        - np.arctan2(minus.vel_ned_mps[:, 1],
                                                     minus.vel_ned_mps[:, 0])))) / 0.2
    right, left = course_rate > 0.05, course_rate < -0.05
    assert right.sum() > 50
    assert left.sum() > 50
    assert np.all(mid.roll_rad[right] > math.radians(10))
    assert np.all(mid.roll_rad[left] < -math.radians(10))
    r_bn = body_to_ned_matrix(mid.roll_rad, mid.pitch_rad, mid.heading_rad)
    assert np.all(r_bn[right, 2, 1] > 0.1)  # body y (right wing) points down
    assert np.all(r_bn[left, 2, 1] < -0.1)


@pytest.mark.parametrize("bank_deg", [30.0, 60.0])
def test_turn_radius_matches_bank(bank_deg: float) -> None:
    scn = bench_with(flight={"turn_bank_deg": bank_deg, **CALM})
    traj = TruthTrajectory.from_scenario(scn)
    eight = next(p for p in traj.phases if p.name == "figure_eight")
    # the first circle of the figure-eight turns right; away from its ends the turn is steady
    circle_s = (eight.t_end_ns - eight.t_start_ns) / 2e9
    half_s = circle_s / 2 - KERNEL_HALF_WIDTH_S - 0.5
    mid_ns = eight.t_start_ns + round(circle_s / 2 * 1e9)
    s = traj.state(mid_ns + np.rint(np.linspace(-half_s, half_s, 21) * 1e9).astype(np.int64))
    bank = math.radians(bank_deg)
    v_h = np.hypot(s.vel_ned_mps[:, 0], s.vel_ned_mps[:, 1])
    a_h = np.hypot(s.acc_ned_mps2[:, 0], s.acc_ned_mps2[:, 1])
    expected = v_h**2 / (STANDARD_GRAVITY_MPS2 * math.tan(bank))
    np.testing.assert_allclose(v_h**2 / a_h, expected, rtol=0.01)
    e, n = LocalPlane.for_scenario(scn).geodetic_to_plane(s.lat_deg, s.lon_deg)
    a = np.column_stack([e, n, np.ones_like(e)])  # Kåsa fit: e² + n² = 2·ce·e + 2·cn·n + c
    (ce2, cn2, c), *_ = np.linalg.lstsq(a, e**2 + n**2, rcond=None)
    radius = math.sqrt(c + (ce2 / 2) ** 2 + (cn2 / 2) ** 2)
    assert radius == pytest.approx(float(expected.mean()), rel=0.01)
    planned = scn.block.ground_speed_mps**2 / (STANDARD_GRAVITY_MPS2 * math.tan(bank))
    assert radius == pytest.approx(planned, rel=0.01)
    np.testing.assert_allclose(np.degrees(s.roll_rad), bank_deg, rtol=0.01)


def check_strips(scn: Scenario, traj: TruthTrajectory, cross_track_m: float) -> None:
    plane = LocalPlane.for_scenario(scn)
    lines = strip_lines(scn)
    assert [f.index for f in traj.strips] == [line.index for line in lines]
    cruise_m = scn.terrain.mean_height_m + scn.block.flying_height_agl_m
    for flown, line in zip(traj.strips, lines, strict=True):
        assert isinstance(flown, FlownStrip)
        assert flown.kind == line.kind
        assert flown.heading_deg == line.heading_deg
        s = traj.state(np.linspace(flown.t_start_ns, flown.t_end_ns, 200).astype(np.int64))
        assert np.abs(s.height_m - cruise_m).max() <= 5 * scn.flight.turbulence_height_m + 1e-3
        speed = np.hypot(s.vel_ned_mps[:, 0], s.vel_ned_mps[:, 1])
        np.testing.assert_allclose(speed, scn.block.ground_speed_mps, rtol=0.01)
        e, n = plane.geodetic_to_plane(s.lat_deg, s.lon_deg)
        (e0, n0), (e1, n1) = line.start_en_m, line.end_en_m
        ux, uy = (e1 - e0) / line.length_m, (n1 - n0) / line.length_m
        assert np.abs((e - e0) * uy - (n - n0) * ux).max() < cross_track_m
        along = (e - e0) * ux + (n - n0) * uy
        assert along[0] == pytest.approx(0.0, abs=0.5)
        assert along[-1] == pytest.approx(line.length_m, abs=0.5)


def test_strips_are_flown_as_planned(bench: tuple[Scenario, TruthTrajectory]) -> None:
    check_strips(*bench, cross_track_m=3.0)


def test_calm_strips_follow_the_line_closely(calm: tuple[Scenario, TruthTrajectory]) -> None:
    check_strips(*calm, cross_track_m=0.5)


def test_transversal_strips_and_no_alternation() -> None:
    scn = bench_with(block={"strips": 3, "transversal_strips": 1, "alternate_directions": False})
    traj = TruthTrajectory.from_scenario(scn)
    assert [f.kind for f in traj.strips] == [StripKind.MAIN] * 3 + [StripKind.TRANSVERSAL]
    check_strips(scn, traj, cross_track_m=3.0)


def test_static_alignment_is_at_rest(bench: tuple[Scenario, TruthTrajectory]) -> None:
    scn, traj = bench
    static = traj.phases[0]
    assert static.name == "static"
    assert static.t_end_ns - static.t_start_ns == round(scn.flight.static_alignment_s * 1e9)
    s = traj.state(np.linspace(static.t_start_ns, static.t_end_ns, 101).astype(np.int64))
    for moving in (s.vel_ned_mps, s.acc_ned_mps2, s.body_rate_rps):
        assert np.all(moving == 0.0)
    for fixed in (s.ecef_m, s.roll_rad, s.pitch_rad, s.heading_rad):
        assert np.all(fixed == fixed[0])
    assert s.roll_rad[0] == 0.0
    assert math.degrees(s.pitch_rad[0]) == pytest.approx(1.0)
    assert math.degrees(s.heading_rad[0]) == pytest.approx(scn.flight.runway_heading_deg,
                                                          abs=1e-4)
    np.testing.assert_allclose(s.height_m, scn.terrain.mean_height_m, atol=1e-6)
    e, n = LocalPlane.for_scenario(scn).geodetic_to_plane(s.lat_deg[:1], s.lon_deg[:1])
    np.testing.assert_allclose([e[0], n[0]], scn.flight.airfield_offset_m, atol=1e-6)


def test_takeoff_rolls_along_the_runway_then_lifts_off() -> None:
    scn = bench_with(flight={"runway_heading_deg": 250.0, **CALM})
    traj = TruthTrajectory.from_scenario(scn)
    takeoff = traj.phases[1]
    assert takeoff.name == "takeoff"
    s = traj.state(np.linspace(takeoff.t_start_ns, takeoff.t_end_ns, 50).astype(np.int64))
    np.testing.assert_allclose(s.height_m, scn.terrain.mean_height_m, atol=1e-6)
    # a straight runway's true heading changes by the meridian convergence (~1e-5 °/m here)
    np.testing.assert_allclose(np.degrees(s.heading_rad), 250.0, atol=0.01)
    np.testing.assert_allclose(s.roll_rad, 0.0, atol=1e-6)
    speed = np.hypot(s.vel_ned_mps[:, 0], s.vel_ned_mps[:, 1])
    assert np.all(np.diff(speed) >= 0)
    assert speed[-1] == pytest.approx(scn.flight.rotation_speed_kmh / 3.6, rel=0.05)
    after = traj.state(np.array([takeoff.t_end_ns + 20 * 10**9]))
    assert after.height_m[0] > scn.terrain.mean_height_m + 50


def test_holding_circles_finish_the_climb_before_the_first_run_in() -> None:
    scn = bench_with(block={"flying_height_agl_m": 2500.0},
                     flight={"climb_rate_mps": 4.0, **CALM})
    traj = TruthTrajectory.from_scenario(scn)
    names = [p.name for p in traj.phases]
    assert "holding" in names
    run_in = next(p for p in traj.phases if p.name == "run_in")
    s = traj.state(np.array([run_in.t_start_ns]))
    cruise = scn.terrain.mean_height_m + scn.block.flying_height_agl_m
    assert s.height_m[0] == pytest.approx(cruise, abs=1e-3)
    assert "holding" not in [p.name for p in TruthTrajectory.from_scenario(
        bench_with(flight=CALM)).phases]


def test_turbulence_is_seeded_and_sized(calm: tuple[Scenario, TruthTrajectory]) -> None:
    scn = bench_with()
    a, b = TruthTrajectory.from_scenario(scn), TruthTrajectory.from_scenario(scn)
    other = TruthTrajectory.from_scenario(scenario_from_table({"base": "bench", "seed": 99}))
    (strip, *_) = a.strips
    t = np.linspace(strip.t_start_ns, strip.t_end_ns, 500).astype(np.int64)
    sa, sb, so, sc = a.state(t), b.state(t), other.state(t), calm[1].state(t)
    np.testing.assert_array_equal(sa.roll_rad, sb.roll_rad)
    assert not np.allclose(sa.roll_rad, so.roll_rad)
    np.testing.assert_allclose(sc.roll_rad, 0.0, atol=1e-6)
    rms_deg = math.degrees(float(np.sqrt(np.mean(sa.roll_rad**2))))
    assert 0.05 < rms_deg < 3 * scn.flight.turbulence_attitude_deg


def test_state_accepts_any_order_and_rejects_outside(bench: tuple[Scenario, TruthTrajectory]
                                                     ) -> None:
    _, traj = bench
    t = np.random.default_rng(3).integers(traj.t_start_ns, traj.t_end_ns, 1000)
    shuffled, ordered = traj.state(t), traj.state(np.sort(t))
    order = np.argsort(t, kind="stable")
    np.testing.assert_array_equal(shuffled.ecef_m[order], ordered.ecef_m)
    np.testing.assert_array_equal(shuffled.t_gps_ns, t)
    assert traj.state(traj.t_end_ns).lat_deg.shape == (1,)
    with pytest.raises(ValueError, match="outside"):
        traj.state(np.array([traj.t_start_ns - 1]))
    with pytest.raises(ValueError, match="outside"):
        traj.state(np.array([traj.t_end_ns + 1]))
    with pytest.raises(TypeError):
        traj.state(np.array([float(traj.t_start_ns)]))


def test_write_csv_round_trips(bench: tuple[Scenario, TruthTrajectory], tmp_path: Path) -> None:
    _, traj = bench
    path = tmp_path / "truth.csv"
    traj.write_csv(path, step_s=0.5)
    lines = path.read_text("utf-8").splitlines()
    assert lines[0].startswith("#")
    rows = list(csv.DictReader(line for line in lines if not line.startswith("#")))
    assert tuple(rows[0]) == CSV_COLUMNS
    t = np.array([int(r["t_gps_ns"]) for r in rows], dtype=np.int64)
    assert t[0] == traj.t_start_ns
    assert np.all(np.diff(t) == 500_000_000)
    assert t[-1] > traj.t_end_ns - 500_000_000
    s = traj.state(t)
    np.testing.assert_allclose([float(r["lat_deg"]) for r in rows], s.lat_deg, atol=1e-9)
    np.testing.assert_allclose([float(r["heading_deg"]) for r in rows],
                               np.degrees(s.heading_rad), atol=1e-6)


def test_dubins_reaches_random_goals() -> None:
    rng = np.random.default_rng(11)
    for _ in range(300):
        x, y = rng.uniform(-3000, 3000, 2)
        start = _Pose(0.0, 0.0, rng.uniform(-4, 4))
        goal = _Pose(x, y, rng.uniform(-4, 4))
        path = _dubins(start, goal, 600.0)  # raises if it misses the goal
        length = sum(seg.length_m for seg in path)
        assert math.hypot(x, y) - 1e-6 <= length <= math.hypot(x, y) + 7 * math.pi * 600.0
        end = path[-1].end()
        assert math.cos(end.theta_rad - goal.theta_rad) == pytest.approx(1.0)


@pytest.mark.parametrize(("preset", "hours"), [("garrotxa", (1.2, 2.0)), ("bellmunt", (0.4, 1.5))])
def test_preset_flights_are_plausible(preset: str, hours: tuple[float, float]) -> None:
    scn = load_scenario(preset)
    t0 = time.perf_counter()
    traj = TruthTrajectory.from_scenario(scn)
    build_s = time.perf_counter() - t0
    print(f"{preset}: flight {traj.duration_s:.0f} s = {traj.duration_s / 3600:.2f} h, "
          f"built in {build_s:.2f} s")
    assert build_s < 5.0
    assert hours[0] < traj.duration_s / 3600 < hours[1]
    assert len(traj.strips) == scn.block.strips + scn.block.transversal_strips
    check_strips(scn, traj, cross_track_m=3.0)
