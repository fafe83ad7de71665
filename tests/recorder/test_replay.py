"""The pure part of replay: the timing board inverted, the schedule (order, CAN frames, ranges,
split and cut files), the survey, and the pacing, pause and loop arithmetic."""

from __future__ import annotations

import shutil

import pytest
from hypothesis import given
from hypothesis import strategies as st
from mcap.writer import Writer

from acquisition.clocks import TimingBoard
from recorder.messages import (
    CAN_EXTENDED_FLAG,
    GpsFix,
    GpsTimeTag,
    PulseEdgeLog,
    RawBytes,
    RawCanFrames,
    SyncPps,
    Topic,
)
from recorder.replay import (
    BoardModel,
    CanFrame,
    EdgeTimeline,
    GpsClock,
    LoopEdges,
    PlayClock,
    RecordedEdge,
    ScheduleStats,
    Wire,
    anchor_from_pps,
    iter_schedule,
    survey_log,
)
from recorder.writer import FlightRecorder, split_parts
from sisa.core.errors import InputError
from tests.recorder import T0_NS

MS = 1_000_000
S = 1_000_000_000
GPS0_NS = 1_465_549_200 * S  # a whole GPS second


# --- the timing board -----------------------------------------------------------------------------

@given(st.integers(min_value=-(10**12), max_value=10**16))
def test_elapsed_inverts_the_recorders_timing_board(dt_ns):
    board = TimingBoard()
    board.counter_ns(0)  # first edge at 0
    count = board.counter_ns(dt_ns)
    assert BoardModel().elapsed_ns(count) == dt_ns


@given(st.integers(min_value=0, max_value=10**15),
       st.floats(min_value=-500.0, max_value=500.0, allow_nan=False))
def test_a_board_fed_the_edge_times_logs_the_recorded_counts_again(t_ns, drift_ppm):
    model = BoardModel(drift_ppm=drift_ppm, start_count_ns=5 * S)
    original = TimingBoard(drift_ppm=drift_ppm, start_count_ns=5 * S)
    t_first = GPS0_NS + 123_456_789
    original.counter_ns(t_first)
    recorded = original.counter_ns(t_first + t_ns)
    timeline = EdgeTimeline(model, anchor_ns=777)
    replayed = TimingBoard(drift_ppm=drift_ppm, start_count_ns=5 * S)
    replayed.counter_ns(timeline.t_edge_ns(5 * S))
    assert replayed.counter_ns(timeline.t_edge_ns(recorded)) == recorded


def test_a_count_the_board_cannot_give_maps_to_the_nearest():
    model = BoardModel(drift_ppm=2_000_000.0, start_count_ns=10)  # counts 10, 13, 16, ...
    assert [model.elapsed_ns(c) for c in range(10, 20)] == [0, 0, 1, 1, 1, 2, 2, 2, 3, 3]


def test_elapsed_is_exact_where_float_division_is_not():
    model = BoardModel()
    for dt in range(2**60, 2**60 + 2000, 7):  # float64 resolves 256 ns here
        assert model.elapsed_ns(model.count_ns(dt)) == dt


def test_anchor_is_the_median_offset_and_stays_an_integer():
    model = BoardModel()
    t_first = GPS0_NS + 400 * MS + 1
    board = TimingBoard()
    board.counter_ns(t_first)
    pps = [(board.counter_ns(GPS0_NS + k * S + jitter), GPS0_NS + k * S)
           for k, jitter in zip(range(1, 8), (20, -30, 10, 0, -10, 5, 10**9), strict=True)]
    anchor = anchor_from_pps(model, pps)
    assert isinstance(anchor, int)
    assert anchor == t_first - 5  # median jitter of 20, −30, 10, 0, −10, 5 and one wrong second
    assert anchor_from_pps(model, []) is None


# --- the schedule ---------------------------------------------------------------------------------

def _can(t_ns, offsets, ids, frames):
    return RawCanFrames(t_ns, offsets, ids, [len(f) for f in frames], b"".join(frames))


