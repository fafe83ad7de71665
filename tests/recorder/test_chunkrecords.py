"""A chunk's records split into columns agree with the mcap package's own record parser, and a
chunk whose records do not frame it is refused whole."""

import io
import struct

import numpy as np
import pytest
from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer

from recorder.chunkrecords import ChunkMessages, split_chunk

LIMIT = 1 << 24


def _chunks(n_messages: int = 500, seed: int = 3) -> list[Chunk]:
    rng = np.random.default_rng(seed)
    buf = io.BytesIO()
    w = Writer(buf, chunk_size=4096, compression=CompressionType.NONE)
    w.start()
    schema = w.register_schema("s", "jsonschema", b"{}")
    channels = [w.register_channel(f"/t{k}", "json", schema) for k in range(4)]
    for _ in range(n_messages):
        size = int(rng.integers(0, 300))
        w.add_message(channels[int(rng.integers(4))], log_time=int(rng.integers(0, 2**63)),
                      data=rng.bytes(size), publish_time=int(rng.integers(0, 2**63)),
                      sequence=int(rng.integers(0, 2**32)))
    w.finish()
    buf.seek(0)
    return [r for r in StreamReader(buf, emit_chunks=True).records if isinstance(r, Chunk)]


def test_split_agrees_with_the_mcap_parser_on_every_chunk() -> None:
    chunks = _chunks()
    assert len(chunks) > 10
    total = 0
    for chunk in chunks:
        theirs = breakup_chunk(chunk, validate_crc=True)
        declarations, ours = split_chunk(chunk.data, LIMIT)
        assert declarations == [r for r in theirs if isinstance(r, Schema | Channel)]
        msgs = [r for r in theirs if isinstance(r, Message)]
        assert ours.channel_id.tolist() == [m.channel_id for m in msgs]
        assert ours.sequence.tolist() == [m.sequence for m in msgs]
        assert ours.log_time.tolist() == [m.log_time for m in msgs]
        assert ours.publish_time.tolist() == [m.publish_time for m in msgs]
        assert ours.payloads() == [m.data for m in msgs]
        total += len(ours)
    assert total == 500


def test_take_keeps_the_order_asked() -> None:
    _, ours = split_chunk(_chunks()[0].data, LIMIT)
    back = ours.take(np.arange(len(ours))[::-1])
    assert back.payloads() == ours.payloads()[::-1]
    assert back.log_time.tolist() == ours.log_time.tolist()[::-1]


def test_a_message_outside_a_chunk() -> None:
    m = Message(channel_id=7, sequence=9, log_time=11, publish_time=13, data=b"abc")
    one = ChunkMessages.of(m)
    assert (one.channel_id.tolist(), one.sequence.tolist(), one.log_time.tolist(),
            one.publish_time.tolist(), one.payloads()) == ([7], [9], [11], [13], [b"abc"])


def test_records_that_do_not_frame_the_chunk_are_refused() -> None:
    data = _chunks()[1].data
    long = bytearray(data)
    struct.pack_into("<Q", long, 1, len(data))  # the first record runs past the end
    with pytest.raises(ValueError, match="runs past"):
        split_chunk(bytes(long), LIMIT)
    with pytest.raises(ValueError, match="no record"):
        split_chunk(data + b"\x05\x00", LIMIT)
    short = b"\x05" + struct.pack("<Q", 21) + bytes(21)  # a message without its fixed fields
    with pytest.raises(ValueError, match="21 bytes long"):
        split_chunk(short, LIMIT)
    unknown = b"\x7f" + struct.pack("<Q", 3) + b"xyz"  # a record type of a later version
    assert len(split_chunk(unknown + data, LIMIT)[1]) == len(split_chunk(data, LIMIT)[1])
