"""The calibration parameters: which groups are estimated, their names, units and starting values.

Every group can be switched on or off (`--estimate`); a group that is off keeps the sensor
file's value (boresight, self-calibration, delay) or zero (the corrections). Values are kept in
the units a user reads: arcsec, mm, µm, ms, m, arcsec/s.

- boresight  ω, φ, κ (arcsec): R_c^b = R_nom·Rx(ω)·Ry(φ)·Rz(κ) (sisa.core.sensor).
- selfcal    δf (mm), δx0, δy0 (µm): pixel j looks along (x0+δx0, (j−c)·pitch+y0+δy0, −(f+δf)).
- delay      τ (ms): a line's true exposure is τ after its time tag.
- antenna    Δg^b (m, body): the true antenna offset is the sensor file's plus Δg. With the
             trajectory fixed, image data see only the perspective centre, r = r_INS + R·(a−g):
             a lever-arm error is the same as −Δg, so one combined offset is estimated.
- gps_block  one shift of every perspective centre (m; east, north, up at the block centre).
- gps_strip  one such shift per strip (segment).
- attitude   per-strip INS attitude offsets (arcsec; small rotations about body x, y, z after
             R_b^e), with a prior σ: a common part is the boresight, so they need one.
- drift      per-strip attitude drift (arcsec/s from the strip's mid time), with a prior σ.
- navigation not a group one chooses: the GPS error's knots (m; east, north, up) of the
             navigation model (postproc.calibration.navigation), nuisance parameters with the
             Gauss–Markov prior of the trajectory's stated accuracy, present when it is given.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import Final

import numpy as np
import numpy.typing as npt

from postproc.calibration.navigation import ENU_NAMES, NavKnots
from postproc.georef import SensorModel
from sisa.core.errors import ConfigError

F64 = npt.NDArray[np.float64]


class Group(StrEnum):
    BORESIGHT = "boresight"
    SELFCAL = "selfcal"
    DELAY = "delay"
    ANTENNA = "antenna"
    GPS_BLOCK = "gps_block"
    GPS_STRIP = "gps_strip"
    ATTITUDE = "attitude"
    DRIFT = "drift"
    NAVIGATION = "navigation"  # the navigation model's knots: nuisance, never in --estimate


PER_STRIP: Final = (Group.GPS_STRIP, Group.ATTITUDE, Group.DRIFT)
DEFAULT_GROUPS: Final = (Group.BORESIGHT, Group.SELFCAL)

# (component names, unit, finite-difference step) of each group
COMPONENTS: Final[dict[Group, tuple[tuple[str, ...], str, float]]] = {
    Group.BORESIGHT: (("omega", "phi", "kappa"), "arcsec", 5.0),
    Group.SELFCAL: (("delta_focal", "delta_x0", "delta_y0"), "mm|um|um", 0.0),
    Group.DELAY: (("time_delay",), "ms", 1.0),
    Group.ANTENNA: (("antenna_dx", "antenna_dy", "antenna_dz"), "m", 0.05),
    Group.GPS_BLOCK: (("gps_east", "gps_north", "gps_up"), "m", 0.05),
    Group.GPS_STRIP: (("gps_east", "gps_north", "gps_up"), "m", 0.05),
    Group.ATTITUDE: (("att_x", "att_y", "att_z"), "arcsec", 5.0),
    Group.DRIFT: (("drift_x", "drift_y", "drift_z"), "arcsec/s", 0.05),
    Group.NAVIGATION: (ENU_NAMES, "m", 0.05),
}
SELFCAL_UNITS: Final = ("mm", "um", "um")
SELFCAL_STEPS: Final = (0.005, 1.0, 1.0)


def parse_groups(text: str) -> tuple[Group, ...]:
    """'boresight,selfcal,delay' → groups; ConfigError naming an unknown one."""
    out: list[Group] = []
    for word in (w.strip().lower() for w in text.split(",") if w.strip()):
        try:
            g = Group(word)
        except ValueError:
            raise ConfigError(f"--estimate: unknown group '{word}' (one of "
                              f"{', '.join(g.value for g in Group if g is not Group.NAVIGATION)}"
                              ")") from None
        if g is Group.NAVIGATION:
            raise ConfigError("--estimate: the navigation's error is modelled from its stated "
                              "accuracy (--nav-sigma-m), not estimated as a group")
        if g not in out:
            out.append(g)
    if not out:
        raise ConfigError("--estimate: name at least one group")
    return tuple(out)


@dataclass(frozen=True)
class Param:
    group: Group
    component: int
    segment: int  # −1 for a block-wide parameter
    name: str
    unit: str
    step: float  # central finite-difference half step
    prior_sigma: float | None  # a pseudo-observation θ = start ± σ, or None (free)
    index: int = -1  # the knot of a navigation parameter

    @property
    def label(self) -> str:
        if self.index >= 0:
            return f"{self.name}[{self.index}]"
        return self.name if self.segment < 0 else f"{self.name}[{self.segment}]"


@dataclass
class State:
    """Every model quantity, estimated or fixed, in user units."""

    boresight_arcsec: F64
    selfcal: F64  # δf mm, δx0 µm, δy0 µm
    delay_ms: float
    antenna_delta_m: F64
    gps_block_enu_m: F64
    gps_strip_enu_m: F64  # (S, 3)
    attitude_arcsec: F64  # (S, 3)
    drift_arcsec_per_s: F64  # (S, 3)
    nav_enu_m: F64 = field(default_factory=lambda: np.zeros((0, 3)))  # (K, 3) knots

    def copy(self) -> State:
        return State(self.boresight_arcsec.copy(), self.selfcal.copy(), self.delay_ms,
                     self.antenna_delta_m.copy(), self.gps_block_enu_m.copy(),
                     self.gps_strip_enu_m.copy(), self.attitude_arcsec.copy(),
                     self.drift_arcsec_per_s.copy(), self.nav_enu_m.copy())


@dataclass(frozen=True)
class PriorSigmas:
    """Prior σ (None: free) around the starting values.

    δx0 needs one: for a line scanner φ and δx0 are the same thing (both turn every pixel's
    look by the same angle along track: δx0 = −f'·φ exactly to first order), so the data fix
    only δx0 − f'·φ and the prior the split; 20 µm (1.3 px) is about a slit's mechanical
    tolerance. ω and δy0 differ by cos² of the view angle (0.87 at the CASI's swath edge): the
    data separate them, weakly, without a prior.
    """

    principal_point_x_um: float | None = 20.0
    principal_point_y_um: float | None = None
    focal_mm: float | None = None
    boresight_arcsec: float | None = None
    attitude_arcsec: float | None = 20.0
    drift_arcsec_per_s: float | None = 0.05
    gps_strip_m: float | None = None
    gps_block_m: float | None = None
    antenna_m: float | None = None
    delay_ms: float | None = None

    def of(self, group: Group, component: int) -> float | None:
        if group is Group.SELFCAL:
            return (self.focal_mm, self.principal_point_x_um,
                    self.principal_point_y_um)[component]
        return {Group.BORESIGHT: self.boresight_arcsec, Group.ATTITUDE: self.attitude_arcsec,
                Group.DRIFT: self.drift_arcsec_per_s, Group.GPS_STRIP: self.gps_strip_m,
                Group.GPS_BLOCK: self.gps_block_m, Group.ANTENNA: self.antenna_m,
                Group.DELAY: self.delay_ms}.get(group)


@dataclass(frozen=True)
class Layout:
    """The estimated parameters in vector order, and the fixed state around them."""

    params: tuple[Param, ...]
    segments: tuple[int, ...]
    base: State
    groups: tuple[Group, ...] = field(default=())
    knots: NavKnots | None = None  # the navigation model's, when there is one

    @property
    def size(self) -> int:
        return len(self.params)

    @property
    def labels(self) -> list[str]:
        return [p.label for p in self.params]

    def seg_index(self, segment: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
        lookup = {s: i for i, s in enumerate(self.segments)}
        return np.array([lookup[int(s)] for s in segment.tolist()], dtype=np.int64)

    def start(self) -> F64:
        return np.array([_get(self.base, p, self.segments) for p in self.params], np.float64)

    def unpack(self, theta: F64) -> State:
        st = self.base.copy()
        for p, v in zip(self.params, theta.tolist(), strict=True):
            _set(st, p, self.segments, float(v))
        return st

    def steps(self) -> F64:
        return np.array([p.step for p in self.params], np.float64)

    @property
    def nav_columns(self) -> npt.NDArray[np.int64]:
        """Columns of the navigation model's knots (3·knot + axis order)."""
        return np.array([i for i, p in enumerate(self.params) if p.group is Group.NAVIGATION],
                        np.int64)

    @property
    def reported(self) -> npt.NDArray[np.int64]:
        """Columns of the parameters a report shows: all but the navigation knots."""
        return np.array([i for i, p in enumerate(self.params)
                         if p.group is not Group.NAVIGATION], np.int64)

    def only_reported(self) -> Layout:
        """The layout without the navigation knots (what a result reports)."""
        return Layout(tuple(self.params[i] for i in self.reported.tolist()), self.segments,
                      self.base, self.groups, None)


def _slot(st: State, p: Param, segments: tuple[int, ...]) -> tuple[F64, int] | None:
    k = segments.index(p.segment) if p.segment >= 0 and p.index < 0 else -1
    arrays = {Group.BORESIGHT: (st.boresight_arcsec, p.component),
              Group.SELFCAL: (st.selfcal, p.component),
              Group.ANTENNA: (st.antenna_delta_m, p.component),
              Group.GPS_BLOCK: (st.gps_block_enu_m, p.component),
              Group.GPS_STRIP: (st.gps_strip_enu_m.reshape(-1), 3 * k + p.component),
              Group.ATTITUDE: (st.attitude_arcsec.reshape(-1), 3 * k + p.component),
              Group.DRIFT: (st.drift_arcsec_per_s.reshape(-1), 3 * k + p.component),
              Group.NAVIGATION: (st.nav_enu_m.reshape(-1), 3 * p.index + p.component)}
    return arrays.get(p.group)


def _get(st: State, p: Param, segments: tuple[int, ...]) -> float:
    slot = _slot(st, p, segments)
    return st.delay_ms if slot is None else float(slot[0][slot[1]])


def _set(st: State, p: Param, segments: tuple[int, ...], value: float) -> None:
    slot = _slot(st, p, segments)
    if slot is None:
        st.delay_ms = value
    else:
        slot[0][slot[1]] = value


def base_state(sensor: SensorModel, n_segments: int, n_knots: int = 0) -> State:
    """The sensor file's values; every correction zero."""
    sc = sensor.scanner
    return State(np.array(sensor.mounting.boresight_arcsec, np.float64),
                 np.array([sc.delta_focal_mm, *sc.delta_principal_point_um], np.float64),
                 float(sensor.time_delay_ms), np.zeros(3), np.zeros(3),
                 np.zeros((n_segments, 3)), np.zeros((n_segments, 3)),
                 np.zeros((n_segments, 3)), np.zeros((n_knots, 3)))


def build_layout(groups: tuple[Group, ...], segments: list[int], sensor: SensorModel | State,
                 priors: PriorSigmas | None = None, knots: NavKnots | None = None) -> Layout:
    """The parameters of `groups` around the starting state: a line scanner's sensor file
    (`base_state`), or a State built by the caller (the frame camera's, without knots)."""
    pri = priors or PriorSigmas()
    params: list[Param] = []
    for g in groups:
        names, unit, step = COMPONENTS[g]
        for seg in (segments if g in PER_STRIP else [-1]):
            for c, name in enumerate(names):
                u = SELFCAL_UNITS[c] if g is Group.SELFCAL else unit
                s = SELFCAL_STEPS[c] if g is Group.SELFCAL else step
                params.append(Param(g, c, seg, name, u, s, pri.of(g, c)))
    n_knots = 0 if knots is None else knots.count
    names, unit, step = COMPONENTS[Group.NAVIGATION]
    for k in range(n_knots):
        seg = int(knots.segment[k]) if knots is not None else -1
        params += [Param(Group.NAVIGATION, c, seg, names[c], unit, step, None, k)
                   for c in range(3)]
    base = sensor.copy() if isinstance(sensor, State) else \
        base_state(sensor, len(segments), n_knots)
    return Layout(tuple(params), tuple(segments), base, tuple(groups), knots if n_knots else None)
