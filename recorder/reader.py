"""The tolerant flight-log reader: every complete chunk of a file, even one cut short by a crash.

Why it is built this way:
- A log from a power cut has no summary and ends inside a record. It is read front to back, one
  record at a time, over a source that returns a record only when all its bytes are there, so a
  half-written tail ends the file instead of becoming garbage; each record is parsed (by mcap)
  from its own bytes only, so a damaged inner length is skipped with its record and cannot eat
  the records after it. Each chunk is checked (length, CRC) before any of its messages is used;
  a bad chunk is skipped and counted, unknown records are skipped (but zeros, which frame as
  records of opcode 0, are damage). A length beyond
  `record_size_limit` is never allocated (nor may a compressed chunk inflate past its declared
  size).
- Damage does not end the file. After a record that cannot be framed (a length beyond the limit
  or the file: its header is damaged) or parsed, the reader resynchronises on the next record
  it can trust: in a complete file, the next chunk, metadata record or summary that the summary
  indexes (its CRC checked); without one (a file cut short), the next chunk whose framing is
  consistent (its length, compression name and records length agree), or the footer. What lies
  between is skipped and counted (`chunks_skipped`, `bytes_skipped`). When there is nothing to
  resynchronise on, the file was cut short there: the end of what was written.
- Channels are declared once, inside the chunk of their first message. When that chunk is
  damaged, the declarations come from the summary of a complete file (read when a message's
  channel is missing, CRC-checked),
  or from the damaged chunk itself when they are exactly what SISA writes for that topic
  (a file cut short has no summary); either way only the damaged chunk's own messages are lost.
- Post-processing wants columns, not objects: `read_columns` turns each batch of messages into
  numpy arrays as it goes, so a long flight never lives as millions of Python dicts. A chunk's
  records are split once into columns (`recorder.chunkrecords`; the mcap package's parsing,
  field by field, was most of the time of reading a log) and message index records are
  checked, not parsed: `raw_batches()` gives them a chunk at a time, `raw()` one by one.
- `LogStats` says what was read and what was not: per-topic counts, span, gaps (> 2x the usual
  interval around them: docs/flight-log.md), messages lost by sequence number, whether each file
  ended cleanly.
"""


from __future__ import annotations

import base64
from array import array
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any, Final, TypeVar

import numpy as np
import numpy.typing as npt
from mcap.records import (
    Message,
)

from recorder.chunkrecords import ChunkMessages
from recorder.filescan import FileScan
from recorder.framing import DEFAULT_RECORD_SIZE_LIMIT, Paths, log_paths, open_log
from recorder.messages import LoggedMessage, Topic
from recorder.parts import PART_OVERLAP_TOLERANCE_NS, split_set
from recorder.stats import SEQUENCE_MOD, ChannelInfo, FileStats, LogStats, TopicStats, fill_timing
from recorder.writer import MESSAGE_ENCODING
from sisa.core.bounded import MAX_NESTING, json_loads
from sisa.core.errors import DecodeError, InputError, shown_text

BATCH: Final = 4096

JSON_ERRORS: Final = (ValueError, KeyError, TypeError, OverflowError, RecursionError)

M = TypeVar("M", bound=LoggedMessage)