def _write_flight(path, **kwargs):
    """GPS and scanner bytes, a CAN batch written late (as the recorder does), edges."""
    with FlightRecorder(path, **kwargs) as rec:
        rec.write(PulseEdgeLog(T0_NS, "PPS", 1_000_000_000, 0), Topic.PULSE_IN)
        rec.write(RawBytes(T0_NS + 2 * MS, "gps", b"$GPGGA,1*00\r\n"), Topic.GPS_RAW)
        rec.write(RawBytes(T0_NS + 40 * MS, "scanner", b"\xa5\x5a\x0d"), Topic.SCANNER_RAW)
        rec.write(_can(T0_NS + 1 * MS, [0, 3 * MS, 60 * MS],
                       [0x100, 0x1ABCDE | CAN_EXTENDED_FLAG, 0x106],
                       [b"\x01\x02", b"", b"\xff" * 8]))
        rec.write(RawBytes(T0_NS + 70 * MS, "gps", b"$PASHR,PTT*00\r\n"), Topic.GPS_RAW)
        rec.write(PulseEdgeLog(T0_NS + 80 * MS, "PPF", 1_080_000_960, 7), Topic.PULSE_IN)
        rec.write(PulseEdgeLog(T0_NS + 90 * MS, "INS_SYNC", 1_090_000_000, 0), Topic.PULSE_OUT)
    return path


