"""The navigation-grade INS (LTN-101 class): records on the CAN bus, timed by the INS's own clock.

What it models, and why:
- **Own clock.** The INS counts time from power-on (scenario start = power-on):
  clock = clock_offset_s + (t_gps − t_power_on)·(1 + clock_drift_ppm·1e-6) + accumulated jumps,
  read in steps of clock_resolution_ns and sent as 100 ns ticks that wrap at 2^48. Post-processing
  must recover offset and drift from the latched sync pulses; nothing on the wire is GPS time.
- **Epochs on the INS grid.** A record is measured whenever the clock reaches a multiple of
  1/rate_hz (rounded to the nearest ns, then up to the next clock tick), so in GPS time the epochs
  drift. Their GPS times come from inverting the clock model exactly in int64 ns.
- **Output.** A record leaves output_delay_ms after its epoch as seven CAN frames, each taking its
  bus time at 500 kbit/s; the counter wraps at 2^counter_bits.
- **Errors.** Attitude = truth + per-axis bias + linear drift (both drawn once per run, drift
  counted from the scenario start) + white noise. Body rates get `ins.rate_noise_rps` and NED
  velocity `ins.velocity_noise_mps` of white noise (navigation-grade gyro ARW ≈ 0.002°/√h is
  ≈ 5e-6 rad/s per sample at 64 Hz). The attitude is output (with the same errors) during the
  alignment too: ALIGNING says it is not yet valid.
- **Status.** ALIGNING during the static phase except its last ALIGN_TAIL_S (engine start, taxi),
  NAVIGATING after; REBOOTED for REBOOTED_FLAG_S after a reboot (an in-flight reboot then goes on
  navigating: this emulator does not model in-air alignment).
- **Sync input.** A pulse is latched at its own timestamp: the record whose interval
  (previous epoch, epoch] contains it carries SYNC_PULSE and the clock reading at the pulse. The
  latch register holds its last value (reset to 0 at power-on), so only SYNC_PULSE says a value is
  new. A second pulse in one interval is counted, not sent. A pulse delivered after the record
  that covers it went out (a missed deadline) goes in the next record with DEGRADED set, so the
  fault shows in the data.
- **Faults.** Clock jumps add jump_ms to the clock from at_s on. A reboot switches the INS off for
  duration_s (records still in the output pipeline and pulses while off are lost), then counter
  and clock restart from 0 at the new power-on.
- **Speed.** Truth states are computed CHUNK_S of epochs at a time; only the latch and the
  encoding are done record by record, at output time, because only then is the latch known.

Truth tables (never written here): `ins_records` (every record sent), `ins_errors` (the drawn
attitude errors), `ins_sync_pulses` (what became of every pulse on the sync input) and rows in the
shared `faults` table.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass
from typing import NamedTuple

import can
import numpy as np
import numpy.typing as npt

from acquisition.ins_can import (
    FRAME_BYTES,
    TICK_NS,
    TICKS_MASK,
    InsRecord,
    InsStatus,
    encode_record,
    frame_bits,
)
from acquisition.pulses import Edge, PulseLine
from emulators.runtime import Device, Output, Port
from emulators.scenario import FaultProfile, InsSettings, Scenario
from emulators.trajectory import TrajectoryState, TruthTrajectory
from emulators.truth import TruthTable
from sisa.core.timescale import NS_PER_S, seconds_since

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

CAN_BITRATE_BPS = 500_000
FRAME_NS = frame_bits(FRAME_BYTES, worst_case_stuffing=False) * NS_PER_S // CAN_BITRATE_BPS
CHUNK_S = 4.0  # epochs per trajectory call: one call per record would be far too slow
ALIGN_TAIL_S = 10.0  # end of the static phase spent navigating (engine start, taxi)
REBOOTED_FLAG_S = 3.0
RATE_NOISE_RPS: float = InsSettings.model_fields["rate_noise_rps"].default
VEL_NOISE_MPS: float = InsSettings.model_fields["velocity_noise_mps"].default
ARCSEC_RAD = math.pi / (180.0 * 3600.0)
NEVER_NS = 1 << 62  # a boot that is never switched off
_TWO_PI = 2.0 * math.pi
_AXES = ("roll", "pitch", "heading")


# --- the clock -----------------------------------------------------------------------------

@dataclass(frozen=True)
class Boot:
    """One power-on of the INS, [t_on_ns, t_off_ns) in GPS ns."""

    index: int
    t_on_ns: int
    t_off_ns: int


@dataclass(frozen=True)
class ClockSegment:
    """A stretch of one boot, [t_start_ns, t_end_ns) GPS, without clock jumps: the clock reads
    base_ns + e + rint(e·drift) ns at GPS time t_on_ns + e."""

    boot: int
    t_start_ns: int
    t_end_ns: int
    t_on_ns: int
    base_ns: int


class FaultRow(NamedTuple):
    t_gps_ns: int
    kind: str
    detail: str


def _ns(t_s: float) -> int:
    return round(t_s * NS_PER_S)


def _boots(t0_ns: int, faults: FaultProfile) -> tuple[list[Boot], list[FaultRow]]:
    """Power-on intervals; a reboot that starts while the INS is already off does nothing."""
    boots: list[Boot] = []
    rows: list[FaultRow] = []
    t_on = t0_ns
    for f in sorted(faults.ins_reboots, key=lambda f: f.at_s):
        t_off = t0_ns + _ns(f.at_s)
        if t_off < t_on:
            rows.append(FaultRow(t_off, "ins_reboot", "ignored: INS already off"))
            continue
        boots.append(Boot(len(boots), t_on, t_off))
        t_on = t_off + _ns(f.duration_s)
        rows.append(FaultRow(t_off, "ins_reboot", f"off {f.duration_s:g} s, then counter and "
                             "clock restart from 0"))
    boots.append(Boot(len(boots), t_on, NEVER_NS))
    return boots, rows


def _segments(boots: list[Boot], t0_ns: int, offset_ns: int, faults: FaultProfile
              ) -> tuple[list[ClockSegment], list[FaultRow]]:
    """Split every boot at the clock jumps inside it; a jump while off does nothing."""
    jumps = sorted((t0_ns + _ns(f.at_s), _ns(f.jump_ms / 1e3)) for f in faults.ins_clock_jumps)
    segments: list[ClockSegment] = []
    rows = [FaultRow(t, "ins_clock_jump", f"{j / 1e6:+.6f} ms") for t, j in jumps
            if any(b.t_on_ns <= t < b.t_off_ns for b in boots)]
    rows += [FaultRow(t, "ins_clock_jump", f"{j / 1e6:+.6f} ms ignored: INS off") for t, j in jumps
             if not any(b.t_on_ns <= t < b.t_off_ns for b in boots)]
    for boot in boots:
        base = offset_ns if boot.index == 0 else 0
        start = boot.t_on_ns
        for t_jump, jump_ns in jumps:
            if boot.t_on_ns <= t_jump < boot.t_off_ns:
                segments.append(ClockSegment(boot.index, start, t_jump, boot.t_on_ns, base))
                base, start = base + jump_ns, t_jump
        segments.append(ClockSegment(boot.index, start, boot.t_off_ns, boot.t_on_ns, base))
    return [s for s in segments if s.t_end_ns > s.t_start_ns], rows


class InsClock:
    """The INS clock model over the whole run, and its exact inverse.

    Why int64: a float64 second since 1980 resolves ~0.2 µs, coarser than the latch. The clock
    count e + rint(e·drift) is non-decreasing in e (|drift| < 1), so its inverse is the unique
    smallest e that reaches a value.
    """

    def __init__(self, ins: InsSettings, t_power_on_ns: int, faults: FaultProfile) -> None:
        self.drift = ins.clock_drift_ppm * 1e-6
        self.resolution_ns = ins.clock_resolution_ns
        self.period_ns = NS_PER_S / ins.rate_hz
        self.boots, boot_rows = _boots(t_power_on_ns, faults)
        self.segments, jump_rows = _segments(self.boots, t_power_on_ns,
                                             _ns(ins.clock_offset_s), faults)
        self.fault_rows = sorted(boot_rows + jump_rows)

    def _count(self, e_ns: IntArray) -> IntArray:
        """Clock ns counted in e_ns GPS ns since power-on."""
        extra: IntArray = np.rint(e_ns * self.drift).astype(np.int64)
        return e_ns + extra

    def read_ns(self, seg: ClockSegment, t_gps_ns: IntArray) -> IntArray:
        """The clock (ns, before quantisation) at GPS instants inside the segment."""
        return seg.base_ns + self._count(t_gps_ns - seg.t_on_ns)

    def gps_ns_reaching(self, seg: ClockSegment, clock_ns: IntArray) -> IntArray:
        """The earliest GPS ns, not before the segment start, at which the clock reads at least
        clock_ns."""
        x = clock_ns - seg.base_ns
        e = np.ceil(x / (1.0 + self.drift)).astype(np.int64)
        for _ in range(6):
            up = self._count(e) < x
            down = self._count(e - 1) >= x
            if not (up.any() or down.any()):
                return seg.t_on_ns + np.maximum(e, seg.t_start_ns - seg.t_on_ns)
            e = e + up.astype(np.int64) - down.astype(np.int64)
        raise RuntimeError("INS clock inverse did not converge")

    def epoch_ns(self, k: IntArray) -> IntArray:
        """Clock value of grid epoch k: k/rate_hz to the nearest ns, up to the next clock tick."""
        nominal = np.rint(k * self.period_ns).astype(np.int64)
        up: IntArray = -np.floor_divide(-nominal, self.resolution_ns)
        return up * self.resolution_ns

    def segment_at(self, t_gps_ns: int) -> ClockSegment | None:
        """The segment running at a GPS instant; None while the INS is off."""
        for seg in self.segments:
            if seg.t_start_ns <= t_gps_ns < seg.t_end_ns:
                return seg
        return None

    def latch_ticks(self, t_gps_ns: int) -> int:
        """What the latch holds for a pulse at a GPS instant: the clock read at its resolution,
        in wrapping 100 ns ticks."""
        seg = self.segment_at(t_gps_ns)
        if seg is None:
            raise ValueError(f"the INS is off at {t_gps_ns} GPS ns")
        clock = int(self.read_ns(seg, np.array([t_gps_ns], dtype=np.int64))[0])
        return ticks(clock // self.resolution_ns * self.resolution_ns)


def ticks(clock_ns: int) -> int:
    """INS clock ns → 100 ns wire ticks, wrapped at 2^48 (negative clocks wrap too)."""
    return (clock_ns // TICK_NS) & TICKS_MASK


# --- epochs --------------------------------------------------------------------------------

class _Epochs:
    """Measurement epochs in time order, segment by segment: (boot, GPS ns, clock ns)."""

    def __init__(self, clock: InsClock, t_last_ns: int) -> None:
        self._clock = clock
        self._t_last_ns = t_last_ns
        self._seg_i = 0
        self._k_next: int | None = None
        self._last_clock_ns = 0

    def take(self, n: int) -> tuple[IntArray, IntArray, IntArray]:
        parts: list[tuple[IntArray, IntArray, IntArray]] = []
        got = 0
        while got < n and self._seg_i < len(self._clock.segments):
            part = self._from_segment(self._clock.segments[self._seg_i], n - got)
            parts.append(part)
            got += part[0].size
        if not parts:
            empty = np.zeros(0, dtype=np.int64)
            return empty, empty, empty
        boot, t, c = (np.concatenate(cols) for cols in zip(*parts, strict=True))
        return boot, t, c

    def _start_segment(self, seg: ClockSegment) -> int:
        c_start = int(self._clock.read_ns(seg, np.array([seg.t_start_ns], dtype=np.int64))[0])
        self._last_clock_ns = c_start - 1  # epochs already reached belong to the segment before
        return math.floor(c_start / self._clock.period_ns) - 1

    def _from_segment(self, seg: ClockSegment, n: int) -> tuple[IntArray, IntArray, IntArray]:
        if self._k_next is None:
            self._k_next = self._start_segment(seg)
        k = self._k_next + np.arange(n, dtype=np.int64)
        c = self._clock.epoch_ns(k)
        c = c[c > self._last_clock_ns]
        c = c[np.diff(c, prepend=self._last_clock_ns) > 0]  # one epoch per clock tick
        t = self._clock.gps_ns_reaching(seg, c)
        inside = int(np.count_nonzero(t < min(seg.t_end_ns, self._t_last_ns + 1)))
        if inside < c.size:
            self._seg_i += 1
            self._k_next = None
        else:
            self._k_next += n
        if inside:
            self._last_clock_ns = int(c[inside - 1])
        return np.full(inside, seg.boot, dtype=np.int64), t[:inside], c[:inside]


# --- records waiting to go out -------------------------------------------------------------

class _Pending(NamedTuple):
    """A measured record, complete except for the latch (known only when it goes out)."""

    boot: int
    t_on_ns: int
    counter: int
    seq: int
    t_meas_ns: int
    t_prev_ns: int  # previous epoch of the same boot (t_on_ns − 1 for the first)
    t_out_ns: int
    ins_time_ticks: int
    status: int
    roll_rad: float
    pitch_rad: float
    heading_rad: float
    rate_rps: tuple[float, float, float]
    vel_mps: tuple[float, float, float]


class _Latched(NamedTuple):
    t_pulse_ns: int  # −1: no pulse
    late: bool  # the carried pulse missed its record
    degraded: bool  # a late pulse reached this record (carried or counted)
    extra: int  # pulses in the interval beyond the first


def _wrap_2pi(angle_rad: FloatArray) -> FloatArray:
    """Into [0, 2π): np.mod alone can round a tiny negative angle up to exactly 2π."""
    wrapped = np.mod(angle_rad, _TWO_PI)
    return np.where(wrapped >= _TWO_PI, 0.0, wrapped)


def _alignment_end_ns(traj: TruthTrajectory) -> int:
    static = [p for p in traj.phases if p.name == "static"]
    if not static:
        return traj.t_start_ns
    return max(static[0].t_start_ns, static[0].t_end_ns - _ns(ALIGN_TAIL_S))


def _record_table() -> TruthTable:
    return TruthTable("ins_records", {
        "boot": "power-on index (0 at the scenario start, +1 per reboot)",
        "counter": "record counter as sent (wraps at 2^counter_bits, 0 after a reboot)",
        "seq": "record index since the scenario start across reboots (gaps: records lost at a "
               "reboot)",
        "t_meas_gps_ns": "measurement epoch (true GPS ns)",
        "t_out_gps_ns": "first frame on the bus (true GPS ns)",
        "ins_time_ticks": "INS clock at the epoch as sent (100 ns ticks, wraps at 2^48)",
        "sync_flag": "1 if the record carries a latched pulse",
        "sync_pulse_gps_ns": "true GPS ns of the carried pulse, -1 if none",
        "late_sync": "1 if the carried pulse arrived after its own record went out",
        "extra_pulses": "further pulses this record took (its interval, or one displaced by an "
                        "earlier late pulse), counted and not sent",
    }, "every INS record sent on the CAN bus")


def _pulse_table() -> TruthTable:
    return TruthTable("ins_sync_pulses", {
        "t_pulse_gps_ns": "pulse time on the INS sync input (true GPS ns)",
        "fate": "latched | late (carried by a later record, DEGRADED) | extra (second pulse in "
                "an interval) | lost (INS off, or no record after it)",
        "seq": "seq of the record that carried or counted it, -1 if lost",
    }, "every pulse on the INS sync input and what became of it")


def _error_table(rate_noise_rps: float, velocity_noise_mps: float) -> TruthTable:
    return TruthTable("ins_errors", {
        "axis": "roll | pitch | heading",
        "bias_arcsec": "constant attitude bias drawn for this run",
        "drift_arcsec_per_h": "linear attitude drift drawn for this run (from the scenario start)",
        "noise_arcsec": "σ of the white attitude noise",
    }, f"INS attitude error model; body-rate noise σ {rate_noise_rps} rad/s, "
       f"velocity noise σ {velocity_noise_mps} m/s")


@dataclass(frozen=True)
class AttitudeErrors:
    """The INS's attitude error model (roll, pitch, heading; rad): a bias and a linear drift
    drawn once per run, and white noise on every record."""

    bias_rad: FloatArray
    drift_rad_per_s: FloatArray  # counted from the scenario start (power-on)
    noise_rad: FloatArray  # σ

    @classmethod
    def draw(cls, ins: InsSettings, rng: np.random.Generator) -> AttitudeErrors:
        bias_sigma = np.asarray(ins.attitude_bias_arcsec) * ARCSEC_RAD
        drift_sigma = np.asarray(ins.attitude_drift_arcsec_per_h) * ARCSEC_RAD / 3600.0
        bias = rng.normal(0.0, 1.0, 3) * bias_sigma
        drift = rng.normal(0.0, 1.0, 3) * drift_sigma
        return cls(bias, drift, np.asarray(ins.attitude_noise_arcsec) * ARCSEC_RAD)

    def at(self, dt_s: FloatArray, rng: np.random.Generator) -> FloatArray:
        """(N, 3) errors at dt_s seconds from the start, with fresh white noise."""
        noise = rng.normal(0.0, 1.0, (dt_s.size, 3)) * self.noise_rad
        return np.asarray(self.bias_rad + self.drift_rad_per_s * dt_s[:, None] + noise,
                          np.float64)


# --- the device ----------------------------------------------------------------------------

class InsEmulator(Device):
    """The INS on the emulation timeline: CAN frames out, INS_SYNC pulses in."""

    name = "ins"
    input_lines = (PulseLine.INS_SYNC,)

    def __init__(self, scn: Scenario, traj: TruthTrajectory, rng: np.random.Generator,
                 faults: TruthTable, chunk_s: float = CHUNK_S) -> None:
        ins = scn.ins
        self._traj, self._rng, self._faults = traj, rng, faults
        self._t0_ns = traj.t_start_ns
        self.counter_bits = ins.counter_bits
        self.output_delay_ns = _ns(ins.output_delay_ms / 1e3)
        self.clock = InsClock(ins, traj.t_start_ns, scn.faults)
        self.truth = _record_table()
        self.pulses = _pulse_table()
        self.rate_noise_rps = ins.rate_noise_rps
        self.velocity_noise_mps = ins.velocity_noise_mps
        self.errors = _error_table(ins.rate_noise_rps, ins.velocity_noise_mps)
        self._draw_errors(ins)
        self._epochs = _Epochs(self.clock, traj.t_end_ns)
        self._chunk_n = max(1, math.ceil(chunk_s * ins.rate_hz))
        self._align_end_ns = _alignment_end_ns(traj)
        self._boot_off_ns = np.array([b.t_off_ns for b in self.clock.boots], dtype=np.int64)
        self._records_in_boot: dict[int, int] = {}
        self._last_meas_ns: dict[int, int] = {}
        self._seq = 0
        self._queue: deque[_Pending] = deque()
        self._frames: deque[can.Message] = deque()
        self._frame_t_ns = 0
        self._bus_free_ns = traj.t_start_ns
        self._pulses_waiting: list[int] = []
        self._latch_register = (-1, 0)  # (boot, ticks): holds its value until the next pulse
        self._fault_rows = deque(self.clock.fault_rows)
        self._last_emit_ns = traj.t_start_ns

    @property
    def tables(self) -> tuple[TruthTable, ...]:
        return self.truth, self.pulses, self.errors

    def _draw_errors(self, ins: InsSettings) -> None:
        err = AttitudeErrors.draw(ins, self._rng)
        self.attitude_bias_rad = err.bias_rad
        self.attitude_drift_rad_per_s = err.drift_rad_per_s
        self.attitude_noise_rad = err.noise_rad
        for i, axis in enumerate(_AXES):
            self.errors.append(
                axis=axis, bias_arcsec=float(self.attitude_bias_rad[i] / ARCSEC_RAD),
                drift_arcsec_per_h=float(self.attitude_drift_rad_per_s[i] * 3600.0 / ARCSEC_RAD),
                noise_arcsec=ins.attitude_noise_arcsec[i])

    # --- Device ----------------------------------------------------------------------------

    def next_time_ns(self) -> int | None:
        if self._frames:
            return self._frame_t_ns
        rec = self._peek()
        return None if rec is None else max(rec.t_out_ns, self._bus_free_ns)

    def emit(self, t_ns: int) -> list[Output]:
        if not self._frames:
            self._start_record(self._queue.popleft(), t_ns)
        msg = self._frames.popleft()
        self._frame_t_ns = self._bus_free_ns = t_ns + FRAME_NS
        self._last_emit_ns = t_ns
        self._write_faults(t_ns)
        return [Output(t_ns, Port.INS_CAN, msg)]

    def on_edge(self, edge: Edge) -> None:
        """Queue the pulse by its own time; the record covering it takes it when it goes out."""
        if edge.line is PulseLine.INS_SYNC:
            bisect.insort(self._pulses_waiting, edge.t_ns)

    def finish(self) -> None:
        """Pulses no record came for are lost; faults that acted by the end are written."""
        for t in self._pulses_waiting:
            self.pulses.append(t_pulse_gps_ns=t, fate="lost", seq=-1)
        self._pulses_waiting.clear()
        done = not self._frames and self._peek() is None
        self._write_faults(self._traj.t_end_ns if done else self._last_emit_ns)

    def _write_faults(self, t_ns: int) -> None:
        while self._fault_rows and self._fault_rows[0].t_gps_ns <= t_ns:
            row = self._fault_rows.popleft()
            self._faults.append(t_gps_ns=row.t_gps_ns, kind=row.kind, target=Port.INS_CAN.value,
                                detail=row.detail)

    # --- measuring (vectorised) --------------------------------------------------------------

    def _peek(self) -> _Pending | None:
        while not self._queue:
            boot, t_meas, clock = self._epochs.take(self._chunk_n)
            if not boot.size:
                return None
            self._queue.extend(self._measure(boot, t_meas, clock))
        return self._queue[0]

    def _measure(self, boot: IntArray, t_meas: IntArray, clock: IntArray) -> list[_Pending]:
        """Records for a run of epochs; those still in the pipeline at a power-off are lost."""
        n = boot.size
        counter, t_prev, t_on = self._bookkeeping(boot, t_meas)
        seq = self._seq + np.arange(n)
        self._seq += n
        st = self._traj.state(t_meas)
        roll, pitch, heading = self._attitude(st, t_meas)
        rate = st.body_rate_rps + self._rng.normal(0.0, self.rate_noise_rps, (n, 3))
        vel = st.vel_ned_mps + self._rng.normal(0.0, self.velocity_noise_mps, (n, 3))
        t_out = t_meas + self.output_delay_ns
        t_off = self._boot_off_ns[boot]
        ins_ticks = np.floor_divide(clock, TICK_NS) & TICKS_MASK
        cols = (boot, t_on, counter, seq, t_meas, t_prev, t_out, ins_ticks,
                self._status(boot, t_meas, t_on), roll, pitch, heading)
        rows = zip(*(c.tolist() for c in cols), map(tuple, rate.tolist()),
                   map(tuple, vel.tolist()), strict=True)
        keep = (t_out < t_off).tolist()
        return [_Pending(*row) for row, k in zip(rows, keep, strict=True) if k]

    def _bookkeeping(self, boot: IntArray, t_meas: IntArray
                     ) -> tuple[IntArray, IntArray, IntArray]:
        """Counter (wrapped), previous epoch and power-on time of every record, boot by boot."""
        counter = np.empty_like(boot)
        t_prev = np.empty_like(boot)
        t_on = np.empty_like(boot)
        for b in np.unique(boot).tolist():
            sel = boot == b
            first = self._records_in_boot.get(b, 0)
            counter[sel] = (first + np.arange(np.count_nonzero(sel))) % (1 << self.counter_bits)
            self._records_in_boot[b] = first + int(np.count_nonzero(sel))
            t_on[sel] = self.clock.boots[b].t_on_ns
            times = t_meas[sel]
            t_prev[sel] = np.concatenate(
                [[self._last_meas_ns.get(b, self.clock.boots[b].t_on_ns - 1)], times[:-1]])
            self._last_meas_ns[b] = int(times[-1])
        return counter, t_prev, t_on

    def _attitude(self, st: TrajectoryState, t_meas: IntArray
                  ) -> tuple[FloatArray, FloatArray, FloatArray]:
        err = AttitudeErrors(self.attitude_bias_rad, self.attitude_drift_rad_per_s,
                             self.attitude_noise_rad).at(seconds_since(t_meas, self._t0_ns),
                                                         self._rng)
        return (st.roll_rad + err[:, 0], st.pitch_rad + err[:, 1],
                _wrap_2pi(st.heading_rad + err[:, 2]))

    def _status(self, boot: IntArray, t_meas: IntArray, t_on: IntArray) -> IntArray:
        aligning = t_meas < self._align_end_ns
        status = np.where(aligning, int(InsStatus.ALIGNING), int(InsStatus.NAVIGATING))
        rebooted = (boot > 0) & (t_meas - t_on < _ns(REBOOTED_FLAG_S))
        return np.asarray(status | np.where(rebooted, int(InsStatus.REBOOTED), 0), dtype=np.int64)

    # --- sending (record by record) ----------------------------------------------------------

    def _start_record(self, rec: _Pending, t_ns: int) -> None:
        latched = self._latch(rec)
        status = InsStatus(rec.status)
        if latched.t_pulse_ns >= 0:
            status |= InsStatus.SYNC_PULSE
            self._latch_register = (rec.boot, self.clock.latch_ticks(latched.t_pulse_ns))
        elif self._latch_register[0] != rec.boot:
            self._latch_register = (rec.boot, 0)  # power-on clears the register
        if latched.degraded:
            status |= InsStatus.DEGRADED
        record = InsRecord(
            counter=rec.counter, ins_time_ticks=rec.ins_time_ticks, roll_rad=rec.roll_rad,
            pitch_rad=rec.pitch_rad, heading_rad=rec.heading_rad, body_rate_rps=rec.rate_rps,
            vel_ned_mps=rec.vel_mps, status=status, sync_flag=latched.t_pulse_ns >= 0,
            sync_time_ticks=self._latch_register[1])
        self._frames.extend(encode_record(record, counter_bits=self.counter_bits))
        self.truth.append(
            boot=rec.boot, counter=rec.counter, seq=rec.seq, t_meas_gps_ns=rec.t_meas_ns,
            t_out_gps_ns=t_ns, ins_time_ticks=rec.ins_time_ticks,
            sync_flag=int(record.sync_flag), sync_pulse_gps_ns=latched.t_pulse_ns,
            late_sync=int(latched.late), extra_pulses=latched.extra)

    def _latch(self, rec: _Pending) -> _Latched:
        """Take every waiting pulse up to this epoch: the earliest is carried, a pulse from an
        interval already sent is late, one from before this power-on is lost."""
        cut = bisect.bisect_right(self._pulses_waiting, rec.t_meas_ns)
        due, self._pulses_waiting[:cut] = self._pulses_waiting[:cut], []
        carried, late, degraded, extra = -1, False, False, 0
        for t in due:
            if t < rec.t_on_ns:
                self.pulses.append(t_pulse_gps_ns=t, fate="lost", seq=-1)
                continue
            is_late = t <= rec.t_prev_ns
            degraded |= is_late
            if carried < 0:
                carried, late = t, is_late
                fate = "late" if is_late else "latched"
            else:
                extra += 1
                fate = "extra"
            self.pulses.append(t_pulse_gps_ns=t, fate=fate, seq=rec.seq)
        return _Latched(carried, late, degraded, extra)
