"""The flight recorder as the rest of SISA uses it: channels and schemas, LocationFix, metadata,
never overwriting, splitting, timed flushes, and the documented topics."""

import base64
import dataclasses
import json
import math
import os
import re
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from recorder.messages import (
    LOGGED_TYPES,
    GpsFix,
    InsRecordLog,
    RawBytes,
    StreamHealth,
    Topic,
    json_schema,
)
from recorder.reader import read_log, read_messages, scan_log
from recorder.writer import (
    LOCATION_FIX_SCHEMA_NAME,
    RECORDER_ID,
    TOPIC_TYPES,
    FlightRecorder,
    encode_message,
    part_path,
    split_parts,
    topics_markdown,
)
from sisa.core.errors import ConfigError, EncodeError, InputError
from tests.recorder import T0_NS, sample_messages, write_sample_log

DOC = Path(__file__).resolve().parents[2] / "docs" / "flight-log.md"


def _write_samples(path, **kwargs):
    return write_sample_log(path, metadata={"scenario": "bench", "seed": 7}, **kwargs)


def test_every_topic_has_a_channel_with_its_json_schema(tmp_path):
    path = tmp_path / "f.mcap"
    _write_samples(path)
    with path.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    schemas = {s.id: s for s in summary.schemas.values()}
    by_topic = {c.topic: (c, schemas[c.schema_id]) for c in summary.channels.values()}
    assert set(by_topic) == {str(t) for t in Topic}
    for topic, (channel, schema) in by_topic.items():
        assert channel.message_encoding == "json"
        assert schema.encoding == "jsonschema"
        cls = TOPIC_TYPES.get(Topic(topic))
        if cls is None:
            assert schema.name == LOCATION_FIX_SCHEMA_NAME
        else:
            assert schema.name == cls.schema_name
            assert json.loads(schema.data) == json_schema(cls)


def test_each_schema_has_one_id_and_rides_with_each_channels_first_chunk(tmp_path):
    """Registered anew for each channel, `sisa.PulseEdge` and `sisa.RawBytes` were stored as
    two identical schemas under two ids each (issue 33, item 10). One id per schema; its record
    is written again (same id, same bytes) in the first chunk of every channel that uses it,
    so that a damaged chunk loses only its own messages."""
    from mcap.records import Channel, Schema
    from mcap.stream_reader import StreamReader

    path = tmp_path / "f.mcap"
    _write_samples(path)
    with path.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    names = [s.name for s in summary.schemas.values()]
    assert len(names) == len(set(names)), names
    shared = {s.id for s in summary.schemas.values()
              if sum(c.schema_id == s.id for c in summary.channels.values()) > 1}
    assert shared  # raw bytes of two ports, edges of two directions
    seen: dict[int, Schema] = {}
    with path.open("rb") as fh:
        for record in StreamReader(fh, skip_magic=False, emit_chunks=False).records:
            if isinstance(record, Schema):
                assert seen.setdefault(record.id, record) == record  # duplicates identical
            elif isinstance(record, Channel):
                assert record.schema_id in seen  # its schema came before it
    assert set(seen) == set(summary.schemas)