def test_schedule_is_in_log_time_order_with_every_can_frame_at_its_own_time(tmp_path):
    items = list(iter_schedule(_write_flight(tmp_path / "f.mcap")))
    assert [(i.t_log_ns - T0_NS) // MS for i in items] == [0, 1, 2, 4, 40, 61, 70, 80]
    assert [i.wire for i in items] == [Wire.PULSES, Wire.INS, Wire.GPS, Wire.INS, Wire.SCANNER,
                                       Wire.INS, Wire.GPS, Wire.PULSES]
    frames = [i.payload for i in items if i.wire is Wire.INS]
    assert frames == [CanFrame(0x100, False, b"\x01\x02"), CanFrame(0x1ABCDE, True, b""),
                      CanFrame(0x106, False, b"\xff" * 8)]
    assert items[-1].payload == RecordedEdge("PPF", 7, 1_080_000_960)
    assert items[2].payload == b"$GPGGA,1*00\r\n"  # /pulses/out is not an input: not replayed


def test_schedule_range_keeps_whole_items_inside_it(tmp_path):
    path = _write_flight(tmp_path / "f.mcap")
    stats = ScheduleStats()
    items = list(iter_schedule(path, T0_NS + 2 * MS, T0_NS + 61 * MS, stats))
    assert [(i.t_log_ns - T0_NS) // MS for i in items] == [2, 4, 40, 61]
    assert stats.items == 4


def test_schedule_reads_every_part_of_a_split_recording(tmp_path):
    path = tmp_path / "split.mcap"
    with FlightRecorder(path, split_duration_s=1.0, chunk_size=1024) as rec:
        for k in range(50):
            rec.write(RawBytes(T0_NS + k * 100 * MS, "gps", bytes([k])), Topic.GPS_RAW)
    parts = split_parts(path)
    assert len(parts) >= 4
    items = list(iter_schedule(parts))
    assert b"".join(i.payload for i in items) == bytes(range(50))
    assert survey_log(parts).counts[Wire.GPS] == 50


def test_schedule_of_a_cut_file_is_what_its_complete_chunks_hold(tmp_path):
    path = tmp_path / "whole.mcap"
    with FlightRecorder(path, chunk_size=1024) as rec:
        for k in range(1000):
            rec.write(RawBytes(T0_NS + k * MS, "scanner", k.to_bytes(2, "little") * 8),
                      Topic.SCANNER_RAW)
    cut = tmp_path / "cut.mcap"
    data = path.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    items = list(iter_schedule(cut))
    assert 100 < len(items) < 1000
    assert [i.payload for i in items] == [k.to_bytes(2, "little") * 8 for k in range(len(items))]
    assert survey_log(cut).stats.truncated


def test_schedule_skips_and_counts_raw_messages_of_another_schema(tmp_path):
    path = tmp_path / "foreign.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start()
        schema = w.register_schema("x", "jsonschema", b"{}")
        ch = w.register_channel(str(Topic.GPS_RAW), "json", schema)
        w.add_message(ch, T0_NS, b'{"data": "not base64!"}', T0_NS)
        w.add_message(ch, T0_NS + 1, b'{"t_host_ns": 1, "port": "gps", "data": "AAE="}',
                      T0_NS + 1)
        w.add_message(ch, T0_NS + 2, b"[1, 2]", T0_NS + 2)
        w.finish()
    stats = ScheduleStats()
    items = list(iter_schedule(path, stats=stats))
    assert [i.payload for i in items] == [b"\x00\x01"]
    assert stats.undecodable == 2


def test_survey_spans_anchor_pairs_and_refusal(tmp_path):
    path = tmp_path / "s.mcap"
    with FlightRecorder(path) as rec:
        rec.write(RawBytes(T0_NS, "gps", b"x"), Topic.GPS_RAW)
        rec.write(PulseEdgeLog(T0_NS + 5 * MS, "PPS", 1_000_000_000, 0), Topic.PULSE_IN)
        rec.write(SyncPps(T0_NS + 6 * MS, 0, 1_000_000_000, GPS0_NS, 1, 1, 1, True))
        rec.write(SyncPps(T0_NS + 7 * MS, 0, 1_500_000_000, GPS0_NS, 1, -1, -1, False))  # spurious
        rec.write(SyncPps(T0_NS + 8 * MS, 0, 2_000_000_012, -1, 1, 2, 0, False))  # no PTT
        rec.write(GpsTimeTag(T0_NS + 30 * MS, "PTT", 5 * S, GPS0_NS))
        rec.write(GpsFix(T0_NS + 50 * MS, GPS0_NS + 10 * MS, 41.0, 2.0, 600.0, 4, 9, 0.8))
        rec.write(RawBytes(T0_NS + 900 * MS, "scanner", b"y"), Topic.SCANNER_RAW)
    survey = survey_log(path)
    assert (survey.start_ns, survey.end_ns) == (T0_NS, T0_NS + 900 * MS)
    assert survey.pps == [(1_000_000_000, GPS0_NS)]
    assert survey.first_edge == (T0_NS + 5 * MS, 1_000_000_000)
    assert survey.gps_pairs == [(T0_NS + 30 * MS, GPS0_NS), (T0_NS + 50 * MS, GPS0_NS + 10 * MS)]
    assert survey.timeline(BoardModel()).t_edge_ns(1_000_000_000) == GPS0_NS
    empty = tmp_path / "empty.mcap"
    with FlightRecorder(empty) as rec:
        rec.write(GpsFix(T0_NS, GPS0_NS, 41.0, 2.0, 600.0, 4, 9, 0.8))
    with pytest.raises(InputError, match="no raw channel to replay"):
        survey_log(empty)


def test_without_pps_seconds_the_edges_are_anchored_at_the_first_edges_host_time(tmp_path):
    path = tmp_path / "nopps.mcap"
    with FlightRecorder(path) as rec:
        rec.write(PulseEdgeLog(T0_NS + 5 * MS, "PPF", 1_000_000_000, 0), Topic.PULSE_IN)
        rec.write(PulseEdgeLog(T0_NS + 21 * MS, "PPF", 1_016_000_192, 1), Topic.PULSE_IN)
    timeline = survey_log(path).timeline(BoardModel())
    assert timeline.t_edge_ns(1_000_000_000) == T0_NS + 5 * MS
    assert timeline.t_edge_ns(1_016_000_192) == T0_NS + 5 * MS + 16 * MS


def test_the_files_are_left_as_they_were(tmp_path):
    path = _write_flight(tmp_path / "f.mcap")
    before = path.read_bytes()
    copy = shutil.copy(path, tmp_path / "copy.mcap")
    list(iter_schedule(path))
    survey_log(path)
    assert path.read_bytes() == before == copy.read_bytes()


# --- pacing, pause, loops -------------------------------------------------------------------------

def test_play_clock_paces_at_the_rate():
    clock = PlayClock(2.0, t_log0_ns=T0_NS, wall0_ns=1_000)
    assert clock.due_wall_ns(T0_NS) == 1_000
    assert clock.due_wall_ns(T0_NS + 3 * S) == 1_000 + 1_500 * MS
    assert clock.log_now_ns(1_000 + 500 * MS) == T0_NS + S
    with pytest.raises(ValueError, match="positive"):
        PlayClock(0.0, 0, 0)


def test_pause_freezes_the_log_and_resume_delays_everything_by_the_pause():
    clock = PlayClock(1.0, t_log0_ns=T0_NS, wall0_ns=0)
    clock.toggle(2 * S)
    assert clock.paused
    assert clock.due_wall_ns(T0_NS + 3 * S) is None
    assert clock.log_now_ns(7 * S) == T0_NS + 2 * S  # frozen
    clock.toggle(9 * S)  # paused for 7 s
    assert not clock.paused
    assert clock.due_wall_ns(T0_NS + 3 * S) == 10 * S
    assert clock.log_now_ns(9 * S) == T0_NS + 2 * S  # resumes where it stopped: no burst
    clock.pause(10 * S)
    clock.pause(11 * S)  # a second pause does not move the pause start
    clock.resume(12 * S)
    assert clock.due_wall_ns(T0_NS + 3 * S) == 12 * S


def test_restart_plays_a_new_pass_from_its_first_item():
    clock = PlayClock(1.0, t_log0_ns=T0_NS, wall0_ns=0)
    clock.restart(T0_NS, 100 * S)
    assert clock.due_wall_ns(T0_NS + S) == 101 * S


def test_loop_passes_move_edges_forward_and_keep_numbering():
    loop = LoopEdges(period_ns=60 * S)
    first = [loop.edge(RecordedEdge("PPS", seq, 0), GPS0_NS + seq * S) for seq in (4, 5, 7)]
    assert first == [(4, GPS0_NS + 4 * S), (5, GPS0_NS + 5 * S), (7, GPS0_NS + 7 * S)]
    ppf = loop.edge(RecordedEdge("PPF", 10, 0), GPS0_NS)
    assert ppf == (10, GPS0_NS)
    loop.next_pass()
    assert loop.edge(RecordedEdge("PPS", 4, 0), GPS0_NS + 4 * S) == (8, GPS0_NS + 64 * S)
    assert loop.edge(RecordedEdge("PPF", 10, 0), GPS0_NS) == (11, GPS0_NS + 60 * S)
    loop.next_pass()
    assert loop.edge(RecordedEdge("PPS", 4, 0), GPS0_NS) == (9, GPS0_NS + 120 * S)


def test_gps_clock_carries_the_last_pair_forward():
    clock = GpsClock([(100, GPS0_NS), (1_100, GPS0_NS + 1_000)])
    assert clock.gps_ns(600) == GPS0_NS + 500
    assert clock.gps_ns(5_100) == GPS0_NS + 5_000
    assert clock.gps_ns(50) == GPS0_NS - 50  # before the first pair: from the first
    assert GpsClock([]).gps_ns(0) is None


@pytest.mark.parametrize(("start_s", "duration_s", "span_ns"), [
    (0.0, None, (0, 60 * 10**9, False)),
    (10.0, 1e308, (10 * 10**9, 60 * 10**9, True)),  # was an OverflowError traceback
    (60.0, 5.0, (60 * 10**9, 60 * 10**9, True)),
    (59.5, 0.25, (59_500_000_000, 59_750_000_000, True)),
])
def test_the_span_to_play_is_clamped_to_the_log_in_seconds(start_s, duration_s, span_ns):
    """--start and --duration are compared with the log's length in seconds before they become
    nanoseconds (1e308 s has no int64 nanoseconds; found by a bad-input sweep)."""
    import argparse

    from recorder.replay import Survey
    from sisa.commands.replay import _span

    survey = Survey(first_ns={"gps": T0_NS}, last_ns={"gps": T0_NS + 60 * 10**9})
    got = _span(argparse.Namespace(start=start_s, duration=duration_s), survey)
    assert (got.from_ns - T0_NS, got.until_ns - T0_NS, got.limited) == span_ns
    with pytest.raises(InputError, match=r"--start 1e\+308 s is beyond the end of the log "
                                         r"\(60\.0 s\)"):
        _span(argparse.Namespace(start=1e308, duration=None), survey)
