"""A flight log as numpy columns, batch by batch, so that a long flight never lives as millions
of Python dicts: what post-processing reads."""


from __future__ import annotations

import base64
import json
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from operator import itemgetter
from typing import Any

import numpy as np
import numpy.typing as npt
import orjson

from recorder.chunkrecords import ChunkMessages
from recorder.framing import Paths
from recorder.messages import Topic
from recorder.parts import MissingPartWarning
from recorder.reader import BATCH, JSON_ERRORS, LogReader, decoding_problem, schema_properties
from recorder.stats import ChannelInfo, DamagedLogWarning, LogStats, damage_notes
from recorder.writer import (
    SCHEMAS,
    TOPIC_TYPES,
)
from sisa.core.bounded import json_loads
from sisa.core.errors import DecodeError

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
        return list(map(itemgetter(path[0]), objs))
    values = []
    for o in objs:
        v: Any = o
        for key in path:
            v = v[key]
        values.append(v)
    return values


def _to_array(values: list[Any], dtype: Any, b64: bool) -> npt.NDArray[Any]:
    if dtype is np.int64 and not set(map(type, values)) <= {int}:
        raise TypeError("a value of an integer field is not an integer")  # numpy would truncate
    if b64 or dtype is object:
        arr = np.empty(len(values), dtype=object)
        arr[:] = [base64.b64decode(v) for v in values] if b64 else values
        return arr
    if dtype is np.str_:
        return np.array(values, dtype=np.str_) if values else np.array([], dtype=np.str_)
    return np.fromiter(values, dtype=dtype, count=len(values))


def _loads_batch(joined: bytes) -> Any:
    """A batch of messages as one JSON array: by orjson (a quarter of the json module's time),
    or, where orjson refuses (a NaN or Infinity the writer spelled out, an integer past 64 bits),
    by the json module, whose verdict is the format's."""
    try:
        return orjson.loads(joined)
    except orjson.JSONDecodeError:
        return json.loads(joined)


class _ColumnBuilder:
    """Accumulates one topic's messages in numpy arrays, one JSON batch at a time."""

    def __init__(self, props: dict[str, Any], fields: Sequence[str] | None = None) -> None:
        self.columns = [c for c in _columns(props) if fields is None or c[0] in fields]
        self.b64 = {name for name, p in props.items() if p.get("contentEncoding") == "base64"}
        self.parts: dict[str, list[npt.NDArray[Any]]] = {"log_time_ns": []}
        self.parts.update({name: [] for name, _, _ in self.columns})

    def add_batch(self, log_times: list[int], datas: list[bytes],
                  on_bad: Callable[[int, str], None]) -> None:
        """One batch of messages into the columns; a message that does not decode, or does
        not match the columns' types, is skipped, and said to `on_bad(log_time, why)`."""
        try:
            objs = _loads_batch(b"[" + b",".join(datas) + b"]")  # at once: the usual case
            if len(objs) != len(datas):
                raise ValueError("a message holds more than one JSON value")
            arrays = self._arrays(objs)
            times = np.array(log_times, dtype=np.int64)
        except JSON_ERRORS:  # one at a time, each bounded, the bad ones left out
            objs, kept = [], []
            for log_time, data in zip(log_times, datas, strict=True):
                try:
                    if not 0 <= log_time < 2**63:
                        raise ValueError(f"log time {log_time} past int64")
                    obj = json_loads(data)
                    self._arrays([obj])  # its values are of the columns' types
                except JSON_ERRORS as exc:
                    on_bad(log_time, decoding_problem(exc))
                    continue
                objs.append(obj)
                kept.append(log_time)
            arrays, times = self._arrays(objs), np.array(kept, dtype=np.int64)
        self.parts["log_time_ns"].append(times)
        for name, arr in arrays.items():
            self.parts[name].append(arr)

    def _arrays(self, objs: list[Any]) -> dict[str, npt.NDArray[Any]]:
        if not all(isinstance(obj, dict) for obj in objs):
            raise TypeError("a message is no JSON object")
        return {name: _to_array(_column_values(objs, path), dtype, path[0] in self.b64)
                for name, path, dtype in self.columns}

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

    def add(self, channel: ChannelInfo, log_time: int, data: bytes,
            on_bad: Callable[[int, str], None]) -> None:
        self.add_many(channel, [log_time], [data], on_bad)

    def add_many(self, channel: ChannelInfo, log_times: list[int], datas: list[bytes],
                 on_bad: Callable[[int, str], None]) -> None:
        if self.builder is None:
            self.builder = _ColumnBuilder(schema_properties(channel) or {}, self.fields)
        self.times += log_times
        self.datas += datas
        if len(self.datas) >= BATCH:
            self.builder.add_batch(self.times, self.datas, on_bad)
            self.times, self.datas = [], []

    def result(self, topic: str, on_bad: Callable[[int, str], None]
               ) -> dict[str, npt.NDArray[Any]]:
        if self.builder is None:
            self.builder = _ColumnBuilder(_known_props(topic), self.fields)
        if self.datas:
            self.builder.add_batch(self.times, self.datas, on_bad)
        columns = self.builder.result()
        missing = [f for f in self.fields or () if f not in columns]
        if missing:
            raise DecodeError(f"the log's schema has no field {', '.join(missing)}")
        return columns


