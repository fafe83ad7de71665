"""Coarse GPS time of every latched pulse, from the log's host receive times.

The host clock maps to GPS time through the receiver's stated times (postproc.sync.clockmap), good
to the serial latency; an INS record reaches the host its output delay plus the CAN latency after
its epoch. So per clock piece, a robust line of (host-derived GPS − INS clock) against the INS
clock removes the INS clock's offset and drift up to a nearly constant shift (−output delay):
a latch's coarse time is then good to a few ms about that shift, which pattern matching finds.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from postproc.sync.clockmap import ClockMap
from postproc.sync.insclock import InsTimeline
from postproc.sync.linefit import Line, robust_line
from sisa.core.timescale import NS_PER_S

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]

COARSE_SIGMA_FLOOR_S: Final = 1e-3
COARSE_MAX_POINTS: Final = 5000  # per piece: the line needs no more


@dataclass(frozen=True)
class Latches:
    """Usable latches in clock order within each piece."""

    x_s: F64  # INS clock seconds relative to the piece's first record
    piece: I64
    u_s: F64  # coarse GPS seconds of the flight epoch


# --- coarse ----------------------------------------------------------------------------------

def coarse_lines(x_s: F64, piece: I64, gps_est_s: F64, pieces: int) -> list[Line | None]:
    """Per piece: a robust line of (host-derived GPS − INS clock) against the INS clock."""
    out: list[Line | None] = []
    bounds = np.searchsorted(piece, np.arange(pieces + 1))
    for p in range(pieces):
        lo, hi = int(bounds[p]), int(bounds[p + 1])
        if hi <= lo:
            out.append(None)
            continue
        step = max(1, (hi - lo) // COARSE_MAX_POINTS)
        x, y = x_s[lo:hi:step], gps_est_s[lo:hi:step] - x_s[lo:hi:step]
        line, _ = robust_line(x, y, sigma_floor=COARSE_SIGMA_FLOOR_S,
                              slope=0.0 if x.size < 3 else None)
        out.append(line)
    return out


def latch_set(tl: InsTimeline, coarse: list[Line | None]) -> Latches:
    piece = tl.piece[tl.latch_record]
    x = tl.seconds(tl.latch_ticks, piece)
    u = np.empty_like(x)
    for p in np.unique(piece).tolist():
        sel = piece == p
        line = coarse[p]
        u[sel] = x[sel] + (line(x[sel]) if line is not None else np.nan)
    return Latches(x, piece, u)


def coarse_latches(tl: InsTimeline, t_host_ns: I64, host: ClockMap, epoch_ns: int
                   ) -> Latches:
    """Every usable latch with its INS clock seconds and its coarse GPS seconds."""
    x_rec = tl.seconds(tl.clock_ticks, tl.piece)
    gps_est_s = (host.gps_ns(t_host_ns) - epoch_ns).astype(np.float64) / NS_PER_S
    return latch_set(tl, coarse_lines(x_rec, tl.piece, gps_est_s, int(tl.piece_first.size)))
