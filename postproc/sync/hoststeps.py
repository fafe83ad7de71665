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
changes level at a step (`find_steps`). Each stream (each in log order, the order it was
received in) then has the step taken out of every item received after it
(`unstep_sync_input`): the streams with a time that never steps (the unit's records by their
board time, fixes and tags by their GPS time) by that time; the INS records, the headers and the
photo messages by where the step can fall in them, their receive times fitting the stretch of
clock on either side, in order, each stretch never going back. docs/sync.md, "Host clock steps".
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
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
MISS_OF_STEP: Final = 0.1  # two edges differ by the step to this share of it (a small step
# just before a large one moves the level they are measured from)
TIE_NS: Final = 100_000_000  # a forward and the header tied to it reach the host this close
TIE_ITEMS: Final = 3  # headers either side of a forward's receive time to look among
SPLIT_MARGIN_NS: Final = 50_000_000  # around the span the PPS edges leave for a step
LOG_LEAD_NS: Final = 900 * 1_000_000_000  # a stream may start this long before the first PPS
# edge (a receiver without a fix yet, the scanner tested on the ground)
LOG_TAIL_NS: Final = 60 * 1_000_000_000  # and end this long after the last (the recorder
# stops them all; the receiver may lose its PPS first)
BOARD_REPORT_LATENCY_NS: Final = (-100_000_000, 2_000_000_000)  # a board edge's record reaches
# the host (a forward is logged when its PPS second closes)
MESSAGE_LATENCY_NS: Final = (0, 3_000_000_000)  # a fix or a tag reaches the host after its GPS
# time (a 9600-baud port queues tags behind fixes)
BACK_TOLERANCE_NS: Final = 1_000_000  # a stream's receive times going back by more: a step
# (or half the smallest step back found, if more)
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
    gps_before_ns: int  # the GPS second of the last edge before it
    gps_after_ns: int  # and of the first after it


def find_steps(pps_host_ns: I64, pps_gps_ns: I64) -> list[HostStep]:
    """Level changes of (host − GPS) over the PPS edges with a GPS second, in log order."""
    have = pps_gps_ns > 0
    host, gps = pps_host_ns[have], pps_gps_ns[have]
    if host.size < 2 * LEVEL_POINTS_AT_ENDS:
        return []
    # (host − GPS) less the host crystal's drift (the median rate between edges, steps being
    # few), so the medians either side of a step measure it and not k seconds of drift too
    with np.errstate(all="ignore"):  # receive times beyond sense (a damaged log) find nothing
        raw_level = (host - gps) - (host[0] - gps[0])
        rate = float(np.median(np.diff(raw_level) / np.maximum(np.diff(gps), 1)))
        drift = np.nan_to_num(np.rint(rate * (gps - gps[0]).astype(np.float64)))
        level = raw_level - drift.astype(np.int64)
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
        best = int(np.argmin(miss / np.abs(jump[plateau])))
        here, at = int(plateau[best]), int(b[plateau[best]])
        if miss[best] > max(floor / 2, MISS_OF_STEP * abs(float(jump[here]))):
            # no two edges step by it: its far side is too short to tell (the log's last
            # seconds), or it is no step (a larger one comes in its window: that one's turn)
            i += 1
            continue
        steps.append(HostStep(int(host[at - 1]), int(host[at]), int(jump[here]),
                              int(gps[at - 1]), int(gps[at])))
        i = here + LEVEL_POINTS
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


