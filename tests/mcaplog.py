"""A flight log rewritten message by message, for tests that need a log no recorder of ours
writes (a hostile message, receive times from a stepping clock)."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path

from mcap.reader import make_reader
from mcap.records import Message
from mcap.writer import Writer

# (topic, message) → the (log time, data) to write in its place: none drops it, several add
Edit = Callable[[str, Message], Iterable[tuple[int, bytes]]]


def rewrite_log(src: Path, dst: Path, edit: Edit) -> None:
    """`dst`: `src`'s metadata, schemas and channels, and every message as `edit` gives it, in
    file order (publish time = log time, the sequence kept)."""
    with src.open("rb") as f_in, dst.open("wb") as f_out:
        reader = make_reader(f_in)
        writer = Writer(f_out)
        writer.start(profile="", library="test")
        for meta in reader.iter_metadata():
            writer.add_metadata(meta.name, dict(meta.metadata))
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if channel.id not in channels:
                if schema is not None and schema.id not in schemas:
                    schemas[schema.id] = writer.register_schema(schema.name, schema.encoding,
                                                                schema.data)
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding,
                    schemas[schema.id] if schema is not None else 0, dict(channel.metadata))
            for log_time, data in edit(channel.topic, message):
                writer.add_message(channels[channel.id], log_time, data, log_time,
                                   message.sequence)
        writer.finish()  # type: ignore[no-untyped-call]
