"""Soak: a long real-time desk test at k× nominal device rates with random faults, then the books.

    .venv/bin/python bench/soak.py [--minutes 60] [--scale 10] [--seed 1] [--out runs/soak]

One continuous `sisa bench` (`sisa emulate` and `sisa record` as separate processes on ptys,
SLCAN and the loopback pulse link, in real time) on the `bench` block made long enough for
`--minutes` (more strips, longer strips), with every device rate times `--scale` (INS records,
NMEA epochs up to 20 Hz, scanner lines) and random faults drawn from `--seed`: lost and
spurious pulses, corrupt and lost serial bytes, lost and corrupt CAN frames, dropped scanner
frames all the way through, plus PPS outages, INS clock jumps, an INS reboot and sync-program
restarts at random moments. The recorder's CPU and memory are sampled every 30 s.

Then the books, per stream, from the emulator's truth (what it sent and every fault it
injected) against the log:
- missing = sent − logged; a message may only be missing because an injected fault destroyed
  it (`unaccounted = missing − injected`, must be ≤ 0), and the recorder must have counted at
  least one decode error or drop for each missing message;
- pulse edges: logged = sent − injected losses + injected spurious pulses, exactly;
- `sisa sync` on the log: every INS record and scan line timed correctly (an OK time off by
  more than 10 µs is a wrong tag, none allowed) or flagged with a reason, counted per reason.
"""

from __future__ import annotations

import argparse
import functools
import json
import re
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from emulators.scenario import scenario_from_table
from emulators.trajectory import TruthTrajectory
from emulators.truth import read_truth_csv
from postproc.sync import TimeStatus, read_sync_input, synchronise
from recorder.columns import read_columns
from recorder.messages import FrameHeaderLog, GpsFix, InsRecordLog, StreamHealth, Topic
from recorder.reader import read_messages
from sisa.core.timescale import NS_PER_S

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from acquisition_headroom import proc_cpu_s_rss_mb, scaled_table  # noqa: E402  (bench/ is the script's dir)

from tests.postproc.test_sync import WRONG_NS, ins_truth_ns  # noqa: E402

# the books, the line join and the jump spans read the same (large) truth tables: once each
truth_table = functools.cache(read_truth_csv)


def soak_table(minutes: float, scale: float, seed: int) -> dict[str, Any]:
    """The bench block made long enough, rates × scale, random faults over the whole flight."""
    rng = np.random.default_rng(seed)
    seconds = minutes * 60
    table = {**scaled_table(scale), "seed": seed}
    strips = 2
    while True:  # enough strips (of 12 km) that the flight outlasts the soak
        table["block"] = {"strips": strips, "strip_length_m": 12_000.0}
        traj = TruthTrajectory.from_scenario(scenario_from_table(table))
        if (traj.t_end_ns - traj.t_start_ns) / 1e9 >= seconds + 30:
            break
        strips += 2

    def at(n: int) -> list[float]:  # after take-off, before the end
        return sorted(float(t) for t in rng.uniform(min(90.0, 0.3 * seconds), 0.9 * seconds, n))

    table["faults"] = {
        "lost_pulse_fraction": 0.002,
        "spurious_pulse_rate_hz": 0.02,
        "corrupt_byte_rate": 2e-6,
        "lost_byte_rate": 2e-6,
        "lost_can_frame_fraction": 2e-5,
        "corrupt_can_frame_fraction": 2e-5,
        "dropped_frame_fraction": 2e-4,
        "pps_outages": [{"at_s": t, "duration_s": float(rng.uniform(10, 60))} for t in at(2)],
        "ins_clock_jumps": [{"at_s": t, "jump_ms": float(rng.choice([-1, 1])
                                                          * 10 ** rng.uniform(-1.3, 3))}
                            for t in at(2)],
        "ins_reboots": [{"at_s": t, "duration_s": float(rng.uniform(3, 10))} for t in at(1)],
        "sync_restarts": [{"at_s": t, "duration_s": float(rng.uniform(1, 5))} for t in at(2)],
    }
    return table