def test_every_schema_requires_what_every_message_holds(tmp_path):
    """Issue 33, item 10: foxglove.LocationFix's schema had no `required` list. (A schema shared
    by several topics is still written with each channel's first chunk: written once, a damaged
    chunk would take other chunks' channels with it; tests/fuzz/test_fuzz_files.py.)"""
    path = tmp_path / "f.mcap"
    _write_samples(path)
    with path.open("rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None
        seen: set[str] = set()
        for schema, _, message in reader.iter_messages(log_time_order=False):
            spec = json.loads(schema.data)
            obj = json.loads(message.data)
            assert set(spec["required"]) == set(obj) == set(spec["properties"]), schema.name
            seen.add(schema.name)
    assert LOCATION_FIX_SCHEMA_NAME in seen


def test_log_time_and_publish_time_are_the_host_time(tmp_path):
    path = tmp_path / "f.mcap"
    _write_samples(path)
    with path.open("rb") as fh:
        for _, channel, message in make_reader(fh).iter_messages(log_time_order=False):
            obj = json.loads(message.data)
            expected = obj.get("t_host_ns")
            if channel.topic == Topic.GPS_LOCATION:
                expected = obj["timestamp"]["sec"] * 10**9 + obj["timestamp"]["nsec"]
            assert message.log_time == message.publish_time == expected


def test_every_message_reads_back_equal_including_nan_and_bytes(tmp_path):
    path = tmp_path / "f.mcap"
    _write_samples(path)
    written = [msg for msg, _ in sample_messages()]
    for cls in LOGGED_TYPES:
        back = list(read_messages(path, cls))
        expected = [m for m in written if type(m) is cls]
        assert [repr(m) for m in back] == [repr(m) for m in expected]  # repr: nan == nan


def test_gps_fix_is_also_a_foxglove_location_fix(tmp_path):
    path = tmp_path / "f.mcap"
    with FlightRecorder(path) as rec:
        rec.write(GpsFix(T0_NS + 123, 10**18, 41.5, 2.25, 650.5, 1, 8, 0.9))
        rec.write(GpsFix(T0_NS + 200, 10**18, 0.0, 0.0, 0.0, 0, 0, 99.9))  # no fix: no map point
    fixes = [obj for topic, _, obj in read_log(path) if topic == Topic.GPS_LOCATION]
    assert fixes == [{"timestamp": {"sec": T0_NS // 10**9, "nsec": 123}, "frame_id": "gps_antenna",
                      "latitude": 41.5, "longitude": 2.25, "altitude": 650.5,
                      "position_covariance": [0.0] * 9, "position_covariance_type": 0}]


def test_metadata_holds_the_recorder_version_and_the_user_dict(tmp_path):
    path = tmp_path / "f.mcap"
    _write_samples(path)
    meta = scan_log(path).files[0].metadata["sisa.recording"]
    assert meta["recorder"] == RECORDER_ID
    assert meta["scenario"] == "bench"
    assert meta["seed"] == "7"


def test_a_message_on_a_topic_of_another_type_is_refused(tmp_path):
    with FlightRecorder(tmp_path / "f.mcap") as rec:
        with pytest.raises(EncodeError, match=r"does not carry sisa\.RawBytes"):
            rec.write(RawBytes(T0_NS, "gps", b"x"), Topic.GPS_FIX)
        with pytest.raises(EncodeError):
            rec.write(RawBytes(T0_NS, "gps", b"x"), Topic.GPS_LOCATION)
        rec.write(RawBytes(T0_NS, "scanner", b"x"), Topic.SCANNER_RAW)


def test_never_overwrites_a_recording_or_a_stale_part(tmp_path):
    path = tmp_path / "f.mcap"
    path.write_bytes(b"precious")
    with pytest.raises(InputError, match="already exists"):
        FlightRecorder(path)
    assert path.read_bytes() == b"precious"
    other = tmp_path / "g.mcap"
    part_path(other, 2).write_bytes(b"old part")
    with pytest.raises(InputError, match=r"g_002\.mcap already exists"):
        FlightRecorder(other)
    assert not other.exists()


@pytest.mark.parametrize("kwargs", [{"split_duration_s": 0}, {"split_size_bytes": 10},
                                    {"flush_interval_s": 0}, {"chunk_size": 10}])
def test_bad_settings_are_config_errors(tmp_path, kwargs):
    with pytest.raises(ConfigError):
        FlightRecorder(tmp_path / "f.mcap", **kwargs)
    assert not (tmp_path / "f.mcap").exists()


def _steady(rec, n, dt_ns):
    for i in range(n):
        rec.write(RawBytes(T0_NS + i * dt_ns, "gps", b"$GPZDA,%d\r\n" % i), Topic.GPS_RAW)


def test_split_by_log_time_gives_complete_numbered_parts(tmp_path):
    path = tmp_path / "flight.mcap"
    with FlightRecorder(path, split_duration_s=10.0) as rec:
        _steady(rec, 3500, 10_000_000)  # 35 s of log time
    names = [p.name for p in split_parts(path)]
    assert names == ["flight.mcap", "flight_001.mcap", "flight_002.mcap", "flight_003.mcap"]
    assert rec.paths == split_parts(path)
    for part in split_parts(path):
        fs = scan_log(part).files[0]
        assert fs.complete
        assert fs.has_summary
        assert fs.metadata["sisa.recording"]["first_part"] == "flight.mcap"
    stats = scan_log(split_parts(path))
    assert stats.topics["/gps/raw"].count == 3500
    assert stats.topics["/gps/raw"].lost_by_sequence == 0  # sequence runs on across parts
    spans = [scan_log(p).end_ns - scan_log(p).start_ns for p in split_parts(path)]
    assert max(spans) < 10 * 10**9


def test_split_by_size_keeps_parts_near_the_limit(tmp_path):
    path = tmp_path / "flight.mcap"
    with FlightRecorder(path, split_size_bytes=200_000, chunk_size=16_384) as rec:
        _steady(rec, 20_000, 1_000_000)
    parts = split_parts(path)
    assert len(parts) >= 5
    assert all(p.stat().st_size < 200_000 + 2 * 16_384 + 8192 for p in parts)
    assert scan_log(parts).topics["/gps/raw"].count == 20_000


def test_a_quiet_stream_is_on_disk_within_the_flush_interval(tmp_path, monkeypatch):
    import recorder.writer as writer_module

    fsyncs = []
    real_fsync = os.fsync
    monkeypatch.setattr(writer_module.os, "fsync", lambda fd: (fsyncs.append(fd), real_fsync(fd)))
    path = tmp_path / "f.mcap"
    with FlightRecorder(path, flush_interval_s=0.2) as rec:
        _steady(rec, 10, 1_000_000)  # far less than a chunk, then silence
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline and scan_log(path).messages < 10:
            time.sleep(0.05)
        assert scan_log(path).messages == 10  # read while the recorder is still open
        assert fsyncs


def test_the_doc_lists_every_topic_with_the_generated_tables():
    text = DOC.read_text(encoding="utf-8")
    block = re.search(r"<!-- BEGIN GENERATED topics -->\n(.*?)<!-- END GENERATED topics -->",
                      text, re.S)
    assert block, "docs/flight-log.md lost its generated block"
    assert block.group(1) == topics_markdown(), (
        "docs/flight-log.md is stale: paste the output of "
        "`python -c 'from recorder.writer import topics_markdown; print(topics_markdown())'`")
    for topic in Topic:
        assert f"`{topic}`" in text


def _reference_json(msg):
    """What the json module makes of a message, with the log's conventions: bytes base64,
    non-finite floats as "NaN"/"Infinity"/"-Infinity", numpy scalars as plain numbers."""
    def plain(v):
        if isinstance(v, bytes):
            return base64.b64encode(v).decode("ascii")
        if isinstance(v, list | tuple):
            return [plain(x) for x in v]
        if isinstance(v, float) and not math.isfinite(v):
            return "NaN" if math.isnan(v) else ("Infinity" if v > 0 else "-Infinity")
        return v.item() if isinstance(v, np.generic) else v
    return {k: plain(v) for k, v in msg.__dict__.items()}


@pytest.mark.parametrize("text", ["ins", "null", "a null here", "é°", 'quo"te'])
@pytest.mark.parametrize("value", [0.25, -0.0, 1e16, float("nan"), float("inf"), -float("inf"),
                                   np.float64(2.5)])
def test_messages_encode_as_the_json_module_reads_them(text, value):
    """orjson writes the log (NaN as null there): every awkward value, and the text "null"
    in a field, reads back as the json module's own encoding of the same message."""
    msgs = [InsRecordLog(T0_NS, 3, 7, value, 0.1, 1.2, value, 0.0, 0.0, 1.0, 2.0, 3.0, 5,
                         True, 6),
            RawBytes(T0_NS, text, b"\x00null\xff" + text.encode()),
            StreamHealth(T0_NS, text, 4, value, value, 1, 2, 3, 4, 5, 6, text)]
    for msg in msgs:
        data = encode_message(msg)
        assert json.loads(data) == _reference_json(msg)
        assert list(json.loads(data)) == [f.name for f in dataclasses.fields(msg)]


def test_what_orjson_refuses_is_left_to_the_json_module():
    """An int beyond 64 bits is JSON all the same; a value no rule converts is an EncodeError."""
    big = StreamHealth(T0_NS, "ins", 2**70, 1.0, 1.0, 1, 2, 3, 4, 5, 6)
    assert json.loads(encode_message(big))["messages"] == 2**70
    with pytest.raises(EncodeError, match="object is not JSON serialisable"):
        encode_message(StreamHealth(T0_NS, "ins", object(), 1.0, 1.0, 1, 2, 3, 4, 5, 6))


def test_the_fast_message_path_writes_what_mcap_writes(tmp_path):
    """message_appender packs records on the mcap Writer's own state: with the mcap version
    installed it must be in use (not the fallback) and make the very bytes add_message makes,
    across chunks and channels, times out of order included."""
    from mcap.writer import CompressionType, Writer

    from recorder.writer import message_appender

    def write(path, fast):
        with path.open("wb") as fh:
            w = Writer(fh, chunk_size=4096, compression=CompressionType.NONE)
            w.start(profile="", library="test")
            schema = w.register_schema("s", "jsonschema", b"{}")
            channels = [w.register_channel(f"/t{i}", "json", schema) for i in range(3)]
            add = message_appender(w) if fast else w.add_message
            if fast:
                assert add != w.add_message, "mcap's writer changed: the fast path is off"
            rng = np.random.default_rng(5)
            for i in range(3000):
                t = T0_NS + int(rng.integers(-10**6, 10**9))
                add(channels[i % 3], t, bytes(rng.integers(0, 256, i % 97, dtype=np.uint8)),
                    t + 1, i)
                if i == 1500:
                    w.flush()  # a chunk closed early, as the recorder's timed flush does
            w.finish()
        return path.read_bytes()

    assert write(tmp_path / "fast.mcap", True) == write(tmp_path / "slow.mcap", False)
