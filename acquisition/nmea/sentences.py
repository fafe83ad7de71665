"""The sentences we speak, each declared once as a table: NMEA 0183 GGA, RMC, ZDA, GNS and GST
from any talker, and the Ashtech `$PASHR,PTT` / `$PASHR,TTT` time tags.

Every field that a receiver may leave null decodes to None ("absent"); a sentence from an older
NMEA version decodes with its newer fields None. The emulated receiver (Ashtech Z-12 profile)
fills every field it has and writes NMEA 2.3 (RMC with its mode indicator).
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from enum import IntEnum, StrEnum
from typing import Any

from acquisition.nmea.tables import Field, NmeaVersion, SentenceKind, SentenceSpec, Unit
from acquisition.nmea.wire import (
    FIRST_DAY_OF_WEEK,
    KNOTS_PER_M_S,
    Blankable,
    ClockStyle,
    DateDayMonthYear,
    DateDdMmYy,
    DayAndTimeOfWeek,
    DegreesMinutes,
    EnumString,
    EnumToken,
    FixedPoint,
    Hemisphere,
    Integer,
    Signed,
    SignOrNull,
    TimeOfDay,
    WithUnit,
)
from sisa.core.timescale import NS_PER_DAY


class Talker(StrEnum):
    """Talker ids of satellite receivers (any other two letters are read as well)."""

    GPS = "GP"
    GLONASS = "GL"
    GALILEO = "GA"
    BEIDOU = "GB"  # NMEA 4.11; BD before it
    BEIDOU_OLD = "BD"
    QZSS = "GQ"
    NAVIC = "GI"
    MULTI = "GN"  # a solution from several constellations


class ProprietaryAddress(StrEnum):
    """Address of the proprietary sentences we speak (`P` + manufacturer + sentence)."""

    PASHR = "PASHR"


class AshtechId(StrEnum):
    """Second header field of the Ashtech proprietary sentences."""

    PTT = "PTT"  # GPS time of the PPS
    TTT = "TTT"  # GPS time of a pulse on the event input


UNIT_METRES = "M"


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
    """Mode indicator of RMC (NMEA 2.3) and GNS (P, R, F from 4.x)."""

    AUTONOMOUS = "A"
    DIFFERENTIAL = "D"
    ESTIMATED = "E"
    MANUAL = "M"
    SIMULATOR = "S"
    NOT_VALID = "N"
    PRECISE = "P"
    RTK_FIXED = "R"
    RTK_FLOAT = "F"


class NavStatus(StrEnum):
    """Navigational status of RMC and GNS (NMEA 4.1): the integrity the receiver claims."""

    SAFE = "S"
    CAUTION = "C"
    UNSAFE = "U"
    NOT_VALID = "V"


# ---------------------------------------------------------------------------------------------
# Messages and their tables.

UTC_CLOCK = TimeOfDay(decimals=2)  # hhmmss.ss: 10 ms
TIME_TAG = DayAndTimeOfWeek(TimeOfDay(decimals=7, style=ClockStyle.COLON))  # 100 ns
LATITUDE = DegreesMinutes(2, 90, Hemisphere.NORTH, Hemisphere.SOUTH, decimals=7)
LONGITUDE = DegreesMinutes(3, 180, Hemisphere.EAST, Hemisphere.WEST, decimals=7)
SATELLITES = Integer(2, 0, 99)
DOP = FixedPoint(decimals=1, maximum=99.9, signed=False)
ALTITUDE = FixedPoint(decimals=3, maximum=99_999.999)
GEOID_SEPARATION = FixedPoint(decimals=3, maximum=999.999)
DGPS_AGE = FixedPoint(decimals=1, maximum=999.9, signed=False)
DGPS_STATION = Integer(4, 0, 1023)
SIGMA = FixedPoint(decimals=3, maximum=99_999.999, signed=False)
ANGLE = FixedPoint(decimals=2, maximum=359.99, signed=False, modulus=360.0)


def _blank_time() -> Field:
    return Field("utc_time_of_day_ns", Blankable(UTC_CLOCK), Unit.NANOSECOND)


@dataclass(frozen=True)
class Gga:
    """Fix data. Altitude is above the geoid: altitude = ellipsoidal height − geoid separation
    (gpsd recovers altHAE = altMSL + separation). A field the receiver left null is None (no
    fix: position, often the time too)."""

    utc_time_of_day_ns: int | None
    lat_deg: float | None
    lon_deg: float | None
    quality: FixQuality | None
    satellites: int | None
    hdop: float | None
    altitude_msl_m: float | None
    geoid_separation_m: float | None
    dgps_age_s: float | None = None
    dgps_station: int | None = None
    talker: str = Talker.GPS.value

    @property
    def height_ellipsoidal_m(self) -> float | None:
        if self.altitude_msl_m is None or self.geoid_separation_m is None:
            return None
        return self.altitude_msl_m + self.geoid_separation_m


GGA_SPEC = SentenceSpec(SentenceKind.GGA, (SentenceKind.GGA.value,), Gga, (
    _blank_time(),
    Field("lat_deg", Blankable(LATITUDE), Unit.DEGREE),
    Field("lon_deg", Blankable(LONGITUDE), Unit.DEGREE),
    Field("quality", Blankable(EnumToken(FixQuality))),
    Field("satellites", Blankable(SATELLITES), Unit.COUNT),
    Field("hdop", Blankable(DOP)),
    Field("altitude_msl_m", Blankable(WithUnit(ALTITUDE, UNIT_METRES)), Unit.METRE),
    Field("geoid_separation_m", Blankable(WithUnit(GEOID_SEPARATION, UNIT_METRES)), Unit.METRE),
    Field("dgps_age_s", Blankable(DGPS_AGE), Unit.SECOND),
    Field("dgps_station", Blankable(DGPS_STATION)),
))


@dataclass(frozen=True)
class Rmc:
    """Recommended minimum data: UTC date and time, position, speed over ground, true course,
    magnetic variation (east positive); the mode indicator from NMEA 2.3, the navigational
    status from 4.1."""

    utc_time_of_day_ns: int | None
    status: RmcStatus | None
    lat_deg: float | None
    lon_deg: float | None
    speed_m_s: float | None
    course_true_deg: float | None
    utc_date: dt.date | None
    magnetic_variation_deg: float | None = None
    mode: ModeIndicator | None = None
    nav_status: NavStatus | None = None
    talker: str = Talker.GPS.value


RMC_SPEC = SentenceSpec(SentenceKind.RMC, (SentenceKind.RMC.value,), Rmc, (
    _blank_time(),
    Field("status", Blankable(EnumToken(RmcStatus))),
    Field("lat_deg", Blankable(LATITUDE), Unit.DEGREE),
    Field("lon_deg", Blankable(LONGITUDE), Unit.DEGREE),
    Field("speed_m_s", Blankable(FixedPoint(decimals=3, maximum=9999.999, scale=KNOTS_PER_M_S,
                                            signed=False)), Unit.METRE_PER_SECOND),
    Field("course_true_deg", Blankable(ANGLE), Unit.DEGREE),
    Field("utc_date", Blankable(DateDdMmYy())),
    Field("magnetic_variation_deg",
          SignOrNull(Signed(FixedPoint(decimals=1, maximum=180.0, signed=False),
                            Hemisphere.EAST, Hemisphere.WEST)), Unit.DEGREE),
    Field("mode", Blankable(EnumToken(ModeIndicator)), since=NmeaVersion.V2_3),
    Field("nav_status", Blankable(EnumToken(NavStatus)), since=NmeaVersion.V4_1),
))


@dataclass(frozen=True)
class Zda:
    """UTC date and time, and the local time zone (hours, minutes) the receiver was told."""

    utc_time_of_day_ns: int | None
    utc_date: dt.date | None
    zone_hours: int | None = 0
    zone_minutes: int | None = 0
    talker: str = Talker.GPS.value


ZDA_SPEC = SentenceSpec(SentenceKind.ZDA, (SentenceKind.ZDA.value,), Zda, (
    _blank_time(),
    Field("utc_date", Blankable(DateDayMonthYear())),
    Field("zone_hours", Blankable(Integer(2, -13, 13))),
    Field("zone_minutes", Blankable(Integer(2, 0, 59))),
))


@dataclass(frozen=True)
class Gns:
    """Fix data of a multi-constellation receiver: one mode indicator per constellation (GPS,
    GLONASS, Galileo, BeiDou, QZSS, NavIC, in that order, as many as the receiver tracks),
    altitude above the geoid as in GGA; the navigational status from NMEA 4.1."""

    utc_time_of_day_ns: int | None
    lat_deg: float | None
    lon_deg: float | None
    modes: tuple[ModeIndicator, ...] | None
    satellites: int | None
    hdop: float | None
    altitude_msl_m: float | None
    geoid_separation_m: float | None
    dgps_age_s: float | None = None
    dgps_station: int | None = None
    nav_status: NavStatus | None = None
    talker: str = Talker.MULTI.value

    @property
    def height_ellipsoidal_m(self) -> float | None:
        if self.altitude_msl_m is None or self.geoid_separation_m is None:
            return None
        return self.altitude_msl_m + self.geoid_separation_m

    @property
    def quality(self) -> FixQuality | None:
        """The GGA quality of the best constellation's mode (None if the modes are null)."""
        if self.modes is None:
            return None
        return max((QUALITY_OF_MODE[m] for m in self.modes), key=_QUALITY_RANK.index,
                   default=FixQuality.INVALID)


