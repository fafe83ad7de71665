"""The live view's cost and the incremental sync's agreement, in one real-time desk run.

`sisa bench --live` on the bench scenario with a strip long enough for three 30 s windows in
mode 2 (scanner recording): the recorder's CPU (its process: acquisition, writing, the tap and
the foxglove-sdk server's threads) and the incremental sync's (its own process) are counted
from /proc over each window, as bench/acquisition_headroom.py counts the recorder's:

    A  no client connected
    B  a client subscribed to every channel and reading (tests/live/js/live_client.mjs,
       @foxglove/ws-protocol, checking every message against its schema)
    C  a client subscribed to everything that never reads, and another sending garbage

Then the incremental sync's last tables are compared with `sisa sync` on the finished file,
row by row, and each row's first live time with the offline one; and how long after it was
logged each record was first timed. With --baseline, the same run without --live first (the
recorder as it was, window A only), for the same hour's figure.

    .venv/bin/python bench/live_view.py [--baseline] [--keep DIR]
    .venv/bin/python bench/live_view.py --pass-cost FLIGHT.mcap   (a pass's CPU on a long log)
    .venv/bin/python bench/live_view.py --late RUN [RUN ...]   (late edges by window of kept runs)
    .venv/bin/python bench/live_view.py --server-cost SECONDS  (the server alone, under a flood)
"""

from __future__ import annotations

import argparse
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
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from emulators.scenario import load_scenario
from postproc.sync import TimeStatus, sync_log, write_time_tables
from recorder.columns import read_columns
from recorder.follow import LogFollower
from recorder.messages import Topic
from sisa.wiring.livesync import LiveSync
from tests.live import RawClient

ROOT = Path(__file__).resolve().parents[1]
CLIENT = ROOT / "tests" / "live" / "js" / "live_client.mjs"
WINDOWS = {"A": (40.0, 70.0), "B": (76.0, 106.0), "C": (112.0, 142.0)}  # s after the 1st INS
CLIENT_AT_S, CLIENT_UNTIL_S, HOSTILE_AT_S = 72.0, 107.0, 108.0
DURATION_S = 150.0
CLK_TCK = os.sysconf("SC_CLK_TCK")
SUMMARY = re.compile(r"(\d+) decode errors, (\d+) drops, (\d+) late edges")


def long_strip_scenario(folder: Path) -> Path:
    """bench with strips three times as long: 150 s of mode 2 in strip 0."""
    base = load_scenario("bench")
    path = folder / "long_strip.toml"
    path.write_text(tomli_w.dumps({"base": "bench", "block": {
        "strip_length_m": base.block.strip_length_m * 3}}), encoding="utf-8")
    return path


def cpu_s(pid: int, tid: int | None = None) -> float:
    """CPU seconds of a process, or of one of its threads."""
    stat = Path(f"/proc/{pid}/stat" if tid is None else f"/proc/{pid}/task/{tid}/stat")
    fields = stat.read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def children(pid: int) -> list[int]:
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1]) == pid:
                    out.append(int(entry.name))
            except (OSError, IndexError, ValueError):
                continue
    return out


def cmdline(pid: int) -> str:
    try:
        return (Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ")
                .decode(errors="replace"))
    except OSError:
        return ""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def first_ins_wall_ns(log: Path, proc: subprocess.Popen[str]) -> int:
    """Follow the growing log until its first INS record: its host time (the wall clock)."""
    follower = None
    while proc.poll() is None:
        if follower is None and log.exists():
            follower = LogFollower(log)
        for channel, msg in follower.poll() if follower is not None else ():
            if channel.topic == "/ins/record":
                return int(msg.log_time)
        time.sleep(0.5)
    raise SystemExit("the bench ended before its first INS record")


class Hostile:
    """A client subscribed to everything that never reads, and one that sends garbage."""

    def __init__(self, port: int) -> None:
        self.port = port
        self.stop = threading.Event()
        self.garbage_sent = 0
        self.stalled_channels = 0
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.stalled: RawClient | None = None

    def start(self) -> None:
        self.stalled = RawClient(self.port, receive_buffer=4096)
        self.stalled.handshake()
        self.stalled_channels = self.stalled.subscribe_all()
        self.thread.start()

    def _run(self) -> None:
        rng = np.random.default_rng(1)
        while not self.stop.wait(0.2):
            try:
                garbage(self.port, rng)
                self.garbage_sent += 1
            except OSError:
                continue

    def close(self) -> None:
        self.stop.set()
        self.thread.join()
        if self.stalled is not None:
            self.stalled.close()


