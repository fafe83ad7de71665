"""A device that disappears and comes back: its reader reopens the same port / channel / address,
the other streams keep recording, the outage is in the health channel with its start and end, and
post-processing reads the log with its gap.

Real ptys (a stable symlink repointed to a new pty pair, as a USB serial adapter replugged under a
udev name), a real python-can slcan bus on the emulator's adapter pty, a real loopback TCP link.
"""

from __future__ import annotations

import contextlib
import os
import pty
import signal
import subprocess
import sys
import threading
import time
import tty
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can
import numpy as np

from acquisition.ins_can import InsRecord, InsStatus, encode_record
from acquisition.live import Arrival, LinkEvent, LinkState, LiveSources, Source
from acquisition.nmea import FixQuality, encode, gga_from_fix, rmc_from_fix
from acquisition.pulses import Edge, PulseLine
from emulators.ports import PulseEndpoint, SlcanAdapter
from recorder.messages import GpsFix, InsRecordLog, StreamHealth
from recorder.reader import read_messages
from sisa.core.timescale import NS_PER_S, gps_ns_from_unix_ns

ROOT = Path(__file__).resolve().parents[2]
LEAP_S = 18
OUTAGE_S = 1.0


def _repoint(link: Path, target: str) -> None:
    """Atomically point `link` at `target` (what udev does when a device is plugged in)."""
    tmp = link.with_name(link.name + ".new")
    with contextlib.suppress(FileNotFoundError):
        tmp.unlink()
    tmp.symlink_to(target)
    os.replace(tmp, link)


class PlugPty:
    """A serial device behind a stable path: `unplug` closes its pty (the reader sees EIO/EOF)
    and removes the path; `plug` makes a new pty pair and points the path at it."""

    def __init__(self, link: Path) -> None:
        self.link = link
        self.master: int | None = None
        self.slave: int | None = None
        self.plug()

    def plug(self) -> None:
        self.master, self.slave = pty.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        _repoint(self.link, os.ttyname(self.slave))

    def unplug(self) -> None:
        self.link.unlink()
        for fd in (self.master, self.slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self.master = self.slave = None

    def write(self, data: bytes) -> None:
        if self.master is not None:
            with contextlib.suppress(BlockingIOError, OSError):
                os.write(self.master, data)


def _nmea_epoch() -> bytes:
    t_gps = gps_ns_from_unix_ns(time.time_ns(), LEAP_S) // (NS_PER_S // 10) * (NS_PER_S // 10)
    gga = gga_from_fix(t_gps, LEAP_S, 41.5, 2.1, 600.0, 49.5, FixQuality.RTK_FIXED, 12, 0.7)
    return encode(rmc_from_fix(t_gps, LEAP_S, 41.5, 2.1, 60.0, 90.0)) + encode(gga)


def _ins_frames(counter: int) -> list[can.Message]:
    rec = InsRecord(counter % 2**16, (counter * 200_000) % 2**48, 0.01, -0.02, 1.0,
                    (0.0, 0.0, 0.0), (60.0, 0.0, 0.0), InsStatus.NAVIGATING, False, 0)
    return encode_record(rec)


class Feeder:
    """Calls `step(i)` every `period_s` in a thread until stopped."""

    def __init__(self, period_s: float, step: Callable[[int], None]) -> None:
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(period_s, step), daemon=True)
        self._thread.start()

    def _run(self, period_s: float, step: Callable[[int], None]) -> None:
        i = 0
        while not self._stop.wait(period_s):
            step(i)
            i += 1

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)


class InsDevice:
    """The INS behind an slcan adapter on a pty, reachable through a stable path."""

    def __init__(self, link: Path) -> None:
        self.link = link
        self.adapter: SlcanAdapter | None = None
        self.lock = threading.Lock()
        self.plug()

    def plug(self) -> None:
        adapter = SlcanAdapter()
        _repoint(self.link, adapter.name)
        with self.lock:
            self.adapter = adapter

    def unplug(self) -> None:
        self.link.unlink()
        with self.lock:
            adapter, self.adapter = self.adapter, None
        if adapter is not None:
            adapter.close()

    def send_record(self, counter: int) -> None:
        with self.lock:
            if self.adapter is not None:
                for msg in _ins_frames(counter):
                    self.adapter.send(msg)

    def wait_open(self, timeout_s: float = 20.0) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                if self.adapter is not None and self.adapter.is_open:
                    return
            time.sleep(0.02)
        raise AssertionError("the recorder never opened the CAN channel")


