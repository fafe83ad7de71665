"""`sisa bench --live`: an independent client (tests/live/js, @foxglove/ws-protocol) gets every
channel with messages that hold to their schemas, while a client that never reads and another
that sends garbage leave the recording whole; the incremental sync's last pass equals `sisa
sync` on the finished file, and times what it times within 30 s of its logging."""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import foxglove
import numpy as np
import pytest
from pyproj import Geod

from emulators.scenario import load_scenario
from emulators.truth import read_truth_csv
from postproc.sync import TimeStatus, sync_input_from_columns, sync_log, synchronise
from recorder.columns import read_columns, read_topics
from recorder.messages import Topic
from recorder.reader import scan_log
from recorder.writer import TOPIC_TYPES
from sisa.core.errors import InputError
from sisa.wiring.live import (
    CAMERA_TOPICS,
    LIVE_HEALTH_SCHEMA,
    LIVE_SYNC_SCHEMA,
    SERVER_NICENESS,
    LiveView,
    layout_json,
    listen_address,
    planned_strips,
)
from sisa.wiring.livesync import LIVE_WANTED, footprint
from sisa.wiring.livesync import crew_warnings as livesync_warnings
from tests.live import RawClient

JS_DIR = Path(__file__).resolve().parent / "js"
LIVE_TOPICS = {"/live/sync", "/live/health", "/live/position", "/live/map/strips",
               "/live/map/footprint"}
DURATION_S = 45  # from 35 s before strip 0: the scanner records its last 10 s


