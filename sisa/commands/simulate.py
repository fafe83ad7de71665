"""`sisa simulate`: a whole flight in virtual time (emulators + sync filter + recorder, one
process). RUN holds what a real flight would give (flight.mcap, the scanner's recording) and,
apart, the resolved scenario and the truth."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import TYPE_CHECKING

from sisa.commands import (
    SubParsers,
    add_command,
    add_force_arg,
    add_scenario_args,
    check_seed,
    scenario_from_args,
)
from sisa.commands.progress import progress
from sisa.core.outdir import staged_output_dir

if TYPE_CHECKING:
    from emulators.scenario import Scenario


def register(sub: SubParsers[argparse.ArgumentParser]) -> None:
    parser = add_command(sub, "simulate", "simulate a whole flight in virtual time: devices, "
                         "sync filter and flight recorder in one process",
                         "sisa simulate --preset bench --out runs/bench --seed 7")
    add_scenario_args(parser)
    parser.add_argument("--out", type=Path, required=True, help="new run folder")
    add_force_arg(parser)
    parser.add_argument("--seed", type=int, default=None, help="override the scenario's seed")
    parser.add_argument("--no-images", action="store_true",
                        help="skip rendering the scanner's image lines (timing only)")
    parser.add_argument("--error-free", action="store_true",
                        help="no GPS position noise and no INS attitude, rate or velocity "
                             "errors: georeferencing must then reproduce the truth")
    parser.set_defaults(handler=_run)


def error_free(scn: Scenario) -> Scenario:
    """The scenario without navigation errors (timing flaws and faults stay as they are)."""
    zero = (0.0, 0.0, 0.0)
    gps = scn.gps.model_copy(update={"horizontal_noise_m": 0.0, "vertical_noise_m": 0.0})
    ins = scn.ins.model_copy(update={
        "attitude_bias_arcsec": zero, "attitude_drift_arcsec_per_h": zero,
        "attitude_noise_arcsec": zero, "rate_noise_rps": 0.0, "velocity_noise_mps": 0.0})
    return scn.model_copy(update={"gps": gps, "ins": ins})


def _run(args: argparse.Namespace) -> int:
    from sisa.commands.scenario import scenario_toml
    from sisa.wiring.simulation import simulate

    scn = scenario_from_args(args)
    check_seed(args.seed)
    if args.seed is not None:
        scn = scn.model_copy(update={"seed": args.seed})
    if args.error_free:
        scn = error_free(scn)
    started = time.perf_counter()
    with staged_output_dir(args.out, force=args.force) as run, progress("simulate") as bar:
        (run / "scenario.toml").write_text(scenario_toml(scn), encoding="utf-8")
        wiring = simulate(scn, run, images=not args.no_images, steps=bar)
    acq = wiring.acq
    flight_s = (wiring.system.traj.t_end_ns - wiring.system.traj.t_start_ns) / 1e9
    wall_s = time.perf_counter() - started
    print(f"{args.out}: {scn.block.name}, {flight_s:.0f} s of flight in {wall_s:.1f} s "
          f"({flight_s / wall_s:.0f}x); INS records {acq.streams['ins'].messages}, "
          f"frame headers {acq.streams['scanner'].messages}, PPS {acq.streams['pps'].messages}, "
          f"sync sessions {acq.session + 1}")
    return 0
