"""The GPS receiver's wire protocol: NMEA 0183 GGA, RMC and ZDA, and the Ashtech `$PASHR,PTT` and
`$PASHR,TTT` time tags, each declared once as a table of fields.

One walker turns a table into both the encoder (used by the receiver emulator) and the decoder
(used by the acquisition), so the two sides cannot drift apart. Encoders round to the wire
resolution (never truncate) and refuse values the wire cannot carry; the `*_from_*` helpers round
the instant itself first, so a carry reaches the date, the day of week or the next week.

Times are integer ns: `utc_time_of_day_ns` for the UTC sentences (GGA, RMC, ZDA) and
`gps_time_of_week_ns` for the Ashtech time tags (GPS time, no leap seconds; day of week d = 1..7
with Sunday = 1, so time of week = (d − 1)·86400 s + time of day).
"""

from __future__ import annotations

import datetime as dt
import math
import re
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum, IntEnum, StrEnum
from functools import cached_property
from typing import Any, ClassVar, Generic, TypeVar

from acquisition.codec import Decoded, DecodeStats, ErrorPolicy, report_error
from sisa.core.errors import DecodeError, EncodeError
from sisa.core.nmea import checksum
from sisa.core.timescale import GPS_EPOCH, NS_PER_DAY, NS_PER_S, NS_PER_WEEK

T = TypeVar("T")
E = TypeVar("E", bound=Enum)
M = TypeVar("M")

# Framing. NMEA 0183 caps a sentence at 82 bytes; our 7-decimal GGA reaches 96 and real Ashtech
# proprietary sentences ($PASHR,POS) run past 100, so the cap leaves room while still bounding
# what garbage can make the stream decoder hold.
MAX_SENTENCE_BYTES = 128
SENTENCE_START_BYTE = b"$"
SENTENCE_START = SENTENCE_START_BYTE[0]
LINE_FEED = ord("\n")
LINE_END = "\r\n"
CHECKSUM_DELIMITER = "*"
FIELD_SEPARATOR = ","
CHECKSUM_DIGITS = 2
_PRINTABLE_ASCII = re.compile(rb"[\x20-\x7e]*")
_HEX_PAIR = re.compile(rb"[0-9A-Fa-f]{2}")
_ADDRESS = re.compile(r"[A-Z0-9]+")
_LINE_BREAK_BYTES = b"\r\n"

KNOTS_PER_M_S = 3600.0 / 1852.0  # 1 knot = 1852 m/h
MINUTES_PER_DEGREE = 60
SECONDS_PER_MINUTE = 60
MINUTES_PER_HOUR = 60
HOURS_PER_DAY = 24
MINUTE_DIGITS = 2  # the "mm" of ddmm.mmmmmmm
NS_DIGITS = 9  # decimals of a second that an int ns holds
FIRST_DAY_OF_WEEK = 1  # Ashtech: Sunday = 1 (the GPS epoch was a Sunday)
DAYS_PER_WEEK = 7
TWO_DIGIT_YEAR_PIVOT = 80  # ddmmyy: yy >= 80 is 19yy, else 20yy (GPS began in 1980)
FIRST_CENTURY, SECOND_CENTURY = 1900, 2000
YEARS_PER_CENTURY = 100
_GPS_EPOCH_DATE = GPS_EPOCH.date()


class ChecksumError(DecodeError):
    """The `*hh` checksum does not match the sentence: counted apart from framing errors."""


class ErrorKind(StrEnum):
    """The two error counters of `DecodeStats`."""

    CHECKSUM = "checksum"
    FRAMING = "framing"


class Unit(StrEnum):
    """Unit of a message attribute, stated in the field table (and in the attribute's name)."""

    NANOSECOND = "ns"
    SECOND = "s"
    DEGREE = "deg"
    METRE = "m"
    METRE_PER_SECOND = "m/s"
    COUNT = "count"
    NONE = ""


class Address(StrEnum):
    """Talker + sentence formatter of the sentences we speak."""

    GPGGA = "GPGGA"
    GPRMC = "GPRMC"
    GPZDA = "GPZDA"
    PASHR = "PASHR"


class AshtechId(StrEnum):
    """Second header field of the Ashtech proprietary sentences."""

    PTT = "PTT"  # GPS time of the PPS
    TTT = "TTT"  # GPS time of a pulse on the event input


class SentenceKind(StrEnum):
    """Name under which a sentence is counted in `DecodeStats.by_kind`."""

    GGA = "GGA"
    RMC = "RMC"
    ZDA = "ZDA"
    PTT = "PTT"
    TTT = "TTT"
    UNKNOWN = "unknown"


class Hemisphere(StrEnum):
    NORTH = "N"
    SOUTH = "S"
    EAST = "E"
    WEST = "W"


class UnitLetter(StrEnum):
    METRES = "M"


