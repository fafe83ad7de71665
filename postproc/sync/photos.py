"""Every frame-camera photo on GPS time: its pulse's time, tied to its photo number.

The sync unit logs every camera pulse with its timing-board time and whether it went to the GPS
event input (`/sisa/camera_pulse`); the camera's port gives the photo numbers, a latency after
each exposure (`/camera/photo`). Here (docs/sync.md, "Photos"):

- A pulse's GPS time, best source first: the receiver's TTT tag of it (found through the board
  map within `ttt_window_ns`, among the tags no scanner forward claimed; it must agree with the
  pulse's own board time within the map's error, as a scanner pulse's must), minus the box's
  gate delay; else the board time through the board map (`board_time`: the event input was
  taken, or the tag was lost), if PPS pin the board down within `max_board_gap_s`. No board map
  at all: no time (a tag tied on host time alone could be the scanner's).
- A photo message is tied to the one pulse whose host time lies in its window before it (the
  camera's stated latency: `camera_message_window_ms` in the log's metadata). None there: the
  pulse was lost (`no_pulse`). Two there, or one pulse two messages claim: `ambiguous`. A
  pulse no message claimed keeps its time with photo number −1 (`no_photo_number`: a lost
  message, or a pulse the camera never made).
Never a silent wrong time: a photo without a single pulse has t_gps_ns = −1.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from postproc.sync.clockmap import BOARD_SIGMA_FLOOR_S, ClockMap
from postproc.sync.flightlog import CameraColumns
from postproc.sync.pulses import (
    GATE_DELAY_NS,
    PulseSource,
    SisaPulses,
    board_agreement_ns,
    ttt_match,
)
from sisa.core.timescale import NS_PER_S

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]

DEFAULT_WINDOW_MS: Final = (0.0, 100.0)  # a log that does not say its camera's latency
SQRT12: Final = 12.0 ** 0.5


class PhotoStatus(IntEnum):
    OK = 0  # photo number tied to its pulse, timed by the receiver's tag
    BOARD_TIME = 1  # tied, timed by the timing board (no tag: input taken, tag lost)
    NO_PHOTO_NUMBER = 2  # a pulse no message named: timed, number unknown (−1)
    NO_PULSE = 3  # a message with no pulse in its window: the pulse was lost
    AMBIGUOUS = 4  # two pulses in its window, or its pulse claimed by two messages
    NO_TIME = 5  # tied, but its pulse has no GPS time (no board map, tag and board disagree)


class PhotoTimeSource(IntEnum):
    EVENT_TAG = 0
    BOARD = 1
    NONE = 2


TIMED: Final = (PhotoStatus.OK, PhotoStatus.BOARD_TIME, PhotoStatus.NO_PHOTO_NUMBER)


@dataclass(frozen=True)
class PhotoTimes:
    """One row per photo message and per pulse no message claimed, in host-time order."""

    photo_number: I64  # −1: a pulse no message named
    t_gps_ns: I64  # mid-exposure, GPS ns; −1 unless status is ok, board_time or no_photo_number
    sigma_ns: F64  # the time's predicted error (1 σ); NaN without a time
    source: I64  # PhotoTimeSource
    status: I64  # PhotoStatus

    @property
    def timed(self) -> Bool:
        return np.asarray(self.t_gps_ns >= 0, dtype=np.bool_)


@dataclass(frozen=True)
class PulseTimes:
    """GPS mid-exposure time of every logged camera pulse, its σ and source."""

    t_gps_ns: I64
    sigma_ns: F64
    source: I64  # PhotoTimeSource
    rejected: int  # tags that disagreed with their pulse's board time


def pulse_times(cam: CameraColumns, ttt: I64, casi: SisaPulses, board: ClockMap | None, *,
                ttt_window_ns: int, max_board_gap_s: float, agree_floor_ns: int,
                tag_lsb_ns: int) -> PulseTimes:
    """Each camera pulse's mid-exposure on GPS time (module docstring)."""
    n = cam.pulse_board_ns.size
    t = np.full(n, -1, dtype=np.int64)
    sigma = np.full(n, np.nan)
    source = np.full(n, int(PhotoTimeSource.NONE), dtype=np.int64)
    if board is None or n == 0:
        return PulseTimes(t, sigma, source, 0)
    out_board = cam.pulse_board_ns + GATE_DELAY_NS
    by_board = board.gps_ns(out_board)
    near = np.asarray(board.gap_s(out_board) <= max_board_gap_s, dtype=np.bool_)
    claimed = casi.t_gps_ns[casi.source == PulseSource.TTT]
    free = np.sort(np.setdiff1d(ttt, claimed))
    tag = ttt_match(by_board, near & cam.pulse_to_gps_event, free, ttt_window_ns)
    tolerance = board_agreement_ns(board, out_board, agree_floor_ns, tag_lsb_ns)
    has_tag = tag >= 0
    disagree = has_tag & (np.abs(tag - by_board) > tolerance)
    use_tag = has_tag & ~disagree
    t[use_tag] = tag[use_tag] - GATE_DELAY_NS
    sigma[use_tag] = tag_lsb_ns / SQRT12
    source[use_tag] = PhotoTimeSource.EVENT_TAG
    use_board = near & ~has_tag
    t[use_board] = by_board[use_board] - GATE_DELAY_NS
    x = (out_board[use_board] - board.epoch_ns).astype(np.float64) / NS_PER_S
    # the line's own error there: the PPS edges' scatter (at least their floor: PTT rounding,
    # PPS jitter) through the fit's leverage; the board's own stamp adds nothing
    point_s = max(board.line.sigma, BOARD_SIGMA_FLOOR_S)
    sigma[use_board] = point_s * NS_PER_S * np.sqrt(board.line.leverage(x))
    source[use_board] = PhotoTimeSource.BOARD
    return PulseTimes(t, sigma, source, int(np.count_nonzero(disagree)))


