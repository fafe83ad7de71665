"""The crash-safe flight recorder: every logged message to MCAP, as JSON with a JSON Schema.

Why it is built this way:
- A flight log must survive a power cut or a SIGKILL. Messages go into small uncompressed chunks;
  at least every `flush_interval_s` (time.monotonic) the open chunk is closed, written and the file
  fsync'd, also when no message arrives (a background thread). A file killed mid-write is readable
  up to its last complete chunk by `recorder.reader`, and `recorder.recover` makes it whole.
- A recording is never overwritten: files are created with O_EXCL, and each appears under its
  name (a hard link) only once its header is on disk, so a power cut never leaves a file that is
  not MCAP.
- Long flights split by log time or by size into NAME.mcap, NAME_001.mcap, NAME_002.mcap, ...;
  each part is a complete MCAP file with its own schemas, channels and metadata.
- A disk error (ENOSPC, EIO, EFBIG) keeps what is on disk and ends as one `RecorderError`.

MCAP log_time = publish_time = the message's `t_host_ns`; sequence counts per topic from 0 across
parts, so a reader can tell lost messages from quiet ones. Every GpsFix is also written as a
`foxglove.LocationFix` on /gps/location_fix, so the log opens on Foxglove's map panel.
"""

from __future__ import annotations

import base64
import contextlib
import dataclasses
import errno
import inspect
import json
import math
import operator
import os
import re
import struct
import threading
import time
import uuid
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO, Final, Protocol, cast

import orjson
from mcap.opcode import Opcode
from mcap.records import MessageIndex
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

import sisa
from recorder.messages import (
    LOGGED_TYPES,
    GpsFix,
    LoggedMessage,
    PulseEdgeLog,
    RawBytes,
    Topic,
    json_schema,
)
from sisa.core.errors import ConfigError, EncodeError, InputError, RecorderError
from sisa.core.outdir import create_partial, open_new_file

RECORDER_ID: Final = f"sisa-recorder/{sisa.__version__}"
MESSAGE_ENCODING: Final = "json"
SCHEMA_ENCODING: Final = "jsonschema"
METADATA_NAME: Final = "sisa.recording"
DEFAULT_CHUNK_SIZE: Final = 64 * 1024  # ≈ 0.1 s of a 2 kHz INS stream
LOCATION_FRAME_ID: Final = "gps_antenna"
_SEQUENCE_MOD: Final = 2**32


class _Timed(Protocol):
    t_host_ns: int  # every logged type has it; LoggedMessage itself does not declare it


def _log_time(msg: LoggedMessage) -> int:
    """The message's t_host_ns as a plain int that MCAP can hold (uint64), or EncodeError."""
    value = cast(_Timed, msg).t_host_ns
    try:
        log_ns = operator.index(value)
    except TypeError:
        raise EncodeError(f"{msg.schema_name}.t_host_ns is not an integer: {value!r}") from None
    if not 0 <= log_ns < 2**64:
        raise EncodeError(f"{msg.schema_name}.t_host_ns out of range: {log_ns}")
    return log_ns




def _topic_types() -> dict[Topic, type[LoggedMessage]]:
    """Which message type each topic carries: each type's own topic, plus the per-port ones."""
    table: dict[Topic, type[LoggedMessage]] = {cls.topic: cls for cls in LOGGED_TYPES}
    table[Topic.SCANNER_RAW] = RawBytes
    table[Topic.CAMERA_RAW] = RawBytes
    table[Topic.PULSE_OUT] = PulseEdgeLog
    return table


TOPIC_TYPES: Final[Mapping[Topic, type[LoggedMessage]]] = _topic_types()

