"""The sync unit with a frame camera beside the scanner (issue 37): camera pulses share the GPS
event input, never the INS sync input, and every pulse sent to the event input is one the
receiver has re-armed for, its source logged with its board time."""

from __future__ import annotations

import itertools
import random

from acquisition.syncfilter import (
    GATE_DELAY_NS,
    Forward,
    Log,
    PulseSource,
    SyncFilter,
    SyncFilterConfig,
)
from recorder.messages import SyncCameraPulse, SyncForward, SyncModeSwitch, SyncPps
from tests.acquisition.test_syncfilter import (
    BOARD0,
    HOST_OFFSET,
    MS,
    Event,
    S,
    Segment,
    _dispatch,
    board,
    config,
    make_stream,
)

SEGMENTS = [Segment(6.0, 26.0, 16 * MS, 12_000), Segment(34.0, 52.0, 16 * MS, 12_000, 1)]
RATE_HZ = 5.0  # a receiver taking 5 events a second: the scanner's 1 of 64 and a photo a second


def camera_events(times_ns: list[int], first_order: int) -> list[Event]:
    """Camera pulse edges at these true times, reaching the host 50–300 µs later."""
    rng = random.Random(7)
    return [Event(t + rng.randint(50_000, 300_000) + HOST_OFFSET, first_order + i, "camera",
                  board(t)) for i, t in enumerate(times_ns)]


def photo_times_ns(start_s: float, end_s: float, interval_s: float) -> list[int]:
    n = int((end_s - start_s) / interval_s) + 1
    return [round((start_s + k * interval_s) * S) for k in range(n)]


def drive(cfg: SyncFilterConfig, events: list[Event]) -> tuple[SyncFilter, list[Forward | Log]]:
    flt = SyncFilter(cfg, board_ns=BOARD0, t_host_ns=HOST_OFFSET)
    actions: list[Forward | Log] = list(flt.start_actions())
    for ev in sorted(events):
        if ev.kind == "camera":
            actions += flt.on_camera(ev.board_ns, ev.t_host_ns)
        else:
            actions += _dispatch(flt, ev)
    return flt, actions + flt.flush()


def logs(actions: list[Forward | Log], kind: type) -> list:
    return [a.message for a in actions if isinstance(a, Log) and isinstance(a.message, kind)]


def forwards(actions: list[Forward | Log]) -> list[Forward]:
    return [a for a in actions if isinstance(a, Forward)]


def two_sensor_runs(photos_ns: list[int]) -> tuple[list[Forward | Log], list[Forward | Log],
                                                   SyncFilterConfig]:
    cfg = config(max_event_rate_hz=RATE_HZ)
    stream = make_stream(60, SEGMENTS, seed=3)
    _, without = drive(cfg, stream.events)
    _, with_camera = drive(cfg, stream.events + camera_events(photos_ns, len(stream.events)))
    return without, with_camera, cfg


def scanner_photos_ns() -> list[int]:
    """A photo every 0.77 s over the strips: every phase to the 1.024 s frame forwards."""
    return photo_times_ns(6.5, 25.5, 0.77) + photo_times_ns(34.5, 51.5, 0.77)


def test_the_ins_gets_the_same_pulses_with_a_camera_as_without() -> None:
    without, with_camera, _ = two_sensor_runs(scanner_photos_ns())
    to_ins = [(f.board_ns, f.source) for f in forwards(without) if f.to_ins]
    assert len(to_ins) > 40  # gated PPS and 1 of 64 frames, both modes flown
    assert [(f.board_ns, f.source) for f in forwards(with_camera) if f.to_ins] == to_ins
    assert not any(f.to_ins for f in forwards(with_camera) if f.source is PulseSource.CAMERA)
    assert logs(with_camera, SyncPps) == logs(without, SyncPps)
    assert logs(with_camera, SyncModeSwitch) == logs(without, SyncModeSwitch)
    # the forward records differ only where a camera pulse had the event input
    a, b = logs(without, SyncForward), logs(with_camera, SyncForward)
    assert [r.__dict__ | {"to_gps_event": 0} for r in a] == [
        r.__dict__ | {"to_gps_event": 0} for r in b]
    lost = [r for r, s in zip(a, b, strict=True) if r.to_gps_event != s.to_gps_event]
    assert lost
    assert all(r.to_gps_event and r.source == "PPF" for r in lost)


