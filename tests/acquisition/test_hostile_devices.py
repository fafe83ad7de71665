"""Devices that send what no device should, against the live acquisition (sweep 4): a real
loopback pulse link (`LiveSources`), the acquisition built as `sisa record` builds it, a real
flight recorder, and one `sisa record` run end to end on a pty and the pulse link.

Each test failed before its fix:
- the pulse link's garbage never reached the health channel (its decoder's counts stayed in
  `LiveSources`): a timing board sending megabytes of noise read as 0 decode errors;
- an edge time near either end of int64 ended `sisa record` with a traceback (the forward's
  time overflowed the link's encoding) or left /pulses/in unreadable (its board count overflowed
  the log's 64-bit integers);
- a ZDA dated 9999 (or 0001) left /gps/fix unreadable (the fix's GPS time beyond int64);
- a timing board that stopped reading held every later edge, and the recorder's loop with it,
  for the 0.5 s send timeout.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import tty
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from acquisition.codec import ErrorPolicy
from acquisition.handover import Handover, dispatch
from acquisition.live import SEND_TIMEOUT_S, LinkEvent, LinkState, LiveSources
from acquisition.nmea import (
    FixQuality,
    NmeaStreamDecoder,
    Zda,
    encode,
    gga_from_fix,
    ptt_from_gps_ns,
    rmc_from_fix,
    zda_from_gps_ns,
)
from acquisition.pulses import EDGE_SIZE, Edge, PulseLine, encode_edge
from acquisition.runner import Acquisition
from emulators.scenario import load_scenario
from recorder.columns import read_columns
from recorder.messages import StreamHealth, Topic
from recorder.reader import read_messages
from recorder.writer import FlightRecorder
from sisa.core.nmea import checksum
from sisa.core.timescale import NS_PER_S, gps_ns_from_unix_ns
from sisa.wiring.acqconfig import acquisition_config

ROOT = Path(__file__).resolve().parents[2]
LEAP_S = 18
INT64_MAX = 2**63 - 1
GARBAGE = bytes(3000) + b"PL" * 2000 + b"\xff" * 1000  # no edge in it


class Board:
    """A timing board on loopback: accepts the recorder, sends what it is told, reads nothing
    unless asked to."""

    def __init__(self) -> None:
        self.server = socket.create_server(("127.0.0.1", 0))
        self.address = f"tcp://127.0.0.1:{self.server.getsockname()[1]}"
        self.conns: list[socket.socket] = []
        self._thread = threading.Thread(target=self._accept, daemon=True)
        self._thread.start()

    def _accept(self) -> None:
        with contextlib.suppress(OSError):
            while True:
                self.conns.append(self.server.accept()[0])

    def send(self, data: bytes) -> None:
        deadline = time.monotonic() + 5
        while not self.conns:
            assert time.monotonic() < deadline, "the recorder never connected"
            time.sleep(0.01)
        self.conns[-1].sendall(data)

    def close(self) -> None:
        for conn in self.conns:
            conn.close()
        self.server.close()


@pytest.fixture
def board() -> Iterator[Board]:
    b = Board()
    yield b
    b.close()


def _acquire(sources: LiveSources, acq: Acquisition, seconds: float) -> list[LinkEvent]:
    """`sisa record`'s loop, briefly: every arrival to the acquisition, link events returned."""
    handover, events = Handover(acq), []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        for item in sources.poll(0.02):
            if isinstance(item.payload, LinkEvent):
                events.append(item.payload)
            else:
                handover.put(item)
    handover.flush()
    return events


def _health(logged: list[object], stream: str) -> StreamHealth:
    return [m for m in logged if isinstance(m, StreamHealth) and m.stream == stream][-1]


def test_pulse_link_garbage_reaches_the_health_channel(board: Board) -> None:
    sources = LiveSources(None, None, None, board.address)
    logged: list[object] = []
    try:
        # as `sisa record` builds it
        acq = Acquisition(acquisition_config(load_scenario("bench")),
                          lambda m, _t: logged.append(m), sources.send_edge,
                          pulse_stats=sources.pulse_stats)
        t_gps = gps_ns_from_unix_ns(time.time_ns(), LEAP_S)
        board.send(GARBAGE + encode_edge(Edge(PulseLine.PPS, 0, t_gps)) + GARBAGE)
        _acquire(sources, acq, 0.5)
    finally:
        sources.close()
    acq.finish(time.time_ns())
    pps = _health(logged, "pps")
    assert pps.framing_errors + pps.checksum_errors >= 2
    assert 2 * len(GARBAGE) - EDGE_SIZE < pps.bytes_skipped <= 2 * len(GARBAGE)  # ≤ 19 held
    assert pps.messages == 1
    assert _health(logged, "ppf").bytes_skipped == 0  # counted once, on the link's first stream


