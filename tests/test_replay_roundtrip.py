"""`sisa replay` end to end: a simulated flight is replayed into virtual devices and recorded again
by `sisa record`, as separate processes on ptys, SLCAN and the pulse link; plus the keyboard and
the one-line refusals.

What "the same" means when the recorder's host clock differs: every host time (`t_host_ns`, the
log times) is the recorder's own and is ignored. Everything the devices said must be equal: the
raw bytes per stream, every decoded message, the pulse edges on the timing board. So must the
sync unit's log, except what depends on when the host looked: the instant a scanner-off switch was
noticed (a tick or the next pulse), which header the filter matched by host latency (the frame
counter itself must agree), the health windows. And the sync log
(`postproc.sync.pipeline.sync_log`) must
give every INS record and every line the same GPS time.

The flight and its replay: tests/replaying.py (flying now keeps the comparison exact whatever
the host clock says).
"""

from __future__ import annotations

import os
import re
import select
import subprocess
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from postproc.sync import TimeStatus, sync_log
from recorder.messages import FrameHeaderLog, PulseEdgeLog, RawBytes, StreamHealth, Topic
from recorder.reader import read_log, read_messages
from recorder.replay import Wire, iter_schedule
from recorder.writer import FlightRecorder
from sisa.cli import main
from sisa.core.timescale import NS_PER_S
from tests.replaying import SISA, finish, replay_and_record, wait_for

HOST_DEPENDENT = {"t_host_ns", "timestamp"}  # LocationFix.timestamp is the fix's host time


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    """(original log, replayed-and-recorded log, replay's stdout)."""
    original, again, out, _ = replay_and_record(tmp_path_factory.mktemp("roundtrip"))
    return original, again, out


# --- raw streams ----------------------------------------------------------------------------------

def _streams(path: Path) -> dict[Wire, Any]:
    out: dict[Wire, list[Any]] = {w: [] for w in Wire}
    for item in iter_schedule(path):
        out[item.wire].append(item.payload)
    return {Wire.GPS: b"".join(out[Wire.GPS]), Wire.SCANNER: b"".join(out[Wire.SCANNER]),
            Wire.INS: out[Wire.INS], Wire.PULSES: out[Wire.PULSES],
            Wire.CAMERA: b"".join(out[Wire.CAMERA])}  # none here: test_replay_camera.py


def test_raw_streams_are_byte_identical(flights):
    original, again, _ = flights
    before, after = _streams(original), _streams(again)
    assert len(before[Wire.GPS]) > 15_000
    assert len(before[Wire.INS]) > 30_000
    for wire in Wire:
        assert after[wire] == before[wire], f"{wire} differs"


# --- decoded messages -----------------------------------------------------------------------------

def _messages(path: Path) -> dict[str, list[dict[str, Any]]]:
    out: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for topic, _t, fields in read_log(path):
        out[topic].append({k: v for k, v in fields.items() if k not in HOST_DEPENDENT})
    return out


DEVICE_TOPICS = (Topic.GPS_FIX, Topic.GPS_LOCATION, Topic.GPS_TIME_TAG, Topic.INS_RECORD,
                 Topic.SCANNER_HEADER, Topic.PULSE_IN, Topic.PULSE_OUT, Topic.SYNC_SESSION,
                 Topic.SYNC_PPS)


def test_decoded_messages_are_the_same_but_for_host_times(flights):
    original, again, _ = flights
    before, after = _messages(original), _messages(again)
    for topic in DEVICE_TOPICS:
        assert before[topic], f"the original has no {topic}"
        assert after[topic] == before[topic], f"{topic} differs"


