"""The geodetic GPS receiver (Ashtech Z-12 class): NMEA fixes, the PPS, and event time tags.

Outputs, on the emulation timeline:
- a PPS edge at every GPS second, with white jitter (`gps.pps_jitter_ns`), and after it
  `$PASHR,PTT` with the receiver's measurement of that edge (rounded to the tag resolution);
- at every NMEA epoch (`gps.nmea_rate_hz`) GGA and RMC, plus ZDA on whole seconds, sent
  `gps.nmea_latency_ms` after the epoch; positions are the true antenna phase centre plus a
  first-order Gauss–Markov error (σ and τ from the scenario: code ~1 m, phase ~3–5 cm);
- `$PASHR,TTT` for every accepted pulse on the event input, tagged at the pulse's own time.

Other receivers (`gps.receiver`, docs/protocols.md) send the same fixes and tags in their own
words: a u-blox F9P NMEA 4.1 with UBX-TIM-TP after each PPS and UBX-TIM-TM2 per event; a NovAtel
OEM7 ASCII logs only: BESTPOSA per fix epoch, TIMEA after each PPS, MARK1TIMEA per event.

Maximum event rate, the way the receiver enforces it: after an accepted event the input is blind
for 0.98 / max_event_rate_hz (a dead time that re-arms just before the next period, so pulses one
period apart ± jitter are all tagged); a pulse in the dead time is ignored (no TTT) and written to
the truth as rejected. Pulses are never queued.

During a PPS outage (fault profile) the receiver has lost lock: no PPS, no PTT, GGA quality 0 and
RMC void, and events are not tagged.

The serial port sends one byte after another at `gps.serial_baud` (8N1: 10 bits a byte): a
sentence due while another is on the wire waits for it (the receiver's output queue), and is
output when its first byte leaves. A Z-12 at 9600 baud sends ~960 bytes a second: 20 TTT tags a
second (34 bytes each) and the fixes would fill it; `Scenario` refuses a load above the port's
capacity and `sisa scenario show` gives the load (`gps_serial_load_pct`).
"""

from __future__ import annotations

import dataclasses
import heapq
import math
from collections.abc import Callable, Sequence
from functools import partial

import numpy as np
import numpy.typing as npt

from acquisition.nmea import (
    DEFAULT_VERSION,
    FixQuality,
    ModeIndicator,
    NavStatus,
    NmeaMessage,
    NmeaVersion,
    Talker,
    encode,
    gga_from_fix,
    ptt_from_gps_ns,
    rmc_from_fix,
    ttt_from_gps_ns,
    zda_from_gps_ns,
)
from acquisition.novatel import (
    BestPos,
    NovatelLog,
    PositionType,
    SolutionStatus,
    encode_log,
    log_header,
    mark1time_from_gps_ns,
    time_for_pps,
)
from acquisition.pulses import Edge, PulseLine
from acquisition.ubx import (
    GpsMessage,
    UbxMessage,
    encode_ubx,
    tim_tm2_from_gps_ns,
    tim_tp_for_pulse,
)
from emulators.localplane import LocalPlane
from emulators.runtime import Device, Output, Port
from emulators.scenario import GpsSettings, GpsSolution, ReceiverModel, Scenario
from emulators.trajectory import TrajectoryState, TruthTrajectory
from emulators.truth import TruthTable
from sisa.core.frames import body_to_ned_matrix, ned_to_ecef_matrix
from sisa.core.timescale import NS_PER_S

PTT_LATENCY_NS = 25_000_000
TTT_LATENCY_NS = 30_000_000
SENTENCE_SPACING_NS = 5_000_000  # one sentence after another on the serial line
FIX_CHUNK_S = 60.0


def wire_time_ns(n_bytes: int, baud: int) -> int:
    """Time `n_bytes` take on an 8N1 serial line (a start bit, 8 data bits, a stop bit)."""
    return n_bytes * 10 * NS_PER_S // baud


