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
  numpy arrays as it goes, so a long flight never lives as millions of Python dicts.
- `LogStats` says what was read and what was not: per-topic counts, span, gaps (> 2x the usual
  interval around them: docs/flight-log.md), messages lost by sequence number, whether each file
  ended cleanly.
"""

from __future__ import annotations

import base64
import bisect
import contextlib
import dataclasses
import io
import json
import os
import stat
import struct
import warnings
import zlib
from array import array
from collections import Counter
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from pathlib import Path
from typing import Any, BinaryIO, Final, TypeVar

import lz4.frame  # type: ignore[import-untyped]  # no stubs; mcap depends on it
import numpy as np
import numpy.typing as npt
import zstandard
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    Footer,
    Header,
    McapRecord,
    Message,
    Metadata,
    MetadataIndex,
    Schema,
)
from mcap.stream_reader import StreamReader, breakup_chunk

from recorder.health import HealthTotals
from recorder.messages import LoggedMessage, Topic
from recorder.writer import (
    KNOWN_SCHEMA_BYTES,
    MESSAGE_ENCODING,
    METADATA_NAME,
    SCHEMA_ENCODING,
    SCHEMAS,
    TOPIC_SCHEMAS,
    TOPIC_TYPES,
    part_path,
)
from sisa.core.errors import DecodeError, InputError, shown_text

MCAP_MAGIC: Final = b"\x89MCAP0\r\n"
DEFAULT_RECORD_SIZE_LIMIT: Final = 256 * 2**20  # our chunks are 64 KiB; 256 MiB is corruption
GAP_FACTOR: Final = 2.0
RHYTHM_NS: Final = 2_000_000_000  # a silence a topic keeps at least this often is its rhythm
RHYTHM_BIN_NS: Final = 20_000_000_000  # ... judged over this much log time and its neighbours
# the sync unit's own outputs, silent by design between forwarded pulses (the LFSR's runs of
# zeros, up to 4 s with 4 bits): their silences say nothing about a device, so no gaps
PATTERNED_TOPICS: Final = frozenset({Topic.SYNC_FORWARD.value, Topic.PULSE_OUT.value})
MAX_GAPS_KEPT: Final = 1000
MAX_PROBLEMS_KEPT: Final = 20
_SEQUENCE_MOD: Final = 2**32
_BATCH: Final = 4096
# OverflowError: a length of 2^63 or more inside a chunk, which mcap hands to a read
_PARSE_ERRORS: Final = (McapError, ValueError, struct.error, UnicodeDecodeError, KeyError,
                        OverflowError)
_JSON_ERRORS: Final = (ValueError, KeyError, TypeError, OverflowError, RecursionError)
_RECORD_HEAD: Final = 9  # opcode u8, length u64
_FOOTER_BODY: Final = 20  # summary_start u64, summary_offset_start u64, summary_crc u32
_KNOWN_OPCODES: Final = frozenset(int(op) for op in Opcode)
_ZEROED_OPCODE: Final = 0x00  # no MCAP record type: what zero-filled storage frames as
# a Chunk's fixed fields: start and end time, uncompressed size u64; CRC u32; compression name
# length u32; records length u64
_CHUNK_FIXED: Final = 40
_COMPRESSIONS: Final = frozenset({b"", b"lz4", b"zstd"})
_CHUNK_PEEK: Final = _RECORD_HEAD + _CHUNK_FIXED + 4  # enough of a chunk to judge its framing
_SCAN_BLOCK: Final = 2**20
_DECLARATION_MAX: Final = 2**16  # the longest Schema or Channel record salvaged from damage
_METADATA_MAX: Final = 2**20  # the longest metadata record read to place a part in its recording
_HEAD_RECORDS: Final = 64  # records looked at before the first chunk for the part's metadata
# how far a part recorded without a recording id may reach back before the previous part's last
# message: threads stamp their messages before they take the recorder's lock, so the first
# messages of a part can be older than the last of the one before by that wait (a slow disk)
PART_OVERLAP_TOLERANCE_NS: Final = 2_000_000_000
_NAMES_SHOWN: Final = 4  # missing parts named in a note; more are elided

PathArg = Path | str
Paths = PathArg | Sequence[PathArg]
M = TypeVar("M", bound=LoggedMessage)


@dataclass(frozen=True)
class ChannelInfo:
    """A channel as declared in the file, with its schema."""

    id: int
    topic: str
    message_encoding: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes


@dataclass(frozen=True)
class Gap:
    """A silence on one topic longer than `GAP_FACTOR` times its usual interval around it."""

    topic: str
    start_ns: int  # log time of the last message before the gap
    end_ns: int  # log time of the first message after it
    usual_ns: int = 0  # the topic's usual interval around it (_local_usual_ns)

    @property
    def duration_ns(self) -> int:
        return self.end_ns - self.start_ns


@dataclass
class TopicStats:
    topic: str
    schema_name: str
    count: int = 0
    first_ns: int = 0
    last_ns: int = 0
    median_interval_ns: int = 0
    usual_interval_ns: int = 0  # see _usual_interval_ns
    gaps: list[Gap] = field(default_factory=list)  # the first MAX_GAPS_KEPT, in time order
    gap_count: int | None = 0  # None: not counted (PATTERNED_TOPICS)
    lost_by_sequence: int = 0  # jumps in the writer's per-topic sequence numbers

    @property
    def span_ns(self) -> int:
        return self.last_ns - self.first_ns

    @property
    def rate_hz(self) -> float:
        return (self.count - 1) * 1e9 / self.span_ns if self.count > 1 and self.span_ns else 0.0


@dataclass
class FileStats:
    path: Path
    size_bytes: int
    library: str = ""
    complete: bool = False  # the footer and the closing magic were read
    has_summary: bool = False
    chunks_read: int = 0
    chunks_skipped: int = 0  # damaged: a bad CRC, or unreadable and skipped over
    bytes_readable: int = 0  # up to the end of the last complete record
    bytes_skipped: int = 0  # in damaged records and unreadable stretches the reader read past
    problems: list[str] = field(default_factory=list)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)

    @property
    def truncated(self) -> bool:
        return not self.complete

    @property
    def bytes_unreadable(self) -> int:
        return self.size_bytes - self.bytes_readable


class DamagedLogWarning(UserWarning):
    """A flight log was cut short or had damaged chunks; everything readable around them was
    read, and post-processing goes on with it."""


class MissingPartWarning(UserWarning):
    """A split recording is read without some of its parts (one not given, or deleted): what
    they held is missing, and post-processing goes on with the rest."""


def damage_notes(fs: FileStats) -> list[str]:
    """What a pass could not read of one file, in words (nothing for a sound file)."""
    notes = []
    if not fs.complete:
        rest = (f", the last {fs.bytes_unreadable} bytes unreadable" if fs.bytes_unreadable
                else "")
        notes.append(f"{fs.path}: cut short (no footer, as after a power cut or a kill): "
                     f"read to its last complete chunk{rest}")
    if fs.chunks_skipped:
        chunks = f"{fs.chunks_skipped} damaged chunk{'s' if fs.chunks_skipped != 1 else ''}"
        notes.append(f"{fs.path}: {chunks} skipped ({fs.bytes_skipped} bytes): the messages in "
                     f"{'it' if fs.chunks_skipped == 1 else 'them'} are missing "
                     f"(`sisa log info {fs.path}` shows the gaps)")
    elif fs.bytes_skipped:  # a stretch inside chunks the summary indexes, no chunk start in it
        notes.append(f"{fs.path}: {fs.bytes_skipped} damaged bytes skipped: the messages in "
                     f"them are missing (`sisa log info {fs.path}` shows the gaps)")
    return notes


@dataclass
class LogStats:
    """What a pass over a log (one file or a split set) found. Complete once the pass ends."""

    files: list[FileStats] = field(default_factory=list)
    topics: dict[str, TopicStats] = field(default_factory=dict)
    undecodable: int = 0
    part_notes: list[str] = field(default_factory=list)  # parts of the recording not given
    health: HealthTotals = field(default_factory=HealthTotals)  # filled by `scan_log`

    @property
    def messages(self) -> int:
        return sum(t.count for t in self.topics.values())

    @property
    def start_ns(self) -> int:
        return min((t.first_ns for t in self.topics.values() if t.count), default=0)

    @property
    def end_ns(self) -> int:
        return max((t.last_ns for t in self.topics.values() if t.count), default=0)

    @property
    def truncated(self) -> bool:
        return any(f.truncated for f in self.files)

    @property
    def chunks_read(self) -> int:
        return sum(f.chunks_read for f in self.files)

    @property
    def gaps(self) -> list[Gap]:
        return sorted((g for t in self.topics.values() for g in t.gaps),
                      key=lambda g: g.start_ns)


class _OverLimitError(ValueError):
    """A length field beyond the record size limit: refused before anything is allocated."""


class _WholeRecords:
    """A file source that returns all the bytes asked for or none: a record cut by the end of
    the file then reads as end-of-file, never as a short record. A length field beyond the file
    or the size limit is refused before anything is allocated for it."""

    def __init__(self, fh: BinaryIO, position: int, size: int, limit: int) -> None:
        self._fh = fh
        self.position = position
        self._size = size
        self._limit = limit

    def read(self, n: int) -> bytes:
        if n > self._limit:
            raise _OverLimitError(f"a field of {n} bytes exceeds the limit {self._limit}")
        if n > self._size - self.position:
            return b""
        data = self._fh.read(n)
        if len(data) < n:
            return b""
        self.position += n
        return data

    def seek(self, position: int) -> None:
        self._fh.seek(position)
        self.position = position


class _RecordBytes(io.BytesIO):
    """One record's bytes. A field claiming more than the size limit is refused before it is
    allocated; either it or a smaller one that overruns the record only damages the record."""

    def __init__(self, data: bytes, limit: int) -> None:
        super().__init__(data)
        self._limit = limit

    def read(self, n: int | None = -1) -> bytes:
        if n is not None and n > self._limit:
            raise _OverLimitError(f"a field of {n} bytes exceeds the limit {self._limit}")
        return super().read(n)


def _records(data: bytes, limit: int, *, emit_chunks: bool = False) -> Iterator[McapRecord]:
    """The MCAP records in `data` (no magic), under the reader's size limit."""
    return StreamReader(_RecordBytes(data, limit), skip_magic=True, emit_chunks=emit_chunks,
                        record_size_limit=None).records


