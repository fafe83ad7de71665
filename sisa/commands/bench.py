"""`sisa bench`: the desk test. `sisa emulate` and `sisa record` run as separate processes on
virtual ports (ptys), CAN (SLCAN on a pty) and the pulse link, in real time; both are stopped
cleanly at the end, or at Ctrl-C (or SIGTERM), at any moment: the run so far is kept once the
recorder has begun its flight log, and nothing before (exit 130 either way). The run folder has
the same layout as `sisa simulate`'s."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

from sisa.commands import (
    ERROR_FD_ENV,
    SubParsers,
    add_command,
    add_force_arg,
    add_scenario_args,
    say_warning,
    scenario_from_args,
)
from sisa.commands.children import Ended, stop_child
from sisa.commands.emulate import (
    HELD_FAILED_LINE,
    HELD_LINE,
    add_span_args,
    check_span,
    imaging_warning,
    timeline,
)
from sisa.commands.progress import progress
from sisa.core.errors import InputError, SisaError
from sisa.core.interrupt import Terminated, exit_code, stop_answered
from sisa.core.outdir import staged_output_dir

if TYPE_CHECKING:
    from emulators.trajectory import TruthTrajectory

ANNOUNCE_TIMEOUT_S = 60.0
MIN_REAL_S = 2.0  # of emulation: a shorter one is over before the recorder has started
DRAIN_S = 0.5  # after the emulator's last output: a frame header's latency, the read clock
EMULATOR_LAG = re.compile(r"latest emission (?P<ms>[\d.]+) ms behind schedule")
RECORDER_LATE = re.compile(r"(?P<n>\d+) late edges")


def register(sub: SubParsers[argparse.ArgumentParser]) -> None:
    parser = add_command(sub, "bench", "desk test: sisa emulate and sisa record as separate "
                         "processes on virtual ports, in real time",
                         "sisa bench --preset bench --out runs/bench-rt --strip 0   "
                         "(then: sisa process runs/bench-rt)")
    add_scenario_args(parser)
    parser.add_argument("--out", type=Path, required=True, help="new run folder")
    add_force_arg(parser)
    parser.add_argument("--speed", type=float, default=1.0, help="times real time")
    add_span_args(parser, "seconds of flight to run (default: the whole scenario, or strip "
                          "N with --strip)")
    parser.add_argument("--no-images", action="store_true", help="do not render image lines")
    parser.add_argument("--live", default=None, metavar="[HOST:]PORT",
                        help="serve the run as it is recorded over the Foxglove WebSocket "
                        "protocol (sisa record --live); the incremental sync's last tables "
                        "are kept in the run's live_sync/")
    parser.set_defaults(handler=_run, real_time_loop=True)  # see sisa.cli.BATCH_GC_THRESHOLDS


def _scenario_args(args: argparse.Namespace) -> list[str]:
    if args.scenario is not None:
        return ["--scenario", str(args.scenario.resolve())]
    return ["--preset", args.preset]


def _live_args(args: argparse.Namespace, run: Path) -> list[str]:
    if args.live is None:
        return []
    return ["--live", args.live, "--live-sync-out", str(run / "live_sync")]


def wait_for_endpoints(path: Path, proc: subprocess.Popen[str],
                       error: ErrorLine | None = None) -> dict[str, str]:
    """The endpoints `sisa emulate --endpoints PATH` announces, once the file is written
    (`error`: where the emulator says why it ended, if it does)."""
    deadline = time.monotonic() + ANNOUNCE_TIMEOUT_S
    while time.monotonic() < deadline:
        if path.exists() and path.stat().st_size:
            endpoints: dict[str, str] = json.loads(path.read_text())
            return endpoints
        if proc.poll() is not None:
            why = error.read() if error is not None else ""
            raise SisaError(f"sisa emulate: {why}" if why else
                            f"sisa emulate exited early with code {proc.returncode}")
        time.sleep(0.05)
    raise SisaError("sisa emulate did not announce its ports in time")


class ErrorLine:
    """The pipe a child gives its one error line to (SISA_ERROR_FD, sisa.commands.say_error),
    instead of the terminal: the bench says one line for the run, theirs in it. A pipe, not a
    file: it takes the line on a full disk too."""

    PREFIX = re.compile(r"^sisa \S+: error: ")

    def __init__(self) -> None:
        self._r, self._w = os.pipe()
        os.set_blocking(self._r, False)
        self._text: str | None = None

    def __enter__(self) -> ErrorLine:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    @property
    def pass_fds(self) -> tuple[int]:
        """For subprocess.Popen: the write end, to the child..."""
        return (self._w,)

    @property
    def env(self) -> dict[str, str]:
        """... and where it is."""
        return {**os.environ, ERROR_FD_ENV: str(self._w)}

    def started(self) -> None:
        """The child has its copy of the write end: the bench's goes (the line ends with
        the child)."""
        if self._w >= 0:
            os.close(self._w)
            self._w = -1

    def read(self) -> str:
        """The child's error line once it has ended ("" if it said none), read once."""
        if self._text is None:
            chunks = []
            with contextlib.suppress(BlockingIOError):
                while chunk := os.read(self._r, 65536):
                    chunks.append(chunk)
            self._text = self.PREFIX.sub("", b"".join(chunks).decode("utf-8", "replace")
                                         .strip())
        return self._text

    def close(self) -> None:
        self.started()
        if self._r >= 0:
            os.close(self._r)
            self._r = -1