def split_candidates(t_host_ns: I64, spans_ns: Sequence[tuple[int, int]], k: int, start: int,
                     steps: Sequence[HostStep] = ()) -> I64:
    """Where the step between stretch k and k + 1 can fall in a stream (receive times in log
    order, its stretches before k ending at `start`): every place j where the items from
    `start` to j fit stretch k (`spans_ns`: the receive times each stretch can hold, on its own
    clock) and the rest fit the later stretches, in order. An item that fits none (after a step
    too early in the log to be found) is taken to fit any."""
    n = t_host_ns.size
    fits = [_within(t_host_ns, [span]) for span in spans_ns]
    anywhere = ~np.logical_or.reduce(fits)
    places = np.arange(n + 1)
    # one stretch is one clock: its receive times never go back, so where they go back by half
    # the smallest step back found (`steps`) a stretch ends (a stream taken wholly for the
    # stretch after two steps, the one between them empty, would go back inside it); less, and
    # it may be a step too small to find, or hidden beside a larger one
    backs = [-h.step_ns for h in steps if h.step_ns < 0]
    tolerance = max(BACK_TOLERANCE_NS, min(backs) // 2) if backs else BACK_TOLERANCE_NS
    back = np.flatnonzero(np.diff(t_host_ns) < -tolerance) + 1
    i = np.searchsorted(back, places, side="right")
    next_back = np.where(i < back.size, back[np.minimum(i, max(back.size - 1, 0))], n) \
        if back.size else np.full(n + 1, n)
    # rest_fits[j]: items j.. fit the stretches from e on, in order (e from the last down)
    rest_fits = places == n
    for e in range(len(spans_ns) - 1, k, -1):
        ok = np.flatnonzero(rest_fits)
        if ok.size == 0:
            break  # nothing fits in order: every place is left to the gaps
        next_ok = ok[np.minimum(np.searchsorted(ok, places), ok.size - 1)]
        rest_fits = next_ok <= np.minimum(_next_misfit(fits[e] | anywhere, places), next_back)
    limit = int(min(_next_misfit(fits[k] | anywhere, places[start:start + 1])[0],
                    next_back[start]))
    candidates = np.arange(start, limit + 1)
    feasible = candidates[rest_fits[candidates]]
    return feasible if feasible.size else candidates


def _next_misfit(fit: Bool, places: I64) -> I64:
    """For each place, the first item from it on that does not fit (the stream's length if
    none)."""
    bad = np.flatnonzero(~fit)
    if bad.size == 0:
        return np.full(places.size, fit.size, dtype=np.int64)
    i = np.searchsorted(bad, places)
    return np.where(i < bad.size, bad[np.minimum(i, bad.size - 1)], fit.size)


def split_index(t_host_ns: I64, step_ns: int, candidates: I64,
                votes: tuple[I64, Bool] | None = None) -> int:
    """Of the places a step can fall in a stream (`split_candidates`), the one most `votes`
    agree with (items, and whether each came after the step), then where the stream runs on
    most evenly with the step taken out."""
    n = t_host_ns.size
    if candidates.size == 1:
        return int(candidates[0])
    # each place leaves the stream's other gaps as they are and makes one gap of its own:
    # the fewest gaps out of the ordinary (a hole, or time going back), then the most usual gap
    # at the place (a stream with a hole across a step back longer than its hole could be
    # split inside the next run of items too, making a second hole there)
    usual = _usual_gap(t_host_ns)
    inner = (candidates > 0) & (candidates < n)
    raw_odd = np.zeros(candidates.size, dtype=bool)
    own_odd = np.zeros(candidates.size, dtype=bool)
    closeness = np.full(candidates.size, np.inf)  # a stream's ends make no gap to judge
    j = candidates[inner]
    raw_odd[inner] = _odd(t_host_ns[j] - t_host_ns[j - 1], usual)
    own = t_host_ns[j] - step_ns - t_host_ns[j - 1]
    own_odd[inner] = _odd(own, usual)
    closeness[inner] = np.abs(own - usual[0])
    span = t_host_ns[max(int(candidates[0]) - 1, 0):int(candidates[-1]) + 1]
    odd = int(np.count_nonzero(_odd(np.diff(span), usual))) - raw_odd.astype(int) + \
        own_odd.astype(int)
    against = np.zeros(candidates.size, dtype=np.int64)
    if votes is not None and votes[0].size:
        # a vote for "after" is against every place past its item, "before" up to it
        items, came_after = votes
        after_at = np.sort(items[came_after])
        before_at = np.sort(items[~came_after])
        against = (np.searchsorted(after_at, candidates) +
                   before_at.size - np.searchsorted(before_at, candidates))
    best = np.lexsort((closeness, odd, against))[0]
    return int(candidates[best])


def _within(t_ns: I64, spans: Sequence[tuple[int, int]]) -> Bool:
    """Whether each time lies in any of the spans."""
    inside = np.zeros(t_ns.size, dtype=bool)
    for lo, hi in spans:
        inside |= (t_ns >= lo) & (t_ns <= hi)
    return inside


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


def unstep_stream(t_host_ns: I64, steps: list[HostStep], eras: list[tuple[int, int]],
                  votes: Callable[[int], tuple[I64, Bool]] | None = None, pin: bool = False
                  ) -> I64:
    """A stream's receive times with each step taken out of the items after it, where
    `split_candidates` and `split_index` place it (`votes(k)`: tied items' votes on step k).
    `pin`: the stream is continuous (the INS records), and where it runs on evenly across a
    step it pins the step's moment in `eras` for the streams after it; a sparse stream, whose
    gaps can hide a small step among its own, never does."""
    out = t_host_ns.copy()
    usual = _usual_gap(t_host_ns)
    start = 0
    for k, step in enumerate(steps):
        s = step.step_ns
        j = start = split_index(t_host_ns, s, split_candidates(t_host_ns, eras, k, start, steps),
                                None if votes is None else votes(k))
        out[j:] -= s
        if pin and 0 < j < t_host_ns.size and not _odd(
                t_host_ns[j:j + 1] - s - t_host_ns[j - 1:j], usual)[0]:
            # the stream ran on across it: the step came between these two items
            eras[k] = (eras[k][0], min(eras[k][1], int(t_host_ns[j] - s) + MOMENT_MARGIN_NS))
            eras[k + 1] = (max(eras[k + 1][0], int(t_host_ns[j - 1]) + s - MOMENT_MARGIN_NS),
                           eras[k + 1][1])
    return out


def era_spans(steps: list[HostStep], log_ns: tuple[int, int]) -> list[tuple[int, int]]:
    """The receive times each stretch between steps can hold, on its own clock: from the
    moment of the step before it to the moment of the step after it (each known to the two PPS
    edges around it, SPLIT_MARGIN_NS wider); the first from the log's first receive time
    (LOG_LEAD_NS earlier), the last to its last (LOG_TAIL_NS later). Without those two ends, a
    stream that came wholly after a step back of an hour could have come, by its times alone,
    before the first step."""
    lower = [log_ns[0] - LOG_LEAD_NS] + [h.last_before_ns + h.step_ns - SPLIT_MARGIN_NS
                                         for h in steps]
    upper = [h.first_after_ns - h.step_ns + SPLIT_MARGIN_NS for h in steps] + [
        log_ns[1] + LOG_TAIL_NS]
    return list(zip(lower, upper, strict=True))


def anchored_stretch(t_host_ns: I64, t_gps_ns: I64, latency_ns: tuple[int, int],
                     steps: list[HostStep], eras: list[tuple[int, int]]) -> I64:
    """How many steps came before each item of a stream whose items carry a time of their own
    that never steps (`t_gps_ns`: the GPS time of the edge, the epoch or the event; −1
    unknown), reaching the host `latency_ns` after it: an item is after a step if it reached
    the host after the step's moment (between the two PPS edges around it). Where the latency
    leaves it open, or the time is unknown, its receive time decides if it fits only the
    stretch after the step (`eras`, as the densest stream left them)."""
    known = t_gps_ns >= 0
    count = np.zeros(t_host_ns.size, dtype=np.int64)
    for k, step in enumerate(steps):
        # the moment, as the densest stream pinned it on the clock before the step, in GPS
        # time by the last PPS edge before it (its report's latency aside, a few ms)
        offset = step.last_before_ns - step.gps_before_ns
        moment_lo = max(step.gps_before_ns, eras[k + 1][0] - step.step_ns - offset)
        moment_hi = min(step.gps_after_ns, eras[k][1] - offset)
        surely_after = known & (t_gps_ns + latency_ns[0] > moment_hi)
        surely_before = known & (t_gps_ns + latency_ns[1] < moment_lo)
        fits_after = _within(t_host_ns, [eras[k + 1]]) & ~_within(t_host_ns, [eras[k]])
        count += surely_after | (~surely_before & ~surely_after & fits_after)
    return count


def _taken_out(t_host_ns: I64, stretch: I64, steps: list[HostStep]) -> I64:
    """Receive times with the steps before each item's stretch taken out."""
    before = np.concatenate([[0], np.cumsum([h.step_ns for h in steps])]).astype(np.int64)
    return t_host_ns - before[np.clip(stretch, 0, len(steps))]


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
    order = np.argsort(hdr_t, kind="stable")  # a step back leaves them out of order
    near = np.searchsorted(hdr_t[order], t_f)
    best = np.full(fwd.size, -1, dtype=np.int64)
    best_dt = np.full(fwd.size, TIE_NS + 1, dtype=np.int64)
    for k in range(-TIE_ITEMS, TIE_ITEMS + 1):
        h = order[np.clip(near + k, 0, hdr_t.size - 1)]
        dt = np.abs(hdr_t[h] - t_f)
        better = (hdr_c[h] == c_f) & (dt < best_dt)
        best[better], best_dt[better] = h[better], dt[better]
    found = best >= 0
    return best[found], fwd[found]


def unstep_sync_input(inp: SyncInput, steps: list[HostStep],
                      board_to_gps: Callable[[I64], I64] | None) -> SyncInput:
    """The log's every receive time with the steps taken out. The INS records, the headers and
    the photo messages by where the steps fall in them (`unstep_stream`; the headers by their
    ties to the forwarded frame pulses where they alone cannot tell); the fixes and tags by
    their GPS time, the sync unit's records by their board time through GPS (`board_to_gps`,
    the sync's board map, which takes no receive time; None: by their receive times alone)
    (`anchored_stretch`): a sparse stream's gaps can hide a step back as long as one of them."""
    if not steps:
        return inp
    g, sisa, hdr, cam = inp.gps, inp.sisa, inp.headers, inp.camera
    pps = sisa.pps_t_host_ns  # steps are found between PPS edges, so there are some
    eras = era_spans(steps, (int(pps[0]), int(pps[-1])))
    ins_t = unstep_stream(inp.ins.t_host_ns, steps, eras, pin=True)
    photo_t = unstep_stream(cam.photo_t_host_ns, steps, eras)

    def by_board(board_ns: I64) -> I64:
        return board_to_gps(board_ns) if board_to_gps is not None else np.full(board_ns.size, -1)

    def stretch(t_host_ns: I64, t_gps_ns: I64, latency_ns: tuple[int, int]) -> I64:
        return anchored_stretch(t_host_ns, t_gps_ns, latency_ns, steps, eras)

    fwd_stretch = stretch(sisa.fwd_t_host_ns, by_board(sisa.fwd_board_ns),
                          BOARD_REPORT_LATENCY_NS)
    hdr_items, fwd_items = frame_ties(inp)
    hdr_t = unstep_stream(hdr.t_host_ns, steps, eras,
                          votes=lambda k: (hdr_items, fwd_stretch[fwd_items] > k))
    return dataclasses.replace(
        inp, ins=dataclasses.replace(inp.ins, t_host_ns=ins_t),
        gps=dataclasses.replace(
            g, fix_t_host_ns=_taken_out(g.fix_t_host_ns, stretch(
                g.fix_t_host_ns, g.fix_t_gps_ns, MESSAGE_LATENCY_NS), steps),
            tag_t_host_ns=_taken_out(g.tag_t_host_ns, stretch(
                g.tag_t_host_ns, g.tag_t_gps_ns, MESSAGE_LATENCY_NS), steps)),
        sisa=dataclasses.replace(
            sisa, fwd_t_host_ns=_taken_out(sisa.fwd_t_host_ns, fwd_stretch, steps),
            pps_t_host_ns=_taken_out(pps, stretch(pps, by_board(sisa.pps_board_ns),
                                                  BOARD_REPORT_LATENCY_NS), steps)),
        headers=dataclasses.replace(hdr, t_host_ns=hdr_t),
        camera=dataclasses.replace(
            cam, photo_t_host_ns=photo_t,
            pulse_t_host_ns=_taken_out(cam.pulse_t_host_ns, stretch(
                cam.pulse_t_host_ns, by_board(cam.pulse_board_ns), BOARD_REPORT_LATENCY_NS),
                steps)))

