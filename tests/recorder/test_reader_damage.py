"""Bytes overwritten inside a flight log (a bad sector, a stray write): the reader reads on at the
next readable record, so only the chunks the damage touched are lost, and says what it skipped.

Each case damages a copy of one log and compares what the reader gives, message by message and in
order, with the undamaged log's messages minus those of the chunks the damage touched (found by
walking the undamaged file's record framing, independently of the reader)."""

import io
import struct
from dataclasses import dataclass

import numpy as np
import pytest
from mcap.records import Channel, Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk

from recorder.messages import GpsFix, InsRecordLog, RawBytes, Topic
from recorder.reader import LogReader, scan_log
from recorder.recover import recover
from recorder.replay import Wire, survey_log
from recorder.writer import FlightRecorder
from sisa.cli import main
from tests.recorder import T0_NS

Key = tuple[str, int, int, bytes]  # topic, log time, sequence, data


@dataclass(frozen=True)
class ChunkAt:
    offset: int
    end: int  # past its last byte
    keys: tuple[Key, ...]  # its messages, in order


@dataclass(frozen=True)
class Layout:
    data: bytes
    chunks: tuple[ChunkAt, ...]
    summary_start: int

    def expected(self, lost: set[int], upto: int | None = None) -> list[Key]:
        """The messages of every chunk not lost (and, in a file cut at `upto`, whole)."""
        return [k for i, c in enumerate(self.chunks) if i not in lost
                and (upto is None or c.end <= upto) for k in c.keys]

    def touched(self, start: int, stop: int) -> set[int]:
        """The chunks that bytes [start, stop) overlap."""
        return {i for i, c in enumerate(self.chunks) if c.offset < stop and start < c.end}


def _layout(data: bytes) -> Layout:
    topics: dict[int, str] = {}
    chunks = []
    pos = 8
    while True:
        opcode, length = struct.unpack_from("<BQ", data, pos)
        if opcode == 0x0F:  # DataEnd: the summary follows it
            return Layout(data, tuple(chunks), pos + 9 + length)
        if opcode == 0x06:
            raw = data[pos:pos + 9 + length]
            chunk = next(StreamReader(io.BytesIO(raw), skip_magic=True, emit_chunks=True).records)
            assert isinstance(chunk, Chunk)
            keys = []
            for record in breakup_chunk(chunk):
                if isinstance(record, Channel):
                    topics[record.id] = record.topic
                elif isinstance(record, Message):
                    keys.append((topics[record.channel_id], record.log_time, record.sequence,
                                 record.data))
            chunks.append(ChunkAt(pos, pos + 9 + length, tuple(keys)))
        pos += 9 + length


def _keys(path) -> list[Key]:
    return [(c.topic, m.log_time, m.sequence, m.data) for c, m in LogReader(path).raw()]


@pytest.fixture(scope="module")
def log(tmp_path_factory) -> Layout:
    """~180 chunks of 4 KiB: INS at 100 Hz, a fix every 10th record, scanner bytes every 5th."""
    path = tmp_path_factory.mktemp("damage") / "flight.mcap"
    with FlightRecorder(path, chunk_size=4096, metadata={"scenario": "damage"}) as rec:
        for i in range(2000):
            t = T0_NS + i * 10_000_000
            rec.write(InsRecordLog(t, i, i * 100_000, 0.01, -0.02, 1.5, 1e-4, 2e-4, -3e-4, 60.0,
                                   1.0, -0.5, 0, False, 0))
            if i % 10 == 0:
                rec.write(GpsFix(t, 10**18 + i, 41.0, 2.0, 600.0, 1, 8, 0.9))
            if i % 5 == 0:
                rec.write(RawBytes(t, "scanner", bytes([i % 256]) * 20), Topic.SCANNER_RAW)
    layout = _layout(path.read_bytes())
    assert len(layout.chunks) > 100
    assert _keys(path) == layout.expected(set())
    return layout


