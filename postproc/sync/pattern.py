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
associated through the clock fitted on resolved blocks).

A block is resolved only when the probability that its best shift is wrong is negligible
(docs/sync.md, "The false-match bound"). Each shift s is a hypothesis: the latches it puts on a
pulse are genuine, the u(s) others are unexplained (spurious, or their pulse missing from the
log), and an unexplained latch falls within tol of a pulse at any other shift only by chance,
with probability at most q (2·tol × the highest pulse rate of the pattern over
`density_window_s`). If s were true, the a(s) latches the best shift explains and s does not
would be such chance agreements: P ≤ P(Bin(u(s), q/(1 − q)) ≥ a(s)), and the best shift is one
of M = 4·window/tol + 1 candidates (one per tol/2), so the probability of taking a wrong shift is
at most M · max over s of that tail (a union bound). The block is resolved when this bound is at
most `max_false_match` (1e-9) and no other shift rules the best one out by the same test (two
shifts each explaining many latches: the coarse time drifted across the block, or the clock
jumped in it); `min_margin` and `min_matches` still apply.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.special import bdtrc

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


@dataclass(frozen=True)
class PatternConfig:
    block_s: float = 30.0  # INS-clock length of a block
    window_s: float = 5.0  # search ± this around the coarse time (< half the LFSR period)
    tol_s: float = 3e-3  # a latch matches a pulse this close (after the coarse drift)
    min_matches: int = 4
    min_margin: int = 3
    max_false_match: float = 1e-9  # per block: bound on the probability of taking a wrong shift
    density_window_s: float = 2.0  # chance agreement: 2·tol × most pulses in any such span / span
    max_group_blocks: int = 8  # a piece with no block resolved is matched in groups up to this


@dataclass(frozen=True)
class ShiftScore:
    shift_s: float
    best: int
    second: int
    matched: I64  # per latch: index of its pulse at the best shift, −1 if none
    false_match: float = 1.0  # bound on the probability that the best shift is wrong
    contradiction: float = 1.0  # the same test with the best shift as the hypothesis: small
    # means another shift explains more of the latches it leaves out than chance allows
    chance: float = float("nan")  # q: one latch, one wrong shift, within tol of a pulse
    cells: int = 0  # M: shifts the search tells apart (the union bound's factor)

    @property
    def margin(self) -> int:
        return self.best - self.second

    def decisive(self, max_false_match: float) -> bool:
        """Every other shift ruled out, and none rules this one out."""
        return self.false_match <= max_false_match < self.contradiction


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


def chance_rate(y: F64, tol_s: float, span_s: float) -> float:
    """q: the probability that a latch unrelated to the pulses falls within tol of one, at one
    shift: 2·tol × the highest pulse rate of y (sorted) over any span_s (≤ 1)."""
    if y.size == 0:
        return 0.0
    most = int(np.max(np.searchsorted(y, y + span_s, side="left") - np.arange(y.size)))
    return min(1.0, 2.0 * tol_s * most / span_s)


def shift_cells(window_s: float, tol_s: float) -> int:
    """M: the shifts the search tells apart (candidates are kept one per tol/2 of ±window)."""
    return int(np.floor(2.0 * window_s / (0.5 * tol_s))) + 1


def chance_tail(agree: I64, unexplained: I64, q: float) -> F64:
    """P(Bin(unexplained, q/(1 − q)) ≥ agree): that many of the latches a hypothesis leaves
    unexplained agree at another shift by chance. q/(1 − q) bounds the chance of agreeing
    there given that a latch does not agree at the hypothesis's own shift."""
    qc = 1.0 if q >= 0.5 else q / (1.0 - q)
    agree = np.asarray(agree)
    tail = bdtrc(np.maximum(agree - 1, 0), np.asarray(unexplained), qc)  # P(X > agree − 1)
    return np.asarray(np.where(agree <= 0, 1.0, tail), dtype=np.float64)


