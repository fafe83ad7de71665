"""Pulse lines as timestamped edge messages (an emulated timing board).

A pty has no modem lines, so between processes a pulse travels as a message that carries the
time of its rising edge on the emulation's own timeline. A receiver acts on the edge's timestamp,
not on its arrival; an edge that arrives after its deadline is a fault that must be counted.

Wire format of one edge (little-endian, 20 bytes):

| offset | type | field                                         |
|--------|------|-----------------------------------------------|
| 0      | 2 B  | magic 0x50 0x4C ("PL")                         |
| 2      | u8   | line (PulseLine)                              |
| 3      | u8   | flags (reserved, 0)                           |
| 4      | u32  | sequence number per line (wraps)              |
| 8      | i64  | edge time, ns on the emulation timeline       |
| 16     | u16  | reserved, 0                                   |
| 18     | u16  | CRC-16/CCITT-FALSE of bytes 0..17             |
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

from acquisition.checksums import crc16_ccitt_false
from acquisition.codec import Decoded, DecodeStats, ErrorPolicy, report_error

EDGE_MAGIC = b"PL"
_EDGE = struct.Struct("<2sBBIqH")
EDGE_SIZE = _EDGE.size + 2


class PulseLine(IntEnum):
    """Every pulse line of the system; outputs of devices and outputs of the sync unit."""

    PPS = 1  # GPS receiver → SISA
    PPF = 2  # scanner pulse per frame (mid-exposure) → SISA
    INS_SYNC = 3  # SISA → INS sync input
    GPS_EVENT = 4  # SISA → GPS event input
    CAMERA = 5  # frame camera mid-exposure pulse → SISA (issue 37)


@dataclass(frozen=True, slots=True)
class Edge:
    line: PulseLine
    seq: int
    t_ns: int


def encode_edge(edge: Edge) -> bytes:
    body = _EDGE.pack(EDGE_MAGIC, int(edge.line), 0, edge.seq & 0xFFFFFFFF, edge.t_ns, 0)
    return body + struct.pack("<H", crc16_ccitt_false(body))


# An edge time farther than this from the timeline's zero (~127 years either side of the GPS
# epoch) is no time a timing board gives: the board counts from its first edge and the log holds
# 64-bit ns, and a forward adds its delay to an input edge's time, so an edge near either end of
# int64 overflowed both (an unreadable /pulses/in, a recorder ended by the forward's encoding).
# The acquisition counts such an edge as a framing error of the link and drops it.
EDGE_TIME_LIMIT_NS = 4 * 10**18


class EdgeStreamDecoder:
    """Edges from a byte stream (a socket), resynchronising on the magic after bad bytes.
    `stats`: counters to add to (a link's, kept over its reconnections), else new ones."""

    def __init__(self, policy: ErrorPolicy = ErrorPolicy.COUNT,
                 stats: DecodeStats | None = None) -> None:
        self.policy = policy
        self.stats = DecodeStats() if stats is None else stats
        self._buf = bytearray()
        self._offset = 0

    def feed(self, data: bytes) -> list[Decoded[Edge]]:
        self._buf += data
        out: list[Decoded[Edge]] = []
        while len(self._buf) >= EDGE_SIZE:
            if self._buf[:2] != EDGE_MAGIC:
                self._skip_to_magic()
                continue
            raw = bytes(self._buf[:EDGE_SIZE])
            edge = self._parse(raw)
            if edge is None:
                continue
            out.append(Decoded(raw, edge))
            self.stats.count_message(edge.line.name)
            self._drop(EDGE_SIZE)
        return out

    def _parse(self, raw: bytes) -> Edge | None:
        _magic, line, _flags, seq, t_ns, _res = _EDGE.unpack_from(raw)
        (crc,) = struct.unpack_from("<H", raw, _EDGE.size)
        if crc != crc16_ccitt_false(raw[: _EDGE.size]):
            self._reject(1, "checksum", "edge CRC mismatch", raw)
            return None
        try:
            return Edge(PulseLine(line), seq, t_ns)
        except ValueError:
            self._reject(1, "framing", f"unknown pulse line {line}", raw)
            return None

    def _skip_to_magic(self) -> None:
        at = self._buf.find(EDGE_MAGIC, 1)
        skip = len(self._buf) - 1 if at < 0 else at
        self._reject(skip, "framing", "bytes before edge magic", bytes(self._buf[:skip]))

    def _reject(self, n: int, kind: str, message: str, raw: bytes) -> None:
        """Skip n bytes (the search goes on after them), then count the error: under RAISE the
        decoder has already moved past the bad bytes, so feeding can go on."""
        offset = self._offset
        self.stats.bytes_skipped += n
        self._drop(n)
        report_error(self.policy, self.stats, kind, message, offset, raw)

    def _drop(self, n: int) -> None:
        del self._buf[:n]
        self._offset += n
