"""Speed of the whole `sisa simulate` command, with where its time goes, beside a baseline.

    .venv/bin/python bench/simulate_speed.py [--preset garrotxa] [--rounds 1]
        [--baseline REV] [--no-split] [--out-dir DIR]

Each round runs `sisa simulate --preset P` (images on) as a child process, once with this
checkout's code and, with `--baseline REV`, once with REV's (checked out into a temporary
detached `git worktree` under /tmp, removed after), alternating, and prints per run:
- the wall time, the CPU time of the process (user + sys, all its threads) and the speed-up over
  real time (target >= 50x for garrotxa: 6 445 s of flight in <= 129 s), and the main thread's
  own CPU time: the event loop's path, what the wall time comes down to on two free cores
  while the scanner renders on its own thread;
- with the split (the default), the time by stage, measured in the same child by wrapping the
  stages' entry points (exclusive wall time: a stage's nested stages are not counted twice),
  plus the recorder's background thread (its CPU time). The wrappers cost ~0.3 us a call, a few
  seconds on garrotxa's ~9 M calls (`--no-split` runs without them). `~CPU s` is a stage's
  share of the main thread's wall time times that thread's CPU time: per-call CPU clocks
  cost 1.4 us a call here, and on a loaded machine every stage waits for a core alike. The
  rendering, on its own thread, is shown apart (its wall time).
The load average is printed beside every run: on a shared machine compare runs of one round.
Outputs go to a temporary folder (or --out-dir) and are deleted after each run. Each tree's
numba kernels are compiled by a warm-up before the first round (a fresh worktree has no cache).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from baseline import REPO, baseline_tree, rev_of  # bench/baseline.py

# stage → the (module, class or None, function) entry points timed as that stage
STAGES: dict[str, list[tuple[str, str | None, str]]] = {
    "terrain + survey files": [("sisa.wiring.simulation", None, "write_survey_data"),
                               ("emulators.terrain", "Terrain", "from_scenario")],
    "trajectory + scene": [("emulators.system", "EmulatedSystem", "__init__")],
    "rendering": [("emulators.render", "LineRenderer", "render")],
    "waiting for rendered lines": [("emulators.scanner", "_Lines", "get")],
    "image files": [("emulators.scanner", "BilSegmentWriter", "__init__"),
                    ("emulators.scanner", "BilSegmentWriter", "append"),
                    ("emulators.scanner", "BilSegmentWriter", "close")],
    "wiring (wires, host clock)": [("sisa.wiring.simulation", "VirtualWiring", "__call__"),
                                   ("sisa.wiring.simulation", "VirtualWiring", "finish")],
    "acquisition (decoding)": [("acquisition.runner", "Acquisition", name) for name in (
        "on_gps_bytes", "on_scanner_bytes", "on_camera_bytes", "on_can_frame",
        "on_can_frames", "on_edge", "tick", "finish")],
    "sync filter": [("acquisition.syncfilter", "SyncFilter", name) for name in (
        "on_pps", "on_gps_time", "on_ppf", "on_camera", "on_header", "tick")],
    "recorder (calls)": [("recorder.writer", "FlightRecorder", name) for name in (
        "__init__", "write", "close")],
    "truth files": [("emulators.system", "EmulatedSystem", "write_truth")],
    "emulation (devices, runner)": [("emulators.runtime", "Runner", "run")],
}


class Split:
    """Exclusive wall time by stage: the time inside a wrapped call, less its nested ones."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = dict.fromkeys(STAGES, 0.0)
        self.calls: dict[str, int] = dict.fromkeys(STAGES, 0)
        self._stack: list[list[float]] = []  # per open call: [nested seconds]
        self._main = threading.main_thread()
        self.flush_thread_cpu_s = 0.0
        self.off_main_s: dict[str, float] = {}  # stages run on other threads (wall)

    def wrap(self, stage: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        stack, seconds, calls, clock = self._stack, self.seconds, self.calls, time.perf_counter
        main, off_main = self._main, self.off_main_s

        def timed(*args: Any, **kwargs: Any) -> Any:
            if threading.current_thread() is not main:  # (the render-ahead thread)
                t0 = clock()
                try:
                    return fn(*args, **kwargs)
                finally:
                    off_main[stage] = off_main.get(stage, 0.0) + clock() - t0
            frame = [0.0]
            stack.append(frame)
            t0 = clock()
            try:
                return fn(*args, **kwargs)
            finally:
                took = clock() - t0
                stack.pop()
                seconds[stage] += took - frame[0]
                calls[stage] += 1
                if stack:
                    stack[-1][0] += took

        return timed

    def install(self) -> None:
        for stage, points in STAGES.items():
            for module_name, cls_name, fn_name in points:
                module = importlib.import_module(module_name)
                owner = getattr(module, cls_name, None) if cls_name else module
                fn = (getattr(owner, "__dict__", {}).get(fn_name) if cls_name
                      else getattr(module, fn_name, None))
                if fn is None:  # (a baseline without this entry point)
                    continue
                if isinstance(fn, classmethod):
                    setattr(owner, fn_name, classmethod(self.wrap(stage, fn.__func__)))
                else:
                    setattr(owner, fn_name, self.wrap(stage, fn))
        self._wrap_flush_loop()

    def _wrap_flush_loop(self) -> None:
        from recorder.writer import FlightRecorder
        loop = FlightRecorder.__dict__.get("_flush_loop")
        if loop is None:
            return
        split = self

        def timed_loop(rec: Any) -> None:
            c0 = time.thread_time()
            try:
                loop(rec)
            finally:
                split.flush_thread_cpu_s += time.thread_time() - c0

        setattr(FlightRecorder, "_flush_loop", timed_loop)  # noqa: B010 (a bench patch)


def child(argv: list[str], split: bool) -> None:
    """Run the command in this process; print one JSON line with what it cost."""
    timing = Split() if split else None
    if timing is not None:
        timing.install()
    from sisa.cli import main
    t0 = time.perf_counter()
    code = main(argv, batch_gc=True)
    wall = time.perf_counter() - t0
    out: dict[str, object] = {"code": code, "command_wall_s": wall,
                              "main_thread_cpu_s": time.thread_time()}
    if timing is not None:
        out["stages_s"] = timing.seconds
        out["calls"] = timing.calls
        out["recorder_thread_cpu_s"] = timing.flush_thread_cpu_s
        out["off_main_s"] = timing.off_main_s
    print("SIMULATE_SPEED " + json.dumps(out), flush=True)


def warm() -> None:
    """Compile (into the tree's numba cache) the kernels a simulation uses: a fresh
    worktree's first run would otherwise count their compilation."""
    import numpy as np

    from emulators.render import LineRenderer
    from emulators.scenario import load_scenario
    from emulators.terrain import Scene, Terrain
    from emulators.trajectory import TruthTrajectory
    scn = load_scenario("bench")
    traj = TruthTrajectory.from_scenario(scn)
    terrain = Terrain.from_scenario(scn)
    renderer = LineRenderer(scn.scanner, scn.mounting, terrain, Scene.from_scenario(scn, terrain),
                            np.random.default_rng(0))
    renderer.render(traj.state(np.array([traj.strips[0].t_start_ns], dtype=np.int64)))


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def run_once(code_root: Path, preset: str, out_root: Path, split: bool) -> dict[str, Any]:
    """One child run of the command on `code_root`'s code: its figures."""
    out = out_root / f"run-{os.getpid()}-{time.monotonic_ns()}"
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", "--preset", preset,
           "--out", str(out)] + ([] if split else ["--no-split"])
    env = {**os.environ, "PYTHONPATH": str(code_root)}
    load_before = _load()
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, cwd=code_root, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    stdout, stderr = proc.communicate()
    wall = time.perf_counter() - t0
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file()) if out.exists() else 0
    shutil.rmtree(out, ignore_errors=True)
    line = next((s for s in stdout.splitlines() if s.startswith("SIMULATE_SPEED ")), None)
    if proc.returncode != 0 or line is None:
        raise SystemExit(f"the run on {code_root} failed (exit {proc.returncode}):\n{stdout}"
                         + "\n".join(stderr.splitlines()[-30:]))
    result: dict[str, Any] = json.loads(line.removeprefix("SIMULATE_SPEED "))
    result.update(wall_s=wall, load_before=load_before, load_after=_load(), out_bytes=size)
    summary = next((s for s in stdout.splitlines() if "s of flight in" in s), "")
    result["summary"] = summary
    return result


