"""A reopened port is taken back only if it proves it is the device (acquisition.proof): a pty
number the kernel gave to another program after the emulator's closed is read from, but
nothing of it is recorded and nothing is written to it; a udev name leads to the device where
its old node does not. Real ptys throughout."""

from __future__ import annotations

import contextlib
import os
import pty
import termios
import time
import tty
from collections.abc import Iterator
from pathlib import Path

import pytest

from acquisition.live import Arrival, LinkEvent, LinkState, LiveSources, Source
from emulators.ports import SlcanAdapter
from recorder.messages import RawBytes, StreamHealth
from recorder.reader import read_messages
from tests.acquisition.test_reconnect import (
    Feeder,
    InsDevice,
    StderrLines,
    _end,
    _nmea_epoch,
    _record,
    _stop,
)

TYPED = b"user typed: secret-password\n"


class Pty:
    """A pty pair held by this test: an emulator's port (raw), or another program's terminal
    (as a terminal leaves it: lines, echo)."""

    def __init__(self, name: str | None = None, raw: bool = True) -> None:
        self.master, self.slave = _open_pty(name)
        if raw:
            tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.name = os.ttyname(self.slave)

    def write(self, data: bytes) -> None:
        with contextlib.suppress(OSError):
            os.write(self.master, data)

    def output(self) -> bytes:
        """What the slave side wrote (and a terminal echoed) since the last call."""
        got = b""
        with contextlib.suppress(BlockingIOError, OSError):
            while chunk := os.read(self.master, 65536):
                got += chunk
        return got

    def close(self) -> None:
        for fd in (self.master, self.slave):
            with contextlib.suppress(OSError):
                os.close(fd)


PTY_WAIT_S = 10.0  # for a pty number another process holds


def _open_pty(name: str | None) -> tuple[int, int]:
    """A new pty pair; with `name`, the one the kernel numbers so (a number just freed is the
    lowest free one: the next to be given), or the test is skipped if another process took it."""
    if name is None:
        return pty.openpty()
    deadline = time.monotonic() + PTY_WAIT_S
    while True:
        held: list[int] = []
        try:
            for _ in range(64):
                master, slave = pty.openpty()
                if os.ttyname(slave) == name:
                    return master, slave
                held += [master, slave]
        finally:
            for fd in held:
                os.close(fd)
        if time.monotonic() > deadline:
            pytest.skip(f"{name} was held by another process for {PTY_WAIT_S:g} s")
        time.sleep(0.05)  # another test worker holds it for now: tests close their ptys soon


@pytest.fixture
def ptys() -> Iterator[list[Pty]]:
    made: list[Pty] = []
    yield made
    for p in made:
        p.close()


def test_sisa_record_does_not_take_another_programs_pty_for_the_gps(tmp_path: Path,
                                                                     ptys: list[Pty]) -> None:
    """The emulator's GPS pty closes; the kernel gives its number to a terminal, whose user
    types a password. It reopened that within 0.2 s, logged the password as /gps/raw and said
    "gps reconnected"; now it is refused, nothing of it recorded, its settings untouched."""
    gps = Pty()
    ptys.append(gps)
    ins = InsDevice(tmp_path / "ttyINS")
    out = tmp_path / "flight.mcap"
    proc = _record("--gps", gps.name, "--ins", f"slcan:{ins.link}", "--out", str(out))
    err = StderrLines(proc)
    feeders: list[Feeder] = []
    try:
        ins.wait_open()
        feeders = [Feeder(0.02, ins.send_record), Feeder(0.1, lambda _i: gps.write(_nmea_epoch()))]
        time.sleep(1.0)
        feeders.pop().stop()
        gps.close()  # the emulator ended
        err.wait_for("gps lost", 5)
        terminal = Pty(gps.name, raw=False)  # the next program to ask for a pty
        ptys.append(terminal)
        settings = termios.tcgetattr(terminal.slave)
        err.wait_for("gps not reconnected", 10, lambda: terminal.write(TYPED))
        time.sleep(2.5)  # more reopen attempts, had it tried again
        terminal.write(TYPED)
        time.sleep(0.5)
        _stop(proc)
    finally:
        _end(proc, feeders, ins)
    stderr = err.join()
    assert proc.returncode == 3, stderr  # it ended with the GPS away
    assert "gps reconnected" not in stderr
    assert stderr.count("gps not reconnected") == 1, stderr  # that node is not opened again
    assert f"{gps.name} opened, but is not the gps" in stderr
    assert "nothing recorded from it, nothing written to it" in stderr
    assert "secret" not in stderr
    # the terminal: only its own echo came back, its settings are as its program left them
    assert terminal.output().replace(TYPED.replace(b"\n", b"\r\n"), b"") == b""
    assert termios.tcgetattr(terminal.slave) == settings
    assert not any(b"secret" in m.data for m in read_messages(out, RawBytes))
    events = [(h.stream, h.event) for h in read_messages(out, StreamHealth) if h.event]
    assert events == [("gps", "link_lost"), ("gps", "link_rejected")]


