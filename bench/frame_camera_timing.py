"""The frame camera's timing figures in docs/frames.md and docs/sync.md: photos and scan lines
through one sync unit, measured against the truth.

    PYTHONPATH=. .venv/bin/python bench/frame_camera_timing.py [--seeds 2] [--no-full]

1. The bench_camera preset (549 s, two 3 km strips, a photo every 62.5 m, 1 of 64 frame pulses,
   a receiver taking 5 events a second), default seed, flown with and without its camera: every
   photo's time against the truth by source (event tag, timing board), the INS records and scan
   lines of both flights, and how far the camera moved any of them.
2. The camera's fault matrix of tests/postproc/test_photo_sync.py on its short flight (~230 s,
   a photo every 31.25 m), per seed: photos timed and flagged, wrong tags (a timed photo off by
   more than 5 µs), and the scanner's side.
About 2 minutes for part 1 and 15 s a flight for part 2 on a loaded two-core machine.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from emulators.scenario import Scenario, load_scenario
from postproc.sync import PhotoStatus, PhotoTimeSource, SyncResult, TimeStatus, read_sync_input
from tests.postproc.test_photo_sync import PHOTO_WRONG_NS, PROFILES, fly, photo_errors_ns, scenario
from tests.postproc.test_sync import ins_truth_ns, line_truth_ns, ok_errors_ns


def rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(a.astype(np.float64) ** 2))) if a.size else float("nan")


def scanner_errors(res: SyncResult, run: Path) -> tuple[np.ndarray, np.ndarray]:
    inp = read_sync_input(run / "flight.mcap")
    return (ok_errors_ns(res.ins.t_gps_ns, res.ins.status, ins_truth_ns(run, inp)),
            ok_errors_ns(res.lines.t_gps_ns, res.lines.status, line_truth_ns(run, res)))


def by_source(res: SyncResult, run: Path) -> None:
    """Photo errors per time source, with the σ the table states."""
    p = res.photos
    if p is None:
        return
    err = photo_errors_ns(res, run)
    named = (p.t_gps_ns >= 0) & (p.photo_number >= 0)
    for src in (PhotoTimeSource.EVENT_TAG, PhotoTimeSource.BOARD):
        pick = p.source[named] == src
        e = err[pick]
        if e.size:
            sigma = np.nanmean(p.sigma_ns[named][pick])
            print(f"    {src.name.lower():9} {e.size:4} photos: RMS {rms(e):6.1f} ns, max "
                  f"{np.abs(e).max():4.0f} ns (stated sigma {sigma:.1f} ns)")


def full_flight(tmp: Path) -> None:
    scn = load_scenario("bench_camera")
    runs: dict[str, tuple[Scenario, SyncResult]] = {}
    for name, s in (("with camera", scn), ("without camera", scn.model_copy(
            update={"camera": None}))):
        runs[name] = (s, fly(s, tmp / name))
    photo_hz = scn.camera.photo_rate_hz(scn.block.ground_speed_mps) if scn.camera else 0.0
    print(f"1. bench_camera, seed {scn.seed}: {photo_hz:.3g} photos/s, 1 of "
          f"{scn.sisa.one_of_n} frame pulses, receiver {scn.gps.max_event_rate_hz:g} events/s")
    res = runs["with camera"][1]
    if res.photos is not None:
        rep = res.report["photos"]
        err = photo_errors_ns(res, tmp / "with camera")
        wrong = int((np.abs(err) > PHOTO_WRONG_NS).sum())
        print(f"  photos timed {err.size}/{rep['photo_messages']}: RMS {rms(err):.1f} ns, max "
              f"{np.abs(err).max():.0f} ns, wrong (> 5 µs) {wrong}"
              f"; camera pulses to the event input {rep['camera_pulses_to_gps_event']}/"
              f"{rep['camera_pulses']}")
        by_source(res, tmp / "with camera")
    for name, (_, r) in runs.items():
        e_ins, e_line = scanner_errors(r, tmp / name)
        fwd = r.report["pulses"]
        print(f"  {name:15} INS {int((r.ins.status == TimeStatus.OK).sum())}/{r.ins.status.size}"
              f" RMS {rms(e_ins):5.1f} max {np.abs(e_ins).max():4.0f} ns; lines "
              f"{int((r.lines.status == TimeStatus.OK).sum())}/{r.lines.status.size} RMS "
              f"{rms(e_line):5.1f} max {np.abs(e_line).max():4.0f} ns; forwarded pulses timed by "
              f"{fwd['timed_by']}")
    a, b = runs["without camera"][1], res
    same = (a.ins.status == b.ins.status).all() and (a.lines.status == b.lines.status).all()
    print(f"  statuses identical: {bool(same)}; the camera moved an INS time by at most "
          f"{np.abs(a.ins.t_gps_ns - b.ins.t_gps_ns).max()} ns, a line by at most "
          f"{np.abs(a.lines.t_gps_ns - b.lines.t_gps_ns).max()} ns")


def fault_matrix(tmp: Path, seeds: int) -> None:
    print(f"2. the camera's faults, short flight, seeds 1..{seeds}")
    print("  profile                       photos timed  flagged (status: count)"
          "                 wrong  RMS ns  lines timed  wrong")
    for profile, faults in PROFILES.items():
        for seed in range(1, seeds + 1):
            run = tmp / f"{profile}-{seed}"
            res = fly(scenario(seed, faults), run)
            p = res.photos
            if p is None:
                continue
            err = photo_errors_ns(res, run)
            _, e_line = scanner_errors(res, run)
            flagged = ", ".join(f"{s.name.lower()} {int((p.status == s).sum())}"
                                for s in PhotoStatus
                                if s not in (PhotoStatus.OK, PhotoStatus.BOARD_TIME)
                                and (p.status == s).any()) or "-"
            named = res.report["photos"]["photo_messages"]
            timed = int(np.isin(p.status, (PhotoStatus.OK, PhotoStatus.BOARD_TIME)).sum())
            lines_ok = int((res.lines.status == TimeStatus.OK).sum())
            print(f"  {profile:29} {timed:3}/{named:<3}      {flagged:40} "
                  f"{int((np.abs(err) > PHOTO_WRONG_NS).sum()):3}  {rms(err):6.1f}  "
                  f"{lines_ok:5}/{res.lines.status.size:<5} "
                  f"{int((np.abs(e_line) > PHOTO_WRONG_NS).sum()):3}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2, help="fault-matrix seeds per profile")
    parser.add_argument("--no-full", action="store_true", help="skip the full bench flights")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        if not args.no_full:
            full_flight(Path(tmp))
        fault_matrix(Path(tmp), args.seeds)


if __name__ == "__main__":
    main()
