"""The SISA sync unit's logic (seed §3.5.2, §5.3), free of I/O and clocks: events in, actions out.

The box sees the GPS PPS, the scanner's pulse per frame (ppf) and its frame headers, and drives two
outputs, the INS sync input and the GPS event input. It works in two modes:

- Mode 1 (scanner off): a maximal-length LFSR steps once per PPS and the PPS is forwarded when the
  output bit is 1, so the pulse pattern found in the INS records names each GPS second.
- Mode 2 (scanner on): 1 of every n ppf is forwarded to the INS and to the GPS event input, and the
  log says which frame (frame counter) each forwarded pulse was.

Design choices, and why:
- The register steps on every accepted PPS, in mode 2 too (the PPS is just not forwarded there).
  So the state is a pure function of the PPS count since the session started, the pattern
  resumes where it would have been after a scanner stretch, and every SyncPps record carries the
  real state and bit (`mode` says whether it was a gate). Each restart (new session) starts from
  the initial state again; post-processing treats every session on its own.
- A PPS edge must fall where the PPS train puts it, else it is spurious: logged with
  lfsr_state = lfsr_bit = −1, never forwarded, register not stepped. Unlocked (at the start, or
  while the PPS jitters more than the gate), "where the train puts it" is whole seconds (board
  counter, 1 ms + 100 ppm) after the last accepted edge, and two rejected edges one second apart
  replace the reference (it was the spurious one). That steps the register, but a glitch up to
  1 ms from the true edge passes it (0.57 and 1.05 ms did, and the true edge was then logged
  spurious): so nothing is forwarded unlocked. Locked (PPS_LOCK_EDGES edges, whichever were
  accepted, a whole board period apart within half the gate: the first 3 s of a session), it
  is the timing board's own prediction: the last edge plus whole measured periods, within
  `pps_gate_ns` (a few µs, + 0.1 ppm of the gap). A locked train gives way only to a new chain
  of such edges none of which was accepted (the PPS moved), or after PPS_HOLD_S without a PPS.
- Scanner on = evidence a spurious ppf cannot fake: `scanner_on_after_ppf` ppf (default 3;
  1 = the seed's "first ppf", which a stray ppf can fake) at the configured line rate (every
  interval within interval_tolerance of `line_period_ns`), or, for a scanner at another rate
  (its latest ppf interval off the line period), a frame header with a ppf in its latency
  window (the switch is dated at that ppf). Three ppf merely alike in rate were enough before:
  3 Hz of spurious pulses switched an idle unit to mode 2 four times a flight, and its forwards
  had no counter. At the line rate a header does not switch, so when the scanner is found on
  does not depend on when a header reached the host (a replayed log switches at the same ppf).
  Scanner off = no ppf for `idle_after_ns`. These are the only mode switches.
- Minimum spacing between ANY two forwarded pulses, so the receiver's dead time (1 / max event rate)
  never eats one, across mode switches too. Two PPS forwards may be `spacing_tolerance_ns` closer
  than 1 / rate: they are one GPS second apart by construction (only PPS jitter and the board
  drift differ). Every other pair must be at least 1 / rate + tolerance apart on the board counter.
- A frame camera (issue 37) shares the GPS event input, never the INS sync input: the INS
  pulse schedule (gated PPS, 1 of n ppf) is exactly what it is without a camera, so the pattern
  post-processing matches is untouched. The event input takes whichever pulse comes first once
  the receiver has re-armed (the spacing rule above, against the last pulse SENT TO IT): a
  camera pulse then goes to it alone; a ppf forward that finds it taken by a camera pulse goes
  to the INS alone (`forwards_event_input_busy`), a camera pulse that finds it taken goes
  nowhere (`camera_event_input_busy`). Both are logged with their board time either way
  (SyncForward, SyncCameraPulse), so every tag the receiver gives has exactly one pulse of
  a known source within its period, and an untagged pulse is timed through the board.
- Mode 2 forwards the first ppf of a scanner stretch that the spacing allows, then the first ppf at
  least n frames after the previous forward that the spacing allows. A ppf that was due but held
  back counts in `forwards_suppressed_by_spacing`.
- The line-period grid: the median of the recent ppf intervals (most of which must agree) and a
  tolerance from their scatter (≥ 10 µs, ≤ interval_tolerance). An interval of about k periods
  means k − 1 lost ppf; a ppf off the grid is spurious and is skipped when counting frames. This
  assumes lost and spurious ppf are a minority: every other ppf lost would look like a scanner at
  half the rate. A spurious ppf splits one line period into two short intervals, so a few of
  them early in a stretch can outvote the true intervals; a grid is therefore also read at 2
  and 3 times its period, and if that reading needs no more lost + spurious ppf, there is no
  grid (yet): a grid too short would put a spurious ppf on it, and a header's counter would
  then confirm it.
- Headers come late, may be lost, and their counter wraps. A header is matched to a ppf of the
  current stretch after the last matched one, with its host time in the latency window (half the
  header's own integration time + [header_latency_min_ns, header_latency_max_ns]). Among the ppf
  in the window, one is accepted if its counter agrees with the line periods counted since the
  last matched frame, or, when that cannot be checked, if no lost ppf could sit in the window
  instead (every grid position in it holds a ppf) and the window is narrower than a line
  period. Anything else is counted and ignored: with a window wider than a line period (a
  scanner faster than ~1 / (header_latency_max_ns − header_latency_min_ns)) no header is taken
  on time alone, because a late host stamp can push a header's own ppf out of the window and
  leave the next one in it alone; such frames keep counter 'unknown'.
- A forwarded ppf without its own header gets an inferred counter only between two matched frames
  of the same segment whose counters differ by exactly the line periods between them (one wrap
  allowed): counter = earlier counter + periods to it, unless another ppf shares its grid
  position (a spurious one within the grid's tolerance of it: which of the two is the frame's
  cannot be told). A header-matched ppf off the grid of its
  neighbours (a spurious ppf that took a lost frame's header) is 'unknown', and so is one that
  cannot be judged (fewer than 4 ppf in the stretch). 'unknown' rather than a guess, always.
- Log records wait until they are complete (PTT, frame counter) or can no longer become complete,
  and SyncForward records go out in their `seq` order. A PTT is matched on host time to a pending
  PPS within `ptt_window_ns`, whose board time must agree with the last known GPS second.

Time bases: `board_ns` (the timing board's counter) for the pulses and every interval; `t_host_ns`
(the logging computer) for matching serial messages (headers, PTT) to pulses, because serial
messages have no board time. SyncPps.board_ns is the input edge; Forward and SyncForward board_ns
are the output edge (input + GATE_DELAY_NS).
"""

