"""`sisa emulate`: the three devices in real time on virtual ports, until Ctrl-C or the end of
the scenario. The scanner's own recording and the truth tables go to the run folder."""

from __future__ import annotations

import argparse
import shutil
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

from sisa.commands import (
    SubParsers,
    add_command,
    add_scenario_args,
    check_endpoints_path,
    check_port,
    scenario_from_args,
    write_endpoints,
)
from sisa.commands.progress import Progress, progress
from sisa.core.errors import InputError
from sisa.core.outdir import name_taken

if TYPE_CHECKING:
    from emulators.runtime import Runner
    from emulators.scenario import Scenario
    from emulators.trajectory import TruthTrajectory

MIN_SPEED = 0.001  # --speed: slower flies a minute of the scenario in more than 16 hours
HELD_LINE = "emulate: the scenario is over; every port held open, silent, until Ctrl-C"


def register(sub: SubParsers[argparse.ArgumentParser]) -> None:
    parser = add_command(sub, "emulate", "run the GPS receiver, INS and scanner emulators in real "
                         "time on virtual serial ports, CAN and pulse lines",
                         "sisa emulate --preset bench --out runs/bench-emu   "
                         "(then: sisa record ... on the printed ports)")
    add_scenario_args(parser)
    parser.add_argument("--out", type=Path, required=True,
                        help="new folder for the scanner's recording and the truth tables")
    parser.add_argument("--speed", type=float, default=1.0,
                        help="times real time (default 1.0)")
    parser.add_argument("--can", default="slcan",
                        help="'slcan' (an SLCAN adapter on a new pty, default) or "
                             "INTERFACE:CHANNEL for python-can, e.g. socketcan:can0")
    parser.add_argument("--pulses-port", type=int, default=0,
                        help="loopback TCP port for pulse edges (default: any free port)")
    parser.add_argument("--start", type=float, default=0.0,
                        help="start this many seconds into the scenario (the devices run "
                             "through the skipped part silently, as fast as they can)")
    parser.add_argument("--duration", type=float, default=None,
                        help="stop after this many seconds of emulation")
    parser.add_argument("--no-images", action="store_true",
                        help="do not render the scanner's image lines")
    parser.add_argument("--endpoints", type=Path, default=None,
                        help="also write the endpoints as JSON to this file")
    parser.add_argument("--quiet", action="store_true", help="no progress display")
    # sisa bench runs this with its own name on the progress lines
    parser.add_argument("--progress-as", default="emulate", help=argparse.SUPPRESS)
    parser.add_argument("--hold", action="store_true",
                        help="at the end of the scenario (or --duration), keep every port "
                             "open and silent until Ctrl-C, so that a recorder on them can be "
                             "stopped before its devices go away")
    parser.set_defaults(handler=_run, real_time_loop=True)  # see sisa.cli.BATCH_GC_THRESHOLDS


def check_span(scn: Scenario, traj: TruthTrajectory, args: argparse.Namespace) -> None:
    """--speed, --start and --duration against the scenario's flight, before anything runs."""
    flight_s = (traj.t_end_ns - traj.t_start_ns) / 1e9
    if args.speed <= 0:  # (sisa.cli has checked that every number is finite)
        raise InputError("--speed must be positive")
    if args.speed < MIN_SPEED:
        raise InputError(f"--speed {args.speed:g}: at least {MIN_SPEED:g} (a thousandth of real "
                         "time)")
    if not 0 <= args.start < flight_s:
        raise InputError(f"--start {args.start:g} s: the {scn.block.name} flight lasts "
                         f"{flight_s:.1f} s")
    if args.duration is not None and args.duration <= 0:
        raise InputError("--duration must be positive")


