"""`sisa emulate` as a separate process, read by real clients: pyserial on the GPS pty,
python-can slcan on the INS adapter, a TCP socket on the pulse endpoint."""

import contextlib
import itertools
import json
import signal
import socket
import subprocess
import sys
import time

import can
import pytest
import serial

from acquisition.codec import ErrorPolicy
from acquisition.ins_can import InsRecordAssembler, InsStatus
from acquisition.nmea import Gga, NmeaStreamDecoder
from acquisition.pulses import Edge, EdgeStreamDecoder, PulseLine, encode_edge


def _wait_for(path, timeout_s=30.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if path.exists() and path.stat().st_size:
            return json.loads(path.read_text())
        time.sleep(0.05)
    raise AssertionError("emulator did not announce its endpoints")


def test_emulate_serves_real_clients_and_takes_sync_pulses(tmp_path):
    endpoints_file = tmp_path / "endpoints.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "sisa.cli", "emulate", "--preset", "bench", "--out",
         str(tmp_path / "run"), "--duration", "60", "--no-images", "--endpoints",
         str(endpoints_file)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        ep = _wait_for(endpoints_file)
        host, port = ep["pulses"].removeprefix("tcp://").split(":")
        assert host == "127.0.0.1"
        gps = serial.Serial(ep["gps"], 115200, timeout=0)
        bus = can.Bus(interface="slcan", channel=ep["ins"].removeprefix("slcan:"))
        pulses = socket.create_connection((host, int(port)), timeout=5)
        pulses.settimeout(0.01)
        nmea = NmeaStreamDecoder(ErrorPolicy.RAISE)
        # COUNT: on a loaded machine this client can fall behind and the adapter drops frames
        # (as a real one does); a record is then incomplete and counted, never wrong
        asm = InsRecordAssembler(ErrorPolicy.COUNT)
        edge_dec = EdgeStreamDecoder(ErrorPolicy.RAISE)
        fixes, records, pps = [], [], []
        deadline = time.monotonic() + 6.0
        while time.monotonic() < deadline:
            fixes += [d.message for d in nmea.feed(gps.read(4096))
                      if isinstance(d.message, Gga)]
            while (msg := bus.recv(timeout=0.0)) is not None:
                if (rec := asm.feed(msg)) is not None:
                    records.append(rec.message)
            try:
                chunk = pulses.recv(4096)
            except TimeoutError:
                chunk = None
            except ConnectionResetError:
                break
            if chunk == b"":
                break  # the emulator has ended
            got = edge_dec.feed(chunk) if chunk else []
            for item in got:
                if item.message.line is PulseLine.PPS:
                    pps.append(item.message)
                    # answer like the sync unit: forward the PPS to the INS sync input
                    pulses.sendall(encode_edge(Edge(PulseLine.INS_SYNC, 0, item.message.t_ns)))
        gps.close()
        # the emulator may already have closed its side of the pty on a slow machine
        with contextlib.suppress(can.CanOperationError):
            bus.shutdown()
        pulses.close()
        proc.send_signal(signal.SIGTERM)  # stops cleanly, as Ctrl-C does
    finally:
        out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert "GPS receiver" in out
    assert len(fixes) >= 3
    assert len(pps) >= 3
    assert len(records) > 64 * 3
    counters = [r.counter for r in records]
    steps = [(b - a) % 2**16 for a, b in itertools.pairwise(counters)]
    assert all(1 <= s < 2**15 for s in steps)  # in order, none repeated
    assert steps.count(1) >= 0.9 * len(steps)  # nearly every record whole
    synced = [r for r in records if r.status & InsStatus.SYNC_PULSE]
    assert len(synced) >= 2  # our forwarded PPS came back inside INS records
    assert (tmp_path / "run" / "truth" / "ins_records.csv").is_file()


def test_gpsd_serves_the_emulated_receiver_and_stops_with_it(tmp_path):
    """Issue 33, item 11: `sisa emulate --gpsd` starts gpsd on a copy of the GPS port (so a
    recorder on the port itself still gets every byte), says how to connect, and stops it."""
    endpoints_file = tmp_path / "endpoints.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "sisa.cli", "emulate", "--preset", "bench", "--out",
         str(tmp_path / "run"), "--duration", "60", "--no-images", "--gpsd", "--endpoints",
         str(endpoints_file)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        ep = _wait_for(endpoints_file)
        address = ep["gpsd"]
        assert address.startswith("127.0.0.1:")
        assert ep["gps_copy"] != ep["gps"]
        gps = serial.Serial(ep["gps"], 115200, timeout=0)
        piped = subprocess.run(["gpspipe", "-w", "-x", "6", address], capture_output=True,
                               text=True, timeout=30, check=False).stdout
        nmea = NmeaStreamDecoder(ErrorPolicy.RAISE)  # the port itself: every sentence whole
        fixes = [d.message for d in nmea.feed(gps.read(65536)) if isinstance(d.message, Gga)]
        gps.close()
        proc.send_signal(signal.SIGINT)
    finally:
        out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert f"gpsd (on a copy of the GPS port):    tcp://{address}" in out
    assert f"gpspipe -w {address}" in out
    tpv = [r for r in map(json.loads, piped.splitlines())
           if r.get("class") == "TPV" and r.get("mode", 0) >= 2]
    assert len(tpv) >= 2, piped
    assert abs(tpv[-1]["lat"] - 41.564) < 0.01  # the bench flight's alignment point
    assert len(fixes) >= 3
    host, port = address.split(":")
    with pytest.raises(ConnectionRefusedError):  # gpsd went with the emulator
        socket.create_connection((host, int(port)), timeout=1).close()


def test_gpsd_reports_3d_fixes_from_the_ublox_profile(tmp_path):
    """Issue 34: gpsd, an independent reader, on the u-blox F9P profile's port (NMEA 4.1 from
    talker GN with UBX-TIM-TP and UBX-TIM-TM2 between the sentences) reports 3-D fixes at the
    emulated position, as it does for a real F9P."""
    scenario = tmp_path / "ublox.toml"
    scenario.write_text('base = "bench"\n[gps]\nreceiver = "ublox_f9p"\n', encoding="utf-8")
    endpoints_file = tmp_path / "endpoints.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "sisa.cli", "emulate", "--scenario", str(scenario), "--out",
         str(tmp_path / "run"), "--start", "70", "--duration", "60", "--no-images", "--gpsd",
         "--endpoints", str(endpoints_file)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        ep = _wait_for(endpoints_file)
        piped = subprocess.run(["gpspipe", "-w", "-x", "8", ep["gpsd"]], capture_output=True,
                               text=True, timeout=30, check=False).stdout
        proc.send_signal(signal.SIGINT)
    finally:
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    reports = [json.loads(line) for line in piped.splitlines()]
    tpv = [r for r in reports if r.get("class") == "TPV" and r.get("mode") == 3]
    assert len(tpv) >= 3, piped
    assert all(abs(r["lat"] - 41.56) < 0.05 and abs(r["lon"] - 2.0) < 0.5 for r in tpv), tpv
    assert all("altHAE" in r or "alt" in r for r in tpv)


def test_gpsd_missing_is_one_line_and_nothing_made(tmp_path, monkeypatch, capsys):
    from sisa.cli import main
    from sisa.wiring import gpsd

    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setattr(gpsd, "GPSD_FALLBACK", tmp_path / "no-gpsd")
    assert main(["emulate", "--preset", "bench", "--out", str(tmp_path / "run"),
                 "--gpsd"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("sisa emulate: error: --gpsd: gpsd is not installed (Debian: ")
    assert "\n" not in err
    assert not (tmp_path / "run").exists()