def test_sisa_record_survives_a_gps_that_goes_away_and_comes_back(tmp_path: Path) -> None:
    gps = PlugPty(tmp_path / "ttyGPS")
    ins = InsDevice(tmp_path / "ttyINS")
    out = tmp_path / "flight.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-m", "sisa.cli", "record", "--quiet", "--gps", str(gps.link),
         "--ins", f"slcan:{ins.link}", "--out", str(out), "--duration", "60"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    feeders: list[Feeder] = []
    try:
        ins.wait_open()
        feeders = [Feeder(0.1, lambda _i: gps.write(_nmea_epoch())),
                   Feeder(0.02, ins.send_record)]
        time.sleep(2.0)
        gps.unplug()
        time.sleep(OUTAGE_S)
        gps.plug()
        time.sleep(2.5)
        proc.send_signal(signal.SIGINT)  # Ctrl-C
        stdout, stderr = proc.communicate(timeout=20)
    finally:
        _end(proc, feeders, ins)
        with contextlib.suppress(FileNotFoundError):
            gps.unplug()
    assert proc.returncode == 0, stderr
    assert "1 disconnects, 1 reconnects" in stdout, stdout
    assert "gps lost" in stderr, stderr
    assert "gps reconnected" in stderr, stderr

    events = [h for h in read_messages(out, StreamHealth) if h.event]
    assert [(h.stream, h.event) for h in events] == [("gps", "link_lost"), ("gps", "link_restored")]
    lost, back = events
    assert lost.link_lost_ns == lost.t_host_ns
    assert lost.disconnects == 1
    assert lost.link_error
    assert back.link_lost_ns == lost.t_host_ns
    assert back.link_restored_ns == back.t_host_ns
    assert back.reconnects == 1
    away_s = (back.link_restored_ns - back.link_lost_ns) / NS_PER_S
    assert 0.8 * OUTAGE_S <= away_s <= OUTAGE_S + 3.0

    # the INS kept recording during the outage; the GPS is recorded again after it
    ins_t = np.array([r.t_host_ns for r in read_messages(out, InsRecordLog)])
    during = ins_t[(ins_t > lost.link_lost_ns) & (ins_t < back.link_restored_ns)]
    assert during.size >= 0.5 * away_s * 50
    fixes_t = np.array([f.t_host_ns for f in read_messages(out, GpsFix)])
    assert ((fixes_t > lost.link_lost_ns) & (fixes_t < back.link_restored_ns)).sum() == 0
    assert (fixes_t > back.link_restored_ns).sum() >= 10
    assert (fixes_t < lost.link_lost_ns).sum() >= 10
    # periodic reports carry the counts too
    final = [h for h in read_messages(out, StreamHealth) if h.stream == "gps" and not h.event]
    assert final[-1].disconnects == final[-1].reconnects == 1
    assert final[-1].link_lost_ns == -1
    # and `sisa log info` says it, from the periodic reports (the events not counted again)
    info = subprocess.run([sys.executable, "-m", "sisa.cli", "log", "info", str(out)],
                          capture_output=True, text=True, check=True, cwd=ROOT).stdout
    assert "recorder health (its own counters, totals over the recording): 1 disconnect\n" in info
    gps_row = next(line.split() for line in info.splitlines() if line.startswith("  gps "))
    assert gps_row[-2:] == ["1", "1"], info  # disconnects, reconnects

    # post-processing reads the log with its gap: tables for every INS record, untimed flagged
    from postproc.sync import TimeStatus, sync_log

    result = sync_log([out])
    times = result.ins
    assert times.t_gps_ns.shape == times.status.shape == (ins_t.size,)
    untimed = times.status != TimeStatus.OK
    assert np.all(times.t_gps_ns[untimed] == -1)  # never a silent wrong time


def _collect(sources: LiveSources, until: float) -> list[Arrival]:
    got = []
    while time.monotonic() < until:
        got.extend(sources.poll(0.05))
    return got


