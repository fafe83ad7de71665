"""The tolerant reader: cut files, damaged chunks, unknown records, huge lengths, columns, stats;
and an independent reader (@mcap/core under node) that must count what the Python reader counts."""

import math
import struct
import warnings
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from recorder.columns import read_columns
from recorder.messages import GpsFix, InsRecordLog, PulseEdgeLog, RawBytes, Topic
from recorder.reader import LogReader, read_log, scan_log
from recorder.stats import DamagedLogWarning
from recorder.writer import FlightRecorder, split_parts
from sisa.cli import main
from sisa.core.errors import InputError
from tests.recorder import T0_NS, sample_messages, write_sample_log
from tests.recorder.crash_child import kill_many

JS_DIR = Path(__file__).resolve().parent / "js"


def _ins(i, t_ns=None):
    t = T0_NS + i * 10_000_000 if t_ns is None else t_ns
    return InsRecordLog(t, i, i * 100_000, 0.01, -0.02, 1.5, 1e-4, 2e-4, -3e-4, 60.0, 1.0, -0.5, 0,
                        False, 0)


def _flight(path, n=3000, **kwargs):
    """n INS records at 100 Hz, a GpsFix every 10th, scanner bytes every 5th."""
    with FlightRecorder(path, chunk_size=4096, **kwargs) as rec:
        for i in range(n):
            rec.write(_ins(i))
            if i % 10 == 0:
                rec.write(GpsFix(T0_NS + i * 10_000_000, 10**18 + i, 41.0, 2.0, 600.0, 1, 8, 0.9))
            if i % 5 == 0:
                rec.write(RawBytes(T0_NS + i * 10_000_000, "scanner", bytes([i % 256]) * 20),
                          Topic.SCANNER_RAW)
    return path


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    return _flight(tmp_path_factory.mktemp("flight") / "flight.mcap")


def _keys(path):
    return [(topic, t, obj.get("counter", obj.get("t_gps_ns"))) for topic, t, obj in read_log(path)]


# --- truncation and damage ----------------------------------------------------------------------

def test_every_cut_reads_a_prefix_of_the_messages(flight, tmp_path):
    full = _keys(flight)
    data = flight.read_bytes()
    cut = tmp_path / "cut.mcap"
    previous = 0
    for size in np.linspace(8, len(data), 97).astype(int):
        cut.unlink(missing_ok=True)
        cut.write_bytes(data[:size])
        got = _keys(cut)
        assert got == full[:len(got)]
        assert len(got) >= previous
        previous = len(got)
        stats = scan_log(cut)
        assert stats.truncated == (size < len(data))
    assert previous == len(full)


def test_a_truncated_file_says_so_and_counts_its_chunks(flight, tmp_path):
    data = flight.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:len(data) // 2 + 3])
    fs = scan_log(cut).files[0]
    assert fs.truncated
    assert not fs.has_summary
    assert fs.chunks_read > 10
    assert 0 < fs.bytes_unreadable < 8192


def _chunk_offsets(data):
    """Offsets of top-level Chunk records (opcode 0x06), walking the record framing."""
    pos, out = 8, []
    while pos + 9 <= len(data):
        opcode, length = struct.unpack_from("<BQ", data, pos)
        if opcode == 0x06:
            out.append(pos)
        if opcode == 0x02:
            break
        pos += 9 + length
    return out


def test_a_damaged_chunk_is_skipped_and_its_messages_counted_as_lost(flight, tmp_path):
    data = bytearray(flight.read_bytes())
    victim = _chunk_offsets(data)[5]
    data[victim + 9 + 40 + 60] ^= 0xFF  # a byte inside the chunk's records: CRC mismatch
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    full, stats = scan_log(flight), scan_log(bad)
    fs = stats.files[0]
    assert fs.chunks_skipped == 1
    assert fs.complete
    assert "crc" in fs.problems[0].lower()
    lost = full.messages - stats.messages
    assert lost > 0
    assert sum(t.lost_by_sequence for t in stats.topics.values()) == lost


