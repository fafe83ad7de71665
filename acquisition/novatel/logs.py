"""The NovAtel OEM7 ASCII logs we speak, each declared once as a list of data fields (a name and
how it is written); one encoder and one decoder serve them all. Facts from NovAtel's public OEM7
Commands and Logs reference, in our own words (docs/protocols.md has the field tables):

- MARK1TIME (and its older name MARKTIME, and MARK2TIME for the second event input): the time
  of the leading edge of a pulse on the event input: GPS week, seconds of week as measured by
  the receiver's clock (9 decimals), the receiver clock's offset from GPS time and its standard
  deviation (s), the offset of GPS time from UTC (s, negative: −leap seconds) and the clock
  model's status. GPS time = the seconds − the offset. The header holds the mark's time too.
- TIME: the clock model's status, the receiver clock's offset from GPS time and its standard
  deviation, the offset of GPS time from UTC, UTC year, month, day, hour, minute and
  milliseconds, and the UTC status. Logged `ontime 1` its header is the whole GPS second; the
  receiver's PPS marks that second (GPS time of the pulse = header time − offset).
- BESTPOS: the solution status and position type, latitude and longitude (degrees), height
  above mean sea level and the undulation (the geoid's height above the ellipsoid) in metres,
  the datum, σ of latitude, longitude and height (m), the base station id (quoted), the
  differential age and solution age (s), satellites tracked, used, used with L1/E1/B1, used
  with several frequencies, a reserved byte, the extended solution status and two signal
  masks (hex bytes). The header's time is the position's epoch.

Values keep what the wire holds: times as exact integer ns, counts as int, the rest as float,
enums as their names.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, Generic, TypeVar

from acquisition.codec import RefusedError
from acquisition.novatel.frame import (
    FINE_TIME,
    LogHeader,
    NovatelRefusal,
    encode_frame,
    format_seconds,
    header_from_gps_ns,
    parse_seconds,
    split_frame,
)
from sisa.core.errors import EncodeError
from sisa.core.timescale import NS_PER_S, NS_PER_WEEK, utc_datetime_from_gps_ns

M = TypeVar("M")


class ClockStatus(StrEnum):
    """The receiver clock model's status."""

    VALID = "VALID"
    CONVERGING = "CONVERGING"
    ITERATING = "ITERATING"
    INVALID = "INVALID"
    ERROR = "ERROR"


class UtcStatus(StrEnum):
    INVALID = "INVALID"
    VALID = "VALID"
    WARNING = "WARNING"


class SolutionStatus(StrEnum):
    """BESTPOS's solution status."""

    SOL_COMPUTED = "SOL_COMPUTED"
    INSUFFICIENT_OBS = "INSUFFICIENT_OBS"
    NO_CONVERGENCE = "NO_CONVERGENCE"
    SINGULARITY = "SINGULARITY"
    COV_TRACE = "COV_TRACE"
    TEST_DIST = "TEST_DIST"
    COLD_START = "COLD_START"
    V_H_LIMIT = "V_H_LIMIT"
    VARIANCE = "VARIANCE"
    RESIDUALS = "RESIDUALS"
    INTEGRITY_WARNING = "INTEGRITY_WARNING"
    PENDING = "PENDING"
    INVALID_FIX = "INVALID_FIX"
    UNAUTHORIZED = "UNAUTHORIZED"
    INVALID_RATE = "INVALID_RATE"


class PositionType(StrEnum):
    """BESTPOS's position type (the kind of solution)."""

    NONE = "NONE"
    FIXEDPOS = "FIXEDPOS"
    FIXEDHEIGHT = "FIXEDHEIGHT"
    DOPPLER_VELOCITY = "DOPPLER_VELOCITY"
    SINGLE = "SINGLE"
    PSRDIFF = "PSRDIFF"
    WAAS = "WAAS"
    PROPAGATED = "PROPAGATED"
    L1_FLOAT = "L1_FLOAT"
    NARROW_FLOAT = "NARROW_FLOAT"
    L1_INT = "L1_INT"
    WIDE_INT = "WIDE_INT"
    NARROW_INT = "NARROW_INT"
    RTK_DIRECT_INS = "RTK_DIRECT_INS"
    INS_SBAS = "INS_SBAS"
    INS_PSRSP = "INS_PSRSP"
    INS_PSRDIFF = "INS_PSRDIFF"
    INS_RTKFLOAT = "INS_RTKFLOAT"
    INS_RTKFIXED = "INS_RTKFIXED"
    PPP_CONVERGING = "PPP_CONVERGING"
    PPP = "PPP"
    OPERATIONAL = "OPERATIONAL"
    WARNING = "WARNING"
    OUT_OF_BOUNDS = "OUT_OF_BOUNDS"
    INS_PPP_CONVERGING = "INS_PPP_CONVERGING"
    INS_PPP = "INS_PPP"
    PPP_BASIC_CONVERGING = "PPP_BASIC_CONVERGING"
    PPP_BASIC = "PPP_BASIC"
    INS_PPP_BASIC_CONVERGING = "INS_PPP_BASIC_CONVERGING"
    INS_PPP_BASIC = "INS_PPP_BASIC"


