"""Every INS record its GPS time, from the clock runs fitted on the latched pulses.

A record between two latches of one run takes that run's line at its own clock value (the INS
clock tags the measurement epoch; the output delay plays no part). A record between latches of
two runs sits across a clock jump of unknown place: CLOCK_JUMP. A record beyond the first or last
latch of its run is OUTSIDE_FIT (`max_extrapolation_s`, 0 by default: a clock jump smaller than
a record period shows only in later latches, and there are none; docs/sync.md, Limits), as is
one where the line's own predicted error exceeds `max_time_sigma_s`; with extrapolation allowed,
never past a latch no run claimed (the clock may have jumped there: AMBIGUOUS). A piece with
latches but no run is AMBIGUOUS; one without latches NO_PULSES.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from postproc.sync.coarse import Latches
from postproc.sync.config import SyncConfig, TimeStatus
from postproc.sync.insclock import TICK_NS, InsTimeline
from postproc.sync.insfit import ClockRun

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]

PIECE_KEY_S: Final = float(1 << 24)  # (piece, clock seconds) as one sortable float key


@dataclass(frozen=True)
class _Claims:
    """Claimed latches sorted by (piece, clock), and where records fall among them."""

    key: F64
    piece: I64
    run: I64
    all_key: F64  # every latch, claimed or not, sorted

    def around(self, key: F64, piece: I64) -> tuple[I64, I64, Bool, Bool]:
        """Claimed latch before/after each key, and whether it is in the key's piece."""
        n = self.key.size
        j = np.searchsorted(self.key, key, side="right")
        before, after = np.clip(j - 1, 0, max(n - 1, 0)), np.clip(j, 0, max(n - 1, 0))
        if n == 0:
            no = np.zeros(key.size, dtype=np.bool_)
            return before, after, no, no
        return (before, after, (j > 0) & (self.piece[before] == piece),
                (j < n) & (self.piece[after] == piece))

    def unclaimed_between(self, lo: F64, hi: F64) -> I64:
        """Latches (claimed or not) strictly between the keys lo and hi."""
        return np.asarray(np.searchsorted(self.all_key, hi, side="left")
                          - np.searchsorted(self.all_key, lo, side="right"), dtype=np.int64)


def _claims(lat: Latches, runs: list[ClockRun]) -> _Claims:
    owner = np.full(lat.x_s.size, -1, dtype=np.int64)
    for i, r in enumerate(runs):
        owner[r.latches] = i
    key = lat.piece * PIECE_KEY_S + lat.x_s
    order = np.argsort(key, kind="stable")
    claimed = order[owner[order] >= 0]
    return _Claims(key[claimed], lat.piece[claimed], owner[claimed], np.sort(key))


def _unsafe_extrapolation(c: _Claims, key: F64, piece: I64, before: I64, after: I64,
                          has_prev: Bool, has_next: Bool) -> Bool:
    """Beyond the last (first) claimed latch of a piece while an unclaimed latch lies anywhere
    further on (before) in that piece: a clock jump may sit anywhere past the last claim."""
    if c.key.size == 0:
        return np.zeros(key.size, dtype=np.bool_)
    start = np.asarray(piece * PIECE_KEY_S, dtype=np.float64)
    end = start + PIECE_KEY_S
    after_last = has_prev & ~has_next & (c.unclaimed_between(c.key[before], end) > 0)
    before_first = has_next & ~has_prev & (c.unclaimed_between(start, c.key[after]) > 0)
    return after_last | before_first


def _uncertain(x: F64, run: I64, runs: list[ClockRun], lat: Latches, noise_s: float,
               cfg: SyncConfig) -> Bool:
    """Further than max_extrapolation_s outside the run's latches, or predicted error (one
    sigma, from the fit) above max_time_sigma_s."""
    bad = np.zeros(x.size, dtype=np.bool_)
    for i, r in enumerate(runs):
        sel = np.flatnonzero(run == i)
        xs = lat.x_s[r.latches]
        lo, hi = float(xs.min()), float(xs.max())
        far = (x[sel] < lo - cfg.max_extrapolation_s) | (x[sel] > hi + cfg.max_extrapolation_s)
        sigma = max(r.line.sigma, noise_s) * np.sqrt(r.line.leverage(x[sel]))
        bad[sel] = far | (sigma > cfg.max_time_sigma_s)
    return bad


def tag_records(tl: InsTimeline, lat: Latches, runs: list[ClockRun], epoch_ns: int,
                noise_s: float, cfg: SyncConfig) -> tuple[I64, I64, I64]:
    """GPS ns, TimeStatus and run (−1 where not OK) of every record."""
    x = tl.seconds(tl.clock_ticks, tl.piece)
    key = tl.piece * PIECE_KEY_S + x
    c = _claims(lat, runs)
    before, after, has_prev, has_next = c.around(key, tl.piece)
    prev_run = c.run[before] if c.key.size else np.full(x.size, -1, dtype=np.int64)
    next_run = c.run[after] if c.key.size else prev_run
    run = np.where(has_prev, prev_run, np.where(has_next, next_run, -1)).astype(np.int64)
    status = np.full(x.size, int(TimeStatus.OK), dtype=np.int64)
    status[_uncertain(x, run, runs, lat, noise_s, cfg)] = TimeStatus.OUTSIDE_FIT
    status[_unsafe_extrapolation(c, key, tl.piece, before, after, has_prev, has_next)] = (
        TimeStatus.AMBIGUOUS)
    status[has_prev & has_next & (prev_run != next_run)] = TimeStatus.CLOCK_JUMP
    none = ~has_prev & ~has_next
    status[none] = np.where(np.isin(tl.piece[none], lat.piece), TimeStatus.AMBIGUOUS,
                            TimeStatus.NO_PULSES)
    run[status != TimeStatus.OK] = -1
    t = np.full(x.size, -1, dtype=np.int64)
    for i, r in enumerate(runs):
        sel = run == i
        t[sel] = epoch_ns + np.rint(r.line(x[sel]) * 1e9).astype(np.int64)
    return t, status, run


def latch_noise_s(tl: InsTimeline, tag_lsb_ns: int) -> float:
    """Noise model of one latch ↔ pulse pair: the latch truncates the INS clock to its
    resolution, the receiver rounds its tags to its LSB (both uniform: width/√12)."""
    res_s = tl.resolution_ticks * TICK_NS * 1e-9
    return float(np.hypot(res_s, tag_lsb_ns * 1e-9) / np.sqrt(12.0))
