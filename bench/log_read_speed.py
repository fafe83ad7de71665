"""Reading a flight log: what `sisa sync` spends before and after its sync, on a real log, beside
the mcap package's own reader of the same file in the same run.

    .venv/bin/python bench/log_read_speed.py FLIGHT.mcap [--repeats 3]

Timed (process CPU and wall, best of --repeats, the file in the page cache after a first read):
- `mcap` baseline: the mcap package's non-seeking reader over every message
  (`iter_messages(log_time_order=False)`, which also reads a file cut short), doing nothing
  with them: what an independent reader costs just to hand each message over;
- `LogReader.raw()`: SISA's tolerant reader, every message as an mcap `Message` with its
  channel (and the per-topic accounting);
- `read_topics`: the columns `sisa sync` reads (sync and health topics), JSON decoded;
- the sync itself and its tables, as `sisa sync` runs them.
A 5-hour flight has ~2.8x the messages of garrotxa's 1.8 h, and the cost is linear in them.
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from mcap.reader import NonSeekingReader

from postproc.sync import WANTED as SYNC_WANTED
from postproc.sync import sync_input_from_columns, synchronise, write_time_tables
from recorder.columns import read_topics
from recorder.health import HEALTH_WANTED
from recorder.reader import LogReader


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def timed(fn: Callable[[], Any], repeats: int) -> tuple[float, float, Any]:
    """(best wall s, its CPU s, the last result)."""
    best: tuple[float, float] | None = None
    out = None
    for _ in range(repeats):
        c0, t0 = _cpu_s(), time.perf_counter()
        out = fn()
        wall, cpu = time.perf_counter() - t0, _cpu_s() - c0
        if best is None or wall < best[0]:
            best = (wall, cpu)
    assert best is not None
    return best[0], best[1], out


def mcap_pass(path: Path) -> int:
    with open(path, "rb") as fh:
        return sum(1 for _ in NonSeekingReader(fh).iter_messages(log_time_order=False))


def raw_pass(path: Path) -> int:
    return sum(1 for _ in LogReader(path).raw())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("flight", type=Path)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    path: Path = args.flight
    path.read_bytes()  # into the page cache
    size_mb = path.stat().st_size / 1e6
    print(f"{path}: {size_mb:.1f} MB; load average {os.getloadavg()[0]:.2f} before")
    wanted = {**SYNC_WANTED, **HEALTH_WANTED}
    rows: list[tuple[str, float, float, int]] = []
    w, c, n = timed(lambda: mcap_pass(path), args.repeats)
    rows.append(("mcap NonSeekingReader, every message", w, c, n))
    w, c, n = timed(lambda: raw_pass(path), args.repeats)
    rows.append(("LogReader.raw(), every message", w, c, n))
    w, c, cols = timed(lambda: read_topics(path, wanted), args.repeats)
    n_cols = sum(len(v["log_time_ns"]) for v in cols.values())
    rows.append(("read_topics (sisa sync's columns)", w, c, n_cols))
    w, c, result = timed(lambda: synchronise(sync_input_from_columns(cols), None), args.repeats)
    rows.append(("synchronise", w, c, result.ins.seq.size + result.lines.line.size))

    def tables() -> None:
        with tempfile.TemporaryDirectory() as tmp:
            write_time_tables(Path(tmp), result.ins, result.lines)
    w, c, _ = timed(tables, args.repeats)
    rows.append(("writing ins_times.csv, line_times.csv", w, c, result.ins.seq.size))
    width = max(len(r[0]) for r in rows)
    print(f"{'step':<{width}}  {'wall s':>7}  {'CPU s':>6}  {'items':>8}  {'k items/s':>9}")
    for label, wall, cpu, items in rows:
        print(f"{label:<{width}}  {wall:7.2f}  {cpu:6.2f}  {items:8d}  {items / wall / 1e3:9.0f}")
    print(f"LogReader.raw() against the mcap reader: {rows[0][1] / rows[1][1]:.2f}x the speed "
          f"by wall, {rows[0][2] / rows[1][2]:.2f}x by CPU")
    total = rows[2][1] + rows[3][1] + rows[4][1]
    print(f"sisa sync's reading + sync + tables: {total:.2f} s wall "
          f"({rows[2][1] / total:.0%} reading); load average {os.getloadavg()[0]:.2f} after")


if __name__ == "__main__":
    main()