def _collect(sources: LiveSources, seconds: float,
             step: tuple[float, Feeder] | None = None) -> list[Arrival]:
    got = []
    until = time.monotonic() + seconds
    while time.monotonic() < until:
        got.extend(sources.poll(0.05))
    return got


def _events(arrivals: list[Arrival], source: Source) -> list[LinkEvent]:
    return [a.payload for a in arrivals
            if a.source is source and isinstance(a.payload, LinkEvent)]


def test_an_slcan_port_given_to_another_program_is_never_written_to(ptys: list[Pty]) -> None:
    """It wrote python-can's open command `O\\r` into the other program's terminal."""
    adapter = SlcanAdapter()
    name = adapter.name
    sources = LiveSources(None, None, f"slcan:{name}", None)
    try:
        time.sleep(0.1)
        adapter.close()  # the emulator ended
        got = _collect(sources, 0.3)
        terminal = Pty(name, raw=False)
        ptys.append(terminal)
        terminal.write(b"secret-password\n")
        got += _collect(sources, 2.5)
    finally:
        sources.close()
    states = [e.state for e in _events(got, Source.INS)]
    assert states == [LinkState.LOST, LinkState.REJECTED], got
    assert "no SLCAN frame" in _events(got, Source.INS)[1].error
    assert terminal.output() == b"secret-password\r\n"  # its own echo: nothing written to it
    assert not [a for a in got if a.source is Source.INS and not isinstance(a.payload, LinkEvent)]


def test_a_silent_port_is_asked_the_slcan_version_once_and_never_opened(ptys: list[Pty]) -> None:
    """A port that says nothing is asked `V\\r` (the harmless query), once; without an answer
    it is given up and its channel never opened (`O\\r`)."""
    adapter = SlcanAdapter()
    name = adapter.name
    sources = LiveSources(None, None, f"slcan:{name}", None)
    try:
        time.sleep(0.1)
        adapter.close()
        got = _collect(sources, 0.3)
        silent = Pty(name)
        ptys.append(silent)
        got += _collect(sources, 4.0)
    finally:
        sources.close()
    events = _events(got, Source.INS)
    assert [e.state for e in events] == [LinkState.LOST, LinkState.REJECTED], got
    assert "did not answer the version query" in events[1].error
    assert "only b'V\\r' written to it" in events[1].error
    assert silent.output() == b"V\r"


def test_an_slcan_adapter_replugged_on_the_same_pty_number_comes_back(ptys: list[Pty]) -> None:
    """The positive case on a reused number: a new adapter there answers the version query and
    is opened; its frames are recorded again."""
    import can

    adapter = SlcanAdapter()
    name = adapter.name
    sources = LiveSources(None, None, f"slcan:{name}", None)
    replugged: SlcanAdapter | None = None
    try:
        time.sleep(0.1)
        adapter.close()
        got = _collect(sources, 0.3)
        replugged = SlcanAdapter()
        if replugged.name != name:
            pytest.skip(f"{name} was taken by another process")
        deadline = time.monotonic() + 5
        while not replugged.is_open and time.monotonic() < deadline:
            got += _collect(sources, 0.1)
        for _ in range(5):
            replugged.send(can.Message(arbitration_id=0x100, data=b"\x01", is_extended_id=False))
        got += _collect(sources, 0.5)
    finally:
        sources.close()
        if replugged is not None:
            replugged.close()
    assert [e.state for e in _events(got, Source.INS)] == [LinkState.LOST, LinkState.RESTORED]
    frames = [f for a in got if a.source is Source.INS and isinstance(a.payload, list)
              for f in a.payload]
    assert len(frames) == 5


def test_a_gps_is_reopened_by_its_udev_name_not_its_old_node(tmp_path: Path, ptys: list[Pty],
                                                              monkeypatch: pytest.MonkeyPatch
                                                              ) -> None:
    """A USB hub reset: the GPS adapter comes back under a new node, and its old one is given
    to another device. It is found by its by-id name; the old node is not even opened."""
    from acquisition import proof

    by_id = tmp_path / "by-id"
    by_id.mkdir()
    monkeypatch.setattr(proof, "SERIAL_LINK_DIRS", (str(by_id),))
    first = Pty()
    ptys.append(first)
    link = by_id / "usb-u-blox_GNSS_receiver-if00"
    link.symlink_to(first.name)
    sources = LiveSources(first.name, None, None, None)
    try:
        first.write(_nmea_epoch())
        got = _collect(sources, 0.3)
        first.close()  # the hub reset
        got += _collect(sources, 0.1)
        other = Pty(first.name, raw=False)  # its old node, now another program's
        ptys.append(other)
        again = Pty()  # the GPS, under a new node
        ptys.append(again)
        link.unlink()
        link.symlink_to(again.name)
        for _ in range(10):
            again.write(_nmea_epoch())
            other.write(TYPED)
            got += _collect(sources, 0.1)
    finally:
        sources.close()
    assert [e.state for e in _events(got, Source.GPS)] == [LinkState.LOST, LinkState.RESTORED]
    data = b"".join(a.payload for a in got if isinstance(a.payload, bytes))
    assert b"secret" not in data
    assert data.count(b"$GPRMC") >= 8
