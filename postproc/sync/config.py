"""Settings of time synchronisation, and the status every timed item carries."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

from postproc.sync.pattern import PatternConfig
from sisa.core.errors import ConfigError


class TimeStatus(IntEnum):
    """Why an item has, or has not, a GPS time. Only OK items carry one (t_gps_ns = −1 else)."""

    OK = 0
    NO_PULSES = 1  # no latched pulse in its clock piece / no timed forwarded frame in its segment
    AMBIGUOUS = 2  # pulses, but no match whose false-match bound is below the threshold
    CLOCK_JUMP = 3  # between two clock fits: a jump between two pulses, side unknown
    OUTSIDE_FIT = 4  # further than the allowed extrapolation from the fitted pulses
    UNLINKED = 5  # a scan line no frame header ties to the log


@dataclass(frozen=True)
class SyncConfig:
    """Tolerances of the solver. Times in seconds unless the name says otherwise."""

    pattern: PatternConfig = field(default_factory=PatternConfig)
    assoc_tol_s: float = 2e-6  # latch ↔ pulse, once a clock fit predicts it (+ resolution)
    # INS records beyond the first/last latch of their run: none by default. A clock jump
    # smaller than a record period shows only in the latches (insjumps), so one past the last
    # latch is invisible, and a record timed there could be wrong by up to a period, unflagged
    max_extrapolation_s: float = 0.0
    max_time_sigma_s: float = 1e-6  # predicted error (1 σ) of a time from its fit
    line_max_extrapolation_s: float = 2.0  # scan lines beyond the first/last timed frame
    ttt_window_ns: int = 50_000  # forward ↔ TTT tag through the timing board
    board_agree_floor_ns: int = 2_000  # a PTT/TTT and its board time: at least this close
    max_board_gap_s: float = 120.0  # timing-board time of an untagged pulse: PPS this close
    step_min_s: float = 1e-6  # smallest INS clock step the pulse fit splits at
    step_z: float = 10.0  # ... and its significance (step / its standard error)
    tag_lsb_ns: int = 100  # PTT/TTT resolution (7 decimals of a second)
    ins_clock_resolution_ns: int | None = None  # None: from the latched values

    def __post_init__(self) -> None:
        p = self.pattern
        checks = {
            "pattern.block_s > 0": p.block_s > 0,
            "pattern.window_s > 0": p.window_s > 0,
            "0 < pattern.tol_s < 0.1": 0 < p.tol_s < 0.1,
            "pattern.min_matches ≥ 2": p.min_matches >= 2,
            "pattern.min_margin ≥ 1": p.min_margin >= 1,
            "0 < pattern.max_false_match < 1": 0 < p.max_false_match < 1,
            "pattern.density_window_s > 0": p.density_window_s > 0,
            "0 < assoc_tol_s < pattern.tol_s": 0 < self.assoc_tol_s < p.tol_s,
            "max_extrapolation_s ≥ 0": self.max_extrapolation_s >= 0,
            "line_max_extrapolation_s ≥ 0": self.line_max_extrapolation_s >= 0,
            "max_time_sigma_s > 0": self.max_time_sigma_s > 0,
            "ttt_window_ns > 0": self.ttt_window_ns > 0,
            "0 < board_agree_floor_ns ≤ ttt_window_ns":
                0 < self.board_agree_floor_ns <= self.ttt_window_ns,
            "max_board_gap_s ≥ 0": self.max_board_gap_s >= 0,
            "step_min_s > 0": self.step_min_s > 0,
            "step_z > 0": self.step_z > 0,
            "tag_lsb_ns ≥ 1": self.tag_lsb_ns >= 1,
            "ins_clock_resolution_ns: a multiple of 100": self.ins_clock_resolution_ns is None
            or (self.ins_clock_resolution_ns > 0 and self.ins_clock_resolution_ns % 100 == 0),
        }
        failed = [name for name, ok in checks.items() if not ok]
        if failed:
            raise ConfigError(f"sync config: need {', '.join(failed)}")
