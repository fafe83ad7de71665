"""Sentences from a byte stream cut anywhere."""

from __future__ import annotations

from acquisition.codec import Decoded, DecodeStats, ErrorPolicy, report_error
from acquisition.nmea.codec import (
    _LINE_BREAK_BYTES,
    LINE_FEED,
    MAX_SENTENCE_BYTES,
    SENTENCE_START,
    ChecksumError,
    ErrorKind,
    decode_sentence,
)
from acquisition.nmea.sentences import NmeaMessage, message_kind
from sisa.errors import DecodeError

# ---------------------------------------------------------------------------------------------
# Streaming decoder.


class NmeaStreamDecoder:
    """Sentences from a byte stream cut anywhere: resynchronises on `$`, never holds more than
    one sentence's worth of bytes, and counts what it drops (exactly once per bad stretch).

    A run of bytes outside sentences is one framing error (CR/LF alone are tolerated); so is a
    sentence cut short by a new `$`, one with no line end within MAX_SENTENCE_BYTES, and one that
    does not decode. Every byte fed ends up in a Decoded's raw, in `stats.bytes_skipped`, or
    still buffered.
    """

    def __init__(self, policy: ErrorPolicy = ErrorPolicy.COUNT) -> None:
        self.policy = policy
        self.stats = DecodeStats()
        self._buffer = bytearray()
        self._pos = 0  # next unread byte of _buffer
        self._base = 0  # stream offset of _buffer[0]
        self._in_bad_run = False  # the bytes being skipped were already counted as an error

    @property
    def buffered_bytes(self) -> int:
        return len(self._buffer) - self._pos

    def feed(self, data: bytes) -> list[Decoded[NmeaMessage]]:
        """Decoded sentences completed by `data`. Under RAISE, raises DecodeError (offset = stream
        offset of the bad bytes) after dropping them, so feeding may go on."""
        self._buffer += data
        out: list[Decoded[NmeaMessage]] = []
        try:
            while self._step(out):
                pass
        finally:
            self._compact()
        return out

    def finish(self) -> None:
        """End of stream: an unfinished sentence still buffered is a truncation error."""
        if self.buffered_bytes:
            self._reject(self.buffered_bytes, "stream ended inside a sentence")
            self._compact()

    def _step(self, out: list[Decoded[NmeaMessage]]) -> bool:
        if self._pos >= len(self._buffer):
            return False
        if self._buffer[self._pos] != SENTENCE_START:
            self._skip_to_start()
            return True
        self._in_bad_run = False  # a '$' ends any run of bad bytes
        return self._take_sentence(out)

    def _skip_to_start(self) -> None:
        start = self._buffer.find(SENTENCE_START, self._pos)
        end = len(self._buffer) if start < 0 else start
        junk = bytes(self._buffer[self._pos:end])
        offset = self._base + self._pos
        self._pos = end
        self.stats.bytes_skipped += len(junk)
        has_junk = bool(junk.strip(_LINE_BREAK_BYTES))  # CR/LF alone are tolerated
        already_counted = self._in_bad_run
        self._in_bad_run = already_counted or has_junk
        if has_junk and not already_counted:
            self._error(ErrorKind.FRAMING, "bytes outside a sentence", offset, junk)

    def _take_sentence(self, out: list[Decoded[NmeaMessage]]) -> bool:
        window_end = min(len(self._buffer), self._pos + MAX_SENTENCE_BYTES)
        line_end = self._buffer.find(LINE_FEED, self._pos, window_end)
        restart = self._buffer.find(SENTENCE_START, self._pos + 1, window_end)
        if restart >= 0 and (line_end < 0 or restart < line_end):
            self._reject(restart - self._pos, "sentence cut short by a new '$'")
        elif line_end >= 0:
            self._accept(line_end + 1 - self._pos, out)
        elif window_end - self._pos >= MAX_SENTENCE_BYTES:
            self._in_bad_run = True  # the rest of the line up to the next '$' is this error
            self._reject(MAX_SENTENCE_BYTES, f"no line end within {MAX_SENTENCE_BYTES} bytes")
        else:
            return False  # wait for more bytes
        return True

    def _accept(self, length: int, out: list[Decoded[NmeaMessage]]) -> None:
        offset = self._base + self._pos
        raw = bytes(self._buffer[self._pos:self._pos + length])
        self._pos += length
        try:
            message = decode_sentence(raw)
        except DecodeError as err:
            self.stats.bytes_skipped += length
            kind = ErrorKind.CHECKSUM if isinstance(err, ChecksumError) else ErrorKind.FRAMING
            self._error(kind, str(err), offset, raw)
            return
        self.stats.count_message(message_kind(message).value)
        out.append(Decoded(raw, message))

    def _reject(self, length: int, reason: str) -> None:
        offset = self._base + self._pos
        raw = bytes(self._buffer[self._pos:self._pos + length])
        self._pos += length
        self.stats.bytes_skipped += length
        self._error(ErrorKind.FRAMING, reason, offset, raw)

    def _error(self, kind: ErrorKind, reason: str, offset: int, raw: bytes) -> None:
        report_error(self.policy, self.stats, kind.value, f"NMEA: {reason}", offset, raw)

    def _compact(self) -> None:
        del self._buffer[:self._pos]
        self._base += self._pos
        self._pos = 0
