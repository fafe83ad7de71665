"""Each INS clock piece fitted to GPS time from its latched pulses (records: insrecords).

Steps, per clock piece (a stretch of one INS clock the records show no jump in):
1. Coarse (postproc.sync.coarse): every latch a GPS time good to tens of ms plus a nearly constant
   shift (the INS output delay), from the host receive times.
2. Pattern (postproc.sync.pattern): blocks of latches find that shift against the forwarded pulses;
   a block is resolved only with a margin.
3. Runs: consecutive resolved blocks whose pulses one line (offset + rate) predicts form a run.
   A lone block that disagrees with agreeing neighbours is dropped as a false match.
4. Then, until nothing changes: growth (each run claims the latches up to its neighbours' claims
   whose pulse its line predicts within the association tolerance plus 5 sigma of the
   prediction; refit; repeat), steps (a clock jump smaller than a record period does not show
   in the records; in a run's pairs it is an offset step at one rate: binary segmentation
   splits the run there),
   merging (neighbouring runs one line fits without a step are one run), and leftovers (latches
   no run claimed are matched again as blocks of their own: the far side of a clock jump).
   A latch two runs claim is nobody's. This is how mode-2 stretches (ambiguous alone) get their
   pulses.
The association tolerance is `assoc_tol_s` plus the clock resolution (the latch truncates):
a jump larger than that leaves latches unclaimed, and records are never extrapolated past an
unclaimed latch (insrecords).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from postproc.sync.coarse import Latches
from postproc.sync.config import SyncConfig
from postproc.sync.linefit import Line, fit_line, robust_line
from postproc.sync.pattern import BlockMatch, match_blocks, nearest

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]

GROW_ITERATIONS: Final = 6
MAX_PASSES: Final = 4
MIN_STEP_SIDE: Final = 3
MIN_RUN_LATCHES: Final = 3  # a line from fewer cannot be trusted to extrapolate


@dataclass(frozen=True)
class ClockRun:
    """One stretch of one INS clock fitted to GPS: line(INS s of its piece) = GPS s of the
    flight epoch; the latches it claimed and their pulses (indices into the sorted pulses)."""

    piece: int
    line: Line
    latches: I64  # sorted by clock
    pulses: I64


# --- runs --------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Ctx:
    """What every step of the solver needs: latch clock x, pulse GPS y (sorted), settings."""

    x: F64
    y: F64
    cfg: SyncConfig
    noise_s: float  # one latch ↔ pulse pair
    assoc_s: float  # association tolerance: assoc_tol_s + clock resolution

    def tolerance(self, line: Line, lat: I64) -> F64:
        sigma = max(line.sigma, self.noise_s)
        lev = line.leverage(self.x[lat])
        return np.asarray(self.assoc_s + 5.0 * sigma * np.sqrt(lev), dtype=np.float64)

    def run(self, piece: int, lat: I64, pul: I64) -> ClockRun | None:
        """A run from pairs: robust line, outlying pairs dropped; None if too few remain."""
        order = np.argsort(self.x[lat], kind="stable")
        lat, pul = lat[order], pul[order]
        if lat.size < MIN_RUN_LATCHES:
            return None
        line, keep = robust_line(self.x[lat], self.y[pul], sigma_floor=self.noise_s)
        if np.count_nonzero(keep) < MIN_RUN_LATCHES:
            return None
        return ClockRun(piece, line, lat[keep], pul[keep])

    def agrees(self, run: ClockRun, lat: I64, pul: I64) -> bool:
        """Most of these pairs lie where the run's line predicts them."""
        res = np.abs(self.y[pul] - run.line(self.x[lat]))
        return bool(np.mean(res <= self.tolerance(run.line, lat)) >= 0.5)

    def merged(self, a: ClockRun, b: ClockRun) -> ClockRun | None:
        lat, first = np.unique(np.concatenate([a.latches, b.latches]), return_index=True)
        pul = np.concatenate([a.pulses, b.pulses])[first]
        return self.run(a.piece, lat, pul)


def _block_pairs(b: BlockMatch) -> tuple[I64, I64]:
    idx = np.flatnonzero(b.score.matched >= 0)
    return (b.first + idx).astype(np.int64), b.score.matched[idx]


def _seed_runs(blocks: list[BlockMatch], c: _Ctx) -> list[ClockRun]:
    """Consecutive resolved blocks that one line predicts, as runs (per piece, in order)."""
    runs: list[ClockRun] = []
    sizes: list[int] = []  # resolved blocks per run
    for b in blocks:
        if not b.resolved:
            continue
        la, pu = _block_pairs(b)
        last = runs[-1] if runs else None
        if last is not None and last.piece == b.piece and c.agrees(last, la, pu):
            both = c.merged(last, ClockRun(b.piece, last.line, la, pu))
            if both is not None:
                runs[-1], sizes[-1] = both, sizes[-1] + 1
                continue
        new = c.run(b.piece, la, pu)
        if new is not None:
            runs.append(new)
            sizes.append(1)
    return _drop_lone_outliers(runs, sizes, c)


