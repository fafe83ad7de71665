"""The NMEA checksum, shared by the acquisition's codec and post-processing (which reads a few
sentences from the raw log itself and must not import the acquisition)."""

from __future__ import annotations

from functools import reduce
from operator import xor


def checksum(body: bytes) -> int:
    """NMEA checksum: XOR of every byte between `$` and `*`."""
    return reduce(xor, body, 0)
