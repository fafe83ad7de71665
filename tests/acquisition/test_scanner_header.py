"""Scanner frame header on RS-232: layout, CRC, chunking, resync and exact error counts."""

from __future__ import annotations

import itertools
import random

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from acquisition.codec import ErrorPolicy
from acquisition.fields import Field
from acquisition.scanner_header import (
    BODY,
    HEADER_BYTES,
    SYNC,
    FrameHeader,
    HeaderStreamDecoder,
    ScannerMode,
    crc16_ccitt_false,
    encode_header,
)
from sisa.core.errors import DecodeError, EncodeError

FAST = settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])

headers = st.builds(FrameHeader, frame_counter=st.integers(0, 2**16 - 1),
                    integration_time_us=st.integers(0, 2**32 - 1),
                    mode=st.sampled_from(ScannerMode), segment=st.integers(0, 2**16 - 1),
                    bands=st.integers(1, 288))


def _decode(data: bytes, chunks: list[int] | None = None, policy: ErrorPolicy = ErrorPolicy.COUNT
            ) -> tuple[list[FrameHeader], HeaderStreamDecoder]:
    dec = HeaderStreamDecoder(policy)
    out: list[FrameHeader] = []
    cuts = [0, *sorted(c % (len(data) + 1) for c in chunks or []), len(data)]
    for a, b in itertools.pairwise(cuts):
        out += [d.message for d in dec.feed(data[a:b])]
    return out, dec


def _clean_stream(n: int, seed: int = 1) -> list[FrameHeader]:
    """Headers whose bytes hold the sync pattern only at their start."""
    rng = random.Random(seed)
    out: list[FrameHeader] = []
    while len(out) < n:
        h = FrameHeader(len(out), rng.randrange(1000, 20_000), ScannerMode.RECORDING,
                        rng.randrange(3), rng.randrange(1, 289))
        if encode_header(h).find(SYNC, 1) < 0:
            out.append(h)
    return out


def test_crc_check_value() -> None:
    assert crc16_ccitt_false(b"123456789") == 0x29B1


def test_known_bytes() -> None:
    h = FrameHeader(0x1234, 12_000, ScannerMode.RECORDING, 3, 19)
    assert encode_header(h).hex() == "a55a0d34120000e02e000001030013004d0e"
    assert len(encode_header(h)) == HEADER_BYTES == 18


@pytest.mark.parametrize("f", BODY.fields, ids=lambda f: f.name)
@given(data=st.data())
@FAST
def test_every_body_field_round_trips(f: Field, data: st.DataObject) -> None:
    raw = data.draw(st.integers(f.raw_min, f.raw_max))
    values = {g.name: g.to_physical(g.raw_min) for g in BODY.fields}
    for step in (-1, 0, 1):
        if f.raw_min <= raw + step <= f.raw_max:
            values[f.name] = f.to_physical(raw + step)
            assert BODY.unpack_raw(BODY.pack(values))[f.name] == raw + step


@given(h=headers)
@FAST
def test_round_trip(h: FrameHeader) -> None:
    data = encode_header(h)
    got, dec = _decode(data, policy=ErrorPolicy.RAISE)
    assert got == [h]
    assert dec.stats.messages == 1
    assert dec.stats.bytes_skipped == 0


def test_raw_is_the_exact_header_bytes() -> None:
    data = encode_header(_clean_stream(1)[0])
    (decoded,) = HeaderStreamDecoder().feed(b"\x00" + data)
    assert decoded.raw == data


def test_encode_refuses_bad_values() -> None:
    h = _clean_stream(1)[0]
    with pytest.raises(EncodeError, match="frame_counter"):
        encode_header(FrameHeader(2**16, 1, ScannerMode.IDLE, 0, 1))
    assert encode_header(FrameHeader(2**20, 1, ScannerMode.IDLE, 0, 1), frame_counter_bits=24)
    with pytest.raises(EncodeError, match="bands"):
        encode_header(FrameHeader(h.frame_counter, 1, ScannerMode.IDLE, 0, 289))


@given(hs=st.lists(headers, max_size=12), chunks=st.lists(st.integers(0, 10_000), max_size=30))
@FAST
def test_any_chunking_gives_the_same_headers(hs: list[FrameHeader], chunks: list[int]) -> None:
    got, _ = _decode(b"".join(map(encode_header, hs)), chunks, ErrorPolicy.RAISE)
    assert got == hs


def _damage(seed: int, n_headers: int, lose: bool) -> tuple[bytes, list[FrameHeader], set[int]]:
    """Corrupt or drop one byte in every third header, never creating a new sync pattern."""
    hs = _clean_stream(n_headers, seed)
    rng = random.Random(seed)
    parts, damaged = [encode_header(h) for h in hs], set(range(1, n_headers - 1, 3))
    for i in damaged:
        while True:
            at = rng.randrange(HEADER_BYTES)
            part = bytearray(parts[i])
            if lose:
                del part[at]
            else:
                part[at] ^= rng.randrange(1, 256)
            around = parts[i - 1][-1:] + bytes(part) + parts[i + 1][:1]
            found = [k for k in range(len(around)) if around.startswith(SYNC, k)]
            if found == ([1] if part[:2] == SYNC else []):
                break
        parts[i] = bytes(part)
    return b"".join(parts), [h for i, h in enumerate(hs) if i not in damaged], damaged


