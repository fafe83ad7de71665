"""What time synchronisation reads from a flight log, as typed numpy columns.

Only what a real flight log holds: host receive times, the INS's own clock, the timing board's
counter, and GPS time only where the receiver stated it (fixes, PTT, TTT). Nothing here knows
the simulation truth. `read_sync_input` reads the log in one streaming pass; the dataclasses can
also be built directly (tests, the speed benchmark).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from recorder.columns import read_topics
from recorder.framing import Paths, log_paths
from recorder.messages import Topic
from recorder.settings import header_window_of_log

Columns = dict[str, npt.NDArray[Any]]
I64 = npt.NDArray[np.int64]
Bool = npt.NDArray[np.bool_]

WANTED: Final[dict[str, tuple[str, ...]]] = {
    Topic.INS_RECORD: ("t_host_ns", "counter", "ins_time_ticks",
                       "status", "sync_flag", "sync_time_ticks"),
    Topic.SCANNER_HEADER: ("t_host_ns", "frame_counter", "segment", "integration_time_us"),
    Topic.GPS_FIX: ("t_host_ns", "t_gps_ns"),
    Topic.GPS_TIME_TAG: ("t_host_ns", "kind", "t_gps_ns"),
    Topic.SYNC_SESSION: ("session", "lfsr_bits"),
    Topic.SYNC_PPS: ("t_host_ns", "board_ns", "gps_second_ns",
                     "lfsr_bit"),
    Topic.SYNC_FORWARD: ("t_host_ns", "session", "board_ns",
                         "mode", "source", "to_gps_event",
                         "gps_second_ns", "frame_counter"),
    Topic.SYNC_MODE: ("to_mode",),
    Topic.SYNC_CAMERA: ("t_host_ns", "board_ns", "to_gps_event"),
    Topic.CAMERA_PHOTO: ("t_host_ns", "photo_number"),
}


def _i64(cols: Columns, name: str) -> I64:
    return np.asarray(cols[name], dtype=np.int64)


def _bool(cols: Columns, name: str) -> Bool:
    return np.asarray(cols[name], dtype=np.bool_)


@dataclass(frozen=True)
class InsColumns:
    """Every logged INS record, in log order."""

    t_host_ns: I64
    counter: I64
    ins_time_ticks: I64  # 100 ns ticks of the INS clock, 48-bit, wraps
    status: I64
    sync_flag: Bool
    sync_time_ticks: I64  # INS clock at the latched pulse (new only where sync_flag)


@dataclass(frozen=True)
class GpsTimes:
    """Where the receiver stated GPS time: fixes (host ↔ GPS pairs) and PTT/TTT tags."""

    fix_t_host_ns: I64
    fix_t_gps_ns: I64
    tag_t_host_ns: I64
    tag_t_gps_ns: I64
    tag_is_ptt: Bool  # PTT (the PPS edge) or TTT (an event-input pulse)


@dataclass(frozen=True)
class SisaColumns:
    """The sync unit's own log: every PPS it saw and every pulse it forwarded."""

    pps_t_host_ns: I64
    pps_board_ns: I64  # input edge on the timing board
    pps_gps_second_ns: I64  # -1: the receiver did not say
    pps_spurious: Bool  # rejected by the box (not whole seconds after the PPS train)
    fwd_t_host_ns: I64
    fwd_session: I64
    fwd_board_ns: I64  # output edge on the timing board
    fwd_mode: I64
    fwd_is_ppf: Bool
    fwd_to_gps_event: Bool
    fwd_gps_second_ns: I64  # mode 1: GPS second of the forwarded PPS, -1 unknown
    fwd_frame_counter: I64  # mode 2: frame counter of the forwarded frame, -1 unknown
    session_lfsr_bits: I64  # per SyncSession record
    mode_switches: int


@dataclass(frozen=True)
class HeaderColumns:
    """Every logged scanner frame header, in log order."""

    t_host_ns: I64
    frame_counter: I64
    segment: I64
    integration_time_us: I64 | None = None  # None: not given (the window checks are skipped)


