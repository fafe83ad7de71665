"""The truth trajectory: the aircraft's true state as a smooth, vectorised function of GPS time.

Every emulator (GPS, INS, scanner) and every accuracy check samples this one model, so it must be
self-consistent to far better than any sensor: velocity and acceleration are the exact
derivatives of one position spline, and body rates the exact derivatives of one attitude spline.

Construction (all float seconds are relative to the scenario start, `sisa.core.timescale`):
1. Plan the horizontal path in the block's local plane (`LocalPlane`) as lines and arcs with a
   speed profile: static alignment, take-off roll, straight climb-out, figure-eights, holding
   circles if the climb is not finished in time, a Dubins transit, then for each strip a run-in,
   the strip, a run-out and a Dubins turn (coordinated, radius v²/(g·tan bank)).
2. Sample that plan every `NODE_STEP_S` and smooth it with a compact triweight kernel
   (σ = `SMOOTHING_SIGMA_S`): bank rolls in smoothly, straight legs longer than the kernel stay
   exactly straight, and nothing moves before the alignment ends. Smoothing shrinks circles, so
   arcs are planned a little wider and faster (`_Cruise`) to keep steady turns exact.
3. Map the samples (plus ellipsoidal height and vertical turbulence) to ECEF with pyproj and
   interpolate with a C⁴ quintic spline. Attitude (roll from lateral acceleration, pitch from the
   flight-path angle, heading from the course plus crab, each with turbulence) is computed from
   that spline on the same nodes and interpolated the same way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
from pyproj import Geod
from scipy.interpolate import BSpline, PPoly, make_interp_spline

from emulators.block import STANDARD_GRAVITY_MPS2, StripKind, StripLine, strip_lines
from emulators.localplane import LocalPlane
from emulators.scenario import (
    _PLAN_CLIMB_ACCELERATION_MPS2,
    _PLAN_CLIMB_OUT_MIN_S,
    _PLAN_CLIMB_RAMP_S,
    _PLAN_KERNEL_HALF_WIDTH_S,
    _PLAN_SMOOTHING_SIGMA_S,
    Scenario,
)
from sisa.core.frames import body_rates_from_euler_rates, ned_to_ecef_matrix
from sisa.core.timescale import NS_PER_S, ns_from_seconds_since, seconds_since

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

NODE_STEP_S = 0.1  # spline node spacing; the smoothed path has no content faster than ~1 s
# The planning rules, defined beside the scenario's flight-length bound that follows them
# (emulators.scenario may not import this module: it would bring scipy into every load).
SMOOTHING_SIGMA_S = _PLAN_SMOOTHING_SIGMA_S  # roll-in time scale of turns, climbs, accelerations
KERNEL_HALF_WIDTH_S = _PLAN_KERNEL_HALF_WIDTH_S  # triweight kernel: σ = half-width / 3
CLIMB_OUT_MIN_S = _PLAN_CLIMB_OUT_MIN_S  # straight flight after rotation before the first turn
CLIMB_ACCELERATION_MPS2 = _PLAN_CLIMB_ACCELERATION_MPS2  # from rotation speed to block speed
CLIMB_RAMP_S = _PLAN_CLIMB_RAMP_S  # vertical speed ramps in and out over this time
ANGLE_OF_ATTACK_DEG = 2.0
GROUND_PITCH_DEG = 1.0
AIRBORNE_RAMP_S = 10.0  # crab, angle of attack and turbulence fade in after lift-off
SLOW_SPEED_MPS = 0.5  # below this the course is the runway's, not the velocity's
TAIL_S = 20.0  # straight flight planned past the end, so the end is an interior point
TURBULENCE_PERIODS_S = (3.0, 60.0)
TURBULENCE_COMPONENTS = 6
_TWO_PI = 2.0 * math.pi


class TrajectoryState(NamedTuple):
    """True state at N instants. NED vectors are ECEF derivatives expressed in local level at
    the aircraft: `acc_ned_mps2` is R_e^n·d²r^e/dt², with no transport-rate or Coriolis terms."""

    t_gps_ns: IntArray
    lat_deg: FloatArray
    lon_deg: FloatArray
    height_m: FloatArray  # ellipsoidal
    ecef_m: FloatArray  # (N, 3)
    vel_ned_mps: FloatArray  # (N, 3)
    acc_ned_mps2: FloatArray  # (N, 3)
    roll_rad: FloatArray
    pitch_rad: FloatArray
    heading_rad: FloatArray  # true heading in [0, 2π)
    body_rate_rps: FloatArray  # (N, 3): ω_nb^b, body rates relative to local level


@dataclass(frozen=True)
class FlownStrip:
    """When the aircraft is on a strip line (the scanner records inside these windows)."""

    index: int
    kind: StripKind
    heading_deg: float
    t_start_ns: int
    t_end_ns: int


@dataclass(frozen=True)
class Phase:
    """A named part of the flight; phases are contiguous and cover the whole trajectory.

    Names: static, takeoff (ground roll to lift-off), climb (straight climb-out; the climb may
    go on through the figure-eights), figure_eight, holding, transit, run_in, strip, run_out,
    turn. Boundaries after lift-off are those of the planned path: smoothing blurs them by
    ±KERNEL_HALF_WIDTH_S, except that strip windows are exact.
    """

    name: str
    t_start_ns: int
    t_end_ns: int


# --- path geometry in the local plane (x east, y north, θ counter-clockwise from east) --------


@dataclass(frozen=True)
class _Pose:
    x_m: float
    y_m: float
    theta_rad: float

    def advanced(self, distance_m: float) -> _Pose:
        return _Pose(self.x_m + distance_m * math.cos(self.theta_rad),
                     self.y_m + distance_m * math.sin(self.theta_rad), self.theta_rad)


@dataclass(frozen=True)
class _Line:
    start: _Pose
    length_m: float

    def points(self, s_m: FloatArray) -> tuple[FloatArray, FloatArray]:
        c, s = math.cos(self.start.theta_rad), math.sin(self.start.theta_rad)
        return self.start.x_m + s_m * c, self.start.y_m + s_m * s

    def end(self) -> _Pose:
        return self.start.advanced(self.length_m)


@dataclass(frozen=True)
class _Arc:
    """Circular arc entered at `start`; turn +1 is left (counter-clockwise), −1 right."""

    start: _Pose
    radius_m: float
    turn: int
    sweep_rad: float

    @property
    def length_m(self) -> float:
        return self.radius_m * self.sweep_rad

    @property
    def centre(self) -> tuple[float, float]:
        return _turn_centre(self.start, self.turn, self.radius_m)

    def _polar_at(self, s_m: FloatArray | float) -> FloatArray | float:
        return self.start.theta_rad - self.turn * math.pi / 2 + self.turn * s_m / self.radius_m

    def points(self, s_m: FloatArray) -> tuple[FloatArray, FloatArray]:
        cx, cy = self.centre
        phi = np.asarray(self._polar_at(s_m))
        return cx + self.radius_m * np.cos(phi), cy + self.radius_m * np.sin(phi)

    def end(self) -> _Pose:
        cx, cy = self.centre
        phi = float(self._polar_at(self.length_m))
        return _Pose(cx + self.radius_m * math.cos(phi), cy + self.radius_m * math.sin(phi),
                     phi + self.turn * math.pi / 2)


_Segment = _Line | _Arc


def _turn_centre(pose: _Pose, turn: int, radius_m: float) -> tuple[float, float]:
    """Centre of the turning circle on the left (turn +1) or right (−1) of a pose."""
    return (pose.x_m - turn * radius_m * math.sin(pose.theta_rad),
            pose.y_m + turn * radius_m * math.cos(pose.theta_rad))


def _sweep(turn: int, from_rad: float, to_rad: float) -> float:
    """Angle turned going from one direction to another in the given sense, in [0, 2π)."""
    sweep = (turn * (to_rad - from_rad)) % _TWO_PI
    return 0.0 if sweep > _TWO_PI - 1e-9 else sweep


def _csc_word(start: _Pose, goal: _Pose, r_m: float, t1: int, t2: int
              ) -> list[tuple[str, int, float]] | None:
    """Turn–straight–turn: the common tangent of the two circles (None if they overlap)."""
    c1, c2 = _turn_centre(start, t1, r_m), _turn_centre(goal, t2, r_m)
    dx, dy = c2[0] - c1[0], c2[1] - c1[1]
    dist = math.hypot(dx, dy)
    offset = (t2 - t1) * r_m  # signed offset of the tangent line between the centres
    if dist < abs(offset):
        return None
    straight = math.sqrt(dist**2 - offset**2)
    theta = math.atan2(dy, dx) - math.atan2(offset, straight)
    return [("arc", t1, _sweep(t1, start.theta_rad, theta)), ("line", 0, straight),
            ("arc", t2, _sweep(t2, theta, goal.theta_rad))]


def _ccc_words(start: _Pose, goal: _Pose, r_m: float, t: int) -> list[list[tuple[str, int, float]]]:
    """Turn–counter-turn–turn through a middle circle touching both end circles."""
    c1, c3 = _turn_centre(start, t, r_m), _turn_centre(goal, t, r_m)
    dx, dy = c3[0] - c1[0], c3[1] - c1[1]
    dist = math.hypot(dx, dy)
    if dist > 4.0 * r_m or dist < 1e-9:
        return []
    h = math.sqrt(4.0 * r_m**2 - (dist / 2.0) ** 2)
    words = []
    for side in (1.0, -1.0):
        c2 = (c1[0] + dx / 2 - side * h * dy / dist, c1[1] + dy / 2 + side * h * dx / dist)
        th12 = math.atan2(c2[1] - c1[1], c2[0] - c1[0]) + t * math.pi / 2
        th23 = math.atan2(c2[1] - c3[1], c2[0] - c3[0]) + t * math.pi / 2
        words.append([("arc", t, _sweep(t, start.theta_rad, th12)),
                      ("arc", -t, _sweep(-t, th12, th23)),
                      ("arc", t, _sweep(t, th23, goal.theta_rad))])
    return words


def _build_word(start: _Pose, r_m: float, word: list[tuple[str, int, float]]) -> list[_Segment]:
    segments: list[_Segment] = []
    pose = start
    for kind, turn, amount in word:
        seg: _Segment = _Line(pose, amount) if kind == "line" else _Arc(pose, r_m, turn, amount)
        if seg.length_m > 0.0:
            segments.append(seg)
            pose = seg.end()
    return segments


def _dubins(start: _Pose, goal: _Pose, r_m: float) -> list[_Segment]:
    """Shortest forward path of bounded curvature between two poses (all six Dubins words)."""
    words = [w for t1 in (1, -1) for t2 in (1, -1)
             if (w := _csc_word(start, goal, r_m, t1, t2)) is not None]
    words += _ccc_words(start, goal, r_m, 1) + _ccc_words(start, goal, r_m, -1)
    best = min(words, key=lambda w: sum(a * (r_m if k == "arc" else 1.0) for k, _, a in w))
    path = _build_word(start, r_m, best)
    end = path[-1].end() if path else start
    miss_m = math.hypot(end.x_m - goal.x_m, end.y_m - goal.y_m)
    if miss_m > 1e-6 * max(1.0, r_m):
        raise AssertionError(f"Dubins path misses its goal by {miss_m:.3g} m")
    return path


# --- legs: a segment flown with a linear speed change ------------------------------------------


@dataclass(frozen=True)
class _Leg:
    segment: _Segment
    v0_mps: float
    v1_mps: float

    @property
    def duration_s(self) -> float:
        return 2.0 * self.segment.length_m / (self.v0_mps + self.v1_mps)

    def points(self, tau_s: FloatArray) -> tuple[FloatArray, FloatArray]:
        accel = (self.v1_mps**2 - self.v0_mps**2) / (2.0 * self.segment.length_m)
        s = np.clip(self.v0_mps * tau_s + 0.5 * accel * tau_s**2, 0.0, self.segment.length_m)
        return self.segment.points(s)


@dataclass(frozen=True)
class _Group:
    """Consecutive legs that form one phase."""

    name: str
    legs: tuple[_Leg, ...]
    strip: StripLine | None = None

    @property
    def duration_s(self) -> float:
        return sum(leg.duration_s for leg in self.legs)


@dataclass(frozen=True)
class _Cruise:
    """How arcs are planned so that, after smoothing, a steady turn at the block speed has
    radius v²/(g·tan bank): smoothing a circle of angular rate ω scales it about its centre by
    k = Σ w_j cos(ω τ_j), so arcs are planned at radius R/k and flown at v/k (same ω)."""

    speed_mps: float
    radius_m: float  # planned
    arc_speed_mps: float  # planned

    @classmethod
    def for_scenario(cls, scn: Scenario) -> _Cruise:
        v = scn.block.ground_speed_mps
        r_m = v**2 / (STANDARD_GRAVITY_MPS2 * math.tan(math.radians(scn.flight.turn_bank_deg)))
        w = _smoothing_weights()
        tau_s = NODE_STEP_S * (np.arange(w.size) - (w.size - 1) // 2)
        k = float(np.sum(w * np.cos(v / r_m * tau_s)))
        return cls(v, r_m / k, v / k)

    def legs(self, segments: list[_Segment]) -> tuple[_Leg, ...]:
        speeds = [self.arc_speed_mps if isinstance(seg, _Arc) else self.speed_mps
                  for seg in segments]
        return tuple(_Leg(seg, v, v) for seg, v in zip(segments, speeds, strict=True))

    def circles(self, pose: _Pose, turns: list[int]) -> tuple[_Leg, ...]:
        return self.legs([_Arc(pose, self.radius_m, t, _TWO_PI) for t in turns])


@dataclass(frozen=True)
class _Plan:
    """The horizontal plan and the vertical profile, in seconds since the scenario start."""

    groups: tuple[_Group, ...]  # the last one is the tail, flown after the end
    start: _Pose
    t_motion_s: float  # planned motion starts here; smoothed motion starts a kernel earlier
    t_rotation_s: float  # lift-off (smoothed)
    t_climb_s: float  # planned climb starts
    climb_duration_s: float
    climb_ramp_s: float
    climb_rate_mps: float
    t_end_s: float


def _runway_theta(scn: Scenario, plane: LocalPlane) -> float:
    """Plane direction whose true heading at the runway start is the runway heading."""
    east, north = scn.flight.airfield_offset_m
    lat, lon = plane.plane_to_geodetic(east, north)
    lon2, lat2, _ = Geod(ellps="WGS84").fwd(float(lon), float(lat),
                                            scn.flight.runway_heading_deg, 1.0)
    e2, n2 = plane.geodetic_to_plane(lat2, lon2)
    return math.atan2(float(n2) - north, float(e2) - east)


def _departure(scn: Scenario, start: _Pose) -> tuple[_Group, _Group]:
    """Take-off roll, then a straight climb-out accelerating to the block speed."""
    f, v = scn.flight, scn.block.ground_speed_mps
    v_rot = f.rotation_speed_kmh / 3.6
    roll = _Line(start, v_rot**2 / (2.0 * f.takeoff_acceleration_mps2))
    accel = _Line(roll.end(), abs(v**2 - v_rot**2) / (2.0 * CLIMB_ACCELERATION_MPS2))
    t_accel = abs(v - v_rot) / CLIMB_ACCELERATION_MPS2
    cruise = _Line(accel.end(), v * max(CLIMB_OUT_MIN_S - t_accel, KERNEL_HALF_WIDTH_S))
    climb = [_Leg(accel, v_rot, v)] if accel.length_m > 0 else []
    return (_Group("takeoff", (_Leg(roll, 0.0, v_rot),)),
            _Group("climb", (*climb, _Leg(cruise, v, v))))


def _survey(scn: Scenario, pose: _Pose, cruise: _Cruise) -> list[_Group]:
    """Transit, then run-in, strip, run-out and turn for each strip; the last group is a tail."""
    straight_m = cruise.speed_mps * max(scn.flight.run_in_s, KERNEL_HALF_WIDTH_S)
    groups: list[_Group] = []
    for k, line in enumerate(strip_lines(scn)):
        heading = math.radians(line.heading_deg)
        strip_start = _Pose(*line.start_en_m, math.pi / 2 - heading)
        run_in = _Line(strip_start.advanced(-straight_m), straight_m)
        groups.append(_Group("transit" if k == 0 else "turn",
                             cruise.legs(_dubins(pose, run_in.start, cruise.radius_m))))
        strip = _Line(strip_start, line.length_m)
        run_out = _Line(strip.end(), straight_m)
        groups += [_Group("run_in", cruise.legs([run_in])),
                   _Group("strip", cruise.legs([strip]), line),
                   _Group("run_out", cruise.legs([run_out]))]
        pose = run_out.end()
    groups.append(_Group("tail", cruise.legs([_Line(pose, cruise.speed_mps * TAIL_S)])))
    return [g for g in groups if g.legs]


def _plan(scn: Scenario, plane: LocalPlane) -> _Plan:
    f, cruise = scn.flight, _Cruise.for_scenario(scn)
    start = _Pose(*f.airfield_offset_m, _runway_theta(scn, plane))
    takeoff, climb = _departure(scn, start)
    pose = climb.legs[-1].segment.end()
    eights = [_Group("figure_eight", cruise.circles(pose, [-1, 1]))
              for _ in range(f.figure_eights)]
    survey = _survey(scn, pose, cruise)
    t_motion = f.static_alignment_s + KERNEL_HALF_WIDTH_S
    t_rotation = t_motion + takeoff.duration_s
    t_climb = t_rotation + KERNEL_HALF_WIDTH_S  # so the smoothed climb starts at rotation
    steady_s = scn.block.flying_height_agl_m / f.climb_rate_mps
    ramp_s = min(CLIMB_RAMP_S, steady_s)
    climb_end = t_climb + steady_s + ramp_s + KERNEL_HALF_WIDTH_S
    first_run_in = next(k for k, g in enumerate(survey) if g.name == "run_in")
    run_in_start = t_motion + sum(g.duration_s for g in (takeoff, climb, *eights,
                                                         *survey[:first_run_in]))
    holding = _holding(pose, cruise, climb_end - run_in_start)
    groups = (takeoff, climb, *eights, *holding, *survey)
    t_end = t_motion + sum(g.duration_s for g in groups[:-1])
    return _Plan(groups, start, t_motion, t_rotation, t_climb, steady_s + ramp_s, ramp_s,
                 f.climb_rate_mps, t_end)


def _holding(pose: _Pose, cruise: _Cruise, late_s: float) -> list[_Group]:
    """Right-hand circles where the climb-out ended, enough to make up `late_s` of climb."""
    n = math.ceil(late_s * cruise.arc_speed_mps / (_TWO_PI * cruise.radius_m))
    return [_Group("holding", cruise.circles(pose, [-1] * n))] if n > 0 else []


# --- sampling the plan --------------------------------------------------------------------------


def _plan_en(plan: _Plan, t_s: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Planned (unsmoothed) east/north displacement from the runway start at sorted times."""
    legs = [leg for g in plan.groups for leg in g.legs]
    starts = plan.t_motion_s + np.concatenate([[0.0], np.cumsum([lg.duration_s for lg in legs])])
    if t_s[-1] > starts[-1]:
        raise AssertionError("sampling past the planned tail")
    bounds = np.searchsorted(t_s, starts)
    de, dn = np.zeros_like(t_s), np.zeros_like(t_s)
    for leg, t0, lo, hi in zip(legs, starts, bounds, bounds[1:], strict=False):
        x, y = leg.points(t_s[lo:hi] - t0)
        de[lo:hi], dn[lo:hi] = x - plan.start.x_m, y - plan.start.y_m
    return de, dn


