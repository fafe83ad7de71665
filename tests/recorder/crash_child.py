"""A recorder in a child process, writing a steady stream until it is killed (crash tests).

    python -m tests.recorder.crash_child OUT.mcap RATE_HZ [FILE_SIZE_LIMIT_BYTES]

Writes InsRecordLog at RATE_HZ with t_host_ns = time.time_ns() (plus a GpsFix every 100th
message), prints "ready" once writing, and never stops on its own. With a file size limit
(RLIMIT_FSIZE, SIGXFSZ ignored) the kernel refuses writes past it with EFBIG, a real disk
error: the child then prints the RecorderError line and its message count, and exits 3.
"""

from __future__ import annotations

import resource
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from recorder.messages import GpsFix, InsRecordLog
from recorder.writer import FlightRecorder
from sisa.core.errors import RecorderError


def ins(t_ns: int, i: int) -> InsRecordLog:
    return InsRecordLog(t_ns, i % 65536, i * 100_000, 0.01, -0.02, 1.5, 1e-4, 2e-4, -3e-4,
                        60.0, 1.0, -0.5, 0, i % 64 == 0, i * 100_000 - 7)


def fix(t_ns: int, i: int) -> GpsFix:
    return GpsFix(t_ns, 1_400_000_000 * 10**9 + i * 10**7, 42.1 + i * 1e-7, 2.5, 600.0, 1, 9, 0.8)


def _write_steadily(rec: FlightRecorder, rate_hz: float) -> None:
    start = time.monotonic()
    i = 0
    while True:
        due = int((time.monotonic() - start) * rate_hz) + 1
        while i < due:
            t = time.time_ns()
            rec.write(ins(t, i))
            if i % 100 == 0:
                rec.write(fix(t, i))
            if i == 0:
                print("ready", flush=True)
            i += 1
        time.sleep(0.0005)


def main(argv: list[str]) -> int:
    out, rate_hz = Path(argv[0]), float(argv[1])
    if len(argv) > 2:
        limit = int(argv[2])
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    rec = FlightRecorder(out, metadata={"test": "crash"})
    try:
        _write_steadily(rec, rate_hz)
    except RecorderError as exc:
        print(f"error {rec.messages_written} {exc}", flush=True)
        return 3
    return 0


@dataclass(frozen=True)
class Killed:
    path: Path
    kill_ns: int  # time.time_ns() just before SIGKILL
    after_ready_s: float
    rate_hz: float


def start(path: Path, rate_hz: float = 2000.0, *extra: str) -> subprocess.Popen[str]:
    """Start a child and return once it is writing."""
    proc = subprocess.Popen([sys.executable, "-m", "tests.recorder.crash_child", str(path),
                             str(rate_hz), *extra], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            cwd=Path(__file__).resolve().parents[2])
    assert proc.stdout is not None
    line = proc.stdout.readline()
    if line.strip() != "ready":
        proc.kill()
        _, err = proc.communicate()
        raise RuntimeError(f"crash child did not start: {line!r} {err[-2000:]}")
    return proc


def kill_many(folder: Path, plan: list[tuple[float, float]]) -> list[Killed]:
    """One child per (delay_s, rate_hz), all writing at once; each SIGKILLed `delay_s` after it
    was ready."""
    runs = []
    for k, (delay, rate_hz) in enumerate(plan):
        path = folder / f"killed_{k}.mcap"
        runs.append((path, delay, start(path, rate_hz), time.monotonic(), rate_hz))
    killed: list[Killed] = []
    for path, delay, proc, ready, rate_hz in sorted(runs, key=lambda r: r[3] + r[1]):
        time.sleep(max(0.0, ready + delay - time.monotonic()))
        kill_ns = time.time_ns()
        proc.send_signal(signal.SIGKILL)
        killed.append(Killed(path, kill_ns, delay, rate_hz))
    for _, _, proc, _, _ in runs:
        proc.communicate()
    return sorted(killed, key=lambda k: k.path.name)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
