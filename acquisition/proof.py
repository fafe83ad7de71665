"""Is the device behind a port the one we recorded before? What a reconnecting reader asks of a
port before anything it sends is recorded as that device's data, or anything is written to it.

A device path alone proves nothing: a pty number freed by an emulator that ended is given by
the kernel to the next program that asks for one (a terminal, an ssh session), and a USB serial
adapter replugged after a hub reset may come back under another `ttyUSBn` while another one
takes its old name. So a reconnecting reader
- reopens a serial device through its stable udev name when it has one (`stable_serial_path`:
  `/dev/serial/by-id/...`, the adapter's USB serial number; else `/dev/serial/by-path/...`, the
  USB port), and
- whatever the path, holds the port *on probation* (`ProbePort`): it reads, records nothing,
  writes nothing and leaves a pty's settings alone, until the device speaks its protocol
  (`StreamProof`: one whole message whose checksum holds: an NMEA sentence, a UBX frame or a
  NovAtel ASCII log for the GPS, a frame header with its CRC for the scanner; `SlcanProof` for
  a CAN adapter, below). A port that sends something else is given up (`Verdict.rejected`,
  said why) and that device node (`DeviceInstance`) is never opened again: a replugged
  device, or a pty allocated afresh, is a new node. A silent port stays on probation (a
  scanner that is idle sends no header until it records).

What probation cannot avoid: while it listens, what the other program's user types is read by
the recorder instead of by that program (it is neither recorded nor shown), for at most
`PROOF_S` after the first byte, once per node.

SLCAN: an adapter that is already open proves itself passively, by its frame lines (two whole
ones). One that is closed (every adapter after a power-up or a replug) sends nothing until it is
told `O`, so after `SLCAN_LISTEN_S` of listening it is asked the one question every SLCAN
adapter answers and that changes nothing, the version query `V\\r`, and must answer
`V` + 4 characters within `SLCAN_REPLY_S`; only then is the channel opened (`O\\r`). A port that
sent anything that is no SLCAN frame or reply is given up without a byte written to it; a
silent port is written `V\\r` once, and never again if it does not answer.
"""

from __future__ import annotations

import os
import re
import stat
import termios
import tty
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import NamedTuple, Protocol

from acquisition.camera_photo import first_photo_message
from acquisition.nmea import first_checked_sentence
from acquisition.novatel import first_novatel_log
from acquisition.scanner_header import first_header
from acquisition.slcan_bulk import parse_frame_line
from acquisition.ubx import first_ubx_frame

PROOF_BYTES = 2048  # a serial device sends a whole message in this many bytes, or is not it
PROOF_S = 3.0  # ... or within this long of its first byte (a GPS at 1 Hz: one second)
SLCAN_LISTEN_S = 0.5  # an open adapter's frames are awaited this long before it is asked
SLCAN_REPLY_S = 1.0  # its answer to `V\r`
SLCAN_FRAMES = 2  # whole frame lines that prove an open adapter
SLCAN_LINE_MAX = 64  # bytes without a terminator: no SLCAN line (the longest is ~30)
VERSION_QUERY = b"V\r"
_VERSION_REPLY = re.compile(rb"V[0-9A-Za-z]{4}")
_TERMINATOR = re.compile(rb"[\r\n\a]")  # a line feed ends a line, and no SLCAN one
SERIAL_LINK_DIRS = ("/dev/serial/by-id", "/dev/serial/by-path")


class DeviceInstance(NamedTuple):
    """One device node as the kernel made it: a pty number given to another program, or a
    USB adapter's node made again on a replug, is another instance (a new change time)."""

    rdev: int
    ino: int
    ctime_ns: int


def device_instance(path: str | None = None, fd: int | None = None) -> DeviceInstance | None:
    """The instance behind a path (followed) or an open descriptor; None if there is none."""
    try:
        st = os.fstat(fd) if fd is not None else os.stat(path or "")
    except OSError:
        return None
    return DeviceInstance(st.st_rdev, st.st_ino, st.st_ctime_ns)


PTY_SLAVE_MAJORS = range(136, 144)  # Linux: Unix98 pty slaves (/dev/pts/N)
BAUD = termios.B115200  # what the recorder opens serial ports at


class ProbePort:
    """A device node opened on probation: read without being taken over. Nothing is written
    but what `write` is given (counted in `written`). A pty's settings are left as they are
    (they belong to whoever holds its other side: making it raw would turn off a terminal's
    echo); any other tty is set raw at the recorder's baud rate, or what it sends could not be
    judged. `instance`: the node it opened."""

    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        self.written = b""
        try:
            st = os.fstat(self.fd)
            self.instance = DeviceInstance(st.st_rdev, st.st_ino, st.st_ctime_ns)
            if not stat.S_ISCHR(st.st_mode):
                raise OSError(f"{path} is not a device")
            if os.major(st.st_rdev) not in PTY_SLAVE_MAJORS and os.isatty(self.fd):
                tty.setraw(self.fd)
                attrs = termios.tcgetattr(self.fd)
                attrs[4] = attrs[5] = BAUD
                termios.tcsetattr(self.fd, termios.TCSANOW, attrs)
        except OSError:
            os.close(self.fd)
            raise
        except termios.error as exc:
            os.close(self.fd)
            raise OSError(f"{path}: {exc}") from None

    def fileno(self) -> int:
        return self.fd

    def read(self) -> bytes:
        """What has arrived (b"" if nothing); OSError if the device is gone (EOF too)."""
        try:
            data = os.read(self.fd, 65536)
        except BlockingIOError:
            return b""
        if not data:
            raise OSError("end of file (the device closed)")
        return data

    def write(self, data: bytes) -> None:
        self.written += data
        os.write(self.fd, data)

    def close(self) -> None:
        os.close(self.fd)


