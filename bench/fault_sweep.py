"""Wrong time tags under random mixes of faults: flights the fault matrix never flies.

    .venv/bin/python bench/fault_sweep.py [--runs 40] [--first-seed 1000] [--out runs/fault_sweep]
                                          [--wide] [--vary-ins] [--vary-devices]

The fault matrix in the tests flies one fault at a time on two seeds. Here every run draws its
own mix from the seed: the receiver (Z-12, F9P, OEM7), the LFSR length (4–7 bits), 1-of-n
(1–8) with a receiver event rate the link can carry, counter widths, the INS clock drift,
and, each with its own odds, lost and spurious pulses (spurious ones sometimes right next to
the PPS edge), corrupt and lost bytes, lost and corrupt CAN frames, dropped scanner frames, a
PPS outage, INS clock jumps, an INS reboot and a sync restart, at random moments. A mix the
scenario refuses (a link that cannot carry its tags) is redrawn. The flight is the fault
matrix's short bench flight (~230 s, two strips); `sisa simulate`'s path (virtual time), then
`postproc.sync.synchronise` on the log, against the truth.

Printed per run: the mix, INS records and scan lines timed, and those timed `ok` but off by
more than 5 µs (wrong tags). The sum of wrong tags over every run must be 0: a wrong time
marked ok is the failure the sync exists to prevent. Flagged rows are not errors, but a run
that times under 99 % is listed so it can be looked at. A host clock step found in a log (whose
recorder's clock never steps) is a false one and fails the sweep too.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from emulators.scenario import Scenario, scenario_from_table
from emulators.truth import read_truth_csv
from postproc.sync import TimeStatus, read_sync_input, synchronise
from postproc.sync.lines import LineTable
from sisa.core.errors import ConfigError
from sisa.wiring.simulation import header_transit_ms, simulate
from tests.postproc.test_sync import ins_truth_ns, line_truth_ns, ok_errors_ns
from tests.postproc.test_sync_faults import SHORT  # the fault matrix's short flight
from tests.postproc.test_sync_faults import _merge as merged

WRONG_NS = 5_000
MISSTATED_COVER = 0.2  # a header window covering less of the headers' latency range: misstated
FLIGHT_S = 220.0  # faults are placed inside the short flight


# a rate fault: its key, the odds it is drawn, how its value is drawn, and the fault it is
# drawn only beside (None: any mix)
RateDraw = tuple[str, float, Callable[[np.random.Generator], float], str | None]


def _uniform(lo: float, hi: float, digits: int) -> Callable[[np.random.Generator], float]:
    return lambda rng: round(float(rng.uniform(lo, hi)), digits)


def _one_of(*values: float) -> Callable[[np.random.Generator], float]:
    return lambda rng: float(rng.choice(list(values)))


RATES: tuple[RateDraw, ...] = (
    ("lost_pulse_fraction", 0.5, _uniform(0.0, 0.1, 4), None),
    ("spurious_pulse_rate_hz", 0.5, _uniform(0.0, 3.0, 3), None),
    ("spurious_pps_near_second_ms", 0.4, _uniform(0.2, 3.0, 3), "spurious_pulse_rate_hz"),
    ("corrupt_byte_rate", 0.3, _one_of(1e-4, 2e-4, 5e-4), None),
    ("lost_byte_rate", 0.2, _one_of(1e-4, 2e-4), None),
    ("lost_can_frame_fraction", 0.2, _uniform(0.0, 0.01, 4), None),
    ("corrupt_can_frame_fraction", 0.2, _uniform(0.0, 0.01, 4), None),
    ("dropped_frame_fraction", 0.3, _uniform(0.0, 0.05, 4), None),
)
WIDE_RATES: tuple[RateDraw, ...] = (  # several times higher
    ("lost_pulse_fraction", 0.6, _uniform(0.0, 0.3, 4), None),
    ("spurious_pulse_rate_hz", 0.6, _uniform(0.0, 10.0, 3), None),
    ("spurious_pps_near_second_ms", 0.5, _uniform(0.05, 5.0, 3), "spurious_pulse_rate_hz"),
    ("corrupt_byte_rate", 0.4, _one_of(5e-4, 1e-3, 3e-3), None),
    ("lost_byte_rate", 0.3, _one_of(5e-4, 1e-3), None),
    ("lost_can_frame_fraction", 0.3, _uniform(0.0, 0.05, 4), None),
    ("corrupt_can_frame_fraction", 0.3, _uniform(0.0, 0.05, 4), None),
    ("dropped_frame_fraction", 0.4, _uniform(0.0, 0.2, 4), None),
)


def draw_rates(rng: np.random.Generator, table: tuple[RateDraw, ...]) -> dict[str, Any]:
    """The rate faults of one mix, each with its own odds, drawn in the table's order (a seed
    draws the same mix as long as the table stays the same)."""
    faults: dict[str, Any] = {}
    for key, odds, draw, beside in table:
        if beside is not None and beside not in faults:
            continue
        if rng.random() < odds:
            faults[key] = draw(rng)
    return faults


def draw_mix(rng: np.random.Generator) -> dict[str, Any]:
    """One random scenario overlay: settings and faults."""
    def maybe(p: float) -> bool:
        return bool(rng.random() < p)

    def at() -> float:
        return round(float(rng.uniform(25.0, FLIGHT_S)), 2)

    faults = draw_rates(rng, RATES)
    if maybe(0.3):
        faults["pps_outages"] = [{"at_s": at(), "duration_s": round(float(rng.uniform(5, 60)),
                                                                     1)}]
    if maybe(0.3):
        faults["ins_clock_jumps"] = [
            {"at_s": at(), "jump_ms": round(float(rng.choice([-1, 1]) * 10 ** rng.uniform(
                -1.5, 3.0)), 4)} for _ in range(int(rng.integers(1, 3)))]
    if maybe(0.15):
        faults["ins_reboots"] = [{"at_s": at(), "duration_s": round(float(rng.uniform(1, 8)),
                                                                     1)}]
    if maybe(0.15):
        faults["sync_restarts"] = [{"at_s": at(), "duration_s": round(float(rng.uniform(1, 5)),
                                                                       1)}]
    one_of_n = int(rng.integers(1, 9))
    return {
        "gps": {"receiver": str(rng.choice(["ashtech_z12", "ublox_f9p", "novatel_oem7"])),
                "max_event_rate_hz": float(rng.choice([1.0, 5.0, 10.0, 20.0, 25.0]))},
        "sisa": {"lfsr_bits": int(rng.choice([4, 5, 6, 7])), "one_of_n": one_of_n},
        "scanner": {"frame_counter_bits": int(rng.choice([8, 16]))},
        "ins": {"counter_bits": int(rng.choice([8, 16])),
                "clock_drift_ppm": round(float(rng.uniform(-200.0, 200.0)), 2)},
        "faults": faults,
    }


def draw_wide_mix(rng: np.random.Generator) -> dict[str, Any]:
    """A harsher mix than `draw_mix`: rates several times higher, up to three PPS outages and
    four INS clock jumps (1 µs to 10 s, either way), reboots and sync restarts that may come
    twice, line clock drift, counters as narrow as they go, and timed faults drawn close to
    one another (a jump inside an outage, a reboot just after a restart): the coincidences
    a fixed matrix never flies."""
    def maybe(p: float) -> bool:
        return bool(rng.random() < p)

    placed: list[float] = []

    def at() -> float:
        if placed and maybe(0.5):  # near a fault already placed
            t = placed[int(rng.integers(len(placed)))] + float(rng.uniform(-5.0, 5.0))
        else:
            t = float(rng.uniform(22.0, FLIGHT_S))
        t = round(min(max(t, 22.0), FLIGHT_S), 2)
        placed.append(t)
        return t

    def timed(n_max: int, lo_s: float, hi_s: float) -> list[dict[str, float]]:
        return [{"at_s": at(), "duration_s": round(float(rng.uniform(lo_s, hi_s)), 2)}
                for _ in range(int(rng.integers(1, n_max + 1)))]

    faults = draw_rates(rng, WIDE_RATES)
    if maybe(0.5):
        faults["pps_outages"] = timed(3, 1.0, 90.0)
    if maybe(0.3):
        faults["sync_restarts"] = timed(2, 0.5, 10.0)
    if maybe(0.3):
        faults["ins_reboots"] = timed(2, 0.5, 15.0)
    if maybe(0.6):
        faults["ins_clock_jumps"] = [
            {"at_s": at(), "jump_ms": round(float(rng.choice([-1, 1]) * 10 ** rng.uniform(
                -3.0, 4.0)), 6)} for _ in range(int(rng.integers(1, 5)))]
    one_of_n = int(rng.integers(1, 13))
    return {
        "gps": {"receiver": str(rng.choice(["ashtech_z12", "ublox_f9p", "novatel_oem7"])),
                "max_event_rate_hz": float(rng.choice([1.0, 2.0, 5.0, 10.0, 20.0, 25.0, 50.0]))},
        "sisa": {"lfsr_bits": int(rng.choice([3, 4, 5, 6, 7, 8])), "one_of_n": one_of_n},
        "scanner": {"frame_counter_bits": int(rng.choice([8, 12, 16, 32])),
                    "line_clock_drift_ppm": round(float(rng.uniform(-300.0, 300.0)), 2)},
        "ins": {"counter_bits": int(rng.choice([8, 10, 16, 32])),
                "clock_drift_ppm": round(float(rng.uniform(-500.0, 500.0)), 2)},
        "faults": faults,
    }


def vary_ins(mix: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:
    """The INS itself drawn too: its rate (128 Hz is 7 812.5 µs a record, no whole number of
    1 µs steps), a clock set anywhere in ±1e5 s (below zero it wraps on the wire), its output
    delay and its clock's resolution."""
    mix["ins"].update({"rate_hz": float(rng.choice([50.0, 64.0, 100.0, 128.0, 200.0])),
                       "clock_offset_s": round(float(rng.uniform(-1e5, 1e5)), 6),
                       "output_delay_ms": round(float(rng.uniform(1.0, 400.0)), 3),
                       "clock_resolution_ns": int(rng.choice([100, 500, 1000]))})
    return mix


