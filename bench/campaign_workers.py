"""A campaign's georeferencing + ortho stage on 2 Dask workers against 1, side by side.

    .venv/bin/python bench/campaign_workers.py                 4 simulated flights, 3 rounds
    .venv/bin/python bench/campaign_workers.py --runs DIR      a folder of `sisa simulate` runs

The flights are simulated once (short bench flights, two strips each: every segment a task
of its own, ~2 200 lines x 512 pixels x 4 bands), then processed once untimed (the sync stage
done, numba's caches written). Each timed round starts from a copy of that output with only
the sync's stamps kept, so that what runs is every segment's ray casting and ortho (and each
flight's summary and the mosaic after them); the figure is the stage's span, from the first
segment task submitted to the last ortho done (`CampaignRun.spans_s`). Two LocalClusters are
started before any round, one with 1 worker process and one with 2 (1 thread each, as
`sisa campaign process` starts them), each warmed by an untimed round; the timed rounds
alternate between them, and the medians are compared. The load average is printed before
and after: the ratio means little on a machine with other work.

Target (issue 36): 2 workers >= 1.7x faster than 1 on a 2-core machine.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SCENARIO = """
base = "bench"
[block]
strip_length_m = 2000.0
first_strip_heading_deg = {heading}
[flight]
static_alignment_s = 30.0
figure_eights = 0
airfield_offset_m = [-600.0, -1500.0]
"""


class Quiet:
    """The driver's events, unshown."""

    def planned(self, stage: Any, tasks: int) -> None:
        pass

    def finished(self, stage: Any, reused: bool) -> None:
        pass

    def warning(self, text: str) -> None:
        pass


def simulate(root: Path, flights: int) -> Path:
    """`flights` runs in root/runs, two at a time; a seed whose terrain cannot place its
    control points (the simulator refuses it) is replaced by the next."""
    runs = root / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "SISA_PROGRESS_S": "off"}

    def start(k: int, seed: int) -> subprocess.Popen[bytes]:
        scn = root / f"f{k}.toml"
        scn.write_text(SCENARIO.format(heading=90.0 * (k % 2)), encoding="utf-8")
        return subprocess.Popen(
            [sys.executable, "-m", "sisa.cli", "simulate", "--scenario", str(scn), "--seed",
             str(seed), "--out", str(runs / f"f{k}")], env=env)

    for pair in range(0, flights, 2):
        batch = {k: (10 + k, start(k, 10 + k)) for k in range(pair, min(pair + 2, flights))
                 if not (runs / f"f{k}" / "flight.mcap").is_file()}
        for k, (seed, proc) in batch.items():
            for _ in range(5):
                if proc.wait() == 0:
                    break
                seed += 100
                proc = start(k, seed)
            else:
                raise SystemExit(f"flight {k}: no seed simulated")
    return runs


def synced_only(template: Path, dest: Path) -> None:
    """A copy of a processed campaign with only the sync stamps kept."""
    shutil.copytree(template, dest, copy_function=shutil.copy2)
    for stamp in dest.rglob(".tasks/*.json"):
        if stamp.name != "sync.json":
            stamp.unlink()


def one_round(spec: Any, template: Path, scratch: Path, client: Any) -> float:
    from postproc.campaign import Driver, Stage

    out = scratch / f"round-{time.monotonic_ns()}"
    synced_only(template, out)
    run = Driver(spec, out, lambda: client, Quiet()).run()
    if run.failures():
        raise SystemExit(f"a round failed: {run.failures()}")
    expected = sum(len(f.cast_keys) for f in run.flights.values())
    if run.ran < 2 * expected:
        raise SystemExit(f"only {run.ran} tasks ran: the round did not redo the segments")
    first, _ = run.spans_s[Stage.GEOREF]
    _, last = run.spans_s[Stage.ORTHO]
    shutil.rmtree(out)
    return last - first


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=Path, default=None, help="folder of sisa simulate runs")
    ap.add_argument("--flights", type=int, default=4)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--keep", type=Path, default=None, help="work folder (kept)")
    args = ap.parse_args()
    from distributed import Client, LocalCluster

    from sisa.commands.campaign import runs_campaign

    work = args.keep or Path(tempfile.mkdtemp(prefix="sisa-campaign-bench-"))
    work.mkdir(parents=True, exist_ok=True)
    runs = args.runs or (work / "runs" if len(list(work.glob("runs/f*/flight.mcap")))
                         >= args.flights else simulate(work, args.flights))
    spec = runs_campaign(runs)
    segments = 0
    clusters = {n: LocalCluster(  # type: ignore[no-untyped-call]
        n_workers=n, threads_per_worker=1, processes=True, dashboard_address="127.0.0.1:0",
        host="127.0.0.1") for n in (1, 2)}
    clients = {n: Client(c) for n, c in clusters.items()}  # type: ignore[no-untyped-call]
    try:
        template = work / "template"
        if not template.is_dir():
            from postproc.campaign import Driver
            Driver(spec, template, lambda: clients[2], Quiet()).run()
        for n in (1, 2):  # warm each cluster's workers (imports, numba caches), untimed
            one_round(spec, template, work, clients[n])
        segments = sum(1 for _ in template.glob("flights/*/segment_*_ortho.tif"))
        load_before = os.getloadavg()
        times: dict[int, list[float]] = {1: [], 2: []}
        for r in range(args.rounds):
            for n in ((1, 2) if r % 2 == 0 else (2, 1)):
                t = one_round(spec, template, work, clients[n])
                times[n].append(t)
                print(f"round {r + 1}: {n} worker{'s' if n > 1 else ''}: {t:.2f} s",
                      flush=True)
        load_after = os.getloadavg()
    finally:
        for c in clients.values():
            c.close()  # type: ignore[no-untyped-call]
        for cl in clusters.values():
            cl.close()
    one, two = statistics.median(times[1]), statistics.median(times[2])
    print(f"georef + ortho stage of {len(spec.flights)} flights, {segments} segments "
          f"({os.cpu_count()} cores):")
    print(f"  1 worker : median {one:.2f} s  {[round(t, 2) for t in times[1]]}")
    print(f"  2 workers: median {two:.2f} s  {[round(t, 2) for t in times[2]]}")
    print(f"  speed-up 2 vs 1: {one / two:.2f}x (target >= 1.7x)")
    print(f"  load average before {load_before[0]:.2f}, after {load_after[0]:.2f} "
          f"(1-min); other work on the machine takes cores from both")
    if args.keep is None:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