# the GGA quality a mode indicator stands for, and the qualities from worst to best
QUALITY_OF_MODE: dict[ModeIndicator, FixQuality] = {
    ModeIndicator.NOT_VALID: FixQuality.INVALID, ModeIndicator.SIMULATOR: FixQuality.SIMULATION,
    ModeIndicator.MANUAL: FixQuality.MANUAL, ModeIndicator.ESTIMATED: FixQuality.ESTIMATED,
    ModeIndicator.AUTONOMOUS: FixQuality.GPS, ModeIndicator.PRECISE: FixQuality.PPS,
    ModeIndicator.DIFFERENTIAL: FixQuality.DGPS, ModeIndicator.RTK_FLOAT: FixQuality.RTK_FLOAT,
    ModeIndicator.RTK_FIXED: FixQuality.RTK_FIXED,
}
_QUALITY_RANK = list(QUALITY_OF_MODE.values())


GNS_SPEC = SentenceSpec(SentenceKind.GNS, (SentenceKind.GNS.value,), Gns, (
    _blank_time(),
    Field("lat_deg", Blankable(LATITUDE), Unit.DEGREE),
    Field("lon_deg", Blankable(LONGITUDE), Unit.DEGREE),
    Field("modes", Blankable(EnumString(ModeIndicator))),
    Field("satellites", Blankable(SATELLITES), Unit.COUNT),
    Field("hdop", Blankable(DOP)),
    Field("altitude_msl_m", Blankable(ALTITUDE), Unit.METRE),
    Field("geoid_separation_m", Blankable(GEOID_SEPARATION), Unit.METRE),
    Field("dgps_age_s", Blankable(DGPS_AGE), Unit.SECOND),
    Field("dgps_station", Blankable(DGPS_STATION)),
    Field("nav_status", Blankable(EnumToken(NavStatus)), since=NmeaVersion.V4_1),
))