def _run(args: argparse.Namespace) -> int:
    from emulators.bridge import CanTarget, RealTimeBridge
    from emulators.runtime import Runner
    from emulators.system import EmulatedSystem
    from emulators.trajectory import TruthTrajectory

    scn = scenario_from_args(args)
    traj = TruthTrajectory.from_scenario(scn)
    check_span(scn, traj, args)
    check_port(args.pulses_port)
    check_endpoints_path(args.endpoints)
    target = CanTarget.parse(args.can)
    if name_taken(args.out, "--out"):
        raise InputError(f"{args.out} already exists: choose a new output folder")
    try:
        args.out.mkdir(parents=True)
    except OSError as exc:  # under a file, in /proc or /sys, a read-only place
        raise InputError(f"cannot create {args.out}: {exc.strerror or exc}") from None
    try:
        system = EmulatedSystem(scn, None if args.no_images else args.out / "scanner",
                                traj=traj, real_time=True)
        runner = Runner(system.devices, lambda out: (), speed=args.speed)
        bridge = RealTimeBridge(target, runner.inbox, pulse_port=args.pulses_port)
    except BaseException:  # a bus or port that cannot be opened: leave nothing behind
        shutil.rmtree(args.out, ignore_errors=True)
        raise
    if args.endpoints is not None:
        try:
            write_endpoints(args.endpoints, bridge.endpoints())
        except InputError:
            bridge.close()
            shutil.rmtree(args.out, ignore_errors=True)
            raise
    runner.sink = system.faulty(bridge)
    stop = threading.Event()

    def on_signal(_sig: int, _frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    _announce(bridge.endpoints(), scn.block.name, args)
    start = system.traj.t_start_ns + int(args.start * 1e9)
    until = None  # a --duration past the end of the scenario is the scenario (1e308 s too)
    if args.duration is not None and args.duration * 1e9 < system.traj.t_end_ns - start:
        until = start + int(args.duration * 1e9)
    started = time.monotonic()
    try:
        with progress(args.progress_as, quiet=args.quiet, refresh_hz=2) as bar:
            bar.follow(_follow(bar, runner, system.traj.t_start_ns, start,
                               until or system.traj.t_end_ns))
            runner.run(until_ns=until, should_stop=stop.is_set, skip_until_ns=start)
        if args.hold and not stop.is_set():
            print(HELD_LINE, flush=True)
            while not stop.wait(0.5):  # a bare wait() would defer the signal handler
                pass
    finally:
        bridge.close()
        system.write_truth(args.out / "truth")
    print(f"emulate: {runner.outputs} outputs in {time.monotonic() - started:.1f} s; "
          f"latest emission {runner.late_ns_max / 1e6:.2f} ms behind schedule; "
          f"truth in {args.out / 'truth'}", flush=True)
    return 0


FAST_FORWARD = "fast-forward to --start"


def _follow(bar: Progress, runner: Runner, t0_ns: int, start_ns: int, end_ns: int
            ) -> Callable[[], None]:
    """The progress of the runner (polled: the real-time loop is not slowed): the run through
    to --start, as fast as it goes, then the flight in real time."""

    def poll() -> None:
        t_ns = runner.t_ns
        if t_ns is None:
            return
        if t_ns < start_ns:
            if bar.label != FAST_FORWARD:
                bar.step(FAST_FORWARD, (start_ns - t0_ns) / 1e9, "s")
            bar.update(completed=(t_ns - t0_ns) / 1e9)
            return
        if bar.label != "flight":
            bar.step("flight", (end_ns - start_ns) / 1e9, "s")
        bar.update(completed=(t_ns - start_ns) / 1e9)

    return poll


def _announce(endpoints: dict[str, str], name: str, args: argparse.Namespace) -> None:
    print(f"GPS receiver (NMEA + Ashtech, RS-232):  {endpoints['gps']}")
    print(f"Scanner frame headers (RS-232):        {endpoints['scanner']}")
    print(f"INS records (CAN):                     {endpoints['ins']}")
    print(f"Pulse lines (timestamped edges, TCP):  {endpoints['pulses']}")
    print(f"Running {name} at {args.speed:g}x real time; Ctrl-C to stop.", flush=True)