def test_edge_times_at_the_ends_of_int64_are_counted_not_fatal(board: Board,
                                                               tmp_path: Path) -> None:
    """A PPS train that ends 500 ns before 2^63: the sync unit's forward of its last edge did
    not fit the link's i64 (struct.error out of `send_edge`: `sisa record` ended)."""
    sources = LiveSources(None, None, None, board.address)
    out = tmp_path / "edges.mcap"
    seconds = 40
    train = [INT64_MAX - 500 - (seconds - k) * NS_PER_S for k in range(seconds + 1)]
    try:
        with FlightRecorder(out) as rec:
            acq = Acquisition(acquisition_config(load_scenario("bench")), rec.write,
                              sources.send_edge, pulse_stats=sources.pulse_stats)
            t_gps = gps_ns_from_unix_ns(time.time_ns(), LEAP_S)
            good = [Edge(PulseLine.PPS, k, t_gps + k * NS_PER_S) for k in range(3)]
            edges = [*good, Edge(PulseLine.PPF, 3, -(2**63)),
                     *(Edge(PulseLine.PPS, 4 + k, t) for k, t in enumerate(train))]
            board.send(b"".join(encode_edge(e) for e in edges))
            _acquire(sources, acq, 0.5)
            acq.finish(time.time_ns())
    finally:
        sources.close()
    stats = acq.streams["pps"].stats
    assert stats.framing_errors == 1 + len(train)
    assert stats.bytes_skipped == EDGE_SIZE * (1 + len(train))
    pulses_in = read_columns(out, Topic.PULSE_IN)  # raised: an integer beyond int64
    assert len(pulses_in["board_ns"]) == len(good)
    read_columns(out, Topic.PULSE_OUT)


def _nmea(body: bytes) -> bytes:
    return b"$" + body + b"*%02X\r\n" % checksum(body)


