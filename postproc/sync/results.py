"""What synchronisation gives: every INS record's and every scan line's GPS time with its
status, and the INS solution in full for reports and tests. Types only, so the report and the
pipeline can both speak them without importing each other."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from postproc.sync.insclock import InsTimeline
from postproc.sync.insfit import ClockRun
from postproc.sync.lines import SegmentFit
from postproc.sync.pattern import BlockMatch
from postproc.sync.photos import PhotoTimes

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class InsTimes:
    """Per INS record, in log order."""

    seq: I64
    counter: I64
    t_gps_ns: I64  # measurement epoch, GPS ns; −1 unless status is OK
    status: I64  # TimeStatus


@dataclass(frozen=True)
class LineTimes:
    """Per scan line (files' order, or header order without the files)."""

    segment: I64
    line: I64
    frame_counter: I64
    t_gps_ns: I64  # mid-exposure, GPS ns; −1 unless status is OK
    status: I64


@dataclass(frozen=True)
class InsSolution:
    """The INS side in full, for reports and tests: timeline, latches, blocks and fits.
    Runs index latches (timeline.latch_record order) and pulses (pulse_t_s order)."""

    timeline: InsTimeline
    latch_x_s: F64  # INS clock seconds of each latch in its piece
    pulse_t_s: F64  # usable forwarded pulses, GPS seconds of the flight epoch, sorted
    pulse_mode: I64  # their sync mode (1: gated PPS, 2: frame pulse)
    runs: list[ClockRun]
    blocks: list[BlockMatch]
    run_of_record: I64
    record_x_s: F64
    noise_s: float


@dataclass(frozen=True)
class SyncResult:
    ins: InsTimes
    lines: LineTimes
    report: dict[str, Any]
    ins_solution: InsSolution
    segment_fits: list[SegmentFit]
    photos: PhotoTimes | None = None  # a flight with a frame camera only
