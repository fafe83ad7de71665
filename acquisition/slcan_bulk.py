"""python-can's SLCAN bus, reading in bulk.

The stock `slcanBus._read` asks the serial port for one byte at a time; at an INS's ~450 frames/s
that is ~13 000 reads a second, most of the recorder's CPU. This subclass reads what is waiting
and splits replies at their terminators, and `recv_ready` hands over every frame that has
arrived for a caller that waits on `fileno()` itself. `recv_ready` parses the classic frame
lines (`t`, `T`, `r`, `R`: what an INS sends) itself, one pass over the burst instead of
python-can's per-frame `recv` (the recorder's largest per-frame cost after the read clock), and
counts and skips a line that does not parse (python-can raises on it, which would look like a
lost adapter) or that it does not take (CAN FD lines); replies to commands (an empty OK, `z`/`Z`
transmit acknowledgements, BEL errors) are not frames and are passed over, as many as lines
were written to the adapter; a reply to no command (a flood of bare terminators) is counted
like a garbled line. Opening, commands and sending are python-can's own.
"""

from __future__ import annotations

import binascii
import os
import re
import time

import can
import serial
from can import CanOperationError
from can.interfaces.slcan import slcanBus

_OK, _ERROR = slcanBus._OK[0], slcanBus._ERROR[0]
_TERMINATOR = re.compile(rb"[\r\a]")
_ID_DIGITS = {ord("t"): 3, ord("r"): 3, ord("T"): 8, ord("R"): 8}  # classic frame lines
_REPLIES = frozenset((b"", b"z", b"Z"))  # OK, transmit acknowledgements: not frames
# the longest SLCAN line is ~30 bytes (T, 8 id digits, length, 16 data digits, a timestamp):
# bytes this many past the last terminator are no line (an adapter sending garbage, a wrong
# baud rate): dropped and counted, or the buffer grew with every read
PENDING_MAX = 4096


def parse_frame_line(line: bytes) -> can.Message | None:
    """One SLCAN line without its terminator: a classic frame, None for a reply to a command;
    ValueError for anything else (a garbled or unsupported line). An adapter timestamp after
    the data (4 hex digits) is ignored, as python-can does."""
    if line in _REPLIES:
        return None
    digits = _ID_DIGITS.get(line[0])
    if digits is None:
        raise ValueError(f"not a classic SLCAN frame line: {line[:12]!r}")
    dlc = line[digits + 1] - 48
    if not 0 <= dlc <= 8:
        raise ValueError(f"bad DLC in {line[:12]!r}")
    remote = line[0] in (ord("r"), ord("R"))
    end = digits + 2 + (0 if remote else 2 * dlc)
    if len(line) not in (end, end + 4):
        raise ValueError(f"SLCAN line of {len(line)} characters: {line[:12]!r}")
    return can.Message(timestamp=time.time(), arbitration_id=int(line[1:digits + 1], 16),
                       is_extended_id=digits == 8, is_remote_frame=remote, dlc=dlc,
                       data=None if remote else binascii.unhexlify(line[digits + 2:end]))


def encode_frame_line(arbitration_id: int, is_extended_id: bool, data: bytes) -> bytes:
    """The SLCAN line of a classic data frame, with its terminator (`parse_frame_line`'s
    inverse): what an adapter sends for a frame it received."""
    ident = b"T%08X" % arbitration_id if is_extended_id else b"t%03X" % arbitration_id
    return b"%s%d%s\r" % (ident, len(data), data.hex().upper().encode())


def parse_frame_lines(block: bytes) -> tuple[list[can.Message], list[bytes], list[bytes]]:
    """The lines of `block` (terminated lines, the last terminator left off) as (frames, lines
    that do not parse, other lines: replies or anything else that is no frame)."""
    frames: list[can.Message] = []
    broken: list[bytes] = []
    others: list[bytes] = []
    for line in _TERMINATOR.split(block):
        try:
            msg = parse_frame_line(line)
        except (ValueError, IndexError):  # IndexError: a line cut short
            broken.append(line)
            continue
        if msg is not None:
            frames.append(msg)
        else:
            others.append(line)
    return frames, broken, others


def _reply_end(buffer: bytearray) -> int:
    """Index of the first reply terminator (OK or ERROR), or −1."""
    ends = [i for i in (buffer.find(_OK), buffer.find(_ERROR)) if i >= 0]
    return min(ends) if ends else -1


class BulkSlcanBus(slcanBus):
    garbled = 0  # adapter lines that did not parse (counted and skipped by recv_ready)
    garbled_bytes = 0  # their bytes, and bytes dropped for want of a terminator
    replies_due = 0  # lines written to the adapter (commands, frames sent) not yet answered

    def _write(self, string: str) -> None:
        super()._write(string)
        self.replies_due += 1

    def _answered(self) -> bool:
        """A reply arrived: True if a written line was waiting for it."""
        if self.replies_due <= 0:
            return False
        self.replies_due -= 1
        return True

    def _read(self, timeout: float | None) -> str | None:
        deadline = serial.Timeout(timeout)
        while True:
            end = _reply_end(self._buffer)
            if end >= 0:
                reply = bytes(self._buffer[: end + 1]).decode(errors="replace")
                del self._buffer[: end + 1]
                self._answered()
                return reply
            try:
                waiting = self.serialPortOrig.in_waiting
                if not waiting and deadline.expired():
                    return None  # recv(timeout=0): only what has already arrived
                chunk = self.serialPortOrig.read(max(1, waiting))
            except (serial.SerialException, OSError) as exc:
                raise CanOperationError(f"Could not read from serial device: {exc}") from exc
            self._buffer.extend(chunk)
            if not chunk and deadline.expired():
                return None

    def recv_ready(self) -> list[can.Message]:
        """The frames that have arrived, without waiting; call when `fileno()` is readable (no
        bytes then means the adapter went away)."""
        chunk: bytes | None
        try:
            chunk = os.read(self.fileno(), 65536)
        except BlockingIOError:
            chunk = None  # nothing after all: parse only what the buffer holds
        except OSError as exc:
            raise CanOperationError(f"Could not read from serial device: {exc}") from exc
        if chunk is not None:
            if not chunk:
                raise CanOperationError("the adapter closed (end of file)")
            self._buffer.extend(chunk)
        last = max(self._buffer.rfind(_OK), self._buffer.rfind(_ERROR))
        if last < 0:
            if len(self._buffer) > PENDING_MAX:  # no terminator in all this: no line
                self._drop_pending()
            return []
        frames, broken, others = parse_frame_lines(bytes(self._buffer[:last]))
        del self._buffer[: last + 1]
        if len(self._buffer) > PENDING_MAX:
            self._drop_pending()
        # a reply to nothing the recorder wrote is garbled too; each line with its terminator
        for line in broken + [line for line in others if not self._answered()]:
            self.garbled += 1
            self.garbled_bytes += len(line) + 1
        return frames

    def _drop_pending(self) -> None:
        """Bytes past PENDING_MAX without a terminator: one garbled line, dropped."""
        self.garbled += 1
        self.garbled_bytes += len(self._buffer)
        del self._buffer[:]
