"""A log recorded on a host clock that was set in flight: the steps are found and taken out of
every receive time, and the flight is timed as if the clock had never stepped.

`sisa record` stamps a clock that never steps (tests/acquisition/test_host_clock.py); a logger
stamping the system clock logs every step chrony's makestep, a leap second or an operator made.
The log here is a simulated one with its receive times moved as such a logger would have
written them (`bench/host_clock_steps.py` draws many more)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.records import Message

from emulators.scenario import scenario_from_table
from postproc.sync import SyncInput, TimeStatus, host_steps_note, read_sync_input, synchronise
from postproc.sync.clockmap import board_map
from postproc.sync.hoststeps import find_steps, split_candidates, split_index, unstep_sync_input
from sisa.cli import main
from sisa.wiring.simulation import simulate
from tests.mcaplog import rewrite_log
from tests.postproc.test_sync import WRONG_NS, ins_truth_ns, line_truth_ns, ok_errors_ns
from tests.postproc.test_sync_faults import SHORT, _merge

S = 1_000_000_000


def stepped(inp: SyncInput, steps: list[tuple[int, int]]) -> SyncInput:
    """Every receive time from each (host time, step) on moved by the step."""
    def move(obj: Any) -> Any:
        changes: dict[str, Any] = {}
        for f in dataclasses.fields(obj):
            value = getattr(obj, f.name)
            if dataclasses.is_dataclass(value) and not isinstance(value, type):
                changes[f.name] = move(value)
            elif f.name.endswith("t_host_ns") and isinstance(value, np.ndarray):
                moved = value.copy()
                for at_ns, step_ns in steps:
                    moved[value >= at_ns] += step_ns
                changes[f.name] = moved
        return dataclasses.replace(obj, **changes)
    return move(inp)  # type: ignore[no-any-return]


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, SyncInput]:
    run = tmp_path_factory.mktemp("host_steps")
    table = _merge({"base": "bench", "seed": 4, **SHORT},
                   {"faults": {"spurious_pulse_rate_hz": 0.3, "lost_pulse_fraction": 0.02}})
    simulate(scenario_from_table(table), run, images=False)
    return run, read_sync_input(run / "flight.mcap")


def _stepped_log(src: Path, dst: Path, at_ns: int, step_ns: int) -> None:
    """A copy of a flight log as a logger on a stepping clock would have written it: every
    `t_host_ns` (and log time) from `at_ns` on moved by `step_ns`; the rest as it was."""
    def edit(topic: str, message: Message) -> list[tuple[int, bytes]]:
        if message.log_time < at_ns:
            return [(message.log_time, message.data)]
        obj = json.loads(message.data)
        if isinstance(obj, dict) and "t_host_ns" in obj:
            obj["t_host_ns"] += step_ns
            return [(message.log_time + step_ns, json.dumps(obj).encode())]
        return [(message.log_time + step_ns, message.data)]
    rewrite_log(src, dst, edit)


def test_sisa_sync_warns_of_the_steps_and_times_the_flight_as_recorded(
        flight: tuple[Path, SyncInput], tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The command on a real MCAP file written on a stepping clock: the same tables as the
    log as recorded, and a warning that names the step."""
    run, inp = flight
    assert main(["sync", str(run / "flight.mcap"), "--out", str(tmp_path / "sound")]) == 0
    capsys.readouterr()
    at_ns, step_ns = _placed(inp, "back_before_the_first_strip")[0]
    _stepped_log(run / "flight.mcap", tmp_path / "stepped.mcap", at_ns, step_ns)
    assert main(["sync", str(tmp_path / "stepped.mcap"), "--out", str(tmp_path / "s")]) == 0
    err = capsys.readouterr().err
    assert "the log's receive times step 1 time(s) (-400.000 s at" in err
    for table in ("ins_times.csv", "line_times.csv"):
        assert (tmp_path / "s" / table).read_bytes() == (tmp_path / "sound" / table).read_bytes()


def _strip_gap(inp: SyncInput) -> tuple[int, int]:
    """The receive times of the last header before the scanner-off gap and the first after."""
    t = inp.headers.t_host_ns
    i = int(np.argmax(np.diff(t)))
    return int(t[i]), int(t[i + 1])