def _overwrite(data: bytes, start: int, stop: int, seed: int = 0) -> bytes:
    """Random bytes over [start, stop), each different from the one it replaces."""
    out = bytearray(data)
    noise = np.random.default_rng(seed).integers(1, 256, stop - start, dtype=np.uint8)
    out[start:stop] = (np.frombuffer(data[start:stop], dtype=np.uint8) ^ noise).tobytes()
    return bytes(out)


# where the damage goes: [start, stop) from the layout
DAMAGE = {
    "at byte 200": lambda lay: (200, 500),  # the tester's: header, metadata, the first chunk
    "at byte 5000": lambda lay: (5000, 5300),
    "the header record": lambda lay: (9, 40),
    "the first chunk's header": lambda lay: (lay.chunks[0].offset + 1, lay.chunks[0].offset + 301),
    "inside the first chunk": lambda lay: (lay.chunks[0].offset + 400, lay.chunks[0].offset + 700),
    "a mid-file chunk's header": lambda lay: (lay.chunks[20].offset, lay.chunks[20].offset + 300),
    "inside a mid-file chunk": lambda lay: (lay.chunks[20].offset + 900,
                                            lay.chunks[20].offset + 1200),
    "across a chunk boundary": lambda lay: (lay.chunks[20].end - 150, lay.chunks[21].offset + 150),
    "over four chunks": lambda lay: (lay.chunks[20].offset + 50, lay.chunks[23].offset + 50),
    "the last chunk's header": lambda lay: (lay.chunks[-1].offset, lay.chunks[-1].offset + 300),
}


@pytest.mark.parametrize("where", DAMAGE)
def test_a_complete_log_loses_only_the_chunks_the_damage_touched(log, tmp_path, where):
    start, stop = DAMAGE[where](log)
    lost = log.touched(start, stop)
    path = tmp_path / "damaged.mcap"
    path.write_bytes(_overwrite(log.data, start, stop))
    assert _keys(path) == log.expected(lost)
    fs = scan_log(path).files[0]
    assert fs.complete
    assert fs.has_summary
    assert fs.chunks_skipped == len(lost)
    assert fs.chunks_read == len(log.chunks) - len(lost)
    assert fs.bytes_unreadable == 0
    assert (fs.bytes_skipped > 0) == bool(lost) or where == "the header record"
    if where != "at byte 200":  # that one damages the metadata record itself
        assert fs.metadata["sisa.recording"]["scenario"] == "damage"


@pytest.mark.parametrize("where", ["at byte 5000", "a mid-file chunk's header",
                                   "inside a mid-file chunk", "across a chunk boundary",
                                   "over four chunks"])
def test_a_cut_log_without_a_summary_resynchronises_on_the_next_chunk(log, tmp_path, where):
    """No summary to say where the chunks are: the reader finds the next chunk whose framing
    is consistent. A stretch it skips counts as one damaged chunk (it cannot tell how many)."""
    start, stop = DAMAGE[where](log)
    lost = log.touched(start, stop)
    cut_at = log.chunks[35].offset + 1000  # inside a chunk: the end of a killed recording
    path = tmp_path / "damaged.mcap"
    path.write_bytes(_overwrite(log.data, start, stop)[:cut_at])
    assert _keys(path) == log.expected(lost, upto=cut_at)
    fs = scan_log(path).files[0]
    assert fs.truncated
    assert not fs.has_summary
    assert 1 <= fs.chunks_skipped <= len(lost)
    assert fs.chunks_read == 35 - len(lost)
    assert fs.bytes_unreadable == 1000


def test_a_cut_log_keeps_the_declarations_of_a_chunk_whose_header_is_damaged(log, tmp_path):
    """The first chunk declares every channel. Its length damaged in a file without a summary:
    the declarations are taken from the skipped stretch (exactly SISA's), so every later
    message is read."""
    data = bytearray(log.data[:log.chunks[30].offset + 10])
    struct.pack_into("<Q", data, log.chunks[0].offset + 1, 2**61 + 12345)
    path = tmp_path / "damaged.mcap"
    path.write_bytes(bytes(data))
    assert _keys(path) == log.expected({0}, upto=len(data))
    stats = scan_log(path)
    assert stats.files[0].chunks_skipped == 1
    assert not any("undeclared" in p for p in stats.files[0].problems)