def log_paths(path_or_paths: Paths) -> list[Path]:
    """One log file or several (a split recording) as a list."""
    if isinstance(path_or_paths, str | Path):
        return [Path(path_or_paths)]
    return [Path(p) for p in path_or_paths]


def open_log(path: Path) -> BinaryIO:
    """Open an MCAP file for reading past its magic; InputError (one line) if it is not one."""
    try:
        # without blocking: a FIFO would wait for a writer forever (refused just below)
        fh = open(path, "rb", opener=_open_nonblocking)  # noqa: SIM115 - the caller closes it
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from None
    mode = os.fstat(fh.fileno()).st_mode
    if not stat.S_ISREG(mode):  # a log is read by offsets, and its size is its file's
        fh.close()
        raise InputError(f"{path}: not an MCAP file (not a regular file: {_file_kind(mode)})")
    os.set_blocking(fh.fileno(), True)
    magic = fh.read(len(MCAP_MAGIC))
    if magic != MCAP_MAGIC:
        fh.close()
        what = "empty" if not magic else "no MCAP magic"
        raise InputError(f"{path}: not an MCAP file ({what})")
    return fh


def _open_nonblocking(path: str, flags: int) -> int:
    return os.open(path, flags | os.O_NONBLOCK)


def _file_kind(mode: int) -> str:
    kinds = ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"),
             (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))
    return next((kind for test, kind in kinds if test(mode)), "a special file")


FIRST_DATA_KEY_BYTES: Final = 32  # a chunk's start and end times, size and CRC


def first_data_key(path: Path) -> bytes | None:
    """The first bytes of a log's first chunk (or unchunked message): its start and end
    times, size and CRC. Two parts of one recording differ there; a file and a copy of it,
    even one cut short, do not. None where there is no such record (or no MCAP)."""
    try:
        fh = open_log(path)
    except InputError:  # the reader says what is wrong with it
        return None
    with fh:
        while len(head := fh.read(_RECORD_HEAD)) == _RECORD_HEAD:
            length = int.from_bytes(head[1:], "little")
            if head[0] in (Opcode.CHUNK, Opcode.MESSAGE):
                want = min(length, FIRST_DATA_KEY_BYTES)
                key = fh.read(want)
                return key if want and len(key) == want else None
            fh.seek(length, io.SEEK_CUR)
    return None


# --- the parts of a split recording -------------------------------------------------------------