@pytest.fixture(scope="session")
def live_client() -> list[str]:
    """`node live_client.mjs`, its packages installed by `npm ci` from the committed lock."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        pytest.fail("node and npm are needed for the independent Foxglove client (Node >= 18)")
    lock = Path(tempfile.gettempdir()) / (
        "sisa-npm-" + hashlib.sha1(str(JS_DIR).encode()).hexdigest()[:12] + ".lock")
    with lock.open("w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)  # pytest-xdist workers install once, not at once
        if not (JS_DIR / "node_modules" / "@foxglove" / "ws-protocol").is_dir():
            proc = subprocess.run([npm, "ci", "--no-audit", "--no-fund"], cwd=JS_DIR,
                                  capture_output=True, text=True, check=False)
            if proc.returncode != 0:
                pytest.fail(f"`npm ci` in {JS_DIR} failed: {proc.stderr.strip()[-1500:]}")
    return [node, str(JS_DIR / "live_client.mjs")]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _connected(port: int, until: float) -> RawClient:
    while True:
        try:
            client = RawClient(port, receive_buffer=4096)
            client.handshake()
            return client
        except OSError:
            if time.monotonic() > until:
                raise
            time.sleep(0.1)


class _Misbehaving:
    """From the moment the server is up: one client subscribed to every channel that never
    reads a byte, and rounds of garbage (bytes instead of a handshake; after one, broken JSON,
    unknown operations, subscriptions to nothing, random binary, a frame claiming 1 TB)."""

    def __init__(self, port: int) -> None:
        self.port = port
        self.stop = threading.Event()
        self.subscribed = 0
        self.rounds = 0
        self.problem = ""
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            stalled = _connected(self.port, time.monotonic() + 120)
            self.subscribed = stalled.subscribe_all()
        except OSError as exc:
            self.problem = repr(exc)
            return
        rng = np.random.default_rng(3)
        while not self.stop.wait(0.3):
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=2) as s:
                    s.sendall(rng.bytes(512))
                c = RawClient(self.port, timeout_s=2)
                c.handshake()
                for payload in (b"{not json", b'{"op":"explode"}', rng.bytes(300),
                                b'{"op":"subscribe","subscriptions":[{"id":1,"channelId":9e9}]}'):
                    c.send_frame(payload)
                c.send_frame(rng.bytes(64), opcode=2)
                c.send_frame(b"x", declared=2**40)
                c.close()
                self.rounds += 1
            except OSError:
                continue  # the server closing on us is its right
        stalled.close()


@pytest.fixture(scope="module")
def live_run(tmp_path_factory: pytest.TempPathFactory, live_client: list[str],
             worker_id: str) -> dict[str, Any]:
    """One real-time `sisa bench --live` for the session, whichever xdist worker asks first
    (a module fixture runs once per worker: two real-time runs at once on two cores)."""
    shared = tmp_path_factory.getbasetemp()
    if worker_id != "master":  # the workers' temp folders share this session's parent
        shared = shared.parent
    with (shared / "live_run.lock").open("w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        done = shared / "live_run.json"
        if not done.exists():
            done.write_text(json.dumps(_live_run(shared / "live", live_client)))
    result: dict[str, Any] = json.loads(done.read_text())
    return {**result, "run": Path(result["run"]), "offline": Path(result["offline"])}


def _live_run(tmp: Path, live_client: list[str]) -> dict[str, Any]:
    run, port = tmp / "run", _free_port()
    bench = subprocess.Popen(
        [sys.executable, "-m", "sisa.cli", "bench", "--preset", "bench", "--out", str(run),
         "--strip", "0", "--duration", str(DURATION_S), "--no-images", "--live", str(port)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    client = subprocess.Popen([*live_client, f"ws://127.0.0.1:{port}", "240"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    bad = _Misbehaving(port)
    try:
        out, err = bench.communicate(timeout=300)
        summary, client_err = client.communicate(timeout=60)
    finally:
        bad.stop.set()
        bench.kill()
        client.kill()
    bad.thread.join(timeout=10)
    assert bench.returncode == 0, err
    assert client.returncode == 0, client_err
    offline = tmp / "sync"
    done = subprocess.run([sys.executable, "-m", "sisa.cli", "sync", str(run / "flight.mcap"),
                           "--out", str(offline)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return {"run": str(run), "stdout": out, "stderr": err, "client": json.loads(summary),
            "misbehaving": {"problem": bad.problem, "subscribed": bad.subscribed,
                            "rounds": bad.rounds}, "offline": str(offline)}


def test_an_independent_client_gets_every_channel_and_every_message_holds_to_its_schema(
        live_run: dict[str, Any]) -> None:
    client = live_run["client"]
    assert client["connected"], client
    assert client["subprotocol"] == "foxglove.sdk.v1"
    assert client["errors"] == []
    # the bench preset flies no frame camera: its channels are not advertised
    logged = {str(t) for t in TOPIC_TYPES} - CAMERA_TOPICS | {str(Topic.GPS_LOCATION)}
    assert set(client["channels"]) == logged | LIVE_TOPICS
    for topic, channel in client["channels"].items():
        assert channel["received"] > 0, topic
        assert channel["invalid"] == 0, (topic, channel["firstProblem"])
    assert client["channels"]["/live/position"]["schemaName"] == "foxglove.LocationFix"
    assert client["channels"]["/live/map/footprint"]["schemaName"] == "foxglove.GeoJSON"
    # reading from its first message on: every message the recorder wrote since, none dropped
    # (it connects as the server starts; the very first may come before it is subscribed)
    for topic, count in _logged_since(live_run["run"] / "flight.mcap", client).items():
        assert client["channels"][topic]["received"] == count, topic


def _logged_since(flight: Path, client: dict[str, Any]) -> dict[str, int]:
    """Per logged topic, its messages in the file from the client's first one on."""
    out = {}
    for topic in scan_log(flight).topics:
        times = read_columns(flight, topic)["log_time_ns"]
        first = int(client["channels"][topic]["firstLogTime"])
        out[topic] = int(np.count_nonzero(times >= first))
        assert out[topic] >= times.size - 2, topic  # it missed at most the very first
    return out


