"""Messages from physical values, and GPS time back from messages."""

from __future__ import annotations

import datetime as dt

from acquisition.nmea.sentences import (
    TIME_TAG,
    UTC_CLOCK,
    FixQuality,
    Gga,
    ModeIndicator,
    PashrPtt,
    PashrTtt,
    Rmc,
    RmcStatus,
    Zda,
)
from acquisition.nmea.wire import GPS_EPOCH_DATE, round_half_up
from sisa.core.timescale import NS_PER_DAY, NS_PER_S, NS_PER_WEEK

# ---------------------------------------------------------------------------------------------
# Messages from physical values, and GPS time back from messages.


def _utc_date_and_time(t_gps_ns: int, leap_s: int) -> tuple[dt.date, int]:
    """UTC date and time of day, rounded to the NMEA clock on the instant so a carry reaches
    the date."""
    t_utc_ns = round_half_up(t_gps_ns - leap_s * NS_PER_S, UTC_CLOCK.resolution_ns)
    days, time_of_day_ns = divmod(t_utc_ns, NS_PER_DAY)
    return GPS_EPOCH_DATE + dt.timedelta(days=days), time_of_day_ns


def _time_of_week(t_gps_ns: int) -> int:
    return round_half_up(t_gps_ns, TIME_TAG.clock.resolution_ns) % NS_PER_WEEK


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
               mode=mode)


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
    days = (utc_date - GPS_EPOCH_DATE).days
    return days * NS_PER_DAY + utc_time_of_day_ns + leap_s * NS_PER_S

