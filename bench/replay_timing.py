"""Replay timing fidelity: what a reader on the replayed ports receives, against the recording.

    .venv/bin/python bench/replay_timing.py [FLIGHT.mcap] [--start S] [--duration 60]
                                            [--rate 1] [--realtime]

Without FLIGHT it simulates the bench preset (no images) and plays 60 s around its first strip
(scanner on: every stream at full rate). `sisa replay --once` runs as its own process; this
script is the reader, as lean as it can be (raw reads of the ptys, the SLCAN pty and the pulse
socket, one select loop, each read stamped with time.perf_counter_ns), so the figures are the
replay's, not a decoder's. Every recorded item (serial chunk, CAN frame, edge) is matched to the
read that completed it, and the bytes are checked to be the recorded ones.

Printed, overall and per wire: the inter-message timing error |(r_i − r_{i−1}) − (t_i − t_{i−1})|
over consecutive items of the merged schedule (r: receive time, t: recorded log time), and the
schedule error |(r_i − t_i) − median(r − t)|: median, p99, max, in ms. Target at x1: p99 < 1 ms.
`--realtime` runs both the replay and this reader with SCHED_FIFO (as `chrt -f` would).
"""

from __future__ import annotations

import argparse
import json
import os
import select
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import numpy.typing as npt

from acquisition.pulses import PulseLine
from recorder.columns import read_columns
from recorder.messages import Topic
from recorder.replay import (
    CanFrame,
    Item,
    Payload,
    RecordedEdge,
    Wire,
    iter_schedule,
    survey_log,
)
from recorder.writer import split_parts

EDGE_SIZE = 20


def _flight(args: argparse.Namespace, tmp: Path) -> Path:
    if args.flight is not None:
        return Path(args.flight)
    run = tmp / "bench"
    subprocess.run([sys.executable, "-m", "sisa.cli", "simulate", "--preset", "bench",
                    "--no-images", "--out", str(run)], check=True, stdout=subprocess.DEVNULL)
    if args.start is None:
        first = int(read_columns(run / "flight.mcap", Topic.SCANNER_RAW)["log_time_ns"][0])
        args.start = max(0.0, (first - survey_log(run / "flight.mcap").start_ns) / 1e9 - 5.0)
    return run / "flight.mcap"


class Reader:
    """Raw reads of every endpoint in one select loop; (perf_counter_ns, bytes) per read."""

    def __init__(self, endpoints: dict[str, str]) -> None:
        self.fds: dict[int, Wire] = {}
        for wire in (Wire.GPS, Wire.SCANNER):
            self.fds[os.open(endpoints[wire], os.O_RDWR | os.O_NOCTTY)] = wire
        can_fd = os.open(endpoints[Wire.INS].removeprefix("slcan:"), os.O_RDWR | os.O_NOCTTY)
        os.write(can_fd, b"S6\rO\r")  # open the adapter's channel, as python-can does
        self.fds[can_fd] = Wire.INS
        host, _, port = endpoints[Wire.PULSES].removeprefix("tcp://").rpartition(":")
        self.sock = socket.create_connection((host, int(port)))
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.fds[self.sock.fileno()] = Wire.PULSES
        self.reads: dict[Wire, list[tuple[int, bytes]]] = {w: [] for w in Wire}

    def run(self, proc: subprocess.Popen[bytes]) -> None:
        open_fds = set(self.fds)
        while open_fds:
            ready, _, _ = select.select(list(open_fds), [], [], 0.5)
            t = time.perf_counter_ns()
            for fd in ready:
                try:
                    data = os.read(fd, 65536)
                except OSError:  # EIO: the replay closed the pty
                    data = b""
                if not data:
                    open_fds.discard(fd)
                    continue
                self.reads[self.fds[fd]].append((t, data))
            if not ready and proc.poll() is not None:
                break

    def close(self) -> None:
        self.sock.close()
        for fd, wire in self.fds.items():
            if wire is not Wire.PULSES:
                os.close(fd)


def _byte_times(reads: list[tuple[int, bytes]], ends: npt.NDArray[np.int64]
                ) -> npt.NDArray[np.int64]:
    """Receive time of the read that holds byte `end − 1` of the stream, for each end."""
    read_ends = np.cumsum([len(d) for _, d in reads], dtype=np.int64)
    times = np.array([t for t, _ in reads], dtype=np.int64)
    idx = np.searchsorted(read_ends, ends, side="left")
    if idx.size and idx.max() >= len(times):
        raise SystemExit("the reader received fewer bytes than the recording holds")
    return times[idx]


def _can_frames(stream: bytes) -> tuple[list[bytes], list[int]]:
    """Every SLCAN frame line the adapter sent, and the stream offset just past each."""
    lines, ends, at = [], [], 0
    while (end := stream.find(b"\r", at)) >= 0:
        if stream[at: at + 1] in (b"t", b"T"):
            lines.append(stream[at:end])
            ends.append(end + 1)
        at = end + 1
    return lines, ends


def _slcan_line(frame: CanFrame) -> bytes:
    kind, width = ("T", 8) if frame.is_extended_id else ("t", 3)
    return f"{kind}{frame.arbitration_id:0{width}X}{len(frame.data)}{frame.data.hex().upper()}" \
        .encode()


