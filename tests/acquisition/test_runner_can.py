"""The acquisition's CAN path: a read's burst of frames is handled as the same frames one by
one would be (records, raw batches, counters), and raw batches close on size and age."""

from __future__ import annotations

import dataclasses

import can

from acquisition.ins_can import InsRecord, InsStatus, encode_record
from acquisition.runner import Acquisition, AcquisitionConfig
from acquisition.syncfilter import SyncFilterConfig
from recorder.messages import InsRecordLog, LoggedMessage, RawCanFrames, Topic

CONFIG = AcquisitionConfig(leap_s=18, sync=SyncFilterConfig(), ins_rate_hz=64.0,
                           nmea_rate_hz=2.0, line_rate_hz=62.5)
T0_NS = 1_700_000_000_000_000_000


def _frames(n_records: int) -> list[can.Message]:
    frames = []
    for k in range(n_records):
        rec = InsRecord(counter=k, ins_time_ticks=1000 * k, roll_rad=0.01 * k, pitch_rad=-0.02,
                        heading_rad=1.0, body_rate_rps=(0.0, 0.1, -0.1),
                        vel_ned_mps=(50.0, -3.0, 0.5), status=InsStatus.NAVIGATING,
                        sync_flag=False, sync_time_ticks=0)
        frames += encode_record(rec)
    return frames


def _run(bursts: list[list[can.Message]], burst_ns: int) -> tuple[list[LoggedMessage],
                                                                    Acquisition]:
    logged: list[LoggedMessage] = []

    def log(msg: LoggedMessage, _topic: Topic | None) -> None:
        logged.append(msg)

    acq = Acquisition(CONFIG, log, lambda _edge: None)
    for i, burst in enumerate(bursts):
        acq.on_can_frames(T0_NS + i * burst_ns, burst)
    acq.finish(T0_NS + len(bursts) * burst_ns)
    return logged, acq


def test_a_burst_is_handled_as_its_frames_one_by_one() -> None:
    frames = _frames(40)
    frames.insert(100, can.Message(arbitration_id=0x7FF, data=b"\x01"))  # another node's frame
    del frames[150]  # a frame lost: one record incomplete
    bursts = [frames[i:i + 9] for i in range(0, len(frames), 9)]
    burst_logged, burst_acq = _run(bursts, 5_000_000)
    single_logged: list[LoggedMessage] = []
    single = Acquisition(CONFIG, lambda m, _t: single_logged.append(m), lambda _e: None)
    for i, burst in enumerate(bursts):
        for msg in burst:
            single.on_can_frame(T0_NS + i * 5_000_000, msg)
    single.finish(T0_NS + len(bursts) * 5_000_000)
    records = [m for m in burst_logged if isinstance(m, InsRecordLog)]
    assert [r.counter for r in records] == [k for k in range(40) if k != 150 // 7]
    assert _without_health(burst_logged) == _without_health(single_logged)
    for acq in (burst_acq, single):
        assert acq.streams["ins"].messages == 39
        assert acq.streams["ins"].stats.framing_errors == 1
        assert acq.ins.frames.foreign == 1
        assert acq.ins.frames.lost == 1


def _without_health(msgs: list[LoggedMessage]) -> list[dict[str, object]]:
    return [dataclasses.asdict(m) for m in msgs  # type: ignore[call-overload]
            if isinstance(m, InsRecordLog | RawCanFrames)]


def test_raw_frames_are_logged_whole_in_batches_bounded_by_age() -> None:
    frames = _frames(30)  # 210 frames, 3 a read every 5 ms: 0.35 s
    logged, _ = _run([frames[i:i + 3] for i in range(0, len(frames), 3)], 5_000_000)
    batches = [m for m in logged if isinstance(m, RawCanFrames)]
    assert b"".join(b.data for b in batches) == b"".join(bytes(f.data) for f in frames)
    assert sum(len(b.dlcs) for b in batches) == len(frames)
    for b in batches:
        assert max(b.t_offsets_ns) <= 200_000_000  # none held longer than its age bound
    assert len(batches) == 2