class Sampler:
    """CPU % and RSS of `sisa record` or `sisa emulate` (`role`) every `period_s` (found by the
    run's path in its command line)."""

    def __init__(self, run: Path, role: str, period_s: float = 30.0) -> None:
        self.run_name, self.period_s = run.name.encode(), period_s  # staged as .NAME.partial-*
        self.role = role.encode()
        self.samples: list[tuple[float, float, float]] = []  # (t_s, cpu %, rss MB)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _pid(self) -> int | None:
        for d in Path("/proc").iterdir():
            if d.name.isdigit():
                try:
                    cmd = (d / "cmdline").read_bytes().split(b"\0")
                except OSError:
                    continue
                if self.role in cmd[:4] and any(self.run_name in a for a in cmd):
                    return int(d.name)
        return None

    def _run(self) -> None:
        t0 = time.monotonic()
        pid, last = None, None
        while not self._stop.wait(1.0 if pid is None else self.period_s):
            try:
                pid = pid or self._pid()
                if pid is None:
                    continue
                cpu_s, rss_mb = proc_cpu_s_rss_mb(pid)
            except (OSError, IndexError, ValueError):
                pid, last = None, None  # the recorder ended
                continue
            now = time.monotonic()
            if last is not None:
                self.samples.append((now - t0, 100 * (cpu_s - last[1]) / (now - last[0]), rss_mb))
            last = (now, cpu_s)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


def truth_positions(truth_keys: list[Any], logged_keys: list[Any]) -> np.ndarray:
    """Index in the truth of every logged item, walking both in order (counters wrap, so a key
    is looked for only after the previous one's place)."""
    out = np.empty(len(logged_keys), np.int64)
    i = 0
    for j, key in enumerate(logged_keys):
        while i < len(truth_keys) and truth_keys[i] != key:
            i += 1
        if i == len(truth_keys):
            raise SystemExit(f"logged {key} is not in the truth (or out of order)")
        out[j] = i
        i += 1
    return out


def in_order(truth_keys: list[Any], logged_keys: list[Any]) -> tuple[int, int, int]:
    """(first, last) truth index of the logged items and how many truth items between them
    were not logged."""
    pos = truth_positions(truth_keys, logged_keys)
    if pos.size == 0:
        return 0, -1, 0
    return int(pos[0]), int(pos[-1]), int(pos[-1] - pos[0] + 1) - pos.size


def books(run: Path) -> dict[str, Any]:
    """Sent (truth) against logged, per stream, over the span the recorder was listening, with
    the injected faults that explain a gap."""
    truth = run / "truth"
    flight = run / "flight.mcap"
    faults = truth_table(truth / "faults.csv")
    kinds, targets = faults["kind"].astype(str), faults["target"].astype(str)
    fault_t = faults["t_gps_ns"].astype(np.int64)
    last = {h.stream: h for h in read_messages(flight, StreamHealth) if not h.event}
    out: dict[str, Any] = {}

    def row(name: str, stream: str, sent: int, missing: int, t0: int, t1: int,
            fault_kinds: tuple[str, ...], target: str | None) -> None:
        sel = np.isin(kinds, fault_kinds) & (fault_t >= t0) & (fault_t <= t1)
        if target is not None:
            sel &= targets == target
        counted = last[stream].checksum_errors + last[stream].framing_errors + last[stream].drops
        out[name] = {"sent": sent, "logged": sent - missing, "missing": missing,
                     "injected": int(sel.sum()), "unaccounted": max(0, missing - int(sel.sum())),
                     "recorder_counted": counted, "noticed": missing <= counted}

    ins = truth_table(truth / "ins_records.csv")
    ins_keys = list(zip(ins["counter"].tolist(), ins["ins_time_ticks"].tolist(), strict=True))
    logged = [(r.counter, r.ins_time_ticks) for r in read_messages(flight, InsRecordLog)]
    first, lst, missing = in_order(ins_keys, logged)
    t_out = ins["t_out_gps_ns"]
    row("ins_records", "ins", lst - first + 1, missing, int(t_out[first]), int(t_out[lst]),
        ("lost_can_frame", "corrupt_can_frame"), None)

    frames = truth_table(truth / "frames.csv")
    sent_frames = frames["dropped"] == 0
    keys = list(zip(frames["segment"][sent_frames].tolist(),
                    frames["frame_counter"][sent_frames].tolist(), strict=True))
    logged = [(h.segment, h.frame_counter) for h in read_messages(flight, FrameHeaderLog)]
    first, lst, missing = in_order(keys, logged)
    t_mid = frames["t_mid_gps_ns"][sent_frames]
    if logged:
        row("frame_headers", "scanner", lst - first + 1, missing, int(t_mid[first]),
            int(t_mid[lst]) + NS_PER_S, ("corrupt_byte", "lost_byte"), "scanner")

    fixes_t = truth_table(truth / "gps_fixes.csv")["t_gps_ns"].tolist()
    logged_fixes = [f.t_gps_ns for f in read_messages(flight, GpsFix)]
    first, lst, missing = in_order(fixes_t, logged_fixes)
    row("gps_fixes", "gps", lst - first + 1, missing, int(fixes_t[first]),
        int(fixes_t[lst]) + NS_PER_S, ("corrupt_byte", "lost_byte"), "gps")

    # pulse edges: the timing board numbers each line's edges; a gap is an edge the recorder
    # never got (pulses lost or added at the source are not on the link)
    edges = read_columns(flight, Topic.PULSE_IN)
    for line in ("PPS", "PPF"):
        seq = np.sort(edges["link_seq"][edges["line"].astype(str) == line].astype(np.int64))
        out[f"{line.lower()}_edges"] = {
            "logged": int(seq.size), "duplicates": int((np.diff(seq) == 0).sum()),
            "unaccounted": int((np.diff(seq) - 1).clip(0).sum()) if seq.size else 0}
    out["recorder"] = {s: {"drops": h.drops, "deadline_misses": h.deadline_misses,
                           "checksum_errors": h.checksum_errors,
                           "framing_errors": h.framing_errors, "gaps": h.gaps}
                       for s, h in last.items()}
    out["faults_injected"] = {k: int((kinds == k).sum()) for k in sorted(set(kinds))}
    return out


