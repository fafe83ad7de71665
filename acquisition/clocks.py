"""The clocks the acquisition has, as real hardware gives them.

- The SISA's timing board: a free-running counter (its own offset and drift) that time-stamps
  every pulse edge. Edges from the emulated wires carry the emulation's timeline; the board turns
  that into its own counter, and only the counter is logged.
- The host clock: the logging computer's idea of UTC (NTP-set at best, not GPS time). In real
  time it is `wall_clock_ns()`: the system clock's reading when the process started, carried
  on by a clock that never steps; in a virtual-time simulation it is modelled.
"""

from __future__ import annotations

import os
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


# the system clock's reading when the process started, carried on by the raw clock since; a
# child process (the live view's sync) inherits its parent's, so both read one clock
HOST_CLOCK_ENV = "SISA_HOST_CLOCK_RAW_TO_UNIX_NS"


def _raw_to_unix_ns() -> int:
    inherited = os.environ.get(HOST_CLOCK_ENV, "")
    if inherited.isdigit():
        return int(inherited)
    return time.time_ns() - time.clock_gettime_ns(time.CLOCK_MONOTONIC_RAW)


_RAW_TO_UNIX_NS = _raw_to_unix_ns()
os.environ[HOST_CLOCK_ENV] = str(_RAW_TO_UNIX_NS)


def wall_clock_ns() -> int:
    """The host clock in real time: Unix ns as the system clock read when the process started,
    run on by CLOCK_MONOTONIC_RAW since, so it never steps or slews.

    The system clock does both in flight: chrony's `makestep` sets it seconds at a time once
    it hears the receiver, a leap second sets it back a second, someone sets it by hand, and
    chrony slews it by up to 8.3 % meanwhile. Every receive time after a step would move
    by it, and `sisa sync` maps host time to GPS with one line. The raw clock is the crystal's: its
    tens of ppm are that line's slope."""
    return time.clock_gettime_ns(time.CLOCK_MONOTONIC_RAW) + _RAW_TO_UNIX_NS