from __future__ import annotations

import bisect
import itertools
import statistics
from collections import deque
from dataclasses import dataclass
from enum import IntEnum, StrEnum
from typing import Final, TypeAlias

from acquisition.lfsr import Lfsr, check_taps, default_taps
from acquisition.scanner_header import FrameHeader
from recorder.messages import (
    LoggedMessage,
    SyncCameraPulse,
    SyncForward,
    SyncModeSwitch,
    SyncPps,
    SyncSession,
)
from sisa.core.errors import ConfigError
from sisa.core.timescale import NS_PER_S

GATE_DELAY_NS: Final = 1_000  # input edge → output edge of the box
PERIOD_WINDOW: Final = 15  # recent ppf intervals whose median estimates the line period
MIN_PERIOD_SAMPLES: Final = 3  # fewer intervals: no period estimate, so no inference
GRID_FLOOR_NS: Final = 10_000  # an interval within this of the period is regular, whatever the MAD
MAD_TO_SIGMA: Final = 1.4826
NEIGHBOURS: Final = 3  # ppf each side that tell a spurious header-matched ppf
SPLIT_READINGS: Final = (2, 3)  # a grid is also read at these multiples of its period
FAULT_WALK_STARTS: Final = 3  # ppf a grid walk may start from (the first may be spurious)
SECOND_TOLERANCE_NS: Final = 1_000_000  # "whole seconds apart" on the board: 1 ms + 100 ppm
SECOND_TOLERANCE_PPM: Final = 100.0
PPS_LOCK_EDGES: Final = 4  # edges a whole board period apart within half the gate: locked
PPS_RECENT_MAX: Final = 512  # edges kept to search for a lock (4 s of them)
PPS_ANCHORS: Final = 16  # recent accepted edges that estimate the board's PPS period
PPS_GATE_GROWTH_NS_PER_S: Final = 100  # the locked gate widens by 0.1 ppm of the gap
PPS_HOLD_S: Final = 600  # no PPS for this long: the prediction is not trusted any more


class Mode(IntEnum):
    PPS = 1  # scanner off: LFSR-gated PPS
    FRAMES = 2  # scanner on: 1 of n ppf


class PulseSource(StrEnum):
    PPS = "PPS"
    PPF = "PPF"
    CAMERA = "CAMERA"  # the frame camera's mid-exposure pulse (GPS event input only)


class CounterSource(StrEnum):
    HEADER = "header"  # the frame's own header was matched to its ppf
    INFERRED = "inferred"  # from two bracketing matched frames and the ppf count between them
    UNKNOWN = "unknown"  # could not be established safely
    NOT_APPLICABLE = "n/a"  # a forwarded PPS


class SwitchReason(StrEnum):
    SCANNER_ON = "scanner on: ppf at the line rate"
    SCANNER_HEADER = "scanner on: frame header"
    SCANNER_OFF = "scanner off: no ppf for"


@dataclass(frozen=True)
class Forward:
    """Drive the outputs now: a pulse at board time `board_ns` (input edge + gate delay)."""

    board_ns: int
    to_ins: bool
    to_gps_event: bool
    source: PulseSource


@dataclass(frozen=True)
class Log:
    """A record for the flight log."""

    message: LoggedMessage


Action: TypeAlias = Forward | Log