def _drop_lone_outliers(runs: list[ClockRun], sizes: list[int], c: _Ctx) -> list[ClockRun]:
    """A one-block run between two runs of its piece that agree with each other is a false
    match: the clock does not jump and jump back."""
    out: list[ClockRun] = []
    i = 0
    while i < len(runs):
        r, prev = runs[i], out[-1] if out else None
        nxt = runs[i + 1] if i + 1 < len(runs) else None
        if (sizes[i] == 1 and prev is not None and nxt is not None
                and prev.piece == r.piece == nxt.piece
                and c.agrees(prev, nxt.latches, nxt.pulses)):
            both = c.merged(prev, nxt)
            if both is not None:
                out[-1] = both
                i += 2
                continue
        out.append(r)
        i += 1
    return out


# --- growth, steps, merging ------------------------------------------------------------------

def _claim(line: Line, cand: I64, c: _Ctx) -> tuple[I64, I64]:
    """Latches among cand whose pulse the line predicts; a pulse goes to its closest latch."""
    pul, dist = nearest(c.y, line(c.x[cand]))
    ok = dist <= c.tolerance(line, cand)
    lat, pul, dist = cand[ok], pul[ok], dist[ok]
    order = np.lexsort((dist, pul))
    _, first = np.unique(pul[order], return_index=True)
    keep = np.sort(order[first])
    return lat[keep], pul[keep]


def _grow(run: ClockRun, cand: I64, c: _Ctx) -> ClockRun:
    for _ in range(GROW_ITERATIONS):
        lat, pul = _claim(run.line, cand, c)
        new = c.run(run.piece, lat, pul)
        if new is None:
            return run
        same = np.array_equal(new.latches, run.latches) and np.array_equal(new.pulses,
                                                                           run.pulses)
        run = new
        if same:
            break
    return run


def _grow_all(runs: list[ClockRun], piece_latches: I64, c: _Ctx) -> list[ClockRun]:
    """Grow each run of one piece, in order, up to its neighbours' claims (a clock jump lies
    between two runs); a latch two runs claim is nobody's."""
    grown = list(runs)
    xs = c.x[piece_latches]
    for i, run in enumerate(grown):
        lo = float(c.x[grown[i - 1].latches[-1]]) if i > 0 else -np.inf
        hi = float(c.x[grown[i + 1].latches[0]]) if i + 1 < len(grown) else np.inf
        grown[i] = _grow(run, piece_latches[(xs > lo) & (xs < hi)], c)
    every = np.concatenate([g.latches for g in grown]) if grown else np.zeros(0, np.int64)
    uniq, counts = np.unique(every, return_counts=True)
    shared = uniq[counts > 1]
    out = []
    for g in grown:
        keep = ~np.isin(g.latches, shared)
        r = g if keep.all() else c.run(g.piece, g.latches[keep], g.pulses[keep])
        if r is not None:
            out.append(r)
    return out


def _best_step(xs: F64, ys: F64, c: _Ctx) -> int | None:
    """Where one offset step best explains the pairs of one run, if significant.

    The model of a clock jump: one rate, two offsets (before and after the k-th latch). For
    every k, least squares of that model (closed form from prefix sums, on the residuals of one
    line to keep the sums small); the k of least residual is the step if the step exceeds
    step_min_s and step_z standard errors (noise from the model's own residuals, at least the
    noise model). The residuals of one line were cut in two before: on a short run around a
    jump one line takes most of the step as a rate (a −0.4 ms jump in 19 s of latches left
    residuals of ±130 µs but a step of 81 µs at 4 of their "sigmas"), and the run stayed whole."""
    n = xs.size
    if n < 2 * MIN_STEP_SIDE:
        return None
    r = ys - fit_line(xs, ys)(xs)
    x = xs - xs.mean()
    k = np.arange(MIN_STEP_SIDE, n - MIN_STEP_SIDE + 1)
    pre = [np.concatenate([[0.0], np.cumsum(v)]) for v in (x, r, x * x, x * r, r * r)]
    tot = [p[-1] for p in pre]
    sx1, sr1, sxx1, sxr1, srr1 = (p[k] for p in pre)
    sx2, sr2, sxx2, sxr2, srr2 = (t - p for t, p in zip(tot, (sx1, sr1, sxx1, sxr1, srr1),
                                                         strict=True))
    n1, n2 = k.astype(np.float64), (n - k).astype(np.float64)
    sxx = sxx1 - sx1 * sx1 / n1 + sxx2 - sx2 * sx2 / n2
    sxr = sxr1 - sx1 * sr1 / n1 + sxr2 - sx2 * sr2 / n2
    srr = srr1 - sr1 * sr1 / n1 + srr2 - sr2 * sr2 / n2
    ok = sxx > 0
    slope = np.where(ok, sxr / np.where(ok, sxx, 1.0), 0.0)
    rss = np.maximum(srr - slope * sxr, 0.0)
    step = (sr2 / n2 - sr1 / n1) - slope * (sx2 / n2 - sx1 / n1)
    b = int(np.argmin(np.where(ok, rss, np.inf)))
    if not ok[b]:
        return None
    sigma = max(c.noise_s, float(np.sqrt(rss[b] / (n - 3))))
    gap = sx2[b] / n2[b] - sx1[b] / n1[b]
    se = sigma * float(np.sqrt(1.0 / n1[b] + 1.0 / n2[b] + gap * gap / sxx[b]))
    if abs(step[b]) > c.cfg.step_min_s and abs(step[b]) > c.cfg.step_z * se:
        return int(k[b])
    return None