def stable_serial_path(port: str, link_dirs: Iterable[str] | None = None) -> str:
    """The udev name of the serial device `port` is, by-id first (the adapter's own serial
    number), then by-path (its USB port); `port` itself if it is one already, or has none (a
    pty, a built-in UART)."""
    link_dirs = SERIAL_LINK_DIRS if link_dirs is None else tuple(link_dirs)
    if any(os.path.dirname(os.path.abspath(port)) == d for d in link_dirs):
        return port
    try:
        target = os.path.realpath(port)
        if not stat.S_ISCHR(os.stat(target).st_mode):
            return port
    except OSError:
        return port
    for folder in link_dirs:
        try:
            names = sorted(os.listdir(folder))
        except OSError:
            continue
        for name in names:
            link = os.path.join(folder, name)
            if os.path.realpath(link) == target:
                return link
    return port


@dataclass(frozen=True)
class Verdict:
    """What a probation came to so far: `proven` (then `data`: what the device sent from its
    first whole message on, its own data), `rejected` (why it is not the device), or neither;
    and `write`: bytes to send the device now (the SLCAN version query)."""

    proven: bool = False
    data: bytes = b""
    rejected: str = ""
    write: bytes = b""


PENDING = Verdict()


class Prover(Protocol):
    def feed(self, data: bytes, now_s: float) -> Verdict: ...

    def tick(self, now_s: float) -> Verdict: ...


class StreamProof:
    """A serial device proves itself by one whole message found by `find` (an index, or −1) in
    what it sends: `what` names it in a rejection. Nothing it sends is ever shown."""

    def __init__(self, find: Callable[[bytes], int], what: str) -> None:
        self.find, self.what = find, what
        self._held = bytearray()
        self._first_byte_s: float | None = None

    def feed(self, data: bytes, now_s: float) -> Verdict:
        if data and self._first_byte_s is None:
            self._first_byte_s = now_s
        self._held += data
        start = self.find(bytes(self._held))
        if start >= 0:
            return Verdict(proven=True, data=bytes(self._held[start:]))
        if len(self._held) > PROOF_BYTES:
            return Verdict(rejected=f"it sent {len(self._held)} bytes without {self.what}")
        return self.tick(now_s)

    def tick(self, now_s: float) -> Verdict:
        if self._first_byte_s is not None and now_s - self._first_byte_s > PROOF_S:
            return Verdict(rejected=f"it sent {len(self._held)} bytes in {PROOF_S:g} s "
                                    f"without {self.what}")
        return PENDING



def first_gps_message(data: bytes) -> int:
    """The first whole NMEA sentence, UBX frame or NovAtel ASCII log whose checksum holds,
    or −1."""
    found = [i for i in (first_checked_sentence(data), first_ubx_frame(data),
                         first_novatel_log(data)) if i >= 0]
    return min(found, default=-1)


def gps_proof() -> StreamProof:
    return StreamProof(first_gps_message, "one NMEA sentence, UBX frame or NovAtel log whose "
                       "checksum holds")


def scanner_proof() -> StreamProof:
    return StreamProof(first_header, "one frame header whose CRC holds")


def camera_proof() -> StreamProof:
    return StreamProof(first_photo_message, "one photo message whose CRC holds")


class SlcanProof:
    """A CAN adapter on a serial port proves itself by its frame lines (it is open) or by its
    answer to the version query (module docstring); anything else rejects it unwritten to."""

    def __init__(self, now_s: float, listen_s: float = SLCAN_LISTEN_S) -> None:
        self.opened_s, self.listen_s = now_s, listen_s
        self.asked_s: float | None = None
        self.frames = 0
        self._pending = bytearray()

    def feed(self, data: bytes, now_s: float) -> Verdict:
        self._pending += data
        *lines, rest = _TERMINATOR.split(bytes(self._pending))
        self._pending[:] = rest
        for line in lines:
            if self.asked_s is not None and _VERSION_REPLY.fullmatch(line):
                return Verdict(proven=True)
            try:
                frame = parse_frame_line(line)
            except (ValueError, IndexError):
                frame = None
            if frame is None:  # a reply to nothing written, or no SLCAN line at all
                return Verdict(rejected="it sent a line that is no SLCAN frame"
                               + (" nor an answer to the version query" if self.asked_s
                                  is not None else ""))
            self.frames += 1
            if self.frames >= SLCAN_FRAMES:
                return Verdict(proven=True)
        if len(self._pending) > SLCAN_LINE_MAX:
            return Verdict(rejected=f"it sent {len(self._pending)} bytes without a line end: "
                                    "no SLCAN line")
        return self.tick(now_s)

    def tick(self, now_s: float) -> Verdict:
        if self.asked_s is None:
            if now_s - self.opened_s >= self.listen_s:
                self.asked_s = now_s
                return Verdict(write=VERSION_QUERY)
            return PENDING
        if now_s - self.asked_s > SLCAN_REPLY_S:
            return Verdict(rejected=f"it did not answer the version query V within "
                                    f"{SLCAN_REPLY_S:g} s")
        return PENDING
