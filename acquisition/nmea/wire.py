"""How one message attribute becomes one or more comma-separated NMEA tokens, and back.

Encoders write exactly one form (the resolution the format declares) and refuse what the wire
cannot carry. Decoders read every form NMEA 0183 allows for the field, from version 2.0 to
4.11: any number of decimals (or none), a number without leading digits, and a null (empty)
field wherever a receiver has no value (`Blankable`); qualifier letters that go with a value (a
hemisphere, a unit) may be present or empty when the value itself is null.
"""

from __future__ import annotations

import datetime as dt
import math
import re
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum, StrEnum
from functools import cached_property
from typing import ClassVar, Generic, TypeVar

from sisa.core.errors import DecodeError, EncodeError
from sisa.core.timescale import GPS_EPOCH, NS_PER_DAY, NS_PER_S, NS_PER_WEEK

T = TypeVar("T")
E = TypeVar("E", bound=Enum)

KNOTS_PER_M_S = 3600.0 / 1852.0  # 1 knot = 1852 m/h
MINUTES_PER_DEGREE = 60
SECONDS_PER_MINUTE = 60
MINUTES_PER_HOUR = 60
HOURS_PER_DAY = 24
LEAP_SECOND = 60  # UTC's 23:59:60, the second a leap second inserts
MINUTE_DIGITS = 2  # the "mm" of ddmm.mmmmmmm
NS_DIGITS = 9  # decimals of a second that an int ns holds
FIRST_DAY_OF_WEEK = 1  # Ashtech: Sunday = 1 (the GPS epoch was a Sunday)
DAYS_PER_WEEK = 7
TWO_DIGIT_YEAR_PIVOT = 80  # ddmmyy: yy >= 80 is 19yy, else 20yy (GPS began in 1980)
FIRST_CENTURY, SECOND_CENTURY = 1900, 2000
YEARS_PER_CENTURY = 100
GPS_EPOCH_DATE = GPS_EPOCH.date()


class Hemisphere(StrEnum):
    NORTH = "N"
    SOUTH = "S"
    EAST = "E"
    WEST = "W"


class ClockStyle(StrEnum):
    """How a time of day is written: NMEA `hhmmss.ss` or Ashtech `hh:mm:ss.sssssss`."""

    COMPACT = ""
    COLON = ":"


def round_half_up(value: int, step: int) -> int:
    """Nearest multiple of `step` (ties up): integer-exact, for ns times."""
    return (value + step // 2) // step * step


def _match(pattern: re.Pattern[str], token: str, what: str) -> re.Match[str]:
    found = pattern.fullmatch(token)
    if found is None:
        raise DecodeError(f"{what}: cannot read {token!r}")
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

    def null_qualifiers_ok(self, tokens: Sequence[str]) -> bool:
        """Whether the tokens after a null value are what a receiver writes with it: all
        empty, unless the format says which letters may stay."""
        return not any(tokens)

    @abstractmethod
    def encode(self, value: T) -> tuple[str, ...]: ...

    @abstractmethod
    def decode(self, tokens: Sequence[str]) -> T: ...


# digits with an optional point, or a point and digits ("12", "12.", "12.5", ".5")
_DECIMAL = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)")
_INTEGER = re.compile(r"[+-]?\d+")


def _format_units(units: int, decimals: int) -> str:
    """Signed integer count of LSBs as a decimal string (no '-0.000')."""
    sign = "-" if units < 0 else ""
    whole, frac = divmod(abs(units), 10**decimals)
    return f"{sign}{whole}.{frac:0{decimals}d}" if decimals else f"{sign}{whole}"


@dataclass(frozen=True)
class FixedPoint(WireFormat[float]):
    """A decimal number, written with a fixed count of decimals (read with any);
    wire value = attribute · scale."""

    decimals: int
    maximum: float  # largest |wire value| the field's width allows (for encoding)
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
    """A zero-padded integer (satellites, station id, calendar fields), read with any padding."""

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
            raise DecodeError(f"{value} outside [{self.minimum}, {self.maximum}]")
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
        raise DecodeError(f"{tokens[0]!r} is not a {self.enum.__name__}")