def recording_metadata(path: Path) -> dict[str, str]:
    """A log's `sisa.recording` metadata ({} if it has none, or is no MCAP): from the records
    before its first chunk, where the recorder writes it (so a part cut short has it too), else
    through the summary's metadata index (a recovered copy has it at its end). A damaged length
    ends the look: the reader says what is wrong with the file."""
    try:
        fh = open_log(path)
    except InputError:  # the reader says what is wrong with it
        return {}
    with fh:
        size = fh.seek(0, io.SEEK_END)
        fh.seek(len(MCAP_MAGIC))
        for _ in range(_HEAD_RECORDS):
            head = fh.read(_RECORD_HEAD)
            length = int.from_bytes(head[1:], "little")
            if len(head) < _RECORD_HEAD or length > size - fh.tell() or head[0] in (
                    Opcode.CHUNK, Opcode.MESSAGE, Opcode.DATA_END, Opcode.FOOTER):
                break
            if head[0] == Opcode.METADATA and length <= _METADATA_MAX:
                found = _recording_record(head + fh.read(length))
                if found is not None:
                    return found
            else:
                fh.seek(length, io.SEEK_CUR)
        summary = _read_summary(fh, size, DEFAULT_RECORD_SIZE_LIMIT)
        for offset in summary.metadata_starts if summary is not None else ():
            fh.seek(offset)
            head = fh.read(_RECORD_HEAD)
            length = int.from_bytes(head[1:], "little")
            if len(head) == _RECORD_HEAD and length <= _METADATA_MAX:
                found = _recording_record(head + fh.read(length))
                if found is not None:
                    return found
    return {}


def _recording_record(data: bytes) -> dict[str, str] | None:
    """The `sisa.recording` metadata if the record in `data` is it (None for any other record,
    or one that does not parse)."""
    with contextlib.suppress(*_PARSE_ERRORS, _OverLimitError, StopIteration):
        record = next(_records(data, _METADATA_MAX))
        if isinstance(record, Metadata) and record.name == METADATA_NAME:
            return {str(k): str(v) for k, v in record.metadata.items()}
    return None


@dataclass(frozen=True)
class PartLabel:
    """Where a file's `sisa.recording` metadata places it: which part of which recording."""

    path: Path
    index: int  # its `part`: 0, 1, ...
    first_part: str  # the file name of part 0
    recording_id: str  # "" in a log recorded before parts carried one

    def same_recording(self, other: PartLabel) -> bool:
        """By the recording id; without one (an older log), by the first part's name only."""
        return (self.recording_id, self.first_part) == (other.recording_id, other.first_part)


def part_label(path: Path) -> PartLabel | None:
    """Where `path` sits in its recording; None for a file without SISA's part metadata (not
    written by SISA's recorder, or damaged there)."""
    meta = recording_metadata(path)
    try:
        index = int(meta["part"])
    except (KeyError, ValueError):
        return None
    if index < 0 or "first_part" not in meta:
        return None
    return PartLabel(Path(path), index, meta["first_part"], meta.get("recording_id", ""))


@dataclass(frozen=True)
class SplitSet:
    """The files of a log as they are to be read, and what is missing of the recording."""

    paths: list[Path]  # in part order when every file says its part, else as given
    notes: list[str]  # the parts of the recording that are not given, in words
    check_times: bool  # parts without a recording id: their log times must follow each other


def split_set(paths: Sequence[Path]) -> SplitSet:
    """Check that the files are parts of ONE recording and put them in part order (the order
    they are given in carries no meaning). InputError names a part of another recording (told
    by the recording id; in a log recorded before parts carried one, by the first part's name,
    and while it is read by its log times: `LogReader`) or a part given twice over (a part and
    its recovered copy). Files without SISA's part metadata are read as given, unchecked."""
    paths = [Path(p) for p in paths]
    labels = [part_label(p) for p in paths]
    known = [label for label in labels if label is not None]
    _refuse_mixed(known)
    if len(known) < len(labels):
        return SplitSet(paths, [], False)
    known.sort(key=lambda label: label.index)
    return SplitSet([label.path for label in known], _missing_notes(known),
                    len(known) > 1 and not known[0].recording_id)


def _refuse_mixed(labels: list[PartLabel]) -> None:
    """InputError for a part of another recording than most of `labels`, or a part twice."""
    if len(labels) < 2:
        return
    in_order = sorted(labels, key=lambda label: label.index)
    # the recording most parts are of (on a tie, the one with the lowest part), by its first
    counts = Counter((label.recording_id, label.first_part) for label in in_order)
    ref = next(label for label in in_order
               if (label.recording_id, label.first_part) == counts.most_common(1)[0][0])
    for label in in_order:
        if not label.same_recording(ref):
            raise InputError(f"{label.path} is part {label.index} of another recording "
                             f"({_which(label)}) than {ref.path} ({_which(ref)}): each "
                             "flight's parts are read together, not mixed")
    seen: dict[int, PartLabel] = {}
    for label in labels:
        other = seen.setdefault(label.index, label)
        if other is not label:
            raise InputError(f"{label.path} is part {label.index} of the recording, as is "
                             f"{other.path} (a copy, or a recovered copy of it?): each part of "
                             "a flight is read once")


def _which(label: PartLabel) -> str:
    """The recording a part says it is of, in words (its metadata shown safely: damage can
    leave anything there)."""
    if label.recording_id:
        return f"id {shown_text(label.recording_id)}"
    return f"no recording id, first part {shown_text(label.first_part)}"


def _missing_notes(labels: list[PartLabel]) -> list[str]:
    """Words for the parts missing before and between `labels` (in part order); parts after
    the last cannot be told from the end of the flight."""
    notes = []
    first = labels[0]
    if first.index > 0:
        what, verb = _parts_phrase(first, 0, first.index)
        notes.append(f"{first.path} is part {first.index} of a split recording whose {what} "
                     f"{verb} not given: the log is read from part {first.index} on")
    for before, after in pairwise(labels):
        if after.index > before.index + 1:
            what, verb = _parts_phrase(first, before.index + 1, after.index)
            notes.append(f"{what} of the split recording {shown_text(first.first_part)} {verb} "
                         f"not given (between {before.path} and {after.path}): the log is read "
                         f"without {'it' if verb == 'is' else 'them'}, a hole in the flight")
    return notes


def _parts_phrase(label: PartLabel, start: int, stop: int) -> tuple[str, str]:
    """('part 2 (flight_002.mcap)', 'is') or ('parts 0-1 (flight.mcap, flight_001.mcap)',
    'are'): parts start..stop-1 of label's recording, with their file names."""
    names = [shown_text(part_path(Path(label.first_part), i).name) for i in range(start, stop)]
    if len(names) > _NAMES_SHOWN:
        names = [*names[:_NAMES_SHOWN - 1], "...", names[-1]]
    if stop - start == 1:
        return f"part {start} ({names[0]})", "is"
    return f"parts {start}-{stop - 1} ({', '.join(names)})", "are"


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
                self.stats.undecodable += 1
                continue
            yield channel.topic, msg.log_time, obj

    def raw(self) -> Iterator[tuple[ChannelInfo, Message]]:
        """Every readable message, in file order, with its channel."""
        previous: tuple[Path, int] | None = None  # the last part with messages, its end
        for path in self.paths:
            fstats = FileStats(path, path.stat().st_size)
            self.stats.files.append(fstats)
            marks = {topic: len(times) for topic, times in self._times.items()}
            for channel, msg in _FileScan(path, fstats, self.record_size_limit).messages():
                self._account(channel, msg)
                yield channel, msg
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

    def _account(self, channel: ChannelInfo, msg: Message) -> None:
        topic = channel.topic
        ts = self.stats.topics.get(topic)
        if ts is None:
            ts = self.stats.topics[topic] = TopicStats(topic, channel.schema_name)
            self._times[topic] = array("Q")
        ts.count += 1  # the rest of the timing is filled in at the end of the pass
        self._times[topic].append(msg.log_time)
        expected = self._next_seq.get(topic)
        if expected is not None and msg.sequence != expected:
            jump = (msg.sequence - expected) % _SEQUENCE_MOD
            ts.lost_by_sequence += jump if jump < _SEQUENCE_MOD // 2 else 0
        self._next_seq[topic] = (msg.sequence + 1) % _SEQUENCE_MOD

    def _finish(self) -> None:
        for topic, ts in self.stats.topics.items():
            times = np.sort(np.frombuffer(self._times[topic], dtype=np.uint64))
            _fill_timing(ts, times)
        self._times.clear()