@pytest.mark.parametrize("delta", [+1000, -1000, +2**40])
def test_a_chunk_length_damaged_to_another_value(log, tmp_path, delta):
    """Longer (still framing): the chunk is read and the reader goes back to the chunk it ran
    over; shorter: that chunk alone is lost; beyond the file: as a damaged header."""
    victim = log.chunks[10]
    data = bytearray(log.data)
    (length,) = struct.unpack_from("<Q", data, victim.offset + 1)
    struct.pack_into("<Q", data, victim.offset + 1, length + delta)
    path = tmp_path / "damaged.mcap"
    path.write_bytes(bytes(data))
    lost = set() if delta == 1000 else {10}
    assert _keys(path) == log.expected(lost)
    fs = scan_log(path).files[0]
    assert fs.complete
    assert fs.chunks_skipped == len(lost)
    cut = tmp_path / "cut.mcap"  # the same without a summary
    cut.write_bytes(bytes(data[:log.chunks[-5].offset]))
    assert _keys(cut) == log.expected(lost, upto=log.chunks[-5].offset)


def test_a_chunk_whose_opcode_is_damaged_is_counted(log, tmp_path):
    """An unknown opcode is a later MCAP version's record, skipped; where the summary indexes a
    chunk, it is a damaged chunk and counted as one."""
    data = bytearray(log.data)
    data[log.chunks[10].offset] = 0x99
    path = tmp_path / "damaged.mcap"
    path.write_bytes(bytes(data))
    assert _keys(path) == log.expected({10})
    assert scan_log(path).files[0].chunks_skipped == 1


def test_a_damaged_summary_too_still_finds_the_chunks_and_the_footer(log, tmp_path):
    start, stop = DAMAGE["across a chunk boundary"](log)
    data = bytearray(_overwrite(log.data, start, stop))
    data[log.summary_start + 30] ^= 0x55  # the summary's CRC no longer checks
    path = tmp_path / "damaged.mcap"
    path.write_bytes(bytes(data))
    lost = log.touched(start, stop)
    assert _keys(path) == log.expected(lost)
    fs = scan_log(path).files[0]
    assert fs.complete
    assert fs.chunks_skipped >= 1


def test_garbage_between_good_chunks_is_skipped(log, tmp_path):
    """A stretch of junk inserted between two chunks (the footer's summary offset then points
    into the wrong bytes, so there is no summary to go by): every chunk is still read."""
    at = log.chunks[15].offset
    junk = np.random.default_rng(3).bytes(5000)
    path = tmp_path / "junk.mcap"
    path.write_bytes(log.data[:at] + junk + log.data[at:])
    assert _keys(path) == log.expected(set())
    fs = scan_log(path).files[0]
    assert fs.complete
    assert fs.bytes_skipped == 5000


# --- sisa log info / recover --------------------------------------------------------------------