@pytest.mark.parametrize("lose", [False, True], ids=["corrupted", "lost"])
@pytest.mark.parametrize("seed", range(6))
def test_damaged_bytes_give_exact_counts(seed: int, lose: bool) -> None:
    data, intact, damaged = _damage(seed, 40, lose)
    for chunks in ([], random.Random(seed).sample(range(len(data)), 25)):
        got, dec = _decode(data, chunks)
        assert got == intact
        assert dec.stats.errors == len(damaged)
        assert dec.stats.bytes_skipped == len(damaged) * (HEADER_BYTES - lose)


def test_false_sync_in_garbage_does_not_swallow_a_header() -> None:
    good = encode_header(_clean_stream(1)[0])
    garbage = b"\x00\xa5\x5a\x0d\x01\x02"  # a plausible sync and length, then a real header
    got, dec = _decode(garbage + good)
    assert got == _clean_stream(1)
    assert dec.stats.framing_errors == 1  # the two bytes before the false sync
    assert dec.stats.checksum_errors == 1  # the false candidate
    assert dec.stats.bytes_skipped == len(garbage)


def test_bad_length_and_out_of_range_values_are_framing_errors_by_reason() -> None:
    h = _clean_stream(1)[0]
    good = encode_header(h)
    bad_mode = bytearray(good)
    bad_mode[11] = 9
    checked = bytes(bad_mode[2:-2])
    bad_mode[-2:] = crc16_ccitt_false(checked).to_bytes(2, "little")
    got, dec = _decode(b"\xa5\x5a\x0c" + good + bytes(bad_mode) + good)
    assert got == [h, h]  # a good header inside the bad length's span is still decoded
    assert dec.stats.framing_errors == 2
    assert dec.stats.checksum_errors == 0
    assert dec.stats.refused == {"scanner.length": 1, "scanner.field_value": 1}
    assert dec.stats.bytes_skipped == 3 + HEADER_BYTES


def test_a_failure_inside_a_damaged_headers_span_is_the_same_error() -> None:
    """A bad length claims the header's 18 bytes: a header that fails within them is not a
    second error (as on every sync + length + CRC port: acquisition.crcframe)."""
    h = _clean_stream(1)[0]
    bad_mode = bytearray(encode_header(h))
    bad_mode[11] = 9
    bad_mode[-2:] = crc16_ccitt_false(bytes(bad_mode[2:-2])).to_bytes(2, "little")
    got, dec = _decode(b"\xa5\x5a\x0c" + bytes(bad_mode) + encode_header(h))
    assert got == [h]
    assert dec.stats.errors == 1
    assert dec.stats.refused == {"scanner.length": 1}


def test_a_damaged_header_is_counted_under_its_reason() -> None:
    h = _clean_stream(1)[0]
    bad_crc = bytearray(encode_header(h))
    bad_crc[6] ^= 0x40
    got, dec = _decode(bytes(bad_crc) + b"\x00\x0d\x0a" + encode_header(h))
    assert got == [h]
    assert dec.stats.refused == {"scanner.checksum": 1, "junk": 1}
    assert (dec.stats.checksum_errors, dec.stats.framing_errors) == (1, 1)


def test_buffer_stays_bounded() -> None:
    dec = HeaderStreamDecoder()
    for _ in range(200):
        dec.feed(bytes(range(256)) + b"\xa5\x5a\x0d" + bytes(10))
        assert dec.buffered_bytes < HEADER_BYTES
    dec.finish()
    assert dec.buffered_bytes == 0


def test_raise_policy_gives_offset_and_raw() -> None:
    good = encode_header(_clean_stream(1)[0])
    bad = bytearray(good)
    bad[5] ^= 0xFF
    dec = HeaderStreamDecoder(ErrorPolicy.RAISE)
    assert len(dec.feed(good)) == 1
    with pytest.raises(DecodeError, match="CRC") as info:
        dec.feed(bytes(bad))
    assert info.value.offset == HEADER_BYTES
    assert info.value.raw == bytes(bad[:2])  # refused as far as its sync: the search goes on
    assert len(dec.feed(good)) == 1  # after it, within the bytes it claimed


@given(data=st.binary(max_size=400), chunks=st.lists(st.integers(0, 400), max_size=20))
@FAST
def test_random_bytes_never_raise(data: bytes, chunks: list[int]) -> None:
    got, dec = _decode(data, chunks)
    whole, dec_whole = _decode(data)
    assert got == whole
    assert dec.stats == dec_whole.stats


@given(hs=st.lists(headers, min_size=1, max_size=8),
       garbage=st.lists(st.binary(max_size=40), min_size=9, max_size=9),
       chunks=st.lists(st.integers(0, 1000), max_size=10))
@FAST
def test_headers_survive_random_garbage(hs: list[FrameHeader], garbage: list[bytes],
                                        chunks: list[int]) -> None:
    data = b"".join(g + encode_header(h) for g, h in zip(garbage, hs, strict=False)) + garbage[-1]
    got, _ = _decode(data, chunks)
    remaining = iter(got)
    assert all(any(h == g for g in remaining) for h in hs), "an intact header was lost"
