"""The u-blox UBX binary frame, and its framer for a stream shared with NMEA sentences.

A frame (u-blox's public interface description, little-endian):

| offset | size | content |
|---|---|---|
| 0 | 2 | sync `B5 62` |
| 2 | 1 | message class |
| 3 | 1 | message id |
| 4 | 2 | payload length n |
| 6 | n | payload |
| 6 + n | 2 | CK_A, CK_B: 8-bit Fletcher checksum over class, id, length and payload |

The framer checks the checksum before it trusts the length: a frame whose checksum fails is
refused only as far as its sync (so whatever follows it is still searched for messages), and
what fails inside the length it claimed is the same error.
"""

from __future__ import annotations

from enum import StrEnum

from acquisition.codec import ErrorKind, RefusedError
from acquisition.framing import MORE, Cut, Verdict, cut_at_sync
from sisa.core.errors import EncodeError

SYNC = b"\xb5\x62"
HEADER_BYTES = 6  # sync, class, id, length
CHECKSUM_BYTES = 2
MAX_PAYLOAD_BYTES = 4096  # a cap on what a corrupted length can make the stream wait for
LENGTH_AT = 4


class UbxRefusal(StrEnum):
    """Why a UBX frame is refused (`DecodeStats.refused` keys)."""

    CHECKSUM = "ubx.checksum"  # CK_A/CK_B do not match
    LENGTH = "ubx.length"  # a length beyond MAX_PAYLOAD_BYTES, or not the message's
    FIELD_VALUE = "ubx.field_value"  # a field outside its declared range
    MALFORMED = "ubx.malformed"  # not a frame at all (decode_frame on other bytes)


def fletcher8(data: bytes) -> tuple[int, int]:
    """UBX's checksum: CK_A = Σ bytes, CK_B = Σ CK_A, both mod 256."""
    a = b = 0
    for byte in data:
        a = (a + byte) & 0xFF
        b = (b + a) & 0xFF
    return a, b


def encode_frame(msg_class: int, msg_id: int, payload: bytes) -> bytes:
    """A whole frame: sync, header, payload, checksum."""
    if not (0 <= msg_class <= 0xFF and 0 <= msg_id <= 0xFF):
        raise EncodeError(f"UBX class/id {msg_class}/{msg_id} is not a byte each")
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise EncodeError(f"UBX payload of {len(payload)} bytes exceeds {MAX_PAYLOAD_BYTES}")
    body = bytes([msg_class, msg_id]) + len(payload).to_bytes(2, "little") + payload
    return SYNC + body + bytes(fletcher8(body))


def split_frame(raw: bytes) -> tuple[int, int, bytes]:
    """(class, id, payload) of a whole frame; RefusedError if it is not one."""
    if len(raw) < HEADER_BYTES + CHECKSUM_BYTES or not raw.startswith(SYNC):
        raise RefusedError(UbxRefusal.MALFORMED, "not a UBX frame", raw=raw)
    length = int.from_bytes(raw[LENGTH_AT:HEADER_BYTES], "little")
    if len(raw) != HEADER_BYTES + length + CHECKSUM_BYTES:
        raise RefusedError(UbxRefusal.LENGTH, f"UBX frame of {len(raw)} bytes, its length "
                           f"says {HEADER_BYTES + length + CHECKSUM_BYTES}", raw=raw)
    if bytes(fletcher8(raw[len(SYNC):-CHECKSUM_BYTES])) != raw[-CHECKSUM_BYTES:]:
        raise RefusedError(UbxRefusal.CHECKSUM, "UBX checksum mismatch",
                           kind=ErrorKind.CHECKSUM, raw=raw)
    return raw[2], raw[3], raw[HEADER_BYTES:-CHECKSUM_BYTES]


def cut_frame(buffer: bytearray, start: int, at_end: bool) -> Cut:
    """A stream framer's verdict on buffer[start:], where buffer[start] is SYNC[0] (a frame
    still short at the end of the stream is left to the stream's `unfinished`)."""
    if (sync := cut_at_sync(buffer, start, SYNC)) is not None:
        return sync
    have = len(buffer) - start
    if have < HEADER_BYTES:
        return MORE
    length = int.from_bytes(buffer[start + LENGTH_AT:start + HEADER_BYTES], "little")
    if length > MAX_PAYLOAD_BYTES:
        return Cut(Verdict.DAMAGED, len(SYNC), UbxRefusal.LENGTH,
                   f"UBX length {length} beyond {MAX_PAYLOAD_BYTES}", run_on=True)
    total = HEADER_BYTES + length + CHECKSUM_BYTES
    if have < total:
        return MORE
    body = bytes(buffer[start + len(SYNC):start + total - CHECKSUM_BYTES])
    if bytes(fletcher8(body)) != buffer[start + total - CHECKSUM_BYTES:start + total]:
        return Cut(Verdict.DAMAGED, len(SYNC), UbxRefusal.CHECKSUM, "UBX checksum mismatch",
                   kind=ErrorKind.CHECKSUM, shadow=total)
    return Cut(Verdict.WHOLE, total)


def first_ubx_frame(data: bytes) -> int:
    """Where the first whole UBX frame whose Fletcher checksum holds begins, or -1: how a port
    proves it is a u-blox receiver before anything of it is recorded."""
    start = data.find(SYNC)
    while 0 <= start <= len(data) - HEADER_BYTES - CHECKSUM_BYTES:
        end = (start + HEADER_BYTES + CHECKSUM_BYTES
               + int.from_bytes(data[start + LENGTH_AT:start + HEADER_BYTES], "little"))
        if end <= len(data) and bytes(fletcher8(data[start + 2:end - 2])) == data[end - 2:end]:
            return start
        start = data.find(SYNC, start + 1)
    return -1
