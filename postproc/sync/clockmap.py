"""Maps from the logging computer's clock and from the timing board's counter to GPS time.

- Host clock → GPS: from every place the log pairs a host receive time with a GPS time the
  receiver stated (fixes, PTT/TTT tags). Good to the serial latency, tens of ms: enough to say
  which few seconds an INS record belongs to, never to time it.
- Timing board → GPS: from the PPS input edges the board stamped and the GPS time the receiver
  gave each edge (PTT). Good to tens of ns: used to associate forwarded pulses with their TTT
  tags, and to time a forwarded pulse that got no tag (a PPS outage, the event input's dead
  time) when PPS on both sides pin the board down.

Each map is a robust line of (GPS − source clock) against the source clock, in float seconds
relative to local epochs (int64 ns in, int64 ns out).
"""

from __future__ import annotations

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


def host_map(fix_host_ns: I64, fix_gps_ns: I64, tag_host_ns: I64, tag_gps_ns: I64) -> ClockMap:
    """Host clock → GPS time from fixes and time tags; InputError if the log has neither."""
    host = np.concatenate([fix_host_ns, tag_host_ns])
    gps = np.concatenate([fix_gps_ns, tag_gps_ns])
    ok = gps > 0
    result = fit_clock_map(host[ok], gps[ok], HOST_SIGMA_FLOOR_S)
    if result is None:
        raise InputError("the log states no GPS time (no /gps/fix, no /gps/time_tag): "
                         "nothing to synchronise to")
    return result


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