def test_no_two_pulses_reach_the_event_input_before_the_receiver_rearms() -> None:
    _, with_camera, cfg = two_sensor_runs(scanner_photos_ns())
    sent = sorted((f.board_ns, f.source) for f in forwards(with_camera) if f.to_gps_event)
    assert {s for _, s in sent} == {PulseSource.PPF, PulseSource.CAMERA}
    for (a, sa), (b, sb) in itertools.pairwise(sent):
        both_pps = sa is PulseSource.PPS and sb is PulseSource.PPS
        need = cfg.event_period_ns + (-1 if both_pps else 1) * cfg.spacing_tolerance_ns
        assert b - a >= need


def test_every_camera_pulse_is_logged_once_with_its_board_time_and_where_it_went() -> None:
    photos = scanner_photos_ns()
    _, with_camera, _ = two_sensor_runs(photos)
    recs = logs(with_camera, SyncCameraPulse)
    assert [r.seq for r in recs] == list(range(len(photos)))
    assert [r.board_ns for r in recs] == [board(t) for t in photos]
    sent = {f.board_ns - GATE_DELAY_NS for f in forwards(with_camera)
            if f.source is PulseSource.CAMERA}
    assert {r.board_ns for r in recs if r.to_gps_event} == sent
    busy = [r for r in recs if not r.to_gps_event]
    assert busy
    assert len(busy) < len(recs) // 3


def _first_frame_forward(actions: list[Forward | Log]) -> int:
    return next(f.board_ns for f in forwards(actions)
                if f.source is PulseSource.PPF and f.to_gps_event)


def _true_time(board_ns: int) -> int:
    """The true time of a board count (board() inverted, to the ns)."""
    t = board_ns - BOARD0
    return t - t * 12 // 1_000_012


def test_a_camera_pulse_just_after_a_forwarded_frame_pulse_finds_the_input_taken() -> None:
    """(0.4 ms apart: the two edges reach the host 50–300 µs late each; whichever the unit
    handles first has the input: the two links carry no common order)"""
    without, _, _ = two_sensor_runs([])
    fwd_board = _first_frame_forward(without)
    t = _true_time(fwd_board - GATE_DELAY_NS)
    with_camera = two_sensor_runs([t + 400_000])[1]
    rec = logs(with_camera, SyncCameraPulse)[0]
    assert not rec.to_gps_event
    assert _first_frame_forward(with_camera) == fwd_board  # the frame pulse kept it
    assert not [f for f in forwards(with_camera) if f.source is PulseSource.CAMERA]


def test_a_camera_pulse_just_before_a_forwarded_frame_pulse_takes_the_input() -> None:
    without, _, _ = two_sensor_runs([])
    fwd_board = _first_frame_forward(without)
    t = _true_time(fwd_board - GATE_DELAY_NS)
    with_camera = two_sensor_runs([t - 400_000])[1]
    rec = logs(with_camera, SyncCameraPulse)[0]
    assert rec.to_gps_event
    frame = next(f for f in forwards(with_camera) if f.board_ns == fwd_board)
    assert frame.to_ins
    assert not frame.to_gps_event
    record = next(r for r in logs(with_camera, SyncForward) if r.board_ns == fwd_board)
    assert not record.to_gps_event
    assert record.source == "PPF"


def test_camera_pulses_alone_never_switch_modes_nor_reach_the_ins() -> None:
    cfg = config(max_event_rate_hz=RATE_HZ)
    stream = make_stream(40, [], seed=4)
    photos = photo_times_ns(5.0, 35.0, 0.5)
    flt, acts = drive(cfg, stream.events + camera_events(photos, len(stream.events)))
    assert not logs(acts, SyncModeSwitch)
    assert all(f.source is PulseSource.PPS for f in forwards(acts) if f.to_ins)
    assert flt.counters.camera_pulses == len(photos)
    assert flt.counters.camera_to_gps_event == len(photos)  # mode 1: nothing else on it