@dataclass(frozen=True)
class Gst:
    """Pseudorange error statistics: RMS of the range residuals, the 1σ error ellipse (semi-
    major and semi-minor axes, the major axis's orientation from true north) and the 1σ errors
    of latitude, longitude and altitude, in metres."""

    utc_time_of_day_ns: int | None
    range_rms_m: float | None
    sigma_major_m: float | None
    sigma_minor_m: float | None
    major_orientation_deg: float | None
    sigma_lat_m: float | None
    sigma_lon_m: float | None
    sigma_alt_m: float | None
    talker: str = Talker.GPS.value


GST_SPEC = SentenceSpec(SentenceKind.GST, (SentenceKind.GST.value,), Gst, (
    _blank_time(),
    Field("range_rms_m", Blankable(SIGMA), Unit.METRE),
    Field("sigma_major_m", Blankable(SIGMA), Unit.METRE),
    Field("sigma_minor_m", Blankable(SIGMA), Unit.METRE),
    Field("major_orientation_deg", Blankable(ANGLE), Unit.DEGREE),
    Field("sigma_lat_m", Blankable(SIGMA), Unit.METRE),
    Field("sigma_lon_m", Blankable(SIGMA), Unit.METRE),
    Field("sigma_alt_m", Blankable(SIGMA), Unit.METRE),
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


def _ashtech(kind: SentenceKind, sub_id: AshtechId, build: type[Any]) -> SentenceSpec[Any]:
    return SentenceSpec(kind, (ProprietaryAddress.PASHR.value, sub_id.value), build, (
        Field("gps_time_of_week_ns", TIME_TAG, Unit.NANOSECOND),
    ), proprietary=True)


PTT_SPEC: SentenceSpec[PashrPtt] = _ashtech(SentenceKind.PTT, AshtechId.PTT, PashrPtt)
TTT_SPEC: SentenceSpec[PashrTtt] = _ashtech(SentenceKind.TTT, AshtechId.TTT, PashrTtt)


@dataclass(frozen=True)
class UnknownSentence:
    """A well-framed sentence we have no table for (another formatter or proprietary
    sentence): kept, counted."""

    address: str
    fields: tuple[str, ...]


KnownMessage = Gga | Rmc | Zda | Gns | Gst | PashrPtt | PashrTtt
NmeaMessage = KnownMessage | UnknownSentence
SPECS: tuple[SentenceSpec[Any], ...] = (GGA_SPEC, RMC_SPEC, ZDA_SPEC, GNS_SPEC, GST_SPEC,
                                        PTT_SPEC, TTT_SPEC)
SPEC_BY_TYPE: dict[Any, SentenceSpec[Any]] = {spec.build: spec for spec in SPECS}


def message_kind(message: NmeaMessage) -> SentenceKind:
    """The counter name of a message."""
    spec = SPEC_BY_TYPE.get(type(message))
    return SentenceKind.UNKNOWN if spec is None else spec.kind