class FixQuality(IntEnum):
    """GGA fix quality: 1 code, 2 DGPS code, 4 carrier phase fixed (RTK), 5 float."""

    INVALID = 0
    GPS = 1
    DGPS = 2
    PPS = 3
    RTK_FIXED = 4
    RTK_FLOAT = 5
    ESTIMATED = 6
    MANUAL = 7
    SIMULATION = 8


class RmcStatus(StrEnum):
    ACTIVE = "A"
    VOID = "V"


class ModeIndicator(StrEnum):
    """RMC mode indicator (NMEA 2.3; P, R, F from 4.x)."""

    AUTONOMOUS = "A"
    DIFFERENTIAL = "D"
    ESTIMATED = "E"
    MANUAL = "M"
    SIMULATOR = "S"
    NOT_VALID = "N"
    PRECISE = "P"
    RTK_FIXED = "R"
    RTK_FLOAT = "F"


class ClockStyle(StrEnum):
    """How a time of day is written: NMEA `hhmmss.ss` or Ashtech `hh:mm:ss.sssssss`."""

    COMPACT = ""
    COLON = ":"


# ---------------------------------------------------------------------------------------------
# Wire formats: how one attribute becomes one or more comma-separated tokens, and back.


def _round_half_up(value: int, step: int) -> int:
    """Nearest multiple of `step` (ties up): integer-exact, for ns times."""
    return (value + step // 2) // step * step


def _bad(reason: str) -> DecodeError:
    return DecodeError(reason)


def _match(pattern: re.Pattern[str], token: str, what: str) -> re.Match[str]:
    found = pattern.fullmatch(token)
    if found is None:
        raise _bad(f"{what}: cannot read {token!r}")
    return found


class WireFormat(ABC, Generic[T]):
    """Encoder and decoder of one attribute; `width` tokens on the wire."""

    @property
    def width(self) -> int:
        return 1

    @property
    def resolution(self) -> float | None:
        """One LSB in the attribute's unit, for scaled numbers; None otherwise."""
        return None

    @abstractmethod
    def encode(self, value: T) -> tuple[str, ...]: ...

    @abstractmethod
    def decode(self, tokens: Sequence[str]) -> T: ...


_DECIMAL = re.compile(r"[+-]?\d+(\.\d+)?")
_INTEGER = re.compile(r"[+-]?\d+")


def _format_units(units: int, decimals: int) -> str:
    """Signed integer count of LSBs as a decimal string (no '-0.000')."""
    sign = "-" if units < 0 else ""
    whole, frac = divmod(abs(units), 10**decimals)
    return f"{sign}{whole}.{frac:0{decimals}d}" if decimals else f"{sign}{whole}"


@dataclass(frozen=True)
class FixedPoint(WireFormat[float]):
    """A decimal number with a fixed count of decimals; wire value = attribute · scale."""

    decimals: int
    maximum: float  # largest |wire value| the field's width allows
    scale: float = 1.0
    signed: bool = True
    modulus: float | None = None  # angles: a rounded 360.00 is written 0.00

    @property
    def resolution(self) -> float:
        return 10.0**-self.decimals / self.scale

    def encode(self, value: float) -> tuple[str, ...]:
        if not math.isfinite(value):
            raise EncodeError(f"not a finite number: {value!r}")
        wire = value * self.scale
        units = round(wire * 10**self.decimals)
        if self.modulus is not None:
            units %= round(self.modulus * 10**self.decimals)
        if abs(units) > round(self.maximum * 10**self.decimals) or (units < 0 and not self.signed):
            raise EncodeError(f"{value!r} outside the wire range ±{self.maximum}")
        return (_format_units(units, self.decimals),)

    def decode(self, tokens: Sequence[str]) -> float:
        return float(_match(_DECIMAL, tokens[0], "number").group(0)) / self.scale


@dataclass(frozen=True)
class Integer(WireFormat[int]):
    """A zero-padded integer (satellites, station id, calendar fields)."""

    digits: int
    minimum: int
    maximum: int

    def encode(self, value: int) -> tuple[str, ...]:
        if not self.minimum <= value <= self.maximum:
            raise EncodeError(f"{value} outside [{self.minimum}, {self.maximum}]")
        sign = "-" if value < 0 else ""
        return (f"{sign}{abs(value):0{self.digits}d}",)

    def decode(self, tokens: Sequence[str]) -> int:
        value = int(_match(_INTEGER, tokens[0], "integer").group(0))
        if not self.minimum <= value <= self.maximum:
            raise _bad(f"{value} outside [{self.minimum}, {self.maximum}]")
        return value


@dataclass(frozen=True)
class EnumToken(WireFormat[E]):
    """An enum member written as its value."""

    enum: type[E]

    def encode(self, value: E) -> tuple[str, ...]:
        return (str(value.value),)

    def decode(self, tokens: Sequence[str]) -> E:
        for member in self.enum:
            if str(member.value) == tokens[0]:
                return member
        raise _bad(f"{tokens[0]!r} is not a {self.enum.__name__}")


@dataclass(frozen=True)
class Blankable(WireFormat[T | None]):
    """A field that a receiver leaves empty when it has no value (no fix, no DGPS)."""

    inner: WireFormat[T]

    @property
    def width(self) -> int:
        return self.inner.width

    @property
    def resolution(self) -> float | None:
        return self.inner.resolution

    def encode(self, value: T | None) -> tuple[str, ...]:
        return ("",) * self.width if value is None else self.inner.encode(value)

    def decode(self, tokens: Sequence[str]) -> T | None:
        return None if not any(tokens) else self.inner.decode(tokens)


@dataclass(frozen=True)
class DegreesMinutes(WireFormat[float]):
    """Signed degrees as `(d)ddmm.mmmmmmm` plus a hemisphere letter (two tokens)."""

    degree_digits: int
    maximum_deg: int
    positive: Hemisphere
    negative: Hemisphere
    decimals: int

    @property
    def width(self) -> int:
        return 2

    @property
    def resolution(self) -> float:
        return 10.0**-self.decimals / MINUTES_PER_DEGREE

    def encode(self, value: float) -> tuple[str, ...]:
        if not math.isfinite(value):
            raise EncodeError(f"not a finite angle: {value!r}")
        per_degree = MINUTES_PER_DEGREE * 10**self.decimals
        units = round(abs(value) * per_degree)  # integer LSBs: the carry to whole minutes is exact
        if units > self.maximum_deg * per_degree:
            raise EncodeError(f"{value!r} beyond ±{self.maximum_deg}°")
        degrees, minute_units = divmod(units, per_degree)
        text = _format_units(minute_units, self.decimals)
        minutes = text.rjust(MINUTE_DIGITS + len(".") + self.decimals, "0")
        hemisphere = self.negative if value < 0 and units else self.positive
        return (f"{degrees:0{self.degree_digits}d}{minutes}", hemisphere.value)

    @cached_property
    def _pattern(self) -> re.Pattern[str]:
        return re.compile(rf"(\d{{{self.degree_digits}}})(\d{{{MINUTE_DIGITS}}}(?:\.\d+)?)")

    def decode(self, tokens: Sequence[str]) -> float:
        found = _match(self._pattern, tokens[0], "degrees-minutes")
        degrees, minutes = int(found.group(1)), float(found.group(2))
        value = degrees + minutes / MINUTES_PER_DEGREE
        if minutes >= MINUTES_PER_DEGREE or value > self.maximum_deg:
            raise _bad(f"angle out of range: {tokens[0]!r}")
        if tokens[1] not in (self.positive, self.negative):
            raise _bad(f"hemisphere {tokens[1]!r} is not {self.positive}/{self.negative}")
        return -value if tokens[1] == self.negative else value


@dataclass(frozen=True)
class TimeOfDay(WireFormat[int]):
    """Time of day in ns as `hhmmss.ss` (NMEA) or `hh:mm:ss.sssssss` (Ashtech)."""

    decimals: int
    style: ClockStyle = ClockStyle.COMPACT

    @property
    def resolution_ns(self) -> int:
        return int(10 ** (NS_DIGITS - self.decimals))

    @property
    def resolution(self) -> float:
        return float(self.resolution_ns)

    def encode(self, value: int) -> tuple[str, ...]:
        rounded = _round_half_up(value, self.resolution_ns)
        if not 0 <= value < NS_PER_DAY or rounded >= NS_PER_DAY:
            raise EncodeError(
                f"time of day {value} ns is not in [0, 24 h) once rounded; round the instant "
                "first (the *_from_* helpers do) so the carry reaches the date"
            )
        seconds, fraction = divmod(rounded, NS_PER_S)
        minutes, second = divmod(seconds, SECONDS_PER_MINUTE)
        hour, minute = divmod(minutes, MINUTES_PER_HOUR)
        sep = self.style.value
        return (f"{hour:02d}{sep}{minute:02d}{sep}{second:02d}."
                f"{fraction // self.resolution_ns:0{self.decimals}d}",)

    @cached_property
    def _pattern(self) -> re.Pattern[str]:
        sep = re.escape(self.style.value)
        return re.compile(rf"(\d\d){sep}(\d\d){sep}(\d\d)(?:\.(\d{{1,{NS_DIGITS}}}))?")

    def decode(self, tokens: Sequence[str]) -> int:
        *clock, fraction = _match(self._pattern, tokens[0], "time").groups()
        hour, minute, second = (int(part) for part in clock)
        if hour >= HOURS_PER_DAY or minute >= MINUTES_PER_HOUR or second >= SECONDS_PER_MINUTE:
            raise _bad(f"not a time of day: {tokens[0]!r}")
        seconds = (hour * MINUTES_PER_HOUR + minute) * SECONDS_PER_MINUTE + second
        return seconds * NS_PER_S + int((fraction or "0").ljust(NS_DIGITS, "0"))


_DAY_OF_WEEK = Integer(1, FIRST_DAY_OF_WEEK, DAYS_PER_WEEK)


@dataclass(frozen=True)
class DayAndTimeOfWeek(WireFormat[int]):
    """Ashtech GPS time of week in ns as day of week (1..7, Sunday = 1) and a time of day."""

    clock: TimeOfDay

    @property
    def width(self) -> int:
        return 2

    @property
    def resolution(self) -> float:
        return self.clock.resolution

    def encode(self, value: int) -> tuple[str, ...]:
        rounded = _round_half_up(value, self.clock.resolution_ns)
        if not 0 <= value < NS_PER_WEEK or rounded >= NS_PER_WEEK:
            raise EncodeError(
                f"time of week {value} ns is not in [0, 1 week) once rounded; round the "
                "instant first (ptt_from_gps_ns / ttt_from_gps_ns do)"
            )
        day, time_of_day = divmod(rounded, NS_PER_DAY)
        return (*_DAY_OF_WEEK.encode(day + FIRST_DAY_OF_WEEK), *self.clock.encode(time_of_day))

    def decode(self, tokens: Sequence[str]) -> int:
        day = _DAY_OF_WEEK.decode(tokens[:1])
        return (day - FIRST_DAY_OF_WEEK) * NS_PER_DAY + self.clock.decode(tokens[1:])


def _date_or_error(year: int, month: int, day: int) -> dt.date:
    try:
        return dt.date(year, month, day)
    except ValueError as err:
        raise _bad(f"not a date: {year}-{month}-{day}") from err


class DateDdMmYy(WireFormat[dt.date]):
    """RMC date `ddmmyy`; the two-digit year is read in 1980..2079."""

    _PATTERN: ClassVar[re.Pattern[str]] = re.compile(r"(\d\d)(\d\d)(\d\d)")
    _YEARS = range(FIRST_CENTURY + TWO_DIGIT_YEAR_PIVOT, SECOND_CENTURY + TWO_DIGIT_YEAR_PIVOT)

    def encode(self, value: dt.date) -> tuple[str, ...]:
        if value.year not in self._YEARS:
            raise EncodeError(f"year {value.year} is ambiguous in ddmmyy")
        return (f"{value.day:02d}{value.month:02d}{value.year % YEARS_PER_CENTURY:02d}",)

    def decode(self, tokens: Sequence[str]) -> dt.date:
        day, month, yy = (int(part) for part in _match(self._PATTERN, tokens[0], "date").groups())
        century = FIRST_CENTURY if yy >= TWO_DIGIT_YEAR_PIVOT else SECOND_CENTURY
        return _date_or_error(century + yy, month, day)


class DateDayMonthYear(WireFormat[dt.date]):
    """ZDA date as three tokens: dd, mm, yyyy; the year in 1980..2079, as RMC's. A year far
    outside (a corrupt or hostile receiver's 9999 or 0001) put the GPS times taken from it
    beyond the log's 64-bit integers, and the whole /gps/fix topic no longer read."""

    _DAY, _MONTH = Integer(2, 1, 31), Integer(2, 1, 12)
    _YEAR = Integer(4, FIRST_CENTURY + TWO_DIGIT_YEAR_PIVOT,
                    SECOND_CENTURY + TWO_DIGIT_YEAR_PIVOT - 1)

    @property
    def width(self) -> int:
        return 3

    def encode(self, value: dt.date) -> tuple[str, ...]:
        return (*self._DAY.encode(value.day), *self._MONTH.encode(value.month),
                *self._YEAR.encode(value.year))

    def decode(self, tokens: Sequence[str]) -> dt.date:
        day, month, year = (fmt.decode(tokens[i:i + 1])
                            for i, fmt in enumerate((self._DAY, self._MONTH, self._YEAR)))
        return _date_or_error(year, month, day)


# ---------------------------------------------------------------------------------------------
# Field tables and the walker.


@dataclass(frozen=True)
class Field:
    """One message attribute: its name in the dataclass, its wire format and its unit."""

    name: str
    wire: WireFormat[Any]
    unit: Unit = Unit.NONE

    @property
    def width(self) -> int:
        return self.wire.width


@dataclass(frozen=True)
class Constant:
    """A token that is always the same (a unit letter, an unused field)."""

    token: str
    width: int = 1


@dataclass(frozen=True)
class SentenceSpec(Generic[M]):
    """A sentence declared as data: its header tokens and its fields in wire order."""

    kind: SentenceKind
    header: tuple[str, ...]
    build: Callable[..., M]
    items: tuple[Field | Constant, ...]

    @property
    def fields(self) -> tuple[Field, ...]:
        return tuple(item for item in self.items if isinstance(item, Field))

    @property
    def width(self) -> int:
        return sum(item.width for item in self.items)


def _encode_tokens(spec: SentenceSpec[Any], message: object) -> list[str]:
    tokens = list(spec.header)
    for item in spec.items:
        if isinstance(item, Constant):
            tokens.append(item.token)
        else:
            tokens.extend(item.wire.encode(getattr(message, item.name)))
    return tokens


def _decode_tokens(spec: SentenceSpec[M], payload: Sequence[str]) -> M:
    if len(payload) != spec.width:
        raise _bad(f"{spec.kind}: {len(payload)} fields, expected {spec.width}")
    values: dict[str, Any] = {}
    start = 0
    for item in spec.items:
        tokens = payload[start:start + item.width]
        start += item.width
        if isinstance(item, Constant):
            if tokens[0] != item.token:
                raise _bad(f"{spec.kind}: expected {item.token!r}, got {tokens[0]!r}")
        else:
            try:
                values[item.name] = item.wire.decode(tokens)
            except DecodeError as err:
                raise _bad(f"{spec.kind}.{item.name}: {err}") from err
    return spec.build(**values)


# ---------------------------------------------------------------------------------------------
# Messages and their tables.

UTC_CLOCK = TimeOfDay(decimals=2)  # hhmmss.ss: 10 ms
TIME_TAG = DayAndTimeOfWeek(TimeOfDay(decimals=7, style=ClockStyle.COLON))  # 100 ns
LATITUDE = DegreesMinutes(2, 90, Hemisphere.NORTH, Hemisphere.SOUTH, decimals=7)
LONGITUDE = DegreesMinutes(3, 180, Hemisphere.EAST, Hemisphere.WEST, decimals=7)
METRES = Constant(UnitLetter.METRES.value)
EMPTY = Constant("")


@dataclass(frozen=True)
class Gga:
    """Fix data. Altitude is above the geoid: altitude = ellipsoidal height − geoid separation
    (gpsd recovers altHAE = altMSL + separation). Position fields are None without a fix."""

    utc_time_of_day_ns: int
    lat_deg: float | None
    lon_deg: float | None
    quality: FixQuality
    satellites: int
    hdop: float | None
    altitude_msl_m: float | None
    geoid_separation_m: float | None
    dgps_age_s: float | None = None
    dgps_station: int | None = None

    @property
    def height_ellipsoidal_m(self) -> float | None:
        if self.altitude_msl_m is None or self.geoid_separation_m is None:
            return None
        return self.altitude_msl_m + self.geoid_separation_m


GGA_SPEC = SentenceSpec(SentenceKind.GGA, (Address.GPGGA.value,), Gga, (
    Field("utc_time_of_day_ns", UTC_CLOCK, Unit.NANOSECOND),
    Field("lat_deg", Blankable(LATITUDE), Unit.DEGREE),
    Field("lon_deg", Blankable(LONGITUDE), Unit.DEGREE),
    Field("quality", EnumToken(FixQuality)),
    Field("satellites", Integer(2, 0, 99), Unit.COUNT),
    Field("hdop", Blankable(FixedPoint(decimals=1, maximum=99.9, signed=False))),
    Field("altitude_msl_m", Blankable(FixedPoint(decimals=3, maximum=99_999.999)), Unit.METRE),
    METRES,
    Field("geoid_separation_m", Blankable(FixedPoint(decimals=3, maximum=999.999)), Unit.METRE),
    METRES,
    Field("dgps_age_s", Blankable(FixedPoint(decimals=1, maximum=999.9, signed=False)),
          Unit.SECOND),
    Field("dgps_station", Blankable(Integer(4, 0, 1023))),
))


@dataclass(frozen=True)
class Rmc:
    """Recommended minimum data: UTC date and time, position, speed over ground, true course."""

    utc_time_of_day_ns: int
    status: RmcStatus
    lat_deg: float | None
    lon_deg: float | None
    speed_m_s: float | None
    course_true_deg: float | None
    utc_date: dt.date
    mode: ModeIndicator


RMC_SPEC = SentenceSpec(SentenceKind.RMC, (Address.GPRMC.value,), Rmc, (
    Field("utc_time_of_day_ns", UTC_CLOCK, Unit.NANOSECOND),
    Field("status", EnumToken(RmcStatus)),
    Field("lat_deg", Blankable(LATITUDE), Unit.DEGREE),
    Field("lon_deg", Blankable(LONGITUDE), Unit.DEGREE),
    Field("speed_m_s", Blankable(FixedPoint(decimals=3, maximum=9999.999, scale=KNOTS_PER_M_S,
                                            signed=False)), Unit.METRE_PER_SECOND),
    Field("course_true_deg", Blankable(FixedPoint(decimals=2, maximum=359.99, signed=False,
                                                  modulus=360.0)), Unit.DEGREE),
    Field("utc_date", DateDdMmYy()),
    EMPTY,  # magnetic variation
    EMPTY,  # its direction E/W
    Field("mode", EnumToken(ModeIndicator)),
))


@dataclass(frozen=True)
class Zda:
    """UTC date and time, and the local time zone (hours, minutes) the receiver was told."""

    utc_time_of_day_ns: int
    utc_date: dt.date
    zone_hours: int = 0
    zone_minutes: int = 0


ZDA_SPEC = SentenceSpec(SentenceKind.ZDA, (Address.GPZDA.value,), Zda, (
    Field("utc_time_of_day_ns", UTC_CLOCK, Unit.NANOSECOND),
    Field("utc_date", DateDayMonthYear()),
    Field("zone_hours", Integer(2, -13, 13)),
    Field("zone_minutes", Integer(2, 0, 59)),
))


@dataclass(frozen=True)
class PashrPtt:
    """Ashtech PPS time tag: GPS time of week of the PPS (GPS time, not UTC)."""

    gps_time_of_week_ns: int

    @property
    def day_of_week(self) -> int:
        return self.gps_time_of_week_ns // NS_PER_DAY + FIRST_DAY_OF_WEEK


@dataclass(frozen=True)
class PashrTtt:
    """Ashtech event time tag: GPS time of week of a pulse on the event input, 100 ns LSB."""

    gps_time_of_week_ns: int

    @property
    def day_of_week(self) -> int:
        return self.gps_time_of_week_ns // NS_PER_DAY + FIRST_DAY_OF_WEEK


PTT_SPEC = SentenceSpec(SentenceKind.PTT, (Address.PASHR.value, AshtechId.PTT.value), PashrPtt, (
    Field("gps_time_of_week_ns", TIME_TAG, Unit.NANOSECOND),
))
TTT_SPEC = SentenceSpec(SentenceKind.TTT, (Address.PASHR.value, AshtechId.TTT.value), PashrTtt, (
    Field("gps_time_of_week_ns", TIME_TAG, Unit.NANOSECOND),
))


@dataclass(frozen=True)
class UnknownSentence:
    """A well-framed sentence we have no table for (another talker or formatter): kept, counted."""

    address: str
    fields: tuple[str, ...]


KnownMessage = Gga | Rmc | Zda | PashrPtt | PashrTtt
NmeaMessage = KnownMessage | UnknownSentence
SPECS: tuple[SentenceSpec[Any], ...] = (GGA_SPEC, RMC_SPEC, ZDA_SPEC, PTT_SPEC, TTT_SPEC)
_SPEC_BY_TYPE: dict[Any, SentenceSpec[Any]] = {spec.build: spec for spec in SPECS}
_SPEC_BY_HEADER = {spec.header: spec for spec in SPECS}
_MAX_HEADER_TOKENS = max(len(spec.header) for spec in SPECS)


def message_kind(message: NmeaMessage) -> SentenceKind:
    """The counter name of a message."""
    spec = _SPEC_BY_TYPE.get(type(message))
    return SentenceKind.UNKNOWN if spec is None else spec.kind


# ---------------------------------------------------------------------------------------------
# Sentences: checksum, encode, decode.


def _tokens_of(message: NmeaMessage) -> list[str]:
    if isinstance(message, UnknownSentence):
        return [message.address, *message.fields]
    return _encode_tokens(_SPEC_BY_TYPE[type(message)], message)


def encode(message: NmeaMessage) -> bytes:
    """The complete sentence, `$...*hh` and CRLF."""
    body = FIELD_SEPARATOR.join(_tokens_of(message)).encode("ascii")
    sentence = b"%s%s%s%02X%s" % (SENTENCE_START_BYTE, body, CHECKSUM_DELIMITER.encode(),
                                   checksum(body), LINE_END.encode())
    if len(sentence) > MAX_SENTENCE_BYTES:
        raise EncodeError(f"sentence of {len(sentence)} bytes exceeds {MAX_SENTENCE_BYTES}")
    return sentence


def _verified_body(raw: bytes) -> str:
    """The text between `$` and `*` of a sentence whose framing and checksum are right."""
    text = raw.removesuffix(b"\n").removesuffix(b"\r")
    if not text.startswith(SENTENCE_START_BYTE):
        raise DecodeError("sentence does not start with '$'", raw=raw)
    if _PRINTABLE_ASCII.fullmatch(text) is None:
        raise DecodeError("non-printable or non-ASCII byte in sentence", raw=raw)
    star = text.rfind(CHECKSUM_DELIMITER.encode())
    digits = text[star + 1:]
    if star < 0 or _HEX_PAIR.fullmatch(digits) is None:
        raise DecodeError("no '*hh' checksum at the end of the sentence", raw=raw)
    body = text[1:star]
    if SENTENCE_START_BYTE in body or CHECKSUM_DELIMITER.encode() in body:
        raise DecodeError("reserved character '$' or '*' inside the sentence", raw=raw)
    if int(digits, 16) != checksum(body):
        raise ChecksumError(f"checksum {digits.decode()} != {checksum(body):02X}", raw=raw)
    return body.decode("ascii")


def _find_spec(tokens: Sequence[str]) -> SentenceSpec[Any] | None:
    for count in range(1, _MAX_HEADER_TOKENS + 1):
        spec = _SPEC_BY_HEADER.get(tuple(tokens[:count]))
        if spec is not None:
            return spec
    return None


def decode_sentence(raw: bytes) -> NmeaMessage:
    """Decode one sentence (`$...*hh`, line end optional). Raises DecodeError, or its subclass
    ChecksumError when only the checksum is wrong."""
    tokens = _verified_body(raw).split(FIELD_SEPARATOR)
    spec = _find_spec(tokens)
    if spec is None:
        if _ADDRESS.fullmatch(tokens[0]) is None:
            raise DecodeError(f"not a sentence address: {tokens[0]!r}", raw=raw)
        return UnknownSentence(tokens[0], tuple(tokens[1:]))
    try:
        message: NmeaMessage = _decode_tokens(spec, tokens[len(spec.header):])
    except DecodeError as err:
        raise DecodeError(str(err), raw=raw) from err
    return message


# ---------------------------------------------------------------------------------------------
# Messages from physical values, and GPS time back from messages.


def _utc_date_and_time(t_gps_ns: int, leap_s: int) -> tuple[dt.date, int]:
    """UTC date and time of day, rounded to the NMEA clock on the instant so a carry reaches
    the date."""
    t_utc_ns = _round_half_up(t_gps_ns - leap_s * NS_PER_S, UTC_CLOCK.resolution_ns)
    days, time_of_day_ns = divmod(t_utc_ns, NS_PER_DAY)
    return _GPS_EPOCH_DATE + dt.timedelta(days=days), time_of_day_ns


def _time_of_week(t_gps_ns: int) -> int:
    return _round_half_up(t_gps_ns, TIME_TAG.clock.resolution_ns) % NS_PER_WEEK


def gga_from_fix(t_gps_ns: int, leap_s: int, lat_deg: float, lon_deg: float,
                 height_ellipsoidal_m: float, geoid_sep_m: float, quality: FixQuality,
                 sats: int, hdop: float, *, dgps_age_s: float | None = None,
                 dgps_station: int | None = None) -> Gga:
    """GGA of a fix at GPS time `t_gps_ns`; the altitude written is height − geoid separation."""
    _, time_of_day_ns = _utc_date_and_time(t_gps_ns, leap_s)
    return Gga(time_of_day_ns, lat_deg, lon_deg, quality, sats, hdop,
               height_ellipsoidal_m - geoid_sep_m, geoid_sep_m, dgps_age_s, dgps_station)


def rmc_from_fix(t_gps_ns: int, leap_s: int, lat_deg: float, lon_deg: float, speed_m_s: float,
                 course_true_deg: float, mode: ModeIndicator = ModeIndicator.AUTONOMOUS) -> Rmc:
    """RMC of a fix; the status is void exactly when the mode says the fix is not valid."""
    utc_date, time_of_day_ns = _utc_date_and_time(t_gps_ns, leap_s)
    status = RmcStatus.VOID if mode is ModeIndicator.NOT_VALID else RmcStatus.ACTIVE
    return Rmc(time_of_day_ns, status, lat_deg, lon_deg, speed_m_s, course_true_deg, utc_date,
               mode)


def zda_from_gps_ns(t_gps_ns: int, leap_s: int) -> Zda:
    """ZDA of an instant, zone 00:00."""
    utc_date, time_of_day_ns = _utc_date_and_time(t_gps_ns, leap_s)
    return Zda(time_of_day_ns, utc_date)


def ptt_from_gps_ns(t_gps_ns: int) -> PashrPtt:
    """PPS time tag of an instant, rounded to 100 ns (a carry may roll into the next week)."""
    return PashrPtt(_time_of_week(t_gps_ns))


def ttt_from_gps_ns(t_gps_ns: int) -> PashrTtt:
    """Event time tag of an instant, rounded to 100 ns (a carry may roll into the next week)."""
    return PashrTtt(_time_of_week(t_gps_ns))


def _nearest(value_ns: int, period_ns: int, near_ns: int) -> int:
    """The instant ≡ value (mod period) closest to `near_ns`."""
    return near_ns + (value_ns - near_ns + period_ns // 2) % period_ns - period_ns // 2


def gps_ns_from_time_of_week(gps_time_of_week_ns: int, near_gps_ns: int) -> int:
    """GPS ns of a time of week (PTT/TTT), taking the week that puts it nearest `near_gps_ns`
    (e.g. the host clock); right while the host is within half a week."""
    return _nearest(gps_time_of_week_ns, NS_PER_WEEK, near_gps_ns)


def gps_ns_from_utc_time_of_day(utc_time_of_day_ns: int, leap_s: int, near_gps_ns: int) -> int:
    """GPS ns of a UTC time of day (GGA), taking the day that puts it nearest `near_gps_ns`."""
    return _nearest(utc_time_of_day_ns + leap_s * NS_PER_S, NS_PER_DAY, near_gps_ns)


def gps_ns_from_utc(utc_date: dt.date, utc_time_of_day_ns: int, leap_s: int) -> int:
    """GPS ns of a UTC date and time of day (RMC, ZDA)."""
    days = (utc_date - _GPS_EPOCH_DATE).days
    return days * NS_PER_DAY + utc_time_of_day_ns + leap_s * NS_PER_S


# ---------------------------------------------------------------------------------------------
# Streaming decoder.


class NmeaStreamDecoder:
    """Sentences from a byte stream cut anywhere: resynchronises on `$`, never holds more than
    one sentence's worth of bytes, and counts what it drops (exactly once per bad stretch).

    A run of bytes outside sentences is one framing error (CR/LF alone are tolerated); so is a
    sentence cut short by a new `$`, one with no line end within MAX_SENTENCE_BYTES, and one that
    does not decode. Every byte fed ends up in a Decoded's raw, in `stats.bytes_skipped`, or
    still buffered.
    """

    def __init__(self, policy: ErrorPolicy = ErrorPolicy.COUNT) -> None:
        self.policy = policy
        self.stats = DecodeStats()
        self._buffer = bytearray()
        self._pos = 0  # next unread byte of _buffer
        self._base = 0  # stream offset of _buffer[0]
        self._in_bad_run = False  # the bytes being skipped were already counted as an error

    @property
    def buffered_bytes(self) -> int:
        return len(self._buffer) - self._pos

    def feed(self, data: bytes) -> list[Decoded[NmeaMessage]]:
        """Decoded sentences completed by `data`. Under RAISE, raises DecodeError (offset = stream
        offset of the bad bytes) after dropping them, so feeding may go on."""
        self._buffer += data
        out: list[Decoded[NmeaMessage]] = []
        try:
            while self._step(out):
                pass
        finally:
            self._compact()
        return out

    def finish(self) -> None:
        """End of stream: an unfinished sentence still buffered is a truncation error."""
        if self.buffered_bytes:
            self._reject(self.buffered_bytes, "stream ended inside a sentence")
            self._compact()

    def _step(self, out: list[Decoded[NmeaMessage]]) -> bool:
        if self._pos >= len(self._buffer):
            return False
        if self._buffer[self._pos] != SENTENCE_START:
            self._skip_to_start()
            return True
        self._in_bad_run = False  # a '$' ends any run of bad bytes
        return self._take_sentence(out)

    def _skip_to_start(self) -> None:
        start = self._buffer.find(SENTENCE_START, self._pos)
        end = len(self._buffer) if start < 0 else start
        junk = bytes(self._buffer[self._pos:end])
        offset = self._base + self._pos
        self._pos = end
        self.stats.bytes_skipped += len(junk)
        has_junk = bool(junk.strip(_LINE_BREAK_BYTES))  # CR/LF alone are tolerated
        already_counted = self._in_bad_run
        self._in_bad_run = already_counted or has_junk
        if has_junk and not already_counted:
            self._error(ErrorKind.FRAMING, "bytes outside a sentence", offset, junk)

    def _take_sentence(self, out: list[Decoded[NmeaMessage]]) -> bool:
        window_end = min(len(self._buffer), self._pos + MAX_SENTENCE_BYTES)
        line_end = self._buffer.find(LINE_FEED, self._pos, window_end)
        restart = self._buffer.find(SENTENCE_START, self._pos + 1, window_end)
        if restart >= 0 and (line_end < 0 or restart < line_end):
            self._reject(restart - self._pos, "sentence cut short by a new '$'")
        elif line_end >= 0:
            self._accept(line_end + 1 - self._pos, out)
        elif window_end - self._pos >= MAX_SENTENCE_BYTES:
            self._in_bad_run = True  # the rest of the line up to the next '$' is this error
            self._reject(MAX_SENTENCE_BYTES, f"no line end within {MAX_SENTENCE_BYTES} bytes")
        else:
            return False  # wait for more bytes
        return True

    def _accept(self, length: int, out: list[Decoded[NmeaMessage]]) -> None:
        offset = self._base + self._pos
        raw = bytes(self._buffer[self._pos:self._pos + length])
        self._pos += length
        try:
            message = decode_sentence(raw)
        except DecodeError as err:
            self.stats.bytes_skipped += length
            kind = ErrorKind.CHECKSUM if isinstance(err, ChecksumError) else ErrorKind.FRAMING
            self._error(kind, str(err), offset, raw)
            return
        self.stats.count_message(message_kind(message).value)
        out.append(Decoded(raw, message))

    def _reject(self, length: int, reason: str) -> None:
        offset = self._base + self._pos
        raw = bytes(self._buffer[self._pos:self._pos + length])
        self._pos += length
        self.stats.bytes_skipped += length
        self._error(ErrorKind.FRAMING, reason, offset, raw)

    def _error(self, kind: ErrorKind, reason: str, offset: int, raw: bytes) -> None:
        report_error(self.policy, self.stats, kind.value, f"NMEA: {reason}", offset, raw)

    def _compact(self) -> None:
        del self._buffer[:self._pos]
        self._base += self._pos
        self._pos = 0