def tie_messages(msg_t_host_ns: I64, pulse_t_host_ns: I64, window_ns: tuple[int, int]
                 ) -> tuple[I64, I64]:
    """(the pulse index of each message, −1 if none or several lie in its window; how many
    pulses lie there). Pulse host times are in log order (non-decreasing)."""
    lo, hi = window_ns
    first = np.searchsorted(pulse_t_host_ns, msg_t_host_ns - hi, side="left")
    last = np.searchsorted(pulse_t_host_ns, msg_t_host_ns - lo, side="right")
    count = (last - first).astype(np.int64)
    return np.where(count == 1, first, -1).astype(np.int64), count


def photo_times(cam: CameraColumns, pulses: PulseTimes, window_ms: tuple[float, float]
                ) -> tuple[PhotoTimes, dict[str, Any]]:
    """The photos table (module docstring) and its counts for the report."""
    window_ns = (round(window_ms[0] * 1e6), round(window_ms[1] * 1e6))
    order = np.argsort(cam.pulse_t_host_ns, kind="stable")
    index, count = tie_messages(cam.photo_t_host_ns, cam.pulse_t_host_ns[order], window_ns)
    pulse_of = np.full(index.size, -1, dtype=np.int64)
    pulse_of[index >= 0] = order[index[index >= 0]]
    claims = np.bincount(pulse_of[pulse_of >= 0], minlength=cam.pulse_board_ns.size)
    tied = pulse_of >= 0
    tied[tied] = claims[pulse_of[tied]] == 1
    m = cam.photo_number.size
    status = np.full(m, int(PhotoStatus.AMBIGUOUS), dtype=np.int64)
    status[count == 0] = PhotoStatus.NO_PULSE
    p = pulse_of[tied]
    src = pulses.source[p]
    status[tied] = np.select([src == PhotoTimeSource.EVENT_TAG, src == PhotoTimeSource.BOARD],
                             [int(PhotoStatus.OK), int(PhotoStatus.BOARD_TIME)],
                             int(PhotoStatus.NO_TIME))
    t = np.full(m, -1, dtype=np.int64)
    sigma = np.full(m, np.nan)
    source = np.full(m, int(PhotoTimeSource.NONE), dtype=np.int64)
    t[tied], sigma[tied], source[tied] = pulses.t_gps_ns[p], pulses.sigma_ns[p], src
    t[~np.isin(status, TIMED)] = -1
    sigma[t < 0], source[t < 0] = np.nan, PhotoTimeSource.NONE
    unclaimed = np.flatnonzero(claims == 0)
    loose_t = pulses.t_gps_ns[unclaimed]
    rows = PhotoTimes(
        np.concatenate([cam.photo_number, np.full(unclaimed.size, -1, dtype=np.int64)]),
        np.concatenate([t, loose_t]),
        np.concatenate([sigma, np.where(loose_t >= 0, pulses.sigma_ns[unclaimed], np.nan)]),
        np.concatenate([source, np.where(loose_t >= 0, pulses.source[unclaimed],
                                         int(PhotoTimeSource.NONE))]),
        np.concatenate([status, np.full(unclaimed.size, int(PhotoStatus.NO_PHOTO_NUMBER),
                                        dtype=np.int64)]))
    host = np.concatenate([cam.photo_t_host_ns, cam.pulse_t_host_ns[unclaimed]])
    rows = _take(rows, np.argsort(host, kind="stable"))
    report = {
        "camera_pulses": int(cam.pulse_board_ns.size),
        "camera_pulses_to_gps_event": int(np.count_nonzero(cam.pulse_to_gps_event)),
        "camera_pulses_tagged": int(np.count_nonzero(pulses.source == PhotoTimeSource.EVENT_TAG)),
        "camera_pulses_board_timed": int(np.count_nonzero(pulses.source == PhotoTimeSource.BOARD)),
        "rejected_ttt_board_disagree": pulses.rejected,
        "photo_messages": int(m),
        "message_window_ms": list(window_ms),
        "status": {s.name.lower(): int(np.count_nonzero(rows.status == s)) for s in PhotoStatus},
    }
    return rows, report


def _take(rows: PhotoTimes, order: I64) -> PhotoTimes:
    return PhotoTimes(rows.photo_number[order], rows.t_gps_ns[order], rows.sigma_ns[order],
                      rows.source[order], rows.status[order])
