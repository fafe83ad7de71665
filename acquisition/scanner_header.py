"""The scanner's frame header on RS-232: one declared layout, encoded by the emulator and decoded
from an arbitrarily chunked, possibly damaged byte stream by the acquisition.

Every value is little-endian, the CRC included:

| offset | size | field               | type | meaning                                          |
|--------|------|---------------------|------|--------------------------------------------------|
| 0      | 2    | sync                | —    | 0xA5 0x5A                                        |
| 2      | 1    | length              | u8   | body length, 13 for this layout                  |
| 3      | 4    | frame_counter       | u32  | frame counter, wraps at 2^frame_counter_bits     |
| 7      | 4    | integration_time_us | u32  | integration time, µs                             |
| 11     | 1    | mode                | u8   | ScannerMode                                      |
| 12     | 2    | segment             | u16  | recording segment number                         |
| 14     | 2    | bands               | u16  | spectral bands recorded, 1–288                   |
| 16     | 2    | crc                 | u16  | CRC-16/CCITT-FALSE over bytes 2–15               |

The framing (sync, length, CRC, resynchronisation, refusals counted as `scanner.length`,
`scanner.checksum`, `scanner.field_value`) is the one `acquisition.crcframe` declares; the port
carries nothing else, so any byte between headers is junk.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

from acquisition.checksums import crc16_ccitt_false
from acquisition.codec import ErrorPolicy
from acquisition.crcframe import CrcFramer, CrcMessage
from acquisition.fields import Field, Layout, WireType
from acquisition.framing import StreamDecoder
from sisa.core.errors import EncodeError

__all__ = ["BODY", "HEADER_BYTES", "MESSAGE", "SYNC", "FrameHeader", "HeaderStreamDecoder",
           "ScannerMode", "crc16_ccitt_false", "decode_header", "encode_header", "first_header"]

SYNC = b"\xa5\x5a"


class ScannerMode(IntEnum):
    IDLE = 0  # no frames recorded
    RECORDING = 1  # scene frames
    CALIBRATION = 2  # frames of the calibration lamp
    DARK = 3  # frames with the shutter closed (dark current)


@dataclass(frozen=True)
class FrameHeader:
    """What the scanner says about one frame (its checksum lives only on the wire)."""

    frame_counter: int  # wraps at 2^frame_counter_bits
    integration_time_us: int
    mode: ScannerMode
    segment: int  # recording segment number
    bands: int


BODY = Layout("scanner_frame_header", 13, (
    Field.at_byte("frame_counter", 0, WireType.U32),
    Field.at_byte("integration_time_us", 4, WireType.U32, unit="us"),
    Field.at_byte("mode", 8, WireType.U8, maximum=max(ScannerMode)),
    Field.at_byte("segment", 9, WireType.U16),
    Field.at_byte("bands", 11, WireType.U16, minimum=1, maximum=288),
))
MESSAGE = CrcMessage("scanner", SYNC, BODY)
HEADER_BYTES = MESSAGE.message_bytes


def encode_header(h: FrameHeader, *, frame_counter_bits: int = 16) -> bytes:
    """The header's bytes; EncodeError for a value out of range or a counter not yet wrapped."""
    if not 0 <= h.frame_counter < 1 << frame_counter_bits:
        raise EncodeError(f"frame_counter = {h.frame_counter} is outside "
                          f"[0, 2^{frame_counter_bits})")
    return MESSAGE.pack({"frame_counter": h.frame_counter, "mode": int(h.mode),
                         "integration_time_us": h.integration_time_us, "segment": h.segment,
                         "bands": h.bands})


def _header(raws: dict[str, int]) -> FrameHeader:
    return FrameHeader(raws["frame_counter"], raws["integration_time_us"],
                       ScannerMode(raws["mode"]), raws["segment"], raws["bands"])


def decode_header(raw: bytes) -> FrameHeader:
    """One whole header; RefusedError (naming its reason) if it is not a valid one."""
    return _header(MESSAGE.unpack(raw))


def first_header(data: bytes) -> int:
    """Where in `data` the first whole, valid header begins, or -1: how a port proves it is the
    scanner before anything of it is recorded."""
    return MESSAGE.first_valid(data)


class HeaderStreamDecoder(StreamDecoder[FrameHeader]):
    """The scanner's header port, cut anywhere: no good header is lost to a damaged one next to
    it, and each bad stretch is counted once, by reason (`stats.refused`). The port carries
    nothing but headers: a CR or LF between them is junk, as any other byte."""

    def __init__(self, policy: ErrorPolicy = ErrorPolicy.COUNT) -> None:
        super().__init__([CrcFramer(MESSAGE, _header, "frame_header")], policy, filler=b"")
