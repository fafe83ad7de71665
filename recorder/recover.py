"""Recover a flight log: every readable message of a truncated or damaged file, into a new
complete MCAP (summary, indexes, statistics) that any tool opens.

Why: a log cut by a power loss has no summary, so indexed readers (Foxglove, `mcap info`,
McapIndexedReader) refuse it or read it slowly. The copy is written to a hidden temporary file
beside the output and appears under its name only when complete (a hard link, which never replaces
an existing file): an interrupted recover leaves nothing half-written, and nothing is overwritten.
"""

from __future__ import annotations

import contextlib
import os
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from mcap.records import Message
from mcap.writer import CompressionType, Writer

from recorder.reader import LogReader, MessageCheck
from recorder.stats import ChannelInfo, LogStats
from recorder.writer import (
    DEFAULT_CHUNK_SIZE,
    RECORDER_ID,
    fsync_dir,
    link_new,
    refuse_existing,
)
from sisa.core.errors import InputError, RecorderError, shown_text
from sisa.core.outdir import create_partial


@dataclass(frozen=True)
class RecoverReport:
    in_path: Path
    out_path: Path
    messages: int
    topics: dict[str, int]
    chunks_read: int
    chunks_skipped: int
    input_complete: bool
    bytes_unreadable: int  # bytes of the input after its last complete record
    problems: list[str] = field(default_factory=list)
    bytes_skipped: int = 0  # bytes of damaged records and unreadable stretches read past
    undecodable: int = 0  # messages read whole that do not decode ...
    dropped: bool = False  # ... left out of the copy (else copied as they are)
    undecodable_note: str = ""  # the first of them, in words

    def summary(self) -> str:
        """One line for the terminal."""
        state = "complete" if self.input_complete else "truncated (no summary)"
        skipped = f", {self.chunks_skipped} damaged chunks skipped" if self.chunks_skipped else ""
        if self.bytes_skipped:
            skipped += f", {self.bytes_skipped} damaged bytes skipped"
        tail = f", {self.bytes_unreadable} bytes unreadable" if self.bytes_unreadable else ""
        if self.undecodable:
            n = self.undecodable
            what = f"{n} message{'s' if n != 1 else ''} that do{'es' if n == 1 else ''} not decode"
            tail += (f"; {what} left out ({self.undecodable_note})" if self.dropped else
                     f"; {what} copied as {'it is' if n == 1 else 'they are'} "
                     f"({self.undecodable_note}): --drop-undecodable leaves "
                     f"{'it' if n == 1 else 'them'} out")
        return (f"{self.out_path}: {self.messages} messages on {len(self.topics)} topics from "
                f"{self.chunks_read} chunks of {self.in_path} ({state}{skipped}{tail})")


class _Copier:
    """Re-declares each schema and channel once in the new file and copies messages verbatim."""

    def __init__(self, fh: BinaryIO) -> None:
        self.mcap = Writer(fh, chunk_size=DEFAULT_CHUNK_SIZE, compression=CompressionType.NONE)
        self.mcap.start(profile="", library=f"{RECORDER_ID} (recover)")
        self.schemas: dict[tuple[str, str, bytes], int] = {}
        self.channels: dict[tuple[str, str, int], int] = {}

    def add(self, channel: ChannelInfo, msg: Message) -> None:
        channel_id = self._channel(channel)
        self.mcap.add_message(channel_id, msg.log_time, msg.data, msg.publish_time, msg.sequence)

    def _channel(self, channel: ChannelInfo) -> int:
        skey = (channel.schema_name, channel.schema_encoding, channel.schema_data)
        schema_id = self.schemas.get(skey)
        if schema_id is None:
            schema_id = 0 if not channel.schema_name else self.mcap.register_schema(*skey)
            self.schemas[skey] = schema_id
        ckey = (channel.topic, channel.message_encoding, schema_id)
        channel_id = self.channels.get(ckey)
        if channel_id is None:
            channel_id = self.mcap.register_channel(channel.topic, channel.message_encoding,
                                                    schema_id)
            self.channels[ckey] = channel_id
        return channel_id

    def finish(self, in_path: Path, stats: LogStats) -> None:
        for name, meta in stats.files[0].metadata.items():
            self.mcap.add_metadata(name, meta)
        fs = stats.files[0]
        self.mcap.add_metadata("sisa.recovered", {
            "source": in_path.name, "source_complete": str(fs.complete).lower(),
            "chunks_read": str(fs.chunks_read), "chunks_skipped": str(fs.chunks_skipped),
            "bytes_unreadable": str(fs.bytes_unreadable),
            "bytes_skipped": str(fs.bytes_skipped), "by": RECORDER_ID})
        self.mcap.finish()  # type: ignore[no-untyped-call]


def recover(in_path: Path | str, out_path: Path | str, *, drop_undecodable: bool = False
            ) -> RecoverReport:
    """Copy every readable message of `in_path` into a new, complete MCAP file `out_path`;
    with `drop_undecodable`, not those that do not decode (JSON nested past the bound, not an
    object, a base64 field that is not base64), which every reader skips and counts."""
    src, out = Path(in_path), Path(out_path)
    try:
        refuse_existing(out)
    except OSError as exc:  # a name longer than the file system takes
        raise InputError(f"{out}: cannot be used as a name: {exc.strerror or exc}") from None
    reader = LogReader(src)  # InputError if missing or not MCAP
    dropped: Counter[str] = Counter()
    tmp: Path | None = None
    try:
        tmp, fd = create_partial(out)
        with os.fdopen(fd, "wb") as fh:
            copier = _Copier(fh)
            check = MessageCheck()
            for channel, msg in reader.raw():
                why = check(channel, msg.data)
                if why is not None:
                    reader.stats.note_bad(channel.topic, msg.log_time, why)
                    if drop_undecodable:
                        dropped[channel.topic] += 1
                        continue
                copier.add(channel, msg)
            copier.finish(src, reader.stats)
            fh.flush()
            os.fsync(fh.fileno())
        link_new(tmp, out, "recover never overwrites")
    except OSError as exc:
        raise RecorderError(f"cannot write {out}: {exc.strerror or exc}") from exc
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                tmp.unlink(missing_ok=True)
    fsync_dir(out.parent)
    return _report(src, out, reader.stats, dropped if drop_undecodable else None)


def _report(src: Path, out: Path, stats: LogStats, dropped: Counter[str] | None
            ) -> RecoverReport:
    fs = stats.files[0]
    topics = Counter({t: s.count for t, s in stats.topics.items()})
    topics.subtract(dropped or Counter())
    kept = stats.messages - (dropped.total() if dropped else 0)
    first = stats.bad[0] if stats.bad else None
    note = "" if first is None else (f"{'the first: ' if stats.undecodable > 1 else ''}"
                                     f"{shown_text(first.topic)} at log time "
                                     f"{first.log_time_ns}: {first.why}")
    return RecoverReport(src, out, kept, {t: n for t, n in topics.items() if n > 0},
                         fs.chunks_read, fs.chunks_skipped, fs.complete, fs.bytes_unreadable,
                         list(fs.problems), fs.bytes_skipped, stats.undecodable,
                         dropped is not None, note)
