"""Time synchronisation: speed and memory on a long flight, accuracy on simulated runs.

    .venv/bin/python bench/sync_speed.py [--hours 5]            speed and memory
    .venv/bin/python bench/sync_speed.py --accuracy RUN [RUN ...] accuracy against the truth
    .venv/bin/python bench/sync_speed.py --ensemble 20          INS error over 20 seeds
    .venv/bin/python bench/sync_speed.py --faults               the fault matrix as a table

Speed: the log arrays of a flight of --hours are synthesised directly at full size (INS at 64 Hz,
a 16 ms scanner over 300 s strips with 30 s turns, 1 Hz PPS gated by a 4-bit LFSR, 1 of 64 frames
tagged), with the emulators' default clocks and noise, then `postproc.sync.pipeline.synchronise` is
timed (the core sync: reading the MCAP file is not included). Target: a 5-hour flight (~1.2 M INS
records, ~1 M lines) in < 5 s with a peak of < 1 GB. The synthetic flight's own truth checks the
result.

Accuracy: `RUN` is a folder from `sisa simulate` (flight.mcap, truth/, optional scanner/);
measured errors against the truth, beside the errors the noise model predicts (docs/sync.md).

Ensemble: an INS record's error is its clock fit's error (an offset and a rate: two random
numbers per fit), so one run's RMS scatters as sqrt(χ²₂/2) around the prediction. Over many
seeds of the short fault-matrix flight the mean of (measured / predicted)² must be 1.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
import tracemalloc
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from acquisition.lfsr import Lfsr
from postproc.sync import (
    GpsTimes,
    HeaderColumns,
    InsColumns,
    SisaColumns,
    SyncInput,
    SyncResult,
    read_sync_input,
    synchronise,
)

I64 = npt.NDArray[np.int64]
NS = 1_000_000_000
T0_NS = 1_465_549_200 * NS  # a whole GPS second
LEAP_NS, HOST_OFFSET_NS, HOST_PPM = 18 * NS, 37_000_000, 3.0
BOARD_START_NS, BOARD_PPM = NS, 12.0
INS_OFFSET_NS, INS_PPM, INS_PERIOD_NS, INS_RES_NS = 12_500_000_000, 35.0, 15_625_000, 1_000
LINE_PERIOD_NS, LINE_PPM, ONE_OF_N = 16_000_000.0, 15.0, 64
STATIC_S, STRIP_S, TURN_S = 600, 300, 30


@dataclass(frozen=True)
class Truth:
    t_meas_ns: I64  # per INS record
    t_mid_ns: I64  # per frame header (line)


def _host(t_ns: I64) -> I64:
    drift_ns: I64 = np.rint((t_ns - T0_NS) * HOST_PPM * 1e-6).astype(np.int64)
    return t_ns - LEAP_NS + HOST_OFFSET_NS + drift_ns


def _board(t_ns: I64) -> I64:
    drift_ns: I64 = np.rint((t_ns - T0_NS) * BOARD_PPM * 1e-6).astype(np.int64)
    return BOARD_START_NS + (t_ns - T0_NS) + drift_ns


def _ins_clock(t_ns: I64) -> I64:
    e = t_ns - T0_NS
    drift_ns: I64 = np.rint(e * INS_PPM * 1e-6).astype(np.int64)
    return INS_OFFSET_NS + e + drift_ns


def _round(t_ns: I64, step: int) -> I64:
    return (t_ns + step // 2) // step * step


def _windows(seconds: int) -> list[tuple[int, int]]:
    out, start = [], STATIC_S
    while start + STRIP_S + TURN_S < seconds:
        out.append((start, start + STRIP_S))
        start += STRIP_S + TURN_S
    return out


def _frames(windows: list[tuple[int, int]], rng: np.random.Generator
            ) -> tuple[I64, I64, I64]:
    """Mid-exposure times, segment and wrapped counter of every frame of every strip."""
    period = LINE_PERIOD_NS * (1 + LINE_PPM * 1e-6)
    c0 = T0_NS + 123_456
    ticks = [np.arange(int(np.ceil((T0_NS + a * NS - c0) / period)),
                       int((T0_NS + b * NS - c0) // period)) for a, b in windows]
    seg = np.concatenate([np.full(t.size, i) for i, t in enumerate(ticks)]).astype(np.int64)
    k = np.concatenate(ticks)
    t_mid = c0 + np.rint(k * period + rng.normal(0.0, 50.0, k.size)).astype(np.int64)
    return t_mid, seg, np.arange(k.size, dtype=np.int64) % (1 << 16)


def _pps(seconds: int, windows: list[tuple[int, int]], rng: np.random.Generator
         ) -> tuple[I64, I64, npt.NDArray[np.bool_]]:
    """GPS seconds, PPS edges and whether each is forwarded (mode 1, LFSR bit 1)."""
    sec = T0_NS + np.arange(seconds, dtype=np.int64) * NS
    edge = sec + np.rint(rng.normal(0.0, 20.0, seconds)).astype(np.int64)
    bits = np.resize(np.array(Lfsr.maximal(4, 1).sequence(15), dtype=np.int64), seconds)
    s = np.arange(seconds)
    scanning = np.zeros(seconds, dtype=np.bool_)
    for a, b in windows:
        scanning |= (s >= a) & (s <= b + 1)
    return sec, edge, (bits == 1) & ~scanning


def _ins(pulse_ns: I64, seconds: int, rng: np.random.Generator
         ) -> tuple[InsColumns, I64]:
    first = -(-INS_OFFSET_NS // INS_PERIOD_NS)
    clock = (first + np.arange(int(seconds * 64), dtype=np.int64)) * INS_PERIOD_NS
    t_meas = T0_NS + np.ceil((clock - INS_OFFSET_NS) / (1 + INS_PPM * 1e-6)).astype(np.int64)
    pulse_ns = np.sort(pulse_ns[pulse_ns < t_meas[-1]])
    rec = np.searchsorted(t_meas, pulse_ns)
    rec, first_pulse = np.unique(rec, return_index=True)
    flag = np.zeros(t_meas.size, dtype=np.bool_)
    flag[rec] = True
    latch = np.zeros(t_meas.size, dtype=np.int64)
    latch[rec] = _ins_clock(pulse_ns[first_pulse]) // INS_RES_NS * INS_RES_NS // 100
    latency = 56_500_000 + rng.integers(100_000, 400_000, t_meas.size)
    counter = np.arange(t_meas.size, dtype=np.int64) % (1 << 16)
    status = np.full(t_meas.size, 2, dtype=np.int64) | np.where(flag, 0x10, 0)
    ins = InsColumns(_host(t_meas + latency), counter, clock // 100, status, flag, latch)
    return ins, t_meas


def synthesise(hours: float, seed: int = 0) -> tuple[SyncInput, Truth]:
    """The log arrays of a flight of `hours`, and its truth."""
    rng = np.random.default_rng(seed)
    seconds = int(hours * 3600)
    windows = _windows(seconds)
    sec, edge, fwd1 = _pps(seconds, windows, rng)
    t_mid, seg, counter = _frames(windows, rng)
    pick = np.concatenate([np.flatnonzero(seg == i)[2::ONE_OF_N] for i in range(len(windows))])
    out2 = t_mid[pick] + 1_000
    ins, t_meas = _ins(np.concatenate([edge[fwd1] + 1_000, out2]), seconds, rng)
    n1, n2 = int(fwd1.sum()), pick.size
    sisa = SisaColumns(
        _host(edge + 50_000), _board(edge), sec, np.zeros(seconds, dtype=np.bool_),
        _host(np.concatenate([edge[fwd1], t_mid[pick]]) + 50_000), np.zeros(n1 + n2, np.int64),
        np.concatenate([_board(edge[fwd1]), _board(t_mid[pick])]) + 1_000,
        np.concatenate([np.ones(n1, np.int64), np.full(n2, 2, np.int64)]),
        np.concatenate([np.zeros(n1, np.bool_), np.ones(n2, np.bool_)]),
        np.concatenate([np.zeros(n1, np.bool_), np.ones(n2, np.bool_)]),
        np.concatenate([sec[fwd1], np.full(n2, -1, np.int64)]),
        np.concatenate([np.full(n1, -1, np.int64), counter[pick]]),
        np.array([4], dtype=np.int64), 2 * len(windows))
    tags_gps = np.concatenate([_round(edge, 100), _round(out2, 100)])
    tags_host = np.concatenate([_host(sec + 25_000_000), _host(out2 + 30_000_000)])
    gps = GpsTimes(_host(sec + 48_000_000), sec, tags_host, tags_gps,
                   np.concatenate([np.ones(seconds, np.bool_), np.zeros(n2, np.bool_)]))
    headers = HeaderColumns(_host(t_mid + 9_600_000), counter, seg)
    return SyncInput(ins, gps, sisa, headers), Truth(t_meas, t_mid)


def _errors(t: I64, status: I64, truth: I64) -> str:
    ok = status == 0
    err = (t[ok] - truth[ok]).astype(np.float64)
    rms = float(np.sqrt(np.mean(err**2))) if err.size else float("nan")
    worst = float(np.abs(err).max()) if err.size else float("nan")
    wrong = int(np.count_nonzero(np.abs(err) > 10_000))
    return (f"{ok.sum()}/{ok.size} timed, error RMS {rms:.1f} ns, max {worst:.0f} ns, "
            f"wrong (> 10 µs) {wrong}")


def speed(hours: float) -> None:
    t0 = time.perf_counter()
    inp, truth = synthesise(hours)
    t_synth = time.perf_counter() - t0
    tracemalloc.start()
    t1 = time.perf_counter()
    result = synchronise(inp)
    wall = time.perf_counter() - t1
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"synthetic flight of {hours:g} h: {inp.ins.counter.size} INS records, "
          f"{inp.headers.segment.size} lines in {len(np.unique(inp.headers.segment))} segments, "
          f"{inp.sisa.fwd_board_ns.size} forwarded pulses (synthesised in {t_synth:.1f} s)")
    print(f"  core sync: {wall:.2f} s (target < 5 s); peak memory allocated during the sync "
          f"{peak / 1e6:.0f} MB, process peak RSS {rss_mb:.0f} MB (target < 1 GB)")
    print(f"  INS records: {_errors(result.ins.t_gps_ns, result.ins.status, truth.t_meas_ns)}")
    print(f"  scan lines:  {_errors(result.lines.t_gps_ns, result.lines.status, truth.t_mid_ns)}")


def accuracy(run: Path) -> None:
    from postproc.sync import read_scanner_lines

    _with_tests()
    from tests.postproc.test_sync import accuracy_lines

    inp = read_sync_input(run / "flight.mcap")
    scanner = run / "scanner"
    lines = read_scanner_lines(scanner) if scanner.is_dir() else None
    t0 = time.perf_counter()
    result: SyncResult = synchronise(inp, lines)
    wall = time.perf_counter() - t0
    print(f"{run}: {inp.ins.counter.size} INS records, {result.lines.line.size} lines "
          f"({'lines files' if lines is not None else 'frame headers'}); core sync {wall:.2f} s")
    for text in accuracy_lines(run, inp, result):
        print(f"  {text}")


def _with_tests() -> None:
    """The truth joins and the noise model live with the tests (never in postproc)."""
    root = str(Path(__file__).resolve().parents[1])
    if root not in sys.path:
        sys.path.insert(0, root)


def ensemble(count: int) -> None:
    import tempfile

    from emulators.scenario import scenario_from_table
    from sisa.wiring.simulation import simulate

    _with_tests()
    from tests.postproc.test_sync import (
        ins_truth_ns,
        ok_errors_ns,
        predicted_ins_rms_ns,
        rms,
    )
    from tests.postproc.test_sync_faults import SHORT

    ratios2, measured2, predicted2 = [], [], []
    for seed in range(1, count + 1):
        scn = scenario_from_table({"base": "bench", "seed": seed, **SHORT})
        with tempfile.TemporaryDirectory() as tmp:
            simulate(scn, Path(tmp), images=False)
            inp = read_sync_input(Path(tmp) / "flight.mcap")
            res = synchronise(inp)
            e = ok_errors_ns(res.ins.t_gps_ns, res.ins.status, ins_truth_ns(Path(tmp), inp))
        p = predicted_ins_rms_ns(res, scn)
        ratios2.append((rms(e) / p) ** 2)
        measured2.append(rms(e) ** 2)
        predicted2.append(p * p)
        print(f"  seed {seed:3d}: INS error RMS {rms(e):6.1f} ns, predicted {p:6.1f} ns")
    mean = float(np.mean(ratios2))
    print(f"{count} seeds: mean (measured/predicted)² = {mean:.2f} ± "
          f"{np.sqrt(2.0 / (2 * count)):.2f} (expected 1); pooled RMS "
          f"{np.sqrt(np.mean(measured2)):.1f} ns vs predicted {np.sqrt(np.mean(predicted2)):.1f}")


def faults() -> None:
    """The fault matrix of tests/postproc/test_sync_faults.py, as a table."""
    import tempfile

    from emulators.scenario import scenario_from_table
    from sisa.wiring.simulation import simulate

    _with_tests()
    from tests.postproc.test_sync import (
        WRONG_NS,
        ins_truth_ns,
        line_truth_ns,
        ok_errors_ns,
        rms,
    )
    from tests.postproc.test_sync_faults import PROFILES, SHORT, _merge

    print(f"{'profile':<20} {'seed':>4} {'INS timed':>13} {'flagged':<18} {'RMS ns':>7} "
          f"{'max ns':>7} {'lines timed':>11} {'RMS ns':>7} {'wrong':>5}")
    for profile in PROFILES:
        for seed in (1, 2):
            scn = scenario_from_table(_merge({"base": "bench", "seed": seed, **SHORT},
                                             PROFILES[profile]))
            with tempfile.TemporaryDirectory() as tmp:
                run = Path(tmp)
                simulate(scn, run, images=False)
                inp = read_sync_input(run / "flight.mcap")
                res = synchronise(inp)
                e = ok_errors_ns(res.ins.t_gps_ns, res.ins.status, ins_truth_ns(run, inp))
                el = ok_errors_ns(res.lines.t_gps_ns, res.lines.status, line_truth_ns(run, res))
            flagged = ", ".join(f"{k} {v}" for k, v in res.report["ins"]["status"].items()
                                if k != "ok") or "-"
            wrong = int((np.abs(e) > WRONG_NS).sum() + (np.abs(el) > WRONG_NS).sum())
            print(f"{profile:<20} {seed:>4} {e.size:>6}/{res.ins.status.size:<6} {flagged:<18} "
                  f"{rms(e):7.1f} {np.abs(e).max():7.0f} {el.size:>5}/{res.lines.status.size:<5} "
                  f"{rms(el):7.1f} {wrong:>5}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--hours", type=float, default=5.0)
    parser.add_argument("--accuracy", nargs="+", type=Path, metavar="RUN")
    parser.add_argument("--ensemble", type=int, metavar="N")
    parser.add_argument("--faults", action="store_true")
    args = parser.parse_args()
    if args.accuracy:
        for run in args.accuracy:
            accuracy(run)
    elif args.ensemble:
        ensemble(args.ensemble)
    elif args.faults:
        faults()
    else:
        shortest_h = (STATIC_S + STRIP_S + TURN_S + 1) / 3600
        if not args.hours >= shortest_h:  # no strip: nothing to time
            parser.error(f"--hours {args.hours:g}: a flight of one strip takes at least "
                         f"{shortest_h:.2f} h")
        speed(args.hours)


if __name__ == "__main__":
    main()