# --- how a field is written ----------------------------------------------------------------

@dataclass(frozen=True)
class Wire:
    """One way of writing a value in an ASCII field, and of reading it back."""

    write: Callable[[Any], str]
    read: Callable[[str], Any]


_INTEGER = re.compile(r"-?[0-9]{1,12}")
_DECIMAL = re.compile(r"[-+]?[0-9]{1,12}(?:\.[0-9]*)?(?:[eE][-+]?[0-9]{1,3})?")


def _int(low: int, high: int) -> Wire:
    def read(text: str) -> int:
        if not _INTEGER.fullmatch(text):
            raise ValueError(f"{text[:80]!r} is no integer")
        value = int(text)
        if not low <= value <= high:
            raise ValueError(f"{value} out of {low}..{high}")
        return value

    def write(value: int) -> str:
        if not low <= value <= high:
            raise EncodeError(f"{value} out of {low}..{high}")
        return str(value)

    return Wire(write, read)


def _finite(text: str) -> float:
    """A decimal number as the receiver writes one (no inf, nan, spaces or underscores)."""
    if not _DECIMAL.fullmatch(text):
        raise ValueError(f"{text[:80]!r} is no decimal number")
    value = float(text)
    if not math.isfinite(value):  # an exponent past a double's range
        raise ValueError(f"{text[:80]!r} is not finite")
    return value


def _fixed(decimals: int) -> Wire:
    return Wire(lambda v: f"{v:.{decimals}f}", _finite)


def _sci(digits: int) -> Wire:
    """Scientific notation, a zero in fixed notation (as NovAtel's examples and its decoder SDK
    write a clock offset: -1.398163614e-08, 0.000000000)."""
    return Wire(lambda v: f"{v:.{digits}e}" if v else f"{0.0:.{digits}f}", _finite)


def _seconds(decimals: int) -> Wire:
    def read(text: str) -> int:
        value = parse_seconds(text)
        if not 0 <= value < NS_PER_WEEK:
            raise ValueError(f"{text!r} not within a week")
        return value

    def write(value: int) -> str:
        if not 0 <= value < NS_PER_WEEK:
            raise EncodeError(f"{value} ns not within a week")
        return format_seconds(value, decimals)

    return Wire(write, read)


def _enum(cls: type[StrEnum]) -> Wire:
    return Wire(lambda v: cls(v).value, cls)


def _hex(digits: int) -> Wire:
    top = 16**digits - 1
    pattern = re.compile(f"[0-9a-fA-F]{{1,{digits}}}")

    def read(text: str) -> int:
        if not pattern.fullmatch(text):
            raise ValueError(f"{text!r} is no {digits}-digit hex number")
        return int(text, 16)

    def write(value: int) -> str:
        if not 0 <= value <= top:
            raise EncodeError(f"{value} out of 0..{top}")
        return f"{value:0{digits}x}"

    return Wire(write, read)


def _quoted_read(text: str) -> str:
    if len(text) < 2 or text[0] != '"' or text[-1] != '"':
        raise ValueError(f"{text[:80]!r} is not a quoted string")
    return text[1:-1]


def _quoted_write(value: str) -> str:
    if '"' in value or len(value) > 32:
        raise EncodeError(f"{value[:80]!r} cannot be a quoted field")
    return f'"{value}"'


def _token_read(text: str) -> str:
    if not re.fullmatch(r"[A-Za-z0-9_]{1,32}", text):
        raise ValueError(f"{text[:80]!r} is no datum name")
    return text


WEEK = _int(0, 0xFFFF)
SECONDS_9 = _seconds(9)
OFFSET = _sci(9)
METRES = _fixed(4)
DEGREES = _fixed(11)
AGE = _fixed(3)
COUNT = _int(0, 255)
HEX_BYTE = _hex(2)
QUOTED = Wire(_quoted_write, _quoted_read)
TOKEN = Wire(lambda v: _token_read(str(v)), _token_read)


