"""The GPS receiver's wire protocol: NMEA 0183 GGA, RMC, ZDA, GNS and GST as receivers send them
(versions 2.0 to 4.11, any talker), and the Ashtech `$PASHR,PTT` and `$PASHR,TTT` time tags,
each declared once as a table of fields.

One walker turns a table into both the encoder (used by the receiver emulator) and the decoder
(used by the acquisition), so the two sides cannot drift apart. Encoders round to the wire
resolution (never truncate) and refuse values the wire cannot carry; the `*_from_*` helpers round
the instant itself first, so a carry reaches the date, the day of week or the next week.

Times are integer ns: `utc_time_of_day_ns` for the UTC sentences (GGA, RMC, ZDA) and
`gps_time_of_week_ns` for the Ashtech time tags (GPS time, no leap seconds; day of week d = 1..7
with Sunday = 1, so time of week = (d − 1)·86400 s + time of day).

One module, one job:
- `wire`: how one attribute becomes one or more comma-separated tokens, and back;
- `tables`: a sentence declared as data, and the walker that encodes and decodes it;
- `sentences`: the sentences we speak, their messages and tables;
- `codec`: one whole sentence (address, checksum, framing) to and from bytes;
- `gpstime`: messages from a GPS instant, and GPS time back from messages;
- `stream`: sentences from a byte stream cut anywhere (a framer for `acquisition.framing`,
  which can interleave them with a binary protocol).

This package's names are the public API; importers use `acquisition.nmea`, not the modules.
"""

from acquisition.nmea.codec import (
    DEFAULT_VERSION,
    MAX_SENTENCE_BYTES,
    ChecksumError,
    decode_sentence,
    encode,
    first_checked_sentence,
)
from acquisition.nmea.gpstime import (
    gga_from_fix,
    gps_ns_from_time_of_week,
    gps_ns_from_utc,
    gps_ns_from_utc_time_of_day,
    ptt_from_gps_ns,
    rmc_from_fix,
    ttt_from_gps_ns,
    zda_from_gps_ns,
)
from acquisition.nmea.sentences import (
    SPECS,
    FixQuality,
    Gga,
    Gns,
    Gst,
    KnownMessage,
    ModeIndicator,
    NavStatus,
    NmeaMessage,
    PashrPtt,
    PashrTtt,
    Rmc,
    RmcStatus,
    Talker,
    UnknownSentence,
    Zda,
    message_kind,
)
from acquisition.nmea.stream import NmeaFramer, NmeaStreamDecoder
from acquisition.nmea.tables import NmeaVersion, Refusal, SentenceKind, SentenceSpec, Unit
from acquisition.nmea.wire import Blankable
from sisa.core.errors import EncodeError
from sisa.core.nmea import checksum

__all__ = [
    "DEFAULT_VERSION", "MAX_SENTENCE_BYTES", "SPECS", "Blankable", "ChecksumError",
    "EncodeError", "FixQuality", "Gga", "Gns", "Gst", "KnownMessage", "ModeIndicator",
    "NavStatus", "NmeaFramer", "NmeaMessage", "NmeaStreamDecoder", "NmeaVersion", "PashrPtt",
    "PashrTtt", "Refusal", "Rmc", "RmcStatus", "SentenceKind", "SentenceSpec", "Talker", "Unit",
    "UnknownSentence", "Zda", "checksum", "decode_sentence", "encode", "first_checked_sentence",
    "gga_from_fix",
    "gps_ns_from_time_of_week", "gps_ns_from_utc", "gps_ns_from_utc_time_of_day",
    "message_kind", "ptt_from_gps_ns", "rmc_from_fix", "ttt_from_gps_ns", "zda_from_gps_ns",
]