LOCATION_FIX_SCHEMA_NAME: Final = "foxglove.LocationFix"
LOCATION_FIX_NOTES: Final[Mapping[str, str]] = {
    "timestamp": "{sec, nsec}: host time of the fix (its log time), not GPS time",
    "frame_id": f'always "{LOCATION_FRAME_ID}"',
    "latitude": "GpsFix.lat_deg",
    "longitude": "GpsFix.lon_deg",
    "altitude": "GpsFix.height_m (ellipsoidal)",
    "position_covariance": "zeros: NMEA gives no covariance",
    "position_covariance_type": "always 0 (UNKNOWN)",
}
LOCATION_FIX_SCHEMA: Final[dict[str, Any]] = {
    "title": LOCATION_FIX_SCHEMA_NAME,
    "description": "GPS antenna position for Foxglove's map panel, written from every GpsFix "
                   "with quality > 0",
    "type": "object",
    "properties": {
        "timestamp": {"type": "object", "title": "time",
                      "properties": {"sec": {"type": "integer", "minimum": 0},
                                     "nsec": {"type": "integer", "minimum": 0,
                                              "maximum": 999_999_999}},
                      "required": ["sec", "nsec"]},
        "frame_id": {"type": "string"},
        "latitude": {"type": "number"},
        "longitude": {"type": "number"},
        "altitude": {"type": "number"},
        "position_covariance": {"type": "array", "items": {"type": "number"},
                                "minItems": 9, "maxItems": 9},
        "position_covariance_type": {"title": "foxglove.PositionCovarianceType",
                                     "oneOf": [{"title": "UNKNOWN", "const": 0},
                                               {"title": "APPROXIMATED", "const": 1},
                                               {"title": "DIAGONAL_KNOWN", "const": 2},
                                               {"title": "KNOWN", "const": 3}]},
    },
    "required": ["timestamp", "frame_id", "latitude", "longitude", "altitude",
                 "position_covariance", "position_covariance_type"],  # every message has all
}


SCHEMAS: Final[Mapping[str, dict[str, Any]]] = {
    **{cls.schema_name: json_schema(cls) for cls in LOGGED_TYPES},
    LOCATION_FIX_SCHEMA_NAME: LOCATION_FIX_SCHEMA,
}
SCHEMA_BYTES: Final[Mapping[str, bytes]] = {
    name: json.dumps(schema).encode() for name, schema in SCHEMAS.items()}  # as written

def _without_required(schema: dict[str, Any]) -> dict[str, Any]:
    return {k: _without_required(v) if isinstance(v, dict) else v
            for k, v in schema.items() if k != "required"}


# Every schema SISA's recorder has written, for the reader's salvage of damaged data: the
# current ones, and foxglove.LocationFix as written before it listed its required fields.
KNOWN_SCHEMA_BYTES: Final[Mapping[str, frozenset[bytes]]] = {
    name: frozenset({data} | ({json.dumps(_without_required(LOCATION_FIX_SCHEMA)).encode()}
                              if name == LOCATION_FIX_SCHEMA_NAME else set()))
    for name, data in SCHEMA_BYTES.items()}
TOPIC_SCHEMAS: Final[Mapping[str, str]] = {  # topic → the schema its channel is declared with
    **{str(topic): cls.schema_name for topic, cls in TOPIC_TYPES.items()},
    str(Topic.GPS_LOCATION): LOCATION_FIX_SCHEMA_NAME,
}


def part_path(path: Path, index: int) -> Path:
    """Name of part `index` of a split recording: NAME.mcap, NAME_001.mcap, NAME_002.mcap, ..."""
    path = Path(path)
    return path if index == 0 else path.with_name(f"{path.stem}_{index:03d}{path.suffix}")


PART_SUFFIX = r"_(\d{3,})"  # NAME_001: a further part's index after the first part's stem


def named_as_part(path: Path) -> tuple[Path, int] | None:
    """(the first part's name, the index) when `path` is named as a further part of a split
    recording (part_path's NAME_001.mcap, ...), else None."""
    path = Path(path)
    found = re.fullmatch("(.+)" + PART_SUFFIX, path.stem)
    if found is None or int(found.group(2)) == 0:
        return None
    return path.with_name(found.group(1) + path.suffix), int(found.group(2))


def split_parts(path: Path) -> list[Path]:
    """The parts of a split recording that exist, in order, given the name of its first part."""
    path = Path(path)
    pattern = re.compile(re.escape(path.stem) + PART_SUFFIX + re.escape(path.suffix) + "$")
    numbered = sorted((int(m.group(1)), p) for p in path.parent.glob(f"{path.stem}_*")
                      if (m := pattern.match(p.name)))
    return ([path] if path.exists() else []) + [p for _, p in numbered]


# --- JSON encoding ------------------------------------------------------------------------------

def _json_default(value: object) -> object:
    """bytes as base64 (as the schemas declare every bytes field); numpy scalars and arrays that
    slip into a message as plain numbers."""
    if isinstance(value, bytes | bytearray):
        return base64.b64encode(value).decode("ascii")
    item = getattr(value, "tolist", None)
    if callable(item):
        return item()
    raise EncodeError(f"{type(value).__name__} is not JSON serialisable")


