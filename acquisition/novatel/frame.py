"""The NovAtel OEM7 ASCII log: its frame, its CRC-32 and its header, and a stream framer's verdict
on bytes. Facts from NovAtel's public OEM7 Commands and Logs reference, in our own words:

    #NAME,port,sequence,idle%,time status,week,seconds,receiver status,reserved,version;
    data field,data field,...*xxxxxxxx<CR><LF>

- the log starts with `#`; the header's ten fields are separated by commas and end at `;`;
- the data fields follow, separated by commas (a string field is in double quotes);
- `*` and eight lowercase hex digits close it: a CRC-32 over every byte between the `#` and
  the `*` (both excluded), then CR LF;
- the CRC is NovAtel's: the reflected polynomial 0xEDB88320, started at 0, with no final
  inversion; zlib's CRC-32 is the same register started and ended inverted, so ours is
  `~zlib.crc32(data, 0xFFFFFFFF)` (`crc32_reference` does it bit by bit);
- the header: the log's name with its format letter (`A` for ASCII), the port it left by, a
  sequence number (counting down to 0 over logs of one epoch that belong together), the
  receiver's idle time in % (one decimal), the time status (how well the receiver knows GPS
  time: FINESTEERING when its clock is steered to it), the GPS week and seconds of week (3
  decimals) of the log, the receiver status word (8 hex digits), a 4-hex-digit word the
  reference calls reserved (NovAtel's own decoder SDK, EDIE, reads it as a CRC of the log's
  definition: 9924 for TIME, 292e for MARK1TIME, cdba for BESTPOS, as in NovAtel's examples;
  the emulator writes those), and the receiver's software build number.
"""

from __future__ import annotations

import re
import zlib
from dataclasses import dataclass
from enum import StrEnum

from acquisition.codec import ErrorKind, RefusedError
from acquisition.framing import Cut, Verdict, cut_at_line_end
from sisa.core.errors import EncodeError
from sisa.core.timescale import NS_PER_S, NS_PER_WEEK

SYNC = b"#"
CRC_MARK = b"*"
CRC_DIGITS = 8
LINE_END = b"\r\n"
MAX_LOG_BYTES = 4096  # a cap on what a log without line end can make the stream wait for
HEADER_FIELDS = 10
NS_PER_MS = 1_000_000


class NovatelRefusal(StrEnum):
    """Why a NovAtel ASCII log is refused (`DecodeStats.refused` keys)."""

    CRC = "novatel.crc"  # the CRC-32 does not match
    MALFORMED = "novatel.malformed"  # no `*` + 8 hex digits, no `;`, a header not of 10 fields
    FIELD_COUNT = "novatel.field_count"  # a known log with more or fewer data fields
    FIELD_VALUE = "novatel.field_value"  # a field that does not parse or is out of range
    CUT_SHORT = "novatel.cut_short"  # a new `#` or `$`, or a byte no log holds, before its end
    TOO_LONG = "novatel.too_long"  # no line end within MAX_LOG_BYTES


class TimeStatus(StrEnum):
    """How well the receiver knows GPS time (the header's time status), worst to best-ish."""

    UNKNOWN = "UNKNOWN"
    APPROXIMATE = "APPROXIMATE"
    COARSEADJUSTING = "COARSEADJUSTING"
    COARSE = "COARSE"
    COARSESTEERING = "COARSESTEERING"
    FREEWHEELING = "FREEWHEELING"
    FINEADJUSTING = "FINEADJUSTING"
    FINE = "FINE"
    FINEBACKUPSTEERING = "FINEBACKUPSTEERING"
    FINESTEERING = "FINESTEERING"
    SATTIME = "SATTIME"


# the time statuses in which the receiver's GPS time is good to well under a microsecond
FINE_TIME = frozenset({TimeStatus.FINE, TimeStatus.FINEBACKUPSTEERING, TimeStatus.FINESTEERING})


def crc32_novatel(data: bytes) -> int:
    """NovAtel's CRC-32 of `data` (the bytes between `#` and `*`)."""
    return ~zlib.crc32(data, 0xFFFFFFFF) & 0xFFFFFFFF


