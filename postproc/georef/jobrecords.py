"""What a georeferencing job is given and what it gives back: its options, each segment's
result, the lines or segments it could not georeference and why, and the flight's result."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from postproc.georef.navigation import AntennaFixes, Trajectory
from postproc.georef.sensorfile import SensorModel
from postproc.sync import SyncResult
from recorder.health import HealthTotals
from sisa.core.timescale import gps_span_label

BLOCK_LINES: Final = 4096


@dataclass(frozen=True)
class GeorefOptions:
    sensor: SensorModel
    dem: Path
    geoid: Path | float | None = None
    epsg: int | None = None  # output CRS; default: the DEM's
    cell_m: float | None = None  # ortho cell; default: the median across-track pixel spacing
    trajectory: Path | None = None  # RTKLIB .pos or Applanix SBET instead of the log's GPS
    block_lines: int = BLOCK_LINES
    products: bool = True  # ortho, GLT, mosaic, quicklooks (the IGM and EO are always made)
    leap_seconds: int | None = None  # GPS − UTC for a .pos on UTC/JST; default: the log's
    leap_seconds_fallback: int | None = None  # when neither is known (a run's scenario)
    max_gap_s: float | None = None  # longest gap bridged: SBET records / GPS fixes (by the INS)


@dataclass
class SegmentResult:
    segment: int
    lines: int
    lines_timed: int
    lines_georeferenced: int
    rays: int
    rays_hit: int
    gsd_across_m: float
    gsd_along_m: float
    t_first_gps_ns: int
    t_last_gps_ns: int
    igm: Path
    image: Path
    files: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class LineSpan:
    """A stretch of a segment's lines (first to last, inclusive) and their GPS times."""

    first_line: int
    last_line: int
    t_first_gps_ns: int
    t_last_gps_ns: int

    def as_dict(self) -> dict[str, Any]:
        return {"first_line": self.first_line, "last_line": self.last_line,
                "t_first_gps_ns": self.t_first_gps_ns, "t_last_gps_ns": self.t_last_gps_ns,
                "gps_time": gps_span_label(self.t_first_gps_ns, self.t_last_gps_ns)}


@dataclass(frozen=True)
class SegmentSkip:
    """Lines of a segment that were not georeferenced for want of a time or a pose, or a
    segment whose swath lies off the DEM or over its voids only (a whole segment: nothing made
    for it)."""

    segment: int
    lines: int
    lines_timed: int
    lines_skipped: int
    whole_segment: bool
    reason: str  # "no line time" | "no pose" | "off the DEM" | "DEM voids"
    spans: tuple[LineSpan, ...]  # timed lines without a pose
    message: str

    def as_dict(self) -> dict[str, Any]:
        return {"segment": self.segment, "lines": self.lines, "lines_timed": self.lines_timed,
                "lines_skipped": self.lines_skipped, "whole_segment": self.whole_segment,
                "reason": self.reason, "spans": [sp.as_dict() for sp in self.spans],
                "message": self.message}


@dataclass
class GeorefResult:
    sync: SyncResult
    trajectory: Trajectory
    epsg: int
    cell_m: float
    segments: list[SegmentResult]
    mosaic: Path | None
    summary: dict[str, Any]
    skipped: list[SegmentSkip] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    log_fixes: AntennaFixes | None = None  # the flight log's GPS fixes, as read for the sync
    recording_health: HealthTotals | None = None  # the recorder's counts (`sisa log info`)