def test_sync_unit_forwarded_the_same_pulses_with_the_same_frame_counters(flights):
    original, again, _ = flights
    before, after = _messages(original)[Topic.SYNC_FORWARD], _messages(again)[Topic.SYNC_FORWARD]
    assert sum(f["mode"] == 2 for f in before) >= 5
    matched_by_host_time = "frame_counter_source"
    strip = [{k: v for k, v in f.items() if k != matched_by_host_time} for f in before]
    assert [{k: v for k, v in f.items() if k != matched_by_host_time} for f in after] == strip
    known = [f[matched_by_host_time] != "unknown" for f in before]
    assert [f[matched_by_host_time] != "unknown" for f in after] == known


def test_mode_switches_agree_but_for_when_scanner_off_was_noticed(flights):
    original, again, _ = flights
    before, after = _messages(original)[Topic.SYNC_MODE], _messages(again)[Topic.SYNC_MODE]
    assert [(m["from_mode"], m["to_mode"]) for m in before] == [(1, 2), (2, 1)]
    assert [(m["session"], m["from_mode"], m["to_mode"]) for m in after] == \
        [(m["session"], m["from_mode"], m["to_mode"]) for m in before]
    assert after[0] == before[0]  # scanner on: at a ppf, on the board counter
    assert abs(after[1]["board_ns"] - before[1]["board_ns"]) < NS_PER_S  # a tick or a pulse


def test_every_stream_counts_the_same_messages_and_no_errors(flights):
    original, again, _ = flights

    def final(path: Path) -> dict[str, tuple[int, ...]]:
        # the periodic reports; link events (the player's ports closing at the end) are not
        # part of what was recorded
        last = {h.stream: h for h in read_messages(path, StreamHealth) if not h.event}
        return {s: (h.messages, h.checksum_errors, h.framing_errors, h.bytes_skipped, h.drops)
                for s, h in last.items()}

    before = final(original)
    assert before["ins"][0] > 5000
    assert before["scanner"][0] > 300
    assert final(again) == before


# --- post-processing ------------------------------------------------------------------------------

def test_sync_log_gives_every_record_and_line_the_same_gps_time(flights):
    original, again, _ = flights
    a, b = sync_log(original), sync_log(again)
    assert a.ins.t_gps_ns.size > 5000
    assert a.lines.t_gps_ns.size > 300
    # every INS record timed but those before the first latched pulse and after the last
    # (no pulse can time them: docs/sync.md, Limits), and every line
    beyond = a.ins_solution.timeline.outside_latch_span()
    assert np.all(a.ins.status[~beyond] == 0)
    assert beyond.sum() < 5 * 64
    assert np.all(a.ins.status[beyond] == TimeStatus.OUTSIDE_FIT)
    assert np.all(a.lines.status == 0)
    for name in ("seq", "counter", "t_gps_ns", "status"):
        _same(getattr(b.ins, name), getattr(a.ins, name), f"INS {name}")
    for name in ("segment", "line", "frame_counter", "t_gps_ns", "status"):
        _same(getattr(b.lines, name), getattr(a.lines, name), f"line {name}")


def _same(got: np.ndarray, want: np.ndarray, what: str) -> None:
    assert got.shape == want.shape, f"{what}: {got.size} values, not {want.size}"
    wrong = np.flatnonzero(got != want)
    assert wrong.size == 0, (f"{what}: {wrong.size} of {want.size} differ, the first at index "
                             f"{wrong[0]}: {got[wrong[0]]} instead of {want[wrong[0]]}")


def test_replay_received_every_pulse_the_sync_unit_sent(flights):
    original, _, out = flights
    sent = len(_messages(original)[Topic.PULSE_OUT])
    summary = out.strip().splitlines()[-1]
    assert summary.startswith("replay done:")
    assert re.search(rf"\b{sent} pulses from the sync unit", summary), summary
    assert "dropped: pty bytes 0, CAN frames 0, edges 0" in summary


# --- keyboard -------------------------------------------------------------------------------------

def _chunks_flight(path: Path, n: int, period_ns: int) -> Path:
    t0 = 1_700_000_000 * NS_PER_S
    with FlightRecorder(path) as rec:
        for k in range(n):
            rec.write(RawBytes(t0 + k * period_ns, "gps", b"%02d\n" % k), Topic.GPS_RAW)
        rec.write(FrameHeaderLog(t0, 1, 12_000, 1, 0, 4))
    return path