def score_shifts(u: F64, y: F64, window_s: float, tol_s: float,
                 density_window_s: float = 2.0) -> ShiftScore:
    """Best shift s (|s| ≤ window) putting latches u + s onto pulses y (sorted), its score, the
    best score of any shift further than 2·tol from it, and the false-match bound of taking it
    (module doc)."""
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
    hit = dist <= tol_s
    scores = np.count_nonzero(hit, axis=1)
    b = int(np.argmax(scores))
    far = np.abs(cand - cand[b]) > 2.0 * tol_s
    others = scores[far]
    idx, d = nearest(y, u + cand[b])
    matched = np.where(d <= tol_s, idx, -1).astype(np.int64)
    # each other shift as the hypothesis (plus a shift that explains nothing, as every shift
    # off the candidates does): the latches the best explains and it does not, by chance?
    best, n = int(scores[b]), u.size
    q, cells = chance_rate(y[lo:hi], tol_s, density_window_s), shift_cells(window_s, tol_s)
    alt = hit[far]
    agree = np.append(np.count_nonzero(hit[b] & ~alt, axis=1), best)
    unexplained = np.append(n - others, n)
    false_match = min(1.0, cells * float(np.max(chance_tail(agree, unexplained, q))))
    # the best as the hypothesis: the latches another shift explains and it does not
    rival = int(np.max(np.count_nonzero(alt & ~hit[b], axis=1), initial=0))
    contradiction = min(1.0, cells * float(chance_tail(np.array([rival]),
                                                       np.array([n - best]), q)[0]))
    return ShiftScore(float(cand[b]), best, int(others.max()) if others.size else 0, matched,
                      false_match, contradiction, q, cells)


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


def _match(u_s: F64, y_s: F64, piece: I64, first: int, stop: int, cfg: PatternConfig
           ) -> BlockMatch:
    score = score_shifts(u_s[first:stop], y_s, cfg.window_s, cfg.tol_s, cfg.density_window_s)
    resolved = (score.best >= cfg.min_matches and score.margin >= cfg.min_margin
                and score.decisive(cfg.max_false_match))
    return BlockMatch(int(piece[first]), first, stop, score, resolved)


def _merged_groups(blocks: list[BlockMatch], u_s: F64, y_s: F64, piece: I64,
                   cfg: PatternConfig) -> list[BlockMatch]:
    """A piece none of whose blocks resolved, matched again as groups of 2, 4, … consecutive
    blocks, until a group resolves or groups reach `max_group_blocks` (or the whole piece). A
    block holds too few PPS-pattern latches when most pulses are mode 2, lost or in a PPS
    outage, yet every block of the piece may agree on one shift: a group's own false-match
    bound then counts all its latches. One coarse shift over a longer span is no weaker an
    assumption than over one block: where the coarse time drifts, its latches stop matching
    and the group is not taken (its bound, or the contradiction test). Returns the blocks
    with every resolved group in place of its members."""
    if len(blocks) < 2 or any(b.resolved for b in blocks):
        return blocks
    limit = min(len(blocks), cfg.max_group_blocks)
    size = 2
    while size // 2 < limit:  # the last level's groups held fewer blocks than the limit
        groups = [blocks[i:i + size] for i in range(0, len(blocks), size)]
        scored = [_match(u_s, y_s, piece, g[0].first, g[-1].stop, cfg) if len(g) > 1 else g[0]
                  for g in groups]
        if any(b.resolved for b in scored):
            return [m for g, b in zip(groups, scored, strict=True)
                    for m in ([b] if b.resolved else g)]
        size *= 2
    return blocks


def match_blocks(u_s: F64, x_s: F64, piece: I64, y_s: F64, cfg: PatternConfig
                 ) -> list[BlockMatch]:
    """Score every block of latches (coarse GPS u_s, INS clock x_s, piece) against the
    pulses y_s (sorted GPS seconds); a piece with no block resolved is tried again in groups
    of blocks (`_merged_groups`)."""
    blocks = [_match(u_s, y_s, piece, first, stop, cfg)
              for first, stop in block_ranges(x_s, piece, cfg.block_s)]
    out: list[BlockMatch] = []
    for _, of_piece in itertools.groupby(blocks, key=lambda b: b.piece):
        out += _merged_groups(list(of_piece), u_s, y_s, piece, cfg)
    return out
