"""Maps from the logging computer's clock and from the timing board's counter to GPS time.

- Host clock → GPS: from the PPS edges the sync unit logged (the host time the timing board's
  report of the edge came, paired with the edge's GPS second), else from the fixes, else from
  the tags too. Good to a few ms: enough to say which few seconds an INS record belongs to,
  never to time it. Never from tag receive times while there is better: a TTT goes out when its
  pulse came, and the receiver's serial port queues it behind the others (or an emulator held
  it back: 0.4 s late on average at 20.8 tags a second, and a map through every pair came out
  at −870 ppm with a 280 ms residual, where it is ~−4 ppm and 10 ms).
- Timing board → GPS: from the PPS input edges the board stamped and the GPS time the receiver
  gave each edge (PTT). Good to tens of ns: used to associate forwarded pulses with their TTT
  tags, and to time a forwarded pulse that got no tag (a PPS outage, the event input's dead
  time) when PPS on both sides pin the board down.

Each map is a robust line of (GPS − source clock) against the source clock, in float seconds
relative to local epochs (int64 ns in, int64 ns out).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from postproc.sync.linefit import Line, robust_line
from sisa.core.errors import InputError
from sisa.core.timescale import NS_PER_S

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]

HOST_SIGMA_FLOOR_S: Final = 1e-3  # serial latency scatter
MIN_PPS_PAIRS: Final = 10  # PPS edges with their second that make a host map of their own
# the fixes' latency after the PPS map (their epoch minus the map at their host time): NMEA
# latency and the serial queue; a PPS map whole seconds off (mislabelled seconds) falls outside
FIX_LAG_RANGE_NS: Final = (-500_000_000, 50_000_000)
BOARD_SIGMA_FLOOR_S: Final = 50e-9  # PTT resolution and PPS jitter
SECOND_WINDOW_NS: Final = 1_000_000  # a PTT belongs to the GPS second within 1 ms of it


@dataclass(frozen=True)
class ClockMap:
    """GPS ≈ t + offset_ns + line(t), the line in float seconds of t − epoch_ns (the integer
    offset keeps the float part small: float64 seconds since 1980 resolve only ~0.2 µs)."""

    epoch_ns: int
    offset_ns: int
    line: Line
    samples_ns: I64  # the source-clock times of the inlier pairs, sorted
    source: str = ""  # what the pairs were (host map: pps, fixes, fixes+tags)

    def gps_ns(self, t_ns: npt.ArrayLike) -> I64:
        t = np.asarray(t_ns, dtype=np.int64)
        x = (t - self.epoch_ns).astype(np.float64) / NS_PER_S
        return t + self.offset_ns + np.rint(self.line(x) * NS_PER_S).astype(np.int64)

    def gap_s(self, t_ns: npt.ArrayLike) -> F64:
        """Distance to the nearest pair the map was fitted on (how far it interpolates)."""
        t = np.asarray(t_ns, dtype=np.int64)
        s = self.samples_ns
        i = np.searchsorted(s, t)
        left = s[np.clip(i - 1, 0, s.size - 1)]
        right = s[np.clip(i, 0, s.size - 1)]
        near = np.minimum(np.abs(t - left), np.abs(right - t))
        return np.asarray(near, dtype=np.float64) / NS_PER_S

    @property
    def residual_rms_ns(self) -> float:
        return self.line.sigma * NS_PER_S

    @property
    def drift_ppm(self) -> float:
        """Rate of GPS time against the source clock, minus one."""
        return self.line.slope * 1e6


def fit_clock_map(t_ns: I64, gps_ns: I64, sigma_floor_s: float) -> ClockMap | None:
    """Robust map from pairs (source time, GPS time); None without pairs."""
    if t_ns.size == 0:
        return None
    epoch = int(np.median(t_ns))
    offset = int(np.median(gps_ns - t_ns))
    x = (t_ns - epoch).astype(np.float64) / NS_PER_S
    y = (gps_ns - t_ns - offset).astype(np.float64) / NS_PER_S
    line, inliers = robust_line(x, y, sigma_floor=sigma_floor_s, slope=0.0 if x.size < 3 else None)
    return ClockMap(epoch, offset, line, np.sort(t_ns[inliers]))


def host_map(fix_host_ns: I64, fix_gps_ns: I64, tag_host_ns: I64, tag_gps_ns: I64,
             pps_host_ns: I64 | None = None, pps_gps_ns: I64 | None = None) -> ClockMap:
    """Host clock → GPS time; InputError if the log has no pair at all.

    Best first: the PPS edges (`pps_host_ns`: when the timing board's report of each edge reached
    the host, no serial message behind it; `pps_gps_ns`: its GPS second), at least
    MIN_PPS_PAIRS of them, used only if the fixes (when there are any) lag that map by what a
    fix lags (FIX_LAG_RANGE_NS); else the fixes (one per NMEA epoch, a fixed latency after it);
    else the fixes and the PTT/TTT tags."""
    ok = fix_gps_ns > 0
    fixes = fit_clock_map(fix_host_ns[ok], fix_gps_ns[ok], HOST_SIGMA_FLOOR_S)
    if pps_host_ns is not None and pps_gps_ns is not None:
        have = pps_gps_ns > 0
        if np.count_nonzero(have) >= MIN_PPS_PAIRS:
            pps = fit_clock_map(pps_host_ns[have], pps_gps_ns[have], HOST_SIGMA_FLOOR_S)
            lag = (np.median(fix_gps_ns[ok] - pps.gps_ns(fix_host_ns[ok]))
                   if fixes is not None and pps is not None else 0.0)
            if pps is not None and FIX_LAG_RANGE_NS[0] < lag <= FIX_LAG_RANGE_NS[1]:
                return dataclasses.replace(pps, source="pps")
    if fixes is not None and fixes.line.n >= 3:
        return dataclasses.replace(fixes, source="fixes")
    host = np.concatenate([fix_host_ns, tag_host_ns])
    gps = np.concatenate([fix_gps_ns, tag_gps_ns])
    ok = gps > 0
    result = fit_clock_map(host[ok], gps[ok], HOST_SIGMA_FLOOR_S)
    if result is None:
        raise InputError("the log states no GPS time (no /gps/fix, no /gps/time_tag): "
                         "nothing to synchronise to")
    return dataclasses.replace(result, source="fixes+tags")


def ptt_of_seconds(seconds_ns: I64, tag_gps_ns: I64, tag_is_ptt: Bool) -> I64:
    """The PTT time of each GPS second's PPS edge, -1 where the receiver sent none (or two)."""
    ptt = np.sort(tag_gps_ns[tag_is_ptt])
    second = (ptt + NS_PER_S // 2) // NS_PER_S * NS_PER_S
    keep = np.abs(ptt - second) <= SECOND_WINDOW_NS
    ptt, second = ptt[keep], second[keep]
    unique, first, counts = np.unique(second, return_index=True, return_counts=True)
    single = counts == 1
    unique, value = unique[single], ptt[first[single]]
    out = np.full(seconds_ns.shape, -1, dtype=np.int64)
    if unique.size:
        i = np.clip(np.searchsorted(unique, seconds_ns), 0, unique.size - 1)
        hit = unique[i] == seconds_ns
        out[hit] = value[i[hit]]
    return out


def board_map(pps_board_ns: I64, pps_gps_second_ns: I64, pps_spurious: Bool,
              tag_gps_ns: I64, tag_is_ptt: Bool) -> ClockMap | None:
    """Timing board → GPS from the PPS edges with a PTT; None if there is none.

    Assumes one free-running board counter for the whole log (the SISA's timing board is never
    reset by a restart of the sync program); a counter that went back would show as outliers and
    a large residual in the report.
    """
    usable = ~pps_spurious & (pps_gps_second_ns >= 0)
    ptt = ptt_of_seconds(pps_gps_second_ns[usable], tag_gps_ns, tag_is_ptt)
    have = ptt >= 0
    return fit_clock_map(pps_board_ns[usable][have], ptt[have], BOARD_SIGMA_FLOOR_S)