def _wanted_in(batches: Mapping[str, _TopicBatches], channels: Mapping[int, ChannelInfo],
               chunk: ChunkMessages) -> Iterator[tuple[_TopicBatches, ChannelInfo,
                                                       ChunkMessages]]:
    """A chunk's messages on each wanted topic's channel, with the topic's batches."""
    ids = chunk.channel_id
    for channel_id in np.unique(ids).tolist():
        channel = channels[channel_id]
        batch = batches.get(channel.topic)
        if batch is not None:
            yield batch, channel, chunk.take(np.flatnonzero(ids == channel_id))


def read_topics(path_or_paths: Paths, wanted: Mapping[str, Sequence[str] | None], *,
                notes: list[str] | None = None) -> dict[str, dict[str, npt.NDArray[Any]]]:
    """Several topics as numpy columns in ONE streaming pass (each pass over a long log costs
    seconds): {topic: {field: array}} for the wanted fields (None: all), plus `log_time_ns`.
    A topic that never appears gives empty typed arrays; a schema without a wanted field raises
    DecodeError; a message that does not decode (lacking a field, a value of the wrong type,
    JSON nested past the bound) is skipped and counted (`LogStats.undecodable`), never fatal.
    What could not be read (a file cut short, damaged chunks, messages skipped) is said as a
    DamagedLogWarning, the parts of a split recording that are not given as a
    MissingPartWarning, or either appended to `notes` if given (for a caller that reports its
    own warnings)."""
    batches = {topic: _TopicBatches(fields) for topic, fields in wanted.items()}
    reader = LogReader(path_or_paths)
    topic = ""

    def on_bad(log_time: int, why: str) -> None:
        reader.stats.note_bad(topic, log_time, why)

    try:  # an error names the file (the part being read) and the topic
        for channels, chunk in reader.raw_batches():
            for batch, channel, on in _wanted_in(batches, channels, chunk):
                topic = channel.topic
                batch.add_many(channel, on.log_time.tolist(), on.payloads(), on_bad)
        out = {}
        for topic, batch in batches.items():
            out[topic] = batch.result(topic, on_bad)
    except DecodeError as exc:
        where = reader.stats.files[-1].path if reader.stats.files else reader.paths[0]
        raise DecodeError(f"{where}: {topic}: {exc}", raw=exc.raw) from None
    said: list[tuple[str, type[UserWarning]]] = [
        (note, MissingPartWarning) for note in reader.stats.part_notes]
    said += [(note, DamagedLogWarning) for fs in reader.stats.files for note in damage_notes(fs)]
    if (bad := reader.stats.bad_note()) is not None:
        said.append((f"{reader.paths[0]}: {bad}", DamagedLogWarning))
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


class GrowingColumns:
    """`read_topics` for a log still being written: messages go in as they are read (from a
    `recorder.follow.LogFollower`), and `columns()` gives every wanted topic's columns so far,
    typed as `read_topics` types them. A message that does not decode is counted in `bad`."""

    def __init__(self, wanted: Mapping[str, Sequence[str] | None]) -> None:
        self._batches = {topic: _TopicBatches(fields) for topic, fields in wanted.items()}
        self.bad = 0

    def _on_bad(self, _log_time: int, _why: str) -> None:
        self.bad += 1

    def add(self, channel: ChannelInfo, log_time: int, data: bytes) -> None:
        batch = self._batches.get(channel.topic)
        if batch is not None:
            batch.add(channel, log_time, data, self._on_bad)

    def add_chunk(self, channels: Mapping[int, ChannelInfo], chunk: ChunkMessages) -> None:
        """A chunk's messages (`recorder.follow.LogFollower.poll_batches`)."""
        for batch, channel, on in _wanted_in(self._batches, channels, chunk):
            batch.add_many(channel, on.log_time.tolist(), on.payloads(), self._on_bad)

    def columns(self) -> dict[str, dict[str, npt.NDArray[Any]]]:
        out = {}
        for topic, batch in self._batches.items():
            out[topic] = batch.result(topic, self._on_bad)
            batch.times, batch.datas = [], []  # converted now: not again on the next call
        return out
