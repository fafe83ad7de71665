"""Issue 32, item 3 (post-processing side): a forwarded pulse is used only if its own board time
agrees with its PTT or TTT tag within the board map's error, never within the 50 µs of the tag
association window. Hand-made logs: a timing board with 12 ppm drift and 20 ns PPS jitter."""

from __future__ import annotations

import numpy as np

from postproc.sync import GpsTimes, SisaColumns
from postproc.sync.clockmap import board_map, host_map
from postproc.sync.pulses import GATE_DELAY_NS, PulseSource, sisa_pulses

S = 10**9
GPS0 = 1_400_000_000 * S
BOARD0 = 5 * S


def _board(t_rel_ns: np.ndarray) -> np.ndarray:
    return BOARD0 + t_rel_ns + t_rel_ns * 12 // 10**6


def _log(fwd_rel_ns: list[int], fwd_is_ppf: list[bool], fwd_second: list[int],
         ttt_rel_ns: list[int]) -> tuple[SisaColumns, GpsTimes]:
    """60 s of PPS with their PTT, forwards at the given true times (relative to GPS0, output
    edges), TTT tags at the given true times."""
    rng = np.random.default_rng(4)
    seconds = np.arange(60, dtype=np.int64) * S
    edge = seconds + np.rint(rng.normal(0, 20, seconds.size)).astype(np.int64)
    ptt = GPS0 + (edge + 50) // 100 * 100
    ttt = GPS0 + (np.array(ttt_rel_ns, dtype=np.int64) + 50) // 100 * 100
    tags = np.concatenate([ptt, ttt])
    is_ptt = np.concatenate([np.ones(ptt.size, bool), np.zeros(ttt.size, bool)])
    host = GPS0 - 18 * S + np.concatenate([seconds + 25_000_000,
                                           np.array(ttt_rel_ns, dtype=np.int64) + 30_000_000])
    fix_host = GPS0 - 18 * S + seconds + 40_000_000
    gps = GpsTimes(fix_host, GPS0 + seconds, host, tags, is_ptt)
    fwd = np.array(fwd_rel_ns, dtype=np.int64)
    n = fwd.size
    ppf = np.array(fwd_is_ppf, dtype=np.bool_)
    sisa = SisaColumns(
        GPS0 - 18 * S + seconds, _board(edge), GPS0 + seconds, np.zeros(60, bool),
        GPS0 - 18 * S + fwd, np.zeros(n, np.int64), _board(fwd),
        np.where(ppf, 2, 1).astype(np.int64), ppf, ppf.copy(),
        np.array(fwd_second, dtype=np.int64), np.full(n, -1, np.int64),
        np.array([4], dtype=np.int64), 0)
    return sisa, gps


def _pulses(sisa: SisaColumns, gps: GpsTimes):
    board = board_map(sisa.pps_board_ns, sisa.pps_gps_second_ns, sisa.pps_spurious,
                      gps.tag_t_gps_ns, gps.tag_is_ptt)
    host = host_map(gps.fix_t_host_ns, gps.fix_t_gps_ns, gps.tag_t_host_ns, gps.tag_t_gps_ns)
    return sisa_pulses(sisa, gps, board, host, ttt_window_ns=50_000, max_board_gap_s=120.0)


def test_a_forward_whose_board_time_disagrees_with_its_ptt_is_never_used() -> None:
    """Mode 1: the box forwarded an edge 20 µs (and one 0.57 ms) before the true PPS of a
    second and logged that second; the PTT is the true edge's. Inside the 50 µs window it was
    used, 20 µs off: now it is rejected, and the good forwards are kept."""
    fwd = [10 * S + GATE_DELAY_NS, 20 * S - 20_000 + GATE_DELAY_NS,
           30 * S - 570_000 + GATE_DELAY_NS, 40 * S + GATE_DELAY_NS]
    sisa, gps = _log(fwd, [False] * 4, [GPS0 + k * S for k in (10, 20, 30, 40)], [])
    pulses, stats = _pulses(sisa, gps)
    assert pulses.source.tolist() == [PulseSource.PTT, PulseSource.NONE, PulseSource.NONE,
                                      PulseSource.PTT]
    assert (pulses.t_gps_ns[[1, 2]] == -1).all()
    assert np.abs(pulses.t_gps_ns[[0, 3]] - (GPS0 + np.array(fwd)[[0, 3]])).max() < 200
    assert stats["rejected_ptt_board_disagree"] == 2


def test_a_forward_whose_ttt_disagrees_with_its_board_time_is_never_used() -> None:
    """Mode 2: a TTT 8 µs from the forward's board time (a tag of another edge on the event
    input, inside the 50 µs association window) is not its time; a tag that agrees is."""
    fwd = [12 * S + 345_678, 24 * S + 876_543]
    ttt = [12 * S + 345_678, 24 * S + 876_543 + 8_000]
    sisa, gps = _log(fwd, [True, True], [-1, -1], ttt)
    pulses, stats = _pulses(sisa, gps)
    assert pulses.source.tolist() == [PulseSource.TTT, PulseSource.NONE]
    assert abs(int(pulses.t_gps_ns[0]) - (GPS0 + fwd[0])) <= 50
    assert stats["rejected_ttt_board_disagree"] == 1