def test_a_client_that_never_reads_and_one_that_sends_garbage_leave_the_recording_whole(
        live_run: dict[str, Any]) -> None:
    bad = live_run["misbehaving"]
    assert bad["problem"] == ""
    assert bad["subscribed"] == len(live_run["client"]["channels"])
    assert bad["rounds"] >= 20  # garbage the whole run long
    out, run = live_run["stdout"], live_run["run"]
    assert "0 decode errors, 0 drops" in out, out
    assert "0 disconnects, 0 reconnects" in out, out
    # a late edge is the recorder's only if the emulator kept to its schedule (sisa bench says
    # which side made it late: a loaded desk machine is not the recorder)
    assert " 0 late edges" in out or "not the recorder's doing" in live_run["stderr"], out
    # nor did the garbage reach the crew's terminal (the SDK's records of it stay in the SDK)
    for said in ("handshake failed", "Invalid message from", "Error receiving from client"):
        assert said not in live_run["stderr"], live_run["stderr"][-2000:]
    ins = read_columns(run / "flight.mcap", Topic.INS_RECORD)["ins_time_ticks"]
    sent = read_truth_csv(run / "truth" / "ins_records.csv")["ins_time_ticks"]
    assert len(ins) >= DURATION_S * 64 - 2
    np.testing.assert_array_equal(ins, sent[-len(ins):])  # every INS record, none lost
    headers = read_columns(run / "flight.mcap", Topic.SCANNER_HEADER)["frame_counter"]
    frames = read_truth_csv(run / "truth" / "frames.csv")
    assert headers.size == len(frames["frame_counter"]) > 500  # every frame header
    np.testing.assert_array_equal(headers, frames["frame_counter"])


def test_the_live_sync_ends_equal_to_sisa_sync_and_timed_each_record_within_30_s(
        live_run: dict[str, Any]) -> None:
    run, offline = live_run["run"], live_run["offline"]
    for table in ("ins_times.csv", "line_times.csv"):
        assert (run / "live_sync" / table).read_bytes() == (offline / table).read_bytes()
    res = sync_log(run / "flight.mcap")
    first = np.load(run / "live_sync" / "first_timed.npz")
    for key, times in (("ins", res.ins), ("line", res.lines)):
        ok = times.status == TimeStatus.OK
        # this flight times whole: but the INS records before its first latched pulse and
        # after its last, which no pulse can time (docs/sync.md, Limits)
        whole = (~res.ins_solution.timeline.outside_latch_span() if key == "ins"
                 else np.ones(ok.size, np.bool_))
        assert np.array_equal(ok, whole)
        assert ok.sum() > 500
        wall, logged = first[f"{key}_wall_ns"], first[f"{key}_log_time_ns"]
        timed = wall >= 0
        assert not np.any(timed & ~ok)  # nothing the offline sync leaves untimed
        within = timed & (wall - logged <= 30 * 10**9)
        assert within.sum() >= 0.99 * ok.sum(), (key, within.sum(), ok.sum())
        # in flight the fits had fewer pulses: a time first given may move, far under 1 µs
        gap = np.abs(first[f"{key}_t_gps_ns"][timed] - times.t_gps_ns[timed])
        assert gap.max() < 1_000, (key, gap.max())


def test_the_client_finds_a_message_that_breaks_its_schema(live_client: list[str]) -> None:
    """The check above can fail: a server of our own with one good and one bad message on a
    JSON channel, and bytes that are no protobuf on a typed one."""
    ctx = foxglove.Context()
    server = foxglove.start_server(host="127.0.0.1", port=0, context=ctx)
    try:
        ch = foxglove.Channel("/t", context=ctx, schema={
            "type": "object", "properties": {"x": {"type": "integer"}}, "required": ["x"]})
        geo = foxglove.channels.GeoJsonChannel("/geo", context=ctx)
        client = subprocess.Popen([*live_client, f"ws://127.0.0.1:{server.port}", "6"],
                                  stdout=subprocess.PIPE, text=True)
        time.sleep(2.5)  # connected and subscribed
        ch.log({"x": 1})
        ch.log({"x": "one"})
        geo.log(foxglove.messages.GeoJson(geojson='{"type": "Point"}'))
        summary = json.loads(client.communicate(timeout=30)[0])
    finally:
        server.stop()
    assert summary["channels"]["/t"]["received"] == 2
    assert summary["channels"]["/t"]["invalid"] == 1
    assert "integer" in summary["channels"]["/t"]["firstProblem"]
    assert summary["channels"]["/geo"]["invalid"] == 1  # not a FeatureCollection


