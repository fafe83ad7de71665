"""UBX frames on a stream, alone or interleaved with NMEA sentences on one port (a u-blox
receiver's default output): one `acquisition.framing.StreamDecoder` with both framers."""

from __future__ import annotations

from typing import Any

from acquisition.codec import ErrorPolicy
from acquisition.framing import Cut, StreamDecoder
from acquisition.nmea import NmeaFramer, NmeaMessage
from acquisition.ubx.frame import CHECKSUM_BYTES, HEADER_BYTES, MAX_PAYLOAD_BYTES, SYNC, cut_frame
from acquisition.ubx.messages import UbxMessage, decode_ubx, ubx_name

GpsMessage = NmeaMessage | UbxMessage


class UbxFramer:
    """UBX frames (`acquisition.ubx.frame`) on a stream."""

    name = "ubx"
    leads = SYNC[:1]
    max_message_bytes = HEADER_BYTES + MAX_PAYLOAD_BYTES + CHECKSUM_BYTES

    def cut(self, buffer: bytearray, start: int, at_end: bool) -> Cut:
        return cut_frame(buffer, start, at_end)

    def decode(self, raw: bytes) -> UbxMessage:
        return decode_ubx(raw)

    def kind(self, message: Any) -> str:
        return ubx_name(message)


class NmeaUbxStreamDecoder(StreamDecoder[GpsMessage]):
    """NMEA sentences and UBX frames interleaved on one stream, cut anywhere: no good message
    is lost to a damaged one next to it, and each bad stretch is counted once, by reason."""

    def __init__(self, policy: ErrorPolicy = ErrorPolicy.COUNT, *,
                 accept_missing_checksum: bool = False) -> None:
        super().__init__([NmeaFramer(accept_missing_checksum=accept_missing_checksum),
                          UbxFramer()], policy)
