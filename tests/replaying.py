"""A simulated flight replayed by `sisa replay` into `sisa record`, both as separate processes on
ptys, SLCAN and the pulse link (test_replay_roundtrip.py, test_replay_camera.py).

The flight starts now (GPS time from the host clock): a receiver's first time tags come before
its first fix and wait for its date (docs/replay.md). It is replayed at x2 to stay under a
minute: its scanner runs at 32 ms lines with 4 ms exposures, so the header latency the sync unit
matches on (halved by the rate) stays inside its window with margin."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from emulators.scenario import scenario_from_table
from sisa.commands.scenario import scenario_toml
from sisa.core.timescale import datetime_from_gps_ns, gps_ns_from_unix_ns
from sisa.wiring.simulation import simulate

RATE = 2.0
SISA = [sys.executable, "-m", "sisa.cli"]


def short_scenario(base: str = "bench") -> Any:
    """One 600 m strip at 60 m, starting now."""
    now = datetime_from_gps_ns(gps_ns_from_unix_ns(time.time_ns(), 18))
    return scenario_from_table({
        "base": base,
        "block": {"start_gps": now.strftime("%Y-%m-%dT%H:%M:%S"), "strips": 1,
                  "strip_length_m": 600.0, "flying_height_agl_m": 60.0},
        "flight": {"static_alignment_s": 10.0, "takeoff_acceleration_mps2": 5.0,
                   "figure_eights": 0, "run_in_s": 2.0, "airfield_offset_m": [0.0, -3000.0]},
        "scanner": {"line_period_ms": 32.0, "integration_time_ms": 4.0},
        "terrain": {"control_points": 0, "check_points": 0},
    })


def wait_for(path: Path, proc: subprocess.Popen[bytes], timeout_s: float = 60.0) -> Any:
    """The endpoints file `proc` (a replay) writes, once it exists."""
    deadline = time.monotonic() + timeout_s
    while not path.exists():
        assert proc.poll() is None, "sisa replay exited before it announced its ports"
        assert time.monotonic() < deadline, "sisa replay did not announce its ports"
        time.sleep(0.02)
    return json.loads(path.read_text())


def finish(proc: subprocess.Popen[bytes], timeout_s: float) -> tuple[int, str]:
    """(exit code, stdout) of `proc`, killed after `timeout_s`."""
    try:
        out, _ = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return proc.returncode, (out or b"").decode()


def replay_and_record(tmp: Path, base: str = "bench") -> tuple[Path, Path, str, dict[str, str]]:
    """(original log, replayed-and-recorded log, replay's stdout, the replay's endpoints) of a
    short flight of `base` simulated without images; the recorder takes every port the replay
    opens (the camera's too, when the flight has one)."""
    scn = short_scenario(base)
    simulate(scn, tmp / "sim", images=False)
    (tmp / "scenario.toml").write_text(scenario_toml(scn), encoding="utf-8")
    original, again = tmp / "sim" / "flight.mcap", tmp / "again.mcap"
    replay = subprocess.Popen([*SISA, "replay", str(original), "--once", "--quiet",
                               "--rate", str(RATE), "--endpoints", str(tmp / "ep.json")],
                              stdout=subprocess.PIPE)
    record: subprocess.Popen[bytes] | None = None
    try:
        ep = wait_for(tmp / "ep.json", replay)
        ports = [arg for wire in ("gps", "scanner", "ins", "pulses", "camera") if wire in ep
                 for arg in (f"--{wire}", ep[wire])]
        record = subprocess.Popen([*SISA, "record", "--quiet", "--scenario",
                                   str(tmp / "scenario.toml"), *ports, "--give-up-after", "3",
                                   "--out", str(again)], stdout=subprocess.PIPE)
        replay_code, replay_out = finish(replay, 150)
        record_code, record_out = finish(record, 30)
    finally:
        for proc in (replay, record):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()
    assert replay_code == 0, replay_out
    # the replay over, its ports closed: every device away, the recorder gives up after 3 s
    # and says the recording ended on loss (exit 3; by default it would wait to be stopped)
    assert record_code == 3, record_out
    return original, again, replay_out, ep
