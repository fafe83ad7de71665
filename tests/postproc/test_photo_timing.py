"""Photo timing from hand-made logs: which pulse a photo number is tied to, which tag times a
camera pulse, and what is flagged instead of guessed (postproc.sync.photos)."""

from __future__ import annotations

import numpy as np
import pytest

from postproc.sync.clockmap import board_map
from postproc.sync.flightlog import CameraColumns
from postproc.sync.photos import (
    PhotoStatus,
    PhotoTimeSource,
    photo_times,
    pulse_times,
    tie_messages,
)
from postproc.sync.pulses import GATE_DELAY_NS, PulseSource, SisaPulses

MS = 1_000_000
S = 1_000_000_000
GPS0 = 1_400_000_000 * S
BOARD0 = 7 * S + 123_456  # the board counts from its own zero
WINDOW_MS = (-1.0, 50.5)


def i64(values: list[int]) -> np.ndarray:
    return np.array(values, dtype=np.int64)


def board_of(t_gps_ns: int) -> int:
    return t_gps_ns - GPS0 + BOARD0


def the_board_map():
    seconds = GPS0 + S * np.arange(60, dtype=np.int64)
    board = board_map(seconds - GPS0 + BOARD0, seconds, np.zeros(60, dtype=np.bool_), seconds,
                      np.ones(60, dtype=np.bool_))
    assert board is not None
    return board


def no_casi_tags() -> SisaPulses:
    empty = np.empty(0, dtype=np.int64)
    return SisaPulses(empty, empty, empty, empty, empty)


def camera(pulse_t_gps: list[int], to_event: list[bool], photo_host: list[int],
           numbers: list[int]) -> CameraColumns:
    """Pulses handled by the host 0.1 ms after their edge; host clock = GPS + 37 ms."""
    return CameraColumns(i64([t + 100_000 + 37 * MS for t in pulse_t_gps]),
                         i64([board_of(t) for t in pulse_t_gps]), np.array(to_event),
                         i64([t + 37 * MS for t in photo_host]), i64(numbers))


def test_a_message_ties_to_the_one_pulse_in_its_window() -> None:
    pulses = i64([0, 1 * S, 2 * S, 2 * S + 10 * MS])  # the last two: one is spurious
    messages = i64([30 * MS, 900 * MS, 1 * S + 52 * MS, 2 * S + 40 * MS])
    index, count = tie_messages(messages, pulses, (-1 * MS, 51 * MS))
    assert index.tolist() == [0, -1, -1, -1]
    assert count.tolist() == [1, 0, 0, 2]


def test_the_camera_tag_is_found_and_a_scanner_tag_is_never_taken() -> None:
    board = the_board_map()
    t = [GPS0 + 10 * S + 333_333, GPS0 + 20 * S + 777_777, GPS0 + 30 * S + 111_111]
    ttt = [x + GATE_DELAY_NS for x in t]  # the receiver tags the unit's output edge exactly
    ttt[2] = ttt[2] + 20_000  # 20 µs off: the board disagrees with it
    cam = camera(t, [True, True, True], [], [])
    casi = SisaPulses(i64([ttt[1]]), i64([int(PulseSource.TTT)]), i64([2]), i64([0]),
                      i64([5]))  # a scanner forward claimed the second tag
    got = pulse_times(cam, i64(ttt), casi, board, ttt_window_ns=50_000, max_board_gap_s=120.0,
                      agree_floor_ns=2_000, tag_lsb_ns=100)
    assert got.source.tolist() == [PhotoTimeSource.EVENT_TAG, PhotoTimeSource.BOARD,
                                   PhotoTimeSource.NONE]
    assert got.t_gps_ns[0] == t[0]
    assert abs(got.t_gps_ns[1] - t[1]) < 50  # the board's time of it
    assert got.t_gps_ns[2] == -1  # two records of one edge that disagree: no time
    assert got.rejected == 1
    assert got.sigma_ns[0] == pytest.approx(100 / 12 ** 0.5)
    assert 0 < got.sigma_ns[1] < 20


def test_without_a_board_map_no_photo_is_timed() -> None:
    t = [GPS0 + 10 * S]
    got = pulse_times(camera(t, [True], [], []), i64([t[0] + GATE_DELAY_NS]), no_casi_tags(),
                      None, ttt_window_ns=50_000, max_board_gap_s=120.0, agree_floor_ns=2_000,
                      tag_lsb_ns=100)
    assert got.t_gps_ns.tolist() == [-1]


