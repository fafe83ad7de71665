"""The frame camera's photo message on its own RS-232 port: one declared layout, encoded by the
emulator and decoded from an arbitrarily chunked, possibly damaged byte stream by the
acquisition (docs/protocols.md, "Frame camera photo message").

The camera sends one message a short latency after each exposure (after the second half of the
exposure, once the image is stored), naming the photo it has just taken. Its mid-exposure pulse
goes out on a pulse line at the exposure itself; the message is how the acquisition learns which
photo number that pulse was. Every value is little-endian, the CRC included:

| offset | size | field            | type | meaning                                        |
|--------|------|------------------|------|------------------------------------------------|
| 0      | 2    | sync             | —    | 0xC5 0x5C                                      |
| 2      | 1    | length           | u8   | body length, 8 for this layout                 |
| 3      | 4    | photo_number     | u32  | the camera's photo counter, wraps at 2^bits    |
| 7      | 4    | exposure_time_us | u32  | exposure (shutter open) time, 1 µs – 1 s       |
| 11     | 2    | crc              | u16  | CRC-16/CCITT-FALSE over bytes 2–10             |

The CRC covers the length byte as well as the body. Every message has the same length, so a
damaged one (wrong length byte, CRC that fails) is refused as far as its sync, and whatever fails
inside the 13 bytes it would span is the same error: a good message that begins inside them is
still decoded.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from acquisition.checksums import crc16_ccitt_false
from acquisition.codec import ErrorKind, ErrorPolicy, RefusedError
from acquisition.fields import Field, Layout, WireType
from acquisition.framing import MORE, Cut, StreamDecoder, Verdict, cut_at_sync
from sisa.core.errors import EncodeError

SYNC = b"\xc5\x5c"
CRC_BYTES = 2
MAX_EXPOSURE_US = 1_000_000


class CameraRefusal(StrEnum):
    """Why a photo message is refused (`DecodeStats.refused` keys)."""

    LENGTH = "camera.length"  # the length byte is not this layout's
    CHECKSUM = "camera.checksum"  # the CRC-16 does not match
    FIELD_VALUE = "camera.field_value"  # a value outside its declared range
    MALFORMED = "camera.malformed"  # not a photo message at all (decode on other bytes)


@dataclass(frozen=True)
class PhotoMessage:
    """What the camera says about one photo (its checksum lives only on the wire)."""

    photo_number: int  # wraps at 2^photo_counter_bits
    exposure_time_us: int


BODY = Layout("camera_photo", 8, (
    Field.at_byte("photo_number", 0, WireType.U32),
    Field.at_byte("exposure_time_us", 4, WireType.U32, unit="us", minimum=1,
                  maximum=MAX_EXPOSURE_US),
))
MESSAGE_BYTES = len(SYNC) + 1 + BODY.size_bytes + CRC_BYTES


def encode_photo(msg: PhotoMessage, *, photo_counter_bits: int = 16) -> bytes:
    """The message's bytes; EncodeError for a value out of range or a counter not yet wrapped."""
    if not 0 <= msg.photo_number < 1 << photo_counter_bits:
        raise EncodeError(f"photo_number = {msg.photo_number} is outside "
                          f"[0, 2^{photo_counter_bits})")
    body = BODY.pack({"photo_number": msg.photo_number,
                      "exposure_time_us": msg.exposure_time_us})
    checked = bytes([BODY.size_bytes]) + body
    return SYNC + checked + crc16_ccitt_false(checked).to_bytes(CRC_BYTES, "little")


def decode_photo(raw: bytes) -> PhotoMessage:
    """One whole message; RefusedError (naming its reason) if it is not a valid one."""
    if len(raw) != MESSAGE_BYTES or not raw.startswith(SYNC):
        raise RefusedError(CameraRefusal.MALFORMED, "not a camera photo message", raw=raw)
    if raw[len(SYNC)] != BODY.size_bytes:
        raise RefusedError(CameraRefusal.LENGTH, f"length {raw[len(SYNC)]} after sync", raw=raw)
    checked = raw[len(SYNC):-CRC_BYTES]
    if crc16_ccitt_false(checked) != int.from_bytes(raw[-CRC_BYTES:], "little"):
        raise RefusedError(CameraRefusal.CHECKSUM, "camera CRC-16 mismatch",
                           kind=ErrorKind.CHECKSUM, raw=raw)
    raws = BODY.unpack_raw(checked[1:])
    if bad := BODY.out_of_range(raws):
        raise RefusedError(CameraRefusal.FIELD_VALUE, f"out of range: {', '.join(bad)}",
                           raw=raw)
    return PhotoMessage(raws["photo_number"], raws["exposure_time_us"])


def cut_photo(buffer: bytearray, start: int, at_end: bool) -> Cut:
    """A stream framer's verdict on buffer[start:], where buffer[start] is SYNC[0] (a message
    still short at the end of the stream is left to the stream's `unfinished`)."""
    if (sync := cut_at_sync(buffer, start, SYNC)) is not None:
        return sync
    have = len(buffer) - start
    if have < len(SYNC) + 1:
        return MORE
    if buffer[start + len(SYNC)] != BODY.size_bytes:
        return Cut(Verdict.DAMAGED, len(SYNC), CameraRefusal.LENGTH,
                   f"length {buffer[start + len(SYNC)]} after sync", shadow=MESSAGE_BYTES)
    if have < MESSAGE_BYTES:
        return MORE
    checked = bytes(buffer[start + len(SYNC):start + MESSAGE_BYTES - CRC_BYTES])
    crc = int.from_bytes(buffer[start + MESSAGE_BYTES - CRC_BYTES:start + MESSAGE_BYTES],
                         "little")
    if crc16_ccitt_false(checked) != crc:
        return Cut(Verdict.DAMAGED, len(SYNC), CameraRefusal.CHECKSUM, "camera CRC-16 mismatch",
                   kind=ErrorKind.CHECKSUM, shadow=MESSAGE_BYTES)
    return Cut(Verdict.WHOLE, MESSAGE_BYTES)


class PhotoFramer:
    """Photo messages on a stream (for `acquisition.framing.StreamDecoder`)."""

    name = "camera"
    leads = SYNC[:1]
    max_message_bytes = MESSAGE_BYTES

    def cut(self, buffer: bytearray, start: int, at_end: bool) -> Cut:
        return cut_photo(buffer, start, at_end)

    def decode(self, raw: bytes) -> PhotoMessage:
        return decode_photo(raw)

    def kind(self, message: Any) -> str:
        return "photo"


class PhotoStreamDecoder(StreamDecoder[PhotoMessage]):
    """The camera's port, cut anywhere: no good message is lost to a damaged one next to it, and
    each bad stretch is counted once, by reason (`stats.refused`). The port carries nothing
    but these messages: a CR or LF between them is junk, as any other byte."""

    def __init__(self, policy: ErrorPolicy = ErrorPolicy.COUNT) -> None:
        super().__init__([PhotoFramer()], policy, filler=b"")


def first_photo_message(data: bytes) -> int:
    """Where in `data` the first whole, valid photo message begins, or -1: how a port proves it
    is the camera before anything of it is recorded."""
    start = data.find(SYNC)
    while 0 <= start <= len(data) - MESSAGE_BYTES:
        try:
            decode_photo(data[start:start + MESSAGE_BYTES])
        except RefusedError:
            start = data.find(SYNC, start + 1)
            continue
        return start
    return -1
