"""The navigation solution (postproc.georef.navigation) against an analytic flight and a simulated
run.

The synthetic flight (`Synthetic`) is written here, independently of the emulators: a straight
strip, then a serpentine of ±30° course swings, with attitude and height turbulence, heading
hovering around north so that it wraps 359° → 0°. GPS fixes (1 Hz, antenna) and INS records
(64 Hz, jittered epochs) are quantised as on the wire: attitude 1e-7 rad, velocity 1 mm/s,
latitude/longitude 1e-7 arc-minute, height 1 mm. test_trajfiles uses it too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pyproj import Transformer

from emulators.scenario import Scenario, load_scenario
from emulators.trajectory import TruthTrajectory
from emulators.truth import read_truth_csv
from postproc.georef.navigation import (
    ALIGNING_BIT,
    NAV_WANTED,
    NAVIGATING_BIT,
    NavConfig,
    Pose,
    nav_from_columns,
    nav_from_log,
)
from postproc.sync import WANTED as SYNC_WANTED
from postproc.sync import InsTimes, SyncResult, TimeStatus, sync_input_from_columns, synchronise
from recorder.columns import read_topics
from recorder.messages import Topic
from sisa.core.errors import ConfigError, InputError
from sisa.core.frames import body_to_ned_matrix, euler_from_body_to_ned, ned_to_ecef_matrix
from sisa.core.timescale import NS_PER_S, parse_gps_datetime

MM = 1e-3
ARCSEC = math.pi / (180 * 3600)
POS_TOL_M = 1.0 * MM
ATT_TOL_RAD = 0.05 * ARCSEC
T0_NS = parse_gps_datetime("2026-06-15T09:00:00")
LAT0, LON0, H0 = 41.6, 2.0, 900.0
G_B = np.array([0.4, -0.2, -1.5])  # antenna offset used by the synthetic flight

_TO_GEO = Transformer.from_crs(4978, 4979, always_xy=True)


def wgs84_ecef(lat_deg: Any, lon_deg: Any, h_m: Any) -> np.ndarray:
    """Closed-form geodetic → ECEF (an oracle independent of pyproj)."""
    a, f = 6378137.0, 1 / 298.257223563
    e2 = f * (2 - f)
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    n = a / np.sqrt(1 - e2 * np.sin(lat) ** 2)
    return np.stack([(n + h_m) * np.cos(lat) * np.cos(lon), (n + h_m) * np.cos(lat) * np.sin(lon),
                     (n * (1 - e2) + h_m) * np.sin(lat)], axis=-1)


def geodetic(ecef: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    lon, lat, h = _TO_GEO.transform(ecef[..., 0], ecef[..., 1], ecef[..., 2])
    return np.asarray(lat), np.asarray(lon), np.asarray(h)


def r_ne(ecef: np.ndarray) -> np.ndarray:
    lat, lon, _ = geodetic(ecef)
    return ned_to_ecef_matrix(np.radians(lat), np.radians(lon))


def rotation_error_rad(r_true: np.ndarray, r_est: np.ndarray) -> np.ndarray:
    """Angle of R_trueᵀ·R_est (small-angle exact through the skew part)."""
    d = np.swapaxes(r_true, -1, -2) @ r_est
    skew = np.stack([d[:, 2, 1] - d[:, 1, 2], d[:, 0, 2] - d[:, 2, 0], d[:, 1, 0] - d[:, 0, 1]],
                    axis=-1) / 2
    return np.arcsin(np.clip(np.linalg.norm(skew, axis=1), 0, 1))


# --- the synthetic flight -----------------------------------------------------------------------

def _turb(t: np.ndarray, periods: tuple[float, ...], amp: float, phase: float) -> tuple[Any, Any]:
    """Sum of sines and its derivative; amp is the RMS."""
    w = [2 * math.pi / p for p in periods]
    a = amp * math.sqrt(2 / len(periods))
    y = sum(a * np.sin(wk * t + phase + k) for k, wk in enumerate(w))
    dy = sum(a * wk * np.cos(wk * t + phase + k) for k, wk in enumerate(w))
    return y, dy


@dataclass(frozen=True)
class Synthetic:
    """Truth as analytic functions of GPS ns: straight strip to T1, blend to T2, serpentine."""

    duration_s: float = 240.0
    speed_mps: float = 70.0
    swing_m: float = 600.0
    swing_period_s: float = 90.0
    t1_s: float = 60.0
    t2_s: float = 90.0
    crab_rad: float = math.radians(-0.1)

    def _blend(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        u = np.clip((t - self.t1_s) / (self.t2_s - self.t1_s), 0, 1)
        w = u**3 * (10 - 15 * u + 6 * u**2)
        dw = 30 * u**2 * (1 - u) ** 2 / (self.t2_s - self.t1_s)
        return w, np.where((u > 0) & (u < 1), dw, 0.0)

    def local(self, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """NED offset from the origin's local level, and its time derivative."""
        t = (np.asarray(t_ns) - T0_NS) / NS_PER_S
        om = 2 * math.pi / self.swing_period_s
        w, dw = self._blend(t)
        e = self.swing_m * np.sin(om * (t - self.t1_s)) * w
        de = self.swing_m * (om * np.cos(om * (t - self.t1_s)) * w
                             + np.sin(om * (t - self.t1_s)) * dw)
        hz, dhz = _turb(t, (7.3, 17.0, 31.0), 1.0, 0.3)
        pos = np.stack([self.speed_mps * t, e, -hz], axis=-1)
        vel = np.stack([np.full_like(t, self.speed_mps), de, -dhz], axis=-1)
        return pos, vel

    def state(self, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(ECEF of the INS centre, NED velocity, R_b^n, R_b^e)."""
        origin = wgs84_ecef(LAT0, LON0, H0)
        r0 = ned_to_ecef_matrix(math.radians(LAT0), math.radians(LON0))
        pos, vel = self.local(t_ns)
        ecef = origin + pos @ r0.T
        rne = r_ne(ecef)
        vel_ned = np.einsum("nji,nj->ni", rne, vel @ r0.T)
        t = (np.asarray(t_ns) - T0_NS) / NS_PER_S
        w, _ = self._blend(t)
        om = 2 * math.pi / self.swing_period_s
        sig = math.radians(0.3)
        heading = (np.arctan2(vel[:, 1], vel[:, 0]) + self.crab_rad
                   + _turb(t, (3.0, 8.0, 23.0), sig, 1.1)[0])
        roll = (math.radians(20) * w * np.sin(om * (t - self.t1_s))
                + _turb(t, (3.3, 9.0, 29.0), sig, 2.2)[0])
        pitch = math.radians(2.0) + _turb(t, (4.1, 11.0, 41.0), sig, 0.7)[0]
        r_bn = body_to_ned_matrix(roll, pitch, heading)
        return ecef, vel_ned, r_bn, rne @ r_bn

    @property
    def end_ns(self) -> int:
        return T0_NS + round(self.duration_s * NS_PER_S)

    def ins_times(self, seed: int = 1) -> np.ndarray:
        n = int(self.duration_s * 64) - 40
        jitter = np.random.default_rng(seed).integers(-2_000, 2_000, n)
        return T0_NS + 300_000_000 + np.arange(n, dtype=np.int64) * 15_625_000 + jitter

    def columns(self, g_b: np.ndarray = G_B, fix_step_s: float = 1.0
                ) -> tuple[dict[str, dict[str, np.ndarray]], InsTimes]:
        """The log's columns and the sync result's record times, quantised as on the wire."""
        t_ins = self.ins_times()
        _, vel, r_bn, _ = self.state(t_ins)
        roll, pitch, heading = euler_from_body_to_ned(r_bn)
        q = np.round
        ins = {"status": np.full(t_ins.size, NAVIGATING_BIT, dtype=np.int64),
               "roll_rad": q(roll / 1e-7) * 1e-7, "pitch_rad": q(pitch / 1e-7) * 1e-7,
               "heading_rad": np.mod(q(heading / 1e-7) * 1e-7, 2 * math.pi),
               **{f"vel_{c}_mps": q(vel[:, k] / 1e-3) * 1e-3 for k, c in enumerate("ned")}}
        step = round(fix_step_s * NS_PER_S)
        t_fix = np.arange(T0_NS + NS_PER_S, self.end_ns, step, dtype=np.int64)
        ecef, _, _, r_eb = self.state(t_fix)
        lat, lon, h = geodetic(ecef + r_eb @ g_b)
        arcmin7 = 1e-7 / 60
        fix = {"t_gps_ns": t_fix, "lat_deg": q(lat / arcmin7) * arcmin7,
               "lon_deg": q(lon / arcmin7) * arcmin7, "height_m": q(h / 1e-3) * 1e-3,
               "quality": np.full(t_fix.size, 4, dtype=np.int64)}
        n = t_ins.size
        times = InsTimes(np.arange(n, dtype=np.int64), np.arange(n, dtype=np.int64) % 65536,
                         t_ins, np.full(n, int(TimeStatus.OK), dtype=np.int64))
        return {Topic.GPS_FIX: fix, Topic.INS_RECORD: ins}, times


def pose_errors(syn: Synthetic, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    """Position (m) and attitude (rad) errors of the valid rows."""
    ecef, _, _, r_eb = syn.state(pose.t_gps_ns[pose.valid])
    dp = np.linalg.norm(pose.ins_ecef_m[pose.valid] - ecef, axis=1)
    return dp, rotation_error_rad(r_eb, pose.r_ecef_from_body[pose.valid])


SYN = Synthetic()


@pytest.fixture(scope="module")
def synthetic() -> tuple[dict[str, dict[str, np.ndarray]], InsTimes]:
    return SYN.columns()


def _random_times(lo_s: float, hi_s: float, n: int, seed: int = 7) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.sort(T0_NS + rng.integers(round(lo_s * NS_PER_S), round(hi_s * NS_PER_S), n))


# --- accuracy on the synthetic flight ------------------------------------------------------------

@pytest.mark.parametrize(("name", "lo_s", "hi_s"), [("straight", 2.0, 59.0),
                                                     ("blend", 59.0, 91.0),
                                                     ("serpentine", 91.0, 238.0)])
def test_within_1mm_and_005arcsec_between_records(synthetic: Any, name: str, lo_s: float,
                                                  hi_s: float) -> None:
    cols, times = synthetic
    traj = nav_from_columns(cols, times, antenna_offset_m=G_B)
    t = np.concatenate([_random_times(lo_s, hi_s, 4000),
                        times.t_gps_ns[1:] - 7_812_500])  # half-way between records
    t = t[(t > T0_NS + round(lo_s * NS_PER_S)) & (t < T0_NS + round(hi_s * NS_PER_S))]
    pose = traj.pose_at(t)
    assert pose.valid.all()
    dp, da = pose_errors(SYN, pose)
    assert dp.max() < POS_TOL_M, f"{name}: position error {dp.max() / MM:.3f} mm"
    assert da.max() < ATT_TOL_RAD, f"{name}: attitude error {da.max() / ARCSEC:.4f} arcsec"


def test_the_serpentine_really_turns_and_is_turbulent() -> None:
    """The accuracy test above means something only if the flight turns and shakes."""
    t = _random_times(91.0, 238.0, 2000)
    _, _, r_bn, _ = SYN.state(t)
    roll, _pitch, heading = euler_from_body_to_ned(r_bn)
    course_swing = np.ptp(np.unwrap(heading))
    assert course_swing > math.radians(50)
    assert np.ptp(roll) > math.radians(30)
    pos, _ = SYN.local(_random_times(2.0, 59.0, 2000))
    assert np.ptp(pos[:, 2]) > 2.0  # height turbulence of ~1 m RMS on the straight strip


def test_heading_wraps_through_north_without_harm(synthetic: Any) -> None:
    cols, times = synthetic
    h = cols[Topic.INS_RECORD]["heading_rad"]
    wraps = np.flatnonzero(np.abs(np.diff(h)) > math.pi)
    assert wraps.size > 20  # the logged heading jumps 2π between neighbouring records
    traj = nav_from_columns(cols, times, antenna_offset_m=G_B)
    t = np.concatenate([times.t_gps_ns[w] + np.array([2_000_000, 7_812_500, 13_000_000])
                        for w in wraps])
    t = t[(t > traj.span_ns[0]) & (t < traj.span_ns[1])]
    assert t.size > 60
    pose = traj.pose_at(t)
    _, da = pose_errors(SYN, pose)
    assert pose.valid.all()
    assert da.max() < ATT_TOL_RAD
    r_bn = np.swapaxes(r_ne(pose.ins_ecef_m), 1, 2) @ pose.r_ecef_from_body
    _, _, heading = euler_from_body_to_ned(r_bn)
    _, _, r_true, _ = SYN.state(t)
    _, _, h_true = euler_from_body_to_ned(r_true)
    d = np.angle(np.exp(1j * (heading - h_true)))
    assert np.abs(d).max() < ATT_TOL_RAD


# --- gaps, bad records, span ---------------------------------------------------------------------

def _drop_fixes(cols: dict[str, dict[str, np.ndarray]], lo_s: float, hi_s: float
                ) -> dict[str, dict[str, np.ndarray]]:
    fix = cols[Topic.GPS_FIX]
    t = fix["t_gps_ns"]
    keep = (t < T0_NS + lo_s * NS_PER_S) | (t > T0_NS + hi_s * NS_PER_S)
    return {**cols, Topic.GPS_FIX: {k: v[keep] for k, v in fix.items()}}


def test_a_20s_gps_outage_in_a_turn_is_bridged_by_the_ins(synthetic: Any) -> None:
    cols, times = synthetic
    traj = nav_from_columns(_drop_fixes(cols, 120.0, 140.0), times, antenna_offset_m=G_B)
    t = _random_times(120.0, 141.0, 3000)
    pose = traj.pose_at(t)
    assert pose.valid.all()
    assert traj.gaps_ns() == []
    dp, da = pose_errors(SYN, pose)
    # the 1 mm/s velocity LSB is a bias, not noise, while the velocity hardly changes: over
    # 20 s without fixes it integrates to ~1 mm (0.9 mm measured), so 2 mm here
    assert dp.max() < 2 * POS_TOL_M, f"bridged 20 s: {dp.max() / MM:.3f} mm"
    assert da.max() < ATT_TOL_RAD


def test_a_gps_outage_longer_than_the_limit_is_invalid_not_extrapolated(synthetic: Any) -> None:
    cols, times = synthetic
    traj = nav_from_columns(_drop_fixes(cols, 120.0, 160.0), times, antenna_offset_m=G_B)
    (gap,) = traj.gaps_ns()
    assert gap == (T0_NS + 119 * NS_PER_S, T0_NS + 161 * NS_PER_S)
    pose = traj.pose_at(np.array([gap[0] - 1, gap[0] + 1, gap[1] - 1, gap[1] + 1]))
    assert pose.valid.tolist() == [True, False, False, True]
    assert np.isnan(pose.ins_ecef_m[1:3]).all()
    assert np.isnan(pose.r_ecef_from_body[1:3]).all()
    loose = nav_from_columns(_drop_fixes(cols, 120.0, 160.0), times, antenna_offset_m=G_B,
                             config=NavConfig(max_gps_gap_s=60.0))
    assert loose.pose_at(np.array([gap[0] + NS_PER_S])).valid.all()


def test_fixes_of_quality_zero_are_discarded(synthetic: Any) -> None:
    cols, times = synthetic
    fix = {k: v.copy() for k, v in cols[Topic.GPS_FIX].items()}
    bad = (fix["t_gps_ns"] > T0_NS + 100 * NS_PER_S) & (fix["t_gps_ns"] < T0_NS + 110 * NS_PER_S)
    fix["quality"][bad] = 0
    fix["height_m"][bad] += 50.0  # a wild fix the receiver flagged invalid
    traj = nav_from_columns({**cols, Topic.GPS_FIX: fix}, times, antenna_offset_m=G_B)
    dp, _ = pose_errors(SYN, traj.pose_at(_random_times(99.0, 112.0, 500)))
    assert dp.max() < POS_TOL_M


def test_records_without_time_or_not_navigating_are_skipped(synthetic: Any) -> None:
    cols, times = synthetic
    ins = {k: v.copy() for k, v in cols[Topic.INS_RECORD].items()}
    t, status = times.t_gps_ns.copy(), times.status.copy()
    lone = np.arange(3000, 9000, 611)  # isolated records the sync could not time
    status[lone], t[lone] = TimeStatus.AMBIGUOUS, -1
    ins["roll_rad"][lone] = 1.0  # garbage that must not leak into the solution
    block = slice(8000, 8064)  # one second still aligning: a gap in the attitude
    ins["status"][block] = ALIGNING_BIT
    ins["heading_rad"][block] += 0.5
    traj = nav_from_columns({**cols, Topic.INS_RECORD: ins},
                            replace(times, t_gps_ns=t, status=status), antenna_offset_m=G_B)
    # records 8000..8063 span 125.3 s to 126.3 s: the solution splits there, and each side
    # ends at its last fix (whole seconds) rather than extrapolate the GPS correction
    assert traj.gaps_ns() == [(T0_NS + 125 * NS_PER_S, T0_NS + 127 * NS_PER_S)]
    good = _random_times(40.0, 140.0, 4000)
    in_block = (good > times.t_gps_ns[7999]) & (good < times.t_gps_ns[8064])
    in_gap = (good > T0_NS + 125 * NS_PER_S) & (good < T0_NS + 127 * NS_PER_S)
    assert in_block.sum() > 20
    pose = traj.pose_at(good)
    assert not pose.valid[in_gap].any()
    assert pose.valid[~in_gap].all()
    dp, da = pose_errors(SYN, pose)
    assert dp.max() < POS_TOL_M
    assert da.max() < ATT_TOL_RAD


def test_times_outside_the_span_are_invalid(synthetic: Any) -> None:
    cols, times = synthetic
    traj = nav_from_columns(cols, times, antenna_offset_m=G_B)
    first_fix, last_fix = T0_NS + NS_PER_S, T0_NS + 239 * NS_PER_S
    assert traj.span_ns == (first_fix, last_fix)  # the INS runs on; fixes bound the span
    t = np.array([-1, T0_NS, first_fix - 1, first_fix, last_fix, last_fix + 1,
                  SYN.end_ns + 10 * NS_PER_S])
    pose = traj.pose_at(t)
    assert pose.valid.tolist() == [False, False, False, True, True, False, False]
    assert np.isnan(pose.ins_ecef_m[~pose.valid]).all()
    assert np.isfinite(pose.ins_ecef_m[pose.valid]).all()


def test_a_log_and_a_sync_result_of_different_lengths_are_refused(synthetic: Any) -> None:
    cols, times = synthetic
    short = InsTimes(*(a[:-1] for a in (times.seq, times.counter, times.t_gps_ns, times.status)))
    with pytest.raises(InputError, match="INS records but the time synchronisation has"):
        nav_from_columns(cols, short, antenna_offset_m=G_B)


# --- the antenna offset, by hand -----------------------------------------------------------------

def _static_columns(heading_rad: float, n_s: int = 10) -> tuple[dict[str, Any], InsTimes]:
    """Parked aircraft, level, at LAT0/LON0/H0 (antenna), the given heading."""
    t_ins = T0_NS + np.arange(n_s * 64, dtype=np.int64) * 15_625_000
    n = t_ins.size
    z = np.zeros(n)
    ins = {"status": np.full(n, NAVIGATING_BIT), "roll_rad": z, "pitch_rad": z,
           "heading_rad": np.full(n, heading_rad), "vel_n_mps": z, "vel_e_mps": z,
           "vel_d_mps": z}
    t_fix = T0_NS + np.arange(n_s, dtype=np.int64) * NS_PER_S
    fix = {"t_gps_ns": t_fix, "lat_deg": np.full(t_fix.size, LAT0),
           "lon_deg": np.full(t_fix.size, LON0), "height_m": np.full(t_fix.size, H0),
           "quality": np.ones(t_fix.size, dtype=np.int64)}
    times = InsTimes(np.arange(n), np.arange(n), t_ins, np.zeros(n, dtype=np.int64))
    return {Topic.GPS_FIX: fix, Topic.INS_RECORD: ins}, times


def test_antenna_above_the_ins_puts_the_ins_centre_below_the_fix() -> None:
    """Level, heading north, g^b = (0, 0, −1.5): the antenna is 1.5 m above the INS centre."""
    cols, times = _static_columns(0.0)
    traj = nav_from_columns(cols, times, antenna_offset_m=(0.0, 0.0, -1.5))
    pose = traj.pose_at(np.array([T0_NS + 4_321_000_000]))
    lat, lon, h = geodetic(pose.ins_ecef_m)
    assert lat[0] == pytest.approx(LAT0, abs=1e-10)
    assert lon[0] == pytest.approx(LON0, abs=1e-10)
    assert h[0] == pytest.approx(H0 - 1.5, abs=1e-6)
    r_level = ned_to_ecef_matrix(math.radians(LAT0), math.radians(LON0))
    np.testing.assert_allclose(pose.r_ecef_from_body[0], r_level, atol=1e-9)


def test_antenna_ahead_facing_east_puts_the_ins_centre_west() -> None:
    """Heading 90°, g^b = (2, 0, 0): the antenna is 2 m east of the INS centre."""
    cols, times = _static_columns(math.pi / 2)
    traj = nav_from_columns(cols, times, antenna_offset_m=(2.0, 0.0, 0.0))
    ins = traj.pose_at(np.array([T0_NS + 5 * NS_PER_S])).ins_ecef_m[0]
    d = ins - wgs84_ecef(LAT0, LON0, H0)
    lon = math.radians(LON0)
    east = np.array([-math.sin(lon), math.cos(lon), 0.0])
    assert d @ east == pytest.approx(-2.0, abs=1e-6)
    assert np.linalg.norm(d - (d @ east) * east) < 1e-6


# --- a real simulated run, error-free ------------------------------------------------------------

ERROR_FREE_TOML = """
base = "bench"
[block]
strip_length_m = 1500.0
[flight]
static_alignment_s = 40.0
[gps]
horizontal_noise_m = 0.0
vertical_noise_m = 0.0
[ins]
attitude_bias_arcsec = [0.0, 0.0, 0.0]
attitude_drift_arcsec_per_h = [0.0, 0.0, 0.0]
attitude_noise_arcsec = [0.0, 0.0, 0.0]
rate_noise_rps = 0.0
velocity_noise_mps = 0.0
"""


@pytest.fixture(scope="module")
def error_free_run(tmp_path_factory: pytest.TempPathFactory
                   ) -> tuple[Scenario, Path, dict[str, Any], SyncResult]:
    from sisa.wiring.simulation import simulate

    work = tmp_path_factory.mktemp("nav_error_free")
    toml = work / "error_free.toml"
    toml.write_text(ERROR_FREE_TOML, encoding="utf-8")
    scn = load_scenario(toml)
    run = work / "run"
    simulate(scn, run, images=False)
    wanted = {topic: tuple(dict.fromkeys((*SYNC_WANTED.get(topic, ()),
                                          *NAV_WANTED.get(topic, ()))))
              for topic in {*SYNC_WANTED, *NAV_WANTED}}
    cols = read_topics(run / "flight.mcap", wanted)
    return scn, run, cols, synchronise(sync_input_from_columns(cols))


def _truth_errors(scn: Scenario, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    st = TruthTrajectory.from_scenario(scn).state(pose.t_gps_ns[pose.valid])
    r_true = (ned_to_ecef_matrix(np.radians(st.lat_deg), np.radians(st.lon_deg))
              @ body_to_ned_matrix(st.roll_rad, st.pitch_rad, st.heading_rad))
    dp = np.linalg.norm(pose.ins_ecef_m[pose.valid] - st.ecef_m, axis=1)
    return dp, rotation_error_rad(r_true, pose.r_ecef_from_body[pose.valid])


def test_error_free_simulation_within_1mm_and_005arcsec(error_free_run: Any) -> None:
    scn, run, cols, res = error_free_run
    traj = nav_from_columns(cols, res.ins, antenna_offset_m=scn.mounting.antenna_offset_m)
    frames = read_truth_csv(run / "truth" / "frames.csv")
    t_lines = frames["t_mid_gps_ns"][frames["line_index"] >= 0]
    records = read_truth_csv(run / "truth" / "ins_records.csv")["t_meas_gps_ns"]
    midway = records[:-1] + np.diff(records) // 2
    report = []
    for name, t in (("scan lines", t_lines), ("INS epochs", records), ("between", midway)):
        pose = traj.pose_at(t)
        dp, da = _truth_errors(scn, pose)
        report.append(f"{name}: {int(pose.valid.sum())}/{t.size} valid, position max "
                      f"{dp.max() / MM:.3f} mm RMS {np.sqrt(np.mean(dp**2)) / MM:.3f} mm, "
                      f"attitude max {da.max() / ARCSEC:.4f}\" RMS "
                      f"{np.sqrt(np.mean(da**2)) / ARCSEC:.4f}\"")
        assert dp.max() < POS_TOL_M, report[-1]
        assert da.max() < ATT_TOL_RAD, report[-1]
        if name == "scan lines":
            assert pose.valid.all()
            assert t.size > 2000
        else:  # the INS aligns on the ground for the first 30 s: no attitude there
            aligned = t > traj.span_ns[0]
            assert pose.valid[aligned & (t < traj.span_ns[1])].all()
            assert pose.valid.sum() > 0.9 * t.size
    print("\n" + "\n".join(report))


def test_nav_from_log_reads_the_same_solution(error_free_run: Any) -> None:
    scn, run, cols, res = error_free_run
    a = nav_from_columns(cols, res.ins, antenna_offset_m=scn.mounting.antenna_offset_m)
    b = nav_from_log(run / "flight.mcap", res.ins, antenna_offset_m=scn.mounting.antenna_offset_m)
    t = np.linspace(*a.span_ns, 101).astype(np.int64)
    pa, pb = a.pose_at(t), b.pose_at(t)
    assert a.span_ns == b.span_ns
    np.testing.assert_array_equal(pa.ins_ecef_m, pb.ins_ecef_m)
    np.testing.assert_array_equal(pa.r_ecef_from_body, pb.r_ecef_from_body)


@pytest.mark.parametrize("gaps", [{"max_gps_gap_s": 0.0}, {"max_ins_gap_s": -1.0},
                                  {"max_gps_gap_s": math.nan}, {"max_gps_gap_s": 1e300},
                                  {"max_ins_gap_s": 86_401.0}])
def test_a_gap_limit_that_bridges_nothing_or_overflows_nanoseconds_is_refused(
        gaps: dict[str, float]) -> None:
    with pytest.raises(ConfigError, match="at most 86400 s"):
        NavConfig(**gaps)
    assert NavConfig(max_gps_gap_s=86_400.0).max_gps_gap_s == 86_400.0
