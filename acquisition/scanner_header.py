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

The CRC covers the length byte as well as the body, so a corrupted length cannot pass. A reader
takes any other length as a framing error: a future layout must change the length byte.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

from acquisition.checksums import crc16_ccitt_false
from acquisition.codec import Decoded, DecodeStats, ErrorPolicy, report_error
from acquisition.fields import Field, Layout, WireType
from sisa.core.errors import EncodeError

SYNC = b"\xa5\x5a"
CRC_BYTES = 2


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
HEADER_BYTES = len(SYNC) + 1 + BODY.size_bytes + CRC_BYTES


def encode_header(h: FrameHeader, *, frame_counter_bits: int = 16) -> bytes:
    """The header's bytes; EncodeError for a value out of range or a counter not yet wrapped."""
    if not 0 <= h.frame_counter < 1 << frame_counter_bits:
        raise EncodeError(f"frame_counter = {h.frame_counter} is outside "
                          f"[0, 2^{frame_counter_bits})")
    body = BODY.pack({"frame_counter": h.frame_counter, "mode": int(h.mode),
                      "integration_time_us": h.integration_time_us, "segment": h.segment,
                      "bands": h.bands})
    checked = bytes([BODY.size_bytes]) + body
    return SYNC + checked + crc16_ccitt_false(checked).to_bytes(CRC_BYTES, "little")


def _header_from_body(body: bytes) -> FrameHeader | None:
    raws = BODY.unpack_raw(body)
    if BODY.out_of_range(raws):
        return None
    return FrameHeader(raws["frame_counter"], raws["integration_time_us"],
                       ScannerMode(raws["mode"]), raws["segment"], raws["bands"])


def first_header(data: bytes) -> int:
    """Where in `data` the first whole, valid header begins (its CRC holds, its values are in
    range), or -1: how a port proves it is the scanner before anything of it is recorded."""
    start = data.find(SYNC)
    while 0 <= start <= len(data) - HEADER_BYTES:
        checked = data[start + len(SYNC):start + HEADER_BYTES - CRC_BYTES]
        crc = int.from_bytes(data[start + HEADER_BYTES - CRC_BYTES:start + HEADER_BYTES],
                             "little")
        if (checked[0] == BODY.size_bytes and crc16_ccitt_false(checked) == crc
                and _header_from_body(checked[1:]) is not None):
            return start
        start = data.find(SYNC, start + 1)
    return -1


class HeaderStreamDecoder:
    """Finds headers in a byte stream cut anywhere, resynchronising after garbage or damage.

    Error counting, the same however the stream is chunked: every sync candidate that fails
    (wrong length, CRC, or a value out of range) counts one error, and a run of bytes skipped
    before any error was counted since the last good header counts one framing error. So each
    damaged header between two intact ones counts exactly one error, unless its damage created a
    new sync pattern. On a failed candidate the search restarts one byte after its sync, so a
    false sync inside garbage never swallows a good header that follows. Between calls the buffer
    holds less than one header.
    """

    def __init__(self, policy: ErrorPolicy = ErrorPolicy.COUNT) -> None:
        self.policy = policy
        self.stats = DecodeStats()
        self._buf = bytearray()
        self._offset = 0  # stream offset of _buf[0]
        self._error_open = False  # an error since the last good header accounts for skipped bytes

    def feed(self, data: bytes) -> list[Decoded[FrameHeader]]:
        """Headers completed by these bytes, in stream order."""
        self._buf += data
        out: list[Decoded[FrameHeader]] = []
        while True:
            start = self._buf.find(SYNC)
            if start < 0:
                self._skip(len(self._buf) - (1 if self._buf.endswith(SYNC[:1]) else 0))
                return out
            self._skip(start)
            if len(self._buf) < len(SYNC) + 1:
                return out
            if self._buf[len(SYNC)] != BODY.size_bytes:
                self._reject(1, "framing", f"length {self._buf[len(SYNC)]} after sync")
                continue
            if len(self._buf) < HEADER_BYTES:
                return out
            item = self._take_candidate()
            if item is not None:
                out.append(item)

    def flush(self) -> None:
        """End of stream: count what is left in the buffer as skipped."""
        self._skip(len(self._buf))

    def _take_candidate(self) -> Decoded[FrameHeader] | None:
        raw = bytes(self._buf[:HEADER_BYTES])
        checked, crc = raw[len(SYNC):-CRC_BYTES], raw[-CRC_BYTES:]
        if crc16_ccitt_false(checked) != int.from_bytes(crc, "little"):
            self._reject(1, "checksum", "CRC-16 mismatch")
            return None
        header = _header_from_body(checked[1:])
        if header is None:
            self._reject(HEADER_BYTES, "framing", "header value out of range")
            return None
        del self._buf[:HEADER_BYTES]
        self._offset += HEADER_BYTES
        self._error_open = False
        self.stats.count_message("frame_header")
        return Decoded(raw, header)

    def _skip(self, n: int) -> None:
        if n <= 0:
            return
        raw = bytes(self._buf[:n])
        self._drop(n)
        if not self._error_open:
            self._error_open = True
            report_error(self.policy, self.stats, "framing", f"{n} unexpected bytes before a sync",
                         offset=self._offset - n, raw=raw)

    def _reject(self, n: int, kind: str, message: str) -> None:
        """Drop a failed candidate's first n bytes and count its error."""
        raw = bytes(self._buf[:HEADER_BYTES])
        self._drop(n)
        self._error_open = True
        report_error(self.policy, self.stats, kind, message, offset=self._offset - n, raw=raw)

    def _drop(self, n: int) -> None:
        del self._buf[:n]
        self._offset += n
        self.stats.bytes_skipped += n
