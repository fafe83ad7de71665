import datetime as dt

import numpy as np
import pytest

from sisa.core import timescale as ts


def test_gps_epoch_is_zero_and_a_sunday():
    assert ts.gps_ns_from_datetime(dt.datetime(1980, 1, 6)) == 0
    assert ts.day_of_week(0) == 1


def test_known_instant_week_and_day():
    # 1998-07-23 was a Thursday, GPS week 967 (hand-worked: 6773 days / 7 = 967 rem 4)
    t = ts.parse_gps_datetime("1998-07-23T08:30:00")
    week, tow_ns = ts.gps_week_and_tow_ns(t)
    assert week == 967
    assert tow_ns == (4 * 86400 + 8 * 3600 + 30 * 60) * ts.NS_PER_S
    assert ts.day_of_week(t) == 5


def test_utc_is_gps_minus_leap_seconds():
    t = ts.parse_gps_datetime("1998-07-23T00:00:05")
    assert ts.utc_datetime_from_gps_ns(t, 12) == dt.datetime(1998, 7, 22, 23, 59, 53)


def test_local_seconds_keep_nanoseconds_that_seconds_since_1980_lose():
    epoch = ts.parse_gps_datetime("2026-06-15T09:00:00")
    t = epoch + np.array([0, 1, 3_600_000_000_123], dtype=np.int64)
    back = ts.ns_from_seconds_since(ts.seconds_since(t, epoch), epoch)
    np.testing.assert_array_equal(back, t)
    # the same round trip through float seconds since 1980 is off by far more than 1 ns
    assert abs(int(np.rint(float(t[2]) / 1e9 * 1e9)) - int(t[2])) > 1


@pytest.mark.parametrize("bad", ["1998-13-01T00:00:00", "yesterday", "1998-07-23"])
def test_bad_datetime_rejected(bad):
    with pytest.raises(ValueError):  # noqa: PT011
        ts.parse_gps_datetime(bad)


def test_host_unix_clock_and_gps_time():
    t = ts.parse_gps_datetime("2026-06-15T09:00:18")
    unix = ts.unix_ns_from_gps_ns(t, 18)
    expected = dt.datetime(2026, 6, 15, 9, 0, 0, tzinfo=dt.UTC).timestamp() * 1e9
    assert unix == int(expected)
    assert ts.gps_ns_from_unix_ns(unix, 18) == t


def test_gps_time_label_is_calendar_week_and_seconds_of_week():
    t = ts.gps_ns_from_datetime(dt.datetime(2026, 6, 15, 9, 5, 47)) + 999_999_999
    assert ts.gps_time_label(t) == "2026-06-15 09:05:47 GPS (week 2423, 119 147 s)"
    assert ts.gps_time_label(0) == "1980-01-06 00:00:00 GPS (week 0, 0 s)"