def _run(args: argparse.Namespace) -> int:
    from emulators.terrain import Terrain
    from emulators.trajectory import TruthTrajectory
    from sisa.commands.scenario import scenario_toml
    from sisa.wiring.acqconfig import acquisition_config
    from sisa.wiring.simulation import write_survey_data

    scn = scenario_from_args(args)
    if args.live is not None:
        from sisa.wiring.live import listen_address

        listen_address(args.live)  # refused before anything starts
    traj = TruthTrajectory.from_scenario(scn)
    check_span(scn, traj, args)  # before anything starts
    real_s = _real_seconds(traj, args)
    if real_s < MIN_REAL_S:  # refused in one line, before the timeline and any warning
        raise InputError(f"this run plays {real_s:.2g} s of real time: sisa record takes about "
                         f"a second to start, so at least {MIN_REAL_S:g} s (a longer --duration, "
                         "or a lower --speed)")
    print("\n".join(timeline(scn, traj, args.start, args.duration)), flush=True)
    warning = imaging_warning(traj, args.start, args.duration)
    if warning is not None:
        say_warning("bench", warning)
    sisa = [sys.executable, "-m", "sisa.cli"]
    stopped: KeyboardInterrupt | None = None  # Ctrl-C or SIGTERM, at whatever moment
    with (staged_output_dir(args.out, force=args.force) as run, ErrorLine() as emu_error,
          ErrorLine() as rec_error):
        endpoints_file = run / "endpoints.json"
        emu_cmd = [*sisa, "emulate", *_scenario_args(args), "--out", str(run / "emulator"),
                   "--speed", str(args.speed), "--start", str(args.start),
                   "--endpoints", str(endpoints_file), "--hold"]
        if args.duration is not None:
            emu_cmd += ["--duration", str(args.duration)]
        if args.no_images:
            emu_cmd.append("--no-images")
        # progress: on a terminal the recorder's live status shows the run (the emulator's bar
        # would fight it); piped, the emulator's plain lines, named as the bench's
        emu_cmd += ["--progress-as", "bench", *(["--quiet"] if sys.stderr.isatty() else [])]
        emu: subprocess.Popen[str] | None = None
        rec: subprocess.Popen[str] | None = None
        rec_end = emu_end = None
        try:
            (run / "scenario.toml").write_text(scenario_toml(scn), encoding="utf-8")
            with _stops_held():  # a child started is a child the bench knows to stop
                emu = subprocess.Popen(emu_cmd, stdout=subprocess.PIPE, text=True,
                                       process_group=0,  # see STOPPED_STARTING
                                       pass_fds=emu_error.pass_fds, env=emu_error.env)
            emu_error.started()
            with progress("bench", "starting: DEM, ground points, emulator") as bar:
                # the DEM and ground points, as `sisa simulate` writes them, while the
                # emulator starts
                write_survey_data(scn, Terrain.from_scenario(scn), run / "terrain")
                bar.step("starting: waiting for the emulator's ports")
                ep = wait_for_endpoints(endpoints_file, emu, emu_error)
            with _stops_held():
                rec = subprocess.Popen([*sisa, "record", *_scenario_args(args),
                                        "--gps", ep["gps"], "--scanner", ep["scanner"],
                                        "--ins", ep["ins"], "--pulses", ep["pulses"],
                                        *(("--camera", ep["camera"]) if "camera" in ep
                                          else ()),
                                        "--out", str(run / "flight.mcap"),
                                        "--shown-as", str(args.out / "flight.mcap"),
                                        *_live_args(args, run)],
                                       stdout=subprocess.PIPE, text=True,
                                       process_group=0,
                                       pass_fds=rec_error.pass_fds, env=rec_error.env)
            rec_error.started()
            rec_end, emu_end = stop_after_hold(emu, rec, DRAIN_S / args.speed)
        except KeyboardInterrupt as exc:
            stopped = exc
            stop_answered()  # what was recorded is kept, as said below
            restore = _ignore_stops()  # a second Ctrl-C must not cut the stopping short
            try:  # the recorder first, its devices still there; then the emulator
                rec_end = stop_child(rec, ask=True) if rec is not None else None
                emu_end = stop_child(emu, ask=True) if emu is not None else None
            finally:
                restore()
        finally:  # both have ended by now, unless something went wrong: then ask them
            if rec is not None:
                stop_child(rec, ask=True)
            if emu is not None:
                stop_child(emu, ask=True)

        def shown(text: str) -> str:  # the run's files where they are kept
            return text.replace(str(run / "emulator"), str(args.out)).replace(str(run),
                                                                               str(args.out))

        if emu_end is not None:
            emu_end = emu_end._replace(error=shown(emu_error.read()))
        if rec_end is not None:
            rec_end = rec_end._replace(error=shown(rec_error.read()))
        if stopped is not None:  # their errors as they said them, beside the stop
            for name, end in (("emulate", emu_end), ("record", rec_end)):
                if end is not None and end.error:
                    print(f"sisa {name}: error: {end.error}", file=sys.stderr)
        if stopped is not None and not (run / "flight.mcap").exists():
            print("sisa bench: stopped before the recorder had begun its flight log: nothing "
                  "recorded, nothing kept", file=sys.stderr)
            raise stopped  # the run folder goes (sisa.cli says `interrupted`, exit 130)
        assert rec_end is not None
        assert emu_end is not None
        failed = None if stopped is not None else failure(emu_end, rec_end, real_s,
                                                          stopped_early=False)
        if failed and not (run / "flight.mcap").exists():  # nothing recorded: nothing kept
            raise SisaError(f"{failed}; nothing was kept (sisa record had not begun its "
                            "flight log)")
        for part in ("scanner", "truth"):
            if (run / "emulator" / part).exists():
                os.replace(run / "emulator" / part, run / part)
        shutil.rmtree(run / "emulator", ignore_errors=True)
        endpoints_file.unlink(missing_ok=True)
    # its summary, told once the run is in place, names the file where it now is
    print(rec_end.stdout.replace(str(run), str(args.out)), end="")
    lag = EMULATOR_LAG.search(emu_end.stdout)
    if lag is not None:
        print(f"emulator: latest emission {lag['ms']} ms behind schedule")
        deadline_ms = acquisition_config(scn).edge_deadline_ns / 1e6
        note = late_edges_note(rec_end.stdout, float(lag["ms"]), deadline_ms)
        if note is not None:
            print(f"sisa bench: {note}", file=sys.stderr)
    if failed:  # what was recorded is kept (the log is readable up to the failure)
        raise SisaError(f"{failed}; the run so far is in {args.out}")
    parts = [f"{p}/" if (args.out / p).is_dir() else p
             for p in ("flight.mcap", "scanner", "terrain", "truth", "live_sync")
             if (args.out / p).exists()]
    how = "" if stopped is None else ", stopped early (Ctrl-C)"
    print(f"{args.out}: {', '.join(parts)} from a real-time run of {scn.block.name}{how}",
          flush=True)
    if stopped is not None:
        print(f"sisa bench: {'terminated' if isinstance(stopped, Terminated) else 'interrupted'}"
              f": the run so far is kept in {args.out}", file=sys.stderr)
        return exit_code(stopped)
    return 0


