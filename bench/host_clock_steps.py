"""Logs recorded on a host clock that stepped: found, taken out, never a wrong time.

    .venv/bin/python bench/host_clock_steps.py [--flights 12] [--variants 6] [--first-seed 5000]

`sisa record` stamps receive times on a clock that never steps (acquisition.clocks), but a log
written on the system clock (an older recorder, another logger) carries every step chrony,
a leap second or an operator made in flight. Each flight is the fault sweep's short bench
flight with a drawn fault mix (`fault_sweep.draw_mix`; every other flight fault-free), simulated
once; its log is then read with 1–3 steps put into every host receive time from a random moment
on (sizes log-uniform from 25 ms to 1 h, either sign; `--variants` such logs a flight), as a
recorder on a stepping clock would have logged them. Each is synchronised and compared with the
truth and with the same log unstepped.

Printed per flight and variant: the steps put in and those found, INS records and scan lines
timed against the unstepped log, and wrong tags (`ok` but more than 5 µs off). Exits 1 on any
wrong tag, and on any step found in an unstepped log.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from emulators.scenario import scenario_from_table
from postproc.sync import SyncInput, TimeStatus, read_sync_input, synchronise
from sisa.wiring.simulation import simulate
from tests.postproc.test_sync import ins_truth_ns, line_truth_ns, ok_errors_ns
from tests.postproc.test_sync_faults import SHORT
from tests.postproc.test_sync_faults import _merge as merged
from tests.postproc.test_sync_host_steps import stepped

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fault_sweep import draw_mix, scanner_lines

WRONG_NS = 5_000


def draw_steps(rng: np.random.Generator, t0_ns: int, t1_ns: int) -> list[tuple[int, int]]:
    n = int(rng.integers(1, 4))
    at = np.sort(rng.uniform(t0_ns, t1_ns, n)).astype(np.int64)
    size_ms = 10 ** rng.uniform(np.log10(25.0), np.log10(3.6e6), n) * rng.choice([-1, 1], n)
    return [(int(a), round(s * 1e6)) for a, s in zip(at, size_ms, strict=True)]


def judged(run: Path, inp: SyncInput, truth: np.ndarray) -> dict[str, Any]:
    res = synchronise(inp, scanner_lines(run))
    e_ins = ok_errors_ns(res.ins.t_gps_ns, res.ins.status, truth)
    e_line = ok_errors_ns(res.lines.t_gps_ns, res.lines.status, line_truth_ns(run, res))
    return {"ins": int(np.count_nonzero(res.ins.status == TimeStatus.OK)),
            "lines": int(e_line.size),
            "wrong": int(np.count_nonzero(np.abs(e_ins) > WRONG_NS)
                         + np.count_nonzero(np.abs(e_line) > WRONG_NS)),
            "found": [s["step_ms"] for s in res.report["host_clock_steps"]]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flights", type=int, default=12)
    ap.add_argument("--variants", type=int, default=6)
    ap.add_argument("--first-seed", type=int, default=5000)
    args = ap.parse_args()
    wrong = false_steps = variants = 0
    same_ins = same_lines = 0
    for seed in range(args.first_seed, args.first_seed + args.flights):
        rng = np.random.default_rng(seed)
        mix = draw_mix(rng) if seed % 2 else {}
        table = merged({"base": "bench", "seed": seed, **SHORT}, mix)
        with tempfile.TemporaryDirectory(prefix="host_steps_") as tmp:
            run = Path(tmp)
            simulate(scenario_from_table(table), run, images=False)
            inp = read_sync_input(run / "flight.mcap")
            truth = ins_truth_ns(run, inp, unknown_ok=True)
            base = judged(run, inp, truth)
            false_steps += len(base["found"])
            wrong += base["wrong"]
            faults = ",".join(sorted(mix.get("faults", {}))) or "no faults"
            print(f"seed {seed} ({faults}): unstepped INS {base['ins']}, lines {base['lines']}, "
                  f"wrong {base['wrong']}, steps found {base['found']}", flush=True)
            t0, t1 = int(inp.ins.t_host_ns[0]), int(inp.ins.t_host_ns[-1])
            for _ in range(args.variants):
                steps = draw_steps(rng, t0, t1)
                got = judged(run, stepped(inp, steps), truth)
                variants += 1
                wrong += got["wrong"]
                same_ins += got["ins"] == base["ins"]
                same_lines += got["lines"] == base["lines"]
                put = [round(s / 1e6, 3) for _, s in steps]
                at = [round((a - t0) / 1e9, 1) for a, _ in steps]
                print(f"    steps {put} ms at {at} s: found {got['found']}; INS {got['ins']} "
                      f"({got['ins'] - base['ins']:+d}), lines {got['lines']} "
                      f"({got['lines'] - base['lines']:+d}), wrong {got['wrong']}", flush=True)
    print(f"{variants} stepped logs of {args.flights} flights: wrong tags {wrong}; as many INS "
          f"records timed as unstepped in {same_ins}, as many lines in {same_lines}; steps found "
          f"in the unstepped logs: {false_steps}")
    if wrong or false_steps:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
