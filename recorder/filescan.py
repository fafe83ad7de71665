"""One file of a flight log read front to back: every record it can trust, resynchronising past
damage on the next chunk, metadata record or summary it can check (recorder.reader explains
why)."""


from __future__ import annotations

import bisect
import contextlib
import zlib
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import BinaryIO

import numpy as np
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    Footer,
    Header,
    McapRecord,
    Message,
    Metadata,
    Schema,
)
from mcap.stream_reader import CRCValidationError

from recorder.chunkrecords import ChunkMessages, check_message_index, split_chunk
from recorder.framing import (
    DECLARATION_MAX,
    KNOWN_OPCODES,
    MCAP_MAGIC,
    PARSE_ERRORS,
    RECORD_HEAD,
    SCAN_BLOCK,
    ZEROED_OPCODE,
    OverLimitError,
    Summary,
    WholeRecords,
    find_chunk,
    footer_points,
    is_ours,
    iter_records,
    length_problem,
    open_log,
    read_summary,
    uncompressed_chunk,
)
from recorder.stats import MAX_PROBLEMS_KEPT, ChannelInfo, FileStats
from recorder.writer import (
    MESSAGE_ENCODING,
    TOPIC_SCHEMAS,
)
from sisa.core.errors import shown_text


class FileScan:
    """Reads one file record by record; what it could not read goes into `fstats`."""

    def __init__(self, path: Path, fstats: FileStats, record_size_limit: int) -> None:
        self.path = path
        self.fstats = fstats
        self.limit = record_size_limit
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, ChannelInfo] = {}
        self._summary: Summary | None = None
        self._summary_read = False  # looked up once: on damage, or once a channel is missing
        self._summary_declared = False

    def batches(self) -> Iterator[tuple[Mapping[int, ChannelInfo], ChunkMessages]]:
        """Every readable message, a chunk at a time (columns over the chunk's bytes), with the
        channels they are on: each message's channel is declared."""
        fs = self.fstats
        with open_log(self.path) as fh:
            source = WholeRecords(fh, len(MCAP_MAGIC), fs.size_bytes, self.limit)
            fs.bytes_readable = source.position
            try:
                for start, record in self.records(fh, source):
                    batch = self._on_record(record, start, source.position)
                    fs.bytes_readable = source.position
                    if batch is not None and len(batch):
                        yield self.channels, batch
            except PARSE_ERRORS as exc:  # not expected: the records are parsed one by one
                self._problem(f"unreadable record after byte {fs.bytes_readable}: {exc}")
            if fs.complete:
                fs.bytes_readable = source.position

    def messages(self) -> Iterator[tuple[ChannelInfo, Message]]:
        """Every readable message, one at a time, with its channel."""
        for channels, batch in self.batches():
            for m in zip(batch.channel_id.tolist(), batch.sequence.tolist(),
                         batch.log_time.tolist(), batch.publish_time.tolist(),
                         batch.payloads(), strict=True):
                yield channels[m[0]], Message(channel_id=m[0], sequence=m[1], log_time=m[2],
                                              publish_time=m[3], data=m[4])

    def records(self, fh: BinaryIO, source: WholeRecords) -> Iterator[tuple[int, object]]:
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
            head = source.read(RECORD_HEAD)
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
                                      f"{length_problem(head[0], length, self.limit)}")
                    return
                self._skip(fh, start, resume, None, head[0],
                           f"unreadable record at byte {start}: "
                           f"{length_problem(head[0], length, self.limit, size - start)}")
                source.seek(resume)
                previous = None
                continue
            body = source.read(length)
            if len(body) != length:
                return  # the file shrank as it was read
            if head[0] == ZEROED_OPCODE:  # storage gone to zeros (a power cut on some file
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
            if head[0] not in KNOWN_OPCODES:  # a record type from a later MCAP version:
                previous = start  # skipped, as the spec says; unless the summary knows better
                if self._indexes_chunk(start):
                    self.fstats.chunks_skipped += 1
                    self.fstats.bytes_skipped += source.position - start
                    self._problem(f"chunk at byte {start} skipped: its opcode is damaged "
                                  f"({head[0]:#04x})")
                continue
            try:
                if head[0] == Opcode.MESSAGE_INDEX:  # nothing a pass uses: checked, not parsed
                    check_message_index(body)
                    record: object = None
                else:
                    record = next(iter_records(head + body, self.limit, emit_chunks=True))
            except (*PARSE_ERRORS, OverLimitError) as exc:
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
            known = next((p for p in footer_points(fh, size) if p > start), None)
            bound = known if known is not None else size
            found = find_chunk(fh, start + 1, min(bound, end or size), bound, self.limit)
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
            known = next((p for p in footer_points(fh, self.fstats.size_bytes)
                          if p > previous), None)
            bound = known if known is not None else self.fstats.size_bytes
            back = find_chunk(fh, previous + 1, min(start, bound), bound, self.limit)
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

    def _on_record(self, record: object, start: int, end: int) -> ChunkMessages | None:
        if isinstance(record, Chunk):
            return self._chunk(record, start, end)
        if isinstance(record, Message):
            return self._declared(ChunkMessages.of(record))
        self._declare(record)
        if isinstance(record, Header):
            self.fstats.library = record.library
        elif isinstance(record, Metadata):
            self.fstats.metadata[record.name] = dict(record.metadata)
        elif isinstance(record, Footer):
            self.fstats.has_summary = record.summary_start != 0
        return None

    def _declare(self, record: object) -> None:
        if isinstance(record, Schema):
            self.schemas[record.id] = record
        elif isinstance(record, Channel) and record.id not in self.channels:
            schema = self.schemas.get(record.schema_id)
            self.channels[record.id] = ChannelInfo.declared(record, schema)

    def _chunk(self, chunk: Chunk, start: int, end: int) -> ChunkMessages | None:
        """All the chunk's messages, or none if the chunk is damaged."""
        try:
            data = uncompressed_chunk(chunk, self.limit).data
            if chunk.uncompressed_crc != 0 and (crc := zlib.crc32(data)) != chunk.uncompressed_crc:
                raise CRCValidationError(expected=chunk.uncompressed_crc, actual=crc,
                                         record=chunk)
            declarations, messages = split_chunk(data, self.limit)
        except (*PARSE_ERRORS, OverLimitError) as exc:
            self.fstats.chunks_skipped += 1
            self.fstats.bytes_skipped += end - start
            self._problem(f"chunk ending at byte {end} skipped: {exc}")
            self._salvage_declarations(chunk)
            return None
        self.fstats.chunks_read += 1
        for declared in declarations:
            self._declare(declared)
        return self._declared(messages)

    def _salvage_declarations(self, chunk: Chunk) -> None:
        """The channels a damaged chunk declares that are exactly what SISA writes (topic,
        encoding, schema name and text), read up to the damage: the later chunks' messages
        on them are not lost with it. Anything else in it is not trusted."""
        schemas: dict[int, Schema] = {}
        try:
            data = uncompressed_chunk(chunk, self.limit).data
            for record in iter_records(data, self.limit):
                self._salvage(record, schemas)
        except (*PARSE_ERRORS, OverLimitError):
            return  # the damage itself: what came before it is kept

    def _salvage_stretch(self, fh: BinaryIO, start: int, end: int) -> None:
        """As _salvage_declarations, for a stretch of the file skipped as unreadable (a chunk
        whose header is damaged): every whole Schema and Channel record found in it (SISA's
        are far shorter than DECLARATION_MAX), read a block at a time."""
        schemas: dict[int, Schema] = {}
        pos = start
        while pos < end:
            span = min(SCAN_BLOCK, end - pos)
            fh.seek(pos)
            data = fh.read(min(span + DECLARATION_MAX, end - pos))
            for opcode in (Opcode.SCHEMA, Opcode.CHANNEL):  # a channel names an earlier schema
                marker = opcode.to_bytes(1, "little")
                i = data.find(marker, 0, span)
                while i >= 0:
                    length = int.from_bytes(data[i + 1:i + RECORD_HEAD], "little")
                    if length <= len(data) - i - RECORD_HEAD:
                        with contextlib.suppress(*PARSE_ERRORS, OverLimitError):
                            record = data[i:i + RECORD_HEAD + length]
                            self._salvage(next(iter_records(record, self.limit)), schemas)
                    i = data.find(marker, i + 1, span)
            pos += span

    def _salvage(self, record: McapRecord, schemas: dict[int, Schema]) -> None:
        """Keep a schema of damaged data if it is exactly one SISA writes; declare a channel
        if it is exactly what SISA writes for its topic, with such a schema."""
        if isinstance(record, Schema) and is_ours(record):
            schemas[record.id] = record
        elif isinstance(record, Channel) and record.id not in self.channels:
            schema = schemas.get(record.schema_id) or self.schemas.get(record.schema_id)
            if schema is not None and record.message_encoding == MESSAGE_ENCODING \
                    and TOPIC_SCHEMAS.get(record.topic) == schema.name:
                self.schemas.setdefault(schema.id, schema)
                self._declare(record)

    def _declared(self, messages: ChunkMessages) -> ChunkMessages:
        """The messages on declared channels; the others skipped, each said."""
        ids = np.unique(messages.channel_id).tolist()
        missing = [i for i in ids if i not in self.channels]
        if missing and not self._summary_declared:  # declared in a damaged chunk
            self._summary_declared = True
            summary = self._summary_info()
            for declared in summary.declarations if summary is not None else ():
                self._declare(declared)
            missing = [i for i in missing if i not in self.channels]
        if not missing:
            return messages
        lost = np.isin(messages.channel_id, np.array(missing, dtype=np.uint16))
        for channel_id in messages.channel_id[lost].tolist():
            self._problem(f"message on undeclared channel {channel_id} skipped")
        return messages.take(np.flatnonzero(~lost))

    def _summary_info(self) -> Summary | None:
        if not self._summary_read:
            self._summary_read = True
            with open_log(self.path) as fh:
                self._summary = read_summary(fh, self.fstats.size_bytes, self.limit)
        return self._summary

    def _problem(self, text: str) -> None:
        if len(self.fstats.problems) < MAX_PROBLEMS_KEPT:  # (a parser's words may quote the
            self.fstats.problems.append(shown_text(text, 300))  # file: escaped, cut)