def garbage(port: int, rng: np.random.Generator) -> None:
    """One round of what no client should send: bytes instead of a handshake, then, after a
    proper one, broken JSON, unknown operations, subscriptions to nothing, random binary
    frames and a frame claiming a terabyte."""
    with socket.create_connection(("127.0.0.1", port), timeout=2) as s:
        s.sendall(rng.bytes(512))
    c = RawClient(port, timeout_s=2)
    try:
        c.handshake()
        for payload in (b"{not json", b'{"op":"explode"}', rng.bytes(300),
                        b'{"op":"subscribe","subscriptions":[{"id":1,"channelId":999999}]}',
                        b'{"op":"unsubscribe","subscriptionIds":[424242]}'):
            c.send_frame(payload)
        c.send_frame(rng.bytes(64), opcode=2)
        c.send_frame(b"x", declared=2**40)
    finally:
        c.close()


def flood(port: int) -> None:
    """A client subscribed to everything that never reads, and two senders of garbage back to
    back (--server-cost's flood): until killed, or until its parent or the server is gone."""
    parent = os.getppid()
    stalled = RawClient(port, receive_buffer=4096)
    stalled.handshake()
    stalled.subscribe_all()
    gone = threading.Event()

    def send(seed: int) -> None:
        rng = np.random.default_rng(seed)
        while not gone.is_set():
            try:
                garbage(port, rng)
            except ConnectionRefusedError:
                gone.set()
            except OSError:
                continue

    for seed in (1, 2):
        threading.Thread(target=send, args=(seed,), daemon=True).start()
    while not gone.wait(1.0) and os.getppid() == parent:
        continue


def server_cost(seconds: float) -> None:
    """What a client makes foxglove-sdk's server cost the process serving it, without the
    rest of a recording: the live view's server (its threads lowered as `sisa record` lowers
    them) and the recorder's channels, a loop that wakes every 5 ms and logs a 300-byte
    message each wake; with no client, then the bench's garbage (window C), then a flood
    (another process). The process's CPU, and how late the loop woke (what makes an edge
    late)."""
    import foxglove

    from recorder.writer import SCHEMA_BYTES, TOPIC_TYPES
    from sisa.wiring.live import start_server

    ctx = foxglove.Context()
    server = start_server("127.0.0.1", 0, ctx)
    channels = [foxglove.Channel(str(t), context=ctx, message_encoding="json",
                                 schema=foxglove.Schema(name=c.schema_name, encoding="jsonschema",
                                                        data=SCHEMA_BYTES[c.schema_name]))
                for t, c in TOPIC_TYPES.items()]
    payload = json.dumps({"t_host_ns": 1, "data": "x" * 300}).encode()
    here = [sys.executable, str(Path(__file__).resolve())]
    for phase in ("no client", "garbage", "flood", "no client"):
        helper: Any = None
        if phase == "garbage":
            helper = Hostile(server.port)
            helper.start()
        elif phase == "flood":
            helper = subprocess.Popen([*here, "--flood", str(server.port)])
        time.sleep(1.0)
        late_ms, cpu0, t0 = [], time.process_time(), time.monotonic()
        wake = t0
        while time.monotonic() - t0 < seconds:
            wake += 0.005
            time.sleep(max(0.0, wake - time.monotonic()))
            late_ms.append((time.monotonic() - wake) * 1e3)
            wake = max(wake, time.monotonic() - 0.005)  # after a long stall: not a burst
            channels[len(late_ms) % len(channels)].log(payload, log_time=time.time_ns())
        cpu = 100 * (time.process_time() - cpu0) / (time.monotonic() - t0)
        late = np.array(late_ms)
        print(f"{phase}: process CPU {cpu:.1f} % of a core; loop woke late by median "
              f"{np.median(late):.2f} ms, p99.9 {np.percentile(late, 99.9):.1f} ms, max "
              f"{late.max():.1f} ms, {int((late > 15).sum())} wakes over 15 ms; load "
              f"{os.getloadavg()[0]:.1f}", flush=True)
        if isinstance(helper, Hostile):
            helper.close()
        elif helper is not None:
            helper.kill()
            helper.wait()
    server.stop()


