"""The records of one uncompressed MCAP chunk, split at once into numpy columns: a flight log holds
hundreds of thousands of small messages, and parsing each through the mcap package's record
classes cost ~8 µs of Python a message, most of the time of reading a log. Messages stay as
offsets into the chunk's bytes; only the chunk's few declarations (schemas, channels) are parsed
as records.

Framing follows the MCAP specification: each record is an opcode byte, a little-endian u64
length and that many bytes; a Message record's body is channel id (u16), sequence (u32), log
time (u64), publish time (u64) and the data. A record whose length runs past the chunk, or a
message shorter than its fixed fields, makes the whole chunk unreadable (ValueError), as the
mcap package's own reader would fail on it.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from mcap.opcode import Opcode
from mcap.records import McapRecord, Message

from recorder.framing import RECORD_HEAD, iter_records

MESSAGE_FIXED = 22  # channel id, sequence, log time, publish time
_HEAD = struct.Struct("<BQ")
_DECLARATIONS = (Opcode.SCHEMA, Opcode.CHANNEL)


@dataclass(frozen=True)
class ChunkMessages:
    """A chunk's messages in chunk order, as columns over its bytes."""

    data: bytes
    channel_id: npt.NDArray[np.uint16]
    sequence: npt.NDArray[np.uint32]
    log_time: npt.NDArray[np.uint64]
    publish_time: npt.NDArray[np.uint64]
    start: npt.NDArray[np.int64]  # of each message's data in `data`
    end: npt.NDArray[np.int64]

    @classmethod
    def of(cls, message: Message) -> ChunkMessages:
        """One message met outside a chunk."""
        return cls(message.data, np.array([message.channel_id], dtype=np.uint16),
                   np.array([message.sequence], dtype=np.uint32),
                   np.array([message.log_time], dtype=np.uint64),
                   np.array([message.publish_time], dtype=np.uint64),
                   np.zeros(1, dtype=np.int64), np.array([len(message.data)], dtype=np.int64))

    def __len__(self) -> int:
        return int(self.channel_id.size)

    def take(self, index: npt.NDArray[np.intp]) -> ChunkMessages:
        """The messages at `index`, in its order."""
        return ChunkMessages(self.data, self.channel_id[index], self.sequence[index],
                             self.log_time[index], self.publish_time[index],
                             self.start[index], self.end[index])

    def messages(self) -> Iterator[Message]:
        """The messages one at a time, as the mcap package's records."""
        for m in zip(self.channel_id.tolist(), self.sequence.tolist(), self.log_time.tolist(),
                     self.publish_time.tolist(), self.payloads(), strict=True):
            yield Message(channel_id=m[0], sequence=m[1], log_time=m[2], publish_time=m[3],
                          data=m[4])

    def payloads(self) -> list[bytes]:
        data = self.data
        return [data[s:e] for s, e in zip(self.start.tolist(), self.end.tolist(), strict=True)]


def split_chunk(data: bytes, limit: int) -> tuple[list[McapRecord], ChunkMessages]:
    """The declarations (Schema and Channel records, parsed) and the messages of an
    uncompressed chunk; records of other kinds are passed over, as the specification says.
    ValueError if the records do not frame the chunk exactly."""
    unpack, size = _HEAD.unpack_from, len(data)
    starts: list[int] = []
    ends: list[int] = []
    declarations: list[McapRecord] = []
    pos = 0
    while pos < size:
        if size - pos < RECORD_HEAD:
            raise ValueError(f"{size - pos} bytes at the end of the chunk are no record")
        opcode, length = unpack(data, pos)
        end = pos + RECORD_HEAD + length
        if end > size:
            raise ValueError(f"a record at byte {pos} of the chunk runs past its end")
        if opcode == Opcode.MESSAGE:
            if length < MESSAGE_FIXED:
                raise ValueError(f"a message at byte {pos} of the chunk is {length} bytes long")
            starts.append(pos)
            ends.append(end)
        elif opcode in _DECLARATIONS:
            declarations.append(next(iter_records(data[pos:end], limit)))
        pos = end
    return declarations, _message_columns(data, np.array(starts, dtype=np.int64),
                                          np.array(ends, dtype=np.int64))


def _message_columns(data: bytes, at: npt.NDArray[np.int64], end: npt.NDArray[np.int64]
                     ) -> ChunkMessages:
    """The fixed fields of the messages whose records begin at `at` and end at `end`."""
    raw = np.frombuffer(data, dtype=np.uint8)

    def field(offset: int, dtype: str) -> npt.NDArray[np.generic]:
        width = np.dtype(dtype).itemsize
        cells = raw[(at + RECORD_HEAD + offset)[:, None] + np.arange(width)]
        return np.ascontiguousarray(cells).view(dtype).ravel()

    return ChunkMessages(
        data,
        field(0, "<u2").astype(np.uint16), field(2, "<u4").astype(np.uint32),
        field(6, "<u8").astype(np.uint64), field(14, "<u8").astype(np.uint64),
        at + RECORD_HEAD + MESSAGE_FIXED, end)


def check_message_index(body: bytes) -> None:
    """ValueError unless `body` frames as a Message Index record (channel id u16, then a u32
    byte count of (log time, offset) u64 pairs within the rest; fields a later MCAP version
    appends may follow): what parsing it would check, at a thousandth of the cost (a long log
    holds one per channel and chunk)."""
    if len(body) < 6:
        raise ValueError(f"a message index of {len(body)} bytes")
    entries_bytes = int.from_bytes(body[2:6], "little")
    if entries_bytes > len(body) - 6 or entries_bytes % 16:
        raise ValueError(f"a message index's entries ({entries_bytes} bytes) do not fit it")
