"""The GPS receiver emulator: its statistics, its tags, and real clients (pynmeagps, gpsd)."""

import datetime as dt
import json
import shutil
import socket
import subprocess
import threading

import numpy as np
import pytest
from pynmeagps import NMEAReader

from acquisition.codec import ErrorPolicy
from acquisition.nmea import Gga, NmeaStreamDecoder, PashrPtt, PashrTtt
from acquisition.pulses import Edge, PulseLine
from emulators.faults import fault_table
from emulators.gps import GpsReceiver
from emulators.localplane import LocalPlane
from emulators.ports import PtyPort
from emulators.runtime import Device, Output, Port, Runner
from emulators.scenario import scenario_from_table
from emulators.trajectory import TruthTrajectory
from emulators.truth import read_truth_csv
from sisa.core.frames import body_to_ned_matrix, ned_to_ecef_matrix
from sisa.core.timescale import NS_PER_S, NS_PER_WEEK, utc_datetime_from_gps_ns


class EventSource(Device):
    """Pulses on the GPS event input at the given true times."""

    def __init__(self, times_ns):
        self.times = list(times_ns)

    def next_time_ns(self):
        return self.times[0] if self.times else None

    def emit(self, t_ns):
        self.times.pop(0)
        return [Output(t_ns, Port.PULSES, Edge(PulseLine.GPS_EVENT, 0, t_ns))]


def _run(table, event_times=()):
    scn = scenario_from_table({"base": "bench", **table})
    traj = TruthTrajectory.from_scenario(scn)
    gps = GpsReceiver(scn, traj, np.random.default_rng(7), fault_table())
    serial, edges = [], []

    def sink(out):
        if out.port is Port.GPS_SERIAL:
            serial.append(out.payload)
        elif out.payload.line is PulseLine.GPS_EVENT:
            return [out.payload]  # wire the event source to the receiver's input
        else:
            edges.append(out.payload)
        return []

    Runner([gps, EventSource(event_times)], sink).run()
    return scn, traj, gps, b"".join(serial), edges


def _antenna_truth(scn, traj, t_ns):
    st = traj.state(np.asarray(t_ns, dtype=np.int64))
    r_bn = body_to_ned_matrix(st.roll_rad, st.pitch_rad, st.heading_rad)
    r_ne = ned_to_ecef_matrix(np.radians(st.lat_deg), np.radians(st.lon_deg))
    lever = np.einsum("nij,j->ni", r_bn, np.asarray(scn.mounting.antenna_offset_m))
    ecef = st.ecef_m + np.einsum("nij,nj->ni", r_ne, lever)
    return LocalPlane.for_scenario(scn).ecef_to_geodetic(ecef)


def test_pps_every_second_with_configured_jitter_and_ptt():
    _, _, gps, stream, edges = _run({"gps": {"pps_jitter_ns": 50.0}})
    pps = gps.pps
    seconds = pps.column("t_second_gps_ns")
    assert np.all(np.diff(seconds) == NS_PER_S)
    jitter = pps.column("t_edge_gps_ns") - seconds
    assert 40 < jitter.std() < 60
    assert [e.t_ns for e in edges] == list(pps.column("t_edge_gps_ns"))
    msgs = [d.message for d in NmeaStreamDecoder(ErrorPolicy.RAISE).feed(stream)]
    ptt = [m.gps_time_of_week_ns for m in msgs if isinstance(m, PashrPtt)]
    assert len(ptt) == len(seconds)
    assert np.all(np.abs(np.array(ptt) - pps.column("t_edge_gps_ns") % NS_PER_WEEK) <= 50)


def test_ttt_tags_equal_true_event_time_within_100ns_and_rate_is_enforced():
    scn0 = scenario_from_table({"base": "bench"})
    t0 = scn0.block.t_start_gps_ns + 5 * NS_PER_S
    rng = np.random.default_rng(3)
    good = [t0 + k * 1_100_000_000 + int(rng.integers(0, 10**6)) for k in range(200)]
    too_soon = [t + 300_000_000 for t in good[::10]]  # inside the 1 s dead time
    _, _, gps, stream, _ = _run({}, sorted(good + too_soon))
    msgs = [d.message for d in NmeaStreamDecoder(ErrorPolicy.RAISE).feed(stream)]
    ttt = np.array([m.gps_time_of_week_ns for m in msgs if isinstance(m, PashrTtt)])
    assert len(ttt) == len(good)
    err = ttt - np.array(good) % NS_PER_WEEK
    assert np.all(np.abs(err) <= 50)  # 100 ns resolution, rounded to nearest
    rejected = gps.events.column("accepted") == 0
    assert rejected.sum() == len(too_soon)


