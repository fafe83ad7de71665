"""Chosen fields of several topics of a flight log as numpy columns, in one streaming pass.

Why not `recorder.reader.read_columns` once per topic: every call reads the whole log again, and
a five-hour log takes tens of seconds per pass. This reads it once, keeps only the named fields,
and converts each batch of messages to arrays as it goes, so memory holds numpy columns, never
millions of Python objects.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from typing import Any, Final, Literal

import numpy as np
import numpy.typing as npt

from recorder.reader import LogReader, Paths
from sisa.errors import DecodeError

Kind = Literal["int", "bool", "str"]
FieldSpec = tuple[str, Kind]
Columns = dict[str, npt.NDArray[Any]]

BATCH: Final = 4096
_DTYPES: Final[dict[str, Any]] = {"int": np.int64, "bool": np.bool_, "str": np.str_}


class _TopicColumns:
    """One topic's wanted fields, accumulated batch by batch."""

    def __init__(self, topic: str, fields: Sequence[FieldSpec]) -> None:
        self.topic = topic
        self.fields = tuple(fields)
        self.pending: list[bytes] = []
        self.parts: dict[str, list[npt.NDArray[Any]]] = {name: [] for name, _ in self.fields}

    def add(self, data: bytes) -> None:
        self.pending.append(data)
        if len(self.pending) >= BATCH:
            self.flush()

    def flush(self) -> None:
        if not self.pending:
            return
        try:
            objs = json.loads(b"[" + b",".join(self.pending) + b"]")
            for name, kind in self.fields:
                self.parts[name].append(_column([o[name] for o in objs], kind))
        except (ValueError, KeyError, TypeError) as exc:
            raise DecodeError(f"{self.topic}: a message lacks a field or has the wrong type: "
                              f"{exc}") from None
        self.pending = []

    def result(self) -> Columns:
        self.flush()
        return {name: (np.concatenate(self.parts[name]) if self.parts[name]
                       else np.array([], dtype=_DTYPES[kind]))
                for name, kind in self.fields}


def _column(values: list[Any], kind: Kind) -> npt.NDArray[Any]:
    if kind == "str":
        return np.array(values, dtype=np.str_) if values else np.array([], dtype=np.str_)
    if kind == "int" and not all(type(v) is int for v in values):
        raise TypeError("expected integers")
    return np.fromiter(values, dtype=_DTYPES[kind], count=len(values))


def read_topic_columns(paths: Paths, wanted: Mapping[str, Sequence[FieldSpec]]
                       ) -> dict[str, Columns]:
    """{topic: {field: array}} for the wanted fields of the wanted topics, in file order.

    A topic that never appears gives empty arrays; a message without a wanted field, or with a
    value of the wrong type, raises DecodeError (a SisaError: one line from the CLI).
    """
    builders = {topic: _TopicColumns(topic, fields) for topic, fields in wanted.items()}
    for channel, msg in LogReader(paths).raw():
        builder = builders.get(channel.topic)
        if builder is not None and channel.message_encoding == "json":
            builder.add(msg.data)
    return {topic: builder.result() for topic, builder in builders.items()}