class LogReader:
    """One pass over a flight log (a file or the parts of a split set, in order).

    Iterate for `(topic, log_time_ns, dict)`; `raw()` for undecoded `(ChannelInfo, Message)`.
    `stats` is filled during the pass. Files are checked to be MCAP before the pass starts.
    """

    def __init__(self, path_or_paths: Paths, *,
                 record_size_limit: int = DEFAULT_RECORD_SIZE_LIMIT) -> None:
        self.paths = log_paths(path_or_paths)
        if not self.paths:
            raise InputError("no flight log given")
        for path in self.paths:
            open_log(path).close()
        parts = split_set(self.paths)  # one recording (else InputError), in part order
        self.paths = parts.paths
        self._check_times = parts.check_times
        self.record_size_limit = record_size_limit
        self.stats = LogStats(part_notes=parts.notes)
        self._times: dict[str, array[int]] = {}
        self._next_seq: dict[str, int] = {}

    def __iter__(self) -> Iterator[tuple[str, int, dict[str, Any]]]:
        decoders = _Decoders()
        for channel, msg in self.raw():
            obj = decoders.decode(channel, msg.data)
            if obj is None:
                self.stats.note_bad(channel.topic, msg.log_time,
                                    decoders.problem(channel, msg.data) or "does not decode")
                continue
            yield channel.topic, msg.log_time, obj

    def raw(self) -> Iterator[tuple[ChannelInfo, Message]]:
        """Every readable message, in file order, with its channel."""
        for channels, batch in self.raw_batches():
            for msg in batch.messages():
                yield channels[msg.channel_id], msg

    def raw_batches(self) -> Iterator[tuple[Mapping[int, ChannelInfo], ChunkMessages]]:
        """Every readable message, in file order, a chunk at a time (columns over its bytes),
        with the channels they are on: how a long log is read without a Python object per
        message."""
        previous: tuple[Path, int] | None = None  # the last part with messages, its end
        for path in self.paths:
            fstats = FileStats(path, path.stat().st_size)
            self.stats.files.append(fstats)
            marks = {topic: len(times) for topic, times in self._times.items()}
            scan = FileScan(path, fstats, self.record_size_limit)
            seen: list[tuple[npt.NDArray[np.uint16], npt.NDArray[np.uint32],
                             npt.NDArray[np.uint64]]] = []  # not the chunks' bytes
            for channels, batch in scan.batches():
                seen.append((batch.channel_id, batch.sequence, batch.log_time))
                yield channels, batch
            self._account(scan.channels, seen)
            if self._check_times:
                previous = self._check_follows(path, marks, previous)
        self._finish()

    def _check_follows(self, path: Path, marks: Mapping[str, int],
                       previous: tuple[Path, int] | None) -> tuple[Path, int] | None:
        """A part recorded without a recording id must begin where the part before it ended
        (within PART_OVERLAP_TOLERANCE_NS): one that begins earlier is of another flight, and
        InputError says so. `marks`: each topic's message count before this part. Returns
        this part and its last log time, or `previous` when it has no messages."""
        spans = [np.frombuffer(times, dtype=np.uint64)[marks.get(topic, 0):]
                 for topic, times in self._times.items()]
        spans = [span for span in spans if span.size]
        if not spans:
            return previous
        first_ns = min(int(span.min()) for span in spans)
        if previous is not None and first_ns < previous[1] - PART_OVERLAP_TOLERANCE_NS:
            raise InputError(f"{path} is part of another recording than {previous[0]}: it "
                             f"begins {(previous[1] - first_ns) / 1e9:.1f} s of log time before "
                             "that part ends (a log recorded without a recording id; its parts "
                             "are told apart by time): each flight's parts are read together, "
                             "not mixed")
        return path, max(int(span.max()) for span in spans)

    def _account(self, channels: Mapping[int, ChannelInfo],
                 batches: list[tuple[npt.NDArray[np.uint16], npt.NDArray[np.uint32],
                                     npt.NDArray[np.uint64]]]) -> None:
        """Counts, log times and sequence gaps of each topic, over one file's messages at once
        (a chunk at a time cost half a millisecond a chunk)."""
        if not batches:
            return
        ids = np.concatenate([b[0] for b in batches])
        seqs = np.concatenate([b[1] for b in batches]).astype(np.int64)
        log_times = np.concatenate([b[2] for b in batches])
        present = np.unique(ids).tolist()
        topics = sorted({channels[i].topic for i in present})
        topic_index = {topic: k for k, topic in enumerate(topics)}
        lookup = np.zeros(int(ids.max()) + 1, dtype=np.int64)
        for channel_id in present:
            lookup[channel_id] = topic_index[channels[channel_id].topic]
        of_topic = lookup[ids]
        for k, topic in enumerate(topics):
            at = np.flatnonzero(of_topic == k)  # in file order
            ts = self.stats.topics.get(topic)
            if ts is None:
                schema = next(c.schema_name for c in channels.values() if c.topic == topic)
                ts = self.stats.topics[topic] = TopicStats(topic, schema)
                self._times[topic] = array("Q")
            ts.count += int(at.size)  # the rest of the timing is filled in at the end
            self._times[topic].frombytes(log_times[at].astype("<u8").tobytes())
            seq = seqs[at]
            expected = np.empty_like(seq)
            expected[1:] = (seq[:-1] + 1) % SEQUENCE_MOD
            before = self._next_seq.get(topic)
            expected[0] = seq[0] if before is None else before
            jump = (seq - expected) % SEQUENCE_MOD
            ts.lost_by_sequence += int(jump[jump < SEQUENCE_MOD // 2].sum())
            self._next_seq[topic] = int((seq[-1] + 1) % SEQUENCE_MOD)

    def _finish(self) -> None:
        for topic, ts in self.stats.topics.items():
            times = np.sort(np.frombuffer(self._times[topic], dtype=np.uint64))
            fill_timing(ts, times)
        self._times.clear()


def schema_properties(channel: ChannelInfo) -> dict[str, Any] | None:
    if channel.schema_encoding != "jsonschema":
        return None
    try:
        props = json_loads(channel.schema_data).get("properties")
    except (ValueError, AttributeError):
        return None
    return props if isinstance(props, dict) else None


class _Decoder:
    """JSON message → dict, with base64 fields as bytes and "NaN"/"Infinity" back as floats."""

    def __init__(self, props: dict[str, Any]) -> None:
        self.b64 = tuple(k for k, p in props.items() if p.get("contentEncoding") == "base64")
        self.numbers = tuple(k for k, p in props.items() if p.get("type") == "number")

    @classmethod
    def for_channel(cls, channel: ChannelInfo) -> _Decoder | None:
        if channel.message_encoding != "json":
            return None
        return cls(schema_properties(channel) or {})

    def __call__(self, data: bytes) -> dict[str, Any] | None:
        try:
            return self.decode(data)
        except JSON_ERRORS:
            return None

    def decode(self, data: bytes) -> dict[str, Any]:
        """The message's fields; one of JSON_ERRORS saying why it does not decode."""
        obj = json_loads(data)  # nesting bounded
        if not isinstance(obj, dict):
            raise TypeError(f"a JSON {type(obj).__name__}, not an object")
        for name in self.b64:
            obj[name] = base64.b64decode(obj[name])
        if self.numbers and (b'"NaN"' in data or b'Infinity"' in data):
            for name in self.numbers:
                if isinstance(obj.get(name), str):
                    obj[name] = float(obj[name])
        return obj


class _Decoders:
    """One decoder per (encoding, schema): what a decoder needs depends on nothing else."""

    def __init__(self) -> None:
        self._by_schema: dict[tuple[str, str, bytes], _Decoder | None] = {}

    def decode(self, channel: ChannelInfo, data: bytes) -> dict[str, Any] | None:
        key = (channel.message_encoding, channel.schema_encoding, channel.schema_data)
        if key not in self._by_schema:
            self._by_schema[key] = _Decoder.for_channel(channel)
        decoder = self._by_schema[key]
        return decoder(data) if decoder is not None else None

    def problem(self, channel: ChannelInfo, data: bytes) -> str | None:
        """Why a message does not decode, in words (None if it does, or is not JSON)."""
        self.decode(channel, data)
        decoder = self._by_schema[(channel.message_encoding, channel.schema_encoding,
                                   channel.schema_data)]
        if decoder is None:
            return None
        try:
            decoder.decode(data)
        except JSON_ERRORS as exc:
            return decoding_problem(exc)
        return None


class MessageCheck:
    """Why a message does not decode, or None (`sisa log recover` asks it of every message)."""

    def __init__(self) -> None:
        self._decoders = _Decoders()

    def __call__(self, channel: ChannelInfo, data: bytes) -> str | None:
        return self._decoders.problem(channel, data)


def decoding_problem(exc: BaseException) -> str:
    """A decoding error in a few words (never the message's own text at length)."""
    if isinstance(exc, KeyError):
        return f"no field {shown_text(str(exc.args[0]) if exc.args else '', 40)}"
    return shown_text(str(exc), 100) or type(exc).__name__


def message_problem(data: bytes) -> str | None:
    """Why a JSON message could not be read by any SISA reader, for a check of every message
    that must stay cheap (`scan_log`): nesting beyond the bound (a message with more brackets
    than the bound allows is decoded to find out: no message of SISA's has more than a few),
    or None."""
    if data.count(b"[") + data.count(b"{") <= MAX_NESTING:
        return None
    try:
        obj = json_loads(data)
    except JSON_ERRORS as exc:
        return decoding_problem(exc)
    return None if isinstance(obj, dict) else f"a JSON {type(obj).__name__}, not an object"


def read_log(path_or_paths: Paths) -> Iterator[tuple[str, int, dict[str, Any]]]:
    """Every readable message as (topic, log_time_ns, fields); bytes fields as bytes."""
    return iter(LogReader(path_or_paths))


def scan_log(path_or_paths: Paths) -> LogStats:
    """Read a whole log for its statistics, decoding only the recorder's health reports."""
    reader = LogReader(path_or_paths)
    decoders = _Decoders()
    health = reader.stats.health
    for channels, chunk in reader.raw_batches():
        ids = chunk.channel_id
        for channel_id in np.unique(ids).tolist():
            channel = channels[channel_id]
            if channel.topic != Topic.HEALTH and channel.message_encoding != MESSAGE_ENCODING:
                continue
            on = chunk.take(np.flatnonzero(ids == channel_id))
            for log_time, data in zip(on.log_time.tolist(), on.payloads(), strict=True):
                if channel.topic == Topic.HEALTH:
                    report = decoders.decode(channel, data)
                    if report is None:
                        health.unreadable += 1
                        reader.stats.note_bad(channel.topic, log_time,
                                              decoders.problem(channel, data) or
                                              "does not decode")
                    else:
                        health.add(report)
                elif (why := message_problem(data)) is not None:
                    reader.stats.note_bad(channel.topic, log_time, why)
    return reader.stats


def read_messages(path_or_paths: Paths, cls: type[M], topic: Topic | str | None = None
                  ) -> Iterator[M]:
    """Every readable message of type `cls` (on every topic carrying it, or only `topic`)."""
    decoders = _Decoders()
    reader = LogReader(path_or_paths)
    for channel, msg in reader.raw():
        if channel.schema_name != cls.schema_name or (topic is not None and channel.topic != topic):
            continue
        where = f"{reader.stats.files[-1].path}: {shown_text(channel.topic, 60)}"
        obj = decoders.decode(channel, msg.data)
        if obj is None:
            raise DecodeError(f"{where}: message at log time {msg.log_time} is not "
                              f"valid {cls.schema_name} JSON", raw=msg.data)
        try:
            item = cls(**obj)
        except TypeError as exc:
            raise DecodeError(f"{where}: fields do not match {cls.schema_name}: {exc}",
                              raw=msg.data) from None
        yield item