def _split_steps(run: ClockRun, c: _Ctx) -> list[ClockRun]:
    todo = [(run.latches, run.pulses)]
    done: list[ClockRun] = []
    while todo:
        lat, pul = todo.pop()
        k = _best_step(c.x[lat], c.y[pul], c)
        if k is None:
            part = c.run(run.piece, lat, pul)
            if part is not None:
                done.append(part)
        else:
            todo += [(lat[:k], pul[:k]), (lat[k:], pul[k:])]
    return done


def _merge_neighbours(runs: list[ClockRun], c: _Ctx) -> list[ClockRun]:
    """Neighbouring runs that one line fits without a step are one run."""
    out: list[ClockRun] = []
    for r in runs:
        prev = out[-1] if out else None
        if prev is not None:
            both = c.merged(prev, r)
            if (both is not None and both.latches.size == prev.latches.size + r.latches.size
                    and _best_step(c.x[both.latches], c.y[both.pulses], c) is None
                    and c.agrees(both, both.latches, both.pulses)):
                out[-1] = both
                continue
        out.append(r)
    return out


def _leftover_runs(runs: list[ClockRun], piece: int, piece_latches: I64, lat: Latches,
                   c: _Ctx) -> list[ClockRun]:
    """Runs from latches nobody claimed, matched as blocks of their own, outside every run's
    span (the far side of a clock jump)."""
    claimed = np.concatenate([r.latches for r in runs]) if runs else np.zeros(0, np.int64)
    free = piece_latches[~np.isin(piece_latches, claimed)]
    spans = [(float(c.x[r.latches[0]]), float(c.x[r.latches[-1]])) for r in runs]
    outside = np.ones(free.size, dtype=np.bool_)
    for lo, hi in spans:
        outside &= (c.x[free] < lo) | (c.x[free] > hi)
    free = free[outside]
    if free.size < c.cfg.pattern.min_matches:
        return []
    blocks = match_blocks(lat.u_s[free], lat.x_s[free], lat.piece[free], c.y, c.cfg.pattern)
    found = []
    for b in blocks:
        if b.resolved:
            idx = np.flatnonzero(b.score.matched >= 0)
            new = c.run(piece, free[b.first + idx], b.score.matched[idx])
            if new is not None:
                found.append(new)
    return found


def _signature(runs: list[ClockRun]) -> tuple[tuple[int, ...], ...]:
    return tuple(tuple(r.latches.tolist()) for r in runs)


def _solve_piece(runs: list[ClockRun], piece: int, piece_latches: I64, lat: Latches,
                 c: _Ctx) -> list[ClockRun]:
    for _ in range(MAX_PASSES):
        before = _signature(runs)
        runs = _grow_all(runs, piece_latches, c)
        runs = [part for r in runs for part in _split_steps(r, c)]
        runs = _merge_neighbours(sorted(runs, key=lambda r: float(c.x[r.latches[0]])), c)
        extra = _leftover_runs(runs, piece, piece_latches, lat, c)
        runs = sorted(runs + extra, key=lambda r: float(c.x[r.latches[0]]))
        if _signature(runs) == before:
            break
    return runs


def fit_runs(lat: Latches, y: F64, cfg: SyncConfig, noise_s: float, resolution_s: float
             ) -> tuple[list[ClockRun], list[BlockMatch]]:
    """Pattern blocks, then runs for every piece: lines from INS clock to GPS time."""
    c = _Ctx(lat.x_s, y, cfg, noise_s, cfg.assoc_tol_s + resolution_s)
    blocks = match_blocks(lat.u_s, lat.x_s, lat.piece, y, cfg.pattern)
    seeds = _seed_runs(blocks, c)
    out: list[ClockRun] = []
    for p in sorted({r.piece for r in seeds}):
        runs = [r for r in seeds if r.piece == p]
        out += _solve_piece(runs, p, np.flatnonzero(lat.piece == p), lat, c)
    return out, blocks
