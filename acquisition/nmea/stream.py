"""Sentences from a byte stream cut anywhere, alone or interleaved with a binary protocol.

`NmeaFramer` tells the generic `acquisition.framing.StreamDecoder` where a sentence ends: at
its line end (LF, CRLF, or a CR not followed by LF). A `$` before the line end cuts the
sentence short (a new sentence starts there); so does any byte that no sentence can hold (a
control or non-ASCII byte: the start of a binary frame, or line noise), and the rest of that
line is the same error. The sentence's bytes end at that byte, so a binary frame right after a
damaged sentence is never swallowed with it.
"""

from __future__ import annotations

import re
from typing import Any

from acquisition.codec import ErrorPolicy
from acquisition.framing import MORE, Cut, StreamDecoder, Verdict, cut_at_line_end
from acquisition.nmea.codec import MAX_SENTENCE_BYTES, SENTENCE_START, decode_sentence
from acquisition.nmea.sentences import NmeaMessage, message_kind
from acquisition.nmea.tables import Refusal

CR, LF = b"\r"[0], b"\n"[0]
# a byte that cannot be inside a sentence: a line end, a '$', a control or non-ASCII byte
_SENTENCE_STOP = re.compile(rb"[^\x20-\x23\x25-\x7e]")
_LINE_END_OR_START = re.compile(rb"[\n$]")
_WHOLE, _DAMAGED, _CUT_SHORT = Verdict.WHOLE, Verdict.DAMAGED, Refusal.CUT_SHORT  # per byte


class NmeaFramer:
    """NMEA 0183 sentences (`$...*hh` + line end) on a stream."""

    name = "nmea"
    leads = bytes([SENTENCE_START])
    max_message_bytes = MAX_SENTENCE_BYTES

    def __init__(self, *, accept_missing_checksum: bool = False,
                 other_starts: bytes = b"") -> None:
        """`other_starts`: printable bytes that begin another text protocol's message on the
        same stream (NovAtel's `#`): such a byte cuts a sentence short as a `$` does."""
        self.accept_missing_checksum = accept_missing_checksum
        self._starts = bytes([SENTENCE_START]) + other_starts
        self._stop = _SENTENCE_STOP if not other_starts else re.compile(
            rb"[^\x20-\x7e]|[" + re.escape(self._starts) + rb"]")

    def cut(self, buffer: bytearray, start: int, at_end: bool) -> Cut:
        at = cut_at_line_end(buffer, start, at_end, self._stop, MAX_SENTENCE_BYTES,
                             Refusal.TOO_LONG)
        if isinstance(at, Cut):
            return at
        byte = buffer[at]
        window_end = min(len(buffer), start + MAX_SENTENCE_BYTES)
        if byte in self._starts:
            return Cut(_DAMAGED, at - start, _CUT_SHORT,
                       f"sentence cut short by a new {chr(byte)!r}")
        return self._cut_by_byte(buffer, start, at, window_end, at_end)

    @staticmethod
    def _cut_by_byte(buffer: bytearray, start: int, at: int, window_end: int,
                     at_end: bool) -> Cut:
        """A byte no sentence holds, at `at`: the sentence is refused up to it, and the rest
        of its line (to its line end, or to a new '$') is the same error, though a message
        of another protocol found in it is still decoded."""
        detail = f"sentence cut short by byte 0x{buffer[at]:02X}"
        end = _LINE_END_OR_START.search(buffer, at + 1, window_end)
        if end is None:
            if window_end - start < MAX_SENTENCE_BYTES and not at_end:
                return MORE  # the rest of the line is not here yet
            return Cut(Verdict.DAMAGED, at - start, Refusal.CUT_SHORT, detail, run_on=True)
        rest = end.start() + (buffer[end.start()] == LF) - start
        return Cut(Verdict.DAMAGED, at - start, Refusal.CUT_SHORT, detail, shadow=rest,
                   yields=True)

    def decode(self, raw: bytes) -> NmeaMessage:
        return decode_sentence(raw, accept_missing_checksum=self.accept_missing_checksum)

    def kind(self, message: Any) -> str:
        return message_kind(message).value


class NmeaStreamDecoder(StreamDecoder[NmeaMessage]):
    """Sentences from a byte stream cut anywhere: resynchronises on `$`, never holds more than
    one sentence's worth of bytes, and counts what it drops (exactly once per bad stretch, and
    by reason in `stats.refused`).

    A run of bytes outside sentences is one framing error (CR/LF alone are tolerated); so is a
    sentence cut short by a new `$` or by a byte no sentence holds, one with no line end within
    MAX_SENTENCE_BYTES, and one that does not decode. A sentence without checksum is refused
    unless `accept_missing_checksum`. Every byte fed ends up in a Decoded's raw, in
    `stats.bytes_skipped`, or still buffered.
    """

    def __init__(self, policy: ErrorPolicy = ErrorPolicy.COUNT, *,
                 accept_missing_checksum: bool = False) -> None:
        super().__init__([NmeaFramer(accept_missing_checksum=accept_missing_checksum)], policy)