def _finite(value: object) -> object:
    """Non-finite floats as proto3-JSON strings ("NaN", "Infinity", "-Infinity"): valid JSON."""
    if isinstance(value, float) and not math.isfinite(value):
        return "NaN" if math.isnan(value) else ("Infinity" if value > 0 else "-Infinity")
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


_JSON_NAN: Final = json.JSONEncoder(separators=(",", ":"), default=_json_default)


def _dumps(obj: object) -> bytes:
    """Compact JSON of a dict or a message dataclass (fields in declaration order). orjson
    writes a message in a tenth of the time of the json module, the largest share of the
    recorder's own CPU; it writes a non-finite float as null, and no message field is ever
    None, so a null sends the message down the exact slow path (rare: a "null" inside a text
    or base64 field takes it too, with the same result)."""
    try:
        data = orjson.dumps(obj, default=_json_default)
    except orjson.JSONEncodeError:  # what orjson does not take (an int beyond 64 bits, a type
        data = b"null"  # nothing converts): the json module's verdict, on the slow path
    if b"null" not in data:
        return data
    fields = obj if isinstance(obj, Mapping) else obj.__dict__
    return _JSON_NAN.encode({k: _finite(v) for k, v in fields.items()}).encode()


def _check_schema(cls: type[LoggedMessage]) -> None:
    """A message is written field by field in declaration order: its JSON Schema must list the
    same fields in that order, base64 exactly for its `bytes` fields (as `_dumps` writes them)."""
    schema = json_schema(cls)["properties"]
    names = tuple(schema)
    if names != tuple(f.name for f in dataclasses.fields(cls)):  # type: ignore[arg-type]
        raise EncodeError(f"{cls.schema_name}: schema and fields disagree")
    b64 = {name for name, prop in schema.items() if prop.get("contentEncoding") == "base64"}
    kinds = {f.name: f.type for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    if any(kinds[name] not in ("bytes", bytes) for name in b64) or any(
            kinds[name] in ("bytes", bytes) for name in names if name not in b64):
        raise EncodeError(f"{cls.schema_name}: base64 fields and bytes fields disagree")


for _cls in LOGGED_TYPES:
    _check_schema(_cls)


def encode_message(msg: LoggedMessage) -> bytes:
    """The JSON bytes the log holds for `msg` (compact; bytes base64; NaN as "NaN")."""
    if type(msg) not in LOGGED_TYPES:
        raise EncodeError(f"{type(msg).__name__} is not a logged message type")
    return _dumps(msg)


def location_fix(fix: GpsFix) -> bytes:
    """A GpsFix as foxglove.LocationFix JSON. Its timestamp is the host time of the fix (the log
    time, so the map follows Foxglove's timeline); the covariance is unknown (NMEA gives none)."""
    sec, nsec = divmod(fix.t_host_ns, 1_000_000_000)
    return _dumps({"timestamp": {"sec": sec, "nsec": nsec}, "frame_id": LOCATION_FRAME_ID,
                   "latitude": fix.lat_deg, "longitude": fix.lon_deg, "altitude": fix.height_m,
                   "position_covariance": [0.0] * 9, "position_covariance_type": 0})


# --- one file of the recording ------------------------------------------------------------------

def _open_new(path: Path) -> BinaryIO:
    """Create `path`, failing if it exists (O_EXCL, no link followed): a recording is never
    overwritten (tests put a failing disk here)."""
    return os.fdopen(open_new_file(path), "wb")


def link_new(tmp: Path, path: Path, refusal: str) -> None:
    """Give the complete file `tmp` the name `path` too, never replacing an existing file
    (InputError '<path> already exists: <refusal>'); on a file system without hard links
    (FAT on a flash card) `tmp` is renamed instead. The caller removes `tmp` if it is left."""
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise InputError(f"{path} already exists: {refusal}") from None
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EXDEV) or path.exists():
            raise
        os.rename(tmp, path)


