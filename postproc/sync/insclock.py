"""The INS record stream on its own clock: counters unwrapped, clock pieces, latched pulses.

What the records tell by themselves (no GPS time yet):
- The record counter wraps (its width is not logged: the modulus is the power of two above the
  largest counter seen, at least 2^8). `seq` numbers the records from 0; a counter step of k
  means k − 1 records missing from the log.
- The 48-bit clock (100 ns ticks) is unwrapped. Records are measured on the INS's own grid, so
  consecutive records differ by whole record periods on its clock: a step whose clock interval
  disagrees with its counter step is a clock jump. A step where the clock goes back is a jump
  back, or a reboot when the REBOOTED status bit comes on, or the counter restarts.
- Each stretch of one clock without a jump the records show is a clock piece; every piece gets
  its own fit to GPS time later. A jump smaller than a record period does not show here; the
  pulse fit finds it.
- A latched pulse (sync_flag) holds the clock at the pulse, read down to the clock's resolution
  (truncated), so the pulse came on average half a resolution step later. The resolution is the
  greatest common divisor of the steps between latched values (from MIN_LATCHES_FOR_GCD of
  them: fewer could share a factor by chance), unless the caller states it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Final

import numpy as np
import numpy.typing as npt

from postproc.sync.flightlog import InsColumns

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]

TICK_NS: Final = 100  # the INS clock's unit on the wire
TICKS_MODULUS: Final = 1 << 48
REBOOTED_BIT: Final = 0x08  # status: first records after power-up (docs/protocols.md)
MIN_COUNTER_BITS: Final = 8
COUNTER_OUTLIERS: Final = 1e-3  # share of the highest record counters the modulus may ignore
MAX_CONTINUE: Final = 1024  # a counter step larger than this, with the clock gone back: restart
MAX_LATCH_AGE_PERIODS: Final = 4  # a latch older than this before its record is not its pulse
MIN_LATCHES_FOR_GCD: Final = 16  # k latches share a spurious factor p with probability p^-k


class PieceStart(IntEnum):
    """Why a clock piece starts."""

    FIRST = 0
    REBOOT = 1
    JUMP_BACK = 2
    JUMP = 3  # the clock interval disagrees with the counter step


@dataclass(frozen=True)
class InsTimeline:
    """The INS records on their own clock, in log order."""

    seq: I64
    piece: I64  # clock piece of each record
    clock_ticks: I64  # unwrapped clock of each record (continuous within its piece)
    piece_first: I64  # first record of each piece
    piece_start: I64  # PieceStart of each piece
    latch_record: I64  # record carrying each usable latch
    latch_ticks: F64  # unwrapped latch + half a resolution step (float ticks)
    resolution_ticks: int
    period_ticks: float
    counter_modulus: int
    counts: dict[str, int]

    def outside_latch_span(self) -> Bool:
        """Records measured before the log's first latched pulse or after its last (the record
        carrying a latch is measured after its pulse): no pulse can show the INS clock there,
        so none of them is timed (insrecords): the flight's first and last seconds. A log
        without latches has no span: none is outside it (its records are all untimed, and
        that is a loss, not the flight's ends)."""
        out = np.zeros(self.seq.size, dtype=np.bool_)
        if self.latch_record.size:
            out[:int(self.latch_record.min())] = True
            out[int(self.latch_record.max()):] = True
        return out

    def seconds(self, ticks: npt.ArrayLike, piece: npt.ArrayLike) -> F64:
        """INS clock seconds relative to the first record of the piece."""
        epoch = self.clock_ticks[self.piece_first[np.asarray(piece, dtype=np.int64)]]
        rel = np.asarray(ticks, dtype=np.float64) - epoch.astype(np.float64)
        return np.asarray(rel * (TICK_NS * 1e-9), dtype=np.float64)


def _signed_ticks(d: I64) -> I64:
    d = np.mod(d, TICKS_MODULUS)
    return np.where(d >= TICKS_MODULUS // 2, d - TICKS_MODULUS, d)


def _counter_modulus(counter: I64) -> int:
    """The power of two above the counters, but for the top COUNTER_OUTLIERS of them: one
    record corrupted past CRC-8 with a counter of 40 000 in an 8-bit stream made the modulus
    65 536, and every wrap of the counter (255 → 0, every 4 s at 64 Hz) a clock jump: 61 clock
    pieces, none timed (fault sweep seed 41001). A modulus too small is harmless as long as it
    exceeds every gap (it divides the true one), a modulus too large is not."""
    if counter.size == 0:
        return 1 << MIN_COUNTER_BITS
    top = int(np.quantile(counter, 1.0 - COUNTER_OUTLIERS, method="higher"))
    return 1 << max(MIN_COUNTER_BITS, math.ceil(math.log2(top + 1)) if top > 0 else 0)


def _period_ticks(d: I64, dc: I64) -> float:
    steady = d[(dc == 1) & (d > 0)]
    if steady.size:
        return float(np.median(steady))
    positive = d[d > 0]
    return float(np.median(positive)) if positive.size else 1.0


def _resolution_ticks(ins: InsColumns) -> int:
    """The greatest common divisor of the steps between consecutive latched values, not of the
    values: a clock that started below zero wraps to 2^48 − k, which is no multiple of the
    resolution (an INS set to −12 333 s, 1 µs resolution: 200 ns from the values, and every
    other record of a 128 Hz stream, 7 812 / 7 813 µs apart, was taken for a clock jump). A
    step that goes down (the 48-bit clock wrapping, a jump back) is left out."""
    latched = ins.sync_time_ticks[ins.sync_flag]
    steps = np.diff(latched[latched > 0])
    steps = steps[steps > 0]
    return int(np.gcd.reduce(steps)) if steps.size >= MIN_LATCHES_FOR_GCD else 1


def _transitions(ins: InsColumns, modulus: int, resolution: int
                 ) -> tuple[I64, I64, I64, float]:
    """Per step i−1 → i: clock step (signed ticks), counter step, PieceStart (−1: none)."""
    d = _signed_ticks(np.diff(ins.ins_time_ticks))
    dc = np.mod(np.diff(ins.counter), modulus)
    period = _period_ticks(d, dc)
    tol = 2.0 * resolution + 1.0
    k = np.rint(d / period)
    rebooted = (ins.status & REBOOTED_BIT) != 0
    newly = rebooted[1:] & ~rebooted[:-1]
    restart = newly | ((d < 0) & (dc > MAX_CONTINUE))
    back = ~restart & (d <= 0) & (dc > 0)
    off_grid = np.abs(d - dc * period) > tol * np.maximum(dc, 1)
    jump = ~restart & ~back & (d > 0) & ((k != dc) | off_grid)
    kind = np.full(d.size, -1, dtype=np.int64)
    kind[restart], kind[back], kind[jump] = PieceStart.REBOOT, PieceStart.JUMP_BACK, PieceStart.JUMP
    return d, dc, kind, period


def _unwrap_clock(ticks: I64, d: I64, first: I64, piece: I64) -> I64:
    """Clock of each record: the raw value of its piece's first record plus the steps since."""
    cum = np.concatenate([[0], np.cumsum(d)])
    start = first[piece]
    return np.asarray(ticks[start] + cum - cum[start], dtype=np.int64)


def _latches(ins: InsColumns, clock: I64, period: float, resolution: int
             ) -> tuple[I64, F64, int]:
    """Usable latches: at most a few record periods before the record that carries them."""
    rec = np.flatnonzero(ins.sync_flag)
    age = np.mod(ins.ins_time_ticks[rec] - ins.sync_time_ticks[rec], TICKS_MODULUS)
    ok = age <= MAX_LATCH_AGE_PERIODS * period
    rec, age = rec[ok], age[ok]
    latch = (clock[rec] - age).astype(np.float64) + resolution / 2.0
    return rec, latch, int(np.count_nonzero(~ok))


def ins_timeline(ins: InsColumns, resolution_ticks: int | None = None) -> InsTimeline:
    """Unwrap counters and clock, split clock pieces, extract the latched pulses.
    `resolution_ticks`: the clock's resolution if known (else from the latches)."""
    n = ins.counter.size
    modulus = _counter_modulus(ins.counter)
    resolution = resolution_ticks or _resolution_ticks(ins)
    d, dc, kind, period = _transitions(ins, modulus, resolution)
    boundary = np.concatenate([[True], kind >= 0]) if n else np.zeros(0, dtype=np.bool_)
    piece = np.cumsum(boundary) - 1
    first = np.flatnonzero(boundary)
    starts = np.concatenate([[PieceStart.FIRST], kind[kind >= 0]]).astype(np.int64)
    step = np.where(kind == PieceStart.REBOOT, 1, dc)
    seq = np.concatenate([[0], np.cumsum(step)]).astype(np.int64) if n else np.zeros(0, np.int64)
    clock = _unwrap_clock(ins.ins_time_ticks, d, first, piece) if n else np.zeros(0, np.int64)
    rec, latch, stale = _latches(ins, clock, period, resolution)
    counts = {
        "records": n,
        "reboots": int(np.count_nonzero(kind == PieceStart.REBOOT)),
        "clock_jumps_back": int(np.count_nonzero(kind == PieceStart.JUMP_BACK)),
        "clock_jumps": int(np.count_nonzero(kind == PieceStart.JUMP)),
        "records_missing": int(np.sum(np.where(kind < 0, np.maximum(dc - 1, 0), 0))),
        "counter_wraps": int(np.count_nonzero((kind < 0) & (np.diff(ins.counter) < 0))),
        "latches": int(np.count_nonzero(ins.sync_flag)),
        "latches_stale": stale,
    }
    return InsTimeline(seq, piece, clock, first, starts, rec, latch, resolution, period,
                       modulus, counts)
