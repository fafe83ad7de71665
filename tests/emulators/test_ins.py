"""The INS emulator, driven by the runtime in virtual time with a pulse source on its sync input,
checked against independent oracles: cantools for the frames, the record assembler for the stream,
exact rational arithmetic for the clock, least-squares fits for drift and offset, and the truth
trajectory for the attitude."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from fractions import Fraction
from importlib import resources
from typing import Any

import can
import cantools
import numpy as np
import pytest

from acquisition.codec import ErrorPolicy
from acquisition.ins_can import FRAMES_PER_RECORD, InsRecord, InsRecordAssembler, InsStatus
from acquisition.pulses import Edge, PulseLine
from emulators.faults import fault_table
from emulators.ins import (
    ALIGN_TAIL_S,
    FRAME_NS,
    RATE_NOISE_RPS,
    REBOOTED_FLAG_S,
    VEL_NOISE_MPS,
    InsClock,
    InsEmulator,
)
from emulators.runtime import Device, Output, Port, Runner
from emulators.scenario import Scenario, scenario_from_table
from emulators.trajectory import TruthTrajectory
from emulators.truth import TruthTable
from sisa.core.timescale import NS_PER_S, seconds_since

ATTITUDE_LSB_RAD = 1e-7
ZERO_ERRORS = {"attitude_bias_arcsec": [0.0, 0.0, 0.0],
               "attitude_drift_arcsec_per_h": [0.0, 0.0, 0.0],
               "attitude_noise_arcsec": [0.0, 0.0, 0.0]}
LATE_AT_S = 30  # the pulse of this second reaches the INS LATE_HOLD_NS late
LATE_HOLD_NS = 200_000_000
JUMP_AT_S, JUMP_MS = 40.0, 5.0
REBOOT_AT_S, REBOOT_S = 70.0, 5.0


class SecondPulses(Device):
    """Stands in for the SISA forwarding the PPS: an INS_SYNC edge at every whole GPS second."""

    name = "sync"

    def __init__(self, t_start_ns: int, t_end_ns: int) -> None:
        self._next = -(-t_start_ns // NS_PER_S) * NS_PER_S
        self._t_end_ns = t_end_ns
        self.sent: list[int] = []

    def next_time_ns(self) -> int | None:
        return self._next if self._next <= self._t_end_ns else None

    def emit(self, t_ns: int) -> list[Output]:
        self.sent.append(t_ns)
        self._next += NS_PER_S
        return [Output(t_ns, Port.PULSES, Edge(PulseLine.INS_SYNC, len(self.sent), t_ns))]


@dataclass
class Run:
    scn: Scenario
    ins: InsEmulator
    faults: TruthTable
    pulses_ns: list[int]
    frames: list[tuple[int, can.Message]] = field(default_factory=list)

    @property
    def t0_ns(self) -> int:
        return self.scn.block.t_start_gps_ns

    def col(self, name: str) -> np.ndarray[Any, Any]:
        return self.ins.truth.column(name)

    def records(self) -> list[InsRecord]:
        asm = InsRecordAssembler(ErrorPolicy.RAISE)
        out = [d.message for _, m in self.frames if (d := asm.feed(m)) is not None]
        asm.flush()
        assert asm.stats.errors == 0
        return out


def emulate(scn: Scenario, until_s: float, late_s: Sequence[int] = (), echo_ns: int = 0) -> Run:
    """Run the INS and the pulse source; pulses of the seconds in late_s are held back, and with
    echo_ns every pulse comes twice (a bouncing contact)."""
    traj = TruthTrajectory.from_scenario(scn)
    t0, until = traj.t_start_ns, traj.t_start_ns + round(until_s * NS_PER_S)
    faults = fault_table()
    ins = InsEmulator(scn, traj, np.random.default_rng(scn.seed), faults)
    source = SecondPulses(t0, until)
    run = Run(scn, ins, faults, source.sent)
    late = {t0 + s * NS_PER_S for s in late_s}
    held: list[Edge] = []

    def sink(out: Output) -> Sequence[Edge]:
        due = [e for e in held if out.t_ns >= e.t_ns + LATE_HOLD_NS]
        held[:] = [e for e in held if e not in due]
        if isinstance(out.payload, can.Message):
            run.frames.append((out.t_ns, out.payload))
        elif isinstance(out.payload, Edge) and out.payload.t_ns in late:
            held.append(out.payload)
        elif isinstance(out.payload, Edge):
            due.append(out.payload)
            if echo_ns:
                due.append(Edge(PulseLine.INS_SYNC, 0, out.payload.t_ns + echo_ns))
        return due

    Runner([ins, source], sink).run(until_ns=until)
    return run


def bench(**ins: Any) -> Scenario:
    return scenario_from_table({"base": "bench", "ins": ins})


@pytest.fixture(scope="module")
def clean() -> Run:
    return emulate(bench(), 150.0)


@pytest.fixture(scope="module")
def exact() -> Run:
    return emulate(bench(**ZERO_ERRORS), 80.0)


@pytest.fixture(scope="module")
def faulty() -> Run:
    scn = scenario_from_table({
        "base": "bench", "ins": {"counter_bits": 8},
        "faults": {"ins_clock_jumps": [{"at_s": JUMP_AT_S, "jump_ms": JUMP_MS}],
                   "ins_reboots": [{"at_s": REBOOT_AT_S, "duration_s": REBOOT_S}]}})
    return emulate(scn, 100.0, late_s=[LATE_AT_S])


def _model_clock_ns(run: Run, t_ns: np.ndarray[Any, Any]) -> np.ndarray[Any, Any]:
    """The clock model written out independently, in exact rationals (boot 0, no jumps)."""
    ins = run.scn.ins
    rate = 1 + Fraction(ins.clock_drift_ppm) / 1_000_000
    offset = Fraction(ins.clock_offset_s) * NS_PER_S
    return np.array([float(offset + (int(t) - run.t0_ns) * rate) for t in t_ns])


# --- wire -------------------------------------------------------------------------------------

def test_cantools_decodes_every_frame(clean: Run) -> None:
    with resources.as_file(resources.files("acquisition").joinpath("ins.dbc")) as path:
        db = cantools.database.load_file(path)
    assert isinstance(db, cantools.database.can.Database)
    counters = clean.col("counter")
    assert len(clean.frames) == FRAMES_PER_RECORD * len(counters)
    for i, (_, msg) in enumerate(clean.frames):
        decoded = db.decode_message(msg.arbitration_id, bytes(msg.data))
        assert isinstance(decoded, dict)
        assert decoded["seq"] == counters[i // FRAMES_PER_RECORD] & 0xFF


def test_stream_assembles_with_zero_errors(clean: Run, faulty: Run) -> None:
    for run in (clean, faulty):
        recs = run.records()
        assert [r.counter for r in recs] == run.col("counter").tolist()
        assert [r.ins_time_ticks for r in recs] == run.col("ins_time_ticks").tolist()
        assert [int(r.sync_flag) for r in recs] == run.col("sync_flag").tolist()


def test_frames_leave_after_the_output_delay_at_bus_speed(clean: Run) -> None:
    t_meas, t_out = clean.col("t_meas_gps_ns"), clean.col("t_out_gps_ns")
    assert np.all(t_out - t_meas == round(clean.scn.ins.output_delay_ms * 1e6))
    times = np.array([t for t, _ in clean.frames]).reshape(-1, FRAMES_PER_RECORD)
    assert np.array_equal(times[:, 0], t_out)
    assert np.all(np.diff(times, axis=1) == FRAME_NS)
    assert FRAME_NS == 222_000  # 111 bits at 500 kbit/s


# --- clock ------------------------------------------------------------------------------------

def test_clock_inverse_is_exact() -> None:
    scn = bench(clock_drift_ppm=-473.25, clock_offset_s=-3.7, clock_resolution_ns=7)
    clock = InsClock(scn.ins, 10**18, scn.faults)
    seg = clock.segments[0]
    rng = np.random.default_rng(5)
    t = 10**18 + np.sort(rng.integers(0, 7_000 * NS_PER_S, 2000))
    c = clock.read_ns(seg, t)
    exact = [Fraction(-37, 10) * NS_PER_S + (int(x) - 10**18) * (1 - Fraction(47325, 10**8))
             for x in t]
    assert max(abs(Fraction(int(a)) - b) for a, b in zip(c, exact, strict=True)) <= Fraction(1, 2)
    back = clock.gps_ns_reaching(seg, c)
    assert np.all(clock.read_ns(seg, back) >= c)
    assert np.all(clock.read_ns(seg, back - 1) < c)
    assert np.all(back <= t)


def test_epochs_are_one_period_apart_in_ins_time(clean: Run) -> None:
    period_ticks = round(1e7 / clean.scn.ins.rate_hz)
    assert np.all(np.diff(clean.col("ins_time_ticks")) == period_ticks)
    gps_step = np.diff(clean.col("t_meas_gps_ns"))
    want = 1e9 / clean.scn.ins.rate_hz / (1 + clean.scn.ins.clock_drift_ppm * 1e-6)
    assert np.all(np.abs(gps_step - want) <= 1.0)


def test_drift_and_offset_from_the_latched_pulses(clean: Run) -> None:
    ins = clean.scn.ins
    latched = [r.sync_time_ticks for r in clean.records() if r.sync_flag]
    pulses_ns = [t for t in clean.pulses_ns if t <= clean.col("t_meas_gps_ns")[-1]]
    assert len(latched) == len(pulses_ns)
    x_s = seconds_since(pulses_ns, clean.t0_ns)
    y_s = np.array(latched, dtype=np.float64) * 1e-7
    slope, intercept = np.polyfit(x_s, y_s, 1)
    assert (slope - 1) * 1e6 == pytest.approx(ins.clock_drift_ppm, abs=1.0)
    assert (slope - 1) * 1e6 == pytest.approx(ins.clock_drift_ppm, abs=1e-3)
    assert intercept == pytest.approx(ins.clock_offset_s, abs=2 * ins.clock_resolution_ns * 1e-9)
    resid_ns = (y_s - (slope * x_s + intercept)) * 1e9
    assert np.max(np.abs(resid_ns)) <= ins.clock_resolution_ns


def test_record_times_fit_the_truth(clean: Run) -> None:
    ins = clean.scn.ins
    x_s = seconds_since(clean.col("t_meas_gps_ns"), clean.t0_ns)
    y_s = np.array([r.ins_time_ticks for r in clean.records()], dtype=np.float64) * 1e-7
    slope, intercept = np.polyfit(x_s, y_s, 1)
    assert (slope - 1) * 1e6 == pytest.approx(ins.clock_drift_ppm, abs=1e-3)
    assert intercept == pytest.approx(ins.clock_offset_s, abs=ins.clock_resolution_ns * 1e-9)
    model = _model_clock_ns(clean, clean.col("t_meas_gps_ns")[::97])
    sent_ns = clean.col("ins_time_ticks")[::97] * 100.0
    assert np.max(np.abs(sent_ns - model)) <= 2.0  # epochs fall on the clock grid, to the ns


# --- content ----------------------------------------------------------------------------------

def _attitude_residuals(run: Run) -> np.ndarray[Any, Any]:
    traj = TruthTrajectory.from_scenario(run.scn)
    st = traj.state(run.col("t_meas_gps_ns"))
    recs = run.records()
    got = np.array([(r.roll_rad, r.pitch_rad, r.heading_rad) for r in recs])
    want = np.stack([st.roll_rad, st.pitch_rad, st.heading_rad], axis=-1)
    d = got - want
    d[:, 2] = (d[:, 2] + math.pi) % (2 * math.pi) - math.pi
    return d


def test_attitude_is_exact_when_the_error_model_is_zeroed(exact: Run) -> None:
    assert np.max(np.abs(_attitude_residuals(exact))) <= 0.5 * ATTITUDE_LSB_RAD * (1 + 1e-6)
    traj = TruthTrajectory.from_scenario(exact.scn)
    st = traj.state(exact.col("t_meas_gps_ns"))
    recs = exact.records()
    rates = np.array([r.body_rate_rps for r in recs])
    vel = np.array([r.vel_ned_mps for r in recs])
    assert np.max(np.abs(rates - st.body_rate_rps)) < 6 * RATE_NOISE_RPS + 1e-6
    assert np.max(np.abs(vel - st.vel_ned_mps)) < 6 * VEL_NOISE_MPS + 1e-3
    assert np.std(rates - st.body_rate_rps) == pytest.approx(RATE_NOISE_RPS, rel=0.1)
    assert all(0.0 <= r.heading_rad < 2 * math.pi for r in recs)


def test_attitude_is_truth_plus_the_error_model(clean: Run) -> None:
    ins = clean.ins
    t_s = seconds_since(clean.col("t_meas_gps_ns"), clean.t0_ns)[:, None]
    model = ins.attitude_bias_rad + ins.attitude_drift_rad_per_s * t_s
    resid = _attitude_residuals(clean) - model
    sigma = ins.attitude_noise_rad
    n = resid.shape[0]
    assert np.all(np.abs(resid.mean(axis=0)) < 5 * sigma / math.sqrt(n) + ATTITUDE_LSB_RAD)
    assert resid.std(axis=0) == pytest.approx(sigma, rel=0.05)
    assert np.any(np.abs(ins.attitude_bias_rad) > sigma)  # the bias is really there
    table = ins.errors
    assert table.column("axis").tolist() == ["roll", "pitch", "heading"]
    assert np.allclose(table.column("bias_arcsec") * math.pi / 648_000, ins.attitude_bias_rad)


def test_status_aligning_then_navigating(clean: Run) -> None:
    t_s = seconds_since(clean.col("t_meas_gps_ns"), clean.t0_ns)
    status = np.array([int(r.status) for r in clean.records()])
    align_end_s = clean.scn.flight.static_alignment_s - ALIGN_TAIL_S
    aligning = (status & InsStatus.ALIGNING) != 0
    assert np.array_equal(aligning, t_s < align_end_s)
    assert np.array_equal((status & InsStatus.NAVIGATING) != 0, ~aligning)
    assert not np.any(status & (InsStatus.REBOOTED | InsStatus.DEGRADED))


def test_every_pulse_is_latched_once(clean: Run) -> None:
    flagged = clean.col("sync_flag") == 1
    t_meas = clean.col("t_meas_gps_ns")
    pulses_ns = [t for t in clean.pulses_ns if t <= t_meas[-1]]
    assert np.array_equal(clean.col("sync_pulse_gps_ns")[flagged], pulses_ns)
    pulse = clean.col("sync_pulse_gps_ns")[flagged]
    t_prev = np.concatenate([[clean.t0_ns - 1], t_meas[:-1]])
    i = np.flatnonzero(flagged)
    assert np.all((pulse <= t_meas[i]) & (pulse > t_prev[i]))
    fates = clean.ins.pulses.column("fate").tolist()
    unrecorded = len(clean.pulses_ns) - len(pulses_ns)  # after the last record of the run
    assert fates == ["latched"] * len(pulses_ns) + ["lost"] * unrecorded


def test_second_pulse_in_an_interval_is_counted_not_sent() -> None:
    run = emulate(bench(), 10.0, echo_ns=1_000_000)
    t_meas = run.col("t_meas_gps_ns")
    pulse = run.col("sync_pulse_gps_ns")
    later = (run.col("sync_flag") == 1) & (pulse > t_meas[0])  # the epoch at t0 splits a pair
    later &= pulse % NS_PER_S == 0
    pulses_ns = [t for t in run.pulses_ns[1:] if t + 1_000_000 <= t_meas[-1]]
    assert run.col("sync_pulse_gps_ns")[later].tolist() == pulses_ns
    assert run.col("extra_pulses")[later].tolist() == [1] * len(pulses_ns)
    assert run.col("extra_pulses").sum() == len(pulses_ns)
    fates = run.ins.pulses.column("fate").tolist()
    assert fates[2: 2 + 2 * len(pulses_ns)] == ["latched", "extra"] * len(pulses_ns)
    assert not any(InsStatus.DEGRADED in r.status for r in run.records())


# --- faults -----------------------------------------------------------------------------------

def test_counter_wraps_and_seq_stays_monotonic(faulty: Run) -> None:
    counter, seq, boot = faulty.col("counter"), faulty.col("seq"), faulty.col("boot")
    assert counter.max() == 255
    first = boot == 0
    assert np.array_equal(counter[first], np.arange(np.count_nonzero(first)) % 256)
    assert np.all(np.diff(seq) > 0)


def test_late_pulse_is_degraded_not_hidden(faulty: Run) -> None:
    t_late = faulty.t0_ns + LATE_AT_S * NS_PER_S
    row = int(np.flatnonzero(faulty.col("sync_pulse_gps_ns") == t_late)[0])
    assert faulty.col("late_sync")[row] == 1
    assert faulty.col("t_out_gps_ns")[row] >= t_late + LATE_HOLD_NS
    rec = faulty.records()[row]
    assert rec.sync_flag
    assert InsStatus.DEGRADED in rec.status
    assert faulty.col("late_sync").sum() == 1
    degraded = [InsStatus.DEGRADED in r.status for r in faulty.records()]
    assert sum(degraded) == 1
    covering = np.flatnonzero(faulty.col("t_meas_gps_ns") >= t_late)[0]
    assert faulty.col("sync_flag")[covering] == 0
    fates = dict(zip(faulty.ins.pulses.column("t_pulse_gps_ns").tolist(),
                     faulty.ins.pulses.column("fate").tolist(), strict=True))
    assert fates[t_late] == "late"


def test_clock_jump_shows_in_the_records_and_the_faults(faulty: Run) -> None:
    t_jump = faulty.t0_ns + round(JUMP_AT_S * NS_PER_S)
    boot0 = faulty.col("boot") == 0
    t_meas = faulty.col("t_meas_gps_ns")[boot0]
    step_ns = faulty.col("ins_time_ticks")[boot0] * 100.0 - _model_clock_ns(faulty, t_meas)
    assert np.max(np.abs(step_ns[t_meas < t_jump])) <= 2.0
    assert np.max(np.abs(step_ns[t_meas >= t_jump] - JUMP_MS * 1e6)) <= 2.0
    rows = _fault_rows(faulty, "ins_clock_jump")
    assert rows == [(t_jump, "+5.000000 ms")]


def test_backward_clock_jump_repeats_grid_times() -> None:
    scn = scenario_from_table({"base": "bench", "faults": {
        "ins_clock_jumps": [{"at_s": 5.0, "jump_ms": -20.0}]}})
    run = emulate(scn, 10.0)
    ticks = run.col("ins_time_ticks")
    period_ticks = round(1e7 / scn.ins.rate_hz)
    assert np.all(ticks % period_ticks == 0)  # still on the INS's own grid
    steps = np.diff(ticks)
    assert steps.tolist().count(period_ticks) == steps.size - 1
    assert steps.min() == -period_ticks  # the clock went back 20 ms: one epoch measured again
    assert np.all(np.diff(run.col("t_meas_gps_ns")) > 0)


def test_reboot_restarts_counter_and_clock(faulty: Run) -> None:
    t_off = faulty.t0_ns + round(REBOOT_AT_S * NS_PER_S)
    t_on = t_off + round(REBOOT_S * NS_PER_S)
    frame_t = np.array([t for t, _ in faulty.frames])
    assert not np.any((frame_t >= t_off) & (frame_t < t_on))
    recs = faulty.records()
    boot = faulty.col("boot")
    first = int(np.flatnonzero(boot == 1)[0])
    assert recs[first].counter == 0
    assert recs[first].ins_time_ticks == 0  # the clock restarts at 0 on the grid
    assert faulty.col("t_meas_gps_ns")[first] == t_on
    t_s = (faulty.col("t_meas_gps_ns")[boot == 1] - t_on) / NS_PER_S
    rebooted = [InsStatus.REBOOTED in r.status for r in recs[first:]]
    assert rebooted == (t_s < REBOOTED_FLAG_S).tolist()
    assert not any(InsStatus.REBOOTED in r.status for r in recs[:first])
    assert _fault_rows(faulty, "ins_reboot")[0][0] == t_off
    pulses = faulty.ins.pulses
    lost = [t for t, f in zip(pulses.column("t_pulse_gps_ns").tolist(),
                              pulses.column("fate").tolist(), strict=True) if f == "lost"]
    assert set(range(t_off, t_on, NS_PER_S)) <= set(lost)
    sync_after = [r.sync_time_ticks for r in recs[first:] if r.sync_flag]
    assert sync_after[0] == 0  # the pulse at power-on is latched at clock 0
    assert all(s < 30 * 10**7 for s in sync_after)


def test_records_in_the_pipeline_at_a_reboot_are_lost(faulty: Run) -> None:
    t_off = faulty.t0_ns + round(REBOOT_AT_S * NS_PER_S)
    boot0 = faulty.col("boot") == 0
    assert faulty.col("t_out_gps_ns")[boot0].max() < t_off
    assert faulty.col("t_meas_gps_ns")[boot0].max() < t_off - round(
        faulty.scn.ins.output_delay_ms * 1e6) + round(1e9 / faulty.scn.ins.rate_hz)
    seq = faulty.col("seq")
    gap = int(seq[np.flatnonzero(~boot0)[0]] - seq[np.flatnonzero(boot0)[-1]])
    assert gap > 1  # records measured but not sent leave a gap in seq


def _fault_rows(run: Run, kind: str) -> list[tuple[int, str]]:
    f = run.faults
    return [(int(t), d) for t, k, d in zip(f.column("t_gps_ns"), f.column("kind"),
                                           f.column("detail"), strict=True) if k == kind]