def crc32_reference(data: bytes) -> int:
    """The same CRC bit by bit, as the reference describes it (for the tests)."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xEDB88320 if crc & 1 else crc >> 1
    return crc


def format_seconds(t_ns: int, decimals: int) -> str:
    """Non-negative ns as seconds with `decimals` decimals (rounded half up), exactly."""
    unit = 10 ** (9 - decimals)
    q = (t_ns + unit // 2) // unit
    if decimals == 0:
        return str(q)
    whole, frac = divmod(q, 10**decimals)
    return f"{whole}.{frac:0{decimals}d}"


_SECONDS = re.compile(r"(-?)(\d{1,12})(?:\.(\d{1,9}))?")


def parse_seconds(text: str) -> int:
    """Seconds written with at most 9 decimals, as exact ns; ValueError if not such a number."""
    m = _SECONDS.fullmatch(text)
    if m is None:
        raise ValueError(f"{text!r} is no number of seconds")
    sign, whole, frac = m.groups()
    ns = int(whole) * NS_PER_S + int((frac or "").ljust(9, "0"))
    return -ns if sign else ns


@dataclass(frozen=True)
class LogHeader:
    """The ten fields of an ASCII log's header (`name` without its format letter `A`)."""

    name: str
    port: str = "COM1"
    sequence: int = 0
    idle_pct: float = 80.0
    time_status: TimeStatus = TimeStatus.FINESTEERING
    week: int = 0
    seconds_ns: int = 0  # of week, whole ms
    receiver_status: int = 0
    definition_crc: int = 0  # the header's "reserved" word
    version: int = 16809

    @property
    def gps_ns(self) -> int:
        """The log's time, ns since the GPS epoch."""
        return self.week * NS_PER_WEEK + self.seconds_ns

    def text(self) -> str:
        for label, value, top in (("sequence", self.sequence, 0xFFFF),
                                  ("week", self.week, 0xFFFF),
                                  ("receiver status", self.receiver_status, 0xFFFFFFFF),
                                  ("reserved", self.definition_crc, 0xFFFF),
                                  ("version", self.version, 0xFFFF)):
            if not 0 <= value <= top:
                raise EncodeError(f"NovAtel header {label} {value} out of 0..{top}")
        if not 0 <= self.seconds_ns < NS_PER_WEEK:
            raise EncodeError(f"NovAtel header seconds {self.seconds_ns} ns not within a week")
        if not _NAME.fullmatch(self.name) or not _NAME.fullmatch(self.port):
            raise EncodeError(f"NovAtel header name {self.name!r} or port {self.port!r}")
        return (f"{self.name}A,{self.port},{self.sequence},{self.idle_pct:.1f},"
                f"{self.time_status.value},{self.week},"
                f"{format_seconds(self.seconds_ns, 3)},{self.receiver_status:08x},"
                f"{self.definition_crc:04x},{self.version}")


_NAME = re.compile(r"[A-Z0-9_]{1,32}")


