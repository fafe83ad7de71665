"""Binary messages cut as two sync bytes, a length byte, a declared body and a CRC-16/CCITT-FALSE
over the length byte and the body, all little-endian. The scanner's frame header and the frame
camera's photo message are both framed this way; one `CrcMessage` declaration gives a protocol
its encoder, its decoder, its stream framer and the proof that a port carries it.

The CRC covers the length byte as well as the body, so a corrupted length cannot pass, and a
reader takes any other length as damage: a future layout must change the length byte. Every
message of a layout has the same length, so a damaged one (a wrong length byte, a CRC that
fails) is refused as far as its sync, and whatever fails inside the bytes it would have spanned
is the same error; a good message that begins inside them is still decoded. Refusals are counted
under `<protocol>.length`, `.checksum`, `.field_value` (CRC right, a value outside its declared
range) and `.malformed` (bytes that are no such message at all, given to `decode`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from acquisition.checksums import crc16_ccitt_false
from acquisition.codec import ErrorKind, RefusedError
from acquisition.fields import Layout
from acquisition.framing import MORE, Cut, Verdict, cut_at_sync

M = TypeVar("M")

CRC_BYTES = 2


@dataclass(frozen=True)
class CrcMessage:
    """One layout of a sync + length + body + CRC-16 message."""

    protocol: str  # the refusals' prefix and the framer's name ("scanner", "camera")
    sync: bytes  # two bytes
    body: Layout

    @property
    def message_bytes(self) -> int:
        return len(self.sync) + 1 + self.body.size_bytes + CRC_BYTES

    def reason(self, what: str) -> str:
        """The `DecodeStats.refused` key of a refusal ("length", "checksum", ...)."""
        return f"{self.protocol}.{what}"

    def pack(self, values: Mapping[str, Any]) -> bytes:
        """The message's bytes for these body values (EncodeError for one out of range)."""
        checked = bytes([self.body.size_bytes]) + self.body.pack(values)
        return self.sync + checked + crc16_ccitt_false(checked).to_bytes(CRC_BYTES, "little")

    def unpack(self, raw: bytes) -> dict[str, int]:
        """The raw body values of one whole message; RefusedError (naming its reason) if it is
        not a valid one."""
        sync_end = len(self.sync)
        if len(raw) != self.message_bytes or not raw.startswith(self.sync):
            raise RefusedError(self.reason("malformed"), f"not a {self.protocol} message",
                               raw=raw)
        if raw[sync_end] != self.body.size_bytes:
            raise RefusedError(self.reason("length"), f"length {raw[sync_end]} after sync",
                               raw=raw)
        checked = raw[sync_end:-CRC_BYTES]
        if crc16_ccitt_false(checked) != int.from_bytes(raw[-CRC_BYTES:], "little"):
            raise RefusedError(self.reason("checksum"), f"{self.protocol} CRC-16 mismatch",
                               kind=ErrorKind.CHECKSUM, raw=raw)
        raws = self.body.unpack_raw(checked[1:])
        if bad := self.body.out_of_range(raws):
            raise RefusedError(self.reason("field_value"), f"out of range: {', '.join(bad)}",
                               raw=raw)
        return raws

    def cut(self, buffer: bytearray, start: int, at_end: bool) -> Cut:
        """A stream framer's verdict on buffer[start:], where buffer[start] is sync[0] (a message
        still short at the end of the stream is left to the stream's `unfinished`); a value out
        of range is found by `unpack`, on the whole message."""
        if (sync := cut_at_sync(buffer, start, self.sync)) is not None:
            return sync
        have, sync_end, size = len(buffer) - start, len(self.sync), self.message_bytes
        if have < sync_end + 1:
            return MORE
        length = buffer[start + sync_end]
        if length != self.body.size_bytes:
            return Cut(Verdict.DAMAGED, sync_end, self.reason("length"),
                       f"length {length} after sync", shadow=size)
        if have < size:
            return MORE
        checked = bytes(buffer[start + sync_end:start + size - CRC_BYTES])
        crc = int.from_bytes(buffer[start + size - CRC_BYTES:start + size], "little")
        if crc16_ccitt_false(checked) != crc:
            return Cut(Verdict.DAMAGED, sync_end, self.reason("checksum"),
                       f"{self.protocol} CRC-16 mismatch", kind=ErrorKind.CHECKSUM,
                       shadow=size)
        return Cut(Verdict.WHOLE, size)

    def first_valid(self, data: bytes) -> int:
        """Where in `data` the first whole, valid message begins (its CRC holds, its values are
        in range), or -1: how a port proves what it carries before anything is recorded."""
        start = data.find(self.sync)
        while 0 <= start <= len(data) - self.message_bytes:
            try:
                self.unpack(data[start:start + self.message_bytes])
            except RefusedError:
                start = data.find(self.sync, start + 1)
                continue
            return start
        return -1


class CrcFramer(Generic[M]):
    """A `CrcMessage` on a stream (for `acquisition.framing.StreamDecoder`), each whole message
    made into `M` by `build` from its raw body values."""

    def __init__(self, message: CrcMessage, build: Callable[[dict[str, int]], M],
                 kind: str) -> None:
        self.message, self._build, self._kind = message, build, kind
        self.name = message.protocol
        self.leads = message.sync[:1]
        self.max_message_bytes = message.message_bytes

    def cut(self, buffer: bytearray, start: int, at_end: bool) -> Cut:
        return self.message.cut(buffer, start, at_end)

    def decode(self, raw: bytes) -> M:
        return self._build(self.message.unpack(raw))

    def kind(self, message: Any) -> str:
        return self._kind
