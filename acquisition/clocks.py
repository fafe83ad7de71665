"""The clocks the acquisition has, as real hardware gives them.

- The SISA's timing board: a free-running counter (its own offset and drift) that time-stamps
  every pulse edge. Edges from the emulated wires carry the emulation's timeline; the board turns
  that into its own counter, and only the counter is logged.
- The host clock: the logging computer's wall clock (UTC-ish, NTP-disciplined, not GPS time).
  In real time it is `time.time_ns()`; in a virtual-time simulation it is modelled.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from sisa.core.timescale import unix_ns_from_gps_ns

PPM = 1e-6


@dataclass
class TimingBoard:
    """Counter time of edges: board_ns = start_count_ns + (t − t_first)·(1 + drift)."""

    drift_ppm: float = 12.0
    start_count_ns: int = 1_000_000_000
    _t_first_ns: int | None = field(default=None, repr=False)

    def counter_ns(self, t_edge_ns: int) -> int:
        if self._t_first_ns is None:
            self._t_first_ns = t_edge_ns
        dt = t_edge_ns - self._t_first_ns
        return self.start_count_ns + dt + round(dt * self.drift_ppm * PPM)


@dataclass
class SimulatedHostClock:
    """A logging computer's clock in a virtual-time run: Unix time (UTC) plus an NTP offset and
    a small drift, read when the bytes arrive."""

    leap_s: int
    offset_ns: int = 37_000_000
    drift_ppm: float = 3.0
    t_ref_ns: int = 0

    def now_ns(self, t_gps_ns: int) -> int:
        dt = t_gps_ns - self.t_ref_ns
        return unix_ns_from_gps_ns(t_gps_ns, self.leap_s) + self.offset_ns + round(
            dt * self.drift_ppm * PPM)


def wall_clock_ns() -> int:
    """The host clock in real time."""
    return time.time_ns()
