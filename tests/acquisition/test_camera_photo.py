"""The frame camera's photo message: layout, CRC, round trip, and a damaged stream that loses no
good message and counts every damaged one, by reason (the byte-level fuzzing is in
tests/fuzz/test_fuzz_codecs.py, codec `camera_photo`)."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from acquisition.camera_photo import (
    BODY,
    MESSAGE_BYTES,
    SYNC,
    CameraRefusal,
    PhotoMessage,
    PhotoStreamDecoder,
    decode_photo,
    encode_photo,
    first_photo_message,
)
from acquisition.checksums import crc16_ccitt_false
from acquisition.codec import ErrorPolicy, RefusedError
from sisa.core.errors import DecodeError, EncodeError

MESSAGES = st.builds(PhotoMessage, photo_number=st.integers(0, 2**32 - 1),
                     exposure_time_us=st.integers(1, 1_000_000))


def test_known_bytes() -> None:
    raw = encode_photo(PhotoMessage(0x0102, 1000))
    body = bytes([8]) + (0x0102).to_bytes(4, "little") + (1000).to_bytes(4, "little")
    assert raw == SYNC + body + crc16_ccitt_false(body).to_bytes(2, "little")
    assert len(raw) == MESSAGE_BYTES == 13
    assert crc16_ccitt_false(b"123456789") == 0x29B1  # the published check value


@given(MESSAGES)
def test_round_trip(msg: PhotoMessage) -> None:
    raw = encode_photo(msg, photo_counter_bits=32)
    assert decode_photo(raw) == msg
    assert [d.message for d in PhotoStreamDecoder(ErrorPolicy.RAISE).feed(raw)] == [msg]


def test_the_range_edges_round_trip_and_one_lsb_beyond_is_refused_both_ways() -> None:
    field = BODY.field("exposure_time_us")
    for value in (field.low, field.high):
        msg = PhotoMessage(7, int(value))
        assert decode_photo(encode_photo(msg)) == msg
    for value in (field.low - 1, field.high + 1):
        with pytest.raises(EncodeError):
            encode_photo(PhotoMessage(7, int(value)))
        body = bytes([8]) + BODY.pack_raw({"photo_number": 7, "exposure_time_us": int(value)})
        raw = SYNC + body + crc16_ccitt_false(body).to_bytes(2, "little")
        with pytest.raises(RefusedError) as err:
            decode_photo(raw)
        assert err.value.reason == CameraRefusal.FIELD_VALUE
        decoder = PhotoStreamDecoder()
        assert decoder.feed(raw) == []
        assert decoder.stats.refused == {CameraRefusal.FIELD_VALUE: 1}


def test_a_photo_number_beyond_the_counter_is_refused() -> None:
    with pytest.raises(EncodeError):
        encode_photo(PhotoMessage(1 << 16, 1000), photo_counter_bits=16)
    assert decode_photo(encode_photo(PhotoMessage((1 << 16) - 1, 1000))).photo_number == 65535


def test_a_corrupted_message_is_one_checksum_error_and_the_next_decodes() -> None:
    good = [encode_photo(PhotoMessage(n, 800)) for n in range(3)]
    bad = bytearray(good[1])
    bad[5] ^= 0x10
    decoder = PhotoStreamDecoder()
    out = decoder.feed(good[0] + bytes(bad) + good[2])
    assert [d.raw for d in out] == [good[0], good[2]]
    assert decoder.stats.refused == {CameraRefusal.CHECKSUM: 1}
    assert decoder.stats.checksum_errors == 1
    assert decoder.stats.framing_errors == 0


def test_a_message_cut_short_does_not_swallow_the_next_one() -> None:
    a, b = encode_photo(PhotoMessage(1, 800)), encode_photo(PhotoMessage(2, 800))
    decoder = PhotoStreamDecoder()
    out = decoder.feed(a[:7] + b) + decoder.finish()
    assert [d.raw for d in out] == [b]
    assert decoder.stats.errors == 1
    assert decoder.stats.bytes_skipped == 7


def test_a_wrong_length_byte_and_line_ends_are_counted_by_reason() -> None:
    msg = bytearray(encode_photo(PhotoMessage(3, 800)))
    msg[2] = 9
    good = encode_photo(PhotoMessage(4, 800))
    decoder = PhotoStreamDecoder()
    out = decoder.feed(bytes(msg) + good + b"\r\n" + good)
    assert [d.raw for d in out] == [good, good]
    assert decoder.stats.refused == {CameraRefusal.LENGTH: 1, "junk": 1}


def test_under_raise_the_error_names_its_offset_and_bytes() -> None:
    good = encode_photo(PhotoMessage(5, 800))
    bad = bytearray(good)
    bad[-1] ^= 1
    decoder = PhotoStreamDecoder(ErrorPolicy.RAISE)
    with pytest.raises(DecodeError) as err:
        decoder.feed(good + bytes(bad))
    assert err.value.offset == MESSAGE_BYTES
    assert err.value.raw == bytes(bad[:2])


def test_first_photo_message_proves_the_port() -> None:
    good = encode_photo(PhotoMessage(9, 800))
    assert first_photo_message(b"\x00" + good[:-1] + b"\xc5\x5c" + good) == MESSAGE_BYTES + 2
    assert first_photo_message(b"$GPGGA,\r\n") == -1


@st.composite
def damaged_streams(draw: st.DrawFn) -> tuple[bytes, list[bytes], int]:
    """Photo messages, some damaged (a byte changed anywhere, sync included; or cut short);
    returns (stream, the good raws in order, the damaged count)."""
    pieces, good, damaged, cuts = [], [], 0, []
    for _ in range(draw(st.integers(1, 30))):
        raw = encode_photo(draw(MESSAGES), photo_counter_bits=32)
        damage = draw(st.sampled_from(["none", "none", "none", "flip", "cut"]))
        if damage == "none":
            pieces.append(raw)
            good.append(raw)
            continue
        if damage == "flip":
            index = draw(st.integers(0, len(raw) - 1))
            new = draw(st.integers(0, 255).filter(lambda b, old=raw[index]: b != old))
            pieces.append(raw[:index] + bytes([new]) + raw[index + 1:])
        else:
            cuts.append((sum(map(len, pieces)), raw))
            pieces.append(raw[:draw(st.integers(1, len(raw) - 1))])
        damaged += 1
    tail = encode_photo(PhotoMessage(0, 1))  # so that damage at the end is ended by a message
    stream = b"".join([*pieces, tail])
    # not damage: a message cut short whose lost bytes the next message begins with (its last
    # byte 0xC5, the next one's sync) is whole again in the stream, and takes that byte
    assume(all(stream[at:at + len(raw)] != raw for at, raw in cuts))
    return stream, [*good, tail], damaged


@settings(max_examples=400, deadline=None)
@given(damaged_streams(), st.integers(1, 40))
def test_a_damaged_stream_loses_no_good_message_and_counts_every_damaged_one(
        case: tuple[bytes, list[bytes], int], chunk: int) -> None:
    stream, good, damaged = case
    decoder = PhotoStreamDecoder()
    out = [d for i in range(0, len(stream), chunk) for d in decoder.feed(stream[i:i + chunk])]
    out += decoder.finish()
    assert [d.raw for d in out] == good
    # one error at least per bad stretch, never more than the damaged messages (two damaged ones
    # count once when one lies inside the 13 bytes the other would have spanned)
    assert (damaged > 0) <= decoder.stats.errors <= damaged
    assert sum(decoder.stats.refused.values()) == decoder.stats.errors
    assert sum(len(d.raw) for d in out) + decoder.stats.bytes_skipped == len(stream)



def test_a_message_cut_by_its_last_byte_before_the_next_sync_is_whole_again() -> None:
    """Found by the property test above: a message ending in 0xC5, cut by that byte, is
    completed by the next message's first sync byte into itself. The stream holds it whole,
    so it is decoded; the next message, without its first byte, is lost and counted."""
    whole = encode_photo(PhotoMessage(0xD6, 0x01A20E))
    assert whole[-1] == SYNC[0]
    after, tail = encode_photo(PhotoMessage(1, 2)), encode_photo(PhotoMessage(3, 4))
    decoder = PhotoStreamDecoder()
    out = decoder.feed(whole[:-1] + after + tail) + decoder.finish()
    assert [d.raw for d in out] == [whole, tail]
    assert decoder.stats.errors == 1
    assert decoder.stats.bytes_skipped == len(after) - 1

@given(st.lists(st.binary(max_size=40), max_size=20))
def test_noise_never_raises_and_every_byte_is_accounted_for(chunks: list[bytes]) -> None:
    decoder = PhotoStreamDecoder()
    out = [d for c in chunks for d in decoder.feed(c)] + decoder.finish()
    assert decoder.buffered_bytes == 0
    assert sum(len(d.raw) for d in out) + decoder.stats.bytes_skipped == sum(map(len, chunks))


def test_the_result_does_not_depend_on_how_the_stream_is_cut() -> None:
    msgs = [encode_photo(PhotoMessage(n, 900 + n)) for n in range(6)]
    bad = bytearray(msgs[2])
    bad[8] ^= 0xFF
    stream = b"\x00\x01" + msgs[0] + msgs[1][:5] + bytes(bad) + b"".join(msgs[3:])
    results = set()
    for a, b in itertools.combinations(range(len(stream) + 1), 2):
        decoder = PhotoStreamDecoder()
        out = decoder.feed(stream[:a]) + decoder.feed(stream[a:b]) + decoder.feed(stream[b:])
        out += decoder.finish()
        results.add((tuple(d.raw for d in out), tuple(sorted(decoder.stats.refused.items()))))
    assert len(results) == 1
    (raws, refused), = results
    assert list(raws) == [msgs[0], *msgs[3:]]
    assert dict(refused) == {"junk": 1, CameraRefusal.CHECKSUM: 1}
