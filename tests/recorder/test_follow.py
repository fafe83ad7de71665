"""Reading a log while it is written (recorder.follow, recorder.columns.GrowingColumns) and the
recorder's tap: what a live view sees must be what the file holds, and nothing a live view
does wrong may cost the log a message."""

from __future__ import annotations

import warnings

import numpy as np

from recorder.columns import GrowingColumns, read_topics
from recorder.follow import LogFollower
from recorder.messages import FrameHeaderLog, InsRecordLog, RawBytes, Topic
from recorder.reader import LogReader, read_log
from recorder.writer import FlightRecorder, split_parts
from tests.recorder import T0_NS, sample_messages

WANTED = {Topic.INS_RECORD: None, Topic.SCANNER_HEADER: None, Topic.GPS_RAW: None,
          Topic.GPS_FIX: None}


def _flight(path, n=3000, **options):
    """A log of INS records, frame headers and raw GPS bytes, several chunks long."""
    with FlightRecorder(path, chunk_size=8192, **options) as rec:
        for msg, topic in sample_messages():
            rec.write(msg, topic)
        for i in range(n):
            t = T0_NS + 1000 + i * 5_000_000
            rec.write(InsRecordLog(t, i % 65536, 10**7 + i * 50_000, 0.01, 0.02, 1.5, 0, 0, 0,
                                   60.0, 1.0, 0.0, 0, i % 64 == 0, i), None)
            if i % 4 == 0:
                rec.write(FrameHeaderLog(t + 1, i // 4, 48_000, 1, 0, 19), None)
            if i % 10 == 0:
                rec.write(RawBytes(t + 2, "gps", b"$GPZDA,%d\r\n" % i), Topic.GPS_RAW)
    return rec


def _same(a, b):
    assert a.keys() == b.keys()
    for topic in a:
        assert a[topic].keys() == b[topic].keys()
        for name in a[topic]:
            x, y = a[topic][name], b[topic][name]
            if x.dtype == object:
                assert list(x) == list(y), (topic, name)
            else:
                assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), (topic, name)


def test_a_growing_log_reads_at_every_moment_as_the_reader_reads_its_prefix(tmp_path):
    whole = tmp_path / "whole.mcap"
    _flight(whole)
    data = whole.read_bytes()
    growing = tmp_path / "growing.mcap"
    follower, cols = LogFollower(growing), GrowingColumns(WANTED)
    rng = np.random.default_rng(7)
    cuts = [*np.sort(rng.integers(1, len(data), 25)).tolist(), len(data)]
    with growing.open("wb") as fh:
        written = 0
        for cut in cuts:  # the file grows by uneven steps, ending anywhere inside a record
            fh.write(data[written:cut])
            fh.flush()
            written = cut
            for channel, msg in follower.poll():
                cols.add(channel, msg.log_time, msg.data)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the prefix is a log cut short: said, known
                _same(cols.columns(), read_topics(growing, WANTED))
    assert follower.stats.chunks_skipped == 0
    assert follower.stats.unreadable == 0
    assert follower.poll() == []  # nothing new: nothing again


def test_the_follower_moves_on_to_the_next_part(tmp_path):
    path = tmp_path / "flight.mcap"
    _flight(path, n=6000, split_size_bytes=150_000)
    parts = split_parts(path)
    assert len(parts) >= 3
    follower, cols = LogFollower(path), GrowingColumns(WANTED)
    for channel, msg in follower.poll():
        cols.add(channel, msg.log_time, msg.data)
    assert follower.stats.parts == len(parts)
    _same(cols.columns(), read_topics(parts, WANTED))


def test_a_damaged_chunk_is_passed_over_and_counted(tmp_path):
    path = tmp_path / "flight.mcap"
    _flight(path)
    data = bytearray(path.read_bytes())
    mid = len(data) // 2
    data[mid:mid + 64] = bytes(64)  # inside a chunk: its CRC fails
    path.write_bytes(bytes(data))
    follower = LogFollower(path)
    got = follower.poll()
    assert follower.stats.chunks_skipped + follower.stats.unreadable >= 1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        readable = list(LogReader(path).raw())
    assert [m.data for _, m in got] == [m.data for _, m in readable]  # what the reader keeps
    assert len(got) > 1000


def test_the_tap_sees_every_message_as_written_and_cannot_break_the_recording(tmp_path):
    seen = []

    def tap(topic, schema_name, msg, log_ns, data):
        seen.append((str(topic), log_ns, data))
        if len(seen) % 3 == 0:
            raise RuntimeError("a live view gone wrong")

    rec = _flight(tmp_path / "flight.mcap", n=500, tap=tap)
    in_file = [(t, log_ns, None) for t, log_ns, _ in read_log(tmp_path / "flight.mcap")]
    assert len(seen) == len(in_file) == rec.messages_written
    assert [(t, n) for t, n, _ in seen] == [(t, n) for t, n, _ in in_file]
    assert rec.tap_failures == len(seen) // 3
    follower = LogFollower(tmp_path / "flight.mcap")
    assert [m.data for _, m in follower.poll()] == [data for _, _, data in seen]
