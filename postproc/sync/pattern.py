"""Whole-second ambiguity: which forwarded pulse is each pulse the INS latched?

The INS clock has an unknown offset; the log's host times place each INS record in GPS time only
to tens of ms plus the INS's output delay (a "coarse" time, good to a few seconds at worst). The
sync unit forwarded a pseudorandom subset of the PPS (mode 1) and 1 of n frame pulses (mode 2),
and logged the GPS time of each. So within a block of latches (`block_s` of INS clock) we try
every shift within ±`window_s` of the coarse time that lines one latch up with one pulse, and
count how many latches then fall within `tol_s` of a pulse: the whole train is compared at once
(all its gaps), each latch votes on its own, so missing and spurious pulses on either side cost
a vote, not the match (prior art: pyControl's Rsync, the barcode schemes of neuroscience).

A maximal-length register of n bits repeats every 2^n − 1 s, so the window must stay below half
that period; inside it a mode-1 shift by k ≠ 0 seconds keeps about half the pulses (the
m-sequence's autocorrelation), the true shift keeps all. Mode-2 trains are nearly periodic and
may match equally well one pulse off: such a block stays unresolved here (its latches are later
associated through the clock fitted on resolved blocks). A block is resolved only when its best
shift beats every other shift (further than 2·tol from it) by `min_margin` latches.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


@dataclass(frozen=True)
class PatternConfig:
    block_s: float = 30.0  # INS-clock length of a block
    window_s: float = 5.0  # search ± this around the coarse time (< half the LFSR period)
    tol_s: float = 3e-3  # a latch matches a pulse this close (after the coarse drift)
    min_matches: int = 4
    min_margin: int = 3


@dataclass(frozen=True)
class ShiftScore:
    shift_s: float
    best: int
    second: int
    matched: I64  # per latch: index of its pulse at the best shift, −1 if none

    @property
    def margin(self) -> int:
        return self.best - self.second


@dataclass(frozen=True)
class BlockMatch:
    piece: int
    first: int  # latch index range [first, stop) of the block
    stop: int
    score: ShiftScore
    resolved: bool


def nearest(y: F64, t: F64) -> tuple[I64, F64]:
    """Index of the nearest y (sorted) to each t, and the distance."""
    j = np.searchsorted(y, t)
    lo = np.clip(j - 1, 0, y.size - 1)
    hi = np.clip(j, 0, y.size - 1)
    dlo, dhi = np.abs(t - y[lo]), np.abs(y[hi] - t)
    return np.where(dlo <= dhi, lo, hi), np.minimum(dlo, dhi)


def score_shifts(u: F64, y: F64, window_s: float, tol_s: float) -> ShiftScore:
    """Best shift s (|s| ≤ window) putting latches u + s onto pulses y (sorted), its score,
    and the best score of any shift further than 2·tol from it."""
    none = ShiftScore(float("nan"), 0, 0, np.full(u.size, -1, dtype=np.int64))
    if u.size == 0 or y.size == 0:
        return none
    lo = int(np.searchsorted(y, u.min() - window_s - tol_s))
    hi = int(np.searchsorted(y, u.max() + window_s + tol_s))
    if hi <= lo:
        return none
    cand = (y[None, lo:hi] - u[:, None]).ravel()
    cand = cand[np.abs(cand) <= window_s]
    if cand.size == 0:
        return none
    _, first = np.unique(np.rint(cand / (0.5 * tol_s)), return_index=True)
    cand = cand[first]
    _, dist = nearest(y[lo:hi], u[None, :] + cand[:, None])
    scores = np.count_nonzero(dist <= tol_s, axis=1)
    b = int(np.argmax(scores))
    others = scores[np.abs(cand - cand[b]) > 2.0 * tol_s]
    idx, d = nearest(y, u + cand[b])
    matched = np.where(d <= tol_s, idx, -1).astype(np.int64)
    return ShiftScore(float(cand[b]), int(scores[b]), int(others.max()) if others.size else 0,
                      matched)


def block_ranges(x_s: F64, piece: I64, block_s: float) -> list[tuple[int, int]]:
    """[first, stop) latch ranges: latches of one piece in the same block_s of its clock,
    counted from the piece's first latch (latches in clock order within a piece)."""
    if x_s.size == 0:
        return []
    idx = np.arange(x_s.size)
    new_piece = np.concatenate([[True], piece[1:] != piece[:-1]])
    piece_first = np.maximum.accumulate(np.where(new_piece, idx, 0))
    block = np.floor((x_s - x_s[piece_first]) / block_s).astype(np.int64)
    starts = np.flatnonzero(new_piece | np.concatenate([[True], block[1:] != block[:-1]]))
    bounds = [*starts.tolist(), x_s.size]
    return list(itertools.pairwise(bounds))


def match_blocks(u_s: F64, x_s: F64, piece: I64, y_s: F64, cfg: PatternConfig
                 ) -> list[BlockMatch]:
    """Score every block of latches (coarse GPS u_s, INS clock x_s, piece) against the
    pulses y_s (sorted GPS seconds)."""
    out = []
    for first, stop in block_ranges(x_s, piece, cfg.block_s):
        score = score_shifts(u_s[first:stop], y_s, cfg.window_s, cfg.tol_s)
        resolved = score.best >= cfg.min_matches and score.margin >= cfg.min_margin
        out.append(BlockMatch(int(piece[first]), first, stop, score, resolved))
    return out