def _ramp_integral(u_s: FloatArray, ramp_s: float) -> FloatArray:
    """∫₀ᵘ clip(s/ramp, 0, 1) ds."""
    u = np.maximum(u_s, 0.0)
    return np.where(u < ramp_s, u**2 / (2.0 * ramp_s), u - ramp_s / 2.0)


def _plan_height(plan: _Plan, t_s: FloatArray) -> FloatArray:
    """Planned height above the runway: vertical speed ramps up, holds, ramps down."""
    ramp = plan.climb_ramp_s
    u = t_s - plan.t_climb_s
    up = _ramp_integral(u, ramp)
    down = _ramp_integral(u - (plan.climb_duration_s - ramp), ramp)
    return plan.climb_rate_mps * (up - down)


def _smoothing_weights() -> FloatArray:
    """Triweight kernel on the node grid: compact (nothing moves before it should), C²."""
    half = round(KERNEL_HALF_WIDTH_S / NODE_STEP_S)
    u = np.arange(-half, half + 1) / half
    w = (1.0 - u**2) ** 3
    return np.asarray(w / w.sum())


def _smoothed(plan: _Plan, t_nodes_s: FloatArray) -> FloatArray:
    """Smoothed east/north displacement and height above the runway at the nodes, (N, 3)."""
    w = _smoothing_weights()
    half = (w.size - 1) // 2
    pad = NODE_STEP_S * np.arange(1, half + 1)
    t_raw = np.concatenate([t_nodes_s[0] - pad[::-1], t_nodes_s, t_nodes_s[-1] + pad])
    de, dn = _plan_en(plan, t_raw)
    raw = (de, dn, _plan_height(plan, t_raw))
    return np.stack([np.convolve(x, w, mode="valid") for x in raw], axis=-1)


