"""Several flights in one calibration: they share the sensor parameters, nothing else.

    inp = join_flights([inp_a, inp_b])        # each a CalibrationInput of its own flight
    result = calibrate(inp, options)

Why: along track a time delay moves the ground by v·τ and the along-track look offset
(φ, δx0) by H·φ; in one flight every strip has the same speed v and height H, so only relief
and attitude rates tell them apart. Two flights with different v/H (another height or speed)
separate them, as two heights separate a lever arm from a boresight.

The joined input keeps each flight's own navigation, line times, points and DEM: the
trajectory routes every instant to the flight whose span holds it (flights never overlap in
GPS time; overlapping spans are refused), segment s of flight k becomes k·SEGMENT_STRIDE + s
and point ids become "k:id" (k from 0), so per-strip groups stay per strip and a point belongs
to one flight. The starting sensor is the first flight's; every flight must start from the same
one (the adjustment estimates one set of sensor parameters). Each flight keeps its
trajectory's stated accuracy (the navigation model, per segment).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Final

import numpy as np
import numpy.typing as npt

from postproc.calibration.data import GroundPoints, ImageObservations, SegmentClock
from postproc.calibration.navigation import NavigationAccuracy, per_segment
from postproc.calibration.surface import DemSurface, Surface
from postproc.georef import Dem, Pose, Trajectory
from sisa.core.errors import InputError

if TYPE_CHECKING:
    from postproc.calibration.adjust import CalibrationInput

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

SEGMENT_STRIDE: Final = 1000


def flight_segment(flight: int, segment: int) -> int:
    """The joined input's number of segment `segment` of flight `flight` (0-based)."""
    return flight * SEGMENT_STRIDE + segment


def flight_point_id(flight: int, point_id: str) -> str:
    return f"{flight}:{point_id}"


class FlightsTrajectory:
    """Several flights' trajectories as one: each instant goes to the flight that holds it."""

    def __init__(self, trajs: Sequence[Trajectory]) -> None:
        spans = [t.span_ns for t in trajs]
        order = np.argsort([s[0] for s in spans])
        for a, b in zip(order[:-1].tolist(), order[1:].tolist(), strict=True):
            if spans[b][0] <= spans[a][1]:
                raise InputError(f"flights {a} and {b} overlap in GPS time: a joint "
                                 "calibration needs separate flights")
        self.trajs = list(trajs)
        self.spans = spans

    @property
    def span_ns(self) -> tuple[int, int]:
        return min(s[0] for s in self.spans), max(s[1] for s in self.spans)

    def pose_at(self, t_gps_ns: npt.ArrayLike) -> Pose:
        t = np.atleast_1d(np.asarray(t_gps_ns, np.int64))
        pos = np.full((t.size, 3), np.nan)
        rot = np.full((t.size, 3, 3), np.nan)
        valid = np.zeros(t.size, dtype=np.bool_)
        for traj, (lo, hi) in zip(self.trajs, self.spans, strict=True):
            sel = np.flatnonzero((t >= lo) & (t <= hi))
            if sel.size:
                p = traj.pose_at(t[sel])
                pos[sel], rot[sel], valid[sel] = p.ins_ecef_m, p.r_ecef_from_body, p.valid
        return Pose(t, pos, rot, valid)


@dataclass(frozen=True)
class FlightsSurface:
    """Several DEMs: each point's height from the first that covers it."""

    surfaces: tuple[Surface, ...]

    def heights(self, ecef_m: F64) -> tuple[F64, F64]:
        h, out = self.surfaces[0].heights(ecef_m)
        out = np.array(out, np.float64)
        for s in self.surfaces[1:]:
            todo = ~np.isfinite(out)
            if not todo.any():
                break
            out[todo] = s.heights(ecef_m[todo])[1]
        return np.asarray(h, np.float64), out


def join_flights(inputs: Sequence[CalibrationInput]) -> CalibrationInput:
    """One CalibrationInput for several flights sharing the sensor (see the module doc)."""
    from postproc.calibration.adjust import CalibrationInput

    if not inputs:
        raise InputError("join_flights: no flight")
    sensor = inputs[0].sensor
    for k, inp in enumerate(inputs[1:], start=1):
        if inp.sensor != sensor:
            raise InputError(f"flight {k} starts from another sensor file than flight 0: a "
                             "joint calibration starts every flight from the same one")
    clock: dict[int, I64] = {}
    navigation: dict[int, NavigationAccuracy] = {}
    ids, kinds, ecef, pid, seg, line, pixel, sig = [], [], [], [], [], [], [], []
    for k, inp in enumerate(inputs):
        for s, t in inp.clock.t_by_segment.items():
            if not 0 <= s < SEGMENT_STRIDE:
                raise InputError(f"flight {k}: segment {s} outside 0…{SEGMENT_STRIDE - 1}")
            clock[flight_segment(k, s)] = t
        for s, acc in per_segment(inp.navigation, list(inp.clock.t_by_segment)).items():
            navigation[flight_segment(k, s)] = acc
        ids.append(np.array([flight_point_id(k, str(i)) for i in inp.points.ids.tolist()]))
        kinds.append(inp.points.kind)
        ecef.append(inp.points.ecef_m)
        o = inp.obs
        pid.append(np.array([flight_point_id(k, str(i)) for i in o.point_id.tolist()]))
        seg.append(o.segment + k * SEGMENT_STRIDE)
        line.append(o.line)
        pixel.append(o.pixel)
        sig.append(o.sigma_px)
    points = GroundPoints(np.concatenate(ids), np.concatenate(kinds), np.concatenate(ecef),
                          inputs[0].points.epsg)
    obs = ImageObservations(np.concatenate(pid), np.concatenate(seg).astype(np.int64),
                            np.concatenate(line), np.concatenate(pixel), np.concatenate(sig))
    surfaces = [_surface(i.dem) for i in inputs if i.dem is not None]
    dem: Dem | Surface | None = (None if not surfaces else surfaces[0] if len(surfaces) == 1
                                 else FlightsSurface(tuple(surfaces)))
    return CalibrationInput(FlightsTrajectory([i.traj for i in inputs]), SegmentClock(clock),
                            points, obs, sensor, dem, navigation or None)


def _surface(dem: Dem | Surface) -> Surface:
    return DemSurface(dem) if isinstance(dem, Dem) else dem