@dataclass(frozen=True)
class EnumString(WireFormat[tuple[E, ...]]):
    """Several one-letter enum members in one token, in a declared order (GNS: one mode
    indicator per constellation, GPS, GLONASS, Galileo, BeiDou, QZSS, NavIC, …)."""

    enum: type[E]

    def encode(self, value: tuple[E, ...]) -> tuple[str, ...]:
        if not value:
            raise EncodeError(f"no {self.enum.__name__} to write")
        return ("".join(str(member.value) for member in value),)

    def decode(self, tokens: Sequence[str]) -> tuple[E, ...]:
        letter = EnumToken(self.enum)
        return tuple(letter.decode((char,)) for char in tokens[0])


@dataclass(frozen=True)
class Blankable(WireFormat[T | None]):
    """A field that a receiver leaves null when it has no value: None on our side."""

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
        if tokens[0] == "":
            if not self.inner.null_qualifiers_ok(tokens[1:]):
                raise DecodeError(f"a null value with {tokens[1:]!r}")
            return None
        return self.inner.decode(tokens)


@dataclass(frozen=True)
class _NumberAndLetter(WireFormat[float]):
    """Two tokens: a fixed-point number, then a letter that qualifies it."""

    number: FixedPoint

    @property
    def width(self) -> int:
        return 2

    @property
    def resolution(self) -> float:
        return self.number.resolution


@dataclass(frozen=True)
class WithUnit(_NumberAndLetter):
    """A number followed by its unit letter (GGA's `545.4,M`); the letter may also be null."""

    unit: str

    def null_qualifiers_ok(self, tokens: Sequence[str]) -> bool:
        return tokens[0] in ("", self.unit)

    def encode(self, value: float) -> tuple[str, ...]:
        return (*self.number.encode(value), self.unit)

    def decode(self, tokens: Sequence[str]) -> float:
        if tokens[1] not in ("", self.unit):
            raise DecodeError(f"unit {tokens[1]!r} is not {self.unit!r}")
        return self.number.decode(tokens[:1])


@dataclass(frozen=True)
class Signed(_NumberAndLetter):
    """An unsigned number and a letter for its sign (RMC's magnetic variation `3.1,W`:
    east positive)."""

    positive: Hemisphere
    negative: Hemisphere

    def null_qualifiers_ok(self, tokens: Sequence[str]) -> bool:
        return tokens[0] in ("", self.positive, self.negative)

    def encode(self, value: float) -> tuple[str, ...]:
        (text,) = self.number.encode(abs(value))
        negative = value < 0 and text.strip("0.") != ""
        return (text, (self.negative if negative else self.positive).value)

    def decode(self, tokens: Sequence[str]) -> float:
        magnitude = self.number.decode(tokens[:1])
        if tokens[1] not in (self.positive, self.negative) or magnitude < 0:
            raise DecodeError(f"{tokens[0]!r},{tokens[1]!r} is not a magnitude and "
                              f"{self.positive}/{self.negative}")
        return -magnitude if tokens[1] == self.negative else magnitude


@dataclass(frozen=True)
class SignOrNull(WireFormat[float | None]):
    """A `Signed` value that may be null, read as null when its letter is neither of its two
    (nor empty), the rest of the sentence kept. Receivers that write RMC's 11 fields of NMEA
    2.0 with 2.3's mode indicator where the magnetic variation's E/W belongs (SiRF III
    `...,181207,0,A`, Saab R4 `...,010611,,A`) lost their whole RMC, date and position with it,
    to a variation nobody uses; gpsd reads them. A number with an empty letter (`3.1,`: which
    sign?) is still refused."""

    inner: Signed

    @property
    def width(self) -> int:
        return self.inner.width

    @property
    def resolution(self) -> float:
        return self.inner.resolution

    def encode(self, value: float | None) -> tuple[str, ...]:
        return Blankable(self.inner).encode(value)

    def decode(self, tokens: Sequence[str]) -> float | None:
        if tokens[1] not in ("", self.inner.positive, self.inner.negative):
            return None
        return Blankable(self.inner).decode(tokens)