@pytest.mark.parametrize(("text", "expected"), [
    ("8765", ("127.0.0.1", 8765)), ("0.0.0.0:9000", ("0.0.0.0", 9000)),
    ("[::1]:9001", ("::1", 9001)), (":7000", ("127.0.0.1", 7000))])
def test_live_addresses(text: str, expected: tuple[str, int]) -> None:
    assert listen_address(text) == expected


@pytest.mark.parametrize("text", ["", "host:", "99999", "x:-1", "port", "1:2:abc"])
def test_a_bad_live_address_is_refused(text: str) -> None:
    with pytest.raises(InputError, match="--live"):
        listen_address(text)


def test_a_bad_live_address_is_one_line_and_exit_2_before_anything_starts(tmp_path: Path
                                                                          ) -> None:
    done = subprocess.run([sys.executable, "-m", "sisa.cli", "record", "--pulses",
                           "tcp://127.0.0.1:1", "--out", str(tmp_path / "f.mcap"), "--live",
                           "localhost:http"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "--live localhost:http" in done.stderr
    assert not (tmp_path / "f.mcap").exists()


def _doctored(flight: Path, change: Callable[[dict[str, dict[str, Any]]], None]
              ) -> list[str]:
    cols = read_topics(flight, LIVE_WANTED)
    change(cols)
    # a record untimed 20 s after its logging is a warning here (45 s in flight): the run
    # lasts 45 s
    return livesync_warnings(cols, synchronise(sync_input_from_columns(cols)), stale_s=20.0)


def test_the_warnings_say_what_to_check(live_run: dict[str, Any]) -> None:
    flight = live_run["run"] / "flight.mcap"
    assert _doctored(flight, lambda cols: None) == []  # a clean flight: nothing to act on

    def no_ttt(cols: dict[str, dict[str, Any]]) -> None:
        tags = cols[Topic.GPS_TIME_TAG]
        keep = tags["kind"] != "TTT"
        cols[Topic.GPS_TIME_TAG] = {k: v[keep] for k, v in tags.items()}

    assert any(w.startswith("tags not arriving") for w in _doctored(flight, no_ttt))

    def no_latch(cols: dict[str, dict[str, Any]]) -> None:
        cols[Topic.INS_RECORD]["sync_flag"] = np.zeros_like(cols[Topic.INS_RECORD]["sync_flag"])

    said = _doctored(flight, no_latch)
    assert any("the INS latched no sync pulse" in w for w in said), said

    def scrambled(cols: dict[str, dict[str, Any]]) -> None:  # latches at random records
        ins = cols[Topic.INS_RECORD]
        flags = np.random.default_rng(5).permutation(ins["sync_flag"])
        ins["sync_flag"] = flags
        ins["sync_time_ticks"] = np.where(flags, ins["ins_time_ticks"], ins["sync_time_ticks"])

    said = _doctored(flight, scrambled)
    assert any(w.startswith("pattern not matching") for w in said), said

    def untied(cols: dict[str, dict[str, Any]]) -> None:
        fwd = cols[Topic.SYNC_FORWARD]
        fwd["frame_counter"] = np.full_like(fwd["frame_counter"], -1)

    said = _doctored(flight, untied)
    assert any(w.startswith("scanner headers without pulses") for w in said), said


def test_the_footprint_is_the_planned_swath_wide_along_the_track(live_run: dict[str, Any]
                                                                 ) -> None:
    flight = live_run["run"] / "flight.mcap"
    cols = read_topics(flight, LIVE_WANTED)
    res = synchronise(sync_input_from_columns(cols))
    _, half = planned_strips(load_scenario("bench"))
    features = footprint(cols, res, half)
    assert len(features) == 1  # one strip, all of it timed
    assert features[0]["properties"]["timed"]
    ring = np.array(features[0]["geometry"]["coordinates"][0])
    n = (len(ring) - 1) // 2  # right edge forward, left edge back, closed
    geod = Geod(ellps="WGS84")
    for i in (0, n // 2, n - 1):
        _, _, width = geod.inv(ring[i, 0], ring[i, 1], ring[2 * n - 1 - i, 0],
                               ring[2 * n - 1 - i, 1])
        assert abs(width - 2 * half) < 0.01 * 2 * half, (i, width, 2 * half)


def test_the_layout_file_is_the_generated_one_on_the_served_fields() -> None:
    text = (Path(__file__).resolve().parents[2] / "docs" / "live-layout.json").read_text()
    assert text == layout_json()
    panels: list[dict[str, Any]] = []

    def walk(node: dict[str, Any]) -> None:
        if node.get("type") == "panel":
            panels.append(node)
        for item in node.get("items", []):
            walk(item["content"])

    walk(json.loads(text)["content"])
    assert {p["panelType"] for p in panels} >= {"Map", "StateTransitions", "Plot", "Indicator",
                                                 "RawMessages"}
    fields = {"/live/sync": LIVE_SYNC_SCHEMA["properties"],
              "/live/health": LIVE_HEALTH_SCHEMA["properties"]}
    for path in re.findall(r'"(/live/[a-z/]+(?:\.[a-z_]+)?)"', text):
        topic, _, name = path.partition(".")
        assert topic in LIVE_TOPICS, path
        assert not name or name in fields[topic], path


def test_the_crew_is_told_when_the_incremental_sync_has_stopped(tmp_path: Path) -> None:
    view = LiveView("127.0.0.1", 0, tmp_path / "flight.mcap")
    try:
        assert view.sync_state(time.time_ns())["warnings"] == []
        view._proc.kill()  # as if it had crashed
        view._proc.wait()
        said = view.sync_state(time.time_ns())["warnings"]
        assert len(said) == 1
        assert said[0].startswith("incremental sync stopped (exit -9)")
        assert view.health(time.time_ns())["log_bytes"] == 0  # no log yet: nothing, no error
    finally:
        view.close()


SERVER_PROBE = """
import json, logging, os, socket, sys, time
from pathlib import Path
import foxglove
from sisa.wiring.live import start_server
from tests.live import RawClient

def threads():
    out = {}
    for task in Path("/proc/self/task").iterdir():
        stat = (task / "stat").read_text()
        out[int(task.name)] = int(stat.rsplit(")", 1)[1].split()[16])  # nice
    return out

caught = []
class Catch(logging.Handler):
    def emit(self, record):
        caught.append(record.getMessage())
logging.getLogger("foxglove").addHandler(Catch())
before = threads()
server = start_server("127.0.0.1", 0, foxglove.Context())
after = threads()
for _ in range(3):  # what no client should send: each one a record of the SDK's
    with socket.create_connection(("127.0.0.1", server.port), timeout=2) as s:
        s.sendall(os.urandom(256))
    c = RawClient(server.port, timeout_s=2)
    c.handshake()
    c.send_frame(b"{not json")
    c.send_frame(b'{"op":"explode"}')
    c.close()
time.sleep(1.0)
server.stop()
print(json.dumps({"main": os.getpriority(os.PRIO_PROCESS, 0),
                  "server": [after[t] for t in after if t not in before], "caught": caught}))
"""


def test_the_servers_threads_give_way_to_the_recorder_and_its_records_stay_in_the_sdk(
        ) -> None:
    """foxglove-sdk's server threads run below the recorder's loop (a flood of connections
    costs them a quarter of a core: docs/live.md), the loop's own thread keeps its priority,
    and a bad client's frames make no Python log record (each took the interpreter lock in a
    server thread and printed a line on the crew's terminal). In a process of its own: the
    SDK's log bridge caches a logger's level at its first record."""
    done = subprocess.run([sys.executable, "-c", SERVER_PROBE], capture_output=True,
                          text=True, timeout=60, cwd=Path(__file__).resolve().parents[2])
    assert done.returncode == 0, done.stderr
    said = json.loads(done.stdout)
    assert said["main"] == 0
    assert said["server"], said
    assert all(nice >= SERVER_NICENESS for nice in said["server"]), said
    assert said["caught"] == []
    assert done.stderr == ""


def test_a_port_in_use_is_one_line_and_exit_2_before_anything_is_recorded(tmp_path: Path
                                                                          ) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        done = subprocess.run([sys.executable, "-m", "sisa.cli", "record", "--pulses",
                               "tcp://127.0.0.1:1", "--out", str(tmp_path / "f.mcap"),
                               "--live", str(port)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [
        f"sisa record: error: --live 127.0.0.1:{port}: cannot serve: FoxgloveError: Failed to "
        "bind port: Address already in use (os error 98)"]
    assert not (tmp_path / "f.mcap").exists()


def test_replay_live_serves_a_recorded_flight_as_the_crew_saw_it(
        live_run: dict[str, Any], live_client: list[str], tmp_path: Path) -> None:
    """`sisa replay --live`: desk review of a recorded flight through the same recorder, live
    server and incremental sync; the independent client gets every channel, every message
    holding to its schema, and the scratch recording is gone at the end."""
    flight, port = live_run["run"] / "flight.mcap", _free_port()
    replay = subprocess.Popen(
        [sys.executable, "-m", "sisa.cli", "replay", str(flight), "--once", "--rate", "2",
         "--live", str(port), "--preset", "bench"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "TMPDIR": str(tmp_path)})
    client = subprocess.Popen([*live_client, f"ws://127.0.0.1:{port}", "240"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        out, err = replay.communicate(timeout=300)
        summary, client_err = client.communicate(timeout=60)
    finally:
        replay.kill()
        client.kill()
    assert replay.returncode == 0, err
    assert client.returncode == 0, client_err
    assert f"live view on ws://127.0.0.1:{port}" in err, err
    assert "replay done" in out, out
    seen = json.loads(summary)
    assert seen["errors"] == []
    logged = {str(t) for t in scan_log(flight).topics}
    assert logged | LIVE_TOPICS <= set(seen["channels"])
    for topic in logged | LIVE_TOPICS:
        channel = seen["channels"][topic]
        assert channel["received"] > 0, topic
        assert channel["invalid"] == 0, (topic, channel["firstProblem"])
    # the flight played again: its INS records and frame headers recorded and served again
    for topic in (Topic.INS_RECORD, Topic.SCANNER_HEADER):
        recorded = read_columns(flight, topic)["log_time_ns"].size
        assert seen["channels"][str(topic)]["received"] >= recorded - 2, topic
    assert not list(tmp_path.iterdir())  # the scratch recording went with the replay


def test_replay_live_on_a_port_in_use_ends_in_one_line_and_exit_2(
        live_run: dict[str, Any], tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        done = subprocess.run(
            [sys.executable, "-m", "sisa.cli", "replay", str(live_run["run"] / "flight.mcap"),
             "--once", "--live", str(port)], capture_output=True, text=True, timeout=120,
            env={**os.environ, "TMPDIR": str(tmp_path)})
    assert done.returncode == 2, done.stderr
    assert done.stderr.endswith("sisa replay: error: --live: sisa record ended (exit 2) before "
                                "the replay did\n"), done.stderr
    assert not list(tmp_path.iterdir())