# --- turbulence and lift-off blending ------------------------------------------------------------


class _Turbulence:
    """Smooth sums of sinusoids, amplitude ∝ period (gusts carry more energy slowly)."""

    def __init__(self, seed: int, channels: int) -> None:
        rng = np.random.default_rng([seed, 0x7452414A])  # own stream: other models draw too
        lo, hi = np.log(TURBULENCE_PERIODS_S[0]), np.log(TURBULENCE_PERIODS_S[1])
        shape = (channels, TURBULENCE_COMPONENTS)
        periods = np.exp(rng.uniform(lo, hi, shape))
        self._omega = _TWO_PI / periods
        self._phase = rng.uniform(0.0, _TWO_PI, shape)
        amp = periods * rng.uniform(0.5, 1.5, shape)
        self._amp = amp / np.sqrt(0.5 * np.sum(amp**2, axis=1, keepdims=True))  # unit RMS

    def unit(self, channel: int, t_s: FloatArray) -> FloatArray:
        arg = np.outer(t_s, self._omega[channel]) + self._phase[channel]
        return np.asarray(np.sin(arg) @ self._amp[channel])


def _airborne_weight(plan: _Plan, t_s: FloatArray) -> FloatArray:
    """0 on the ground, rising smoothly (C²) to 1 over AIRBORNE_RAMP_S after lift-off."""
    u = np.clip((t_s - plan.t_rotation_s) / AIRBORNE_RAMP_S, 0.0, 1.0)
    return np.asarray(u**3 * (10.0 - 15.0 * u + 6.0 * u**2))


