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

The framing (sync, length, CRC over the length byte and the body, resynchronisation, refusals
by reason) is the one `acquisition.crcframe` declares, shared with the scanner's frame header.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from acquisition.codec import ErrorPolicy
from acquisition.crcframe import CrcFramer, CrcMessage
from acquisition.fields import Field, Layout, WireType
from acquisition.framing import StreamDecoder
from sisa.core.errors import EncodeError

SYNC = b"\xc5\x5c"
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
MESSAGE = CrcMessage("camera", SYNC, BODY)
MESSAGE_BYTES = MESSAGE.message_bytes


def encode_photo(msg: PhotoMessage, *, photo_counter_bits: int = 16) -> bytes:
    """The message's bytes; EncodeError for a value out of range or a counter not yet wrapped."""
    if not 0 <= msg.photo_number < 1 << photo_counter_bits:
        raise EncodeError(f"photo_number = {msg.photo_number} is outside "
                          f"[0, 2^{photo_counter_bits})")
    return MESSAGE.pack({"photo_number": msg.photo_number,
                         "exposure_time_us": msg.exposure_time_us})


def _photo(raws: dict[str, int]) -> PhotoMessage:
    return PhotoMessage(raws["photo_number"], raws["exposure_time_us"])


def decode_photo(raw: bytes) -> PhotoMessage:
    """One whole message; RefusedError (naming its reason) if it is not a valid one."""
    return _photo(MESSAGE.unpack(raw))


class PhotoStreamDecoder(StreamDecoder[PhotoMessage]):
    """The camera's port, cut anywhere: no good message is lost to a damaged one next to it, and
    each bad stretch is counted once, by reason (`stats.refused`). The port carries nothing
    but these messages: a CR or LF between them is junk, as any other byte."""

    def __init__(self, policy: ErrorPolicy = ErrorPolicy.COUNT) -> None:
        super().__init__([CrcFramer(MESSAGE, _photo, "photo")], policy, filler=b"")


def first_photo_message(data: bytes) -> int:
    """Where in `data` the first whole, valid photo message begins, or -1: how a port proves it
    is the camera before anything of it is recorded."""
    return MESSAGE.first_valid(data)