def line_truth_ns(run: Path, segment: Any, counter: Any) -> Any:
    """True mid-exposure of every timed line, its (segment, frame counter) walked through the
    frames the scanner sent (without the scanner's lines files the log's line numbers skip
    lost headers, so they cannot be the join)."""
    fr = truth_table(run / "truth" / "frames.csv")
    sent = fr["dropped"] == 0
    keys = list(zip(fr["segment"][sent].tolist(), fr["frame_counter"][sent].tolist(),
                    strict=True))
    logged = list(zip(segment.tolist(), counter.tolist(), strict=True))
    return fr["t_mid_gps_ns"][sent][truth_positions(keys, logged)]


def unrevealed_jump_spans_ns(run: Path) -> list[tuple[int, int]]:
    """GPS spans from each injected INS clock jump to the first pulse the INS latched after it
    (or its next reboot, whichever is first). No pulse reveals a jump there, so no solver can
    know the records in the span moved: the sync leaves them untimed (insrecords: records are
    timed only between two latches), and a wrong tag there is still a wrong tag (counted
    apart as well, to say where it was)."""
    faults = truth_table(run / "truth" / "faults.csv")
    jumps = faults["t_gps_ns"][faults["kind"].astype(str) == "ins_clock_jump"].astype(np.int64)
    ins = truth_table(run / "truth" / "ins_records.csv")
    t, boot = ins["t_meas_gps_ns"].astype(np.int64), ins["boot"].astype(np.int64)
    latched = ins["sync_pulse_gps_ns"].astype(np.int64)
    spans = []
    for t_jump in jumps.tolist():
        at = int(np.searchsorted(t, t_jump))
        if at >= t.size:
            continue
        same_boot = boot[at:] == boot[at]
        revealed = latched[at:][same_boot & (latched[at:] > t_jump)]
        end = int(revealed.min()) if revealed.size else int(t[at:][same_boot].max()) + 1
        spans.append((int(t_jump), end))
    return spans


def sync_check(run: Path) -> dict[str, Any]:
    """`sisa sync`'s core on the log: wrong tags (none allowed; those in a stretch no pulse
    could reveal also counted apart) and flagged items per reason."""
    inp = read_sync_input(run / "flight.mcap")
    res = synchronise(inp)
    spans = unrevealed_jump_spans_ns(run)
    out: dict[str, Any] = {}
    for name, t, status, truth in (
            ("ins_records", res.ins.t_gps_ns, res.ins.status, ins_truth_ns(run, inp)),
            ("lines", res.lines.t_gps_ns, res.lines.status,
             line_truth_ns(run, res.lines.segment, res.lines.frame_counter))):
        ok = status == TimeStatus.OK
        err = np.abs(t[ok] - truth[ok])
        hidden = np.zeros(err.size, dtype=bool)
        if name == "ins_records":
            for lo, hi in spans:
                hidden |= (truth[ok] >= lo) & (truth[ok] < hi)
        wrong = err > WRONG_NS
        reasons = {TimeStatus(s).name.lower(): int((status == s).sum())
                   for s in np.unique(status[~ok])}
        out[name] = {"logged": int(status.size), "ok": int(ok.sum()),
                     "wrong": int(wrong.sum()),
                     "wrong_past_unrevealed_jump": int((wrong & hidden).sum()),
                     "max_error_ns": int(err[~hidden].max()) if (~hidden).any() else 0,
                     "rms_error_ns": float(np.sqrt(np.mean(err[~hidden].astype(float) ** 2)))
                     if (~hidden).any() else 0.0, "flagged": reasons}
    out["unrevealed_jump_spans_s"] = [round((hi - lo) / 1e9, 3) for lo, hi in spans]
    return out


