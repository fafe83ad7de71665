"""Every scan line its GPS time, propagated from the few frames the GPS receiver tagged.

- The scanner's frame counter wraps (the width is not logged: the modulus is the power of two
  above the largest counter seen, at least 2^8) and runs on across segments. Per recording
  segment it is unwrapped; a step of k means k − 1 frames exposed but not recorded (dropped).
  Between frame headers, the host receive times say how many frames passed, so a gap longer
  than the modulus is still counted right.
- A forwarded frame pulse names its frame by counter; it is placed on its segment's unwrapped
  axis through the header nearest in time (the counter step to it, taken modulo the wrap, is
  small), and its GPS time (TTT, or the timing board) less the box's gate delay is the frame's
  mid-exposure.
- The line clock is a free-running oscillator: per segment, mid-exposure time is a line in the
  unwrapped counter (period and phase; drift is the period's departure from nominal). A segment
  with a single timed frame borrows the period of the others. A line is timed from its counter
  up to `line_max_extrapolation_s` (or 1.5 timed-frame spacings) beyond the timed frames.
- Lines come from the scanner's own `.lines.csv` files (line index → frame counter) when given,
  aligned to the header axis by whole wraps; else from the headers themselves (line = header
  order in its segment, which counts only headers that reached the log).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from postproc.sync.clockmap import ClockMap
from postproc.sync.config import SyncConfig, TimeStatus
from postproc.sync.flightlog import HeaderColumns
from postproc.sync.linefit import Line, robust_line
from postproc.sync.pulses import GATE_DELAY_NS, SisaPulses

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]

MIN_COUNTER_BITS: Final = 8
LINE_SIGMA_FLOOR_S: Final = 100e-9  # line-clock jitter and tag resolution
MAX_WRAP_SHIFT: Final = 4  # lines file vs headers: whole wraps tried either way
EARLY_HEADER_FLOOR_S: Final = 0.5e-3  # a header before its frame's mid-exposure by more: early
EARLY_HEADER_HOST_SIGMAS: Final = 5.0  # ... plus this many of the host map's residual RMS
SUSPECT_HEADERS_MIN: Final = 3  # a segment with this many suspect headers (and ≥ 1 %) is refused


@dataclass(frozen=True)
class LineTable:
    """Recorded lines: segment, line index in its segment file, raw frame counter."""

    segment: I64
    line: I64
    frame_counter: I64


@dataclass(frozen=True)
class SegmentFit:
    segment: int
    line: Line | None  # x: unwrapped counter − ref, y: GPS s of the flight epoch
    ref: int  # unwrapped counter of x = 0
    frames_timed: int
    frames_rejected: int
    borrowed_period: bool
    spacing: float = 0.0  # median step between timed frames (frames)


def by_segment(segment: I64) -> list[tuple[int, I64]]:
    """(segment, indices of its items in their order) for every segment, ascending: one sort
    instead of a mask over all items per segment (52 segments of a 5 h flight made that
    quadratic)."""
    if segment.size == 0:
        return []
    order = np.argsort(segment, kind="stable")
    s = segment[order]
    starts = np.flatnonzero(np.concatenate([[True], s[1:] != s[:-1]]))
    return list(zip(s[starts].tolist(), np.split(order, starts[1:]), strict=True))


def counter_modulus(*counters: I64) -> int:
    top = max((int(c.max()) for c in counters if c.size), default=0)
    return 1 << max(MIN_COUNTER_BITS, math.ceil(math.log2(top + 1)) if top > 0 else 0)


def _steps(counter: I64, modulus: int) -> I64:
    return np.mod(np.diff(counter), modulus)


def unwrap_headers(hdr: HeaderColumns, modulus: int, period_s: float) -> I64:
    """Unwrapped counter of every header, per segment; host-time gaps add whole wraps."""
    u = np.empty(hdr.frame_counter.size, dtype=np.int64)
    for _, idx in by_segment(hdr.segment):
        c, t = hdr.frame_counter[idx], hdr.t_host_ns[idx]
        dc = _steps(c, modulus)
        frames = np.diff(t).astype(np.float64) * 1e-9 / period_s
        wraps = np.rint((frames - dc) / modulus).astype(np.int64)
        u[idx] = c[0] + np.concatenate([[0], np.cumsum(dc + modulus * np.maximum(wraps, 0))])
    return u


def header_period_s(hdr: HeaderColumns, modulus: int) -> float:
    """Host-time interval of headers one frame apart (coarse: host jitter): their median, or
    their mean when a read holds several headers (a line period below the recorder's read
    clock: most intervals are 0, and a 0 period divided the wrap count by zero); 1 s when the
    headers do not tell."""
    period = measured_header_period_s(hdr, modulus)
    return 1.0 if period is None else period


def measured_header_period_s(hdr: HeaderColumns, modulus: int) -> float | None:
    """The line period the headers' host times show (see header_period_s); None if no two
    headers one frame apart tell it."""
    same = hdr.segment[1:] == hdr.segment[:-1]
    one = same & (_steps(hdr.frame_counter, modulus) == 1)
    dt = np.diff(hdr.t_host_ns)[one]
    if dt.size == 0:
        return None
    median_ns = float(np.median(dt))
    mean_ns = float(dt.mean())
    if median_ns > 0:
        return median_ns * 1e-9
    return mean_ns * 1e-9 if mean_ns > 0 else None


def place_forwards(pulses: SisaPulses, hdr: HeaderColumns, u_hdr: I64, hdr_gps_ns: I64,
                   modulus: int) -> tuple[I64, I64, I64]:
    """Segment and unwrapped counter of each timed, counted frame pulse (indices, seg, u)."""
    fwd = np.flatnonzero(pulses.usable & (pulses.frame_counter >= 0))
    if fwd.size == 0 or hdr_gps_ns.size == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, empty
    order = np.argsort(hdr_gps_ns, kind="stable")
    t_sorted = hdr_gps_ns[order]
    j = np.searchsorted(t_sorted, pulses.t_gps_ns[fwd])
    lo, hi = np.clip(j - 1, 0, t_sorted.size - 1), np.clip(j, 0, t_sorted.size - 1)
    t_f = pulses.t_gps_ns[fwd]
    near = np.where(np.abs(t_sorted[lo] - t_f) <= np.abs(t_sorted[hi] - t_f), lo, hi)
    h = order[near]
    half = modulus // 2
    step = np.mod(pulses.frame_counter[fwd] - hdr.frame_counter[h] + half, modulus) - half
    return fwd, hdr.segment[h], u_hdr[h] + step


def fit_segment(seg: int, x: F64, y: F64, ref: int, period_s: float | None) -> SegmentFit:
    """Mid-exposure time against the unwrapped counter; one point borrows the period."""
    if x.size == 0 or (x.size == 1 and period_s is None):
        return SegmentFit(seg, None, ref, 0, int(x.size), False)
    borrow = x.size == 1 or float(np.ptp(x)) == 0.0
    slope = period_s if borrow else None
    line, inliers = robust_line(x, y, sigma_floor=LINE_SIGMA_FLOOR_S, slope=slope)
    n_in = int(np.count_nonzero(inliers))
    steps = np.diff(np.sort(x[inliers]))
    spacing = float(np.median(steps)) if steps.size else 0.0
    return SegmentFit(seg, line, ref, n_in, int(x.size) - n_in, borrow, spacing)


def segment_fits(seg_of_fwd: I64, u_fwd: I64, t_fwd_ns: I64, segments: I64, refs: I64,
                 epoch_ns: int) -> list[SegmentFit]:
    """One fit per segment; single-frame segments borrow the median fitted period."""
    y = (t_fwd_ns - GATE_DELAY_NS - epoch_ns).astype(np.float64) * 1e-9
    first = [fit_segment(int(s), (u_fwd[seg_of_fwd == s] - r).astype(np.float64),
                         y[seg_of_fwd == s], int(r), None)
             for s, r in zip(segments.tolist(), refs.tolist(), strict=True)]
    periods = [f.line.slope for f in first if f.line is not None]
    if not periods:
        return first
    period = float(np.median(periods))
    return [f if f.line is not None else
            fit_segment(f.segment, (u_fwd[seg_of_fwd == f.segment] - f.ref).astype(np.float64),
                        y[seg_of_fwd == f.segment], f.ref, period)
            for f in first]


def _fitted_headers(fits: list[SegmentFit], hdr: HeaderColumns, u_hdr: I64
                    ) -> Iterator[tuple[int, Line, I64, F64]]:
    """Per fitted segment: its number, its fit, the indices of its headers within the fit's
    span, and their x."""
    by_seg = dict(by_segment(hdr.segment))
    for f in fits:
        idx = by_seg.get(f.segment)
        if f.line is None or idx is None:
            continue
        x = (u_hdr[idx] - f.ref).astype(np.float64)
        inside = (x >= f.line.x_min) & (x <= f.line.x_max)
        yield f.segment, f.line, idx[inside], x[inside]


def early_headers(fits: list[SegmentFit], hdr: HeaderColumns, u_hdr: I64, hdr_gps_ns: I64,
                  epoch_ns: int, tolerance_s: float) -> dict[int, tuple[int, int]]:
    """Per fitted segment: its headers that reached the host before their own frame's
    mid-exposure (by more than `tolerance_s`, the host map's error), and its headers checked.

    A header describes a frame the scanner has exposed, so it cannot reach the host before the
    exposure's middle. When the header window does not fit the scanner's latency, the sync
    filter ties each header to the next frame's pulse and every later counter agrees with that
    tie (docs/sync.md, Limits): the fit then puts every frame one line period late, and headers
    whose latency is shorter than a line period come out before their frame."""
    out: dict[int, tuple[int, int]] = {}
    for seg, line, idx, x in _fitted_headers(fits, hdr, u_hdr):
        arrived_s = (hdr_gps_ns[idx] - epoch_ns).astype(np.float64) * 1e-9
        out[seg] = (int(np.count_nonzero(arrived_s < line(x) - tolerance_s)), int(idx.size))
    return out


def neighbour_ties(fits: list[SegmentFit], hdr: HeaderColumns, u_hdr: I64, hdr_gps_ns: I64,
                   epoch_ns: int, window_ms: tuple[float, float]) -> dict[int, tuple[int, int]]:
    """Per fitted segment: its headers that, on time alone, fall in another frame's header
    window (the frame before or after theirs, on the fit), and its headers that fall in one
    frame's window at all.

    The sync filter ties a header to the one frame pulse its window (ms after the frame's end)
    holds, and every later counter follows from that tie. A window that holds the latency of
    some headers and not of others puts those in a neighbour's window: the first tie of a
    stretch may then have been either kind, and the whole stretch a line period wrong either
    way; headers that come before their frame show only one of the two (`early_headers`).
    Skipped (empty) for a window not narrower than a line period (no tie on time alone is
    made) or headers without their integration time."""
    out: dict[int, tuple[int, int]] = {}
    if hdr.integration_time_us is None:
        return out
    lo_s, hi_s = window_ms[0] * 1e-3, window_ms[1] * 1e-3
    for seg, line, idx, x in _fitted_headers(fits, hdr, u_hdr):
        if hi_s - lo_s >= abs(line.slope):
            continue
        after_end_s = ((hdr_gps_ns[idx] - epoch_ns).astype(np.float64) * 1e-9 - line(x)
                       - hdr.integration_time_us[idx] * 0.5e-6)
        frames_s = after_end_s[:, None] - np.array([-2, -1, 0, 1, 2]) * line.slope
        ties = (frames_s >= lo_s) & (frames_s <= hi_s)  # header × frame offset −2 … 2
        tied = ties.any(axis=1)
        out[seg] = (int(np.count_nonzero(tied & ~ties[:, 2])), int(np.count_nonzero(tied)))
    return out


def suspect_segments(check: dict[int, tuple[int, int]]) -> dict[int, tuple[int, int]]:
    """The segments of a check's counts (found, checked) that fail it: SUSPECT_HEADERS_MIN
    headers found, and 1 % of those checked."""
    return {seg: (n, k) for seg, (n, k) in check.items()
            if n >= max(SUSPECT_HEADERS_MIN, 0.01 * k)}


def refuse_segments(fits: list[SegmentFit], segments: Collection[int]) -> list[SegmentFit]:
    """These segments lose their fit: their lines are flagged `no_pulses`, not timed a line
    period wrong."""
    return [SegmentFit(f.segment, None, f.ref, 0, f.frames_timed + f.frames_rejected, False)
            if f.segment in segments else f for f in fits]


def align_lines(table: LineTable, hdr: HeaderColumns, u_hdr: I64, modulus: int
                ) -> tuple[I64, Bool]:
    """Unwrapped counter of every line of the files, on its segment's header axis; False
    where the segment has no header to align to."""
    u = np.zeros(table.frame_counter.size, dtype=np.int64)
    linked = np.zeros(table.frame_counter.size, dtype=np.bool_)
    hdr_of = dict(by_segment(hdr.segment))
    for seg, idx in by_segment(table.segment):
        c = table.frame_counter[idx]
        u_l = c[0] + np.concatenate([[0], np.cumsum(_steps(c, modulus))])
        if seg not in hdr_of:
            continue
        u_h = u_hdr[hdr_of[seg]]
        shifts = np.arange(-MAX_WRAP_SHIFT, MAX_WRAP_SHIFT + 1) * modulus
        hits = [np.count_nonzero(np.isin(u_l + s, u_h)) for s in shifts]
        best = int(np.argmax(hits))
        if hits[best] == 0:
            continue
        u[idx], linked[idx] = u_l + shifts[best], True
    return u, linked


def time_lines(segment: I64, u: I64, linked: Bool, fits: list[SegmentFit], epoch_ns: int,
               cfg: SyncConfig) -> tuple[I64, I64]:
    """GPS ns and TimeStatus of every line."""
    t = np.full(u.size, -1, dtype=np.int64)
    status = np.full(u.size, int(TimeStatus.UNLINKED), dtype=np.int64)
    by_seg = {f.segment: f for f in fits}
    for seg, idx in by_segment(segment):
        sel = idx[linked[idx]]
        f = by_seg.get(seg)
        if f is None or f.line is None:
            status[sel] = TimeStatus.NO_PULSES
            continue
        x = (u[sel] - f.ref).astype(np.float64)
        reach = max(cfg.line_max_extrapolation_s / abs(f.line.slope) if f.line.slope else 0.0,
                    1.5 * f.spacing)
        inside = (x >= f.line.x_min - reach) & (x <= f.line.x_max + reach)
        status[sel] = np.where(inside, TimeStatus.OK, TimeStatus.OUTSIDE_FIT)
        t[sel[inside]] = epoch_ns + np.rint(f.line(x[inside]) * 1e9).astype(
            np.int64)
    shared = np.flatnonzero(linked)[_claims_shared(segment[linked], u[linked])]
    t[shared], status[shared] = -1, TimeStatus.AMBIGUOUS
    return t, status


def _claims_shared(segment: I64, u: I64) -> Bool:
    """Lines that claim one frame with another line of their segment (a lines file listing a
    frame counter twice): which of them the frame was is unknown, so neither is timed. Both
    took the frame's time, flagged OK (found by a bad-input sweep)."""
    order = np.lexsort((u, segment))
    s, v = segment[order], u[order]
    same = (s[1:] == s[:-1]) & (v[1:] == v[:-1])
    shared = np.zeros(u.size, dtype=np.bool_)
    shared[order[1:][same]] = True
    shared[order[:-1][same]] = True
    return shared


def frame_drops(table: LineTable, modulus: int) -> int:
    """Counter steps beyond one, within segments: in the lines files, frames exposed but not
    recorded; in the frame headers, frames whose header is missing (a dropped frame has none,
    but a header lost or damaged on the serial link is missing as well)."""
    same = table.segment[1:] == table.segment[:-1]
    return int(np.sum(np.maximum(_steps(table.frame_counter, modulus) - 1, 0)[same]))


def headers_lost(table: LineTable, hdr: HeaderColumns, u_line: I64, linked: Bool,
                 u_hdr: I64) -> int:
    """Recorded lines (of the lines files) whose frame header is not in the log: lost or damaged
    on the way (a line of a segment no header ties to the log counts too)."""
    lost = int(np.count_nonzero(~linked))
    hdr_of = dict(by_segment(hdr.segment))
    for seg, idx in by_segment(table.segment):
        sel = idx[linked[idx]]
        if sel.size:
            u_h = u_hdr[hdr_of[seg]] if seg in hdr_of else np.zeros(0, dtype=np.int64)
            lost += int(np.count_nonzero(~np.isin(u_line[sel], u_h)))
    return lost


def lines_from_headers(hdr: HeaderColumns) -> LineTable:
    """Lines as the headers give them: line = order of the header within its segment."""
    line = np.zeros(hdr.segment.size, dtype=np.int64)
    for _, idx in by_segment(hdr.segment):
        line[idx] = np.arange(idx.size)
    return LineTable(hdr.segment.copy(), line, hdr.frame_counter.copy())


def first_gap_lines(table: LineTable, modulus: int) -> dict[int, int]:
    """Per segment whose frame counter skips, the first line after the first skip. Numbered by
    header order, a line from there on may not be the image's line of that number: a frame the
    scanner dropped (no image line) and a header lost on the link (an image line) leave the
    same gap, and only the scanner's lines files tell them apart."""
    first: dict[int, int] = {}
    for seg, idx in by_segment(table.segment):
        skips = np.flatnonzero(_steps(table.frame_counter[idx], modulus) != 1)
        if skips.size:
            first[int(seg)] = int(table.line[idx[skips[0] + 1]])
    return first


def hdr_gps(hdr: HeaderColumns, host: ClockMap) -> I64:
    return host.gps_ns(hdr.t_host_ns) if hdr.t_host_ns.size else np.zeros(0, dtype=np.int64)