def _flight_s(summary: str) -> float | None:
    try:
        return float(summary.split(", ")[1].split(" s of flight")[0])
    except (IndexError, ValueError):
        return None


def report(name: str, r: dict[str, Any], cpu_s: float) -> None:
    flight = _flight_s(r["summary"])
    factor = f"{flight / r['wall_s']:.1f}x real time" if flight else "?"
    main_cpu = r.get("main_thread_cpu_s")
    critical = (f" (main thread {main_cpu:.1f} s = {flight / main_cpu:.1f}x)"
                if main_cpu and flight else "")
    print(f"{name}: wall {r['wall_s']:.1f} s (command {r['command_wall_s']:.1f} s) = {factor}; "
          f"CPU {cpu_s:.1f} s{critical}; load {r['load_before']} -> {r['load_after']}; "
          f"outputs {r['out_bytes'] / 1e6:.0f} MB")
    if "stages_s" in r:
        total = r["command_wall_s"]
        stages = dict(r["stages_s"])
        stages["other (start-up, imports, ...)"] = total - sum(stages.values())
        print(f"    {'stage':30s} {'wall s':>8s} {'share':>6s} {'~CPU s':>7s}  calls")
        per_cpu = main_cpu or cpu_s
        for stage, s in sorted(stages.items(), key=lambda kv: -kv[1]):
            share = s / total
            print(f"    {stage:30s} {s:8.1f} {100 * share:5.1f}% {share * per_cpu:7.1f}  "
                  f"{r['calls'].get(stage, '')}")
        print(f"    {'recorder thread (its CPU)':30s} {r['recorder_thread_cpu_s']:8.1f}")
        for stage, s in r.get("off_main_s", {}).items():
            print(f"    {stage + ' (own thread)':30s} {s:8.1f}  (wall, beside the main thread)")


