"""The live loop's batched hand-over (acquisition.handover) against handing every read over at
once: the same records logged, the same pulses forwarded, each forward while its own edge is
being handed over (never out of a held batch)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import pytest

from acquisition.handover import EdgeClock, Handover, dispatch
from acquisition.live import Arrival, Source
from acquisition.pulses import Edge, EdgeStreamDecoder, PulseLine
from acquisition.rereading import arrivals, raw_reads
from acquisition.runner import Acquisition, AcquisitionConfig
from emulators.scenario import load_scenario, scenario_from_table
from recorder.messages import RawCanFrames, SyncForward, SyncModeSwitch, SyncSession
from sisa.core.timescale import NS_PER_S
from sisa.wiring.acqconfig import acquisition_config
from sisa.wiring.simulation import simulate

TICK_NS = 100_000_000
Step = Arrival | int  # an int: the loop's clock tick at that host time


def _acquire(config: AcquisitionConfig, steps: Sequence[Step], held: bool,
             ) -> tuple[list[tuple[object, object]], list[tuple[int, Edge]], Acquisition, int]:
    """Records logged, (step being handed over, edge) of every pulse sent, the acquisition, and
    the number of batches (0 when handed over at once)."""
    logged: list[tuple[object, object]] = []
    sent: list[tuple[int, Edge]] = []
    step = [-1]
    edges = EdgeStreamDecoder()
    acq = Acquisition(config, lambda m, topic: logged.append((m, topic)),
                      lambda e: sent.append((step[0], e)), pulse_stats=edges.stats)
    handover, clock = Handover(acq), EdgeClock()
    for i, s in enumerate(steps):
        step[0] = i
        if held:
            handover.tick(s) if isinstance(s, int) else handover.put(s)
        elif isinstance(s, int):  # `sisa record`'s loop as it was: every read at once
            t_edge = clock.now(s)
            if t_edge is not None:
                acq.tick(s, t_edge)
        else:
            if s.source is Source.PULSES:
                assert isinstance(s.payload, Edge)
                clock.seen(s.t_host_ns, s.payload.t_ns)
            dispatch(acq, s)
    step[0] = len(steps)
    handover.flush()
    last = steps[-1]
    acq.finish(last if isinstance(last, int) else last.t_host_ns)
    return logged, sent, acq, handover.batches


def _with_ticks(items: Sequence[Arrival]) -> list[Step]:
    """The reads with the loop's clock ticks between them, every TICK_NS."""
    steps: list[Step] = []
    next_tick = items[0].t_host_ns
    for item in items:
        while next_tick <= item.t_host_ns:
            steps.append(next_tick)
            next_tick += TICK_NS
        steps.append(item)
    return steps


def _assert_same(config: AcquisitionConfig, steps: list[Step]) -> tuple[list[object], int]:
    logged_now, sent_now, acq_now, _ = _acquire(config, steps, held=False)
    logged_held, sent_held, acq_held, batches = _acquire(config, steps, held=True)
    assert sent_held == sent_now  # same pulses, each sent while its own edge was handed over
    assert len(logged_held) == len(logged_now)
    for i, (a, b) in enumerate(zip(logged_held, logged_now, strict=True)):
        assert a == b, f"record {i} differs"
    assert acq_held.streams["ppf"].deadline_misses == acq_now.streams["ppf"].deadline_misses
    return [m for m, _ in logged_now], batches


@pytest.fixture(scope="module")
def simulated_log(tmp_path_factory: pytest.TempPathFactory) -> tuple[AcquisitionConfig, Path]:
    scn = scenario_from_table({"base": "bench", "block": {"strip_length_m": 600.0},
                               "flight": {"static_alignment_s": 20.0}})
    out = tmp_path_factory.mktemp("sim")
    simulate(scn, out, images=False)
    return acquisition_config(scn), out / "flight.mcap"


def test_a_flights_reads_give_the_same_log_held_and_at_once(
        simulated_log: tuple[AcquisitionConfig, Path]) -> None:
    config, log = simulated_log
    reads = raw_reads([log], config.read_interval_ns)
    steps = _with_ticks(list(arrivals(reads, EdgeStreamDecoder())))
    logged, batches = _assert_same(config, steps)
    switches = [m for m in logged if isinstance(m, SyncModeSwitch)]
    forwards = [m for m in logged if isinstance(m, SyncForward)]
    assert [(s.from_mode, s.to_mode) for s in switches] == [(1, 2), (2, 1)] * 2
    assert sum(f.mode == 2 for f in forwards) >= 15
    assert sum(f.mode == 1 for f in forwards) >= 15
    seconds = (reads[-1][0] - reads[0][0]) / NS_PER_S
    assert batches < 8 * seconds < len(steps) / 10  # it did hold: a few batches a second


