"""Speed of `sisa process` on a simulated flight, with its time split by stage, beside a baseline.

    .venv/bin/python bench/process_speed.py RUN [--rounds 2] [--baseline REV]

Each round runs `sisa process RUN` as a child process with this checkout's code and, with
`--baseline REV`, with REV's (checked out into a temporary detached `git worktree`, removed
after), alternating, and prints per run the wall time, the CPU time of the process (user + sys,
all its threads) as a share of one core, the load average, and the command's own split by stage
(issue 38: the garrotxa run in half the time of 2026-11-28's 86-88 s, at >= 180 % of a core).
Outputs go to a temporary folder, deleted after each run. Numba's kernels are compiled by a
warm-up run per tree before the first round (a fresh worktree has no cache).
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from baseline import REPO, baseline_tree, rev_of  # bench/baseline.py


def _children_cpu_s() -> float:
    use = resource.getrusage(resource.RUSAGE_CHILDREN)
    return use.ru_utime + use.ru_stime


def run_once(code_root: Path, run: Path) -> dict[str, Any]:
    """One `sisa process RUN` with the code under code_root: wall, CPU, load, its split."""
    env = {**os.environ, "PYTHONPATH": str(code_root), "SISA_PROGRESS_S": "3600"}
    with tempfile.TemporaryDirectory(prefix="process_speed_") as tmp:
        load = os.getloadavg()[0]
        cpu0, t0 = _children_cpu_s(), time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "sisa.cli", "process", str(run), "--out",
                               str(Path(tmp) / "out")], cwd=code_root, env=env,
                              capture_output=True, text=True, check=False)
        wall, cpu = time.perf_counter() - t0, _children_cpu_s() - cpu0
    if done.returncode not in (0, 3):
        raise SystemExit(f"sisa process failed ({done.returncode}): {done.stderr.strip()}")
    lines = done.stdout.splitlines()
    head = next((i for i, ln in enumerate(lines) if ln.strip().startswith("time ")), len(lines))
    return {"wall_s": wall, "cpu_s": cpu, "load": load, "split": lines[head + 1:]}


def show(name: str, r: dict[str, Any]) -> None:
    print(f"{name}: {r['wall_s']:6.1f} s wall, {r['cpu_s']:6.1f} s CPU "
          f"({100 * r['cpu_s'] / r['wall_s']:.0f} % of a core), load {r['load']:.1f}")
    for line in r["split"]:  # the command's stages (its own total line left out)
        print(f"    {line.strip()}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="a run folder of `sisa simulate` (with images)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--baseline", default=None, metavar="REV",
                    help="also time this revision, alternating (e.g. 3492d7e)")
    args = ap.parse_args()
    run = args.run.resolve()
    trees: list[tuple[str, Any]] = [(f"this ({rev_of('HEAD')})", None)]
    with baseline_tree(args.baseline) as base:
        if base is not None:
            trees.append((f"baseline ({rev_of(args.baseline)})", base))
        for _, tree in trees:  # warm-up: numba's caches for each tree
            run_once(tree or REPO, run)
        results: dict[str, list[dict[str, Any]]] = {name: [] for name, _ in trees}
        for k in range(args.rounds):
            order = trees if k % 2 == 0 else trees[::-1]
            for name, tree in order:
                r = run_once(tree or REPO, run)
                results[name].append(r)
                show(f"round {k + 1}, {name}", r)
    print()
    medians = {}
    for name, rs in results.items():
        walls = [r["wall_s"] for r in rs]
        medians[name] = statistics.median(walls)
        print(f"{name}: median {medians[name]:.1f} s wall over {len(rs)} runs "
              f"({', '.join(f'{w:.1f}' for w in walls)})")
    if len(trees) == 2:
        a, b = (medians[n] for n, _ in trees)
        print(f"time ratio this / baseline: {a / b:.2f}")


if __name__ == "__main__":
    main()