# --- splines --------------------------------------------------------------------------------------


def _quintic(t_s: FloatArray, y: FloatArray) -> BSpline:
    """Interpolating quintic, at rest at the first node (the aircraft leaves the alignment)."""
    zero = np.zeros(y.shape[1])
    return make_interp_spline(t_s, y, k=5, bc_type=([(1, zero), (2, zero)],
                                                     [(3, zero), (4, zero)]))


def _ppoly_channels(splines: list[BSpline], static_s: float) -> PPoly:
    """All channels in one piecewise polynomial (shared breakpoints, one interval search),
    preceded by a constant interval for the static alignment so it is exactly at rest."""
    parts = [PPoly.from_spline(BSpline(s.t, s.c[:, j], s.k))
             for s in splines for j in range(s.c.shape[1])]
    x = parts[0].x
    keep = np.diff(x) > 0
    c = np.stack([p.c[:, keep] for p in parts], axis=-1)
    breaks = np.concatenate([x[:-1][keep], x[-1:]])
    c[-3:-1, 0] = 0.0  # at rest where the motion starts: exactly, not to rounding
    if static_s > 0.0:
        rest = np.zeros((c.shape[0], 1, c.shape[2]))
        rest[-1, 0] = c[-1, 0]
        c = np.concatenate([rest, c], axis=1)
        breaks = np.concatenate([[0.0], breaks])
    return PPoly.construct_fast(c, breaks)