@dataclass(frozen=True)
class CameraColumns:
    """A frame camera's pulses as the sync unit logged them, and its photo messages."""

    pulse_t_host_ns: I64
    pulse_board_ns: I64  # input edge on the timing board
    pulse_to_gps_event: Bool  # forwarded to the receiver's event input
    photo_t_host_ns: I64
    photo_number: I64

    @property
    def empty(self) -> bool:
        return self.pulse_board_ns.size == 0 and self.photo_number.size == 0


def no_camera() -> CameraColumns:
    empty = np.empty(0, dtype=np.int64)
    return CameraColumns(empty, empty, np.empty(0, dtype=np.bool_), empty, empty)


@dataclass(frozen=True)
class SyncInput:
    ins: InsColumns
    gps: GpsTimes
    sisa: SisaColumns
    headers: HeaderColumns
    camera: CameraColumns = dataclasses.field(default_factory=no_camera)
    # the sync filter's header window (ms after a frame's end) as the log records it, or the
    # default: only to refuse segments whose ties it cannot have made (lines.neighbour_ties)
    header_window_ms: tuple[float, float] | None = None


def sync_input_from_columns(cols: dict[str, Columns],
                            header_window_ms: tuple[float, float] | None = None) -> SyncInput:
    """The typed bundle from `read_topics(paths, WANTED)`; `header_window_ms` as the log
    records it (`recorder.settings.header_window_of_log`), None to skip the checks it makes."""
    ins, tags = cols[Topic.INS_RECORD], cols[Topic.GPS_TIME_TAG]
    fix, pps, fwd = cols[Topic.GPS_FIX], cols[Topic.SYNC_PPS], cols[Topic.SYNC_FORWARD]
    hdr = cols[Topic.SCANNER_HEADER]
    cam, photo = cols.get(Topic.SYNC_CAMERA), cols.get(Topic.CAMERA_PHOTO)
    camera = no_camera() if cam is None or photo is None else CameraColumns(
        _i64(cam, "t_host_ns"), _i64(cam, "board_ns"), _bool(cam, "to_gps_event"),
        _i64(photo, "t_host_ns"), _i64(photo, "photo_number"))
    return SyncInput(
        InsColumns(_i64(ins, "t_host_ns"), _i64(ins, "counter"), _i64(ins, "ins_time_ticks"),
                   _i64(ins, "status"), _bool(ins, "sync_flag"), _i64(ins, "sync_time_ticks")),
        GpsTimes(_i64(fix, "t_host_ns"), _i64(fix, "t_gps_ns"), _i64(tags, "t_host_ns"),
                 _i64(tags, "t_gps_ns"), np.asarray(tags["kind"] == "PTT", dtype=np.bool_)),
        SisaColumns(
            _i64(pps, "t_host_ns"), _i64(pps, "board_ns"), _i64(pps, "gps_second_ns"),
            np.asarray(_i64(pps, "lfsr_bit") < 0, dtype=np.bool_),
            _i64(fwd, "t_host_ns"), _i64(fwd, "session"), _i64(fwd, "board_ns"),
            _i64(fwd, "mode"), np.asarray(fwd["source"] == "PPF", dtype=np.bool_),
            _bool(fwd, "to_gps_event"), _i64(fwd, "gps_second_ns"),
            _i64(fwd, "frame_counter"), _i64(cols[Topic.SYNC_SESSION], "lfsr_bits"),
            len(cols[Topic.SYNC_MODE]["to_mode"])),
        HeaderColumns(_i64(hdr, "t_host_ns"), _i64(hdr, "frame_counter"),
                      _i64(hdr, "segment"), _i64(hdr, "integration_time_us")), camera,
        header_window_ms)


def read_sync_input(paths: Paths) -> SyncInput:
    """Everything time synchronisation needs from a log (one file or the parts of a split one),
    in one streaming pass."""
    return sync_input_from_columns(read_topics(paths, WANTED),
                                   header_window_of_log(log_paths(paths))[0])