@dataclass(frozen=True)
class SyncFilterConfig:
    """What the box is told. Defaults suit the bench scenario; durations are ns."""

    lfsr_bits: int = 4
    lfsr_taps: tuple[int, ...] | None = None  # None: the maximal-length table
    lfsr_initial_state: int = 1
    one_of_n: int = 1
    max_event_rate_hz: float = 1.0
    event_input_in_mode1: bool = False
    line_period_ns: int = 16_000_000  # nominal
    scanner_idle_after_ns: int | None = None  # None: max(20 line periods, 0.5 s)
    header_latency_min_ns: int = -2_000_000  # beyond half the integration time (readout, link)
    header_latency_max_ns: int = 10_000_000
    frame_counter_bits: int = 16
    spacing_tolerance_ns: int = 100_000
    ptt_window_ns: int = 900_000_000  # a PTT later than this after its PPS is not matched
    interval_tolerance: float = 0.05  # ppf grid: most intervals agree this well; max tolerance
    infer_max_gap_frames: int = 1000  # bracketing frames further apart: no inference
    scanner_on_after_ppf: int = 3  # ppf at a steady rate that mean "scanner on" (1: the first)
    pps_gate_ns: int = 5_000  # locked: a PPS edge this close to the board's prediction, or spurious

    def __post_init__(self) -> None:
        Lfsr(self.lfsr_bits, self.taps, self.lfsr_initial_state)
        checks = {
            "one_of_n ≥ 1": self.one_of_n >= 1,
            "max_event_rate_hz > 0": self.max_event_rate_hz > 0,
            "line_period_ns > 0": self.line_period_ns > 0,
            "scanner_idle_after_ns > 0":
                self.scanner_idle_after_ns is None or self.scanner_idle_after_ns > 0,
            "header_latency_min_ns ≤ header_latency_max_ns":
                self.header_latency_min_ns <= self.header_latency_max_ns,
            "1 ≤ frame_counter_bits ≤ 32": 1 <= self.frame_counter_bits <= 32,
            "0 ≤ spacing_tolerance_ns < 1 / max_event_rate_hz":
                0 <= self.spacing_tolerance_ns < NS_PER_S / self.max_event_rate_hz,
            "ptt_window_ns > 0": self.ptt_window_ns > 0,
            "0 < pps_gate_ns < SECOND_TOLERANCE_NS":
                0 < self.pps_gate_ns < SECOND_TOLERANCE_NS,
            "0 < interval_tolerance < 0.5": 0 < self.interval_tolerance < 0.5,
            "infer_max_gap_frames ≥ 1": self.infer_max_gap_frames >= 1,
            f"1 ≤ scanner_on_after_ppf ≤ {PERIOD_WINDOW}":
                1 <= self.scanner_on_after_ppf <= PERIOD_WINDOW,
        }
        failed = [name for name, ok in checks.items() if not ok]
        if failed:
            raise ConfigError(f"sync filter config: need {', '.join(failed)}")

    @property
    def taps(self) -> tuple[int, ...]:
        if self.lfsr_taps is None:
            return default_taps(self.lfsr_bits)
        return check_taps(self.lfsr_bits, self.lfsr_taps)

    @property
    def idle_after_ns(self) -> int:
        if self.scanner_idle_after_ns is not None:
            return self.scanner_idle_after_ns
        return max(20 * self.line_period_ns, NS_PER_S // 2)

    @property
    def event_period_ns(self) -> int:
        return round(NS_PER_S / self.max_event_rate_hz)

    @property
    def min_spacing_ns(self) -> int:
        """No two forwarded pulses are closer than this (two PPS forwards may be this close)."""
        return self.event_period_ns - self.spacing_tolerance_ns

    @property
    def counter_modulus(self) -> int:
        return 1 << self.frame_counter_bits


@dataclass
class SyncCounters:
    """Health counters of one session."""

    pps_seen: int = 0
    pps_rejected: int = 0  # not where the PPS train puts it: spurious, register not stepped
    pps_rejected_by_gate: int = 0  # of those, refused by the locked gate (the 1 ms rule took them)
    pps_lock_lost: int = 0  # a locked train given up (a new train, or no PPS for PPS_HOLD_S)
    pps_not_forwarded_unlocked: int = 0  # one-bits while the PPS train was not locked
    ppf_seen: int = 0
    ppf_bursts_ignored: int = 0  # ppf that stopped before they were steady: no mode switch
    headers_matched: int = 0
    headers_unmatched: int = 0
    forwards: int = 0
    forwards_suppressed_by_spacing: int = 0
    forwards_event_input_busy: int = 0  # went to the INS alone: a camera pulse had the input
    ptt_unmatched: int = 0
    camera_pulses: int = 0
    camera_to_gps_event: int = 0
    camera_event_input_busy: int = 0  # timed by the board alone: the input was taken


# ---------------------------------------------------------------------------------------------
# Pending records
# ---------------------------------------------------------------------------------------------


@dataclass
class _PendingForward:
    seq: int
    board_ns: int  # output edge
    t_host_ns: int
    mode: Mode
    source: PulseSource
    to_gps_event: bool
    frame_index: int = -1  # index of the ppf in its run (PPF only)
    gps_second_ns: int = -1
    frame_counter: int = -1
    counter_source: CounterSource = CounterSource.NOT_APPLICABLE
    resolved: bool = False


@dataclass
class _PendingPps:
    board_ns: int
    t_host_ns: int
    mode: Mode
    lfsr_state: int
    lfsr_bit: int
    forward: _PendingForward | None
    gps_second_ns: int = -1


@dataclass(frozen=True)
class _Grid:
    period_ns: float
    tolerance_ns: float

    def steps(self, interval_ns: int) -> int | None:
        """How many line periods the interval spans (≥ 1), or None if it is off the grid."""
        k = round(interval_ns / self.period_ns)
        if k < 1 or abs(interval_ns - k * self.period_ns) > self.tolerance_ns:
            return None
        return k


@dataclass
class _Frame:
    index: int
    board_ns: int
    t_host_ns: int
    counter: int | None = None  # from its own header
    segment: int = -1


# ---------------------------------------------------------------------------------------------
# The PPS train on the timing board
# ---------------------------------------------------------------------------------------------


class _PpsTrain:
    """Which PPS edges are the PPS.

    Unlocked: an edge whole seconds (1 ms + 100 ppm) after the last accepted one is the PPS
    (two rejected edges one second apart replace the reference). That steps the register, but
    a glitch up to ~1 ms from the true edge passes it, so nothing is forwarded unlocked.
    Locked: PPS_LOCK_EDGES edges (any seen, accepted or not) a whole board period apart within
    half the gate; then only an edge within the gate of the last accepted one plus whole
    measured periods is the PPS. A locked train gives way to a new such chain of edges none
    accepted (the PPS itself moved), or after PPS_HOLD_S without a PPS."""

    def __init__(self, gate_ns: int) -> None:
        self.gate_ns = gate_ns
        self.anchors: deque[tuple[int, int]] = deque(maxlen=PPS_ANCHORS)  # (second, board ns)
        self.recent: deque[int] = deque(maxlen=PPS_RECENT_MAX)  # every edge lately, board ns
        self.ref: int | None = None  # unlocked: the last accepted edge
        self.doubt: int | None = None  # unlocked: the last rejected one
        self.locked = False

    def accept(self, board_ns: int) -> tuple[bool, str]:
        """Whether this edge is the PPS, and a remark: "gate" when only the locked gate refused
        it (the whole-second rule would have taken it), "lock lost" when a locked train gave way."""
        self._remember(board_ns)
        remark = ""
        if self.locked:
            k, residual = self._predict(board_ns)
            if 1 <= k <= PPS_HOLD_S and abs(residual) <= self.window_ns(k):
                self._add(k, board_ns)
                return True, ""
            chain = self._chain(board_ns, after=self.anchors[-1][1])
            if chain is not None:  # the PPS moved: four edges on a new phase, none accepted
                self._lock(chain)
                return True, "lock lost"
            if k <= PPS_HOLD_S:
                whole = _whole_seconds(board_ns - self.anchors[-1][1]) is not None
                return False, "gate" if whole else ""
            self.locked, remark = False, "lock lost"  # too long without a PPS
            self.ref, self.doubt = self.anchors[-1][1], None
        ok = self._whole_second_rule(board_ns)
        last = self.ref
        chain = self._chain(board_ns, after=None)
        if chain is not None and (ok or last is None or board_ns - last > NS_PER_S // 2):
            self._lock(chain)  # (not when a glitch already took this second: next second)
            self.ref, self.doubt = board_ns, None
            return True, remark
        return ok, remark

    def _whole_second_rule(self, board_ns: int) -> bool:
        ref, doubt = self.ref, self.doubt
        in_train = ref is None or _whole_seconds(board_ns - ref) is not None
        new_train = doubt is not None and _whole_seconds(board_ns - doubt) == 1
        if in_train or new_train:
            self.ref, self.doubt = board_ns, None
            return True
        self.doubt = board_ns
        return False

    def window_ns(self, seconds: int) -> float:
        return self.gate_ns + PPS_GATE_GROWTH_NS_PER_S * seconds

    def _period_ns(self) -> float:
        (i0, b0), (i1, b1) = self.anchors[0], self.anchors[-1]
        return (b1 - b0) / (i1 - i0)

    def _predict(self, board_ns: int) -> tuple[int, float]:
        """Whole periods after the last accepted edge, and this edge's distance from there."""
        last = self.anchors[-1][1]
        period = self._period_ns()
        k = round((board_ns - last) / period)
        return k, board_ns - last - k * period

    def _remember(self, board_ns: int) -> None:
        while self.recent and board_ns - self.recent[0] > PPS_LOCK_EDGES * NS_PER_S:
            self.recent.popleft()
        self.recent.append(board_ns)

    def _chain(self, board_ns: int, after: int | None) -> list[int] | None:
        """PPS_LOCK_EDGES edges ending with this one, a whole period apart within half the
        gate (the period from this edge and one about a second before it), all later than
        `after`; oldest first. None if there is no such chain."""
        half = self.gate_ns / 2
        earlier = [b for b in self.recent if b < board_ns and (after is None or b > after)]
        for first in reversed(earlier):
            period = board_ns - first
            if _whole_seconds(period) != 1:
                continue
            chain = [board_ns, first]
            for j in range(2, PPS_LOCK_EDGES):
                near = _nearest(earlier, board_ns - j * period)
                if abs(near - (board_ns - j * period)) > half:
                    break
                chain.append(near)
            else:
                return chain[::-1]
        return None

    def _lock(self, chain: list[int]) -> None:
        self.anchors.clear()
        self.anchors.extend(enumerate(chain))
        self.locked = True

    def _add(self, seconds: int, board_ns: int) -> None:
        self.anchors.append((self.anchors[-1][0] + seconds, board_ns))


# ---------------------------------------------------------------------------------------------
# One scanner-on stretch: ppf, headers, counters
# ---------------------------------------------------------------------------------------------


class _FrameRun:
    """The ppf of one scanner-on stretch, the headers matched to them, and counter inference."""

    def __init__(self, config: SyncFilterConfig) -> None:
        self.cfg = config
        self.frames: deque[_Frame] = deque()
        self.matched: list[int] = []  # indices of frames with their own header, increasing
        self.intervals: deque[int] = deque(maxlen=PERIOD_WINDOW)
        self.next_index = 0
        self._grid: tuple[int, _Grid | None] = (-1, None)  # (next_index when fitted, grid)

    # --- frames ---------------------------------------------------------------------------

    def add(self, board_ns: int, t_host_ns: int) -> int:
        if self.frames:
            self.intervals.append(board_ns - self.frames[-1].board_ns)
        self.frames.append(_Frame(self.next_index, board_ns, t_host_ns))
        self.next_index += 1
        self._prune()
        return self.next_index - 1

    def _prune(self) -> None:
        """Keep only frames that can still anchor an inference or take a header."""
        oldest = self.next_index - 1 - self.cfg.infer_max_gap_frames
        while self.frames and self.frames[0].index < oldest:
            self.frames.popleft()
        cut = bisect.bisect_left(self.matched, oldest)
        del self.matched[:cut]

    def steady(self, count: int) -> bool:
        """At least `count` ppf, the last count − 1 intervals at the configured line period
        (a scanner; random spurious intervals are almost never that close to it twice)."""
        if self.next_index < count:
            return False
        recent = list(self.intervals)[len(self.intervals) - (count - 1):] if count > 1 else []
        nominal = self.cfg.line_period_ns
        return all(abs(i - nominal) <= self.cfg.interval_tolerance * nominal for i in recent)

    def off_line_rate(self) -> bool:
        """The latest ppf interval is not the configured line period."""
        nominal = self.cfg.line_period_ns
        return bool(self.intervals) and (abs(self.intervals[-1] - nominal)
                                         > self.cfg.interval_tolerance * nominal)

    def ppf_for_header(self, header: FrameHeader, t_host_ns: int) -> _Frame | None:
        """The latest ppf of this stretch in the header's latency window (host time)."""
        lo, hi = self._window(header)
        return next((f for f in reversed(self.frames) if lo <= t_host_ns - f.t_host_ns <= hi),
                    None)

    def frame(self, index: int) -> _Frame | None:
        if not self.frames:
            return None
        pos = index - self.frames[0].index
        return self.frames[pos] if 0 <= pos < len(self.frames) else None

    def grid(self) -> _Grid | None:
        """The line-period grid of the recent intervals (refitted when a ppf came)."""
        if self._grid[0] != self.next_index:
            self._grid = (self.next_index, self._fit_grid())
        return self._grid[1]

    def _fit_grid(self) -> _Grid | None:
        """The line period and how far a real interval strays from it, from recent intervals.

        Period: median of the intervals within interval_tolerance of the overall median, which
        must be most of them (lost and spurious ppf are outliers, never the majority).
        Tolerance: 8 robust sigmas (MAD) of those, at least GRID_FLOOR_NS and at most
        interval_tolerance of a period. A spurious ppf is caught unless it falls that close to
        where a ppf belongs, and then its time is off by no more than that.
        """
        if len(self.intervals) < MIN_PERIOD_SAMPLES:
            return None
        rough = statistics.median(self.intervals)
        limit = self.cfg.interval_tolerance * rough
        inliers = [i for i in self.intervals if abs(i - rough) <= limit]
        if len(inliers) < MIN_PERIOD_SAMPLES or 2 * len(inliers) <= len(self.intervals):
            return None
        period = float(statistics.median(inliers))
        mad = float(statistics.median(abs(i - period) for i in inliers))
        grid = _Grid(period, min(max(8 * MAD_TO_SIGMA * mad, GRID_FLOOR_NS), limit))
        if _split_periods(self.intervals, grid) or self._lost_majority(grid):
            return None
        return grid

    def _lost_majority(self, grid: _Grid) -> bool:
        """Could the grid be two or three line periods, most ppf of a short run lost? Only if
        its period is that multiple of the operator's line period and some interval is one
        such period: a spurious ppf lands that close to a period after a frame's rarely, a
        frame always. On such a grid a header ties to the next frame's ppf on time alone and
        every counter after it agrees (fault sweep seed 40024), so there is no grid until the
        intervals of one period are the majority."""
        nominal = self.cfg.line_period_ns
        near = self.cfg.interval_tolerance * nominal
        return (any(abs(grid.period_ns - m * nominal) <= m * near for m in SPLIT_READINGS)
                and any(abs(i - nominal) <= near for i in self.intervals))

    def steps_between(self, first: int, last: int) -> int | None:
        """Line periods from frame `first` to frame `last` (first ≤ last), lost ppf included and
        ppf off the grid in between (spurious) skipped; None if a frame is no longer held or
        `last` itself is off the grid."""
        grid = self.grid()
        ref = self.frame(first)
        if grid is None or ref is None:
            return None
        total = 0
        for i in range(first + 1, last + 1):
            cur = self.frame(i)
            if cur is None:
                return None
            k = grid.steps(cur.board_ns - ref.board_ns)
            if k is not None:
                total, ref = total + k, cur
            elif i == last:
                return None
        return total

    # --- headers --------------------------------------------------------------------------

    def match_header(self, header: FrameHeader, t_host_ns: int) -> bool:
        """Attach the header to its ppf; False if there is no single plausible ppf."""
        lo, hi = self._window(header)
        after = self.matched[-1] if self.matched else -1
        in_window = []
        for f in reversed(self.frames):  # newest first; host times do not decrease
            if f.index <= after or t_host_ns - f.t_host_ns > hi:
                break
            if t_host_ns - f.t_host_ns >= lo:
                in_window.append(f)
        verdicts = [(f, self._verdict(f, header)) for f in in_window]
        possible = [(f, v) for f, v in verdicts if v is not False]
        if len(possible) > 1 and not any(v for _, v in possible):
            return False  # several candidates and none confirmed by its counter: ambiguous
        # An unconfirmed candidate (no count to check its counter against) is taken only if the
        # window is narrower than a line period: in a wider one the header's own frame may have
        # fallen just outside (a late host stamp) while the next one sits inside.
        narrow = hi - lo < self._period_floor_ns()
        trusted = [f for f, v in possible
                   if v or (narrow
                            and not self._lost_ppf_could_fit(f, t_host_ns - f.t_host_ns, lo, hi))]
        if len(trusted) != 1 or (len(possible) > 1 and not self._verdict(trusted[0], header)):
            return False
        frame = trusted[0]
        frame.counter, frame.segment = header.frame_counter, header.segment
        self.matched.append(frame.index)
        return True

    def _period_floor_ns(self) -> float:
        """The shortest interval a line period can take (the grid's, else the configured)."""
        grid = self.grid()
        period = grid.period_ns if grid is not None else float(self.cfg.line_period_ns)
        return period * (1.0 - self.cfg.interval_tolerance)

    def _window(self, header: FrameHeader) -> tuple[int, int]:
        """Host-time latency window of a header after its ppf (mid-exposure)."""
        half_integration_ns = header.integration_time_us * 500
        return (half_integration_ns + self.cfg.header_latency_min_ns,
                half_integration_ns + self.cfg.header_latency_max_ns)

    def _lost_ppf_could_fit(self, frame: _Frame, latency_ns: int, lo: int, hi: int) -> bool:
        """Could the header belong instead to a lost ppf j line periods after (or before) this
        one? Only if that grid position falls in the window and holds no ppf."""
        step = self._period_floor_ns()
        for direction in (1, -1):
            j = 1
            while lo <= latency_ns - direction * j * step <= hi:
                if not self._occupied(frame.index, direction * j):
                    return True
                j += 1
        return False

    def _occupied(self, index: int, offset: int) -> bool:
        """A ppf is held exactly `offset` line periods from frame `index` (on the grid)."""
        sign = 1 if offset > 0 else -1
        i = index + sign
        while self.frame(i) is not None:
            steps = self.steps_between(min(index, i), max(index, i))
            if steps is None or steps > abs(offset):
                return False
            if steps == abs(offset):
                return True
            i += sign
        return False

    def _verdict(self, frame: _Frame, header: FrameHeader) -> bool | None:
        """Does the header's counter agree with the line periods since the last matched frame?
        None when that count is not known (no match yet, or a spurious ppf in between)."""
        last = self.frame(self.matched[-1]) if self.matched else None
        steps = self.steps_between(last.index, frame.index) if last is not None else None
        if last is None or last.counter is None or steps is None:
            return None
        return (last.segment == header.segment
                and self._wrapped(last.counter, header.frame_counter, steps) is not None)

    def _wrapped(self, c_from: int, c_to: int, frames: int) -> bool | None:
        """None if the counters disagree with the frame count, else whether it wrapped once."""
        step = c_to - c_from
        if step == frames:
            return False
        if step + self.cfg.counter_modulus == frames:
            return True
        return None

    # --- counters of forwarded frames -----------------------------------------------------

    def resolve(self, index: int, ended: bool) -> tuple[int, CounterSource] | None:
        """The counter of frame `index`, or None while it may still become known."""
        frame = self.frame(index)
        if frame is None:
            return -1, CounterSource.UNKNOWN
        if frame.counter is not None:
            return self._own_header(frame, frame.counter, ended)
        return self._inferred(frame, ended)

    def _own_header(self, frame: _Frame, counter: int,
                    ended: bool) -> tuple[int, CounterSource] | None:
        spurious = self._looks_spurious(frame, ended)
        if spurious is None:
            return None  # wait for later ppf, or a line period estimate, to judge this one
        return (-1, CounterSource.UNKNOWN) if spurious else (counter, CounterSource.HEADER)

    def _looks_spurious(self, frame: _Frame, ended: bool) -> bool | None:
        """Off the line-period grid of its neighbours (up to NEIGHBOURS each side): a spurious
        ppf that took a lost frame's header. None while it cannot be told yet; at the end of
        the stretch (or too long after) what cannot be told counts as spurious."""
        final = ended or self.next_index - 1 - frame.index > self.cfg.infer_max_gap_frames
        grid = self.grid()
        if grid is None:
            return True if final else None
        i = frame.index
        later = [f for f in map(self.frame, range(i + 1, i + 1 + NEIGHBOURS)) if f is not None]
        if not later and not final:
            return None
        earlier = [f for f in map(self.frame, range(i - NEIGHBOURS, i)) if f is not None]
        return not any(grid.steps(abs(frame.board_ns - f.board_ns)) is not None
                       for f in earlier + later)

    def _crowded(self, frame: _Frame) -> bool:
        """Another ppf at the frame's grid position (both within the grid's tolerance of it,
        µs apart): a spurious one, and nothing tells which is the frame's; the first of the two
        was counted for it, the other skipped as off the grid."""
        grid = self.grid()
        if grid is None:
            return False
        return any(other is not None and abs(other.board_ns - frame.board_ns)
                   <= 2 * grid.tolerance_ns
                   for other in (self.frame(frame.index - 1), self.frame(frame.index + 1)))

    def _inferred(self, frame: _Frame, ended: bool) -> tuple[int, CounterSource] | None:
        pos = bisect.bisect_left(self.matched, frame.index)
        before = self.frame(self.matched[pos - 1]) if pos > 0 else None
        after = self.frame(self.matched[pos]) if pos < len(self.matched) else None
        if after is None:
            anchor = before.index if before is not None else frame.index
            gave_up = self.next_index - 1 - anchor > self.cfg.infer_max_gap_frames
            return (-1, CounterSource.UNKNOWN) if ended or gave_up else None
        if before is None:
            return -1, CounterSource.UNKNOWN
        return self._bracket(frame, before, after)

    def _bracket(self, frame: _Frame, a: _Frame, b: _Frame) -> tuple[int, CounterSource]:
        span = self.steps_between(a.index, b.index)
        offset = self.steps_between(a.index, frame.index)
        if a.counter is None or b.counter is None or span is None or offset is None or \
                self._crowded(frame):
            return -1, CounterSource.UNKNOWN
        wrapped = self._wrapped(a.counter, b.counter, span)
        if wrapped is None or a.segment != b.segment or span > self.cfg.infer_max_gap_frames:
            return -1, CounterSource.UNKNOWN
        counter = a.counter + offset
        return (counter % self.cfg.counter_modulus if wrapped else counter), CounterSource.INFERRED


# ---------------------------------------------------------------------------------------------
# The filter
# ---------------------------------------------------------------------------------------------


class SyncFilter:
    """The SISA box of one session: feed it events, apply the actions it returns.

    The SyncSession record is returned by `start_actions()`, or else with the first actions any
    other call returns.
    """

    def __init__(self, config: SyncFilterConfig, session: int = 0, board_ns: int = 0,
                 t_host_ns: int = 0) -> None:
        self.config = config
        self.session = session
        self.counters = SyncCounters()
        self.mode = Mode.PPS
        self._lfsr = Lfsr(config.lfsr_bits, config.taps, config.lfsr_initial_state)
        self._pps: list[_PendingPps] = []
        self._forwards: deque[_PendingForward] = deque()
        self._run: _FrameRun | None = None
        self._since_forward = 0  # ppf since the last forward in this run
        self._last_forward: tuple[int, PulseSource] | None = None  # output board_ns, source
        self._last_event: tuple[int, PulseSource] | None = None  # the last to the GPS event in
        self._camera_seq = 0
        self._last_ppf_board_ns: int | None = None
        self._last_second: tuple[int, int] | None = None  # (board_ns, gps_second_ns) of a PTT
        self._challenger: tuple[int, int] | None = None  # a refused lone PTT match
        self._pps_train = _PpsTrain(config.pps_gate_ns)
        self._clock = (board_ns, t_host_ns)  # latest (board_ns, t_host_ns) seen
        self._startup: list[Action] = [Log(self._session_record(board_ns, t_host_ns))]

    def _session_record(self, board_ns: int, t_host_ns: int) -> SyncSession:
        cfg = self.config
        return SyncSession(t_host_ns, self.session, board_ns, cfg.lfsr_bits, list(cfg.taps),
                           cfg.lfsr_initial_state, cfg.one_of_n, cfg.min_spacing_ns,
                           cfg.event_input_in_mode1)

    @property
    def lfsr_state(self) -> int:
        return self._lfsr.state

    def start_actions(self) -> list[Action]:
        """The session record (once)."""
        out, self._startup = self._startup, []
        return out

    # --- events ---------------------------------------------------------------------------

    def on_pps(self, board_ns: int, t_host_ns: int) -> list[Action]:
        """A PPS edge: step the register; in mode 1 forward it if the bit is 1."""
        self.counters.pps_seen += 1
        logs = self._advance(board_ns, t_host_ns) + self._close_stale_pps(board_ns)
        if not self._pps_in_train(board_ns):
            self.counters.pps_rejected += 1
            self._pps.append(_PendingPps(board_ns, t_host_ns, self.mode, -1, -1, None))
            return self._actions(None, logs + self._emit_forwards())
        bit = self._lfsr.step()
        fwd = None
        if self.mode is Mode.PPS and bit and not self.pps_locked:
            self.counters.pps_not_forwarded_unlocked += 1
        elif self.mode is Mode.PPS and bit:
            fwd = self._try_forward(board_ns, t_host_ns, PulseSource.PPS,
                                    self.config.event_input_in_mode1)
        self._pps.append(_PendingPps(board_ns, t_host_ns, self.mode, self._lfsr.state, bit, fwd))
        return self._actions(fwd, logs + self._emit_forwards())

    def on_gps_time(self, gps_second_ns: int, t_host_ns: int) -> list[Action]:
        """The receiver's PTT (GPS second of its last PPS), matched to a PPS on host time."""
        index = self._ptt_target(gps_second_ns, t_host_ns)
        if index is None:
            self.counters.ptt_unmatched += 1
            return self._actions(None, [])
        pps = self._pps[index]
        pps.gps_second_ns = gps_second_ns
        self._last_second = (pps.board_ns, gps_second_ns)
        return self._actions(None, self._close_pps(index + 1) + self._emit_forwards())

    def on_ppf(self, board_ns: int, t_host_ns: int) -> list[Action]:
        """A frame pulse: scanner on (mode 2) if it was off; forward 1 of n."""
        self.counters.ppf_seen += 1
        logs = self._advance(board_ns, t_host_ns)
        if self._run is None:
            self._run = _FrameRun(self.config)  # a stretch, tentative while in mode 1
        index = self._run.add(board_ns, t_host_ns)
        self._last_ppf_board_ns = board_ns
        if self.mode is Mode.PPS:
            if not self._run.steady(self.config.scanner_on_after_ppf):
                return self._actions(None, logs)
            logs += self._switch(Mode.FRAMES, board_ns, t_host_ns, SwitchReason.SCANNER_ON)
        self._since_forward += 1
        fwd = None
        if self._since_forward >= self.config.one_of_n:
            fwd = self._try_forward(board_ns, t_host_ns, PulseSource.PPF, True, index)
            if fwd is not None:
                self._since_forward = 0
        self._resolve_frames(ended=False)
        return self._actions(fwd, logs + self._emit_forwards())

    def on_camera(self, board_ns: int, t_host_ns: int) -> list[Action]:
        """A frame-camera pulse (mid-exposure): to the GPS event input if the input is free
        (`_event_input_free`), never to the INS; logged either way with its board time. It
        changes nothing of the scanner's and the PPS's forwarding: no mode switch, no spacing
        of the INS pulses (docs/sync.md, "Two sensors, one event input")."""
        self.counters.camera_pulses += 1
        out_ns = board_ns + GATE_DELAY_NS
        free = self._event_input_free(out_ns, PulseSource.CAMERA)
        actions: list[Action] = []
        if free:
            self.counters.camera_to_gps_event += 1
            self._last_event = (out_ns, PulseSource.CAMERA)
            actions.append(Forward(out_ns, False, True, PulseSource.CAMERA))
        else:
            self.counters.camera_event_input_busy += 1
        record = SyncCameraPulse(t_host_ns, self.session, self._camera_seq, board_ns, free)
        self._camera_seq += 1
        return actions + self.start_actions() + [Log(record)]

    def ppf_may_forward(self, ppf_unseen: int) -> bool:
        """Could the ppf after `ppf_unseen` more (none of them forwarded) be forwarded? In
        mode 1 any ppf may be the one that turns the scanner on and goes at once; in mode 2
        every n-th (an idle gap before it, which would switch modes, is the caller's to see)."""
        return (self.mode is Mode.PPS
                or self._since_forward + ppf_unseen + 1 >= self.config.one_of_n)

    def on_header(self, header: FrameHeader, t_host_ns: int) -> list[Action]:
        """A frame header from the scanner's serial port (in mode 1, with a ppf of the
        tentative stretch in its window: the scanner is on)."""
        logs: list[Log] = []
        run = self._run
        ppf = (run.ppf_for_header(header, t_host_ns)
               if self.mode is Mode.PPS and run is not None and run.off_line_rate() else None)
        if ppf is not None:  # on since that ppf, on the board counter
            logs = self._switch(Mode.FRAMES, ppf.board_ns, t_host_ns, SwitchReason.SCANNER_HEADER)
        if self._run is not None and self._run.match_header(header, t_host_ns):
            self.counters.headers_matched += 1
            self._resolve_frames(ended=False)
        else:
            self.counters.headers_unmatched += 1
        return self._actions(None, logs + self._emit_forwards())

    def tick(self, board_ns: int, t_host_ns: int | None = None) -> list[Action]:
        """Time passes: scanner-off detection, PPS records whose PTT never came."""
        if t_host_ns is None:
            t_host_ns = self._clock[1] + board_ns - self._clock[0]
        logs = self._advance(board_ns, t_host_ns) + self._close_stale_pps(board_ns)
        return self._actions(None, logs + self._emit_forwards())

    def flush(self) -> list[Action]:
        """Shutdown: every pending record, complete or not."""
        logs = self._close_pps(len(self._pps))
        if self._run is not None:
            self._resolve_frames(ended=True)
        return self._actions(None, logs + self._emit_forwards())

    # --- time and modes -------------------------------------------------------------------

    def _advance(self, board_ns: int, t_host_ns: int) -> list[Log]:
        """Note the time; end the scanner stretch if no ppf came for the idle time."""
        self._clock = (board_ns, t_host_ns)
        last = self._last_ppf_board_ns
        if self._run is None or last is None or board_ns - last <= self.config.idle_after_ns:
            return []
        if self.mode is Mode.PPS:  # a burst that never became steady: noise, not the scanner
            self.counters.ppf_bursts_ignored += self._run.next_index
            self._run = None
            return []
        self._resolve_frames(ended=True)
        logs = self._emit_forwards()
        self._run = None
        idle_ms = (board_ns - last) / 1e6
        return logs + self._switch(Mode.PPS, board_ns, t_host_ns,
                                   f"{SwitchReason.SCANNER_OFF} {idle_ms:.0f} ms")

    def _switch(self, to: Mode, board_ns: int, t_host_ns: int, reason: str) -> list[Log]:
        record = SyncModeSwitch(t_host_ns, self.session, board_ns, int(self.mode), int(to),
                                str(reason))
        self.mode = to
        if to is Mode.FRAMES:
            self._since_forward = self.config.one_of_n - 1  # this ppf may go at once
        return [Log(record)]

    def _frame_run(self) -> _FrameRun:
        if self._run is None:
            raise RuntimeError("no scanner stretch open")
        return self._run

    # --- forwarding -----------------------------------------------------------------------

    def _spacing_ok(self, out_ns: int, source: PulseSource) -> bool:
        """Far enough from the last pulse forwarded to the INS (the INS pulse schedule)."""
        return self._spaced(self._last_forward, out_ns, source)

    def _event_input_free(self, out_ns: int, source: PulseSource) -> bool:
        """Far enough from the last pulse sent to the GPS event input that the receiver has
        re-armed: the one output two sensors share. Without a camera this is never stricter
        than `_spacing_ok` (every pulse sent to the event input was an INS forward too)."""
        return self._spaced(self._last_event, out_ns, source)

    def _spaced(self, last: tuple[int, PulseSource] | None, out_ns: int,
                source: PulseSource) -> bool:
        if last is None:
            return True
        last_ns, last_source = last
        tol = self.config.spacing_tolerance_ns
        both_pps = source is PulseSource.PPS and last_source is PulseSource.PPS
        need = self.config.event_period_ns + (-tol if both_pps else tol)
        gap = out_ns - last_ns
        if PulseSource.CAMERA in (source, last_source):
            gap = abs(gap)  # two links: a camera edge may be handled before an earlier ppf
        return gap >= need

    def _try_forward(self, board_ns: int, t_host_ns: int, source: PulseSource,
                     to_gps_event: bool, frame_index: int = -1) -> _PendingForward | None:
        out_ns = board_ns + GATE_DELAY_NS
        if not self._spacing_ok(out_ns, source):
            self.counters.forwards_suppressed_by_spacing += 1
            return None
        if to_gps_event and not self._event_input_free(out_ns, source):
            to_gps_event = False  # a camera pulse has the input: to the INS alone
            self.counters.forwards_event_input_busy += 1
        fwd = _PendingForward(self.counters.forwards, out_ns, t_host_ns, self.mode, source,
                              to_gps_event, frame_index)
        self.counters.forwards += 1
        self._last_forward = (out_ns, source)
        if to_gps_event:
            self._last_event = (out_ns, source)
        self._forwards.append(fwd)
        return fwd

    def _actions(self, fwd: _PendingForward | None, logs: list[Log]) -> list[Action]:
        """The output pulse first (it is due now), then the records."""
        out: list[Action] = []
        if fwd is not None:
            out.append(Forward(fwd.board_ns, True, fwd.to_gps_event, fwd.source))
        out += self.start_actions()
        out += logs
        return out

    # --- records --------------------------------------------------------------------------

    def _ptt_target(self, gps_second_ns: int, t_host_ns: int) -> int | None:
        """Index of the pending PPS this PTT belongs to: in its host-time window and, when
        several are, the one whose board time agrees with the last known second. A lone
        candidate that disagrees is refused, unless the previous refused one agrees with it
        (then the old reference was the wrong one)."""
        window = [i for i, p in enumerate(self._pps)
                  if 0 <= t_host_ns - p.t_host_ns <= self.config.ptt_window_ns]
        agree = [i for i in window
                 if _seconds_agree(self._last_second, self._pps[i].board_ns, gps_second_ns)
                 and self._pps[i].lfsr_bit >= 0]
        if len(agree) == 1:
            self._challenger = None
            return agree[0]
        if len(window) != 1:
            return None
        candidate = (self._pps[window[0]].board_ns, gps_second_ns)
        if self._challenger is not None and _seconds_agree(self._challenger, *candidate):
            self._challenger = None
            return window[0]
        self._challenger = candidate
        return None

    def _pps_in_train(self, board_ns: int) -> bool:
        """Is this edge the PPS (`_PpsTrain`)? Anything else is spurious and does not step
        the register."""
        ok, why = self._pps_train.accept(board_ns)
        if why == "gate":
            self.counters.pps_rejected_by_gate += 1
        elif why == "lock lost":
            self.counters.pps_lock_lost += 1
        return ok

    @property
    def pps_locked(self) -> bool:
        """The PPS train is locked: edges are gated by the board's prediction."""
        return self._pps_train.locked

    def _close_stale_pps(self, board_ns: int) -> list[Log]:
        """PPS records whose PTT can no longer come (by the next PPS, or a tick)."""
        stale = 0
        while (stale < len(self._pps)
               and board_ns - self._pps[stale].board_ns > self.config.ptt_window_ns):
            stale += 1
        return self._close_pps(stale)

    def _close_pps(self, count: int) -> list[Log]:
        """Emit the oldest `count` PPS records as they stand (−1 where no PTT came)."""
        closing, self._pps = self._pps[:count], self._pps[count:]
        logs = []
        for p in closing:
            if p.forward is not None:
                p.forward.gps_second_ns = p.gps_second_ns
                p.forward.resolved = True
            logs.append(Log(SyncPps(p.t_host_ns, self.session, p.board_ns, p.gps_second_ns,
                                    int(p.mode), p.lfsr_state, p.lfsr_bit,
                                    p.forward is not None)))
        return logs

    def _resolve_frames(self, ended: bool) -> None:
        run = self._frame_run()
        for fwd in self._forwards:
            if fwd.resolved or fwd.source is not PulseSource.PPF:
                continue
            result = run.resolve(fwd.frame_index, ended)
            if result is not None:
                fwd.frame_counter, fwd.counter_source = result
                fwd.resolved = True

    def _emit_forwards(self) -> list[Log]:
        """SyncForward records, in seq order, as far as they are resolved."""
        logs = []
        while self._forwards and self._forwards[0].resolved:
            f = self._forwards.popleft()
            logs.append(Log(SyncForward(f.t_host_ns, self.session, f.seq, f.board_ns,
                                        int(f.mode), str(f.source), f.to_gps_event,
                                        f.gps_second_ns, f.frame_counter,
                                        str(f.counter_source))))
        return logs


def _split_periods(intervals: deque[int], grid: _Grid) -> bool:
    """Could these ppf as well be a scanner at SPLIT_READINGS times the grid's period, some of
    whose line periods spurious ppf split? One spurious ppf makes two short intervals of one
    line period, so a few of them early in a stretch can outvote the true intervals (ppf 0, 8,
    16, 32, 48, 64, 72, 80 ms: 8 ms with three lost, or 16 ms with two spurious). A grid too
    short puts a spurious ppf on it and counts it as a frame, and a header's counter then
    confirms it; so when the longer reading needs no more faults (lost + spurious ppf) than
    the grid's own, there is no grid."""
    times = list(itertools.accumulate(intervals, initial=0))
    faults = _faults(times, grid, len(times))
    return any(_faults(times, _Grid(m * grid.period_ns, m * grid.tolerance_ns), faults) <= faults
               for m in SPLIT_READINGS)


def _faults(times: list[int], grid: _Grid, limit: int) -> int:
    """Lost plus spurious ppf if these ppf times are a scanner on this grid: walked from each
    of the first few ppf (those before it counted spurious), the fewest; counting stops past
    `limit` (the result is then limit + 1)."""
    best = limit + 1
    for start in range(min(FAULT_WALK_STARTS, len(times))):
        if start >= best:
            break
        faults, ref = start, times[start]
        for t in times[start + 1:]:
            k = grid.steps(t - ref)
            if k is None:
                faults += 1  # off the grid: spurious
            else:
                faults, ref = faults + k - 1, t  # k − 1 lost
            if faults >= best:
                break
        best = min(best, faults)
    return best


def _nearest(values: list[int], want: float) -> int:
    """The value closest to `want` (values not empty)."""
    return min(values, key=lambda v: abs(v - want))


def _whole_seconds(d_board_ns: int) -> int | None:
    """The whole number (≥ 1) of seconds this board interval spans, or None if it is not
    whole seconds (1 ms + 100 ppm: PPS jitter and the board's drift)."""
    k = round(d_board_ns / NS_PER_S)
    tol = SECOND_TOLERANCE_NS + abs(d_board_ns) * SECOND_TOLERANCE_PPM * 1e-6
    return k if k >= 1 and abs(d_board_ns - k * NS_PER_S) <= tol else None


def _seconds_agree(reference: tuple[int, int] | None, board_ns: int, gps_second_ns: int) -> bool:
    """A PPS at board_ns can be GPS second gps_second_ns given a reference (board_ns, second):
    the board counter advanced by the same whole seconds."""
    if reference is None:
        return True
    board_ref, second_ref = reference
    seconds = _whole_seconds(board_ns - board_ref)
    return seconds is not None and seconds * NS_PER_S == gps_second_ns - second_ref