def _children_cpu_s() -> float:
    import resource
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--preset", default="garrotxa")
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument("--baseline", help="a git revision to run beside this checkout")
    parser.add_argument("--baseline-first", action="store_true",
                        help="round 1 runs the baseline first (then alternating)")
    parser.add_argument("--no-split", action="store_true", help="no stage wrappers")
    parser.add_argument("--out-dir", type=Path, default=None,
                        help="where the runs write (deleted after each); default a temp dir")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--warm", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--out", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.warm:
        warm()
        return
    if args.child:
        child(["simulate", "--preset", args.preset, "--out", args.out], not args.no_split)
        return
    print(f"sisa simulate --preset {args.preset}, {time.strftime('%Y-%m-%d %H:%M', time.gmtime())}"
          f" UTC, {os.cpu_count()} CPUs, HEAD {rev_of('HEAD')}")
    with contextlib.ExitStack() as stack:
        out_root = args.out_dir or Path(stack.enter_context(tempfile.TemporaryDirectory()))
        trees = [("this", REPO)]
        if args.baseline:
            base = stack.enter_context(baseline_tree(args.baseline))
            assert base is not None  # a REV was given
            trees.append((f"baseline {rev_of(args.baseline)}", base))
        for _, root in trees:
            subprocess.run([sys.executable, str(Path(__file__).resolve()), "--warm"], check=True,
                           env={**os.environ, "PYTHONPATH": str(root)}, cwd=root)
        for rnd in range(args.rounds):
            order = trees if (rnd + args.baseline_first) % 2 == 0 else trees[::-1]
            for name, root in order:
                c0 = _children_cpu_s()
                r = run_once(root, args.preset, out_root, not args.no_split)
                report(f"round {rnd + 1} {name}", r, _children_cpu_s() - c0)


if __name__ == "__main__":
    main()