def _placed(inp: SyncInput, case: str) -> list[tuple[int, int]]:
    t0, t1 = int(inp.ins.t_host_ns[0]), int(inp.ins.t_host_ns[-1])
    gap_start, gap_end = _strip_gap(inp)
    first_header = int(inp.headers.t_host_ns[0])
    mid_strip = first_header + (gap_start - first_header) // 2
    return {
        # the 4-bit PPS pattern's period: the far side matches as well one period off
        "back_15s_in_a_strip": [(mid_strip, -15 * S)],
        # the next strip's headers fall before the step on the stepped clock: only their ties
        # to the forwarded frame pulses say they came after it
        "back_past_the_gap": [((gap_start + gap_end) // 2, -(gap_end - gap_start) - 20 * S)],
        # as far back as the next strip's headers read 2 s before the step's moment: the headers
        # ending the strip before could be after it as well, but for their ties
        "back_into_the_strip_before": [(gap_start + 5 * S, -(gap_end - gap_start - 5 * S) - 2 * S)],
        "back_before_the_first_strip": [((t0 + first_header) // 2, -400 * S)],
        "forward_1h": [(t0 + (t1 - t0) // 3, 3600 * S)],
        # chrony setting the clock on the ground, then a leap second in the air
        "makestep_and_leap_second": [(t0 + 30 * S, 2_300_000_000), (mid_strip, -S)],
    }[case]


@pytest.mark.parametrize("case", ["back_15s_in_a_strip", "back_past_the_gap",
                                  "back_into_the_strip_before",
                                  "back_before_the_first_strip", "forward_1h",
                                  "makestep_and_leap_second"])
def test_a_stepped_host_clock_is_timed_as_if_it_had_not_stepped(
        flight: tuple[Path, SyncInput], case: str) -> None:
    run, inp = flight
    steps = _placed(inp, case)
    sound = synchronise(inp)
    res = synchronise(stepped(inp, steps))
    found = res.report["host_clock_steps"]
    assert [round(s["step_ms"]) for s in found] == [round(s / 1e6) for _, s in steps]
    assert sound.report["host_clock_steps"] == []
    # the same records and lines timed, at the same times
    np.testing.assert_array_equal(res.ins.status, sound.ins.status)
    np.testing.assert_array_equal(res.lines.status, sound.lines.status)
    np.testing.assert_array_equal(res.ins.t_gps_ns, sound.ins.t_gps_ns)
    np.testing.assert_array_equal(res.lines.t_gps_ns, sound.lines.t_gps_ns)
    assert np.count_nonzero(res.ins.status == TimeStatus.OK) > 0.95 * res.ins.status.size
    e_ins = ok_errors_ns(res.ins.t_gps_ns, res.ins.status, ins_truth_ns(run, inp))
    e_line = ok_errors_ns(res.lines.t_gps_ns, res.lines.status, line_truth_ns(run, res))
    assert np.abs(e_ins).max() < WRONG_NS
    assert np.abs(e_line).max() < WRONG_NS
    note = host_steps_note(res.report)
    assert note is not None
    assert f"{len(steps)} time(s)" in note


def test_every_receive_time_comes_back_as_recorded(flight: tuple[Path, SyncInput]) -> None:
    _, inp = flight
    for case in ("back_past_the_gap", "back_into_the_strip_before", "back_before_the_first_strip",
                 "forward_1h"):
        log = stepped(inp, _placed(inp, case))
        real = ~log.sisa.pps_spurious
        board = board_map(log.sisa.pps_board_ns, log.sisa.pps_gps_second_ns,
                          log.sisa.pps_spurious, log.gps.tag_t_gps_ns, log.gps.tag_is_ptt)
        assert board is not None
        back = unstep_sync_input(log, find_steps(log.sisa.pps_t_host_ns[real],
                                                 log.sisa.pps_gps_second_ns[real]), board.gps_ns)
        for got, want in ((back.ins.t_host_ns, inp.ins.t_host_ns),
                          (back.headers.t_host_ns, inp.headers.t_host_ns),
                          (back.gps.fix_t_host_ns, inp.gps.fix_t_host_ns),
                          (back.gps.tag_t_host_ns, inp.gps.tag_t_host_ns),
                          (back.sisa.pps_t_host_ns, inp.sisa.pps_t_host_ns),
                          (back.sisa.fwd_t_host_ns, inp.sisa.fwd_t_host_ns)):
            assert np.abs(got - want).max() < 1_000_000, case


def test_a_host_that_stalls_is_no_step() -> None:
    """A recorder that stopped reading for 3 s and then read the queued PPS reports at once
    logs them late by 3, 2 and 1 s: a passing lag, not a clock set."""
    gps = (np.arange(60, dtype=np.int64) + 1_400_000_000) * S
    host = gps + 37_000_000 + np.random.default_rng(1).integers(0, 2_000_000, 60)
    host[30:33] = host[33] - np.array([2, 1, 0]) * 1_000  # read together with the next one
    assert find_steps(host, gps) == []
    host[40:] += 250_000_000  # and a real step later
    found = find_steps(host, gps)
    assert len(found) == 1
    assert abs(found[0].step_ns - 250_000_000) < 3_000_000  # to the reports' latency scatter
    assert found[0].gps_after_ns == gps[40]


def test_a_stream_split_by_its_ties_where_its_gaps_cannot_tell() -> None:
    """Headers with the scanner off across a step back of 60 s at 40 s: the strip after it
    (70–80 s) reads 10–20 s, right after the strip before it (0–10 s), as if no step had come
    between them. Their ties to the forwarded frame pulses (1 frame in 64, split already) say
    one did; between the last tie before it and the first after, nothing in the stream tells
    (docs/sync.md, Limits)."""
    period = 16_000_000
    before = np.arange(0, 10 * S, period)
    after = np.arange(70 * S, 80 * S, period) - 60 * S
    t = np.concatenate([before, after])
    step, moment = -60 * S, (40 * S - 5_000_000, 40 * S + 5_000_000)
    spans = [(-S, moment[1]), (moment[0] + step, 100 * S)]  # before it, after it
    places = split_candidates(t, spans, 0, 0)
    assert split_index(t, step, places) in (0, t.size)  # the gaps alone: all after, or none
    tied = np.arange(7, t.size, 64)
    votes = tied, tied >= before.size
    last_before, first_after = tied[tied < before.size][-1], tied[tied >= before.size][0]
    assert last_before < split_index(t, step, places, votes=votes) <= first_after
    # a frame forwarded at the end of the strip pins it
    votes = np.append(tied, before.size - 1), np.append(votes[1], False)
    assert before.size - 1 < split_index(t, step, places, votes=votes) <= first_after
