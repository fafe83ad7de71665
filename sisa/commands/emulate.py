"""`sisa emulate`: the three devices in real time on virtual ports, until Ctrl-C or the end of
the scenario. The scanner's own recording and the truth tables go to the run folder."""

from __future__ import annotations

import argparse
import shutil
import signal
import threading
import time
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
from sisa.core.errors import InputError
from sisa.core.outdir import name_taken

if TYPE_CHECKING:
    from emulators.bridge import RealTimeBridge
    from emulators.scenario import Scenario
    from emulators.trajectory import TruthTrajectory
    from sisa.wiring.gpsd import Gpsd

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
    parser.add_argument("--hold", action="store_true",
                        help="at the end of the scenario (or --duration), keep every port "
                             "open and silent until Ctrl-C, so that a recorder on them can be "
                             "stopped before its devices go away")
    parser.add_argument("--gpsd", action="store_true",
                        help="also start gpsd (if installed) on a copy of the GPS port, "
                             "listening on loopback, and print how to connect")
    parser.add_argument("--gpsd-port", type=int, default=0,
                        help="gpsd's TCP port (default: any free port; a system gpsd keeps "
                             "2947)")
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
    if args.gpsd:
        from sisa.wiring.gpsd import gpsd_binary

        check_port(args.gpsd_port, "--gpsd-port")
        gpsd_binary()  # installed, or one line before anything starts
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
        bridge = RealTimeBridge(target, runner.inbox, pulse_port=args.pulses_port,
                                gps_copy=args.gpsd)
    except BaseException:  # a bus or port that cannot be opened: leave nothing behind
        shutil.rmtree(args.out, ignore_errors=True)
        raise
    gpsd = _start_gpsd(args, bridge)
    if args.endpoints is not None:
        try:
            write_endpoints(args.endpoints, {**bridge.endpoints(),
                                             **({"gpsd": gpsd.address} if gpsd else {})})
        except InputError:
            if gpsd is not None:
                gpsd.stop()
            bridge.close()
            shutil.rmtree(args.out, ignore_errors=True)
            raise
    runner.sink = system.faulty(bridge)
    stop = threading.Event()

    def on_signal(_sig: int, _frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    if gpsd is not None:
        print("\n".join(gpsd.how_to_connect()))
    _announce(bridge.endpoints(), scn.block.name, args)
    start = system.traj.t_start_ns + int(args.start * 1e9)
    until = None  # a --duration past the end of the scenario is the scenario (1e308 s too)
    if args.duration is not None and args.duration * 1e9 < system.traj.t_end_ns - start:
        until = start + int(args.duration * 1e9)
    started = time.monotonic()
    try:
        runner.run(until_ns=until, should_stop=stop.is_set, skip_until_ns=start)
        if args.hold and not stop.is_set():
            print(HELD_LINE, flush=True)
            while not stop.wait(0.5):  # a bare wait() would defer the signal handler
                pass
    finally:
        if gpsd is not None:
            gpsd.stop()
        bridge.close()
        system.write_truth(args.out / "truth")
    print(f"emulate: {runner.outputs} outputs in {time.monotonic() - started:.1f} s; "
          f"latest emission {runner.late_ns_max / 1e6:.2f} ms behind schedule; "
          f"truth in {args.out / 'truth'}", flush=True)
    return 0


def _start_gpsd(args: argparse.Namespace, bridge: RealTimeBridge) -> Gpsd | None:
    """gpsd on the bridge's copy of the GPS port (--gpsd); the bridge and the run folder go if
    it cannot start."""
    if not args.gpsd or bridge.gps_copy is None:
        return None
    from sisa.wiring.gpsd import Gpsd

    try:
        return Gpsd(bridge.gps_copy.name, args.gpsd_port)
    except BaseException:
        bridge.close()
        shutil.rmtree(args.out, ignore_errors=True)
        raise


def _announce(endpoints: dict[str, str], name: str, args: argparse.Namespace) -> None:
    print(f"GPS receiver (NMEA + Ashtech, RS-232):  {endpoints['gps']}")
    print(f"Scanner frame headers (RS-232):        {endpoints['scanner']}")
    print(f"INS records (CAN):                     {endpoints['ins']}")
    print(f"Pulse lines (timestamped edges, TCP):  {endpoints['pulses']}")
    print(f"Running {name} at {args.speed:g}x real time; Ctrl-C to stop.", flush=True)