def _to_ned(lat_deg: FloatArray, lon_deg: FloatArray, *v_ecef: FloatArray) -> list[FloatArray]:
    """ECEF vectors (N, 3) expressed in local-level NED: R_e^n·v = (R_n^e)ᵀ·v."""
    r_ne = ned_to_ecef_matrix(np.radians(lat_deg), np.radians(lon_deg))
    return [np.asarray(np.einsum("...ji,...j->...i", r_ne, v)) for v in v_ecef]


def _attitude_nodes(scn: Scenario, plan: _Plan, turb: _Turbulence, t_s: FloatArray,
                    vel_ned: FloatArray, acc_ned: FloatArray) -> FloatArray:
    """Roll, pitch and unwrapped heading at the nodes, shape (N, 3)."""
    vn, ve, vd = vel_ned.T
    speed = np.hypot(vn, ve)
    moving = speed > SLOW_SPEED_MPS
    safe = np.where(moving, speed, 1.0)
    course = np.arctan2(ve, vn)
    course[~moving] = course[np.argmax(moving)]  # on the runway: the runway's course
    a_lat = np.where(moving, (vn * acc_ned[:, 1] - ve * acc_ned[:, 0]) / safe, 0.0)
    gamma = np.where(moving, np.arctan2(-vd, safe), 0.0)
    w = _airborne_weight(plan, t_s)
    f = scn.flight
    sig = math.radians(f.turbulence_attitude_deg)
    roll = np.arctan(a_lat / STANDARD_GRAVITY_MPS2) + w * sig * turb.unit(0, t_s)
    pitch = (gamma + (1.0 - w) * math.radians(GROUND_PITCH_DEG)
             + w * (math.radians(ANGLE_OF_ATTACK_DEG) + sig * turb.unit(1, t_s)))
    heading = np.unwrap(course) + w * (math.radians(f.crab_deg) + sig * turb.unit(2, t_s))
    return np.stack([roll, pitch, heading], axis=-1)