@pytest.mark.parametrize("where", ["at byte 200", "at byte 5000", "across a chunk boundary"])
def test_log_info_and_recover_on_a_damaged_complete_log(log, tmp_path, capsys, where):
    start, stop = DAMAGE[where](log)
    lost = log.touched(start, stop)
    path = tmp_path / "damaged.mcap"
    path.write_bytes(_overwrite(log.data, start, stop))
    assert main(["log", "info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "complete (summary present)" in out
    assert "truncated" not in out
    assert f"; {len(lost)} damaged chunks skipped" in out
    assert "damaged bytes passed over)" in out
    expected = log.expected(lost)
    assert f"{len(expected)} messages on 4 topics" in out
    saved = tmp_path / "recovered.mcap"
    assert main(["log", "recover", str(path), str(saved)]) == 0
    said = capsys.readouterr().out
    assert f"{len(expected)} messages" in said
    assert f"complete, {len(lost)} damaged chunks skipped" in said
    assert _keys(saved) == expected
    again = scan_log(saved).files[0]
    assert again.complete
    assert again.chunks_skipped == 0


def test_recover_reports_the_bytes_it_skipped(log, tmp_path):
    start, stop = DAMAGE["a mid-file chunk's header"](log)
    path = tmp_path / "damaged.mcap"
    path.write_bytes(_overwrite(log.data, start, stop))
    report = recover(path, tmp_path / "out.mcap")
    assert report.input_complete
    assert report.chunks_skipped == 1
    assert report.bytes_skipped > 0
    assert f"{report.bytes_skipped} damaged bytes skipped" in report.summary()


def test_replay_finds_the_raw_channels_of_a_log_damaged_at_its_start(log, tmp_path):
    path = tmp_path / "damaged.mcap"
    path.write_bytes(_overwrite(log.data, 200, 500))
    survey = survey_log(path)
    raw = [k for k in log.expected(log.touched(200, 500)) if k[0] == Topic.SCANNER_RAW]
    assert survey.counts == {Wire.SCANNER: len(raw)}


@pytest.mark.parametrize("where", ["inside a mid-file chunk", "a mid-file chunk's header",
                                   "across a chunk boundary", "over four chunks"])
def test_zeroed_storage_counts_every_chunk_and_byte_it_took(log, tmp_path, where):
    """Zeros frame as empty records of opcode 0, which no MCAP record has: every 9 bytes one.
    They were passed over as unknown records, so a zeroed stretch counted only the chunks
    whose start happened to fall on a 9-byte step, and a few bytes (a bad-input sweep found
    '0 damaged chunks skipped (28741 bytes)' for 1 MB of zeros)."""
    start, stop = DAMAGE[where](log)
    lost = log.touched(start, stop)
    data = bytearray(log.data)
    data[start:stop] = bytes(stop - start)
    path = tmp_path / "zeroed.mcap"
    path.write_bytes(bytes(data))
    assert _keys(path) == log.expected(lost)
    fs = scan_log(path).files[0]
    assert fs.complete
    assert fs.chunks_skipped == len(lost)
    assert fs.bytes_skipped >= stop - start


def test_a_log_whose_tail_went_to_zeros_reads_to_its_last_chunk(log, tmp_path):
    """A power cut can leave a file's last blocks allocated but zero: read as cut short there."""
    cut_at = log.chunks[35].offset
    data = log.data[:cut_at] + bytes(len(log.data) - cut_at)
    path = tmp_path / "zero_tail.mcap"
    path.write_bytes(data)
    assert _keys(path) == log.expected(set(), upto=cut_at)
    fs = scan_log(path).files[0]
    assert fs.truncated
    assert fs.chunks_read == 35
    assert any("zeros from byte" in p for p in fs.problems)


def test_log_info_shows_metadata_damage_made_unprintable_escaped_and_cut(tmp_path, capsys):
    """A damaged Metadata record can hold a terminal's escape sequences, a line break or
    thousands of characters: log info prints them escaped and cut, on the file's own line,
    and plain values as they are."""
    path = tmp_path / "flight.mcap"
    hostile = {"scenario": "bench", "note": "\x1b[2J\x1b[31mred", "crew": "a\nb",
               "long": "x" * 5000}
    with FlightRecorder(path, chunk_size=4096, metadata=hostile) as rec:
        rec.write(GpsFix(T0_NS, 10**18, 41.0, 2.0, 600.0, 1, 8, 0.9))
    assert main(["log", "info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "\x1b" not in out
    meta_line = next(line for line in out.splitlines() if "scenario=bench" in line)
    assert r"note='\x1b[2J\x1b[31mred'" in meta_line
    assert r"crew='a\nb'" in meta_line
    assert "long='xxx" in meta_line
    assert "x" * 200 not in meta_line
    assert len(meta_line) < 600