def test_can_channel_and_pulse_link_reconnect_while_gps_keeps_arriving(tmp_path: Path) -> None:
    gps = PlugPty(tmp_path / "ttyGPS")
    ins = InsDevice(tmp_path / "ttyINS")
    pulses = PulseEndpoint(lambda _e: None)
    port = int(pulses.address.rpartition(":")[2])
    endpoint: list[PulseEndpoint] = [pulses]
    sources = LiveSources(str(gps.link), None, f"slcan:{ins.link}", pulses.address)
    feeders: list[Feeder] = []
    try:
        ins.wait_open()
        feeders = [
            Feeder(0.05, lambda _i: gps.write(_nmea_epoch())),
            Feeder(0.02, ins.send_record),
            Feeder(0.05, lambda i: endpoint[0].send(Edge(PulseLine.PPF, 0, i * 50_000_000))),
        ]
        before = _collect(sources, time.monotonic() + 1.0)
        ins.unplug()
        endpoint[0].close()
        outage = _collect(sources, time.monotonic() + OUTAGE_S)
        ins.plug()
        endpoint[0] = PulseEndpoint(lambda _e: None, port=port)
        after = _collect(sources, time.monotonic() + 3.0)
    finally:
        for feeder in feeders:
            feeder.stop()
        sources.close()
        endpoint[0].close()
        with contextlib.suppress(FileNotFoundError):
            ins.unplug()
        gps.unplug()

    everything = before + outage + after
    for source in (Source.INS, Source.PULSES):
        events = [a for a in everything if a.source is source and isinstance(a.payload, LinkEvent)]
        states = [e.payload.state for e in events]  # type: ignore[union-attr]
        assert states == [LinkState.LOST, LinkState.RESTORED], (source, events)
        lost, back = (e.payload for e in events)
        assert isinstance(lost, LinkEvent)
        assert isinstance(back, LinkEvent)
        assert back.lost_t_host_ns == lost.lost_t_host_ns == events[0].t_host_ns
        assert back.attempts >= 1
        assert events[1].t_host_ns - events[0].t_host_ns >= 0.8 * OUTAGE_S * NS_PER_S
        # data again after the device came back
        later = [a for a in everything if a.source is source and a.t_host_ns > events[1].t_host_ns
                 and not isinstance(a.payload, LinkEvent)]
        assert len(later) >= 10, source
    # the GPS never stopped
    gps_during = [a for a in outage if a.source is Source.GPS and isinstance(a.payload, bytes)]
    assert len(gps_during) >= 0.5 * OUTAGE_S / 0.05
    assert not any(isinstance(a.payload, LinkEvent) for a in everything if a.source is Source.GPS)