# sisa record's exit when asked to stop (SIGTERM) before its own handler is in place:
# Terminated in `sisa.cli.main`, or death by the signal while the interpreter was starting up
STOPPED_STARTING = (143, -signal.SIGTERM)

# The children run in process groups of their own, and the bench alone stops them, with
# SIGTERM: the terminal's Ctrl-C goes to its whole foreground group, and a child still starting
# its interpreter died of it with a traceback (CI, 2026-11-28); SIGTERM, which Python leaves at
# its default until `sisa.cli` takes it, ends a starting child silently.

@contextlib.contextmanager
def _stops_held() -> Iterator[None]:
    """Ctrl-C or SIGTERM during the block is held, then raised as it ends: a stop between a
    child's start and its assignment left a recorder running that the bench did not know of
    (it then opened ports the emulator had closed; CI, 2026-11-29). The children start with
    default handlers: a Python handler is not inherited across exec."""
    held: list[int] = []

    def hold(sig: int, _frame: FrameType | None) -> None:
        held.append(sig)

    saved = {sig: signal.signal(sig, hold) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)
        if held:
            signal.raise_signal(held[0])  # now, to the handler it was meant for


def _ignore_stops() -> Callable[[], None]:
    """Ignore SIGINT and SIGTERM until the returned function puts their handlers back."""
    saved = {sig: signal.signal(sig, signal.SIG_IGN) for sig in (signal.SIGINT, signal.SIGTERM)}

    def restore() -> None:
        for sig, handler in saved.items():
            signal.signal(sig, handler)

    return restore


