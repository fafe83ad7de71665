import random

from hypothesis import given
from hypothesis import strategies as st

from acquisition.codec import ErrorPolicy
from acquisition.pulses import EDGE_SIZE, Edge, EdgeStreamDecoder, PulseLine, encode_edge


def _edges(n):
    return [Edge(PulseLine(1 + i % 4), i, 1_000_000_000 * i + 123) for i in range(n)]


def test_round_trip_any_chunking():
    edges = _edges(50)
    stream = b"".join(encode_edge(e) for e in edges)
    rng = random.Random(1)
    dec = EdgeStreamDecoder(ErrorPolicy.RAISE)
    got, at = [], 0
    while at < len(stream):
        step = rng.randint(1, 30)
        got += [d.message for d in dec.feed(stream[at:at + step])]
        at += step
    assert got == edges
    assert dec.stats.messages == 50


def test_resynchronises_after_garbage_and_a_corrupt_edge():
    edges = _edges(3)
    bad = bytearray(encode_edge(edges[1]))
    bad[10] ^= 0x40
    stream = encode_edge(edges[0]) + b"\x00PLxx" + bytes(bad) + encode_edge(edges[2])
    dec = EdgeStreamDecoder()
    got = [d.message for d in dec.feed(stream)]
    assert got == [edges[0], edges[2]]
    assert dec.stats.checksum_errors >= 1
    assert dec.stats.errors >= 2


@given(st.binary(max_size=500))
def test_random_bytes_never_raise_and_buffer_stays_bounded(data):
    dec = EdgeStreamDecoder()
    dec.feed(data)
    assert len(dec._buf) < EDGE_SIZE
