"""The GPS receiver emulator with `gps.receiver = "novatel_oem7"`: NovAtel ASCII logs on its port,
a TIMEA after every pulse naming that pulse's second, a MARK1TIMEA for every accepted event,
a BESTPOSA for every fix epoch whose position is the one the default receiver's GGA states;
the scenario's serial load counts the longest logs we write."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from acquisition.codec import ErrorPolicy
from acquisition.nmea import Gga, NmeaStreamDecoder
from acquisition.novatel import (
    BestPos,
    MarkTime,
    NmeaNovatelStreamDecoder,
    PositionType,
    SolutionStatus,
    TimeLog,
    TimeStatus,
    encode_log,
    header_from_gps_ns,
    mark1time_from_gps_ns,
    time_for_pps,
)
from acquisition.pulses import Edge, PulseLine
from acquisition.runner import NOVATEL_QUALITY
from emulators.faults import fault_table
from emulators.gps import GpsReceiver
from emulators.runtime import Output, Port, Runner
from emulators.scenario import (
    BESTPOS_BYTES,
    MARK_BYTES,
    TIME_LOG_BYTES,
    gps_event_rate_hz,
    gps_serial_load,
    scenario_from_table,
)
from emulators.trajectory import TruthTrajectory
from emulators.truth import read_truth_csv
from sisa.core.timescale import NS_PER_S, NS_PER_WEEK
from tests.emulators.test_gps import EventSource, _run
from tests.emulators.test_gps_ublox import _events

NOVATEL = {"gps": {"receiver": "novatel_oem7"}}


def test_novatel_stream_has_a_time_log_after_every_pulse_and_a_mark_per_event() -> None:
    good, too_soon = _events(NOVATEL)
    _, _, gps, stream, edges = _run(NOVATEL, sorted(good + too_soon))
    decoder = NmeaNovatelStreamDecoder(ErrorPolicy.RAISE)
    msgs = [d.message for d in decoder.feed(stream)]
    assert decoder.stats.errors == 0
    assert not stream.count(b"$")  # NovAtel logs only
    seconds = gps.pps.column("t_second_gps_ns")
    times = [m for m in msgs if isinstance(m, TimeLog)]
    assert [m.pps_gps_ns for m in times] == list(seconds)
    assert {m.header.time_status for m in times} == {TimeStatus.FINESTEERING}
    assert [e.t_ns for e in edges] == list(gps.pps.column("t_edge_gps_ns"))
    marks = [m for m in msgs if isinstance(m, MarkTime)]
    assert len(marks) == len(good)
    err = np.array([m.gps_ns for m in marks]) - np.array(good)
    assert np.all(np.abs(err) <= 50)  # the scenario's 100 ns tag resolution, rounded
    assert [m.gps_ns for m in marks] == list(
        gps.events.column("ttt_gps_ns")[gps.events.column("accepted") == 1])
    fixes = [m for m in msgs if isinstance(m, BestPos)]
    assert len(fixes) == len(gps.fixes.column("t_gps_ns"))
    assert {(m.solution_status, m.position_type) for m in fixes} == {
        (SolutionStatus.SOL_COMPUTED, PositionType.NARROW_INT)}


def test_bestpos_states_the_position_the_default_receivers_gga_states() -> None:
    _, _, _, novatel, _ = _run(NOVATEL)
    _, _, _, ashtech, _ = _run({})
    pos = [m for d in NmeaNovatelStreamDecoder(ErrorPolicy.RAISE).feed(novatel)
           if isinstance(m := d.message, BestPos)]
    gga = [m for d in NmeaStreamDecoder(ErrorPolicy.RAISE).feed(ashtech)
           if isinstance(m := d.message, Gga)]
    assert len(pos) == len(gga) > 10
    for p, g in zip(pos, gga, strict=True):
        assert abs(p.lat_deg - g.lat_deg) < 1e-8  # GGA: 7 decimals of minutes
        assert abs(p.lon_deg - g.lon_deg) < 1e-8
        assert abs(p.height_ellipsoidal_m - g.height_ellipsoidal_m) < 2e-3


def test_log_times_follow_the_pulses_and_epochs_with_the_receivers_latencies() -> None:
    """TIME 25 ms after its pulse, MARK1TIME 30 ms after its event, BESTPOS the scenario's
    latency after its epoch (no later than the serial port lets them out)."""
    scn = scenario_from_table({"base": "bench", **NOVATEL})
    good, _ = _events(NOVATEL)
    traj = TruthTrajectory.from_scenario(scn)
    gps = GpsReceiver(scn, traj, np.random.default_rng(7), fault_table())
    sent: list[tuple[int, bytes]] = []

    def sink(out: Output) -> list[Edge]:
        if out.port is Port.GPS_SERIAL:
            sent.append((out.t_ns, out.payload))
            return []
        return [out.payload] if out.payload.line is PulseLine.GPS_EVENT else []

    Runner([gps, EventSource(good[:20])], sink).run()
    latency = round(scn.gps.nmea_latency_ms * 1e6)
    for t, raw in sent:
        (item,) = NmeaNovatelStreamDecoder(ErrorPolicy.RAISE).feed(raw)
        m = item.message
        if isinstance(m, TimeLog):
            assert 25_000_000 <= t - m.header.gps_ns < 40_000_000
        elif isinstance(m, MarkTime):
            assert 30_000_000 - 100 <= t - m.gps_ns < 45_000_000
        elif isinstance(m, BestPos):
            assert latency <= t - m.header.gps_ns < latency + 15_000_000


def test_the_longest_logs_fit_the_scenarios_byte_counts() -> None:
    t = 2500 * NS_PER_WEEK - 1_000_000  # seconds of week with every digit
    pos = BestPos(header_from_gps_ns("BESTPOS", t), SolutionStatus.INSUFFICIENT_OBS,
                  PositionType.PPP_BASIC_CONVERGING, -89.12345678901, -179.12345678901,
                  -9999.1234, -119.1234, "WGS84", 99.1234, 99.1234, 99.1234, "0", 999.123,
                  999.123, 255, 255, 255, 255, 255, 255, 255, 255)
    pos = dataclasses.replace(pos, header=dataclasses.replace(pos.header, sequence=65535,
                                                              idle_pct=100.0))
    assert len(encode_log(pos)) <= BESTPOS_BYTES
    time = dataclasses.replace(time_for_pps(t // NS_PER_S * NS_PER_S, 1e-6, 18),
                               offset_s=-1.123456789e-07)
    assert len(encode_log(time)) <= TIME_LOG_BYTES
    mark = dataclasses.replace(mark1time_from_gps_ns(t, 1e-6, 18), offset_s=-1.123456789e-07)
    assert len(encode_log(mark)) <= MARK_BYTES


def test_the_serial_load_counts_the_logs() -> None:
    """The load `sisa scenario show` gives bounds what the port sent (a mark a second here)."""
    good, _ = _events(NOVATEL)
    scn, traj, _, stream, _ = _run(NOVATEL, good)
    per_s, load = gps_serial_load(scn)
    span_s = (traj.t_end_ns - traj.t_start_ns) / NS_PER_S
    assert len(stream) / span_s <= per_s
    assert per_s == pytest.approx(scn.gps.nmea_rate_hz * BESTPOS_BYTES + TIME_LOG_BYTES
                                  + gps_event_rate_hz(scn) * MARK_BYTES)
    assert load < 0.7


def test_an_outage_sends_no_time_log_and_fixes_without_a_solution(tmp_path: Path) -> None:
    _, traj, gps, stream, _ = _run({**NOVATEL, "faults": {"pps_outages": [
        {"at_s": 100, "duration_s": 20}]}})
    msgs = [d.message for d in NmeaNovatelStreamDecoder(ErrorPolicy.RAISE).feed(stream)]
    fixes = [m for m in msgs if isinstance(m, BestPos)]
    table = read_truth_csv(gps.fixes.write_csv(tmp_path))
    assert [m.header.gps_ns for m in fixes] == table["t_gps_ns"].tolist()
    # the acquisition's quality of each BESTPOS is the truth's (GGA's) quality of that fix
    ours = [int(NOVATEL_QUALITY[m.position_type]) if m.solution_status
            is SolutionStatus.SOL_COMPUTED else 0 for m in fixes]
    assert ours == table["quality"].tolist()
    lost = [m for m in fixes if m.solution_status is SolutionStatus.INSUFFICIENT_OBS]
    assert 15 <= len(lost) <= 21
    assert {m.position_type for m in lost} == {PositionType.NONE}
    seconds = [m.pps_gps_ns for m in msgs if isinstance(m, TimeLog)]
    assert seconds == gps.pps.column("t_second_gps_ns").tolist()
    start = traj.t_start_ns
    assert len([s for s in seconds if start + 100 * NS_PER_S <= s < start + 120 * NS_PER_S]) <= 1
    assert not [s for s in seconds if start + 101 * NS_PER_S <= s < start + 119 * NS_PER_S]