def failure(emu_end: Ended, rec_end: Ended, real_s: float, *, stopped_early: bool
            ) -> str | None:
    """What went wrong with the two children, if anything, in the words of the bench."""
    if emu_end.code == 0 and rec_end.code == 0:
        return None
    if emu_end.error or rec_end.error:  # (a full disk: both, often) in their words
        return "; ".join(f"sisa {name}: {end.error}" if end.error else
                         f"sisa {name} exited {end.code}"
                         for name, end in (("emulate", emu_end), ("record", rec_end))
                         if end.code != 0)
    if not stopped_early and emu_end.code == 0 and rec_end.code in STOPPED_STARTING:
        # the scenario ended and the recorder was asked to stop, as always, but it was still
        # starting up: "sisa record exited 130" said nothing of why
        return (f"the emulated run was over ({real_s:.2g} s of real time) before sisa record "
                "had started, and it was stopped starting: run for longer (--duration, or a "
                "lower --speed)")
    return f"sisa emulate exited {emu_end.code}, sisa record exited {rec_end.code}"


def late_edges_note(recorder_summary: str, emulator_lag_ms: float, deadline_ms: float
                    ) -> str | None:
    """When the recorder counted late edges, which side of the link made them late: on a desk
    the emulator shares the machine with the recorder, and an emulator that fell behind its own
    schedule sent its edges late, as a busy timing board would."""
    late = RECORDER_LATE.search(recorder_summary)
    if late is None or int(late["n"]) == 0:
        return None
    said = f"the recorder counted {late['n']} late edges"
    if emulator_lag_ms >= deadline_ms:
        return (f"{said}; the emulator itself fell {emulator_lag_ms:.0f} ms behind its schedule "
                f"at worst, past the {deadline_ms:g} ms deadline: it sent edges late (a busy "
                "desk machine), which is not the recorder's doing")
    return (f"{said}, while the emulator kept within {emulator_lag_ms:.1f} ms of its schedule "
            f"(deadline {deadline_ms:g} ms): they came late on the recorder's side of the link")


def _real_seconds(traj: TruthTrajectory, args: argparse.Namespace) -> float:
    """How long the emulator plays: --duration, or the scenario from --start, at --speed."""
    flight_s = (traj.t_end_ns - traj.t_start_ns) / 1e9 - args.start
    return float(min(flight_s, args.duration or flight_s) / args.speed)


def stop_after_hold(emu: subprocess.Popen[str], rec: subprocess.Popen[str], drain_s: float
                    ) -> tuple[Ended, Ended]:
    """(the recorder, the emulator) once ended. Once `sisa emulate --hold` says the scenario is
    over (or that it stopped on an error: a full disk), give the recorder `drain_s` for what is
    still in flight, stop it, then the emulator: the recorder ends on a stop, not on its
    devices going away (no disconnects logged, and no wait for it to give them up). If the
    recorder ends first (it failed), the emulator is stopped at once rather than left to play
    out the scenario; if the emulator ends without holding (it failed), the recorder, which
    would wait for its devices, is stopped."""
    assert emu.stdout is not None
    held = threading.Event()

    def stop_emulator_if_recorder_ends() -> None:
        rec.wait()
        if not held.is_set():
            emu.send_signal(signal.SIGTERM)

    watcher = threading.Thread(target=stop_emulator_if_recorder_ends, daemon=True)
    watcher.start()
    if any(line.rstrip("\n") in (HELD_LINE, HELD_FAILED_LINE) for line in emu.stdout):
        held.set()
        time.sleep(drain_s)
        return stop_child(rec, ask=True), stop_child(emu, ask=True)
    return stop_child(rec, ask=True), stop_child(emu)
