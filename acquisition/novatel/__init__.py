"""NovAtel OEM7 ASCII logs: the frame (`#header;data*crc32`), NovAtel's CRC-32, the logs
MARK1TIME (event marks), TIME (the PPS's second) and BESTPOS (fixes) declared as field lists,
and a stream decoder for those logs interleaved with NMEA on one port.

- `frame`: the frame, its CRC and header, and a stream framer's verdict on bytes;
- `logs`: the logs as data, their encoder and decoder, logs from GPS instants;
- `stream`: the framer, and the NMEA + NovAtel stream decoder.
"""

from acquisition.novatel.frame import (
    MAX_LOG_BYTES,
    LogHeader,
    NovatelRefusal,
    TimeStatus,
    crc32_novatel,
    crc32_reference,
    encode_frame,
    first_novatel_log,
    header_from_gps_ns,
)
from acquisition.novatel.logs import (
    BESTPOS,
    LOG_SPECS,
    MARK1TIME,
    MARK2TIME,
    MARKTIME,
    TIME,
    BestPos,
    ClockStatus,
    MarkTime,
    NovatelLog,
    PositionType,
    SolutionStatus,
    TimeLog,
    UnknownLog,
    UtcStatus,
    decode_log,
    encode_log,
    log_header,
    log_name,
    mark1time_from_gps_ns,
    time_for_pps,
    time_is_fine,
)
from acquisition.novatel.stream import NmeaNovatelMessage, NmeaNovatelStreamDecoder, NovatelFramer

__all__ = [
    "BESTPOS", "LOG_SPECS", "MARK1TIME", "MARK2TIME", "MARKTIME", "MAX_LOG_BYTES", "TIME",
    "BestPos", "ClockStatus", "LogHeader", "MarkTime", "NmeaNovatelMessage",
    "NmeaNovatelStreamDecoder", "NovatelFramer", "NovatelLog", "NovatelRefusal",
    "PositionType", "SolutionStatus", "TimeLog", "TimeStatus", "UnknownLog", "UtcStatus",
    "crc32_novatel", "crc32_reference", "decode_log", "encode_frame", "encode_log",
    "first_novatel_log", "header_from_gps_ns", "log_header", "log_name", "mark1time_from_gps_ns",
    "time_for_pps", "time_is_fine",
]