def _usual_interval_ns(intervals: npt.NDArray[np.uint64], median_ns: int) -> int:
    """The longest silence a topic keeps at least once every RHYTHM_NS on average: its median
    interval for a steady stream, the time between bursts for one that talks in bursts (a GPS
    receiver's sentences, once a second), which the median would call a gap every time."""
    recurrences = int(intervals.sum() // RHYTHM_NS)
    if not 1 <= recurrences < len(intervals):
        return median_ns
    return max(median_ns, int(np.partition(intervals, -recurrences)[-recurrences]))


def _local_usual_ns(starts_ns: npt.NDArray[np.uint64], intervals: npt.NDArray[np.uint64],
                    overall_ns: int) -> npt.NDArray[np.int64]:
    """The usual interval around each interval: as _usual_interval_ns, over the RHYTHM_BIN_NS
    of log time it starts in and the bins either side (the longest silence kept at least every
    RHYTHM_NS there), so a topic whose rhythm changes in flight (frame pulses while the scanner
    records, the PPS alone between strips) is judged by the rhythm it had at the time. Where
    those bins are too short (under two RHYTHM_NS: the log's last seconds, a short log) or hold
    too few intervals to tell, the topic's overall usual interval."""
    bins = ((starts_ns - starts_ns[0]) // RHYTHM_BIN_NS).astype(np.int64)
    n_bins = int(bins[-1]) + 1
    span_ns = int(starts_ns[-1] - starts_ns[0] + intervals[-1])
    extent_ns = np.minimum(RHYTHM_BIN_NS, span_ns - np.arange(n_bins) * RHYTHM_BIN_NS)
    k = extent_ns // RHYTHM_NS  # the silences a bin's rhythm keeps: its k-th longest
    order = np.lexsort((-intervals.astype(np.int64), bins))  # by bin, longest first
    first = np.searchsorted(bins[order], np.arange(n_bins))
    count = np.bincount(bins, minlength=n_bins)
    per_bin = np.full(n_bins + 2, -1, dtype=np.int64)  # -1: cannot tell; padded both sides
    enough = (k >= 2) & (count >= k)
    per_bin[1:-1][enough] = intervals[order[first[enough] + k[enough] - 1]].astype(np.int64)
    around = np.maximum(np.maximum(per_bin[:-2], per_bin[1:-1]), per_bin[2:])
    usual = around[bins]
    return np.where(usual >= 0, usual, overall_ns)


def _fill_timing(ts: TopicStats, times: npt.NDArray[np.uint64]) -> None:
    """Count, span, median and usual interval; the gaps: intervals longer than GAP_FACTOR x
    the usual interval around them."""
    ts.count = len(times)
    if not ts.count:
        return
    ts.first_ns, ts.last_ns = int(times[0]), int(times[-1])
    if ts.count < 3:
        return
    intervals = np.diff(times)
    ts.median_interval_ns = int(np.median(intervals))
    ts.usual_interval_ns = _usual_interval_ns(intervals, ts.median_interval_ns)
    if ts.topic in PATTERNED_TOPICS:
        ts.gap_count = None
        return
    usual = _local_usual_ns(times[:-1], intervals, ts.usual_interval_ns)
    (idx,) = np.nonzero((usual > 0) & (intervals > GAP_FACTOR * usual))
    ts.gap_count = len(idx)
    ts.gaps = [Gap(ts.topic, int(times[i]), int(times[i + 1]), int(usual[i]))
               for i in idx[:MAX_GAPS_KEPT]]


class _FileScan:
    """Reads one file record by record; what it could not read goes into `fstats`."""

    def __init__(self, path: Path, fstats: FileStats, record_size_limit: int) -> None:
        self.path = path
        self.fstats = fstats
        self.limit = record_size_limit
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, ChannelInfo] = {}
        self._summary: _Summary | None = None
        self._summary_read = False  # looked up once: on damage, or once a channel is missing
        self._summary_declared = False

    def messages(self) -> Iterator[tuple[ChannelInfo, Message]]:
        fs = self.fstats
        with open_log(self.path) as fh:
            source = _WholeRecords(fh, len(MCAP_MAGIC), fs.size_bytes, self.limit)
            fs.bytes_readable = source.position
            try:
                for start, record in self._records(fh, source):
                    batch = self._on_record(record, start, source.position)
                    fs.bytes_readable = source.position
                    yield from batch
            except _PARSE_ERRORS as exc:  # not expected: the records are parsed one by one
                self._problem(f"unreadable record after byte {fs.bytes_readable}: {exc}")
            if fs.complete:
                fs.bytes_readable = source.position

    def _records(self, fh: BinaryIO, source: _WholeRecords) -> Iterator[tuple[int, object]]:
        """Top-level records with their offsets, each parsed from its own bytes only, so damage
        inside a record (an inner length gone wrong) is skipped with it instead of running on
        into the records after it. After a record that cannot be framed or parsed, reading goes
        on at the next record the reader can trust (_resume_at), or at one the record before it
        ran over (_overrun). Ends where the data does, or after the footer and the closing
        magic."""
        size = self.fstats.size_bytes
        previous: int | None = None  # where the last record that framed began
        while True:
            start = source.position
            head = source.read(_RECORD_HEAD)
            if not head:
                return  # the end of what was written
            length = int.from_bytes(head[1:], "little")
            framed = length <= self.limit and length <= size - source.position
            if previous is not None and not framed:
                back = self._overrun(fh, previous, start)
                if back is not None:
                    source.seek(back)
                    previous = None
                    continue
            if not framed:
                resume = self._resume_at(fh, start, None)
                if resume is None:  # nothing readable after it: the file was cut short here
                    if length > self.limit:
                        self._problem(f"unreadable record after byte {start}: "
                                      f"{_length_problem(head[0], length, self.limit)}")
                    return
                self._skip(fh, start, resume, None, head[0],
                           f"unreadable record at byte {start}: "
                           f"{_length_problem(head[0], length, self.limit, size - start)}")
                source.seek(resume)
                previous = None
                continue
            body = source.read(length)
            if len(body) != length:
                return  # the file shrank as it was read
            if head[0] == _ZEROED_OPCODE:  # storage gone to zeros (a power cut on some file
                # systems): every 9 zero bytes frame as an empty record, and unknown records
                # are passed over, so without this the stretch went uncounted
                resume = self._resume_at(fh, start, None)
                if resume is None:
                    self._problem(f"zeros from byte {start} to the end (a power cut?)")
                    return
                self._skip(fh, start, resume, None, head[0], f"zeros at byte {start}")
                source.seek(resume)
                previous = None
                continue
            if head[0] not in _KNOWN_OPCODES:  # a record type from a later MCAP version:
                previous = start  # skipped, as the spec says; unless the summary knows better
                if self._indexes_chunk(start):
                    self.fstats.chunks_skipped += 1
                    self.fstats.bytes_skipped += source.position - start
                    self._problem(f"chunk at byte {start} skipped: its opcode is damaged "
                                  f"({head[0]:#04x})")
                continue
            try:
                record = next(_records(head + body, self.limit, emit_chunks=True))
            except (*_PARSE_ERRORS, _OverLimitError) as exc:
                end = source.position
                back = None if previous is None else self._overrun(fh, previous, start)
                if back is not None:
                    source.seek(back)
                    previous = None
                    continue
                resume = self._resume_at(fh, start, end) or end  # at the latest, its end
                self._skip(fh, start, resume, end, head[0],
                           f"damaged record (opcode {head[0]:#04x}) ending at byte {end} "
                           f"skipped: {exc}")
                source.seek(resume)  # the search for it may have moved the file position
                previous = None
                continue
            previous = start
            yield start, record
            if isinstance(record, Footer):
                self.fstats.complete = source.read(len(MCAP_MAGIC)) == MCAP_MAGIC
                if not self.fstats.complete:
                    self._problem("no closing magic after the footer")
                return

    def _resume_at(self, fh: BinaryIO, start: int, end: int | None) -> int | None:
        """Where to read on after the unreadable record at `start`. `end`: where it ends if its
        length can be believed (it parsed no further). A complete file's summary (CRC-checked)
        says where every chunk, metadata record and the summary begin; without one, the next
        chunk whose framing is consistent, else the footer of a file that ends in one. None:
        nothing readable after it."""
        size = self.fstats.size_bytes
        summary = self._summary_info()
        if summary is not None:
            i = bisect.bisect_right(summary.resume_points, start)
            known = summary.resume_points[i] if i < len(summary.resume_points) else None
            found = None
        else:
            known = next((p for p in _footer_points(fh, size) if p > start), None)
            bound = known if known is not None else size
            found = _find_chunk(fh, start + 1, min(bound, end or size), bound, self.limit)
        points = [p for p in (found, known, end) if p is not None]
        return min(points) if points else None

    def _indexes_chunk(self, start: int) -> bool:
        """Whether the summary of a complete file says a chunk begins at `start`."""
        summary = self._summary_info()
        if summary is None:
            return False
        i = bisect.bisect_left(summary.chunk_starts, start)
        return i < len(summary.chunk_starts) and summary.chunk_starts[i] == start

    def _overrun(self, fh: BinaryIO, previous: int, start: int) -> int | None:
        """A record the reader can trust that begins inside the one read before the unreadable
        record at `start` (from `previous`): that one's length was damaged to a larger value
        that still framed, and it ran over the records after it. Read on there (what it ran
        over was never read as records, so nothing is read twice); None if there is none."""
        summary = self._summary_info()
        if summary is not None:
            i = bisect.bisect_right(summary.resume_points, previous)
            back = summary.resume_points[i] if i < len(summary.resume_points) else None
            back = back if back is not None and back < start else None
        else:
            known = next((p for p in _footer_points(fh, self.fstats.size_bytes)
                          if p > previous), None)
            bound = known if known is not None else self.fstats.size_bytes
            back = _find_chunk(fh, previous + 1, min(start, bound), bound, self.limit)
        if back is not None:
            self._problem(f"the record at byte {previous} ran over the one at byte {back} (a "
                          f"damaged length); read on there")
        return back

    def _skip(self, fh: BinaryIO, start: int, resume: int, end: int | None, opcode: int,
              why: str) -> None:
        """Count what lies between `start` and `resume` (`end`: where the record at `start`
        ends, if its length could be believed): the chunks the summary indexes there; without
        one, the record at `start` if it framed as a chunk, or a stretch whose first record
        could not be framed (its header is damaged) as one chunk: nearly all of a flight log's
        bytes are chunks."""
        fs = self.fstats
        fs.bytes_skipped += resume - start
        if self._summary is not None:
            starts = self._summary.chunk_starts
            fs.chunks_skipped += bisect.bisect_left(starts, resume) - \
                bisect.bisect_left(starts, start)
        elif opcode == Opcode.CHUNK or end is None:
            fs.chunks_skipped += 1
        self._problem(why if resume == end else
                      f"{why}; {resume - start} bytes skipped, read on at byte {resume}")
        if self._summary is None:  # nothing else declares what it may have declared
            self._salvage_stretch(fh, start, resume)

    def _on_record(self, record: object, start: int, end: int
                   ) -> list[tuple[ChannelInfo, Message]]:
        if isinstance(record, Chunk):
            return self._chunk(record, start, end)
        if isinstance(record, Message):
            return self._message(record)
        self._declare(record)
        if isinstance(record, Header):
            self.fstats.library = record.library
        elif isinstance(record, Metadata):
            self.fstats.metadata[record.name] = dict(record.metadata)
        elif isinstance(record, Footer):
            self.fstats.has_summary = record.summary_start != 0
        return []

    def _declare(self, record: object) -> None:
        if isinstance(record, Schema):
            self.schemas[record.id] = record
        elif isinstance(record, Channel) and record.id not in self.channels:
            schema = self.schemas.get(record.schema_id)
            self.channels[record.id] = ChannelInfo(
                record.id, record.topic, record.message_encoding,
                schema.name if schema else "", schema.encoding if schema else "",
                schema.data if schema else b"")

    def _chunk(self, chunk: Chunk, start: int, end: int) -> list[tuple[ChannelInfo, Message]]:
        """All the chunk's messages, or none if the chunk is damaged."""
        try:
            records = breakup_chunk(_uncompressed(chunk, self.limit), validate_crc=True)
        except _PARSE_ERRORS as exc:
            self.fstats.chunks_skipped += 1
            self.fstats.bytes_skipped += end - start
            self._problem(f"chunk ending at byte {end} skipped: {exc}")
            self._salvage_declarations(chunk)
            return []
        self.fstats.chunks_read += 1
        out: list[tuple[ChannelInfo, Message]] = []
        for record in records:
            if isinstance(record, Message):
                out.extend(self._message(record))
            else:
                self._declare(record)
        return out

    def _salvage_declarations(self, chunk: Chunk) -> None:
        """The channels a damaged chunk declares that are exactly what SISA writes (topic,
        encoding, schema name and text), read up to the damage: the later chunks' messages
        on them are not lost with it. Anything else in it is not trusted."""
        schemas: dict[int, Schema] = {}
        try:
            data = _uncompressed(chunk, self.limit).data
            for record in _records(data, self.limit):
                self._salvage(record, schemas)
        except (*_PARSE_ERRORS, _OverLimitError):
            return  # the damage itself: what came before it is kept

    def _salvage_stretch(self, fh: BinaryIO, start: int, end: int) -> None:
        """As _salvage_declarations, for a stretch of the file skipped as unreadable (a chunk
        whose header is damaged): every whole Schema and Channel record found in it (SISA's
        are far shorter than _DECLARATION_MAX), read a block at a time."""
        schemas: dict[int, Schema] = {}
        pos = start
        while pos < end:
            span = min(_SCAN_BLOCK, end - pos)
            fh.seek(pos)
            data = fh.read(min(span + _DECLARATION_MAX, end - pos))
            for opcode in (Opcode.SCHEMA, Opcode.CHANNEL):  # a channel names an earlier schema
                marker = opcode.to_bytes(1, "little")
                i = data.find(marker, 0, span)
                while i >= 0:
                    length = int.from_bytes(data[i + 1:i + _RECORD_HEAD], "little")
                    if length <= len(data) - i - _RECORD_HEAD:
                        with contextlib.suppress(*_PARSE_ERRORS, _OverLimitError):
                            record = data[i:i + _RECORD_HEAD + length]
                            self._salvage(next(_records(record, self.limit)), schemas)
                    i = data.find(marker, i + 1, span)
            pos += span

    def _salvage(self, record: McapRecord, schemas: dict[int, Schema]) -> None:
        """Keep a schema of damaged data if it is exactly one SISA writes; declare a channel
        if it is exactly what SISA writes for its topic, with such a schema."""
        if isinstance(record, Schema) and _is_ours(record):
            schemas[record.id] = record
        elif isinstance(record, Channel) and record.id not in self.channels:
            schema = schemas.get(record.schema_id) or self.schemas.get(record.schema_id)
            if schema is not None and record.message_encoding == MESSAGE_ENCODING \
                    and TOPIC_SCHEMAS.get(record.topic) == schema.name:
                self.schemas.setdefault(schema.id, schema)
                self._declare(record)

    def _message(self, msg: Message) -> list[tuple[ChannelInfo, Message]]:
        channel = self.channels.get(msg.channel_id)
        if channel is None and not self._summary_declared:  # declared in a damaged chunk
            self._summary_declared = True
            summary = self._summary_info()
            for declared in summary.declarations if summary is not None else ():
                self._declare(declared)
            channel = self.channels.get(msg.channel_id)
        if channel is None:
            self._problem(f"message on undeclared channel {msg.channel_id} skipped")
            return []
        return [(channel, msg)]

    def _summary_info(self) -> _Summary | None:
        if not self._summary_read:
            self._summary_read = True
            with open_log(self.path) as fh:
                self._summary = _read_summary(fh, self.fstats.size_bytes, self.limit)
        return self._summary

    def _problem(self, text: str) -> None:
        if len(self.fstats.problems) < MAX_PROBLEMS_KEPT:
            self.fstats.problems.append(text)


def _length_problem(opcode: int, length: int, limit: int, room: int | None = None) -> str:
    what = f"a record (opcode {opcode:#04x}) of {length} bytes"
    if length > limit:
        return f"{what} exceeds limit {limit}"
    return f"{what} runs past the end of the file ({room} bytes from its start)"


@dataclass(frozen=True)
class _Summary:
    """The summary section of a complete file, read only when its CRC checks."""

    declarations: list[Schema | Channel]
    chunk_starts: list[int]  # sorted
    resume_points: list[int]  # sorted: chunks, metadata records, the summary, the footer
    metadata_starts: list[int] = field(default_factory=list)  # the sisa.recording records


def _footer(fh: BinaryIO, size: int) -> tuple[int, bytes] | None:
    """(offset, bytes) of the footer record of a file that ends in one and the closing magic."""
    footer_at = size - len(MCAP_MAGIC) - _RECORD_HEAD - _FOOTER_BODY
    if footer_at <= len(MCAP_MAGIC):
        return None
    fh.seek(footer_at)
    footer = fh.read(_RECORD_HEAD + _FOOTER_BODY + len(MCAP_MAGIC))
    if footer[0] != Opcode.FOOTER or footer[-len(MCAP_MAGIC):] != MCAP_MAGIC or \
            int.from_bytes(footer[1:_RECORD_HEAD], "little") != _FOOTER_BODY:
        return None
    return footer_at, footer


def _footer_points(fh: BinaryIO, size: int) -> list[int]:
    """Where the summary section (when the footer gives a plausible start) and the footer of a
    file that ends in a footer begin: places to read on at when its summary cannot be used."""
    found = _footer(fh, size)
    if found is None:
        return []
    footer_at, footer = found
    (summary_start,) = struct.unpack_from("<Q", footer, _RECORD_HEAD)
    return [summary_start, footer_at] if len(MCAP_MAGIC) < summary_start < footer_at \
        else [footer_at]


def _read_summary(fh: BinaryIO, size: int, limit: int) -> _Summary | None:
    """The summary section, when the file ends in a footer whose summary CRC checks; None
    otherwise (a file cut short, a damaged summary)."""
    found = _footer(fh, size)
    if found is None:
        return None
    footer_at, footer = found
    summary_start, _, summary_crc = struct.unpack_from("<QQI", footer, _RECORD_HEAD)
    if not len(MCAP_MAGIC) < summary_start < footer_at or footer_at - summary_start > limit \
            or summary_crc == 0:
        return None
    fh.seek(summary_start)
    summary = fh.read(footer_at - summary_start)
    checked = footer[:_RECORD_HEAD + _FOOTER_BODY - 4]  # the footer up to its CRC field
    if zlib.crc32(checked, zlib.crc32(summary)) != summary_crc:
        return None
    declarations: list[Schema | Channel] = []
    chunks: set[int] = set()
    metadata: set[int] = set()
    points = {summary_start, footer_at}
    in_data = range(len(MCAP_MAGIC), summary_start)
    # it ends in EndOfFile (no footer in these bytes); its CRC has checked what came before
    with contextlib.suppress(*_PARSE_ERRORS, _OverLimitError):
        for record in _records(summary, limit):
            if isinstance(record, Schema | Channel):
                declarations.append(record)
            elif isinstance(record, ChunkIndex) and record.chunk_start_offset in in_data:
                chunks.add(record.chunk_start_offset)
            elif isinstance(record, MetadataIndex) and record.offset in in_data:
                points.add(record.offset)
                if record.name == METADATA_NAME:
                    metadata.add(record.offset)
    return _Summary(declarations, sorted(chunks), sorted(points | chunks), sorted(metadata))


def _find_chunk(fh: BinaryIO, first: int, last: int, bound: int, limit: int) -> int | None:
    """The offset of the first Chunk record that starts in [first, last), ends by `bound` and
    whose framing is consistent; None if there is none."""
    pos = first
    while pos < last:
        span = min(_SCAN_BLOCK, last - pos)
        fh.seek(pos)
        buf = fh.read(span + _CHUNK_PEEK)
        i = buf.find(Opcode.CHUNK.to_bytes(1, "little"), 0, span)
        while i >= 0:
            if _chunk_framing(buf, i, bound - pos - i, limit):
                return pos + i
            i = buf.find(Opcode.CHUNK.to_bytes(1, "little"), i + 1, span)
        pos += span
    return None


def _chunk_framing(buf: bytes, i: int, room: int, limit: int) -> bool:
    """Whether a Chunk record at buf[i] frames consistently: its length fits in `room` and the
    limit, its compression is one MCAP names, and its records length is what is left of it.
    Random bytes, or a message's bytes, pass with odds of about 2^-64."""
    if len(buf) - i < _RECORD_HEAD + _CHUNK_FIXED - 8:
        return False
    length, _, _, uncompressed, _, name_len = struct.unpack_from("<QQQQII", buf, i + 1)
    if not _CHUNK_FIXED <= length <= min(limit, room - _RECORD_HEAD) or uncompressed > limit \
            or len(buf) - i < _RECORD_HEAD + _CHUNK_FIXED + name_len:
        return False
    at = i + _RECORD_HEAD + _CHUNK_FIXED - 8
    if buf[at:at + name_len] not in _COMPRESSIONS:
        return False
    (records_len,) = struct.unpack_from("<Q", buf, at + name_len)
    return bool(records_len == length - _CHUNK_FIXED - name_len)


def _is_ours(schema: Schema) -> bool:
    """A schema exactly as SISA's recorder writes it."""
    return schema.encoding == SCHEMA_ENCODING and schema.data in KNOWN_SCHEMA_BYTES.get(
        schema.name, frozenset())


def _uncompressed(chunk: Chunk, limit: int) -> Chunk:
    """The chunk with its records uncompressed, never inflated past the size it declares (nor
    the record size limit): a damaged size or a compression bomb must not allocate gigabytes."""
    if chunk.uncompressed_size > limit:
        raise ValueError(f"declares {chunk.uncompressed_size} bytes uncompressed (limit {limit})")
    data = chunk.data
    if chunk.compression:
        data = _inflate(chunk.compression, data, chunk.uncompressed_size + 1)
    if len(data) != chunk.uncompressed_size:
        raise ValueError("size does not match its header")
    return dataclasses.replace(chunk, compression="", data=data)


def _inflate(compression: str, data: bytes, max_bytes: int) -> bytes:
    """At most `max_bytes` of the decompressed data."""
    try:
        if compression == "zstd":
            out = bytearray()
            with zstandard.ZstdDecompressor().stream_reader(data) as reader:
                while len(out) < max_bytes and (piece := reader.read(max_bytes - len(out))):
                    out += piece
            return bytes(out)
        if compression == "lz4":
            inflated: bytes = lz4.frame.LZ4FrameDecompressor().decompress(data,
                                                                          max_length=max_bytes)
            return inflated
    except (zstandard.ZstdError, RuntimeError) as exc:
        raise ValueError(f"{compression}: {exc}") from None
    raise ValueError(f"unknown compression {compression!r}")


# --- decoding -----------------------------------------------------------------------------------

def _schema_properties(channel: ChannelInfo) -> dict[str, Any] | None:
    if channel.schema_encoding != "jsonschema":
        return None
    try:
        props = json.loads(channel.schema_data).get("properties")
    except (ValueError, AttributeError, RecursionError):
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
        return cls(_schema_properties(channel) or {})

    def __call__(self, data: bytes) -> dict[str, Any] | None:
        try:
            obj = json.loads(data)
            if not isinstance(obj, dict):
                return None
            for name in self.b64:
                obj[name] = base64.b64decode(obj[name])
            if self.numbers and (b'"NaN"' in data or b'Infinity"' in data):
                for name in self.numbers:
                    if isinstance(obj.get(name), str):
                        obj[name] = float(obj[name])
        except _JSON_ERRORS:
            return None
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


def read_log(path_or_paths: Paths) -> Iterator[tuple[str, int, dict[str, Any]]]:
    """Every readable message as (topic, log_time_ns, fields); bytes fields as bytes."""
    return iter(LogReader(path_or_paths))


def scan_log(path_or_paths: Paths) -> LogStats:
    """Read a whole log for its statistics, decoding only the recorder's health reports."""
    reader = LogReader(path_or_paths)
    decoders = _Decoders()
    health = reader.stats.health
    for channel, msg in reader.raw():
        if channel.topic == Topic.HEALTH:
            report = decoders.decode(channel, msg.data)
            if report is None:
                health.unreadable += 1
            else:
                health.add(report)
    return reader.stats


def read_messages(path_or_paths: Paths, cls: type[M], topic: Topic | str | None = None
                  ) -> Iterator[M]:
    """Every readable message of type `cls` (on every topic carrying it, or only `topic`)."""
    decoders = _Decoders()
    reader = LogReader(path_or_paths)
    for channel, msg in reader.raw():
        if channel.schema_name != cls.schema_name or (topic is not None and channel.topic != topic):
            continue
        where = f"{reader.stats.files[-1].path}: {channel.topic}"
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


# --- columns ------------------------------------------------------------------------------------

Column = tuple[str, tuple[str, ...], Any]  # column name, path into the JSON object, numpy dtype


def _columns(props: dict[str, Any], prefix: tuple[str, ...] = ()) -> list[Column]:
    """Flatten a JSON Schema's properties into typed columns ("timestamp.sec", ...)."""
    out: list[Column] = []
    for name, prop in props.items():
        path = (*prefix, name)
        kind = prop.get("type")
        if kind == "object" and isinstance(prop.get("properties"), dict):
            out.extend(_columns(prop["properties"], path))
            continue
        dtype: Any = {"integer": np.int64, "number": np.float64, "boolean": np.bool_,
                      "string": np.str_}.get(kind, object)
        if prop.get("contentEncoding") == "base64":
            dtype = object
        out.append((".".join(path), path, dtype))
    return out


def _column_values(objs: list[dict[str, Any]], path: tuple[str, ...]) -> list[Any]:
    if len(path) == 1:
        return [o[path[0]] for o in objs]
    values = []
    for o in objs:
        v: Any = o
        for key in path:
            v = v[key]
        values.append(v)
    return values


def _to_array(values: list[Any], dtype: Any, b64: bool) -> npt.NDArray[Any]:
    if dtype is np.int64 and not all(type(v) is int for v in values):
        raise TypeError("a value of an integer field is not an integer")  # numpy would truncate
    if b64 or dtype is object:
        arr = np.empty(len(values), dtype=object)
        arr[:] = [base64.b64decode(v) for v in values] if b64 else values
        return arr
    if dtype is np.str_:
        return np.array(values, dtype=np.str_) if values else np.array([], dtype=np.str_)
    return np.fromiter(values, dtype=dtype, count=len(values))


class _ColumnBuilder:
    """Accumulates one topic's messages in numpy arrays, one JSON batch at a time."""

    def __init__(self, props: dict[str, Any], fields: Sequence[str] | None = None) -> None:
        self.columns = [c for c in _columns(props) if fields is None or c[0] in fields]
        self.b64 = {name for name, p in props.items() if p.get("contentEncoding") == "base64"}
        self.parts: dict[str, list[npt.NDArray[Any]]] = {"log_time_ns": []}
        self.parts.update({name: [] for name, _, _ in self.columns})

    def add_batch(self, log_times: list[int], datas: list[bytes]) -> None:
        try:
            objs = json.loads(b"[" + b",".join(datas) + b"]")
            arrays = {name: _to_array(_column_values(objs, path), dtype, path[0] in self.b64)
                      for name, path, dtype in self.columns}
            times = np.array(log_times, dtype=np.int64)
        except _JSON_ERRORS as exc:
            raise DecodeError(f"a message does not match its schema: {exc}") from None
        self.parts["log_time_ns"].append(times)
        for name, arr in arrays.items():
            self.parts[name].append(arr)

    def result(self) -> dict[str, npt.NDArray[Any]]:
        out: dict[str, npt.NDArray[Any]] = {}
        dtypes = {name: dtype for name, _, dtype in self.columns} | {"log_time_ns": np.int64}
        for name, parts in self.parts.items():
            out[name] = np.concatenate(parts) if parts else np.array([], dtype=dtypes[name])
        return out


def _known_props(topic: str) -> dict[str, Any]:
    """The schema SISA writes on `topic`, for a log where the topic never appeared."""
    if topic == Topic.GPS_LOCATION:
        return dict(SCHEMAS["foxglove.LocationFix"]["properties"])
    try:
        cls = TOPIC_TYPES[Topic(topic)]
    except (ValueError, KeyError):
        return {}
    return dict(SCHEMAS[cls.schema_name]["properties"])


def read_columns(path_or_paths: Paths, topic: Topic | str) -> dict[str, npt.NDArray[Any]]:
    """One topic as numpy arrays, one per field (plus `log_time_ns`), in file order.

    integer → int64, number → float64 (NaN kept), boolean → bool, string → str, bytes and
    arrays → object; nested objects flatten to "parent.child".
    """
    return read_topics(path_or_paths, {str(topic): None})[str(topic)]


class _TopicBatches:
    """One topic's messages waiting to be converted, and its column builder."""

    def __init__(self, fields: Sequence[str] | None) -> None:
        self.fields = fields
        self.builder: _ColumnBuilder | None = None
        self.times: list[int] = []
        self.datas: list[bytes] = []

    def add(self, channel: ChannelInfo, log_time: int, data: bytes) -> None:
        if self.builder is None:
            self.builder = _ColumnBuilder(_schema_properties(channel) or {}, self.fields)
        self.times.append(log_time)
        self.datas.append(data)
        if len(self.datas) >= _BATCH:
            self.builder.add_batch(self.times, self.datas)
            self.times, self.datas = [], []

    def result(self, topic: str) -> dict[str, npt.NDArray[Any]]:
        if self.builder is None:
            self.builder = _ColumnBuilder(_known_props(topic), self.fields)
        if self.datas:
            self.builder.add_batch(self.times, self.datas)
        columns = self.builder.result()
        missing = [f for f in self.fields or () if f not in columns]
        if missing:
            raise DecodeError(f"the log's schema has no field {', '.join(missing)}")
        return columns


def read_topics(path_or_paths: Paths, wanted: Mapping[str, Sequence[str] | None], *,
                notes: list[str] | None = None) -> dict[str, dict[str, npt.NDArray[Any]]]:
    """Several topics as numpy columns in ONE streaming pass (each pass over a long log costs
    seconds): {topic: {field: array}} for the wanted fields (None: all), plus `log_time_ns`.
    A topic that never appears gives empty typed arrays; a message lacking a wanted field, or
    with a value of the wrong type, raises DecodeError. What could not be read (a file cut
    short, damaged chunks) is said as a DamagedLogWarning, the parts of a split recording that
    are not given as a MissingPartWarning, or either appended to `notes` if given (for a
    caller that reports its own warnings)."""
    batches = {topic: _TopicBatches(fields) for topic, fields in wanted.items()}
    reader = LogReader(path_or_paths)
    topic = ""
    try:  # an error names the file (the part being read) and the topic
        for channel, msg in reader.raw():
            batch = batches.get(channel.topic)
            if batch is not None:
                topic = channel.topic
                batch.add(channel, msg.log_time, msg.data)
        out = {}
        for topic, batch in batches.items():
            out[topic] = batch.result(topic)
    except DecodeError as exc:
        where = reader.stats.files[-1].path if reader.stats.files else reader.paths[0]
        raise DecodeError(f"{where}: {topic}: {exc}", raw=exc.raw) from None
    said: list[tuple[str, type[UserWarning]]] = [
        (note, MissingPartWarning) for note in reader.stats.part_notes]
    said += [(note, DamagedLogWarning) for fs in reader.stats.files for note in damage_notes(fs)]
    for note, kind in said:
        if notes is not None:
            notes.append(note)
        else:  # said once per file and kind (Python's warning registry)
            warnings.warn(note, kind, stacklevel=1)
    return out


def topics_in(stats: LogStats) -> Iterable[str]:
    """Topics of a log in a stable order (as declared by SISA's Topic enum, then the rest)."""
    order = {str(t): i for i, t in enumerate(Topic)}
    return sorted(stats.topics, key=lambda t: (order.get(t, len(order)), t))
