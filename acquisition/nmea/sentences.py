"""The sentences we speak, each declared once as a table: NMEA 0183 GGA, RMC, ZDA and the Ashtech
`$PASHR,PTT` / `$PASHR,TTT` time tags."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from enum import IntEnum, StrEnum
from typing import Any

from acquisition.nmea.tables import Constant, Field, SentenceKind, SentenceSpec, Unit
from acquisition.nmea.wire import (
    FIRST_DAY_OF_WEEK,
    KNOTS_PER_M_S,
    Blankable,
    ClockStyle,
    DateDayMonthYear,
    DateDdMmYy,
    DayAndTimeOfWeek,
    DegreesMinutes,
    EnumToken,
    FixedPoint,
    Hemisphere,
    Integer,
    TimeOfDay,
)
from sisa.timescale import NS_PER_DAY


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