def _node_times(plan: _Plan, static_s: float) -> FloatArray:
    n = math.ceil((plan.t_end_s + TAIL_S / 2 - static_s) / NODE_STEP_S) + 1
    return np.asarray(static_s + NODE_STEP_S * np.arange(n), dtype=np.float64)


def _wrap_2pi(angle_rad: FloatArray) -> FloatArray:
    """Into [0, 2π): np.mod alone can round a tiny negative angle up to exactly 2π."""
    wrapped = np.mod(angle_rad, _TWO_PI)
    return np.where(wrapped >= _TWO_PI, 0.0, wrapped)


# --- the trajectory -------------------------------------------------------------------------------


class TruthTrajectory:
    """The true flight of a scenario; build with `from_scenario`, query with `state`."""

    def __init__(self, *, t_start_ns: int, t_end_ns: int, origin_ecef_m: FloatArray,
                 channels: PPoly, plane: LocalPlane, strips: tuple[FlownStrip, ...],
                 phases: tuple[Phase, ...]) -> None:
        self.t_start_ns = t_start_ns
        self.t_end_ns = t_end_ns
        self.strips = strips
        self.phases = phases
        self._origin = origin_ecef_m
        self._p = channels
        self._dp = channels.derivative(1)
        acc = channels.derivative(2)
        self._ddp = PPoly.construct_fast(np.ascontiguousarray(acc.c[..., :3]), acc.x)
        self._plane = plane

    @property
    def duration_s(self) -> float:
        return (self.t_end_ns - self.t_start_ns) / NS_PER_S

    @classmethod
    def from_scenario(cls, scn: Scenario) -> TruthTrajectory:
        plane = LocalPlane.for_scenario(scn)
        plan = _plan(scn, plane)
        static_s = scn.flight.static_alignment_s
        t = _node_times(plan, static_s)
        den = _smoothed(plan, t)
        lat, lon = plane.plane_to_geodetic(plan.start.x_m + den[:, 0], plan.start.y_m + den[:, 1])
        turb = _Turbulence(scn.seed, 4)
        turb_h = scn.flight.turbulence_height_m * turb.unit(3, t)
        h = scn.terrain.mean_height_m + den[:, 2] + _airborne_weight(plan, t) * turb_h
        ecef = plane.geodetic_to_ecef(lat, lon, h)
        origin = ecef[0].copy()
        pos = _quintic(t, ecef - origin)
        att = _attitude_nodes(scn, plan, turb, t, *_to_ned(lat, lon, pos(t, 1), pos(t, 2)))
        channels = _ppoly_channels([pos, _quintic(t, att)], static_s)
        t0 = scn.block.t_start_gps_ns
        return cls(t_start_ns=t0, t_end_ns=int(ns_from_seconds_since(plan.t_end_s, t0)),
                   origin_ecef_m=origin, channels=channels, plane=plane,
                   strips=_flown_strips(plan, t0), phases=_phases(plan, static_s, t0))

    def state(self, t_gps_ns: npt.ArrayLike) -> TrajectoryState:
        """True state at GPS instants (int64 ns, any order); ValueError outside the flight."""
        t_ns = np.atleast_1d(np.asarray(t_gps_ns))
        if t_ns.ndim != 1 or not np.issubdtype(t_ns.dtype, np.integer):
            raise TypeError("t_gps_ns must be a 1-D array of integer GPS nanoseconds")
        t_ns = t_ns.astype(np.int64)
        if t_ns.size and (t_ns.min() < self.t_start_ns or t_ns.max() > self.t_end_ns):
            raise ValueError(f"times outside the trajectory [{self.t_start_ns}, {self.t_end_ns}]"
                             " GPS ns")
        order = None if np.all(np.diff(t_ns) >= 0) else np.argsort(t_ns, kind="stable")
        t_s = seconds_since(t_ns if order is None else t_ns[order], self.t_start_ns)
        val, d1, d2 = self._p(t_s), self._dp(t_s), self._ddp(t_s)
        if order is not None:
            inv = np.empty_like(order)
            inv[order] = np.arange(order.size)
            val, d1, d2 = val[inv], d1[inv], d2[inv]
        return self._assemble(t_ns, val, d1, d2)

    def _assemble(self, t_ns: IntArray, val: FloatArray, d1: FloatArray, d2: FloatArray
                  ) -> TrajectoryState:
        ecef = val[:, :3] + self._origin
        lat, lon, h = self._plane.ecef_to_geodetic(ecef)
        roll, pitch, heading = val[:, 3], val[:, 4], val[:, 5]
        rates = body_rates_from_euler_rates(roll, pitch, d1[:, 3], d1[:, 4], d1[:, 5])
        vel, acc = _to_ned(lat, lon, d1[:, :3], d2)
        return TrajectoryState(
            t_gps_ns=t_ns, lat_deg=lat, lon_deg=lon, height_m=h, ecef_m=ecef,
            vel_ned_mps=vel, acc_ned_mps2=acc,
            roll_rad=roll, pitch_rad=pitch, heading_rad=_wrap_2pi(heading),
            body_rate_rps=rates)

    def write_csv(self, path: str | Path, step_s: float = 0.1) -> None:
        """Write the state every `step_s` from start to end; the columns are CSV_COLUMNS,
        documented in a `#` comment block (CSV_DOC) above the header row."""
        if step_s <= 0:
            raise ValueError("step_s must be positive")
        step_ns = round(step_s * NS_PER_S)
        s = self.state(np.arange(self.t_start_ns, self.t_end_ns + 1, step_ns, dtype=np.int64))
        deg = np.degrees
        cols = [s.t_gps_ns, s.lat_deg, s.lon_deg, s.height_m, *s.vel_ned_mps.T, deg(s.roll_rad),
                deg(s.pitch_rad), deg(s.heading_rad), *deg(s.body_rate_rps).T]
        table = np.empty(s.t_gps_ns.size, dtype=[(name, "i8" if k == 0 else "f8")
                                                 for k, name in enumerate(CSV_COLUMNS)])
        for name, col in zip(CSV_COLUMNS, cols, strict=True):
            table[name] = col
        fmt = ["%d", "%.9f", "%.9f", "%.4f", *["%.5f"] * 3, *["%.7f"] * 6]
        doc = "".join(f"# {line}\n" for line in CSV_DOC.splitlines())
        with open(path, "w", encoding="utf-8") as out:
            out.write(doc + ",".join(CSV_COLUMNS) + "\n")
            np.savetxt(out, table, fmt=fmt, delimiter=",")


