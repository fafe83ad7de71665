"""Steps of the logging computer's clock: found, and taken out of every host receive time.

SISA's recorder stamps receive times on a clock that never steps (`sisa record` runs the
system clock's reading at start on by the raw monotonic clock). A log written on the system
clock itself — an older recorder, another logger — carries every step the clock made in flight:
chrony's `makestep` setting it once it hears the receiver, a leap second, an operator. Every
later receive time moves by the step, and the sync's host → GPS map is one line: the far side of
a step would be placed seconds off, and a step near a multiple of the PPS pattern's period (15 s
for 4 bits) or of the frame counter's wrap matches as well there as the truth.

A step shows in the PPS edges the sync unit logged: host time − GPS second, in log order, keeps
one level (the report's latency, a few ms) but for the slow drift of the host's crystal, and
changes level at a step. Each step is found as a change of the running median over
LEVEL_POINTS edges on either side, and its size is the difference of those medians. In each
stream (INS records, headers, fixes, tags, the unit's own records; each in log order, the
order they were received in) the step falls between the last item received before it and the
first after: where the stream's receive times jump by the step (forward) or go back (back),
within the span the PPS edges leave for it. The step is taken out of every item after it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt
from numpy.lib.stride_tricks import sliding_window_view

from postproc.sync.flightlog import SyncInput

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]

STEP_MIN_NS: Final = 20_000_000  # smaller level changes are latency, and harmless to a map
STEP_SCATTER_SIGMAS: Final = 10.0  # and a step is this many times the edges' own scatter
LEVEL_POINTS: Final = 9  # PPS edges either side that set a level (a stall of fewer cannot)
LEVEL_POINTS_AT_ENDS: Final = 5  # as few at the log's ends (a step in its last seconds)
TIE_NS: Final = 100_000_000  # a forward and the header tied to it reach the host this close
TIE_ITEMS: Final = 3  # headers either side of a forward's receive time to look among
SPLIT_MARGIN_NS: Final = 50_000_000  # around the span the PPS edges leave for a step
MOMENT_MARGIN_NS: Final = 5_000_000  # around the span a stream that runs across it leaves
EVEN_GAP: Final = 3.0  # a gap up to this many of a stream's median (or its 95th percentile)
# is ordinary; a split whose stream, unstepped, runs on so pins the step's moment for the rest


@dataclass(frozen=True)
class HostStep:
    """The host clock set by `step_ns` between two PPS edges' receive times (both as logged:
    `last_before_ns` on the clock before the step, `first_after_ns` on the clock after it)."""

    last_before_ns: int
    first_after_ns: int
    step_ns: int
    gps_ns: int  # the GPS second of the first edge after it


def find_steps(pps_host_ns: I64, pps_gps_ns: I64) -> list[HostStep]:
    """Level changes of (host − GPS) over the PPS edges with a GPS second, in log order."""
    have = pps_gps_ns > 0
    host, gps = pps_host_ns[have], pps_gps_ns[have]
    if host.size < 2 * LEVEL_POINTS_AT_ENDS:
        return []
    # (host − GPS) less the host crystal's drift (the median rate between edges, steps being
    # few), so the medians either side of a step measure it and not k seconds of drift too
    raw_level = (host - gps) - (host[0] - gps[0])
    rate = float(np.median(np.diff(raw_level) / np.maximum(np.diff(gps), 1)))
    level = raw_level - np.rint(rate * (gps - gps[0]).astype(np.float64)).astype(np.int64)
    b, before, after = _levels(level)
    jump = after - before
    scatter = 1.4826 * float(np.median(np.abs(np.diff(level) - np.median(np.diff(level)))))
    floor = max(STEP_MIN_NS, STEP_SCATTER_SIGMAS * scatter)
    steps: list[HostStep] = []
    i = 0
    while i < b.size:
        if abs(jump[i]) <= floor:
            i += 1
            continue
        # a step leaves a plateau of boundaries about LEVEL_POINTS wide: the exact one is where
        # the two neighbouring edges differ by the step
        plateau = np.arange(i, min(i + LEVEL_POINTS, b.size))
        plateau = plateau[np.abs(jump[plateau]) > floor]
        miss = np.abs(level[b[plateau]] - level[b[plateau] - 1] - jump[plateau])
        here = plateau[np.argmin(miss)]
        at = int(b[here])
        if miss.min() > floor / 2:  # no two edges step by it: its far side is too short to
            i = int(here) + LEVEL_POINTS  # tell (a log's last seconds), or it is no step
            continue
        steps.append(HostStep(int(host[at - 1]), int(host[at]), int(jump[here]), int(gps[at])))
        i = int(here) + LEVEL_POINTS
    return steps


def _levels(level: I64) -> tuple[I64, F64, F64]:
    """Every boundary b (between edges b − 1 and b) with the median level of the LEVEL_POINTS
    edges before it and after it (fewer at the log's ends, at least LEVEL_POINTS_AT_ENDS)."""
    n, k, m = level.size, LEVEL_POINTS, LEVEL_POINTS_AT_ENDS
    b = np.arange(m, n - m + 1)
    before, after = np.empty(b.size), np.empty(b.size)
    if n >= 2 * k:
        median = np.median(sliding_window_view(level, k), axis=1)  # median[i]: level[i:i + k]
        inner = (b >= k) & (b <= n - k)
        before[inner], after[inner] = median[b[inner] - k], median[b[inner]]
    else:
        inner = np.zeros(b.size, dtype=bool)
    for i in np.flatnonzero(~inner).tolist():
        at = int(b[i])
        before[i] = np.median(level[max(0, at - k):at])
        after[i] = np.median(level[at:at + k])
    return b, before, after


def split_index(t_host_ns: I64, step_ns: int, moment_ns: tuple[int, int], start: int = 0,
                votes: tuple[I64, Bool] | None = None) -> int:
    """Index of the first item of a stream (receive times in log order, the items before
    `start` received before an earlier step) received after the step, which came between
    `moment_ns` on the clock before it: of the places it can be, the one most `votes` agree
    with (items, and whether each came after the step), then where the stream runs on most
    evenly with the step taken out."""
    n = t_host_ns.size
    # an item before the step came before its moment, an item after it after that moment (on
    # the stepped clock)
    rest = t_host_ns[start:]
    late = np.flatnonzero(rest > moment_ns[1])
    hi = start + (int(late[0]) if late.size else rest.size)  # from here on every item is after
    early = np.flatnonzero(t_host_ns[start:hi] < moment_ns[0] + step_ns)
    lo = start + (int(early[-1]) + 1 if early.size else 0)  # before here every item is before
    if lo >= hi:
        return hi
    # each place leaves the stream's other gaps as they are and makes one gap of its own:
    # the fewest gaps out of the ordinary (a hole, or time going back), then the most usual gap
    # at the place (a stream with a hole across a step back longer than its hole could be
    # split inside the next run of items too, making a second hole there)
    usual = _usual_gap(t_host_ns)
    candidates = np.arange(lo, hi + 1)
    inner = (candidates > 0) & (candidates < n)
    raw_odd = np.zeros(candidates.size, dtype=bool)
    own_odd = np.zeros(candidates.size, dtype=bool)
    closeness = np.full(candidates.size, np.inf)  # a stream's ends make no gap to judge
    j = candidates[inner]
    raw_odd[inner] = _odd(t_host_ns[j] - t_host_ns[j - 1], usual)
    own = t_host_ns[j] - step_ns - t_host_ns[j - 1]
    own_odd[inner] = _odd(own, usual)
    closeness[inner] = np.abs(own - usual[0])
    odd = int(np.count_nonzero(raw_odd)) - raw_odd.astype(int) + own_odd.astype(int)
    against = np.zeros(candidates.size, dtype=np.int64)
    if votes is not None and votes[0].size:
        # a vote for "after" is against every place past its item, "before" up to it
        items, after = votes
        after_at = np.sort(items[after])
        before_at = np.sort(items[~after])
        against = (np.searchsorted(after_at, candidates) +
                   before_at.size - np.searchsorted(before_at, candidates))
    best = np.lexsort((closeness, odd, against))[0]
    return int(candidates[best])


def _usual_gap(t_host_ns: I64) -> tuple[float, float]:
    """The stream's median gap and the longest it makes out of the ordinary: EVEN_GAP medians,
    or its 95th percentile where its gaps vary (forwards gated by the PPS pattern)."""
    if t_host_ns.size < 2:
        return 0.0, 0.0
    gaps = np.diff(t_host_ns)
    median = float(np.median(gaps))
    return median, max(EVEN_GAP * median, float(np.percentile(gaps, 95)))


def _odd(gap_ns: I64, usual: tuple[float, float]) -> npt.NDArray[np.bool_]:
    """Gaps out of the ordinary: a hole, or time going back."""
    return np.asarray((gap_ns < 0) | (gap_ns > usual[1]), dtype=np.bool_)


@dataclass(frozen=True)
class Ties:
    """Items of two streams received together (a forwarded frame pulse and the header the sync
    unit tied it to, within ms): on the same side of a step but where it fell between them."""

    stream: int
    partner: int
    items: I64
    partner_items: I64


def unstep_streams(streams: list[I64], steps: list[HostStep], ties: Sequence[Ties] = ()
                   ) -> list[I64]:
    """Every stream's receive times with each step taken out of the items after it.

    A step's moment is first known to the span between the two PPS edges around it. The
    densest streams (the INS records) are split first, and a split where the stream runs on
    evenly pins the moment for the others. A stream with a hole across the step can still be
    split in more than one place alike (headers with the scanner off across a step back longer
    than the hole: the next run of headers may have come before the step or after it); its
    ties to a stream already split decide, as most of them vote."""
    if not steps:
        return streams
    out = [t.copy() for t in streams]
    starts = [0] * len(streams)
    tied = {t.stream: t for t in ties}
    order = sorted(range(len(streams)), key=lambda i: (i in tied, -streams[i].size))
    for step in steps:
        s = step.step_ns
        moment = (step.last_before_ns - SPLIT_MARGIN_NS, step.first_after_ns - s + SPLIT_MARGIN_NS)
        splits: dict[int, int] = {}
        for i in order:
            t = streams[i]
            votes = None
            if i in tied:
                tie = tied[i]
                votes = (tie.items, tie.partner_items >= splits[tie.partner])
            j = split_index(t, s, moment, starts[i], votes)
            splits[i] = starts[i] = j
            out[i][j:] -= s
            if 0 < j < t.size and not _odd(t[j:j + 1] - s - t[j - 1:j], _usual_gap(t))[0]:
                moment = (max(moment[0], int(t[j - 1]) - MOMENT_MARGIN_NS),
                          min(moment[1], int(t[j] - s) + MOMENT_MARGIN_NS))
    return out


def frame_ties(inp: SyncInput) -> tuple[I64, I64]:
    """The headers the sync unit tied its forwarded frame pulses to, and those forwards: the
    header with the forward's frame counter nearest it in receive time, within TIE_NS."""
    hdr_t, hdr_c = inp.headers.t_host_ns, inp.headers.frame_counter
    sisa = inp.sisa
    fwd = np.flatnonzero(sisa.fwd_is_ppf & (sisa.fwd_frame_counter >= 0))
    if fwd.size == 0 or hdr_t.size == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty
    t_f, c_f = sisa.fwd_t_host_ns[fwd], sisa.fwd_frame_counter[fwd]
    near = np.searchsorted(hdr_t, t_f)
    best = np.full(fwd.size, -1, dtype=np.int64)
    best_dt = np.full(fwd.size, TIE_NS + 1, dtype=np.int64)
    for k in range(-TIE_ITEMS, TIE_ITEMS + 1):
        h = np.clip(near + k, 0, hdr_t.size - 1)
        dt = np.abs(hdr_t[h] - t_f)
        better = (hdr_c[h] == c_f) & (dt < best_dt)
        best[better], best_dt[better] = h[better], dt[better]
    found = best >= 0
    return best[found], fwd[found]


def unstep_sync_input(inp: SyncInput, steps: list[HostStep]) -> SyncInput:
    """The log's every receive time with the steps taken out (the headers by their ties to
    the forwarded frame pulses where they alone cannot tell)."""
    if not steps:
        return inp
    g, sisa, hdr, cam = inp.gps, inp.sisa, inp.headers, inp.camera
    streams = [hdr.t_host_ns, sisa.fwd_t_host_ns, inp.ins.t_host_ns, g.fix_t_host_ns,
               g.tag_t_host_ns, sisa.pps_t_host_ns, cam.pulse_t_host_ns, cam.photo_t_host_ns]
    (hdr_t, fwd_t, ins_t, fix_t, tag_t, pps_t, cam_t, photo_t) = unstep_streams(
        streams, steps, [Ties(0, 1, *frame_ties(inp))])
    return dataclasses.replace(
        inp, ins=dataclasses.replace(inp.ins, t_host_ns=ins_t),
        gps=dataclasses.replace(g, fix_t_host_ns=fix_t, tag_t_host_ns=tag_t),
        sisa=dataclasses.replace(sisa, pps_t_host_ns=pps_t, fwd_t_host_ns=fwd_t),
        headers=dataclasses.replace(hdr, t_host_ns=hdr_t),
        camera=dataclasses.replace(cam, pulse_t_host_ns=cam_t, photo_t_host_ns=photo_t))