def report(out: Path, head: dict[str, Any]) -> int:
    """Books and sync check of the run in `out`; prints and writes soak_report.json."""
    rep = {**head, "books": books(out), "sync": sync_check(out)}
    (out / "soak_report.json").write_text(json.dumps(rep, indent=1), encoding="utf-8")
    print(json.dumps(rep, indent=1))
    b, s = rep["books"], rep["sync"]
    unaccounted = sum(max(0, v["unaccounted"]) for v in b.values()
                      if isinstance(v, dict) and "unaccounted" in v)
    unnoticed = sum(1 for v in b.values() if isinstance(v, dict) and v.get("noticed") is False)
    wrong = s["ins_records"]["wrong"] + s["lines"]["wrong"]
    print(f"soak: unaccounted losses {unaccounted}, streams with uncounted losses {unnoticed}, "
          f"wrong tags {wrong} (of them {s['ins_records']['wrong_past_unrevealed_jump']} INS "
          f"records past a clock jump no pulse revealed); lines OK {s['lines']['ok']}/"
          f"{s['lines']['logged']} (flagged "
          f"{s['lines']['flagged']}), INS records OK {s['ins_records']['ok']}/"
          f"{s['ins_records']['logged']} (flagged {s['ins_records']['flagged']})")
    return 0 if unaccounted == 0 and unnoticed == 0 and wrong == 0 else 1


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=60.0)
    parser.add_argument("--scale", type=float, default=10.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "soak")
    parser.add_argument("--books-only", action="store_true",
                        help="only the books and the sync check of the existing run in --out")
    args = parser.parse_args()
    if args.books_only:
        return report(args.out, {"books_only": True})
    if args.out.exists():
        raise SystemExit(f"{args.out} exists: give a new --out")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    scenario = args.out.with_name(args.out.name + "-scenario.toml")
    table = soak_table(args.minutes, args.scale, args.seed)
    scenario.write_text(tomli_w.dumps(table), encoding="utf-8")
    print(f"soak: {args.minutes:g} min of sisa bench at {args.scale:g}x nominal rates "
          f"({table['block']['strips']} strips of 12 km), faults from seed {args.seed}: "
          f"{json.dumps(table['faults'])}", flush=True)
    sampler, emulator = Sampler(args.out, "record"), Sampler(args.out, "emulate")
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "sisa.cli", "bench", "--scenario",
                           str(scenario), "--out", str(args.out), "--no-images", "--duration",
                           str(args.minutes * 60)], capture_output=True, text=True)
    wall_s = time.monotonic() - t0
    sampler.stop()
    emulator.stop()
    print(proc.stdout.strip(), proc.stderr.strip()[-2000:], sep="\n", flush=True)
    if proc.returncode != 0:
        print(f"sisa bench exited {proc.returncode}")
        return 1
    summary = re.search(r"recorded .*", proc.stdout)
    cpu = np.array([x[1] for x in sampler.samples])
    rss = np.array([x[2] for x in sampler.samples])
    return report(args.out, {
        "minutes": args.minutes, "scale": args.scale, "seed": args.seed, "wall_s": wall_s,
        "recorder_summary": summary.group(0) if summary else None,
        "recorder_cpu_pct": {"median": float(np.median(cpu)), "max": float(cpu.max())}
        if cpu.size else None,
        "recorder_rss_mb": {"first": float(rss[0]), "last": float(rss[-1]),
                            "max": float(rss.max())} if rss.size else None,
        "emulator_rss_mb": {"first": emulator.samples[0][2], "last": emulator.samples[-1][2]}
        if emulator.samples else None})


if __name__ == "__main__":
    sys.exit(main())