def antenna_fix_ecef_m(st: TrajectoryState, antenna_offset_m: Sequence[float],
                       error_ned_m: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """(N, 3) ECEF of the antenna phase centre at the states `st` (body-frame offset from the
    INS centre), moved by a fix's error (N, 3, local north/east/down): what each fix reports,
    before NMEA's rounding."""
    r_bn = body_to_ned_matrix(st.roll_rad, st.pitch_rad, st.heading_rad)
    r_ne = ned_to_ecef_matrix(np.radians(st.lat_deg), np.radians(st.lon_deg))
    lever_ned = r_bn @ np.asarray(antenna_offset_m, np.float64)
    return np.asarray(st.ecef_m + np.einsum("nij,nj->ni", r_ne, lever_ned + error_ned_m))


class _Schedule:
    """A time-ordered queue of actions; ties keep insertion order."""

    def __init__(self) -> None:
        self._heap: list[tuple[int, int, Callable[[int], list[Output]]]] = []
        self._order = 0

    def at(self, t_ns: int, action: Callable[[int], list[Output]]) -> None:
        self._order += 1
        heapq.heappush(self._heap, (t_ns, self._order, action))

    def next_time_ns(self) -> int | None:
        return self._heap[0][0] if self._heap else None

    def run_due(self, t_ns: int) -> list[Output]:
        outputs: list[Output] = []
        while self._heap and self._heap[0][0] <= t_ns:
            _, _, action = heapq.heappop(self._heap)
            outputs += action(t_ns)
        return outputs


class GpsReceiver(Device):
    name = "gps"
    input_lines = (PulseLine.GPS_EVENT,)

    def __init__(self, scn: Scenario, traj: TruthTrajectory, rng: np.random.Generator,
                 faults: TruthTable, chunk_s: float = FIX_CHUNK_S) -> None:
        self.scn, self.traj, self.rng, self.faults = scn, traj, rng, faults
        self.chunk_s = chunk_s
        self.plane = LocalPlane.for_scenario(scn)
        self.tag_res_ns = scn.gps.event_tag_resolution_ns
        self.ublox = scn.gps.receiver is ReceiverModel.UBLOX_F9P
        self.novatel = scn.gps.receiver is ReceiverModel.NOVATEL_OEM7
        # u-blox: NMEA 4.1 from a multi-constellation solution; Ashtech: NMEA 2.3, GPS alone
        self._talker = Talker.MULTI if self.ublox else Talker.GPS
        self._nmea_version = NmeaVersion.V4_1 if self.ublox else DEFAULT_VERSION
        self._edges_seen = 0  # u-blox: TIM-TM2's rising edge counter
        self._tm2_accuracy_ns = max(1, round(scn.gps.pps_jitter_ns))
        self._clock_std_s = scn.gps.pps_jitter_ns * 1e-9  # NovAtel: the clock offset's σ
        # re-arms 2 % early, so pulses exactly one period apart (PPS ± jitter) all get tagged
        self.dead_time_ns = round(0.98 * NS_PER_S / scn.gps.max_event_rate_hz)
        self._outages = [(traj.t_start_ns + int(f.at_s * NS_PER_S),
                          traj.t_start_ns + int((f.at_s + f.duration_s) * NS_PER_S))
                         for f in scn.faults.pps_outages]
        for (a, b), f in zip(self._outages, scn.faults.pps_outages, strict=True):
            faults.append(t_gps_ns=a, kind="pps_outage", target="gps",
                          detail=f"{f.duration_s:g} s, until {b}")
        self._armed_at_ns = traj.t_start_ns
        self._uart_free_ns = traj.t_start_ns  # the serial port is sending until then
        self._epoch_ns = round(NS_PER_S / scn.gps.nmea_rate_hz)
        # epoch → (lat, lon, h, speed, course, error n, e, d): computed a minute ahead
        self._fixes: dict[int, tuple[float, ...]] = {}
        self._gm_state: np.ndarray | None = None
        self._schedule = _Schedule()
        self.pps = TruthTable("pps", {
            "t_second_gps_ns": "the GPS second the pulse marks",
            "t_edge_gps_ns": "true edge time (with jitter)",
            "ptt_gps_ns": "time the receiver reported in PTT (rounded to the tag resolution)",
        }, "PPS edges output by the GPS receiver")
        self.events = TruthTable("events", {
            "t_edge_gps_ns": "true time of the pulse on the event input",
            "accepted": "1 if tagged, 0 if ignored",
            "ttt_gps_ns": "time reported in TTT (-1 if not tagged)",
            "reason": "why a pulse was not tagged",
        }, "pulses seen on the GPS receiver's event input")
        self.fixes = TruthTable("gps_fixes", {
            "t_gps_ns": "NMEA epoch", "error_n_m": "position error north",
            "error_e_m": "position error east", "error_d_m": "position error down",
            "quality": "GGA quality",
        }, "errors added to the true antenna position in each NMEA fix the receiver sent")
        first_second = -(-traj.t_start_ns // NS_PER_S) * NS_PER_S
        self._schedule.at(first_second, self._pps_edge)
        first_epoch = -(-traj.t_start_ns // self._epoch_ns) * self._epoch_ns
        self._schedule.at(first_epoch + self._latency_ns, self._nmea_epoch)

    @property
    def tables(self) -> tuple[TruthTable, ...]:
        return (self.pps, self.events, self.fixes)

    @property
    def _latency_ns(self) -> int:
        return round(self.scn.gps.nmea_latency_ms * 1e6)

    def in_outage(self, t_ns: int) -> bool:
        return any(a <= t_ns < b for a, b in self._outages)

    def next_time_ns(self) -> int | None:
        return self._schedule.next_time_ns()

    def emit(self, t_ns: int) -> list[Output]:
        return self._schedule.run_due(t_ns)

    # --- PPS -------------------------------------------------------------------------------

    def _pps_edge(self, t_ns: int) -> list[Output]:
        second = t_ns  # scheduled on the whole second
        nxt = second + NS_PER_S
        if nxt <= self.traj.t_end_ns:
            self._schedule.at(nxt, self._pps_edge)
        if self.in_outage(second):
            return []
        jitter_ns = round(self.rng.normal(0.0, self.scn.gps.pps_jitter_ns))
        t_edge = second + jitter_ns
        if self.ublox:  # TIM-TP announces the next pulse; this one was announced on time
            self.pps.append(t_second_gps_ns=second, t_edge_gps_ns=t_edge, ptt_gps_ns=second)
            self._send_at(second + PTT_LATENCY_NS, tim_tp_for_pulse(nxt))
        elif self.novatel:  # TIME logged on the second: the second this pulse marks
            self.pps.append(t_second_gps_ns=second, t_edge_gps_ns=t_edge, ptt_gps_ns=second)
            self._send_at(second + PTT_LATENCY_NS,
                          time_for_pps(second, self._clock_std_s, self.scn.block.leap_seconds))
        else:
            self.pps.append(t_second_gps_ns=second, t_edge_gps_ns=t_edge,
                            ptt_gps_ns=self._rounded(t_edge))
            self._send_at(second + PTT_LATENCY_NS, ptt_from_gps_ns(t_edge))
        return [Output(t_ns, Port.PULSES, Edge(PulseLine.PPS, 0, t_edge))]

    def _rounded(self, t_ns: int) -> int:
        return (t_ns + self.tag_res_ns // 2) // self.tag_res_ns * self.tag_res_ns

    # --- events ----------------------------------------------------------------------------

    def on_edge(self, edge: Edge) -> None:
        t = edge.t_ns
        if self.in_outage(t):
            self.events.append(t_edge_gps_ns=t, accepted=0, ttt_gps_ns=-1, reason="no lock")
            return
        self._edges_seen += 1
        if t < self._armed_at_ns:
            self.events.append(t_edge_gps_ns=t, accepted=0, ttt_gps_ns=-1, reason="dead time")
            return
        self._armed_at_ns = t + self.dead_time_ns
        tag: GpsMessage | NovatelLog
        if self.ublox:
            tag = tim_tm2_from_gps_ns(self._rounded(t), self._edges_seen, self._tm2_accuracy_ns)
        elif self.novatel:
            tag = mark1time_from_gps_ns(self._rounded(t), self._clock_std_s,
                                        self.scn.block.leap_seconds)
        else:
            tag = ttt_from_gps_ns(t)
        self.events.append(t_edge_gps_ns=t, accepted=1, ttt_gps_ns=self._rounded(t), reason="")
        self._send_at(t + TTT_LATENCY_NS, tag)

    # --- NMEA ------------------------------------------------------------------------------

    def _send(self, message: GpsMessage | NovatelLog, t_ns: int) -> list[Output]:
        """On the wire now if the port is free; else queued until it is."""
        if self._uart_free_ns > t_ns:
            self._schedule.at(self._uart_free_ns, partial(self._send, message))
            return []
        if isinstance(message, UbxMessage):
            data = encode_ubx(message)
        elif isinstance(message, NovatelLog):
            data = encode_log(message)
        else:
            data = encode(message, self._nmea_version)
        self._uart_free_ns = t_ns + wire_time_ns(len(data), self.scn.gps.serial_baud)
        return [Output(t_ns, Port.GPS_SERIAL, data)]

    def _send_at(self, t_ns: int, message: GpsMessage | NovatelLog) -> None:
        self._schedule.at(t_ns, partial(self._send, message))

    def _nmea_epoch(self, t_ns: int) -> list[Output]:
        epoch = t_ns - self._latency_ns
        nxt = epoch + self._epoch_ns
        if nxt <= self.traj.t_end_ns:
            self._schedule.at(nxt + self._latency_ns, self._nmea_epoch)
        lat, lon, h, speed, course, err_n, err_e, err_d = self._fix(epoch)
        leap = self.scn.block.leap_seconds
        lost = self.in_outage(epoch)
        quality = FixQuality.INVALID if lost else self._quality
        # the truth of the fix sent, when it is sent: rows for the minute computed ahead were
        # written past the flight's end, stamped with its end time (the epochs were clipped)
        self.fixes.append(t_gps_ns=epoch, error_n_m=err_n, error_e_m=err_e, error_d_m=err_d,
                          quality=int(quality))
        if self.novatel:
            return self._send(self._bestpos(epoch, lat, lon, h, lost), t_ns)
        mode = ModeIndicator.NOT_VALID if lost else self._mode
        gps = self.scn.gps
        gga = gga_from_fix(epoch, leap, lat, lon, h, gps.geoid_separation_m, quality, 9, 0.9)
        rmc = rmc_from_fix(epoch, leap, lat, lon, speed, course, mode)
        zda = zda_from_gps_ns(epoch, leap) if epoch % NS_PER_S == 0 else None
        if self.ublox:  # its RMC states no navigational status: V, as u-blox receivers write
            talker = self._talker.value
            gga = dataclasses.replace(gga, talker=talker)
            rmc = dataclasses.replace(rmc, talker=talker, nav_status=NavStatus.NOT_VALID)
            zda = None if zda is None else dataclasses.replace(zda, talker=talker)
        messages: list[NmeaMessage] = [gga, rmc]
        if zda is not None:
            messages.append(zda)
        for k, msg in enumerate(messages[1:], start=1):
            self._send_at(t_ns + k * SENTENCE_SPACING_NS, msg)
        return self._send(messages[0], t_ns)

    def _bestpos(self, epoch: int, lat: float, lon: float, h: float, lost: bool) -> BestPos:
        """BESTPOS of a fix: height above the receiver's geoid and its undulation, the
        scenario's σ, the solution type of `gps.solution`; with lock lost no solution."""
        gps = self.scn.gps
        phase = gps.solution is GpsSolution.PHASE
        kind = PositionType.NARROW_INT if phase else PositionType.PSRDIFF
        return BestPos(log_header("BESTPOS", epoch),
                       SolutionStatus.INSUFFICIENT_OBS if lost else SolutionStatus.SOL_COMPUTED,
                       PositionType.NONE if lost else kind, lat, lon,
                       h - gps.geoid_separation_m, gps.geoid_separation_m, "WGS84",
                       gps.horizontal_sigma_m, gps.horizontal_sigma_m, gps.vertical_sigma_m,
                       "0", 1.0, 0.0, 12, 9, 9, 9 if phase else 0, 0, 0, 0, 0x11 if phase else 0x01)

    @property
    def _quality(self) -> FixQuality:
        if self.scn.gps.solution is GpsSolution.PHASE:
            return FixQuality.RTK_FIXED
        return FixQuality.DGPS

    @property
    def _mode(self) -> ModeIndicator:
        if self.scn.gps.solution is GpsSolution.PHASE:
            return ModeIndicator.RTK_FIXED
        return ModeIndicator.DIFFERENTIAL

    def _fix(self, epoch_ns: int) -> tuple[float, ...]:
        if epoch_ns not in self._fixes:
            self._fixes = self._fix_chunk(epoch_ns)
        return self._fixes.pop(epoch_ns)

    def _fix_chunk(self, first_ns: int) -> dict[int, tuple[float, ...]]:
        """Antenna fixes (and their errors) for the next minute of epochs, computed in one
        vectorised pass; the errors are drawn for the whole minute even past the flight's end,
        so that the random stream, hence every later draw, stays as it was."""
        n = max(1, math.floor(self.chunk_s * NS_PER_S / self._epoch_ns))
        t = first_ns + self._epoch_ns * np.arange(n, dtype=np.int64)
        t = np.clip(t, self.traj.t_start_ns, self.traj.t_end_ns)
        st = self.traj.state(t)
        err_ned = self._position_errors(n)
        lat, lon, h = self.plane.ecef_to_geodetic(
            antenna_fix_ecef_m(st, self.scn.mounting.antenna_offset_m, err_ned))
        vn, ve = st.vel_ned_mps[:, 0], st.vel_ned_mps[:, 1]
        speed = np.hypot(vn, ve)
        course = np.mod(np.degrees(np.arctan2(ve, vn)), 360.0)
        return {int(ti): (float(a), float(b), float(c), float(d), float(e), *map(float, err))
                for ti, a, b, c, d, e, err in zip(t, lat, lon, h, speed, course, err_ned,
                                                  strict=True)}

    def _position_errors(self, n: int) -> np.ndarray:
        """First-order Gauss–Markov errors (N, E, D) with the scenario's σ and τ."""
        out, self._gm_state = position_errors(self.scn.gps, n, self._epoch_ns / NS_PER_S,
                                              self.rng, self._gm_state)
        return out


def position_errors(gps: GpsSettings, n: int, step_s: float, rng: np.random.Generator,
                    state: npt.NDArray[np.float64] | None = None
                    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """The receiver's position errors at n epochs step_s apart: a first-order Gauss–Markov
    process per axis (N, E, D) with σ (horizontal, horizontal, vertical) and τ from the
    settings, continuing from `state` (the last epoch's error), or starting in its stationary
    distribution. Returns (errors (n, 3), the new state)."""
    sigma = np.array([gps.horizontal_sigma_m, gps.horizontal_sigma_m, gps.vertical_sigma_m])
    phi = math.exp(-step_s / gps.noise_correlation_s)
    if state is None:
        state = rng.normal(0.0, 1.0, 3) * sigma  # start in the stationary distribution
    out = np.empty((n, 3))
    drive = rng.normal(0.0, 1.0, (n, 3)) * sigma * math.sqrt(1.0 - phi * phi)
    for k in range(n):
        state = phi * state + drive[k]
        out[k] = state
    return out, state