@dataclass(frozen=True)
class LogSpec(Generic[M]):
    """A log declared as data: its name (without the format letter) and its data fields in
    order, each a dataclass field of `build` and how it is written."""

    name: str
    fields: tuple[tuple[str, Wire], ...]
    build: Callable[..., M]


# --- the logs ------------------------------------------------------------------------------

@dataclass(frozen=True)
class MarkTime:
    """MARK1TIME (MARKTIME, MARK2TIME): the time of a pulse on an event input."""

    header: LogHeader
    week: int
    seconds_ns: int  # of week, by the receiver's clock
    offset_s: float  # receiver clock − GPS time
    offset_std_s: float
    utc_offset_s: float  # UTC − GPS: −leap seconds
    status: ClockStatus

    @property
    def gps_ns(self) -> int:
        """GPS time of the pulse, ns since the GPS epoch (the clock offset taken off)."""
        return self.week * NS_PER_WEEK + self.seconds_ns - round(self.offset_s * NS_PER_S)


@dataclass(frozen=True)
class TimeLog:
    """TIME: the receiver's clock model and UTC; logged on the second, the time of its PPS."""

    header: LogHeader
    clock_status: ClockStatus
    offset_s: float
    offset_std_s: float
    utc_offset_s: float
    utc_year: int
    utc_month: int
    utc_day: int
    utc_hour: int
    utc_minute: int
    utc_ms: int
    utc_status: UtcStatus

    @property
    def pps_gps_ns(self) -> int:
        """GPS time of the PPS of the header's second (the clock offset taken off)."""
        return self.header.gps_ns - round(self.offset_s * NS_PER_S)


@dataclass(frozen=True)
class BestPos:
    """BESTPOS: the receiver's best position at the header's epoch."""

    header: LogHeader
    solution_status: SolutionStatus
    position_type: PositionType
    lat_deg: float
    lon_deg: float
    height_msl_m: float
    undulation_m: float
    datum: str
    lat_sigma_m: float
    lon_sigma_m: float
    height_sigma_m: float
    station_id: str
    diff_age_s: float
    solution_age_s: float
    svs_tracked: int
    svs_used: int
    svs_used_l1: int
    svs_used_multi: int
    reserved: int
    extended_status: int
    galileo_beidou_mask: int
    gps_glonass_mask: int

    @property
    def height_ellipsoidal_m(self) -> float:
        return self.height_msl_m + self.undulation_m


_MARK_FIELDS = (("week", WEEK), ("seconds_ns", SECONDS_9), ("offset_s", OFFSET),
                ("offset_std_s", OFFSET), ("utc_offset_s", _fixed(9)),
                ("status", _enum(ClockStatus)))
MARK1TIME = LogSpec("MARK1TIME", _MARK_FIELDS, MarkTime)
MARKTIME = LogSpec("MARKTIME", _MARK_FIELDS, MarkTime)  # the older name of MARK1TIME
MARK2TIME = LogSpec("MARK2TIME", _MARK_FIELDS, MarkTime)
TIME = LogSpec("TIME", (
    ("clock_status", _enum(ClockStatus)), ("offset_s", OFFSET), ("offset_std_s", OFFSET),
    ("utc_offset_s", _fixed(11)), ("utc_year", _int(0, 9999)), ("utc_month", _int(0, 12)),
    ("utc_day", _int(0, 31)), ("utc_hour", _int(0, 23)), ("utc_minute", _int(0, 59)),
    ("utc_ms", _int(0, 60_999)), ("utc_status", _enum(UtcStatus)),
), TimeLog)
BESTPOS = LogSpec("BESTPOS", (
    ("solution_status", _enum(SolutionStatus)), ("position_type", _enum(PositionType)),
    ("lat_deg", DEGREES), ("lon_deg", DEGREES), ("height_msl_m", METRES),
    ("undulation_m", METRES), ("datum", TOKEN), ("lat_sigma_m", METRES),
    ("lon_sigma_m", METRES), ("height_sigma_m", METRES), ("station_id", QUOTED),
    ("diff_age_s", AGE), ("solution_age_s", AGE), ("svs_tracked", COUNT), ("svs_used", COUNT),
    ("svs_used_l1", COUNT), ("svs_used_multi", COUNT), ("reserved", HEX_BYTE),
    ("extended_status", HEX_BYTE), ("galileo_beidou_mask", HEX_BYTE),
    ("gps_glonass_mask", HEX_BYTE),
), BestPos)


