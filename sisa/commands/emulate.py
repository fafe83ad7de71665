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
    say_warning,
    scenario_from_args,
    write_endpoints,
)
from sisa.commands.progress import Progress, progress
from sisa.core.errors import InputError, RecorderError
from sisa.core.outdir import name_taken

if TYPE_CHECKING:
    from emulators.bridge import RealTimeBridge
    from emulators.runtime import Runner
    from emulators.scenario import Scenario
    from emulators.trajectory import TruthTrajectory
    from sisa.wiring.gpsd import Gpsd

MIN_SPEED = 0.001  # --speed: slower flies a minute of the scenario in more than 16 hours
HELD_LINE = "emulate: the scenario is over; every port held open, silent, until Ctrl-C"
# with --hold, after a disk error: the ports stay until Ctrl-C as well, so that a recorder on
# them is stopped before its devices go away; then the error
HELD_FAILED_LINE = ("emulate: stopped on an error, said at the end; every port held open, "
                    "silent, until Ctrl-C")


def register(sub: SubParsers[argparse.ArgumentParser]) -> None:
    parser = add_command(sub, "emulate", "run the GPS receiver, INS and scanner emulators in real "
                         "time on virtual serial ports, CAN and pulse lines",
                         "sisa emulate --preset bench --out runs/bench-emu --strip 0   "
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
    add_span_args(parser, "stop after this many seconds of emulation")
    parser.add_argument("--no-images", action="store_true",
                        help="do not render the scanner's image lines")
    parser.add_argument("--endpoints", type=Path, default=None,
                        help="also write the endpoints as JSON to this file")
    parser.add_argument("--quiet", action="store_true", help="no progress display")
    # sisa bench runs this with its own name on the progress lines
    parser.add_argument("--progress-as", default="emulate", help=argparse.SUPPRESS)
    parser.add_argument("--hold", action="store_true",
                        help="at the end of the scenario (or --duration), or on a disk "
                             "error, keep every port open and silent until Ctrl-C, so that a "
                             "recorder on them can be stopped before its devices go away")
    parser.add_argument("--gpsd", action="store_true",
                        help="also start gpsd (if installed) on a copy of the GPS port, "
                             "listening on loopback, and print how to connect")
    parser.add_argument("--gpsd-port", type=int, default=0,
                        help="gpsd's TCP port (default: any free port; a system gpsd keeps "
                             "2947)")
    parser.set_defaults(handler=_run, real_time_loop=True)  # see sisa.cli.BATCH_GC_THRESHOLDS


# --strip N starts this long before the strip: two periods of the default 4-bit register
# (15 s) of scanner-off pulses, which `sisa sync` needs to tell the whole GPS second (mode-2
# trains alone match one pulse off as well: docs/sync.md), and `sisa record`'s start-up.
STRIP_LEAD_S = 35.0
STRIP_TAIL_S = 5.0  # after the strip's end, with no --duration: its last lines and run-out
MODE1_BEFORE_S = 20.0  # less of scanner-off flight before a strip: its INS records go untimed


def add_span_args(parser: argparse.ArgumentParser, duration_help: str) -> None:
    """--start, --duration and --strip, the window of the flight a real-time run plays."""
    parser.add_argument("--start", type=float, default=None,
                        help="start this many seconds into the scenario (default 0; the "
                             "devices run through the skipped part silently, as fast as they "
                             "can)")
    parser.add_argument("--duration", type=float, default=None, help=duration_help)
    parser.add_argument("--strip", type=int, default=None, metavar="N",
                        help=f"start {STRIP_LEAD_S:g} s before strip N (scanner-off pulses "
                             "first, which `sisa sync` needs) and, without --duration, stop "
                             f"{STRIP_TAIL_S:g} s after it: the printed timeline gives every "
                             "strip's times")


def check_span(scn: Scenario, traj: TruthTrajectory, args: argparse.Namespace) -> None:
    """--speed, --start, --duration and --strip against the scenario's flight, before anything
    runs; --strip N is turned into --start (and --duration, if not given)."""
    flight_s = (traj.t_end_ns - traj.t_start_ns) / 1e9
    if args.strip is not None:
        if args.start is not None:
            raise InputError("--strip N sets the start: give --strip or --start, not both")
        if not 0 <= args.strip < len(traj.strips):
            raise InputError(f"--strip {args.strip}: the {scn.block.name} flight has strips 0 "
                             f"to {len(traj.strips) - 1}")
        strip = traj.strips[args.strip]
        begin_s, end_s = ((strip.t_start_ns - traj.t_start_ns) / 1e9,
                          (strip.t_end_ns - traj.t_start_ns) / 1e9)
        args.start = max(0.0, begin_s - STRIP_LEAD_S)
        if args.duration is None:
            args.duration = min(end_s + STRIP_TAIL_S, flight_s) - args.start
    if args.start is None:
        args.start = 0.0
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


def _s(ns: int, traj: TruthTrajectory) -> float:
    return (ns - traj.t_start_ns) / 1e9


def timeline(scn: Scenario, traj: TruthTrajectory, start_s: float, duration_s: float | None
             ) -> list[str]:
    """The flight's timeline, in seconds from its start as --start counts them (the static
    alignment, the take-off, each strip with its --strip start), and the window this run
    plays, with what it holds."""
    flight_s = traj.duration_s
    static = [p for p in traj.phases if p.name == "static"]
    takeoff = next((p for p in traj.phases if p.name == "takeoff"), None)
    rows: list[tuple[str, str]] = []
    if static:
        rows.append((f"{_s(static[0].t_start_ns, traj):.0f}-{_s(static[0].t_end_ns, traj):.0f} s",
                     "static alignment (engines off)"))
    if takeoff is not None:
        rows.append((f"{_s(takeoff.t_start_ns, traj):.0f} s", "take-off"))
    for strip in traj.strips:
        a, b = _s(strip.t_start_ns, traj), _s(strip.t_end_ns, traj)
        rows.append((f"{a:.0f}-{b:.0f} s", f"strip {strip.index} (--strip {strip.index} starts "
                     f"at {max(0.0, a - STRIP_LEAD_S):.0f} s)"))
    rows.append((f"{flight_s:.0f} s", "end"))
    width = max(len(when) for when, _ in rows)
    lines = [f"timeline of {scn.block.name} ({flight_s:.0f} s; --start counts from 0):"]
    lines += [f"  {when:>{width}}  {what}" for when, what in rows]
    end_s = min(flight_s, start_s + duration_s) if duration_s is not None else flight_s
    held = [st.index for st in traj.strips
            if _s(st.t_start_ns, traj) < end_s and _s(st.t_end_ns, traj) > start_s]
    holds = (f"strip {', '.join(map(str, held))}" if len(held) == 1 else
             f"strips {', '.join(map(str, held))}" if held else "no strip")
    lines.append(f"this run: {start_s:.0f}-{end_s:.0f} s, {holds}")
    return lines


def imaging_warning(traj: TruthTrajectory, start_s: float, duration_s: float | None
                    ) -> str | None:
    """What a run over this window will lack, said before it starts: no strip at all (the
    scanner records nothing, `sisa process` has nothing to georeference), or a strip entered
    with too little scanner-off flight before it for `sisa sync` to time the INS records."""
    flight_s = traj.duration_s
    end_s = min(flight_s, start_s + duration_s) if duration_s is not None else flight_s
    strips = [(st.index, _s(st.t_start_ns, traj), _s(st.t_end_ns, traj)) for st in traj.strips]
    held = [(k, a, b) for k, a, b in strips if a < end_s and b > start_s]
    if not strips:
        return None
    if not held:
        nxt = next(((k, a, b) for k, a, b in strips if a >= end_s), strips[-1])
        return (f"this run ({start_s:.0f}-{end_s:.0f} s of the flight) holds no strip: the "
                "scanner records no image, and `sisa process` will have nothing to "
                f"georeference; strip {nxt[0]} is at {nxt[1]:.0f}-{nxt[2]:.0f} s "
                f"(--strip {nxt[0]})")
    k, a, b = held[0]
    if a - start_s < MODE1_BEFORE_S:
        where = (f"inside strip {k} ({a:.0f}-{b:.0f} s)" if a <= start_s else
                 f"{a - start_s:.0f} s before strip {k} (at {a:.0f} s)")
        return (f"this run starts {where}: `sisa sync` needs about {MODE1_BEFORE_S:g} s of "
                "scanner-off pulses first "
                f"to time the INS records, and may leave them untimed (--strip {k} starts "
                f"{STRIP_LEAD_S:g} s before it)")
    return None


def _run(args: argparse.Namespace) -> int:
    from emulators.bridge import CanTarget, RealTimeBridge
    from emulators.runtime import Runner
    from emulators.system import EmulatedSystem
    from emulators.trajectory import TruthTrajectory

    scn = scenario_from_args(args)
    traj = TruthTrajectory.from_scenario(scn)
    check_span(scn, traj, args)
    warning = imaging_warning(traj, args.start, args.duration)
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
                                gps_copy=args.gpsd, camera=scn.camera is not None)
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
    if not args.quiet:
        print("\n".join(timeline(scn, traj, args.start, args.duration)), flush=True)
    if warning is not None and args.progress_as == "emulate":  # (sisa bench has said it)
        say_warning("emulate", warning)
    start = system.traj.t_start_ns + int(args.start * 1e9)
    until = None  # a --duration past the end of the scenario is the scenario (1e308 s too)
    if args.duration is not None and args.duration * 1e9 < system.traj.t_end_ns - start:
        until = start + int(args.duration * 1e9)
    started = time.monotonic()
    failed: RecorderError | None = None  # the scanner's recording, on a full disk
    truth_failed: RecorderError | None = None
    try:
        try:
            with progress(args.progress_as, quiet=args.quiet, refresh_hz=2) as bar:
                bar.follow(_follow(bar, runner, system.traj.t_start_ns, start,
                                   until or system.traj.t_end_ns))
                runner.run(until_ns=until, should_stop=stop.is_set, skip_until_ns=start)
        except RecorderError as exc:  # the devices stopped (and the scanner closed its files)
            failed = exc
        if args.hold and not stop.is_set():  # a recorder on the ports is stopped first
            print(HELD_LINE if failed is None else HELD_FAILED_LINE, flush=True)
            while not stop.wait(0.5):  # a bare wait() would defer the signal handler
                pass
    finally:
        if gpsd is not None:
            gpsd.stop()
        bridge.close()
        try:
            system.write_truth(args.out / "truth")
        except RecorderError as exc:
            truth_failed = exc
    if failed is not None:
        truth = (f"truth: {truth_failed}" if truth_failed is not None else
                 f"the truth tables are whole in {args.out / 'truth'}")
        raise RecorderError(f"{failed}; {truth}") from failed
    if truth_failed is not None:
        raise truth_failed
    print(f"emulate: {runner.outputs} outputs in {time.monotonic() - started:.1f} s; "
          f"latest emission {runner.late_ns_max / 1e6:.2f} ms behind schedule; "
          f"truth in {args.out / 'truth'}", flush=True)
    refused = bridge.pulses.refused_note()
    if refused is not None:
        say_warning("emulate", refused)
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
    if "camera" in endpoints:
        print(f"Frame camera photo numbers (RS-232):   {endpoints['camera']}")
    print(f"Running {name} at {args.speed:g}x real time; Ctrl-C to stop.", flush=True)