def test_positions_are_the_antenna_with_configured_noise():
    scn, traj, gps, stream, _ = _run({"gps": {"solution": "code"}})
    msgs = [d.message for d in NmeaStreamDecoder(ErrorPolicy.RAISE).feed(stream)]
    fixes = [m for m in msgs if isinstance(m, Gga)]
    epochs = gps.fixes.column("t_gps_ns")[: len(fixes)]
    lat, _, h = _antenna_truth(scn, traj, epochs)
    lat_e = np.array([f.lat_deg for f in fixes])
    north_err = np.radians(lat_e - lat) * 6.37e6
    recorded = gps.fixes.column("error_n_m")[: len(fixes)]
    np.testing.assert_allclose(north_err, recorded, atol=0.01)
    heights = np.array([f.height_ellipsoidal_m for f in fixes])
    np.testing.assert_allclose(heights - h, -gps.fixes.column("error_d_m")[: len(fixes)],
                               atol=0.002)
    assert 0.3 < np.std(recorded) < 2.0  # code solution ~1 m, correlated over 60 s


def test_the_truth_has_one_row_per_fix_sent(tmp_path):
    """Issue 33, item 10: truth/gps_fixes.csv had a row for every epoch of the last minute
    computed ahead, those past the flight's end all stamped with its end time (600 rows for 549
    fixes on `bench`), and the quality of a fix in an outage said 4 where the GGA said 0."""
    scn, traj, gps, stream, _ = _run({"faults": {"pps_outages": [{"at_s": 100,
                                                                   "duration_s": 20}]}})
    ggas = [d.message for d in NmeaStreamDecoder(ErrorPolicy.RAISE).feed(stream)
            if isinstance(d.message, Gga)]
    table = read_truth_csv(gps.fixes.write_csv(tmp_path))
    t = table["t_gps_ns"]
    assert len(t) == len(ggas)
    assert np.all(np.diff(t) == NS_PER_S // scn.gps.nmea_rate_hz)
    assert t[-1] <= traj.t_end_ns
    leap_ns = scn.block.leap_seconds * NS_PER_S
    assert [(int(ti) - leap_ns) % (86_400 * NS_PER_S) for ti in t] == [
        g.utc_time_of_day_ns for g in ggas]
    assert table["quality"].tolist() == [int(g.quality) for g in ggas]
    assert 0 < int(np.count_nonzero(table["quality"] == 0)) < len(ggas)


def test_every_standard_sentence_parses_with_pynmeagps():
    _, _, _, stream, _ = _run({})
    lines = [ln + b"\r\n" for ln in stream.split(b"\r\n") if ln]
    standard = [ln for ln in lines if not ln.startswith(b"$PASHR")]
    assert len(standard) > 1000
    for raw in standard:
        msg = NMEAReader.parse(raw, validate=1)
        assert msg.msgID in ("GGA", "RMC", "ZDA")


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def gpsd_on_pty():
    gpsd = shutil.which("gpsd") or "/usr/sbin/gpsd"
    port = PtyPort()
    tcp = _free_port()
    proc = subprocess.Popen([gpsd, "-N", "-n", "-b", "-S", str(tcp), port.name],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        yield port, tcp
    finally:
        proc.terminate()
        proc.wait(timeout=5)
        port.close()


def test_gpsd_reports_fixes_matching_the_truth(gpsd_on_pty):
    port, tcp = gpsd_on_pty
    scn = scenario_from_table({"base": "bench", "gps": {"solution": "phase"}})
    traj = TruthTrajectory.from_scenario(scn)
    gps = GpsReceiver(scn, traj, np.random.default_rng(2), fault_table())
    stop = threading.Event()

    def sink(out):
        if out.port is Port.GPS_SERIAL:
            port.write(out.payload)
        return []

    runner = Runner([gps], sink, speed=4.0)
    feeder = threading.Thread(target=runner.run, kwargs={"should_stop": stop.is_set})
    feeder.start()
    try:
        out = subprocess.run(["gpspipe", "-w", "-x", "8", f"127.0.0.1:{tcp}"],
                             capture_output=True, text=True, timeout=30, check=False).stdout
    finally:
        stop.set()
        feeder.join()
    tpv = [r for r in map(json.loads, out.splitlines())
           if r.get("class") == "TPV" and r.get("mode", 0) >= 2 and "lat" in r]
    assert len(tpv) >= 5
    leap = scn.block.leap_seconds
    for r in tpv[-5:]:
        when = dt.datetime.fromisoformat(r["time"].replace("Z", "+00:00")).replace(tzinfo=None)
        match = [t for t in gps.fixes.column("t_gps_ns")
                 if utc_datetime_from_gps_ns(int(t), leap) == when]
        assert match, f"gpsd time {when} is not an emulated epoch"
        lat, lon, h = _antenna_truth(scn, traj, [int(match[0])])
        assert abs(r["lat"] - lat[0]) * 111e3 < 0.3  # phase solution, a few cm
        assert abs(r["lon"] - lon[0]) * 111e3 * np.cos(np.radians(lat[0])) < 0.3
        assert abs(r["altHAE"] - h[0]) < 0.3