def header_from_gps_ns(name: str, t_gps_ns: int, **fields: object) -> LogHeader:
    """A header stamped at `t_gps_ns` (rounded to the ms the header holds)."""
    t_ms = (t_gps_ns + NS_PER_MS // 2) // NS_PER_MS * NS_PER_MS
    week, seconds_ns = divmod(t_ms, NS_PER_WEEK)
    return LogHeader(name, week=week, seconds_ns=seconds_ns, **fields)  # type: ignore[arg-type]


def encode_frame(header: LogHeader, fields: list[str]) -> bytes:
    """A whole log: `#`, header, `;`, the data fields, `*`, CRC, CR LF."""
    body = (header.text() + ";" + ",".join(fields)).encode("ascii")
    if any(b in body for b in (0x23, 0x24, 0x2A)) or not body.isascii() \
            or any(b < 0x20 or b > 0x7E for b in body):
        raise EncodeError("a NovAtel log field holds '#', '$', '*' or a byte no log holds")
    raw = SYNC + body + CRC_MARK + f"{crc32_novatel(body):08x}".encode() + LINE_END
    if len(raw) > MAX_LOG_BYTES:
        raise EncodeError(f"NovAtel log of {len(raw)} bytes exceeds {MAX_LOG_BYTES}")
    return raw


_FRAME = re.compile(rb"#([\x20-\x7e]*)\*([0-9a-fA-F]{8})\r?\n?")


def split_frame(raw: bytes) -> tuple[LogHeader, list[str]]:
    """The header and data fields of a whole log (its line end optional); RefusedError if it
    is not one, its CRC fails, or its header does not parse."""
    m = _FRAME.fullmatch(raw)
    if m is None:
        raise RefusedError(NovatelRefusal.MALFORMED, "not a NovAtel ASCII log (#...*xxxxxxxx)",
                           raw=raw)
    body, crc = m.group(1), int(m.group(2), 16)
    if crc32_novatel(body) != crc:
        raise RefusedError(NovatelRefusal.CRC, "NovAtel CRC-32 mismatch", kind=ErrorKind.CHECKSUM,
                           raw=raw)
    text = body.decode("ascii")
    head, sep, data = text.partition(";")
    parts = head.split(",")
    if not sep or len(parts) != HEADER_FIELDS or not parts[0].endswith("A"):
        raise RefusedError(NovatelRefusal.MALFORMED, "NovAtel ASCII header is not ten fields "
                           "ending in ';' with a name ending in 'A'", raw=raw)
    try:
        header = _parse_header(parts)
    except ValueError as err:
        raise RefusedError(NovatelRefusal.FIELD_VALUE, f"NovAtel header: {err}", raw=raw) \
            from err
    return header, split_fields(data)


_HEADER_NUMBERS = re.compile(r"[0-9]{1,5},[0-9]{1,3}(?:\.[0-9])?,[^,]*,[0-9]{1,5},[^,]*,"
                             r"[0-9a-fA-F]{1,8},[0-9a-fA-F]{1,4},[0-9]{1,5}")


def _parse_header(parts: list[str]) -> LogHeader:
    name, port, seq, idle, status, week, seconds, rx, reserved, version = parts
    if not _NAME.fullmatch(name[:-1]) or not _NAME.fullmatch(port):
        raise ValueError(f"log name {name[:80]!r} or port {port[:80]!r}")
    if not _HEADER_NUMBERS.fullmatch(",".join(parts[2:])):
        raise ValueError(f"a header number that is none: {','.join(parts[2:])[:120]!r}")
    seconds_ns = parse_seconds(seconds)
    week_n = int(week)
    if not (0 <= seconds_ns < NS_PER_WEEK and 0 <= week_n <= 0xFFFF):
        raise ValueError(f"time {week},{seconds}")
    if int(seq) > 0xFFFF or float(idle) > 100.0 or int(version) > 0xFFFF:
        raise ValueError(f"sequence {seq}, idle {idle} % or version {version} out of range")
    return LogHeader(name[:-1], port, int(seq), float(idle), TimeStatus(status), week_n,
                     seconds_ns, int(rx, 16), int(reserved, 16), int(version))


def split_fields(data: str) -> list[str]:
    """Data fields split at commas outside double quotes."""
    if '"' not in data:
        return data.split(",")
    out: list[str] = []
    field: list[str] = []
    quoted = False
    for ch in data:
        if ch == '"':
            quoted = not quoted
        if ch == "," and not quoted:
            out.append("".join(field))
            field = []
        else:
            field.append(ch)
    out.append("".join(field))
    return out


# a byte that cannot be inside a log: a line end, '#', '$', a control or non-ASCII byte
_LOG_STOP = re.compile(rb"[^\x20-\x22\x25-\x7e]")


def cut_frame(buffer: bytearray, start: int, at_end: bool) -> Cut:
    """A stream framer's verdict on buffer[start:], where buffer[start] is `#`: a whole line up
    to its line end (LF, CR LF, or a CR not followed by LF) is a log to decode; a new `#` or
    `$` or a byte no log holds before it cuts the log short there (the rest of its line, up to
    the next message start, is the same error)."""
    at = cut_at_line_end(buffer, start, at_end, _LOG_STOP, MAX_LOG_BYTES,
                         NovatelRefusal.TOO_LONG)
    if isinstance(at, Cut):
        return at
    byte = buffer[at]
    if byte in b"#$":
        return Cut(Verdict.DAMAGED, at - start, NovatelRefusal.CUT_SHORT,
                   f"log cut short by a new {chr(byte)!r}")
    return Cut(Verdict.DAMAGED, at - start, NovatelRefusal.CUT_SHORT,
               f"log cut short by byte 0x{byte:02X}", run_on=True)


_WHOLE_LOG = re.compile(rb"#([\x20-\x22\x25-\x7e]*)\*([0-9a-fA-F]{8})")


def first_novatel_log(data: bytes) -> int:
    """Where the first NovAtel ASCII log whose CRC holds begins, or -1: how a port proves it
    is a NovAtel receiver before anything of it is recorded."""
    for m in _WHOLE_LOG.finditer(data):
        if crc32_novatel(m.group(1)) == int(m.group(2), 16):
            return m.start()
    return -1
