"""A flight log read while it is still being written: each call returns the messages of the
records completed since the last call, so a live view can keep up with a recording without
reading it again from the start.

The recorder writes whole chunks (at least every flush interval), a record at a time, and its
file may end inside one at any moment: a record is taken only once all its bytes are there,
and the next call starts where the last complete record ended. A chunk is used only whole and
with a good CRC (a damaged one is counted and passed over, as `recorder.reader` does); after
the footer, reading moves on to the recording's next part when one appears beside it.
"""

from __future__ import annotations

import dataclasses
import os
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import Final

import numpy as np
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Footer, Message, Schema

from recorder.chunkrecords import ChunkMessages, check_message_index, split_chunk
from recorder.framing import (
    DEFAULT_RECORD_SIZE_LIMIT,
    MCAP_MAGIC,
    PARSE_ERRORS,
    RECORD_HEAD,
    OverLimitError,
    iter_records,
    uncompressed_chunk,
)
from recorder.stats import ChannelInfo
from recorder.writer import part_path

READ_MAX: Final = 64 * 2**20  # bytes read a call at most: a long log is caught up in steps


@dataclasses.dataclass
class FollowStats:
    """What the follower read and what it could not."""

    parts: int = 0
    chunks_read: int = 0
    chunks_skipped: int = 0
    unreadable: int = 0  # records that framed but did not parse
    bytes_read: int = 0


class LogFollower:
    """Follows a recording as it grows: `poll()` gives the messages written since the last
    call, in file order, with their channels."""

    def __init__(self, path: Path | str, *, record_size_limit: int = DEFAULT_RECORD_SIZE_LIMIT
                 ) -> None:
        self.first = Path(path)
        self.part = 0
        self.limit = record_size_limit
        self.position = 0  # in the current part: where the next record starts (0: at its magic)
        self.stats = FollowStats()
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, ChannelInfo] = {}
        self._part_done = False

    @property
    def path(self) -> Path:
        return part_path(self.first, self.part)

    def poll(self) -> list[tuple[ChannelInfo, Message]]:
        """The messages of the records completed since the last call (none if nothing new)."""
        return [(channels[m[0]], Message(channel_id=m[0], sequence=m[1], log_time=m[2],
                                         publish_time=m[3], data=m[4]))
                for channels, batch in self.poll_batches()
                for m in zip(batch.channel_id.tolist(), batch.sequence.tolist(),
                             batch.log_time.tolist(), batch.publish_time.tolist(),
                             batch.payloads(), strict=True)]

    def poll_batches(self) -> list[tuple[Mapping[int, ChannelInfo], ChunkMessages]]:
        """As `poll`, a chunk at a time (columns over its bytes), with the channels the
        messages are on: every message's channel is declared."""
        out: list[tuple[Mapping[int, ChannelInfo], ChunkMessages]] = []
        while True:
            if self._part_done:
                if not part_path(self.first, self.part + 1).exists():
                    return out
                self.part += 1
                self.position = 0
                self._schemas, self._channels = {}, {}
                self._part_done = False
            got = self._read_part(out)
            if not self._part_done or not got:
                return out

    def _read_part(self, out: list[tuple[Mapping[int, ChannelInfo], ChunkMessages]]) -> bool:
        """Read the current part's new complete records into `out`; False if it had none."""
        try:
            with open(self.path, "rb") as fh:
                size = os.fstat(fh.fileno()).st_size
                if self.position == 0:
                    if size < len(MCAP_MAGIC):
                        return False
                    if fh.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
                        self._part_done = True  # not an MCAP file: nothing to follow in it
                        return False
                    self.position = len(MCAP_MAGIC)
                    self.stats.parts += 1
                fh.seek(self.position)
                data = fh.read(min(size - self.position, READ_MAX))
        except FileNotFoundError:
            return False
        end = _complete_records_end(data, self.limit)
        if end == 0:
            return False
        self.position += end
        self.stats.bytes_read += end
        for record in _records(data[:end], self.limit, self.stats):
            self._on_record(record, out)
        return True

    def _on_record(self, record: object,
                   out: list[tuple[Mapping[int, ChannelInfo], ChunkMessages]]) -> None:
        if isinstance(record, Chunk):
            try:
                data = uncompressed_chunk(record, self.limit).data
                if record.uncompressed_crc != 0 and zlib.crc32(data) != record.uncompressed_crc:
                    raise ValueError("chunk CRC mismatch")
                declarations, messages = split_chunk(data, self.limit)
            except (*PARSE_ERRORS, OverLimitError):
                self.stats.chunks_skipped += 1
                return
            self.stats.chunks_read += 1
            for item in declarations:
                self._on_record(item, out)
            self._add(messages, out)
        elif isinstance(record, Schema):
            self._schemas[record.id] = record
        elif isinstance(record, Channel) and record.id not in self._channels:
            schema = self._schemas.get(record.schema_id)
            self._channels[record.id] = ChannelInfo.declared(record, schema)
        elif isinstance(record, Message):
            self._add(ChunkMessages.of(record), out)
        elif isinstance(record, Footer):
            self._part_done = True

    def _add(self, messages: ChunkMessages,
             out: list[tuple[Mapping[int, ChannelInfo], ChunkMessages]]) -> None:
        """The messages on declared channels (the others cannot be read: left out)."""
        known = np.isin(messages.channel_id, np.fromiter(self._channels, dtype=np.uint16,
                                                         count=len(self._channels)))
        if not known.all():
            messages = messages.take(np.flatnonzero(known))
        if len(messages):
            out.append((self._channels, messages))


def _complete_records_end(data: bytes, limit: int) -> int:
    """Where the last record wholly inside `data` ends (0: none is)."""
    i = 0
    while i + RECORD_HEAD <= len(data):
        length = int.from_bytes(data[i + 1:i + RECORD_HEAD], "little")
        if length > limit or i + RECORD_HEAD + length > len(data):
            break
        i += RECORD_HEAD + length
    return i


def _records(data: bytes, limit: int, stats: FollowStats) -> list[object]:
    """The top-level records in `data`, each parsed from its own bytes; one that does not
    parse is counted and passed over."""
    out: list[object] = []
    i = 0
    while i < len(data):
        length = int.from_bytes(data[i + 1:i + RECORD_HEAD], "little")
        piece = data[i:i + RECORD_HEAD + length]
        i += RECORD_HEAD + length
        try:
            if piece[0] == Opcode.MESSAGE_INDEX:  # nothing the follower uses: checked only
                check_message_index(piece[RECORD_HEAD:])
                continue
            out.append(next(iter_records(piece, limit, emit_chunks=True)))
        except (*PARSE_ERRORS, OverLimitError):
            stats.unreadable += 1
    return out