def fsync_dir(folder: Path) -> None:
    """Make a new name in `folder` survive a power cut (best effort)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


AddMessage = Callable[[int, int, bytes, int, int], None]
_MESSAGE_HEAD: Final = struct.Struct("<BQHIQQ")  # opcode, record length, channel, sequence,
# log time, publish time: a Message record up to its data


def message_appender(mcap: Writer) -> AddMessage:
    """`mcap.add_message` (channel_id, log_time, data, publish_time, sequence), one record
    packed in one call. The mcap package builds every message as a record object written field
    by field through a stream, a fifth of the recorder's own CPU; this does what its
    Writer.add_message does (mcap 1.6: statistics, the chunk's time range and message index,
    the record, a full chunk closed) on the writer's own state. It produces the same bytes
    (tests/recorder/test_writer.py compares the files); a version of mcap without that state
    gets its public add_message."""
    try:
        stats = mcap._Writer__statistics  # type: ignore[attr-defined]
        chunk = mcap._Writer__chunk_builder  # type: ignore[attr-defined]
        close_if_full = mcap._Writer__maybe_finalize_chunk  # type: ignore[attr-defined]
        counts, indices = stats.channel_message_counts, chunk.message_indices
    except AttributeError:
        return mcap.add_message
    if not hasattr(chunk.record_writer, "_buffer"):  # the record stream it writes into
        return mcap.add_message
    pack = _MESSAGE_HEAD.pack
    opcode = int(Opcode.MESSAGE)

    def add(channel_id: int, log_time: int, data: bytes, publish_time: int,
            sequence: int) -> None:
        if stats.message_count == 0 or log_time < stats.message_start_time:
            stats.message_start_time = log_time
        if log_time > stats.message_end_time:
            stats.message_end_time = log_time
        counts[channel_id] += 1
        stats.message_count += 1
        if chunk.num_messages == 0 or log_time < chunk.message_start_time:
            chunk.message_start_time = log_time
        if log_time > chunk.message_end_time:
            chunk.message_end_time = log_time
        index = indices.get(channel_id)
        if index is None:
            index = indices[channel_id] = MessageIndex(channel_id=channel_id, records=[])
        buffer = chunk.record_writer._buffer
        index.records.append((log_time, buffer.tell()))
        chunk.num_messages += 1
        buffer.write(pack(opcode, 22 + len(data), channel_id, sequence, log_time, publish_time))
        buffer.write(data)
        close_if_full()

    return add


@dataclass
class _Part:
    """One open MCAP file of the recording and the channels registered in it."""

    path: Path
    file: BinaryIO
    mcap: Writer
    add_message: AddMessage
    channels: dict[tuple[Topic, str], int] = field(default_factory=dict)
    schemas: dict[str, int] = field(default_factory=dict)  # schema name → its one id
    first_log_ns: int | None = None
    dirty: bool = False

    @classmethod
    def create(cls, path: Path, chunk_size: int, metadata: Mapping[str, str]) -> _Part:
        """A new file that appears under its name only with its header and metadata on disk
        (written to a hidden file, fsync'd, then hard-linked, which never replaces a file): a
        power cut while a part is started leaves no file that is not MCAP."""
        try:
            tmp, fh = create_partial(path, _open_new)
        except OSError as exc:
            raise InputError(f"cannot create {path}: {exc.strerror or exc}") from None
        try:
            mcap = Writer(fh, chunk_size=chunk_size, compression=CompressionType.NONE)
            mcap.start(profile="", library=f"{RECORDER_ID}; {LIBRARY_IDENTIFIER}")
            mcap.add_metadata(METADATA_NAME, dict(metadata))
            fh.flush()  # a recording killed in its first second is still an MCAP file
            os.fsync(fh.fileno())
            link_new(tmp, path, "recordings are never overwritten")
        except BaseException as exc:
            with contextlib.suppress(OSError, ValueError):
                fh.close()
            if isinstance(exc, OSError) and not exc.filename:
                raise OSError(exc.errno, exc.strerror, str(path)) from exc  # say which file
            raise
        finally:
            tmp.unlink(missing_ok=True)
        fsync_dir(path.parent)
        return cls(path, fh, mcap, message_appender(mcap))

    def channel(self, topic: Topic, schema_name: str) -> int:
        key = (topic, schema_name)
        channel_id = self.channels.get(key)
        if channel_id is None:
            schema_id = self._schema(schema_name)
            channel_id = self.mcap.register_channel(str(topic), MESSAGE_ENCODING, schema_id)
            self.channels[key] = channel_id
        return channel_id

    def _schema(self, name: str) -> int:
        """The schema's one id in this file, its record written again with the first chunk of
        every channel that uses it (the same id, identical bytes, as MCAP allows): a damaged
        chunk then loses only its own messages, never a later channel's schema. (Registered
        anew for each channel, the file held identical schemas under several ids.)"""
        schema_id = self.schemas.get(name)
        if schema_id is None:
            schema_id = int(self.mcap.register_schema(name, SCHEMA_ENCODING, SCHEMA_BYTES[name]))
            self.schemas[name] = schema_id
            return schema_id
        try:
            schema = self.mcap._Writer__schemas[schema_id]  # type: ignore[attr-defined]
            chunk = self.mcap._Writer__chunk_builder  # type: ignore[attr-defined]
        except AttributeError:  # a version of mcap without that state: a new id, as before
            return int(self.mcap.register_schema(name, SCHEMA_ENCODING, SCHEMA_BYTES[name]))
        if chunk is not None:
            chunk.add_schema(schema)
        return schema_id

    def add(self, channel_id: int, log_ns: int, data: bytes, sequence: int) -> None:
        if self.first_log_ns is None:
            self.first_log_ns = log_ns
        self.add_message(channel_id, log_ns, data, log_ns, sequence)
        self.dirty = True

    def size(self) -> int:
        return self.file.tell()

    def hand_over(self) -> int:
        """Close the open chunk and hand everything to the OS (a SIGKILL no longer loses it);
        returns the descriptor to fsync for power loss, which the caller does outside its lock."""
        self.mcap.flush()  # type: ignore[no-untyped-call]
        self.file.flush()
        self.dirty = False
        return self.file.fileno()

    def sync(self) -> None:
        """hand_over() and fsync."""
        os.fsync(self.hand_over())

    def finish(self) -> None:
        """Write the summary and footer, fsync and close."""
        self.mcap.finish()  # type: ignore[no-untyped-call]
        self.file.flush()
        os.fsync(self.file.fileno())
        self.file.close()

    def abandon(self) -> None:
        """After a disk error: keep whatever reached the disk, release the file, raise nothing."""
        for step in (self.file.flush, self.file.close):
            with contextlib.suppress(OSError, ValueError):
                step()


# --- the recorder -------------------------------------------------------------------------------

Tap = Callable[[Topic, str, LoggedMessage, int, bytes], None]
"""Called with (topic, schema name, message, log time ns, the JSON bytes as written) after each
message is written: how a live view sees the log as it grows, without encoding it again."""


class FlightRecorder:
    """Writes a flight log; use as a context manager. Thread-safe (one lock per recorder).

    `metadata` (scenario name, settings, ...) goes into every part's `sisa.recording` metadata
    record beside the recorder version, the part's index, the first part's name and the
    `recording_id` (random, one per recorder: readers tell this flight's parts from another's
    by it). `paths` lists the parts written so far.
    """

    def __init__(self, path: Path | str, *, split_duration_s: float | None = None,
                 split_size_bytes: int | None = None, flush_interval_s: float = 1.0,
                 chunk_size: int = DEFAULT_CHUNK_SIZE,
                 metadata: Mapping[str, object] | None = None,
                 tap: Tap | None = None) -> None:
        _check_settings(split_duration_s, split_size_bytes, flush_interval_s, chunk_size)
        self.path = Path(path)
        refuse_existing(self.path)
        self._split_ns = None if split_duration_s is None else round(split_duration_s * 1e9)
        self._split_bytes = split_size_bytes
        self._flush_interval_s = flush_interval_s
        self._chunk_size = chunk_size
        self._user_metadata = {str(k): str(v) for k, v in (metadata or {}).items()}
        self._sequences: dict[Topic, int] = {}
        self._lock = threading.Lock()
        self._error: RecorderError | None = None
        self._error_raised = False
        self._closed = False
        self.paths: list[Path] = []
        self.messages_written = 0
        self.recording_id = uuid.uuid4().hex  # in every part: readers refuse to mix flights
        self._tap = tap
        self.tap_failures = 0  # calls of the tap that raised: counted, never the recording's
        try:
            self._part = self._open_part()
        except OSError as exc:
            raise RecorderError(f"cannot start {self.path}: {exc.strerror or exc}") from exc
        self._next_sync = time.monotonic() + flush_interval_s
        self._stop = threading.Event()
        self._flusher = threading.Thread(target=self._flush_loop, name="sisa-recorder-flush",
                                         daemon=True)
        self._flusher.start()

    def __enter__(self) -> FlightRecorder:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def write(self, msg: LoggedMessage, topic: Topic | None = None) -> None:
        """Log `msg` on its own topic, or on `topic` (RawBytes per port, PulseEdgeLog in/out)."""
        cls = type(msg)
        topic = cls.topic if topic is None else topic
        if TOPIC_TYPES.get(topic) is not cls:
            raise EncodeError(f"topic {topic} does not carry {cls.schema_name}")
        data = _dumps(msg)  # cls is a logged type: TOPIC_TYPES said so
        extra = location_fix(msg) if isinstance(msg, GpsFix) and msg.quality > 0 else None
        log_ns = _log_time(msg)
        with self._lock:
            self._check_open()
            try:
                self._maybe_split(log_ns)
                self._add(topic, cls.schema_name, log_ns, data)
                if extra is not None:
                    self._add(Topic.GPS_LOCATION, LOCATION_FIX_SCHEMA_NAME, log_ns, extra)
            except (OSError, InputError) as exc:  # InputError: a part name taken mid-flight
                self._fail(exc)
                self._check_open()
        tap = self._tap
        if tap is not None:  # after the write, outside the lock
            self._tapped(tap, topic, cls.schema_name, msg, log_ns, data)
            if extra is not None:
                self._tapped(tap, Topic.GPS_LOCATION, LOCATION_FIX_SCHEMA_NAME, msg, log_ns,
                             extra)

    def _tapped(self, tap: Tap, topic: Topic, schema_name: str, msg: LoggedMessage,
                log_ns: int, data: bytes) -> None:
        """Hand a written message to the tap; whatever the tap does wrong is counted and
        dropped: a live view must never cost the log a message."""
        try:
            tap(topic, schema_name, msg, log_ns, data)
        except Exception:  # anything: the recording goes on
            self.tap_failures += 1

    def flush(self) -> None:
        """Close the open chunk and fsync now (also done every `flush_interval_s`)."""
        with self._lock:
            self._check_open()
            try:
                self._sync()
            except OSError as exc:
                self._fail(exc)
                self._check_open()

    def close(self) -> None:
        """Finish the last part (summary, footer, fsync). Raises a disk error not yet raised."""
        self._stop.set()
        self._flusher.join()
        with self._lock:
            if not self._closed:
                self._closed = True
                try:
                    self._part.finish()
                except OSError as exc:
                    self._fail(exc)
            if self._error is not None and not self._error_raised:
                self._error_raised = True
                raise self._error

    # --- internals ---

    def _check_open(self) -> None:
        if self._error is not None:
            self._error_raised = True
            raise self._error
        if self._closed:
            raise RecorderError(f"{self.path}: the recorder is closed")

    def _add(self, topic: Topic, schema_name: str, log_ns: int, data: bytes) -> None:
        part = self._part
        channel_id = part.channels.get((topic, schema_name)) or part.channel(topic, schema_name)
        seq = self._sequences.get(topic, 0)
        self._sequences[topic] = (seq + 1) % _SEQUENCE_MOD
        part.add(channel_id, log_ns, data, seq)
        self.messages_written += 1

    def _maybe_split(self, log_ns: int) -> None:
        part = self._part
        if part.first_log_ns is None:
            return
        by_time = self._split_ns is not None and log_ns - part.first_log_ns >= self._split_ns
        by_size = self._split_bytes is not None and part.size() >= self._split_bytes
        if by_time or by_size:
            part.finish()
            self._part = self._open_part()

    def _open_part(self) -> _Part:
        index = len(self.paths)
        path = part_path(self.path, index)
        own = {"recorder": RECORDER_ID, "recording_id": self.recording_id, "part": str(index),
               "first_part": self.path.name}  # readers rely on these: never the caller's
        meta = own | {k: v for k, v in self._user_metadata.items() if k not in own}
        part = _Part.create(path, self._chunk_size, meta)
        self.paths.append(path)
        return part

    def _sync(self) -> None:
        if self._part.dirty:
            self._part.sync()
        self._next_sync = time.monotonic() + self._flush_interval_s

    def _flush_loop(self) -> None:
        """Hand chunks to the OS on time (writers never wait for it), then fsync outside the
        lock: a slow disk must not stall the acquisition."""
        while not self._stop.wait(self._flush_interval_s / 10):
            with self._lock:
                if self._closed:
                    return
                if time.monotonic() < self._next_sync or not self._part.dirty:
                    continue
                try:
                    fd = self._part.hand_over()
                except OSError as exc:
                    self._fail(exc)
                    return
                self._next_sync = time.monotonic() + self._flush_interval_s
            try:
                os.fsync(fd)
            except OSError as exc:
                if exc.errno != errno.EBADF:  # EBADF: the part was closed meanwhile (fsync'd)
                    with self._lock:
                        self._fail(exc)
                    return

    def _fail(self, exc: OSError | InputError) -> None:
        """Stop on a disk error: keep what is on disk; every later call raises the one error."""
        if self._error is not None:
            return
        self._part.abandon()
        self._closed = True
        reason = (exc.strerror if isinstance(exc, OSError) else None) or exc
        where = (exc.filename if isinstance(exc, OSError) else None) or self._part.path
        self._error = RecorderError(
            f"cannot write {where}: {reason} (after {self.messages_written} messages)")
        self._error.__cause__ = exc


def _check_settings(split_duration_s: float | None, split_size_bytes: int | None,
                    flush_interval_s: float, chunk_size: int) -> None:
    if split_duration_s is not None and not split_duration_s > 0:
        raise ConfigError(f"split_duration_s must be > 0 (got {split_duration_s})")
    if split_size_bytes is not None and split_size_bytes < 4096:
        raise ConfigError(f"split_size_bytes must be >= 4096 (got {split_size_bytes})")
    if not 0 < flush_interval_s <= 60:
        raise ConfigError(f"flush_interval_s must be in (0, 60] (got {flush_interval_s})")
    if chunk_size < 1024:
        raise ConfigError(f"chunk_size must be >= 1024 bytes (got {chunk_size})")


def refuse_existing(path: Path) -> None:
    """A new log never replaces a file, and a stale part beside it would join it when the set
    is read back (readers find a log's numbered parts beside its first)."""
    if path.exists():
        raise InputError(f"{path} already exists: recordings are never overwritten")
    stale = split_parts(path)
    if stale:
        raise InputError(f"{stale[0]} already exists: choose another name (it would be read as "
                         f"a part of {path.name})")
    if not path.parent.is_dir():
        raise InputError(f"{path.parent} is not a folder")


# --- documentation ------------------------------------------------------------------------------

def _field_notes(cls: type) -> dict[str, str]:
    """The trailing `# comment` of each field in the class source: units and meanings."""
    try:
        source = inspect.getsource(cls)
    except (OSError, TypeError):
        return {}
    found = (re.match(r"\s+(\w+): [^#]*#\s*(.*)$", line) for line in source.splitlines())
    return {m.group(1): m.group(2).strip() for m in found if m}


def _json_type(prop: Mapping[str, Any]) -> str:
    if prop.get("contentEncoding") == "base64":
        return "string (base64 bytes)"
    if prop.get("type") == "array":
        return f"array of {prop['items']['type']}"
    if "oneOf" in prop:
        return "integer (" + ", ".join(f"{o['const']} {o['title']}" for o in prop["oneOf"]) + ")"
    return str(prop.get("type", "?"))


def _topic_section(topic: Topic, schema_name: str, doc: str, notes: Mapping[str, str]) -> list[str]:
    lines = [f"### `{topic}` — `{schema_name}`", ""] + ([doc, ""] if doc else [])
    lines += ["| field | JSON type | note |", "|---|---|---|"]
    for name, prop in SCHEMAS[schema_name]["properties"].items():
        note = notes.get(name, "").replace("|", "\\|")
        lines.append(f"| `{name}` | {_json_type(prop)} | {note} |")
    return [*lines, ""]


def topics_markdown() -> str:
    """The per-topic field tables of docs/flight-log.md, generated from recorder.messages."""
    lines = ["| topic | schema |", "|---|---|"]
    for topic in Topic:
        cls = TOPIC_TYPES.get(topic)
        lines.append(f"| `{topic}` | `{cls.schema_name if cls else LOCATION_FIX_SCHEMA_NAME}` |")
    lines.append("")
    for topic in Topic:
        cls = TOPIC_TYPES.get(topic)
        if cls is None:
            lines += _topic_section(topic, LOCATION_FIX_SCHEMA_NAME,
                                    LOCATION_FIX_SCHEMA["description"] + ".", LOCATION_FIX_NOTES)
        else:
            doc = (inspect.getdoc(cls) or "").split("\n\n")[0].replace("\n", " ")
            doc = "" if doc.startswith(f"{cls.__name__}(") else doc  # dataclass's own repr doc
            lines += _topic_section(topic, cls.schema_name, doc, _field_notes(cls))
    return "\n".join(lines).rstrip() + "\n"
