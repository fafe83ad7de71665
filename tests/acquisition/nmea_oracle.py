"""pynmeagps as the independent decoder of NMEA sentences: what it reads from the same bytes,
compared field by field with what acquisition.nmea decoded.

Agreement means: the same talker; times equal to the microsecond (pynmeagps's resolution);
latitude and longitude within 1 mm on the ground; heights, separations and σ within 1 mm;
every other value equal; a field null on one side exactly where it is null on the other.
"""

from __future__ import annotations

import datetime as dt
import math
from typing import Any

from pynmeagps import VALCKSUM, NMEAReader

from acquisition.nmea import Gga, Gns, Gst, NmeaMessage, Rmc, Zda
from acquisition.nmea.wire import KNOTS_PER_M_S

M_PER_DEG = 111_320.0  # a degree of latitude, and of longitude on the equator, to < 1 %
MM = 1e-3
NS_PER_US = 1_000


def pynmeagps_read(raw: bytes, *, check_checksum: bool = True) -> Any:
    """pynmeagps's message of one sentence (raises its own errors)."""
    return NMEAReader.parse(raw, validate=VALCKSUM if check_checksum else 0)


def _blank(value: Any) -> bool:
    return value == "" or value is None


def _time(ns: int | None, theirs: Any) -> str | None:
    if ns is None or _blank(theirs):
        return None if (ns is None) == _blank(theirs) else f"time {ns} / {theirs!r}"
    if ns % NS_PER_US:
        return f"time {ns} ns has sub-µs digits pynmeagps cannot hold"
    clock = (dt.datetime.min + dt.timedelta(microseconds=ns // NS_PER_US)).time()
    return None if clock == theirs else f"time {clock} / {theirs}"


def _number(name: str, ours: float | None, theirs: Any, tolerance: float) -> str | None:
    if ours is None or _blank(theirs):
        return None if (ours is None) == _blank(theirs) else f"{name} {ours!r} / {theirs!r}"
    ok = abs(float(theirs) - ours) <= tolerance * (1 + 1e-9)
    return None if ok else f"{name} {ours!r} / {theirs!r}"


def _equal(name: str, ours: Any, theirs: Any) -> str | None:
    if ours is None or _blank(theirs):
        return None if (ours is None) == _blank(theirs) else f"{name} {ours!r} / {theirs!r}"
    ours = getattr(ours, "value", ours)
    return None if ours == theirs else f"{name} {ours!r} / {theirs!r}"


def _signed(magnitude: Any, letter: Any, negative: str) -> float | str:
    """pynmeagps's unsigned value and its letter as one signed number ("" when null)."""
    if _blank(magnitude):
        return ""
    return -float(magnitude) if letter == negative else float(magnitude)


def _position(ours: Gga | Rmc | Gns, theirs: Any) -> list[str | None]:
    lat = ours.lat_deg if ours.lat_deg is not None else 0.0
    lon_tol = MM / (M_PER_DEG * max(math.cos(math.radians(lat)), 1e-6))
    return [_number("lat", ours.lat_deg, theirs.lat, MM / M_PER_DEG),  # pynmeagps signs them
            _number("lon", ours.lon_deg, theirs.lon, lon_tol)]


def _fix(ours: Gga | Gns, theirs: Any) -> list[str | None]:
    return [*_position(ours, theirs),
            _equal("satellites", ours.satellites, theirs.numSV),
            _number("hdop", ours.hdop, theirs.HDOP, 0.0),
            _number("altitude", ours.altitude_msl_m, theirs.alt, MM),
            _number("separation", ours.geoid_separation_m, theirs.sep, MM),
            _number("dgps age", ours.dgps_age_s, theirs.diffAge, 0.0),
            _equal("dgps station", ours.dgps_station, theirs.diffStation)]


def _differences(ours: NmeaMessage, theirs: Any) -> list[str | None]:
    if isinstance(ours, Gga):
        return [*_fix(ours, theirs), _equal("quality", ours.quality, theirs.quality)]
    if isinstance(ours, Gns):
        modes = None if ours.modes is None else "".join(m.value for m in ours.modes)
        return [*_fix(ours, theirs), _equal("modes", modes, theirs.posMode),
                _equal("nav status", ours.nav_status, getattr(theirs, "navStatus", ""))]
    if isinstance(ours, Rmc):
        speed_kn = None if ours.speed_m_s is None else ours.speed_m_s * KNOTS_PER_M_S
        return [*_position(ours, theirs), _equal("status", ours.status, theirs.status),
                _number("speed", speed_kn, theirs.spd, 1e-6),
                _number("course", ours.course_true_deg, theirs.cog, 0.0),
                _equal("date", ours.utc_date, theirs.date),
                _number("variation", ours.magnetic_variation_deg,
                        _signed(theirs.mv, theirs.mvEW, "W"), 0.0),
                _equal("mode", ours.mode, getattr(theirs, "posMode", "")),
                _equal("nav status", ours.nav_status, getattr(theirs, "navStatus", ""))]
    if isinstance(ours, Zda):
        date = None if ours.utc_date is None else (
            ours.utc_date.day, ours.utc_date.month, ours.utc_date.year)
        theirs_date = "" if _blank(theirs.year) else (theirs.day, theirs.month, theirs.year)
        return [_equal("date", date, theirs_date),
                _equal("zone hours", ours.zone_hours,
                       "" if _blank(theirs.ltzh) else int(theirs.ltzh)),
                _equal("zone minutes", ours.zone_minutes,
                       "" if _blank(theirs.ltzn) else int(theirs.ltzn))]
    if isinstance(ours, Gst):
        return [_number(name, getattr(ours, attr), getattr(theirs, key), MM)
                for name, attr, key in (
                    ("rms", "range_rms_m", "rangeRms"), ("major", "sigma_major_m", "stdMajor"),
                    ("minor", "sigma_minor_m", "stdMinor"), ("lat σ", "sigma_lat_m", "stdLat"),
                    ("lon σ", "sigma_lon_m", "stdLong"), ("alt σ", "sigma_alt_m", "stdAlt"))] + [
            _number("orientation", ours.major_orientation_deg, theirs.orient, 0.0)]
    return [f"no comparison for {type(ours).__name__}"]


def disagreements(ours: NmeaMessage, theirs: Any) -> list[str]:
    """Where our message and pynmeagps's differ ([] when they agree)."""
    found: list[str | None] = [_equal("talker", getattr(ours, "talker", None), theirs.talker),
                               _equal("formatter", type(ours).__name__.upper(), theirs.msgID)]
    time_ns = getattr(ours, "utc_time_of_day_ns", None)
    found.append(_time(time_ns, theirs.time))
    found += _differences(ours, theirs)
    return [d for d in found if d is not None]
