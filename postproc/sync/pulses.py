"""The sync unit's forwarded pulses, each with the best GPS time the log gives it.

A forwarded pulse went to the INS sync input (and, in mode 2, to the GPS event input). Its GPS
time, best source first:
- mode 1 (a gated PPS): the receiver's PTT time of that PPS edge plus the box's gate delay;
- mode 2 (a frame pulse): the receiver's TTT tag of the pulse itself, associated through the
  timing board (the forward's board time, mapped to GPS, must fall within `ttt_window_ns` of it);
- otherwise the board time mapped to GPS, if PPS pin the board down within `max_board_gap_s`;
- otherwise, for mode 1, the GPS second the box logged, plus the gate delay.
A pulse whose PTT or TTT time disagrees with its own board time (through the board map) by more
than the board map's error is rejected, never used: two independent records of one edge must
agree. The map's error is its residual scatter (tens of ns: the PPS jitter, the tag rounding)
times BOARD_AGREE_SIGMAS, widened by the prediction's leverage, never below `agree_floor_ns`
(2 µs), plus one tag LSB: far inside the sync unit's locked PPS gate (5 µs), far below the
0.5–1 ms of a glitch the box once took for the PPS. (It was the 50 µs TTT window, PTT only.)
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import Final

import numpy as np
import numpy.typing as npt

from postproc.sync.clockmap import ClockMap, ptt_of_seconds
from postproc.sync.flightlog import GpsTimes, SisaColumns
from sisa.core.timescale import NS_PER_S

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]

GATE_DELAY_NS: Final = 1_000  # the SISA box, input edge → output edge (its specification)
HOST_TTT_WINDOW_NS: Final = 300_000_000  # without a board map: TTT vs forward on host time
BOARD_AGREE_SIGMAS: Final = 6.0  # a tag and its board time agree within this many map sigmas


class PulseSource(IntEnum):
    PTT = 0  # PPS edge time from PTT + gate delay
    TTT = 1  # the receiver tagged the forwarded pulse
    BOARD = 2  # timing board stamp through the board map
    SECOND = 3  # the logged GPS second + gate delay (no PTT, no board map)
    NONE = 4  # no GPS time, or two records of the edge disagree


@dataclass(frozen=True)
class SisaPulses:
    """Every forwarded pulse in log order, with its GPS time (-1 where unusable)."""

    t_gps_ns: I64
    source: I64  # PulseSource
    mode: I64
    session: I64
    frame_counter: I64  # mode 2 (-1 unknown or mode 1)

    @property
    def usable(self) -> Bool:
        return np.asarray(self.t_gps_ns >= 0, dtype=np.bool_)

    def counts(self) -> dict[str, int]:
        return {s.name: int(np.count_nonzero(self.source == s)) for s in PulseSource}


def _board_times(sisa: SisaColumns, board: ClockMap | None, max_gap_s: float
                 ) -> tuple[I64, Bool]:
    if board is None:
        return np.full(sisa.fwd_board_ns.shape, -1, dtype=np.int64), np.zeros(
            sisa.fwd_board_ns.shape, dtype=np.bool_)
    ok = board.gap_s(sisa.fwd_board_ns) <= max_gap_s
    return board.gps_ns(sisa.fwd_board_ns), np.asarray(ok, dtype=np.bool_)


def board_agreement_ns(board: ClockMap, board_ns: I64, floor_ns: int, tag_lsb_ns: int) -> F64:
    """How far a tag (PTT, TTT) may lie from its pulse's board time through the map: the map's
    predicted error there (BOARD_AGREE_SIGMAS of its residual scatter, with the fit's
    leverage), at least floor_ns, plus one tag LSB."""
    x = (np.asarray(board_ns, dtype=np.int64) - board.epoch_ns).astype(np.float64) / NS_PER_S
    sigma_ns = board.line.sigma * NS_PER_S * np.sqrt(1.0 + board.line.leverage(x))
    return np.asarray(np.maximum(BOARD_AGREE_SIGMAS * sigma_ns, floor_ns) + tag_lsb_ns,
                      dtype=np.float64)


def ttt_match(estimate_ns: I64, want: Bool, ttt_ns: I64, window_ns: int) -> I64:
    """The TTT tag nearest each wanted estimate, if within the window; each tag used once."""
    out = np.full(estimate_ns.shape, -1, dtype=np.int64)
    if ttt_ns.size == 0:
        return out
    i = np.searchsorted(ttt_ns, estimate_ns)
    lo, hi = np.clip(i - 1, 0, ttt_ns.size - 1), np.clip(i, 0, ttt_ns.size - 1)
    pick = np.where(np.abs(ttt_ns[lo] - estimate_ns) <= np.abs(ttt_ns[hi] - estimate_ns), lo, hi)
    hit = want & (np.abs(ttt_ns[pick] - estimate_ns) <= window_ns)
    _, first = np.unique(pick[hit], return_index=True)
    keep = np.zeros(hit.size, dtype=np.bool_)
    keep[np.flatnonzero(hit)[first]] = True
    out[keep] = ttt_ns[pick[keep]]
    return out


def _tags(sisa: SisaColumns, ttt: I64, board: ClockMap | None, by_board: I64,
          board_ok: Bool, host: ClockMap, window_ns: int, host_tags: bool) -> I64:
    """The TTT tag of each forward sent to the event input: through the board map, or on host
    time (a wider window) when the log has no PTT to build one and `host_tags` allows it."""
    if board is not None:
        return ttt_match(by_board, board_ok & sisa.fwd_to_gps_event, ttt, window_ns)
    if not host_tags:
        return np.full(sisa.fwd_board_ns.shape, -1, dtype=np.int64)
    return ttt_match(host.gps_ns(sisa.fwd_t_host_ns), sisa.fwd_to_gps_event, ttt,
                      HOST_TTT_WINDOW_NS)


def sisa_pulses(sisa: SisaColumns, gps: GpsTimes, board: ClockMap | None, host: ClockMap, *,
                ttt_window_ns: int, max_board_gap_s: float, agree_floor_ns: int = 2_000,
                tag_lsb_ns: int = 100, host_tags: bool = True
                ) -> tuple[SisaPulses, dict[str, int]]:
    """GPS time of every forwarded pulse, and counts of tags and rejections. `host_tags`
    False: no tag is tied on host time (without a board map): a log whose event input also
    carried camera pulses, whose tags lie within the 300 ms host window of a frame pulse."""
    n = sisa.fwd_board_ns.size
    t = np.full(n, -1, dtype=np.int64)
    source = np.full(n, int(PulseSource.NONE), dtype=np.int64)
    by_board, board_ok = _board_times(sisa, board, max_board_gap_s)
    tolerance = (board_agreement_ns(board, sisa.fwd_board_ns, agree_floor_ns, tag_lsb_ns)
                 if board is not None else np.full(n, np.inf))
    mode1 = ~sisa.fwd_is_ppf
    ptt = ptt_of_seconds(sisa.fwd_gps_second_ns, gps.tag_t_gps_ns, gps.tag_is_ptt)
    from_ptt = mode1 & (ptt >= 0)
    t[from_ptt], source[from_ptt] = ptt[from_ptt] + GATE_DELAY_NS, PulseSource.PTT
    disagree = from_ptt & board_ok & (np.abs(t - by_board) > tolerance)
    ttt = np.sort(gps.tag_t_gps_ns[~gps.tag_is_ptt])
    tagged = _tags(sisa, ttt, board, by_board, board_ok, host, ttt_window_ns, host_tags)
    has_ttt = (tagged >= 0) & ~from_ptt
    t[has_ttt], source[has_ttt] = tagged[has_ttt], PulseSource.TTT
    ttt_disagree = has_ttt & board_ok & (np.abs(tagged - by_board) > tolerance)
    rest = (source == PulseSource.NONE) & board_ok
    t[rest], source[rest] = by_board[rest], PulseSource.BOARD
    second = (source == PulseSource.NONE) & mode1 & (sisa.fwd_gps_second_ns >= 0)
    t[second], source[second] = sisa.fwd_gps_second_ns[second] + GATE_DELAY_NS, PulseSource.SECOND
    bad = disagree | ttt_disagree
    t[bad], source[bad] = -1, PulseSource.NONE
    stats = {"ttt_tags": int(ttt.size),
             "ttt_unclaimed": int(ttt.size - np.count_nonzero(tagged >= 0)),
             "rejected_ptt_board_disagree": int(np.count_nonzero(disagree)),
             "rejected_ttt_board_disagree": int(np.count_nonzero(ttt_disagree))}
    return SisaPulses(t, source, sisa.fwd_mode, sisa.fwd_session, sisa.fwd_frame_counter), stats
