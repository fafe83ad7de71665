"""Messages of one or several protocols interleaved on one byte stream, cut anywhere: a receiver
that sends NMEA sentences and binary frames on one port.

Each protocol is a `Framer`: it names the bytes that can begin one of its messages, and, shown
the bytes from such a byte on, says whether they hold a whole message (and how long it is), a
damaged one, no message at all, or not enough bytes yet; then it decodes a whole message. One
`StreamDecoder` runs any number of framers over a stream:

- between messages it skips to the next byte that can begin one (CR and LF alone are filler,
  not errors: text protocols end their lines with them);
- a message that does not decode, or is damaged, is dropped, counted under its reason, and the
  search goes on right after the bytes the framer says it spans, so a good message of another
  protocol that follows a damaged one is never swallowed;
- each bad stretch is one error: the bytes after a damaged message up to the next message start
  belong to it when its framer says so (`Cut.run_on`), and so does whatever fails to decode
  inside the length a damaged binary frame claimed or the rest of a damaged line (`Cut.shadow`),
  while a whole message found there is still decoded; a damaged message that ends where another
  protocol's message may begin leaves that message's damage its own (`Cut.yields`);
- it never holds more than the longest message a framer allows, and every byte fed ends up in
  a `Decoded`'s raw, in `stats.bytes_skipped`, or still buffered.

The result does not depend on how the stream was cut into chunks.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from enum import Enum, StrEnum
from typing import Any, Generic, NamedTuple, Protocol, TypeVar

from acquisition.codec import (
    Decoded,
    DecodeStats,
    ErrorKind,
    ErrorPolicy,
    RefusedError,
    report_error,
)
from sisa.core.errors import DecodeError

M = TypeVar("M")
M_co = TypeVar("M_co", covariant=True)

FILLER = b"\r\n"  # tolerated between messages


class StreamRefusal(StrEnum):
    """Reasons the stream itself gives (a framer gives its protocol's own)."""

    JUNK = "junk"  # bytes that are no message of any protocol
    UNFINISHED = "unfinished"  # the stream ended inside a message


class Verdict(Enum):
    MORE = "more"  # not enough bytes to tell
    WHOLE = "whole"  # a whole message of `length` bytes, to decode
    DAMAGED = "damaged"  # a message start whose first `length` bytes are refused
    NOT_A_START = "not_a_start"  # the byte looked like a start but is none: junk


class Cut(NamedTuple):
    """A framer's verdict on the bytes from a message-start byte on (a tuple: a stream of
    garbage makes one per byte, and a frozen dataclass cost twice as much to build)."""

    verdict: Verdict
    length: int = 0
    reason: str = ""  # DAMAGED: what it is counted under
    detail: str = ""  # DAMAGED: for the error message
    kind: ErrorKind = ErrorKind.FRAMING
    run_on: bool = False  # DAMAGED: the bytes after it, up to the next start, are this error
    shadow: int = 0  # DAMAGED: bytes (from the start) inside which failures are this error
    # DAMAGED with a shadow: if the byte it ends at can begin another protocol's message, the
    # shadow ends there (that message's own damage is its own error); junk after it is still
    # this error
    yields: bool = False


MORE = Cut(Verdict.MORE)
_CR, _LF = 0x0D, 0x0A


def cut_at_line_end(buffer: bytearray, start: int, at_end: bool, stop: re.Pattern[bytes],
                    max_bytes: int, too_long: str) -> Cut | int:
    """The verdict on a text message (an NMEA sentence, a NovAtel ASCII log) from
    buffer[start] to the first byte `stop` finds after it: WHOLE up to its line end (LF, CR LF,
    or a CR not followed by LF), MORE while the line may still come, DAMAGED (`too_long`) with
    no line end within `max_bytes`; a stop byte that is no line end is returned as its index,
    for the protocol to judge (a new message start, a byte no message holds)."""
    window_end = min(len(buffer), start + max_bytes)
    found = stop.search(buffer, start + 1, window_end)
    if found is None:
        if window_end - start >= max_bytes:
            return Cut(Verdict.DAMAGED, max_bytes, too_long,
                       f"no line end within {max_bytes} bytes", run_on=True)
        return MORE
    at = found.start()
    byte = buffer[at]
    if byte == _LF:
        return Cut(Verdict.WHOLE, at + 1 - start)
    if byte == _CR:
        if at + 1 < len(buffer):
            return Cut(Verdict.WHOLE, at + (2 if buffer[at + 1] == _LF else 1) - start)
        if at_end or at + 1 - start >= max_bytes:
            return Cut(Verdict.WHOLE, at + 1 - start)  # an LF after it is filler
        return MORE  # an LF may follow
    return at


def cut_at_sync(buffer: bytearray, start: int, sync: bytes) -> Cut | None:
    """The verdict on a binary message's two sync bytes, buffer[start] being sync[0]: MORE
    while the second has not come, NOT_A_START when it is not sync[1]; None when both hold,
    for the protocol to go on (a UBX frame, a camera photo message)."""
    if len(buffer) - start < 2:
        return MORE
    if buffer[start + 1] != sync[1]:
        return Cut(Verdict.NOT_A_START, 1)
    return None


# members as module names: an Enum class's attribute lookup is slow enough to show in a loop
# that runs once per byte of garbage
_MORE, _WHOLE, _DAMAGED = Verdict.MORE, Verdict.WHOLE, Verdict.DAMAGED


class Framer(Protocol[M_co]):
    """One protocol's messages on a stream."""

    @property
    def name(self) -> str: ...

    @property
    def leads(self) -> bytes:
        """The bytes a message can begin with."""
        ...

    @property
    def max_message_bytes(self) -> int:
        """The longest message it waits for (a cap on what garbage can make the stream hold)."""
        ...

    def cut(self, buffer: bytearray, start: int, at_end: bool) -> Cut:
        """The verdict on buffer[start:] (buffer[start] is one of `leads`); `at_end`: no more
        bytes will come. MORE only while fewer than max_message_bytes are there."""
        ...

    def decode(self, raw: bytes) -> M_co:
        """A whole message; raises DecodeError (a `RefusedError` names its reason)."""
        ...

    def kind(self, message: Any) -> str:
        """The name a decoded message is counted under in `DecodeStats.by_kind`."""
        ...


class StreamDecoder(Generic[M]):
    """Messages from a byte stream cut anywhere, for the framers given (see the module)."""

    def __init__(self, framers: Sequence[Framer[M]],
                 policy: ErrorPolicy = ErrorPolicy.COUNT, *, filler: bytes = FILLER) -> None:
        """`filler`: bytes tolerated between messages (CR and LF, where a text protocol may
        run; none on a port that carries only binary messages)."""
        self.policy = policy
        self._filler = filler
        self.stats = DecodeStats()
        self._by_lead = {lead: framer for framer in framers for lead in framer.leads}
        if len(self._by_lead) != sum(len(framer.leads) for framer in framers):
            raise ValueError("two framers claim the same lead byte")
        self._next_lead = re.compile(b"[" + b"".join(re.escape(bytes([b])) for b in
                                                     sorted(self._by_lead)) + b"]")
        self._label = "+".join(framer.name for framer in framers)
        self._buffer = bytearray()
        self._pos = 0  # next unread byte of _buffer
        self._base = 0  # stream offset of _buffer[0]
        self._in_bad_run = False  # the bytes being skipped were already counted as an error
        self._quiet_until = 0  # stream offset: failures before it belong to a counted error
        self._at_end = False

    @property
    def buffered_bytes(self) -> int:
        return len(self._buffer) - self._pos

    def feed(self, data: bytes) -> list[Decoded[M]]:
        """Messages completed by `data`. Under RAISE, raises DecodeError (offset = stream offset
        of the bad bytes) after dropping them, so feeding may go on."""
        self._buffer += data
        out: list[Decoded[M]] = []
        try:
            self._run(out)
        finally:
            self._compact()
        return out

    def finish(self) -> list[Decoded[M]]:
        """End of stream: messages that needed no more bytes than there are, then whatever is
        still buffered is one error (a message cut short by the end)."""
        self._at_end = True
        try:
            out = self.feed(b"")
            if self.buffered_bytes:
                self._reject(Cut(Verdict.DAMAGED, self.buffered_bytes, StreamRefusal.UNFINISHED,
                                 "stream ended inside a message"))
        finally:
            self._at_end = False
            self._compact()
        return out

    def _run(self, out: list[Decoded[M]]) -> None:
        """Decode, skip and reject until the buffer holds only the start of a message (one
        loop, not a call per step: a stream of garbage makes a step per byte)."""
        buffer, by_lead = self._buffer, self._by_lead
        while self._pos < len(buffer):
            framer = by_lead.get(buffer[self._pos])
            if framer is None:
                self._skip_junk(0)
                continue
            cut = framer.cut(buffer, self._pos, self._at_end)
            verdict = cut.verdict
            if verdict is _MORE:
                return
            if verdict is _WHOLE:
                self._accept(framer, cut.length, out)
            elif verdict is _DAMAGED:
                self._reject(cut)
            else:
                self._skip_junk(max(cut.length, 1))

    def _skip_junk(self, at_least: int) -> None:
        """Skip to the next byte that can begin a message (past the first `at_least` bytes)."""
        found = self._next_lead.search(self._buffer, self._pos + at_least)
        end = len(self._buffer) if found is None else found.start()
        quiet_end = self._quiet_until - self._base
        if self._pos < quiet_end:  # the rest of a damaged message, already counted
            end = min(end, quiet_end)
            self.stats.bytes_skipped += end - self._pos
            self._pos = end
            return
        junk = bytes(self._buffer[self._pos:end])
        offset = self._base + self._pos
        self._pos = end
        self.stats.bytes_skipped += len(junk)
        has_junk = bool(junk.strip(self._filler)) if self._filler else bool(junk)
        already_counted = self._in_bad_run
        self._in_bad_run = already_counted or has_junk
        if has_junk and not already_counted:
            self._error(ErrorKind.FRAMING, StreamRefusal.JUNK, "bytes outside a message",
                        offset, junk)

    def _accept(self, framer: Framer[M], length: int, out: list[Decoded[M]]) -> None:
        offset = self._base + self._pos
        raw = bytes(self._buffer[self._pos:self._pos + length])
        self._pos += length
        self._in_bad_run = False
        try:
            message = framer.decode(raw)
        except RefusedError as err:
            self._refuse(offset, raw, err.kind, err.reason, str(err))
            return
        except DecodeError as err:
            self._refuse(offset, raw, ErrorKind.FRAMING, f"{framer.name}.malformed", str(err))
            return
        self.stats.count_message(framer.kind(message))
        out.append(Decoded(raw, message))

    def _refuse(self, offset: int, raw: bytes, kind: ErrorKind, reason: str, detail: str
                ) -> None:
        """A whole message its decoder refused is one error, and then treated as a damaged
        one: only its first byte is passed, and its bytes are looked at again under its
        shadow, so a good message that began inside it is still decoded (a checksum can pass
        by chance over a damaged frame and the start of the next: 1 in 65 536 for UBX's, and
        the next was lost); the rest of it is this error."""
        try:
            self._error(kind, reason, detail, offset, raw)
        finally:
            self._pos = offset - self._base + 1
            self.stats.bytes_skipped += 1
            self._quiet_until = max(self._quiet_until, offset + len(raw))

    def _reject(self, cut: Cut) -> None:
        offset = self._base + self._pos
        raw = bytes(self._buffer[self._pos:self._pos + cut.length])
        self._pos += cut.length
        self.stats.bytes_skipped += cut.length
        shadow, run_on = cut.shadow, cut.run_on
        at_a_start = self._pos < len(self._buffer) and self._buffer[self._pos] in self._by_lead
        if cut.yields and at_a_start:
            shadow, run_on = 0, True
        self._in_bad_run = run_on
        quiet = offset < self._quiet_until  # inside a damaged frame already counted
        if shadow:
            self._quiet_until = max(self._quiet_until, offset + shadow)
        if not quiet:
            report_error(self.policy, self.stats, cut.kind, f"{self._label}: {cut.detail}",
                         offset, raw, reason=cut.reason)

    def _error(self, kind: ErrorKind, reason: str, detail: str, offset: int,
               raw: bytes) -> None:
        if offset < self._quiet_until:
            return  # inside a damaged frame already counted
        report_error(self.policy, self.stats, kind, f"{self._label}: {detail}", offset, raw,
                     reason=reason)

    def _compact(self) -> None:
        del self._buffer[:self._pos]
        self._base += self._pos
        self._pos = 0
