"""`sisa replay` of a flight with a frame camera: its photo messages go out on their own pty and
`sisa record --camera` takes them back, so the camera's bench test runs from a recorded flight as
the scanner's does. The flight is the bench_camera block made short, replayed at x2 (as in
test_replay_roundtrip.py, whose comparison rules hold here: host times are the recorder's own)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from emulators.scenario import scenario_from_table
from postproc.sync import sync_log
from postproc.sync.photos import PhotoStatus
from recorder.messages import RawBytes, Topic
from recorder.reader import read_log
from recorder.replay import Wire, iter_schedule, survey_log
from recorder.writer import FlightRecorder
from sisa.commands.scenario import scenario_toml
from sisa.core.timescale import datetime_from_gps_ns, gps_ns_from_unix_ns
from sisa.wiring.simulation import simulate

SISA = [sys.executable, "-m", "sisa.cli"]


def _scenario() -> Any:
    now = datetime_from_gps_ns(gps_ns_from_unix_ns(time.time_ns(), 18))
    return scenario_from_table({
        "base": "bench_camera",
        "block": {"start_gps": now.strftime("%Y-%m-%dT%H:%M:%S"), "strips": 1,
                  "strip_length_m": 600.0, "flying_height_agl_m": 60.0},
        "flight": {"static_alignment_s": 10.0, "takeoff_acceleration_mps2": 5.0,
                   "figure_eights": 0, "run_in_s": 2.0, "airfield_offset_m": [0.0, -3000.0]},
        "scanner": {"line_period_ms": 32.0, "integration_time_ms": 4.0},
        "terrain": {"control_points": 0, "check_points": 0},
    })


def _wait_for(path: Path, proc: subprocess.Popen[bytes], timeout_s: float = 60.0) -> Any:
    deadline = time.monotonic() + timeout_s
    while not path.exists():
        assert proc.poll() is None, "sisa replay exited before it announced its ports"
        assert time.monotonic() < deadline, "sisa replay did not announce its ports"
        time.sleep(0.02)
    return json.loads(path.read_text())


def _finish(proc: subprocess.Popen[bytes], timeout_s: float) -> tuple[int, str]:
    try:
        out, _ = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return proc.returncode, (out or b"").decode()


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    """(original log, replayed-and-recorded log, replay's stdout, endpoints)."""
    tmp = tmp_path_factory.mktemp("camera_roundtrip")
    scn = _scenario()
    simulate(scn, tmp / "sim", images=False)
    (tmp / "scenario.toml").write_text(scenario_toml(scn), encoding="utf-8")
    original, again = tmp / "sim" / "flight.mcap", tmp / "again.mcap"
    replay = subprocess.Popen([*SISA, "replay", str(original), "--once", "--quiet",
                               "--rate", "2", "--endpoints", str(tmp / "ep.json")],
                              stdout=subprocess.PIPE)
    record: subprocess.Popen[bytes] | None = None
    try:
        ep = _wait_for(tmp / "ep.json", replay)
        record = subprocess.Popen([*SISA, "record", "--quiet", "--scenario",
                                   str(tmp / "scenario.toml"), "--gps", ep["gps"], "--scanner",
                                   ep["scanner"], "--ins", ep["ins"], "--pulses", ep["pulses"],
                                   "--camera", ep["camera"], "--give-up-after", "3",
                                   "--out", str(again)], stdout=subprocess.PIPE)
        replay_code, replay_out = _finish(replay, 150)
        record_code, record_out = _finish(record, 30)
    finally:
        for proc in (replay, record):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()
    assert replay_code == 0, replay_out
    assert record_code == 3, record_out  # every device away after the replay: gives up
    return original, again, replay_out, ep


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
