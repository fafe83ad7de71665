"""The GPS week of the receiver's first time tags. A tag ($PASHR,PTT/TTT) carries only the
day of week and time of day: its week was taken from the host clock until the first fix, so a
June 2026 flight replayed (or emulated) in November showed `week 2447` for its first 2 s in the
recorder's status, then `week 2423`, and logged those tags 24 weeks off (issue 33, item 7).
The first tags now wait for the receiver's date (RMC or ZDA, within the second)."""

from __future__ import annotations

import datetime as dt

from acquisition.runner import MAX_UNDATED_TAGS, Acquisition, AcquisitionConfig
from acquisition.syncfilter import SyncFilterConfig
from recorder.messages import GpsTimeTag, LoggedMessage, Topic
from sisa.core.timescale import gps_ns_from_unix_ns, gps_week_and_tow_ns

CONFIG = AcquisitionConfig(leap_s=18, sync=SyncFilterConfig(), ins_rate_hz=64.0,
                           nmea_rate_hz=2.0, line_rate_hz=62.5)
# the receiver's first second, as the emulated Z-12 sends it on 2026-06-15 (GPS week 2423)
FIRST_SECOND = [
    b"$PASHR,PTT,2,09:05:30.0000000*07\r\n",
    b"$GPGGA,090512.00,4134.6724974,N,00200.1648400,E,4,09,0.9,851.596,M,50.000,M,,*67\r\n"
    b"$GPRMC,090512.00,A,4134.6724974,N,00200.1648400,E,117.419,334.68,150626,,,R*77\r\n",
    b"$GPZDA,090512.00,15,06,2026,00,00*6D\r\n",
    b"$PASHR,PTT,2,09:05:31.0000000*06\r\n",
]
NOVEMBER_NS = int(dt.datetime(2026, 11, 30, 9, 5, 12, tzinfo=dt.UTC).timestamp() * 1e9)
HOST_WEEK = 2447


def _acquisition() -> tuple[Acquisition, list[LoggedMessage]]:
    logged: list[LoggedMessage] = []

    def log(msg: LoggedMessage, _topic: Topic | None) -> None:
        logged.append(msg)

    return Acquisition(CONFIG, log, lambda _edge: None), logged


def _week(t_gps_ns: int) -> int:
    return gps_week_and_tow_ns(t_gps_ns)[0]


def test_the_first_tags_take_their_week_from_the_receivers_date_not_the_host_clock() -> None:
    acq, logged = _acquisition()
    assert _week(gps_ns_from_unix_ns(NOVEMBER_NS, 18)) == HOST_WEEK != 2423
    seen = []
    for k, data in enumerate(FIRST_SECOND):
        acq.on_gps_bytes(NOVEMBER_NS + k * 100_000_000, data)
        if acq.last_pps_gps_ns is not None:
            seen.append(_week(acq.last_pps_gps_ns))
    tags = [m for m in logged if isinstance(m, GpsTimeTag)]
    assert [_week(t.t_gps_ns) for t in tags] == [2423, 2423]
    assert seen
    assert set(seen) == {2423}
    assert [t.t_host_ns for t in tags] == [NOVEMBER_NS, NOVEMBER_NS + 300_000_000]


def test_a_receiver_that_never_says_its_date_still_has_its_tags_logged() -> None:
    """No RMC or ZDA (a receiver configured without them): after a few tags, the host clock's
    week, as before; none is lost."""
    acq, logged = _acquisition()
    for k in range(MAX_UNDATED_TAGS + 2):
        acq.on_gps_bytes(NOVEMBER_NS + k * 1_000_000_000, FIRST_SECOND[0])
    acq.finish(NOVEMBER_NS + 10**10)
    tags = [m for m in logged if isinstance(m, GpsTimeTag)]
    assert len(tags) == MAX_UNDATED_TAGS + 2
    assert {_week(t.t_gps_ns) for t in tags} == {HOST_WEEK}