def run(folder: Path, scenario: Path, live: bool) -> dict[str, Any]:
    port = free_port()
    out = folder / ("live" if live else "plain")
    cmd = [sys.executable, "-m", "sisa.cli", "bench", "--scenario", str(scenario), "--out",
           str(out), "--strip", "0", "--duration", str(DURATION_S), "--no-images"]
    if live:
        cmd += ["--live", str(port)]
    scratch = None
    bench = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # wall ns, recorder CPU s, live sync CPU s, the recorder's main thread (its loop, the tap)
    samples: list[tuple[int, float, float, float]] = []
    done = threading.Event()

    def sample() -> None:
        rec = sync = None
        while not done.wait(0.25):
            if rec is None:
                rec = next((p for p in children(bench.pid) if " record " in cmdline(p)), None)
            if rec is not None and sync is None and live:
                sync = next((p for p in children(rec) if "livesync" in cmdline(p)), None)
            try:
                samples.append((time.time_ns(), cpu_s(rec) if rec else float("nan"),
                                cpu_s(sync) if sync else 0.0,
                                cpu_s(rec, rec) if rec else float("nan")))
            except OSError:
                continue

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    # the bench records into a scratch folder beside --out, renamed at the end
    while scratch is None and bench.poll() is None:
        scratch = next(iter(sorted(folder.glob(f".{out.name}*/flight.mcap"))), None)
        time.sleep(0.2)
    t_first = first_ins_wall_ns(scratch, bench) if scratch is not None else time.time_ns()

    def at(seconds: float) -> None:
        time.sleep(max(0.0, (t_first + seconds * 1e9 - time.time_ns()) / 1e9))

    client = hostile = None
    if live:
        at(CLIENT_AT_S)
        client = subprocess.Popen(["node", str(CLIENT), f"ws://127.0.0.1:{port}",
                                   str(CLIENT_UNTIL_S - CLIENT_AT_S)],
                                  stdout=subprocess.PIPE, text=True)
        at(HOSTILE_AT_S)
        hostile = Hostile(port)
        hostile.start()
    stdout, stderr = bench.communicate(timeout=DURATION_S + 300)
    done.set()
    sampler.join()
    if hostile is not None:
        hostile.close()
    summary = json.loads(client.communicate(timeout=60)[0]) if client is not None else None
    if bench.returncode != 0:
        raise SystemExit(f"sisa bench exited {bench.returncode}: {stderr[-800:]}")
    cpu = {}
    for name, (a, b) in WINDOWS.items():
        win = [s for s in samples if t_first + a * 1e9 <= s[0] <= t_first + b * 1e9]
        if len(win) < 2 or (not live and name != "A"):
            continue
        span = (win[-1][0] - win[0][0]) / 1e9
        cpu[name] = tuple(100 * (win[-1][k] - win[0][k]) / span for k in (1, 2, 3))
    counts = SUMMARY.search(stdout)
    lag = re.search(r"latest emission ([\d.]+) ms behind", stdout)
    return {"out": out, "cpu": cpu, "client": summary, "stdout": stdout,
            "late_edges": int(counts.group(3)) if counts else -1,
            "drops": int(counts.group(2)) if counts else -1,
            "decode_errors": int(counts.group(1)) if counts else -1,
            "emulator_lag_ms": float(lag.group(1)) if lag else float("nan"),
            "stalled_channels": hostile.stalled_channels if hostile else 0,
            "garbage_rounds": hostile.garbage_sent if hostile else 0}


LATE_WINDOWS = {"pre": (0.0, 40.0), "A": (40.0, 70.0), "B": (70.0, 106.0), "C": (106.0, 145.0),
                "after": (145.0, float("inf"))}


def late_by_window(flight: Path) -> dict[str, int]:
    """Late edges (the health channel's deadline misses) in each window of the run, seconds
    from the log's first INS record."""
    health = read_columns(flight, Topic.HEALTH)
    t0 = int(read_columns(flight, Topic.INS_RECORD)["log_time_ns"][0])
    out = dict.fromkeys(LATE_WINDOWS, 0)
    for stream in np.unique(health["stream"]).tolist():
        mine = health["stream"] == stream
        t_s = (health["log_time_ns"][mine] - t0) / 1e9
        misses = health["deadline_misses"][mine]
        for name, (a, b) in LATE_WINDOWS.items():
            inside = (t_s >= a) & (t_s < b)
            if inside.any():
                before = misses[t_s < a]
                out[name] += int(misses[inside][-1] - (before[-1] if before.size else 0))
    return out


def agreement(out: Path) -> None:
    """The incremental sync's tables against `sisa sync` on the finished file."""
    offline = sync_log(out / "flight.mcap")
    first = np.load(out / "live_sync" / "first_timed.npz")
    with tempfile.TemporaryDirectory() as tmp:
        ins, ln = offline.ins, offline.lines
        write_time_tables(Path(tmp), ins, ln)
        same = {csv: (Path(tmp) / csv).read_bytes() == (out / "live_sync" / csv).read_bytes()
                for csv in ("ins_times.csv", "line_times.csv")}
    for kind, key, res, csv in (("INS records", "ins", ins, "ins_times.csv"),
                                ("scan lines", "line", ln, "line_times.csv")):
        ok = res.status == TimeStatus.OK
        wall, logged = first[f"{key}_wall_ns"], first[f"{key}_log_time_ns"]
        t_first = first[f"{key}_t_gps_ns"]
        timed = wall >= 0
        late_s = (wall - logged) / 1e9
        within = timed & (late_s <= 30.0)
        diff = np.abs(t_first[timed] - res.t_gps_ns[timed])
        print(f"  {kind}: offline timed {int(ok.sum())}/{ok.size}; live, last pass: "
              f"{'identical' if same[csv] else 'DIFFERENT'} table; first timed live "
              f"{int(timed.sum())} ({100 * timed.sum() / max(1, ok.sum()):.2f} % of offline), "
              f"within 30 s of being logged {100 * within.sum() / max(1, ok.sum()):.2f} %; "
              f"delay median {np.median(late_s[timed]):.1f} s, p99 "
              f"{np.percentile(late_s[timed], 99):.1f} s, max {late_s[timed].max():.1f} s; "
              f"first live time vs offline: {int((diff == 0).sum())} equal, max "
              f"{int(diff.max()) if diff.size else 0} ns apart; timed live but not offline: "
              f"{int((timed & ~ok).sum())}")