def _edges(stream: bytes) -> list[tuple[str, int]]:
    out = []
    for at in range(0, len(stream) - EDGE_SIZE + 1, EDGE_SIZE):
        line, seq = stream[at + 2], int.from_bytes(stream[at + 4: at + 8], "little")
        out.append((PulseLine(line).name, seq))
    return out


def _ends(wire: Wire, payloads: list[Payload], stream: bytes) -> list[int]:
    """Offset just past each recorded item in the received stream; exits if they differ."""
    if wire is Wire.INS:
        got, ends = _can_frames(stream)
        same = got[: len(payloads)] == [_slcan_line(p) for p in payloads
                                        if isinstance(p, CanFrame)]
    elif wire is Wire.PULSES:
        ends = [EDGE_SIZE * (k + 1) for k in range(len(stream) // EDGE_SIZE)]
        same = _edges(stream)[: len(payloads)] == [(p.line, p.link_seq) for p in payloads
                                                   if isinstance(p, RecordedEdge)]
    else:
        chunks = [p for p in payloads if isinstance(p, bytes)]
        ends = np.cumsum([len(c) for c in chunks], dtype=np.int64).tolist()
        same = stream.startswith(b"".join(chunks))
    if not same or len(ends) < len(payloads):
        raise SystemExit(f"{wire}: what the reader received is not what was recorded")
    return ends[: len(payloads)]


def match(items: list[Item], reads: dict[Wire, list[tuple[int, bytes]]]
          ) -> npt.NDArray[np.int64]:
    """Receive time of every recorded item (in schedule order)."""
    recv = np.zeros(len(items), dtype=np.int64)
    for wire in Wire:
        idx = [i for i, it in enumerate(items) if it.wire is wire]
        if idx:
            stream = b"".join(d for _, d in reads[wire])
            ends = _ends(wire, [items[i].payload for i in idx], stream)
            recv[idx] = _byte_times(reads[wire], np.array(ends, dtype=np.int64))
    return recv


def _figures(err_ns: npt.NDArray[np.int64]) -> str:
    a = np.abs(err_ns) / 1e6
    if a.size == 0:
        return "-"
    return (f"median {np.median(a):.3f}  p99 {np.percentile(a, 99):.3f}  "
            f"max {a.max():.3f} ms")


def report(items: list[Item], recv: npt.NDArray[np.int64]) -> None:
    t_log = np.array([it.t_log_ns for it in items], dtype=np.int64)
    latency = recv - t_log
    sched = latency - int(np.median(latency))
    inter = np.diff(recv) - np.diff(t_log)
    wires = np.array([str(it.wire) for it in items])
    print(f"{len(items)} items over {(t_log[-1] - t_log[0]) / 1e9:.1f} s of log")
    print(f"  all       inter-message {_figures(inter)};  schedule {_figures(sched)}")
    for wire in Wire:
        sel = np.flatnonzero(wires == wire)
        if sel.size < 2:
            continue
        d = np.diff(recv[sel]) - np.diff(t_log[sel])
        print(f"  {wire:<9} {sel.size:>6} items, inter-message {_figures(d)};  "
              f"schedule {_figures(sched[sel])}")


@contextmanager
def replay(flight: Path, args: argparse.Namespace, tmp: Path
           ) -> Iterator[tuple[subprocess.Popen[bytes], dict[str, str]]]:
    ep = tmp / "endpoints.json"
    cmd = [sys.executable, "-m", "sisa.cli", "replay", str(flight), "--once", "--quiet",
           "--endpoints", str(ep), "--rate", str(args.rate), "--start", str(args.start or 0.0),
           "--duration", str(args.duration)]
    if args.realtime:
        cmd.append("--realtime")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 60
        while not ep.exists():
            if proc.poll() is not None or time.monotonic() > deadline:
                raise SystemExit("sisa replay did not start")
            time.sleep(0.02)
        yield proc, json.loads(ep.read_text())
    finally:
        out, _ = proc.communicate(timeout=120)
        print(out.decode().strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("flight", nargs="?", default=None)
    parser.add_argument("--start", type=float, default=None, help="seconds into the log")
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--rate", type=float, default=1.0)
    parser.add_argument("--realtime", action="store_true",
                        help="SCHED_FIFO for the replay and this reader")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        flight = _flight(args, tmp)
        survey = survey_log(split_parts(flight))
        lo = survey.start_ns + round((args.start or 0.0) * 1e9)
        items = list(iter_schedule(split_parts(flight), lo, lo + round(args.duration * 1e9)))
        if args.realtime:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
        with replay(flight, args, tmp) as (proc, endpoints):
            reader = Reader(endpoints)
            try:
                reader.run(proc)
            finally:
                reader.close()
    recv = match(items, reader.reads)
    if args.rate != 1.0:  # compare against the recording played at the rate
        t0 = items[0].t_log_ns
        items = [Item(t0 + round((it.t_log_ns - t0) / args.rate), it.wire, it.payload)
                 for it in items]
    print(f"replay of {flight} from {args.start or 0.0:g} s at x{args.rate:g}"
          f"{' (SCHED_FIFO)' if args.realtime else ''}; load average "
          f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    report(items, recv)


if __name__ == "__main__":
    main()
