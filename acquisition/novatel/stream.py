"""NovAtel ASCII logs on a stream, alone or interleaved with NMEA sentences on one port (an
OEM7 port can carry both): one `acquisition.framing.StreamDecoder` with both framers."""

from __future__ import annotations

from typing import Any

from acquisition.codec import ErrorPolicy
from acquisition.framing import Cut, StreamDecoder
from acquisition.nmea import NmeaFramer, NmeaMessage
from acquisition.novatel.frame import MAX_LOG_BYTES, SYNC, cut_frame
from acquisition.novatel.logs import NovatelLog, decode_log, log_name

NmeaNovatelMessage = NmeaMessage | NovatelLog


class NovatelFramer:
    """NovAtel ASCII logs (`acquisition.novatel.frame`) on a stream."""

    name = "novatel"
    leads = SYNC
    max_message_bytes = MAX_LOG_BYTES

    def cut(self, buffer: bytearray, start: int, at_end: bool) -> Cut:
        return cut_frame(buffer, start, at_end)

    def decode(self, raw: bytes) -> NovatelLog:
        return decode_log(raw)

    def kind(self, message: Any) -> str:
        return log_name(message)


class NmeaNovatelStreamDecoder(StreamDecoder[NmeaNovatelMessage]):
    """NMEA sentences and NovAtel ASCII logs interleaved on one stream, cut anywhere: a `#`
    cuts a sentence short as a `$` cuts a log short, so no good message is lost to a damaged
    one next to it, and each bad stretch is counted once, by reason."""

    def __init__(self, policy: ErrorPolicy = ErrorPolicy.COUNT, *,
                 accept_missing_checksum: bool = False) -> None:
        super().__init__([NmeaFramer(accept_missing_checksum=accept_missing_checksum,
                                     other_starts=SYNC),
                          NovatelFramer()], policy)