@dataclass(frozen=True)
class DegreesMinutes(WireFormat[float]):
    """Signed degrees as `(d)ddmm.mmmmmmm` plus a hemisphere letter (two tokens). Written with
    the standard's leading zeros and `decimals` decimals of minutes; read with any."""

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

    def null_qualifiers_ok(self, tokens: Sequence[str]) -> bool:
        return tokens[0] in ("", self.positive, self.negative)

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
        return re.compile(rf"(\d{{0,{self.degree_digits}}})(\d{{{MINUTE_DIGITS}}}(?:\.\d*)?)")

    def decode(self, tokens: Sequence[str]) -> float:
        found = _match(self._pattern, tokens[0], "degrees-minutes")
        degrees, minutes = int(found.group(1) or "0"), float(found.group(2))
        value = degrees + minutes / MINUTES_PER_DEGREE
        if minutes >= MINUTES_PER_DEGREE or value > self.maximum_deg:
            raise DecodeError(f"angle out of range: {tokens[0]!r}")
        if tokens[1] not in (self.positive, self.negative):
            raise DecodeError(f"hemisphere {tokens[1]!r} is not {self.positive}/{self.negative}")
        return -value if tokens[1] == self.negative else value


def _fraction_ns(digits: str | None) -> int:
    """Decimals of a second as ns, rounded to the nearest ns (ties up) past nine digits."""
    if not digits:
        return 0
    if len(digits) <= NS_DIGITS:
        return int(digits.ljust(NS_DIGITS, "0"))
    step: int = 10 ** (len(digits) - NS_DIGITS)
    return round_half_up(int(digits), step) // step


@dataclass(frozen=True)
class TimeOfDay(WireFormat[int]):
    """Time of day in ns as `hhmmss.ss` (NMEA) or `hh:mm:ss.sssssss` (Ashtech); read with any
    number of decimals. UTC's leap second 23:59:60 reads as 86 400 s and more (the day it
    ends is one second longer)."""

    decimals: int
    style: ClockStyle = ClockStyle.COMPACT

    @property
    def resolution_ns(self) -> int:
        return int(10 ** (NS_DIGITS - self.decimals))

    @property
    def resolution(self) -> float:
        return float(self.resolution_ns)

    def encode(self, value: int) -> tuple[str, ...]:
        rounded = round_half_up(value, self.resolution_ns)
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
        return re.compile(rf"(\d\d){sep}(\d\d){sep}(\d\d)(?:\.(\d*))?")

    def decode(self, tokens: Sequence[str]) -> int:
        *clock, fraction = _match(self._pattern, tokens[0], "time").groups()
        hour, minute, second = (int(part) for part in clock)
        leap = (hour, minute, second) == (HOURS_PER_DAY - 1, MINUTES_PER_HOUR - 1, LEAP_SECOND)
        if (hour >= HOURS_PER_DAY or minute >= MINUTES_PER_HOUR
                or (second >= SECONDS_PER_MINUTE and not leap)):
            raise DecodeError(f"not a time of day: {tokens[0]!r}")
        seconds = (hour * MINUTES_PER_HOUR + minute) * SECONDS_PER_MINUTE + second
        return seconds * NS_PER_S + _fraction_ns(fraction)


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
        rounded = round_half_up(value, self.clock.resolution_ns)
        if not 0 <= value < NS_PER_WEEK or rounded >= NS_PER_WEEK:
            raise EncodeError(
                f"time of week {value} ns is not in [0, 1 week) once rounded; round the "
                "instant first (ptt_from_gps_ns / ttt_from_gps_ns do)"
            )
        day, time_of_day = divmod(rounded, NS_PER_DAY)
        return (*_DAY_OF_WEEK.encode(day + FIRST_DAY_OF_WEEK), *self.clock.encode(time_of_day))

    def decode(self, tokens: Sequence[str]) -> int:
        day = _DAY_OF_WEEK.decode(tokens[:1])
        time_of_day = self.clock.decode(tokens[1:])
        if time_of_day >= NS_PER_DAY:
            raise DecodeError(f"GPS time has no leap second: {tokens[1]!r}")
        return (day - FIRST_DAY_OF_WEEK) * NS_PER_DAY + time_of_day


def _date_or_error(year: int, month: int, day: int) -> dt.date:
    try:
        return dt.date(year, month, day)
    except ValueError as err:
        raise DecodeError(f"not a date: {year}-{month}-{day}") from err


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