def vary_devices(mix: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:
    """The scanner's line clock and header timing, the recorder's read clock, the receiver's
    own timing, the sync unit's PPS gate, mode-1 events and 1-of-n (auto) and the leap seconds
    drawn too. Seven mixes in ten get a header window that covers the
    headers' latencies (`sisa scenario show`'s header_early_by_min_ms to header_late_by_max_ms);
    one in ten a window as wide that closes before the latest headers (a latency
    underestimated), one in ten one that opens after the earliest (overestimated); one in ten
    keeps the default window whatever the line period and latency.
    A window wider than a period, or one that misses the latency, is a misconfigured unit, and
    it must cost flagged lines, never wrong ones."""
    period_ms = float(rng.choice([5.0, 8.0, 10.0, 12.5, 16.0, 20.0, 25.0, 40.0]))
    lat_lo_ms = round(float(rng.uniform(0.0, 3.0)), 3)
    lat_hi_ms = round(lat_lo_ms + float(rng.uniform(0.0, 5.0)), 3)
    read_ms = float(rng.choice([0.0, 1.0, 2.0, 5.0]))
    mix["scanner"].update({
        "line_period_ms": period_ms,
        "integration_time_ms": round(period_ms * float(rng.uniform(0.3, 0.95)), 3),
        "header_latency_ms": [lat_lo_ms, lat_hi_ms],
        "line_clock_jitter_ns": round(float(rng.uniform(0.0, 500.0)), 1),
        "line_clock_drift_ppm": round(float(rng.uniform(-300.0, 300.0)), 2)})
    mix["sisa"]["read_interval_ms"] = read_ms
    transit_ms = header_transit_ms()
    early_ms = lat_lo_ms + transit_ms[0]
    late_ms = lat_hi_ms + transit_ms[1] + read_ms
    window = rng.random()
    if window < 0.7:
        mix["sisa"]["header_window_ms"] = [round(early_ms - 0.5, 3), round(late_ms + 0.5, 3)]
    elif window < 0.9:  # closes before the latest headers, or opens after the earliest
        shift_ms = float(rng.uniform(0.3, 0.9)) * (late_ms - early_ms + 1.0) * (
            -1.0 if window < 0.8 else 1.0)
        mix["sisa"]["header_window_ms"] = [round(early_ms - 0.5 + shift_ms, 3),
                                           round(late_ms + 0.5 + shift_ms, 3)]
    mix["gps"].update({"nmea_rate_hz": float(rng.choice([1.0, 2.0, 5.0, 10.0])),
                       "pps_jitter_ns": float(rng.choice([5.0, 20.0, 200.0])),
                       "event_tag_resolution_ns": int(rng.choice([1, 50, 100, 1000])),
                       "serial_baud": int(rng.choice([9600, 19200, 38400, 115200])),
                       "nmea_latency_ms": round(float(rng.uniform(0.0, 400.0)), 1)})
    mix["sisa"].update({"event_input_in_mode1": bool(rng.random() < 0.3),
                        "pps_gate_us": float(rng.choice([2.0, 5.0, 20.0]))})
    if rng.random() < 0.3:
        mix["sisa"]["one_of_n"] = "auto"
    mix["block"] = {"leap_seconds": int(rng.choice([17, 18]))}
    return mix


def one_run(seed: int, wide: bool = False, ins: bool = False,
            devices: bool = False) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    for _ in range(20):
        mix = (draw_wide_mix if wide else draw_mix)(rng)
        if ins:
            mix = vary_ins(mix, rng)
        if devices:
            mix = vary_devices(mix, rng)
        try:
            scn = scenario_from_table(merged({"base": "bench", "seed": seed, **SHORT}, mix))
            break
        except ConfigError:
            continue
    else:
        raise SystemExit(f"seed {seed}: no mix the scenario accepts in 20 draws")
    with tempfile.TemporaryDirectory(prefix="fault_sweep_") as tmp:
        run = Path(tmp)
        simulate(scn, run, images=False)
        inp = read_sync_input(run / "flight.mcap")
        res = synchronise(inp, scanner_lines(run))
        truth_ins = ins_truth_ns(run, inp, unknown_ok=True)
        # a record the INS never sent (corrupted past its CRC): any time given it is wrong
        forged = truth_ins < 0
        ins_ok = res.ins.status == TimeStatus.OK
        forged_ok = int(np.count_nonzero(forged & ins_ok))
        e_ins = ok_errors_ns(res.ins.t_gps_ns[~forged], res.ins.status[~forged],
                             truth_ins[~forged])
        e_line = ok_errors_ns(res.lines.t_gps_ns, res.lines.status, line_truth_ns(run, res))
    return {
        "seed": seed, "mix": mix, "window_covers": window_covers(scn),
        "ins": [int(np.count_nonzero(ins_ok)), int(res.ins.status.size)],
        "lines": [int(e_line.size), int(res.lines.status.size)],
        "wrong_ins": int(np.count_nonzero(np.abs(e_ins) > WRONG_NS)) + forged_ok,
        "wrong_lines": int(np.count_nonzero(np.abs(e_line) > WRONG_NS)),
        "forged_ins": [forged_ok, int(np.count_nonzero(forged))],
        # the simulated recorder's clock never steps: a step found is a false one
        "host_steps": len(res.report["host_clock_steps"]),
        "worst_ns": float(max(np.abs(e_ins).max(initial=0.0), np.abs(e_line).max(initial=0.0))),
        "flagged_ins": {TimeStatus(int(s)).name.lower(): int(n) for s, n in zip(
            *np.unique(res.ins.status[res.ins.status != TimeStatus.OK], return_counts=True),
            strict=True)},
    }


def window_covers(scn: Scenario) -> float | None:
    """The share of the headers' latency range (`sisa scenario show`'s header_early_by_min_ms
    to header_late_by_max_ms) the header window covers; None for a window not narrower than
    a line period (no header is tied on time alone). Under MISSTATED_COVER the window is the
    operator's statement wrong for nearly every header: if a neighbouring frame's window holds
    them instead, every line is tied one frame off alike, and the log cannot show it
    (docs/sync.md, Limits); wrong tags there are counted apart."""
    lo, hi = scn.sisa.header_window_ms
    if hi - lo >= scn.scanner.line_period_ms:
        return None
    transit_ms = header_transit_ms()
    early = scn.scanner.header_latency_ms[0] + transit_ms[0]
    late = scn.scanner.header_latency_ms[1] + transit_ms[1] + scn.sisa.read_interval_ms
    return round(float(max(0.0, min(late, hi) - max(early, lo)) / (late - early)), 3)


def misstated(r: dict[str, Any]) -> bool:
    cover = r.get("window_covers")
    return cover is not None and cover < MISSTATED_COVER


def scanner_lines(run: Path) -> LineTable:
    """What the scanner's lines files would hold (line → frame counter of every recorded
    frame), from the truth: the run has no images, and without them lines are numbered by
    header order, which a lost header shifts (`sisa sync` warns)."""
    fr = read_truth_csv(run / "truth" / "frames.csv")
    rec = fr["line_index"] >= 0
    return LineTable(fr["segment"][rec].astype(np.int64), fr["line_index"][rec].astype(np.int64),
                     fr["frame_counter"][rec].astype(np.int64))


def summary(mix: dict[str, Any]) -> str:
    g, s = mix["gps"], mix["sisa"]
    head = (f"{g['receiver'][:6]} lfsr{s['lfsr_bits']} 1of{s['one_of_n']} "
            f"{g['max_event_rate_hz']:g}/s")
    return head + " " + ",".join(sorted(mix["faults"])) if mix["faults"] else head


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=40)
    ap.add_argument("--first-seed", type=int, default=1000)
    ap.add_argument("--out", type=Path, default=Path("runs/fault_sweep"))
    ap.add_argument("--wide", action="store_true",
                    help="harsher mixes (draw_wide_mix): higher rates, several timed faults, "
                         "drawn close together")
    ap.add_argument("--vary-ins", action="store_true",
                    help="also draw the INS rate, clock offset, output delay and resolution")
    ap.add_argument("--vary-devices", action="store_true",
                    help="also draw the scanner's line clock and header timing, the read "
                         "clock, the header window and the receiver's timing (vary_devices)")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "fault_sweep.json"
    rows: list[dict[str, Any]] = json.loads(path.read_text()) if path.is_file() else []
    done = {r["seed"] for r in rows}
    t0 = time.perf_counter()
    for seed in range(args.first_seed, args.first_seed + args.runs):
        if seed in done:
            continue
        r = one_run(seed, args.wide, args.vary_ins, args.vary_devices)
        rows.append(r)
        path.write_text(json.dumps(rows) + "\n", encoding="utf-8")
        print(f"seed {seed}: INS {r['ins'][0]}/{r['ins'][1]}, lines {r['lines'][0]}/"
              f"{r['lines'][1]}, wrong {r['wrong_ins']} + {r['wrong_lines']}, "
              f"{r['forged_ins'][1]} records past the CRC ({r['forged_ins'][0]} ok), worst "
              f"{r['worst_ns'] / 1e3:.2f} µs  [{summary(r['mix'])}]", flush=True)
    wrong = sum(r["wrong_ins"] + (0 if misstated(r) else r["wrong_lines"]) for r in rows)
    stated = [r for r in rows if misstated(r)]
    ins_ok, ins_n = (sum(r["ins"][i] for r in rows) for i in (0, 1))
    ln_ok, ln_n = (sum(r["lines"][i] for r in rows) for i in (0, 1))
    print(f"\n{len(rows)} runs ({time.perf_counter() - t0:.0f} s): INS records timed "
          f"{ins_ok}/{ins_n} ({100 * ins_ok / max(ins_n, 1):.2f} %), scan lines {ln_ok}/{ln_n} "
          f"({100 * ln_ok / max(ln_n, 1):.2f} %); wrong tags (ok, off by > 5 µs): {wrong}")
    if stated:
        print(f"  apart: {len(stated)} runs whose header window covers under "
              f"{MISSTATED_COVER:.0%} of the headers' latency range (a misstated window, "
              f"docs/sync.md, Limits): scan lines wrong {sum(r['wrong_lines'] for r in stated)} "
              f"(" + ", ".join(f"seed {r['seed']}: {r['wrong_lines']} of {r['lines'][1]}, "
                               f"covers {r['window_covers']:.0%}" for r in stated) + ")")
    low = [r for r in rows if r["ins"][0] < 0.99 * r["ins"][1] or r["lines"][0] < 0.99 * r[
        "lines"][1]]
    for r in low:
        print(f"  under 99 %: seed {r['seed']}: INS {r['ins'][0]}/{r['ins'][1]} "
              f"{r['flagged_ins']}, lines {r['lines'][0]}/{r['lines'][1]}  [{summary(r['mix'])}]")
    false_steps = [r["seed"] for r in rows if r.get("host_steps")]
    if false_steps:
        print(f"  host clock steps found in logs recorded without one: seeds {false_steps}")
    if wrong or false_steps:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