def _edges(line: PulseLine, t0_ns: int, period_ns: int, count: int, latency_ns: int,
           shift_ns: int = 0) -> list[Arrival]:
    """Edges on the timeline (minus `shift_ns`: a source restarted on an earlier timeline),
    read on the 5 ms clock after `latency_ns`."""
    out = []
    for k in range(count):
        t = t0_ns + k * period_ns
        t_read = (t + latency_ns) // 5_000_000 * 5_000_000 + 5_000_000
        out.append(Arrival(t_read, Source.PULSES, Edge(line, k, t - shift_ns)))
    return out


def test_edge_cases_give_the_same_pulses_held_and_at_once() -> None:
    """A burst of ppf in mode 1 (noise), the scanner off and on again (once between two PPS, its
    'off' found by a held tick), a pulse source back on an earlier timeline (a new session),
    n = 3 with spacing: every pulse forwarded at once and every record as when each read was
    handed over at once."""
    config = acquisition_config(load_scenario("bench"))
    t0 = 1_800_000_000 * NS_PER_S
    line_ns = 16_000_000
    short_offs = []  # 100 lines, off 0.52-0.64 s (no PPS in between), four times
    start = t0 + 19_784_000_000
    for gap_ms in (520, 560, 600, 640):
        start += gap_ms * 1_000_000
        short_offs += _edges(PulseLine.PPF, start, line_ns, 100, 300_000)
        start += 99 * line_ns
    restart = t0 + 30 * NS_PER_S
    items = (_edges(PulseLine.PPS, t0, NS_PER_S, 30, 1_000_000)
             + _edges(PulseLine.PPS, restart, NS_PER_S, 15, 1_000_000, shift_ns=60 * NS_PER_S)
             + _edges(PulseLine.PPF, t0 + 3 * NS_PER_S, 40 * line_ns, 2, 300_000)  # noise
             + _edges(PulseLine.PPF, t0 + 5 * NS_PER_S, line_ns, 400, 300_000)
             + _edges(PulseLine.PPF, t0 + 15 * NS_PER_S, line_ns, 300, 300_000)
             + short_offs
             + _edges(PulseLine.PPF, restart, line_ns, 600, 300_000, shift_ns=60 * NS_PER_S))
    items.sort(key=lambda a: a.t_host_ns)
    steps = _with_ticks(items)
    for one_of_n in (config.sync.one_of_n, 3):
        logged, batches = _assert_same(_with_one_of_n(config, one_of_n), steps)
        sessions = [m for m in logged if isinstance(m, SyncSession)]
        switches = [m for m in logged if isinstance(m, SyncModeSwitch)]
        assert len(sessions) == 2
        assert [(s.session, s.from_mode, s.to_mode) for s in switches] == (
            [(0, 1, 2), (0, 2, 1)] * 6 + [(1, 1, 2), (1, 2, 1)])
        assert 0 < batches < len(steps) / 4


def _with_one_of_n(config: AcquisitionConfig, n: int) -> AcquisitionConfig:
    return dataclasses.replace(config, sync=dataclasses.replace(config.sync, one_of_n=n))


def test_a_batch_is_handed_over_when_its_work_is_held_not_only_its_time() -> None:
    """At high rates 200 ms is a lot of work, during which the loop reads nothing: a batch also
    goes when `HOLD_UNITS` are held (CAN frames here), so host times stay near the reads."""
    import can

    from acquisition.handover import HOLD_NS, HOLD_UNITS

    config = acquisition_config(load_scenario("bench"))
    logged: list[object] = []
    acq = Acquisition(config, lambda m, _t: logged.append(m), lambda _e: None)
    handover = Handover(acq)
    t0 = 1_800_000_000 * NS_PER_S
    frames = [can.Message(arbitration_id=0x7F0, data=bytes(8), is_extended_id=False)] * 100
    reads = HOLD_UNITS // len(frames) + 1
    for k in range(reads):
        assert handover.batches == 0
        assert not any(isinstance(m, RawCanFrames) for m in logged)
        handover.put(Arrival(t0 + k * 1_000_000, Source.INS, frames))
    assert (reads - 1) * 1_000_000 < HOLD_NS
    assert handover.batches == 1
    assert any(isinstance(m, RawCanFrames) for m in logged)  # handed over, raw CAN logged
