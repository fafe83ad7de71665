"""Clock runs carried across an INS clock jump the records do not show.

An INS clock jump smaller than a record period leaves every record interval one period of
ticks (the INS measures on its own clock grid; `insclock`), so only the pulses show it: past the
jump, the latches no longer fall where the run's line puts their pulses, and the run stops at
the last latch before it. If the pulses past the jump cannot be matched on their own (a mode-2
train repeats every 1.024 s; a few mode-1 pulses give no margin of 3), every record after the
jump stayed `ambiguous`: a −0.4 ms jump 26 s before the end of a log cost 2 336 records.

But such a jump is bounded: one that crossed a grid point (a record period, 15.6 ms at 64 Hz)
would show in the records and start a clock piece of its own. So the first unclaimed latch past
a run's last claimed latch has its pulse within ±(record period + association tolerance) of
where the run's line puts it. If exactly one pulse no run claimed lies there, the jump is that
pulse minus the prediction; the clock rate does not change in a jump, so the run continues at
the same rate from there, offset by the jump, and claims each further unclaimed latch whose
pulse the shifted line predicts within the association tolerance (and 5 σ of the latch noise).
The same holds backwards from a run's first latch. A carried run is carried again (a second
jump); it stops at a latch with no pulse where it predicts one.

So only the records between the last latch before the jump and the first latch after it stay
unplaced (`clock_jump`: the jump lies somewhere between them), wherever the jump falls: the loss
is bounded by the pulse spacing.

Never a guess: more than one unclaimed pulse in the window (a pulse train faster than twice a
record period) or none gives nothing, and the records stay flagged. A latch with no pulse of its
own (a spurious latch on the INS input) finds one in the window only if that pulse was not
latched where the run predicts it (else the run claimed it): i.e. only if the INS also missed a
forwarded pulse there.

A carried run's line: the old run's rate, an offset from its own latches; its prediction error
is the offset's (σ/√n) and the rate's over the distance from its latches (the old run's
leverage: σ²/Sxx per second squared).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy.typing as npt

from postproc.sync.coarse import Latches
from postproc.sync.insfit import ClockRun
from postproc.sync.linefit import fit_line

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]

MAX_CARRIES = 64  # carried runs per solve (each needs a jump of its own)


def carry_runs(runs: list[ClockRun], lat: Latches, y: F64, noise_s: float, assoc_s: float,
               period_s: float) -> list[ClockRun]:
    """`runs` plus every run carried across an unshown jump, in (piece, clock) order.
    `y`: the pulses (GPS s of the flight epoch, sorted); `period_s`: the record period."""
    out = sorted(runs, key=lambda r: (r.piece, float(lat.x_s[r.latches[0]])))
    owner = np.full(lat.x_s.size, -1, dtype=np.int64)
    taken = np.zeros(y.size, dtype=np.bool_)
    for i, r in enumerate(out):
        owner[r.latches] = i
        taken[r.pulses] = True
    for _ in range(MAX_CARRIES):
        new = None
        for r in out:
            for direction in (1, -1):
                free = _free_beyond(r, direction, lat, owner)
                new = _carry(r, free, lat, y, taken, noise_s, assoc_s, period_s)
                if new is not None:
                    break
            if new is not None:
                break
        if new is None:
            break
        owner[new.latches] = len(out)
        taken[new.pulses] = True
        out.append(new)
    return sorted(out, key=lambda r: (r.piece, float(lat.x_s[r.latches[0]])))


def _free_beyond(run: ClockRun, direction: int, lat: Latches, owner: I64) -> I64:
    """The unclaimed latches of the run's piece past its last (direction 1) or before its
    first (−1) latch, up to the nearest latch another run claimed; nearest first."""
    piece = np.flatnonzero(lat.piece == run.piece)
    x = lat.x_s[piece]
    if direction > 0:
        edge = float(lat.x_s[run.latches[-1]])
        beyond = piece[x > edge]
    else:
        edge = float(lat.x_s[run.latches[0]])
        beyond = piece[x < edge][::-1]
    claimed = np.flatnonzero(owner[beyond] >= 0)
    return beyond[:claimed[0]] if claimed.size else beyond


def _carry(run: ClockRun, free: I64, lat: Latches, y: F64, taken: Bool, noise_s: float,
           assoc_s: float, period_s: float) -> ClockRun | None:
    """The run carried across a jump before `free[0]`, or None (no unique pulse for it)."""
    if free.size == 0:
        return None
    first = int(free[0])
    predicted = float(run.line(lat.x_s[first]))
    window = period_s + assoc_s
    lo, hi = np.searchsorted(y, [predicted - window, predicted + window + 1e-12])
    candidates = np.arange(lo, hi)[~taken[lo:hi]]
    if candidates.size != 1:
        return None
    jump = float(y[candidates[0]]) - predicted
    tolerance = assoc_s + 5.0 * max(run.line.sigma, noise_s)
    latches, pulses = [first], [int(candidates[0])]
    used = {int(candidates[0])}
    for k in free[1:].tolist():
        want = float(run.line(lat.x_s[k])) + jump
        j = int(np.clip(np.searchsorted(y, want), 1, max(y.size - 1, 1)))
        near = min((j - 1, j), key=lambda i: abs(float(y[i]) - want)) if y.size > 1 else 0
        if abs(float(y[near]) - want) > tolerance or taken[near] or near in used:
            break
        latches.append(k)
        pulses.append(near)
        used.add(near)
    order = np.argsort(lat.x_s[latches], kind="stable")
    lat_i = np.asarray(latches, dtype=np.int64)[order]
    pul_i = np.asarray(pulses, dtype=np.int64)[order]
    line = fit_line(lat.x_s[lat_i], y[pul_i], slope=run.line.slope)
    line = dataclasses.replace(line, sxx=run.line.sxx, sigma=max(run.line.sigma, line.sigma))
    return ClockRun(run.piece, line, lat_i, pul_i)

