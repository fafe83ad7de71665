"""Power loss: 50 recorders SIGKILLed while recording, while splitting into parts and while
finishing (writing the summary, closing), at random moments and at exact steps (right after the
k-th file of a split set is created, at the k-th fsync).

Every file left must be readable by `sisa log info` (alone and as a set), by `sisa log recover`
and by the post-processor's reader (`postproc.sync.flightlog.read_sync_input`); every part but the
last must be complete; the per-topic sequence runs on across parts without a gap; and the messages
kept reach to within 1.5 s of the kill.

The children are this module run as a program:

    python -m tests.recorder.test_power_loss OUT.mcap PLAN_JSON
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pytest

# every log here is cut short or damaged on purpose: the reader's warning saying so is expected
pytestmark = pytest.mark.filterwarnings("ignore::recorder.stats.DamagedLogWarning")

MAX_LOSS_NS = 1_500_000_000
ROOT = Path(__file__).resolve().parents[2]
KILLS = 50
BATCHES = 5  # tests of KILLS / BATCHES children each, all running at once


@dataclass(frozen=True)
class Plan:
    rate_hz: float
    split_duration_s: float | None = None
    split_size_bytes: int | None = None
    kill_after_s: float | None = None  # the parent kills this long after "ready"
    finish_after_s: float | None = None  # the child closes the recorder then; killed around it
    kill_at_file: int | None = None  # the child kills itself right after creating file k
    kill_at_fsync: int | None = None  # the child kills itself at its k-th fsync

    @property
    def self_killed(self) -> bool:
        return self.kill_at_file is not None or self.kill_at_fsync is not None


def make_plans(seed: int = 20260615) -> list[Plan]:
    rng = random.Random(seed)
    plans = []
    for k in range(KILLS):
        rate = rng.choice((1000.0, 1000.0, 300.0, 40.0))
        split = rng.choice(("time", "size", "size", None))
        duration = rng.uniform(0.15, 0.6) if split == "time" else None
        size = rng.choice((4096, 8192, 20_000, 65_536)) if split == "size" else None
        kind = k % 5
        if kind in (0, 1):  # while recording (and splitting)
            plans.append(Plan(rate, duration, size, kill_after_s=rng.uniform(0.4, 2.2)))
        elif kind == 2:  # while finishing
            plans.append(Plan(rate, duration, size, finish_after_s=rng.uniform(0.3, 1.5)))
        elif kind == 3:  # right after a part's file is created
            plans.append(Plan(max(rate, 300.0), rng.uniform(0.1, 0.3), None,
                              kill_at_file=rng.randint(1, 3)))
        else:  # at an fsync: part start, timed flush, part finish
            plans.append(Plan(rate, rng.uniform(0.1, 0.4), size, kill_at_fsync=rng.randint(1, 9)))
    return plans


PLANS = make_plans()


# --- the child ----------------------------------------------------------------------------------

def _die() -> None:
    print(f"dying {time.time_ns()}", flush=True)
    os.kill(os.getpid(), signal.SIGKILL)


def _install_self_kill(plan: Plan) -> None:
    import recorder.writer as writer

    if plan.kill_at_file is not None:
        created = [0]
        open_new = writer._open_new

        def open_and_die(path: Path):  # type: ignore[no-untyped-def]
            fh = open_new(path)
            created[0] += 1
            if created[0] == plan.kill_at_file + 1:
                _die()
            return fh

        writer._open_new = open_and_die
    if plan.kill_at_fsync is not None:
        calls = [0]
        fsync = os.fsync

        def fsync_or_die(fd: int) -> None:
            calls[0] += 1
            if calls[0] == plan.kill_at_fsync:
                _die()
            fsync(fd)

        writer.os.fsync = fsync_or_die  # type: ignore[attr-defined]


def child(out: Path, plan: Plan) -> None:
    from recorder.writer import FlightRecorder
    from tests.recorder.crash_child import fix, ins

    _install_self_kill(plan)
    rec = FlightRecorder(out, split_duration_s=plan.split_duration_s,
                         split_size_bytes=plan.split_size_bytes, metadata={"test": "power"})
    start = time.monotonic()
    i = 0
    while plan.finish_after_s is None or time.monotonic() - start < plan.finish_after_s:
        due = int((time.monotonic() - start) * plan.rate_hz) + 1
        while i < due:
            t = time.time_ns()
            rec.write(ins(t, i))
            if i % 50 == 0:
                rec.write(fix(t, i))
            if i == 0:
                print("ready", flush=True)
            i += 1
        time.sleep(0.0005)
    print(f"closing {time.time_ns()}", flush=True)
    rec.close()
    print("closed", flush=True)
    time.sleep(3600)


# --- the parent ---------------------------------------------------------------------------------

@dataclass(frozen=True)
class Killed:
    path: Path
    plan: Plan
    kill_ns: int  # when the recording was cut (or told to close, if that came first)
    alive_s: float  # from "ready" to the kill


def _start(path: Path, plan: Plan) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "tests.recorder.test_power_loss", str(path),
                             json.dumps(asdict(plan))], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT)


def _readline(proc: subprocess.Popen[str]) -> str:
    assert proc.stdout is not None
    return proc.stdout.readline().strip()


def _kill_one(path: Path, plan: Plan, proc: subprocess.Popen[str], delay_s: float) -> Killed:
    line = _readline(proc)
    if plan.self_killed and line.startswith("dying"):  # died before its first message
        proc.wait()
        return Killed(path, plan, int(line.split()[1]), 0.0)
    assert line == "ready", f"child did not start: {line!r} {proc.stderr.read()[-2000:]}"  # type: ignore[union-attr]
    ready = time.monotonic()
    if plan.self_killed:
        line = _readline(proc)
        proc.wait(timeout=60)
        assert line.startswith("dying"), f"child did not kill itself: {line!r}"
        return Killed(path, plan, int(line.split()[1]), time.monotonic() - ready)
    stopped_ns = None
    if plan.finish_after_s is not None:
        line = _readline(proc)
        assert line.startswith("closing"), line
        stopped_ns = int(line.split()[1])  # no message after this: the recorder is closing
        time.sleep(delay_s)
    else:
        time.sleep(max(0.0, ready + (plan.kill_after_s or 0.0) - time.monotonic()))
    kill_ns = time.time_ns()
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=60)
    return Killed(path, plan, min(kill_ns, stopped_ns or kill_ns), time.monotonic() - ready)


def run_batch(folder: Path, plans: list[Plan], seed: int) -> list[Killed]:
    """All children at once, each watched by its own thread and killed (or killing itself) as
    its plan says."""
    rng = random.Random(seed)
    procs = []
    for k, plan in enumerate(plans):
        path = folder / f"flight{k:02d}.mcap"
        procs.append((path, plan, _start(path, plan), rng.uniform(0.0, 0.004)))
    try:
        with ThreadPoolExecutor(len(procs)) as pool:
            return list(pool.map(lambda job: _kill_one(*job), procs))
    finally:
        for _, _, proc, _ in procs:
            if proc.poll() is None:
                proc.kill()
            proc.communicate()


def check_killed(run: Killed, scratch: Path, capsys: pytest.CaptureFixture[str]) -> float:
    """Every check on one killed recording; returns the loss before the kill in seconds."""
    from postproc.sync import read_sync_input
    from recorder.reader import scan_log
    from recorder.writer import split_parts
    from sisa.cli import main

    parts = split_parts(run.path)
    others = sorted(p.name for p in run.path.parent.iterdir()
                    if run.path.stem in p.name and p not in parts)
    # a file killed before its header reached the disk never got its name: a hidden leftover
    assert all(name.startswith(f".{run.path.stem}") and ".partial-" in name for name in others)
    if not parts:
        assert run.alive_s == 0.0, f"{run.plan}: no file at all"
        return 0.0
    for part in parts:  # each file on its own
        assert main(["log", "info", str(part)]) == 0, capsys.readouterr().err
        out = scratch / f"{part.stem}-recovered.mcap"
        assert main(["log", "recover", str(part), str(out)]) == 0, capsys.readouterr().err
        assert scan_log(out).messages == scan_log(part).messages
    assert main(["log", "info", *map(str, parts)]) == 0, capsys.readouterr().err
    capsys.readouterr()
    stats = scan_log(parts)
    assert all(f.complete for f in stats.files[:-1]), "a part before the last is not complete"
    sync = read_sync_input(parts)
    n = len(sync.ins.counter)
    assert np.array_equal(sync.ins.counter, np.arange(n) % 65536), "INS records lost or repeated"
    if n == 0:  # killed before its first chunk reached the file: all of it is the loss
        assert run.alive_s <= MAX_LOSS_NS / 1e9, f"{run.plan}: nothing kept after " \
            f"{run.alive_s:.2f} s"
        return run.alive_s
    assert all(t.lost_by_sequence == 0 for t in stats.topics.values())
    assert n >= run.plan.rate_hz * (run.alive_s - 1.5)
    loss_ns = run.kill_ns - stats.end_ns
    assert 0 < loss_ns <= MAX_LOSS_NS, f"{run.plan}: lost {loss_ns / 1e9:.3f} s"
    return loss_ns / 1e9


@pytest.mark.parametrize("batch", range(BATCHES))
def test_power_loss_while_recording_splitting_and_finishing(
        batch: int, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    size = KILLS // BATCHES
    plans = PLANS[batch * size:(batch + 1) * size]
    runs = run_batch(tmp_path, plans, seed=batch)
    scratch = tmp_path / "recovered"
    scratch.mkdir()
    losses = [check_killed(run, scratch, capsys) for run in runs]
    with capsys.disabled():
        print(f"\npower loss batch {batch}: {len(runs)} kills, loss before the kill max "
              f"{max(losses) * 1e3:.0f} ms, mean {np.mean(losses) * 1e3:.0f} ms")


def test_the_plan_covers_every_phase() -> None:
    assert len(PLANS) == KILLS
    assert sum(p.kill_after_s is not None for p in PLANS) >= 10
    assert sum(p.finish_after_s is not None for p in PLANS) >= 10
    assert sum(p.kill_at_file is not None for p in PLANS) >= 10
    assert sum(p.kill_at_fsync is not None for p in PLANS) >= 10
    assert sum(p.split_duration_s is not None or p.split_size_bytes is not None
               for p in PLANS) >= 30


if __name__ == "__main__":
    child(Path(sys.argv[1]), Plan(**json.loads(sys.argv[2])))