class StderrLines:
    """A child's stderr, read as it comes (the test acts on what it said)."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        assert proc.stderr is not None
        self.lines: list[str] = []
        self._thread = threading.Thread(target=self._read, args=(proc.stderr,), daemon=True)
        self._thread.start()

    def _read(self, stream: Any) -> None:
        for line in stream:
            self.lines.append(line)

    @property
    def text(self) -> str:
        return "".join(self.lines)

    def wait_for(self, needle: str, timeout_s: float, while_waiting: Callable[[], None]
                 = lambda: None) -> None:
        deadline = time.monotonic() + timeout_s
        while needle not in self.text:
            assert time.monotonic() < deadline, f"never said {needle!r}: {self.text}"
            while_waiting()
            time.sleep(0.1)

    def join(self) -> str:
        self._thread.join(timeout=10)
        return self.text


def _stop(proc: subprocess.Popen[str]) -> str:
    """Ctrl-C; its stdout (its stderr is being read by a StderrLines)."""
    proc.send_signal(signal.SIGINT)
    assert proc.stdout is not None
    stdout = proc.stdout.read()
    proc.wait(timeout=20)
    return stdout


def _record(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "sisa.cli", "record", "--quiet", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)


def _end(proc: subprocess.Popen[str], feeders: list[Feeder], ins: InsDevice) -> None:
    """A test's clean-up: the feeders stopped, the recorder killed if still running, the INS
    adapter unplugged."""
    for feeder in feeders:
        feeder.stop()
    if proc.poll() is None:
        proc.kill()
        proc.communicate()
    ins.unplug()


def _wait_recording(out: Path, gps: PlugPty) -> None:
    deadline = time.monotonic() + 20
    while not out.exists() and time.monotonic() < deadline:  # its ports are open by then
        gps.write(_nmea_epoch())
        time.sleep(0.1)
    for _ in range(5):
        gps.write(_nmea_epoch())
        time.sleep(0.1)


def test_sisa_record_keeps_waiting_for_a_device_past_the_old_limit(tmp_path: Path) -> None:
    """Every device away for 10 s ended the recording for good, exit 0: a USB hub reset in
    flight lost the rest of the flight. Now it waits, says so, and takes the device back."""
    gps = PlugPty(tmp_path / "ttyGPS")
    out = tmp_path / "flight.mcap"
    proc = _record("--gps", str(gps.link), "--out", str(out), "--duration", "60")
    err = StderrLines(proc)
    try:
        _wait_recording(out, gps)
        gps.unplug()
        err.wait_for("gps lost", 5)
        lost_at = time.monotonic()
        err.wait_for("WARNING: gps away for", 15)
        while time.monotonic() - lost_at < 11.0:  # past the old limit
            time.sleep(0.2)
        assert proc.poll() is None, err.text  # still recording
        gps.plug()
        err.wait_for("gps reconnected", 10, lambda: gps.write(_nmea_epoch()))
        for _ in range(10):
            gps.write(_nmea_epoch())
            time.sleep(0.1)
        stdout = _stop(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        with contextlib.suppress(FileNotFoundError):
            gps.unplug()
    stderr = err.join()
    assert proc.returncode == 0, stderr
    assert "every device away" not in stderr
    assert "WARNING: gps away for 1" in stderr  # 10.x s: said once every minute from then
    assert "still recording and reconnecting" in stderr
    assert "1 disconnects, 1 reconnects" in stdout, stdout
    fixes_t = np.array([f.t_host_ns for f in read_messages(out, GpsFix)])
    back = [h for h in read_messages(out, StreamHealth) if h.event == "link_restored"]
    assert len(back) == 1
    assert (back[0].link_restored_ns - back[0].link_lost_ns) / NS_PER_S > 10.5
    assert (fixes_t > back[0].link_restored_ns).sum() >= 5


def test_give_up_after_ends_a_recording_on_loss_with_exit_3(tmp_path: Path) -> None:
    """The old end on loss, now only when asked for, and no longer a success."""
    gps = PlugPty(tmp_path / "ttyGPS")
    out = tmp_path / "flight.mcap"
    proc = _record("--gps", str(gps.link), "--out", str(out), "--duration", "60",
                   "--give-up-after", "1")
    try:
        _wait_recording(out, gps)
        gps.unplug()
        started = time.monotonic()
        stdout, stderr = proc.communicate(timeout=30)
        ended_after_s = time.monotonic() - started
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        with contextlib.suppress(FileNotFoundError):
            gps.unplug()
    assert proc.returncode == 3, stderr
    assert 0.9 < ended_after_s < 8, ended_after_s
    assert "every device away for 1 s (--give-up-after): recording ended" in stderr, stderr
    assert "sisa record: recording ended with gps away for " in stderr, stderr
    assert "recorded " in stdout, stdout
    assert [h.event for h in read_messages(out, StreamHealth) if h.event] == ["link_lost"]


def test_a_recording_stopped_while_a_device_is_away_exits_3(tmp_path: Path) -> None:
    gps = PlugPty(tmp_path / "ttyGPS")
    ins = InsDevice(tmp_path / "ttyINS")
    out = tmp_path / "flight.mcap"
    proc = _record("--gps", str(gps.link), "--ins", f"slcan:{ins.link}", "--out", str(out))
    err = StderrLines(proc)
    feeders: list[Feeder] = []
    try:
        ins.wait_open()
        feeders = [Feeder(0.02, ins.send_record)]
        _wait_recording(out, gps)
        gps.unplug()
        err.wait_for("gps lost", 5)
        _stop(proc)
    finally:
        _end(proc, feeders, ins)
    stderr = err.join()
    assert proc.returncode == 3, stderr
    assert "recording ended with gps away for " in stderr, stderr
    assert "ins away" not in stderr