CSV_COLUMNS = ("t_gps_ns", "lat_deg", "lon_deg", "height_m", "vel_n_mps", "vel_e_mps",
               "vel_d_mps", "roll_deg", "pitch_deg", "heading_deg", "rate_x_dps", "rate_y_dps",
               "rate_z_dps")
CSV_DOC = """SISA simulation truth: trajectory of the INS centre; post-processing never reads it.
t_gps_ns: GPS time, ns since 1980-01-06T00:00:00, no leap seconds.
lat_deg, lon_deg, height_m: WGS84 geodetic latitude, longitude, ellipsoidal height.
vel_n/e/d_mps: velocity over the ground in local-level north, east, down.
roll/pitch/heading_deg: R_b^n = Rz(heading) Ry(pitch) Rx(roll); body x forward, y right,
z down; heading is true, in [0, 360).
rate_x/y/z_dps: body rates relative to local level (omega_nb^b), deg/s."""


def _flown_strips(plan: _Plan, t0_ns: int) -> tuple[FlownStrip, ...]:
    out = []
    t = plan.t_motion_s
    for g in plan.groups:
        if g.strip is not None:
            start_ns = int(ns_from_seconds_since(t, t0_ns))
            end_ns = int(ns_from_seconds_since(t + g.duration_s, t0_ns))
            out.append(FlownStrip(g.strip.index, g.strip.kind, g.strip.heading_deg,
                                  start_ns, end_ns))
        t += g.duration_s
    return tuple(out)


def _phases(plan: _Plan, static_s: float, t0_ns: int) -> tuple[Phase, ...]:
    """Static, then one phase per planned group; the take-off starts when the smoothed
    motion does (a kernel half-width before the planned roll)."""
    bounds: list[tuple[str, float, float]] = [("static", 0.0, static_s)] if static_s > 0 else []
    t = plan.t_motion_s
    for k, g in enumerate(plan.groups[:-1]):
        bounds.append((g.name, static_s if k == 0 else t, t + g.duration_s))
        t += g.duration_s
    return tuple(Phase(name, int(ns_from_seconds_since(a, t0_ns)),
                       int(ns_from_seconds_since(b, t0_ns))) for name, a, b in bounds)
