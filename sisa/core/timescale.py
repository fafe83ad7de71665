"""GPS time as int64 nanoseconds since 1980-01-06T00:00:00 (GPS epoch), and the few conversions
the protocols need.

GPS time has no leap seconds. UTC = GPS − leap_s; the leap-second count is a scenario setting
(12 s in mid-1998, 18 s since 2017), never looked up from the host.
"""

from __future__ import annotations

import datetime as dt
import re

import numpy as np
import numpy.typing as npt

NS_PER_S = 1_000_000_000
NS_PER_DAY = 86_400 * NS_PER_S
NS_PER_WEEK = 7 * NS_PER_DAY
GPS_EPOCH = dt.datetime(1980, 1, 6, tzinfo=dt.UTC)
UNIX_NS_AT_GPS_EPOCH = 315_964_800 * NS_PER_S  # host clocks count from 1970 (UTC, with leaps)
_GPS_EPOCH_NAIVE = GPS_EPOCH.replace(tzinfo=None)


def gps_ns_from_datetime(when: dt.datetime) -> int:
    """GPS ns of a calendar instant already on the GPS scale (naive or tz-aware, no leap)."""
    naive = when.astimezone(dt.UTC).replace(tzinfo=None) if when.tzinfo else when
    delta = naive - _GPS_EPOCH_NAIVE
    return (delta.days * 86_400 + delta.seconds) * NS_PER_S + delta.microseconds * 1_000


def datetime_from_gps_ns(t_gps_ns: int) -> dt.datetime:
    """Calendar instant on the GPS scale (naive; microsecond precision)."""
    return _GPS_EPOCH_NAIVE + dt.timedelta(microseconds=t_gps_ns // 1_000)


def utc_datetime_from_gps_ns(t_gps_ns: int, leap_s: int) -> dt.datetime:
    """UTC calendar instant (naive; microsecond precision) of a GPS instant."""
    return datetime_from_gps_ns(t_gps_ns - leap_s * NS_PER_S)


def gps_week_and_tow_ns(t_gps_ns: int) -> tuple[int, int]:
    """GPS week number and time of week in ns."""
    week, tow_ns = divmod(t_gps_ns, NS_PER_WEEK)
    return int(week), int(tow_ns)


def gps_time_label(t_gps_ns: int) -> str:
    """'2026-06-15 09:05:47 GPS (week 2423, 119 147 s)': as a receiver shows it, to the second
    (GPS time, which runs ahead of UTC by the leap seconds)."""
    week, tow_ns = gps_week_and_tow_ns(t_gps_ns)
    when = datetime_from_gps_ns(t_gps_ns).strftime("%Y-%m-%d %H:%M:%S")
    return f"{when} GPS (week {week}, {tow_ns // NS_PER_S:_} s)".replace("_", " ")


def gps_span_label(t0_ns: int, t1_ns: int) -> str:
    """'2026-06-15T09:00:00 to 09:05:10 GPS (week 2423, 118800.0 to 119110.0 s)' (ASCII, as
    every message)."""
    a = datetime_from_gps_ns(t0_ns).isoformat(timespec="seconds")
    b = datetime_from_gps_ns(t1_ns).isoformat(timespec="seconds")
    (w0, s0), (w1, s1) = gps_week_and_tow_ns(t0_ns), gps_week_and_tow_ns(t1_ns)
    when = f"{a} to {b[11:]}" if a[:10] == b[:10] else f"{a} to {b}"
    week = (f"week {w0}, {s0 / NS_PER_S:.1f} to {s1 / NS_PER_S:.1f} s" if w0 == w1 else
            f"week {w0} {s0 / NS_PER_S:.1f} s to week {w1} {s1 / NS_PER_S:.1f} s")
    return f"{when} GPS ({week})"


def day_of_week(t_ns: int) -> int:
    """Ashtech day of week, 1..7 with Sunday = 1 (the GPS epoch was a Sunday)."""
    return int((t_ns % NS_PER_WEEK) // NS_PER_DAY) + 1


def parse_gps_datetime(text: str) -> int:
    """GPS ns from an ISO-8601 string read on the GPS scale (e.g. '1998-07-23T08:00:00')."""
    if not re.fullmatch(r"\d{4}-\d{2}-\d{2}[T ]\d{2}:\d{2}(:\d{2}(\.\d+)?)?", text.strip()):
        raise ValueError(f"not an ISO date-time 'YYYY-MM-DDThh:mm:ss': {text!r}")
    return gps_ns_from_datetime(dt.datetime.fromisoformat(text.strip()))


def seconds_since(t_ns: npt.ArrayLike, epoch_ns: int) -> npt.NDArray[np.float64]:
    """Float seconds relative to a local epoch: the only float time numerical code may use."""
    return (np.asarray(t_ns, dtype=np.int64) - np.int64(epoch_ns)).astype(np.float64) / NS_PER_S


def ns_from_seconds_since(t_s: npt.ArrayLike, epoch_ns: int) -> npt.NDArray[np.int64]:
    """Inverse of `seconds_since`, rounded to the nearest ns."""
    return np.int64(epoch_ns) + np.rint(np.asarray(t_s, dtype=np.float64) * NS_PER_S).astype(
        np.int64
    )


def unix_ns_from_gps_ns(t_gps_ns: int, leap_s: int) -> int:
    """A host (Unix, UTC) clock reading of a GPS instant."""
    return t_gps_ns - leap_s * NS_PER_S + UNIX_NS_AT_GPS_EPOCH


def gps_ns_from_unix_ns(t_unix_ns: int, leap_s: int) -> int:
    """The GPS instant of a host (Unix, UTC) clock reading."""
    return t_unix_ns - UNIX_NS_AT_GPS_EPOCH + leap_s * NS_PER_S