def pass_cost(log: Path) -> None:
    """The incremental sync on a finished log: its catch-up passes, then passes with nothing
    new to read (what a pass costs at that length of flight)."""
    live = LiveSync(log, 600.0)
    for i in range(12):
        cpu0, wall0 = time.process_time(), time.perf_counter()
        state = live.run_pass()["state"]
        print(f"pass {i}: CPU {time.process_time() - cpu0:.2f} s, wall "
              f"{time.perf_counter() - wall0:.2f} s, bytes read "
              f"{live.follower.stats.bytes_read}, INS {state['ins_timed']}/"
              f"{state['ins_records']} timed, lines {state['lines_timed']}/{state['lines']}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pass-cost", type=Path, default=None, metavar="FLIGHT",
                        help="only measure the incremental sync's passes on this log")
    parser.add_argument("--late", type=Path, nargs="+", default=None, metavar="RUN",
                        help="only count the late edges by window in kept runs (--keep)")
    parser.add_argument("--baseline", action="store_true",
                        help="first the same run without --live (window A only)")
    parser.add_argument("--keep", type=Path, default=None, help="keep the runs here")
    parser.add_argument("--server-cost", type=float, default=None, metavar="SECONDS",
                        help="only measure the server under no client, garbage and a flood")
    parser.add_argument("--flood", type=int, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.flood is not None:
        flood(args.flood)
        return
    if args.server_cost is not None:
        server_cost(args.server_cost)
        return
    if args.late:
        for folder in args.late:
            print(f"{folder}: late edges by window {late_by_window(folder / 'flight.mcap')}")
        return
    if args.pass_cost is not None:
        pass_cost(args.pass_cost)
        return
    if shutil.which("node") is None or not (CLIENT.parent / "node_modules").is_dir():
        raise SystemExit("needs node and `npm ci` in tests/live/js")
    folder = Path(tempfile.mkdtemp(prefix="live_view_")) if args.keep is None else args.keep
    folder.mkdir(parents=True, exist_ok=True)
    print(f"load average at start: {os.getloadavg()}")
    scenario = long_strip_scenario(folder)
    if args.baseline:
        base = run(folder, scenario, live=False)
        print(f"without --live: recorder {base['cpu']['A'][0]:.1f} % of a core (window A; "
              f"its loop's thread {base['cpu']['A'][2]:.1f} %); "
              f"late edges {base['late_edges']}, drops {base['drops']}, decode errors "
              f"{base['decode_errors']}; emulator lag {base['emulator_lag_ms']:.1f} ms; late "
              f"edges by window {late_by_window(base['out'] / 'flight.mcap')}")
    r = run(folder, scenario, live=True)
    names = {"A": "no client", "B": "a client reading every channel",
             "C": "a client that never reads + a garbage sender"}
    for name, (rec, sync, main_thread) in r["cpu"].items():
        print(f"with --live, {names[name]}: recorder {rec:.1f} % (its loop's thread "
              f"{main_thread:.1f} %, its other threads {rec - main_thread:.1f} %: flush, live "
              f"view, foxglove-sdk server), incremental sync {sync:.1f} %, together "
              f"{rec + sync:.1f} % of a core")
    print(f"late edges {r['late_edges']}, drops {r['drops']}, decode errors "
          f"{r['decode_errors']}; emulator lag {r['emulator_lag_ms']:.1f} ms; stalled client "
          f"subscribed to {r['stalled_channels']} channels, {r['garbage_rounds']} garbage rounds; "
          f"late edges by window {late_by_window(r['out'] / 'flight.mcap')}")
    client = r["client"] or {"channels": {}}
    bad = {t: c["invalid"] for t, c in client["channels"].items() if c["invalid"]}
    empty = [t for t, c in client["channels"].items() if c["received"] == 0]
    print(f"client: {len(client['channels'])} channels advertised, {len(empty)} without a "
          f"message in its window {empty}, invalid messages {bad or 0}")
    agreement(r["out"])
    print(f"load average at end: {os.getloadavg()}")
    if args.keep is None:
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