def test_space_pauses_and_resumes_and_q_stops(tmp_path):
    flight = _chunks_flight(tmp_path / "kb.mcap", 20, NS_PER_S // 10)
    master, slave = os.openpty()
    proc = subprocess.Popen([*SISA, "replay", str(flight), "--no-wait", "--quiet",
                             "--endpoints", str(tmp_path / "ep.json")],
                            stdin=slave, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    os.close(slave)
    try:
        gps = os.open(wait_for(tmp_path / "ep.json", proc)["gps"], os.O_RDONLY | os.O_NOCTTY)
        arrivals: list[tuple[float, bytes]] = []

        def read_for(seconds: float) -> None:
            end = time.monotonic() + seconds
            while (left := end - time.monotonic()) > 0:
                if select.select([gps], [], [], left)[0]:
                    arrivals.append((time.monotonic(), os.read(gps, 4096)))

        read_for(0.55)
        assert arrivals, "nothing played"
        os.write(master, b" ")
        paused_at = time.monotonic()
        read_for(1.0)
        during = [d for t, d in arrivals if paused_at + 0.15 < t]
        os.write(master, b" ")
        read_for(2.2)
        os.write(master, b"q")
        code, out = finish(proc, 20)
        os.close(gps)
    finally:
        proc.kill()
        os.close(master)
    assert during == []
    assert b"".join(d for _, d in arrivals) == b"".join(b"%02d\n" % k for k in range(20))
    assert arrivals[-1][0] - arrivals[0][0] > 1.9 + 0.8  # 1.9 s of log and the pause
    assert code == 0
    assert "replay stopped" in out
    assert "end of the recording" in out


# --- refusals -------------------------------------------------------------------------------------

@pytest.mark.parametrize(("args", "message"), [
    (["missing.mcap"], "no such file"),
    (["notmcap.mcap"], "not an MCAP file"),
    (["kb.mcap", "--rate", "0"], "--rate 0: at least 0.001"),
    (["kb.mcap", "--rate", "nan"], "--rate nan: must be a finite number"),
    (["kb.mcap", "--start", "30"], "beyond the end of the log"),
    (["noraw.mcap"], "no raw channel to replay"),
])
def test_bad_input_is_one_line_exit_2_and_writes_nothing(tmp_path, capsys, monkeypatch, args,
                                                         message):
    monkeypatch.chdir(tmp_path)
    _chunks_flight(tmp_path / "kb.mcap", 5, NS_PER_S // 10)
    (tmp_path / "notmcap.mcap").write_bytes(b"hello")
    with FlightRecorder(tmp_path / "noraw.mcap") as rec:
        rec.write(FrameHeaderLog(1, 1, 12_000, 1, 0, 4))
    code = main(["replay", *args, "--once", "--endpoints", "ep.json"])
    err = capsys.readouterr().err
    assert code == 2
    assert message in err
    assert err.count("\n") == 1, err
    assert not (tmp_path / "ep.json").exists()


def test_once_and_loop_exclude_each_other(tmp_path):
    with pytest.raises(SystemExit) as exc:
        main(["replay", str(tmp_path / "x.mcap"), "--once", "--loop"])
    assert exc.value.code == 2


# --- when piped -----------------------------------------------------------------------------------

def _stderr_line(proc: subprocess.Popen[str], wanted: str, timeout_s: float) -> str:
    """The first line of the child's stderr holding `wanted`, read as the child writes it."""
    assert proc.stderr is not None
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if select.select([proc.stderr], [], [], 0.1)[0]:
            line = proc.stderr.readline()
            assert line, f"stderr closed before {wanted!r}"
            if wanted in line:
                return line
    raise AssertionError(f"no {wanted!r} on stderr in {timeout_s} s")


def test_a_piped_replay_says_it_waits_and_shows_progress_while_it_plays(tmp_path):
    """`sisa replay … | cat` waited for a client without a word (the "waiting for clients" line
    was on a terminal only) and showed no progress (issue 33, item 1)."""
    import socket

    flight = tmp_path / "piped.mcap"
    t0 = 1_700_000_000 * NS_PER_S
    with FlightRecorder(flight) as rec:
        for k in range(40):
            rec.write(RawBytes(t0 + k * NS_PER_S // 10, "gps", b"%02d\n" % k), Topic.GPS_RAW)
        rec.write(PulseEdgeLog(t0 + NS_PER_S, "PPS", NS_PER_S, 0), Topic.PULSE_IN)
    proc = subprocess.Popen([*SISA, "replay", str(flight), "--once", "--endpoints",
                             str(tmp_path / "ep.json")], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "SISA_PROGRESS_S": "0.3"})
    try:
        ep = wait_for(tmp_path / "ep.json", proc)  # type: ignore[arg-type]
        said = _stderr_line(proc, "waiting for a client", 20)
        assert said == (f"sisa replay: waiting for a client on the pulse link {ep['pulses']} "
                        "before playing (--no-wait starts at once)\n")
        assert proc.poll() is None
        host, port = ep["pulses"].removeprefix("tcp://").rsplit(":", 1)
        with socket.create_connection((host, int(port))):
            line = _stderr_line(proc, "sisa replay: playing", 20)
            assert proc.poll() is None  # said while it plays, not at the end
            assert re.fullmatch(r"\d\d:\d\d:\d\d sisa replay: playing [\d.]+/3\.9 s \(\d+%\).*\n",
                                line), line
            out, _ = proc.communicate(timeout=30)
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == 0
    assert out.strip().splitlines()[-1].startswith("replay done:")


def test_topics_plays_a_subset_of_the_wires(tmp_path):
    """`sisa replay --topics` plays only the wires named (issue 33, item 11); the others' ports
    stay silent, and no client is waited for on them."""
    flight = tmp_path / "two.mcap"
    t0 = 1_700_000_000 * NS_PER_S
    with FlightRecorder(flight) as rec:
        for k in range(5):
            rec.write(RawBytes(t0 + k * NS_PER_S // 10, "gps", b"%02d\n" % k), Topic.GPS_RAW)
        rec.write(PulseEdgeLog(t0 + NS_PER_S // 5, "PPS", NS_PER_S, 0), Topic.PULSE_IN)
    played = {}
    for topics in ("gps", "/gps/raw"):
        done = subprocess.run([*SISA, "replay", str(flight), "--once", "--topics", topics],
                              capture_output=True, text=True, timeout=60)
        assert done.returncode == 0, done.stderr
        assert "(gps only)" in done.stdout
        played[topics] = done.stdout.strip().splitlines()[-1]
        assert "waiting for a client" not in done.stderr  # the pulse link is not played
    for summary in played.values():
        assert "5 items in 1 pass(es): GPS 15 B, scanner 0 B, CAN 0 frames, 0 edges;" in summary


@pytest.mark.parametrize(("topics", "says"), [
    ("radar", "--topics: radar: not a wire of the replay; choose from gps (/gps/raw), "),
    ("scanner", "--topics scanner: the log holds no scanner to play (it holds gps, pulses)"),
])
def test_topics_that_name_nothing_to_play_are_one_line(tmp_path, capsys, topics, says):
    flight = tmp_path / "two.mcap"
    with FlightRecorder(flight) as rec:
        rec.write(RawBytes(1_700_000_000 * NS_PER_S, "gps", b"x\n"), Topic.GPS_RAW)
        rec.write(PulseEdgeLog(1_700_000_000 * NS_PER_S, "PPS", NS_PER_S, 0), Topic.PULSE_IN)
    assert main(["replay", str(flight), "--once", "--topics", topics]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"sisa replay: error: {says}"), err
    assert err.count("\n") == 1