def test_columns_of_a_cut_or_damaged_log_come_with_a_warning_that_names_the_file(flight,
                                                                                 tmp_path):
    data = bytearray(flight.read_bytes())
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(bytes(data[:len(data) // 2 + 3]))
    with pytest.warns(DamagedLogWarning, match=rf"^{cut}: cut short .* the last \d+ bytes "
                      "unreadable$"):
        assert read_columns(cut, Topic.INS_RECORD)["counter"].size > 0
    data[_chunk_offsets(data)[5] + 9 + 40 + 60] ^= 0xFF
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    with pytest.warns(DamagedLogWarning, match=rf"^{bad}: 1 damaged chunk skipped \(\d+ bytes\): "
                      "the messages in it are missing"):
        read_columns(bad, Topic.INS_RECORD)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DamagedLogWarning)  # a sound log: nothing to say
        read_columns(flight, Topic.INS_RECORD)


def test_unknown_records_are_skipped(flight, tmp_path):
    data = flight.read_bytes()
    first_chunk = _chunk_offsets(data)[0]
    unknown = struct.pack("<BQ", 0x81, 5) + b"hello"
    odd = tmp_path / "odd.mcap"
    odd.write_bytes(data[:first_chunk] + unknown + data[first_chunk:])
    assert scan_log(odd).messages == scan_log(flight).messages


def test_a_huge_record_length_is_skipped_without_allocating_it(flight, tmp_path):
    data = bytearray(flight.read_bytes())
    chunks = _chunk_offsets(data)
    struct.pack_into("<Q", data, chunks[3] + 1, 2**62)
    bad = tmp_path / "huge.mcap"
    bad.write_bytes(bytes(data))
    fs = scan_log(bad).files[0]
    assert fs.chunks_read == len(chunks) - 1  # read on at the next chunk (test_reader_damage)
    assert fs.chunks_skipped == 1
    assert "exceeds limit" in fs.problems[0]
    assert fs.complete


def test_a_huge_length_inside_a_chunk_header_is_refused_too(flight, tmp_path):
    data = bytearray(flight.read_bytes())
    victim = _chunk_offsets(data)[4]
    (compression_len,) = struct.unpack_from("<I", data, victim + 9 + 28)
    struct.pack_into("<Q", data, victim + 9 + 32 + compression_len, 2**62)  # records length
    bad = tmp_path / "huge2.mcap"
    bad.write_bytes(bytes(data))
    fs = scan_log(bad).files[0]
    assert fs.chunks_read == len(_chunk_offsets(data)) - 1  # that chunk alone is lost
    assert fs.chunks_skipped == 1
    assert "exceeds the limit" in fs.problems[0]


def test_garbage_after_the_magic_reads_as_nothing(tmp_path):
    rng = np.random.default_rng(5)
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"\x89MCAP0\r\n" + rng.bytes(50_000))
    stats = scan_log(junk)
    assert stats.messages == 0
    assert stats.truncated


@pytest.mark.parametrize(("content", "match"), [(None, "no such file"), (b"", "empty"),
                                                (b"PK\x03\x04 a zip", "not an MCAP file")])
def test_what_is_not_an_mcap_file_is_an_input_error(tmp_path, content, match):
    path = tmp_path / "x.mcap"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(InputError, match=match):
        LogReader(path)


# --- statistics and columns ---------------------------------------------------------------------

def test_stats_find_the_gap_and_the_rates(tmp_path):
    path = tmp_path / "gap.mcap"
    with FlightRecorder(path) as rec:
        for i in [*range(0, 500), *range(530, 1000)]:  # 0.3 s missing at 100 Hz
            rec.write(_ins(i))
    stats = scan_log(path)
    ins = stats.topics["/ins/record"]
    assert ins.count == 970
    assert ins.median_interval_ns == 10_000_000
    assert ins.gap_count == 1
    assert ins.gaps[0].start_ns == T0_NS + 499 * 10_000_000
    assert ins.gaps[0].duration_ns == 31 * 10_000_000
    assert ins.rate_hz == pytest.approx(969 / 9.99)
    assert ins.lost_by_sequence == 0  # the writer never saw them: a gap, not a loss



def test_a_topic_that_talks_in_bursts_has_gaps_only_where_it_went_quiet(tmp_path):
    """GPS sentences: 5 chunks 15 ms apart once a second for 30 s, then 3 s of nothing: the
    silence between bursts is its rhythm, the outage is its only gap."""
    path = tmp_path / "bursts.mcap"
    seconds = [*range(0, 12), *range(15, 30)]
    with FlightRecorder(path) as rec:
        for sec in seconds:
            for k in range(5):
                t = T0_NS + sec * 1_000_000_000 + k * 15_000_000
                rec.write(RawBytes(t, "gps", b"$GPZDA*00\r\n"), Topic.GPS_RAW)
    gps = scan_log(path).topics["/gps/raw"]
    assert gps.median_interval_ns == 15_000_000
    assert gps.usual_interval_ns == 940_000_000
    assert gps.gap_count == 1
    assert gps.gaps[0].start_ns == T0_NS + 11 * 1_000_000_000 + 60_000_000
    assert gps.gaps[0].duration_ns == 3_940_000_000
    short = tmp_path / "short.mcap"  # 4 s of it (a recording killed early): no gap at all
    with FlightRecorder(short) as rec:
        for sec in range(4):
            for k in range(5):
                t = T0_NS + sec * 1_000_000_000 + k * 15_000_000
                rec.write(RawBytes(t, "gps", b"$GPZDA*00\r\n"), Topic.GPS_RAW)
    assert scan_log(short).topics["/gps/raw"].gap_count == 0


def test_a_topic_whose_rhythm_changes_is_judged_by_the_rhythm_it_has_then(tmp_path):
    """Pulse edges: the PPS alone for 40 s, frame pulses at 20 Hz besides for 120 s (the
    scanner recording), the PPS alone again with a 3 s outage: only the outage is a gap (the
    median, 50 ms, or the flight's overall rhythm would call every PPS-only second one).
    Forwarded pulses are not judged at all."""
    path = tmp_path / "pulses.mcap"
    pps = [s for s in range(200) if not 170 <= s < 173]
    ppf = [40.0 + k / 20 for k in range(1, 2400)]
    edges = sorted([(s * 1.0, "PPS") for s in pps] + [(t, "PPF") for t in ppf])
    with FlightRecorder(path) as rec:
        for k, (t_s, line) in enumerate(edges):
            t = T0_NS + round(t_s * 1e9)
            rec.write(PulseEdgeLog(t, line, t, k), Topic.PULSE_IN)
            if line == "PPS" and k % 3:
                rec.write(PulseEdgeLog(t, "INS_SYNC", t, k), Topic.PULSE_OUT)
    stats = scan_log(path).topics
    edges_in = stats["/pulses/in"]
    assert edges_in.median_interval_ns == 50_000_000
    assert edges_in.gap_count == 1
    assert edges_in.gaps[0].start_ns == T0_NS + 169 * 1_000_000_000
    assert edges_in.gaps[0].usual_ns == 1_000_000_000
    assert stats["/pulses/out"].gap_count is None

def test_columns_are_numpy_arrays_of_the_declared_types(flight):
    cols = read_columns(flight, Topic.INS_RECORD)
    assert cols["counter"].dtype == np.int64
    assert np.array_equal(cols["counter"], np.arange(3000))
    assert np.array_equal(cols["log_time_ns"], T0_NS + np.arange(3000) * 10_000_000)
    assert cols["roll_rad"].dtype == np.float64
    assert cols["sync_flag"].dtype == np.bool_
    raw = read_columns(flight, Topic.SCANNER_RAW)
    assert raw["data"][1] == bytes([5]) * 20
    assert raw["port"].dtype.kind == "U"
    assert raw["port"][0] == "scanner"
    loc = read_columns(flight, Topic.GPS_LOCATION)
    assert loc["timestamp.sec"].dtype == np.int64
    assert len(loc["latitude"]) == 300


def test_columns_keep_nan_and_infinity(tmp_path):
    path = tmp_path / "nan.mcap"
    write_sample_log(path)
    cols = read_columns(path, Topic.INS_RECORD)
    assert math.isnan(cols["rate_y_rps"][0])
    assert cols["vel_e_mps"][0] == math.inf
    assert cols["vel_d_mps"][0] == -math.inf
    assert read_columns(path, Topic.SYNC_SESSION)["lfsr_taps"][0] == [4, 3]


def test_columns_of_an_absent_topic_are_empty_but_typed(flight):
    cols = read_columns(flight, Topic.SYNC_PPS)
    assert cols["gps_second_ns"].dtype == np.int64
    assert len(cols["gps_second_ns"]) == 0


# --- sisa log info ------------------------------------------------------------------------------

def test_log_info_on_a_truncated_file(flight, tmp_path, capsys):
    data = flight.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    chunks = scan_log(cut).files[0].chunks_read
    assert main(["log", "info", str(cut)]) == 0
    out = capsys.readouterr().out
    assert f"truncated (no summary): read {chunks} complete chunks" in out
    assert "/ins/record" in out
    assert "/gps/location_fix" in out


def test_log_info_json_says_what_the_text_says(flight, tmp_path, capsys):
    """--json for scripts: the same figures, times as int64 ns, counts as the reader's."""
    import json
    from collections import Counter

    data = flight.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    stats = scan_log(cut)
    assert main(["log", "info", "--json", "--gaps", "3", str(cut)]) == 0
    doc = json.loads(capsys.readouterr().out)
    (fs,) = doc["files"]
    assert (fs["complete"], fs["chunks_read"]) == (False, stats.files[0].chunks_read)
    assert fs["metadata"]["sisa.recording"]["recording_id"]
    read = Counter(topic for topic, _t, _obj in read_log(cut))
    assert {t: v["count"] for t, v in doc["topics"].items()} == dict(read)
    assert doc["messages"] == sum(read.values())
    assert isinstance(doc["start_ns"], int)
    assert doc["start_ns"] == min(v["first_ns"] for v in doc["topics"].values())
    assert len(doc["largest_gaps"]) <= 3
    assert doc["health"] == {"problems": [], "unreadable_reports": 0, "streams": {}}  # none


@pytest.mark.parametrize("content", [None, b"", b"not an mcap at all"])
def test_log_info_on_bad_input_is_one_line_and_exit_2(tmp_path, capsys, content):
    path = tmp_path / "x.mcap"
    if content is not None:
        path.write_bytes(content)
    assert main(["log", "info", str(path)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.count("\n") == 1
    assert "x.mcap" in captured.err


# --- the independent reader ---------------------------------------------------------------------

def _python_counts(paths):
    return Counter(topic for topic, _, _ in read_log(paths))


def test_node_reads_a_complete_file_like_python(node_reader, tmp_path):
    path = tmp_path / "all.mcap"
    with FlightRecorder(path) as rec:
        for k in range(50):
            for msg, topic in sample_messages(T0_NS + k * 10**6):
                rec.write(msg, topic)
    js = node_reader(path)
    assert js["stream"]["complete"]
    assert js["stream"]["error"] is None
    assert js["stream"]["invalid_json"] == 0  # NaN and infinities are valid JSON in the log
    assert js["stream"]["topics"] == dict(_python_counts(path))
    assert js["indexed"]["topics"] == js["stream"]["topics"]


def test_node_reads_each_part_of_a_split_set_like_python(node_reader, tmp_path):
    path = tmp_path / "split.mcap"
    with FlightRecorder(path, split_duration_s=8.0) as rec:
        for i in range(3000):
            rec.write(_ins(i))
            rec.write(PulseEdgeLog(T0_NS + i * 10_000_000, "PPF", i, i), Topic.PULSE_OUT)
    parts = split_parts(path)
    assert len(parts) == 4
    total: Counter[str] = Counter()
    for part in parts:
        js = node_reader(part)
        assert js["stream"]["complete"]
        assert js["indexed"]["topics"] == js["stream"]["topics"] == dict(_python_counts(part))
        total.update(js["stream"]["topics"])
    assert total == _python_counts(parts) == {"/ins/record": 3000, "/pulses/out": 3000}


def test_node_reads_a_killed_recording_like_python(node_reader, tmp_path):
    (killed,) = kill_many(tmp_path, [(1.3, 2000.0)])
    js = node_reader(killed.path)
    stats = scan_log(killed.path)
    assert not js["stream"]["complete"]
    assert stats.truncated
    assert js["stream"]["error"] is None
    assert js["stream"]["topics"] == dict(_python_counts(killed.path))
    assert js["stream"]["bytes_remaining"] == stats.files[0].bytes_unreadable
    assert int(js["stream"]["last_log_time_ns"]) == stats.end_ns