def test_the_photo_table_flags_what_it_cannot_tie() -> None:
    board = the_board_map()
    t = [GPS0 + k * S for k in (5, 6, 7, 8)] + [GPS0 + 8 * S + 20 * MS]  # the last spurious
    # photo 1: tied; photo 2: its pulse lost (no pulse at 4 s); photo 3's message lost;
    # photo 4: two pulses in its window; photo 5: tied
    msgs = [t[0] + 30 * MS, GPS0 + 4 * S + 30 * MS, t[3] + 35 * MS, t[2] + 30 * MS]
    cam = camera(t, [True] * 5, sorted(msgs), [0, 0, 0, 0])
    cam = CameraColumns(cam.pulse_t_host_ns, cam.pulse_board_ns, cam.pulse_to_gps_event,
                        cam.photo_t_host_ns, i64([2, 1, 5, 4]))
    ttt = i64([x + GATE_DELAY_NS for x in t])
    pt = pulse_times(cam, ttt, no_casi_tags(), board, ttt_window_ns=50_000,
                     max_board_gap_s=120.0, agree_floor_ns=2_000, tag_lsb_ns=100)
    rows, report = photo_times(cam, pt, WINDOW_MS)
    by_number = dict(zip(rows.photo_number.tolist(), rows.status.tolist(), strict=False))
    assert by_number[2] == PhotoStatus.NO_PULSE
    assert by_number[1] == PhotoStatus.OK
    assert by_number[5] == PhotoStatus.OK
    assert by_number[4] == PhotoStatus.AMBIGUOUS
    loose = rows.status == PhotoStatus.NO_PHOTO_NUMBER
    assert sorted(rows.t_gps_ns[loose].tolist()) == [t[1], t[3], t[4]]  # times kept, number -1
    assert (rows.photo_number[loose] == -1).all()
    untimed = ~np.isin(rows.status, (PhotoStatus.OK, PhotoStatus.BOARD_TIME,
                                     PhotoStatus.NO_PHOTO_NUMBER))
    assert (rows.t_gps_ns[untimed] == -1).all()
    assert report["status"]["ok"] == 2


def test_one_pulse_claimed_by_two_messages_times_neither() -> None:
    board = the_board_map()
    t = [GPS0 + 5 * S]
    cam = camera(t, [True], [t[0] + 20 * MS, t[0] + 45 * MS], [1, 2])
    pt = pulse_times(cam, i64([t[0] + GATE_DELAY_NS]), no_casi_tags(), board,
                     ttt_window_ns=50_000, max_board_gap_s=120.0, agree_floor_ns=2_000,
                     tag_lsb_ns=100)
    rows, _ = photo_times(cam, pt, WINDOW_MS)
    assert rows.status.tolist() == [PhotoStatus.AMBIGUOUS, PhotoStatus.AMBIGUOUS]
    assert rows.t_gps_ns.tolist() == [-1, -1]


@pytest.mark.parametrize(("pulses", "messages"), [([], [5]), ([5], []), ([], [])])
def test_pulses_without_messages_and_messages_without_pulses(pulses: list[int],
                                                             messages: list[int]) -> None:
    board = the_board_map()
    t = [GPS0 + k * S for k in pulses]
    cam = camera(t, [True] * len(t), [GPS0 + k * S + 30 * MS for k in messages],
                 list(range(1, len(messages) + 1)))
    pt = pulse_times(cam, i64([x + GATE_DELAY_NS for x in t]), no_casi_tags(), board,
                     ttt_window_ns=50_000, max_board_gap_s=120.0, agree_floor_ns=2_000,
                     tag_lsb_ns=100)
    rows, report = photo_times(cam, pt, WINDOW_MS)
    assert rows.status.tolist() == ([PhotoStatus.NO_PHOTO_NUMBER] * len(t)
                                    + [PhotoStatus.NO_PULSE] * len(messages))
    assert rows.t_gps_ns.tolist() == t + [-1] * len(messages)
    assert report["camera_pulses"] == len(t)


def test_without_a_board_map_a_frame_pulse_ties_no_tag_on_host_time_beside_a_camera() -> None:
    """With no PPS to map the board, a frame pulse's tag was tied on host time within 300 ms;
    with camera pulses on the same event input, the nearest tag there may be a photo's."""
    from postproc.sync.clockmap import fit_clock_map
    from postproc.sync.flightlog import GpsTimes, SisaColumns
    from postproc.sync.pulses import sisa_pulses

    t_fwd = GPS0 + 10 * S
    empty, none = np.empty(0, dtype=np.int64), np.empty(0, dtype=np.bool_)
    sisa = SisaColumns(empty, empty, empty, none, i64([t_fwd + 37 * MS]), i64([0]),
                       i64([board_of(t_fwd)]), i64([2]), np.array([True]), np.array([True]),
                       i64([-1]), i64([7]), i64([4]), 1)
    photo_tag = t_fwd + 120 * MS  # the frame pulse's own tag was lost; a photo's is near
    gps = GpsTimes(empty, empty, i64([photo_tag + 37 * MS]), i64([photo_tag]), np.array([False]))
    host = fit_clock_map(GPS0 + 37 * MS + S * np.arange(20, dtype=np.int64),
                         GPS0 + S * np.arange(20, dtype=np.int64), 1e-3)
    for host_tags, want in ((True, photo_tag), (False, -1)):
        got, _ = sisa_pulses(sisa, gps, None, host, ttt_window_ns=50_000,
                             max_board_gap_s=120.0, host_tags=host_tags)
        assert got.t_gps_ns.tolist() == [want]