@pytest.mark.parametrize("year", [b"9999", b"0001"])
def test_a_zda_dated_beyond_gps_time_is_a_framing_error(tmp_path: Path, year: bytes) -> None:
    t_gps = 1_400_000_000 * NS_PER_S
    fields = encode(zda_from_gps_ns(t_gps, LEAP_S))[1:-5].split(b",")
    fields[4] = year
    bad_zda = _nmea(b",".join(fields))
    gga = encode(gga_from_fix(t_gps, LEAP_S, 41.5, 2.1, 600.0, 49.5, FixQuality.RTK_FIXED, 12,
                              0.7))
    decoder = NmeaStreamDecoder(ErrorPolicy.COUNT)
    assert [type(d.message) for d in decoder.feed(encode(zda_from_gps_ns(t_gps, LEAP_S)))] == [Zda]
    assert decoder.feed(bad_zda) == []
    assert decoder.stats.framing_errors == 1

    out = tmp_path / "gps.mcap"
    host_ns = 1_700_000_000 * NS_PER_S
    with FlightRecorder(out) as rec:
        acq = Acquisition(acquisition_config(load_scenario("bench")), rec.write,
                          lambda _e: None)
        acq.on_gps_bytes(host_ns, encode(rmc_from_fix(t_gps, LEAP_S, 41.5, 2.1, 60.0, 90.0)))
        acq.on_gps_bytes(host_ns + 1, bad_zda + gga + encode(ptt_from_gps_ns(t_gps)))
        acq.finish(host_ns + 2)
    fixes = read_columns(out, Topic.GPS_FIX)  # raised: a t_gps_ns beyond int64
    assert fixes["t_gps_ns"].tolist() == [t_gps // NS_PER_S * NS_PER_S]
    read_columns(out, Topic.GPS_TIME_TAG)
    assert acq.streams["gps"].stats.framing_errors == 1


def test_a_timing_board_that_stops_reading_is_dropped_not_waited_on(board: Board) -> None:
    """A board that hangs with its socket open fills the link; each later edge then waited the
    0.5 s send timeout, and the recorder's loop, every device's reading, with it."""
    sources = LiveSources(None, None, None, board.address)
    try:
        sock = sources._pulse_sock
        assert sock is not None
        sock.settimeout(0.0)
        with contextlib.suppress(BlockingIOError):
            while True:  # what hours of forwards to a board that reads nothing leave behind
                sock.send(bytes(65536))
        sock.settimeout(SEND_TIMEOUT_S)
        started = time.monotonic()
        for k in range(8):
            sources.send_edge(Edge(PulseLine.INS_SYNC, 0, k))
        waited = time.monotonic() - started
        deadline = time.monotonic() + 5
        events: list[LinkEvent] = []
        while len(events) < 2 and time.monotonic() < deadline:
            events += [a.payload for a in sources.poll(0.05) if isinstance(a.payload, LinkEvent)]
    finally:
        sources.close()
    assert waited < 1.0, waited  # one send timeout, not one per edge
    assert [e.state for e in events] == [LinkState.LOST, LinkState.RESTORED], events
    assert "took no edge" in events[0].error
    deadline = time.monotonic() + 2
    while len(board.conns) < 2 and time.monotonic() < deadline:  # the board's accept thread
        time.sleep(0.01)
    assert len(board.conns) == 2  # reconnected


# --- one `sisa record`, end to end ---------------------------------------------------------


def _pty() -> tuple[int, str]:
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    return master, os.ttyname(slave)


def _nmea_second(t_gps: int, zda_year: bytes | None = None) -> bytes:
    t = t_gps // NS_PER_S * NS_PER_S
    zda = encode(zda_from_gps_ns(t, LEAP_S))
    if zda_year is not None:
        fields = zda[1:-5].split(b",")
        fields[4] = zda_year
        zda = _nmea(b",".join(fields))
    gga = gga_from_fix(t, LEAP_S, 41.5, 2.1, 600.0, 49.5, FixQuality.RTK_FIXED, 12, 0.7)
    rmc = encode(rmc_from_fix(t, LEAP_S, 41.5, 2.1, 60.0, 90.0))
    return rmc + zda + encode(gga) + encode(ptt_from_gps_ns(t))


def test_sisa_record_survives_a_hostile_pulse_link_and_gps(board: Board, tmp_path: Path) -> None:
    master, gps_port = _pty()
    out = tmp_path / "flight.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-m", "sisa.cli", "record", "--quiet", "--gps", gps_port, "--pulses",
         board.address, "--out", str(out), "--scenario", "bench", "--duration", "30"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        for k in range(40):
            t_gps = gps_ns_from_unix_ns(time.time_ns(), LEAP_S)
            # a good second, then one whose ZDA is dated 9999 (the GGA after it takes its date)
            with contextlib.suppress(BlockingIOError):
                os.write(master, _nmea_second(t_gps, b"9999" if k % 2 else None))
            if k == 5:
                board.send(GARBAGE * 100)  # 800 kB of noise on the pulse link
            if k >= 5:  # a PPS train running into the end of int64, 10 edges a second
                board.send(encode_edge(Edge(PulseLine.PPS, k, INT64_MAX - 500
                                            - (39 - k) * NS_PER_S)))
            time.sleep(0.1)
        proc.send_signal(signal.SIGINT)
        _stdout, stderr = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        os.close(master)
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stderr, stderr
    health = read_columns(out, Topic.HEALTH)
    periodic = health["event"] == ""
    pps = periodic & (health["stream"] == "pps")
    assert health["bytes_skipped"][pps][-1] >= 100 * len(GARBAGE) + 35 * EDGE_SIZE
    gps = periodic & (health["stream"] == "gps")
    assert health["framing_errors"][gps][-1] >= 15  # the ZDAs dated 9999
    fixes = read_columns(out, Topic.GPS_FIX)["t_gps_ns"]  # every topic reads
    assert len(fixes) >= 30  # the GPS kept being recorded
    assert np.all(np.abs(np.diff(fixes)) < 10 * NS_PER_S)
    for topic in (Topic.PULSE_IN, Topic.PULSE_OUT, Topic.GPS_TIME_TAG):
        read_columns(out, topic)
    assert list(read_messages(out, StreamHealth))
    info = subprocess.run([sys.executable, "-m", "sisa.cli", "log", "info", str(out)],
                          capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert info.returncode == 0, info.stderr


def test_garbled_can_lines_reach_the_health_channel_with_their_bytes() -> None:
    """`sisa record` hands a read's bad SLCAN lines over as GarbledCanLines: lines are framing
    errors of the INS stream, and their bytes are bytes skipped (they were not counted)."""
    from acquisition.live import Arrival, GarbledCanLines, Source

    logged: list[object] = []
    acq = Acquisition(acquisition_config(load_scenario("bench")),
                      lambda m, _t: logged.append(m), lambda _e: None)
    host_ns = 1_700_000_000 * NS_PER_S
    dispatch(acq, Arrival(host_ns, Source.INS, GarbledCanLines(3, 4200)))
    acq.finish(host_ns + NS_PER_S)
    ins = [m for m in logged if isinstance(m, StreamHealth) and m.stream == "ins"][-1]
    assert (ins.framing_errors, ins.bytes_skipped) == (3, 4200)