@dataclass(frozen=True)
class UnknownLog:
    """A well-framed log whose CRC holds but that we have no field list for: kept, counted."""

    header: LogHeader
    fields: tuple[str, ...]


NovatelLog = MarkTime | TimeLog | BestPos | UnknownLog
LOG_SPECS: tuple[LogSpec[Any], ...] = (MARK1TIME, MARKTIME, MARK2TIME, TIME, BESTPOS)
_SPEC_BY_NAME = {spec.name: spec for spec in LOG_SPECS}
UNKNOWN_KIND = "NovAtel-unknown"


def log_name(message: NovatelLog) -> str:
    """The counter name of a log: its name with the format letter (MARK1TIMEA, ...)."""
    if isinstance(message, UnknownLog):
        return UNKNOWN_KIND
    return message.header.name + "A"


def encode_log(message: NovatelLog) -> bytes:
    """The whole ASCII log of a message (EncodeError for a value its field cannot hold)."""
    if isinstance(message, UnknownLog):
        return encode_frame(message.header, list(message.fields))
    spec = _SPEC_BY_NAME.get(message.header.name)
    if spec is None or type(message) is not spec.build:
        raise EncodeError(f"no {type(message).__name__} log named {message.header.name!r}")
    try:
        fields = [wire.write(getattr(message, name)) for name, wire in spec.fields]
    except ValueError as err:  # an enum member that is none
        raise EncodeError(f"{spec.name}: {err}") from err
    return encode_frame(message.header, fields)


def decode_log(raw: bytes) -> NovatelLog:
    """The log of a whole ASCII line; RefusedError (a DecodeError) naming the reason."""
    header, fields = split_frame(raw)
    spec = _SPEC_BY_NAME.get(header.name)
    if spec is None:
        return UnknownLog(header, tuple(fields))
    if len(fields) != len(spec.fields):
        raise RefusedError(NovatelRefusal.FIELD_COUNT, f"{spec.name}A: {len(fields)} data "
                           f"fields, not {len(spec.fields)}", raw=raw)
    values: dict[str, Any] = {}
    for text, (name, wire) in zip(fields, spec.fields, strict=True):
        try:
            values[name] = wire.read(text)
        except ValueError as err:
            raise RefusedError(NovatelRefusal.FIELD_VALUE,
                               f"{spec.name}A: {name} {text[:80]!r}: {err}", raw=raw) from err
    message: NovatelLog = spec.build(header, **values)
    return message


def time_is_fine(header: LogHeader) -> bool:
    """The receiver knows GPS time to well under a microsecond (its clock steered to it)."""
    return header.time_status in FINE_TIME


# ---------------------------------------------------------------------------------------------
# Logs from GPS instants (the emulator's side).

# the header's reserved word as NovAtel's receivers fill it for our logs (the definition's CRC)
DEFINITION_CRC = {"MARK1TIME": 0x292E, "MARKTIME": 0x292E, "MARK2TIME": 0x861E, "TIME": 0x9924,
                  "BESTPOS": 0xCDBA}


def log_header(name: str, t_gps_ns: int) -> LogHeader:
    """The header the emulated receiver writes for log `name` at `t_gps_ns`."""
    return header_from_gps_ns(name, t_gps_ns, definition_crc=DEFINITION_CRC.get(name, 0))


def mark1time_from_gps_ns(t_gps_ns: int, offset_std_s: float, leap_s: int) -> MarkTime:
    """MARK1TIME of a pulse at `t_gps_ns` (the receiver's clock steered: offset 0)."""
    week, seconds_ns = divmod(t_gps_ns, NS_PER_WEEK)
    return MarkTime(log_header("MARK1TIME", t_gps_ns), week, seconds_ns, 0.0,
                    offset_std_s, float(-leap_s), ClockStatus.VALID)


def time_for_pps(second_gps_ns: int, offset_std_s: float, leap_s: int) -> TimeLog:
    """TIME logged on the second `second_gps_ns` (the PPS's second), with its UTC."""
    utc = utc_datetime_from_gps_ns(second_gps_ns, leap_s)
    return TimeLog(log_header("TIME", second_gps_ns), ClockStatus.VALID, 0.0,
                   offset_std_s, float(-leap_s), utc.year, utc.month, utc.day, utc.hour,
                   utc.minute, utc.second * 1000 + utc.microsecond // 1000, UtcStatus.VALID)
