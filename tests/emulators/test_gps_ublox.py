"""The GPS receiver emulator with `gps.receiver = "ublox_f9p"`: NMEA 4.1 from talker GN and UBX
frames on one port, read by pyubx2 (NMEA and UBX alike) as our decoder reads them; a TIM-TP
before every pulse and a TIM-TM2 for every accepted event; the default profile unchanged."""

from __future__ import annotations

import io

import numpy as np
from pyubx2 import NMEA_PROTOCOL, UBX_PROTOCOL, UBXReader

from acquisition.codec import ErrorPolicy
from acquisition.nmea import Gga, NavStatus, Rmc, Zda
from acquisition.ubx import NmeaUbxStreamDecoder, TimTm2, TimTp
from emulators.scenario import scenario_from_table
from sisa.core.timescale import NS_PER_S
from tests.emulators.test_gps import _run

UBLOX = {"gps": {"receiver": "ublox_f9p"}}


def _events(scn_table: dict[str, object]) -> tuple[list[int], list[int]]:
    scn0 = scenario_from_table({"base": "bench", **scn_table})
    t0 = scn0.block.t_start_gps_ns + 5 * NS_PER_S
    rng = np.random.default_rng(3)
    good = [t0 + k * 1_100_000_000 + int(rng.integers(0, 10**6)) for k in range(100)]
    return good, [t + 300_000_000 for t in good[::10]]  # inside the dead time


def test_ublox_stream_has_a_tim_tp_before_every_pulse_and_a_tim_tm2_per_event() -> None:
    good, too_soon = _events(UBLOX)
    _, _, gps, stream, edges = _run(UBLOX, sorted(good + too_soon))
    msgs = [d.message for d in NmeaUbxStreamDecoder(ErrorPolicy.RAISE).feed(stream)]
    seconds = gps.pps.column("t_second_gps_ns")
    pulses = [m.pulse_gps_ns for m in msgs if isinstance(m, TimTp)]
    assert pulses == list(seconds + NS_PER_S)  # each announces the next second's pulse
    assert [e.t_ns for e in edges] == list(gps.pps.column("t_edge_gps_ns"))
    marks = [m for m in msgs if isinstance(m, TimTm2)]
    assert len(marks) == len(good)
    err = np.array([m.rising_gps_ns for m in marks]) - np.array(good)
    assert np.all(np.abs(err) <= 50)  # the scenario's 100 ns tag resolution, rounded
    counts = [m.count for m in marks]
    assert counts == sorted(counts)
    assert counts[-1] == len(good) + len(too_soon)
    gga = [m for m in msgs if isinstance(m, Gga)]
    rmc = [m for m in msgs if isinstance(m, Rmc)]
    assert {m.talker for m in (*gga, *rmc)} == {"GN"}
    assert {m.nav_status for m in rmc} == {NavStatus.NOT_VALID}  # NMEA 4.1, as u-blox writes
    assert any(isinstance(m, Zda) for m in msgs)


def test_pyubx2_reads_the_interleaved_stream_as_we_do() -> None:
    good, _ = _events(UBLOX)
    _, _, _, stream, _ = _run(UBLOX, good[:20])
    ours = [d for d in NmeaUbxStreamDecoder(ErrorPolicy.RAISE).feed(stream)]
    reader = UBXReader(io.BytesIO(stream), protfilter=NMEA_PROTOCOL | UBX_PROTOCOL, quitonerror=2)
    theirs = list(reader)
    assert [raw for raw, _ in theirs] == [d.raw for d in ours]
    for (_, parsed), item in zip(theirs, ours, strict=True):
        if isinstance(item.message, TimTm2):
            assert (parsed.wnR, parsed.towMsR, parsed.towSubMsR, parsed.count) == (
                item.message.rising_week, item.message.rising_tow_ms,
                item.message.rising_sub_ms_ns, item.message.count)
        elif isinstance(item.message, TimTp):
            assert (parsed.week, parsed.towMS, parsed.towSubMS) == (
                item.message.week, item.message.tow_ms, 0.0)


def test_the_default_receiver_sends_no_ubx() -> None:
    _, _, _, stream, _ = _run({})
    assert b"\xb5\x62" not in stream
    assert b"$GPGGA," in stream
    assert b"$PASHR,PTT," in stream
