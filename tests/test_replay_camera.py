"""`sisa replay` of a flight with a frame camera: its photo messages go out on their own pty and
`sisa record --camera` takes them back, so the camera's bench test runs from a recorded flight as
the scanner's does. The flight is the bench_camera block made short (tests/replaying.py), and
test_replay_roundtrip.py's comparison rules hold: host times are the recorder's own."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from postproc.sync import sync_log
from postproc.sync.photos import PhotoStatus
from recorder.messages import RawBytes, Topic
from recorder.reader import read_log
from recorder.replay import Wire, iter_schedule, survey_log
from recorder.writer import FlightRecorder
from tests.replaying import SISA, replay_and_record


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    """(original log, replayed-and-recorded log, replay's stdout, endpoints)."""
    return replay_and_record(tmp_path_factory.mktemp("camera_roundtrip"), base="bench_camera")


def _camera_bytes(path: Path) -> bytes:
    return b"".join(item.payload for item in iter_schedule(path, wires={Wire.CAMERA})
                    if isinstance(item.payload, bytes))


def test_the_camera_gets_its_own_port_and_its_bytes_come_back_unchanged(flights):
    original, again, out, ep = flights
    assert ep["camera"].startswith("/dev/pts/")
    sent = _camera_bytes(original)
    assert len(sent) > 100  # ten photo messages of 13 bytes on this strip
    assert _camera_bytes(again) == sent
    assert f"camera {len(sent)} B" in out.strip().splitlines()[-1]


def test_photo_messages_and_camera_pulses_are_the_same(flights):
    original, again, _, _ = flights

    def of(path: Path, topic: str) -> list[dict[str, Any]]:
        return [{k: v for k, v in f.items() if k != "t_host_ns"}
                for t, _, f in read_log(path) if t == topic]

    for topic in (Topic.CAMERA_PHOTO, Topic.SYNC_CAMERA):
        before = of(original, topic)
        assert len(before) >= 5, f"the original has {len(before)} {topic}"
        assert of(again, topic) == before, f"{topic} differs"


def test_the_replayed_flight_times_the_same_photos(flights):
    original, again, _, _ = flights
    a, b = sync_log(original).photos, sync_log(again).photos
    assert a is not None
    assert b is not None
    assert a.t_gps_ns.size >= 5
    # every photo timed: by its tag, or by the timing board where the receiver took no tag
    assert np.isin(a.status, [PhotoStatus.OK, PhotoStatus.BOARD_TIME]).all()
    for name in ("photo_number", "t_gps_ns", "status"):
        np.testing.assert_array_equal(getattr(b, name), getattr(a, name), err_msg=name)


def test_a_flight_without_a_camera_opens_no_camera_port(tmp_path):
    flight = tmp_path / "f.mcap"
    with FlightRecorder(flight) as rec:
        rec.write(RawBytes(1_700_000_000_000_000_000, "gps", b"$X\r\n"), Topic.GPS_RAW)
    assert Wire.CAMERA not in survey_log(flight).first_ns
    proc = subprocess.run([*SISA, "replay", str(flight), "--once", "--no-wait", "--quiet",
                           "--endpoints", str(tmp_path / "ep.json")], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "camera" not in json.loads((tmp_path / "ep.json").read_text())
    assert "Frame camera" not in proc.stdout
