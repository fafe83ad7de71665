"""`sisa replay`: a recorded flight played back into virtual devices — the GPS and scanner ptys,
the INS CAN channel and the pulse-line link, the same endpoints `sisa emulate` offers — at the
recorded timing, so acquisition software (`sisa record`, or anyone's) meets a real flight on a
desk. The schedule, pacing and pause arithmetic live in `recorder.replay`; this module owns the
ports, the wall clock, the keyboard and the progress display."""

from __future__ import annotations

import argparse
import gc
import os
import queue
import select
import shutil
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any, Protocol

from sisa.commands import (
    FLIGHT_HELP,
    SubParsers,
    add_command,
    add_scenario_args,
    check_endpoints_path,
    check_port,
    flight_parts,
    say_warning,
    scenario_from_args,
    write_endpoints,
)
from sisa.core.errors import ConfigError, InputError

if TYPE_CHECKING:
    import can
    from rich.progress import Progress, TaskID

    from acquisition.pulses import Edge
    from emulators.bridge import CanTarget
    from emulators.ports import PtyPort
    from recorder.replay import (
        CanFrame,
        GpsClock,
        Item,
        LoopEdges,
        PlayClock,
        RecordedEdge,
        Survey,
    )

SLEEP_SLICE_NS = 50_000_000  # longest sleep: keys and Ctrl-C are served at least this often
SPIN_NS = 100_000  # the last stretch before an item is due is spun, not slept (sleep overshoots)
REFRESH_NS = 250_000_000  # progress display period
SLACK_NS = 4_000_000  # read ahead only when the next item is this far away
DISPLAY_SLACK_NS = 8_000_000  # draw the display (~0.5 ms, more at times) only with this much
LOOKAHEAD_NS = 1_000_000_000  # items read ahead of the play position
LOOP_GAP_NS = 1_000_000_000  # log time between the passes of a loop: a quiet second
LIVE_STOP_S = 180.0  # --live: the recorder's end, its incremental sync's last pass included
LIVE_CHECK_S = 0.5  # --live: how often the replay looks whether its recorder still runs
REALTIME_PRIORITY = 10  # SCHED_FIFO priority with --realtime (1..99; kernel threads use 50)
CLIENT_SETTLE_S = 0.2  # after the pulse client connects: its reader thread starts
MIN_RATE = 0.001  # --rate: slower plays a minute of flight for more than 16 hours
DRAIN_S = 1.0  # --once: the ports stay this long after the last item (a closed pty loses data)


def register(sub: SubParsers[argparse.ArgumentParser]) -> None:
    parser = add_command(sub, "replay", "play a recorded flight back into virtual devices (GPS "
                         "and scanner ptys, INS CAN, pulse lines; the frame camera's pty when the "
                         "flight had one) at the recorded timing",
                         "sisa replay runs/bench/flight.mcap --endpoints ep.json   "
                         "(then: sisa record ... on the printed ports)")
    parser.add_argument("files", nargs="+", type=Path, metavar="FLIGHT",
                        help=FLIGHT_HELP)
    parser.add_argument("--rate", type=float, default=1.0,
                        help="times real time (default 1.0: the recorded timing)")
    parser.add_argument("--start", type=float, default=0.0, metavar="SECONDS",
                        help="start this many seconds after the first raw message")
    parser.add_argument("--duration", type=float, default=None, metavar="SECONDS",
                        help="play only this many seconds of the log")
    parser.add_argument("--topics", default=None, metavar="LIST",
                        help="play only these wires, a comma list of gps, scanner, ins, pulses, "
                             "camera "
                             "(or their raw topics, /gps/raw, ...); the others' ports stay "
                             "silent (default: all)")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--loop", action="store_true", help="start again at the end, forever")
    mode.add_argument("--once", action="store_true",
                      help="one shot for scripts and tests: no keyboard, exit when done")
    parser.add_argument("--no-wait", action="store_true",
                        help="start at once instead of waiting for a client on the pulse "
                             "link and the CAN channel")
    parser.add_argument("--can", default="slcan",
                        help="'slcan' (an SLCAN adapter on a new pty, default) or "
                             "INTERFACE:CHANNEL for python-can, e.g. socketcan:can0")
    parser.add_argument("--pulses-port", type=int, default=0,
                        help="loopback TCP port for pulse edges (default: any free port)")
    parser.add_argument("--endpoints", type=Path, default=None,
                        help="also write the endpoints as JSON to this file")
    parser.add_argument("--quiet", action="store_true", help="no progress display")
    parser.add_argument("--realtime", action="store_true",
                        help="ask for real-time scheduling (SCHED_FIFO, as `chrt -f 10`): "
                             "keeps the timing on a loaded machine; needs the privilege")
    parser.add_argument("--live", default=None, metavar="[HOST:]PORT",
                        help="desk review of the live view: a `sisa record --live` on these "
                        "ports, recording to a scratch file removed at the end, serves the "
                        "flight over the Foxglove WebSocket protocol as the crew saw it "
                        "(docs/live.md); give the flight's own --preset or --scenario")
    add_scenario_args(parser, "with --live, the recorder's settings from this")
    parser.set_defaults(handler=_run, real_time_loop=True)  # see sisa.cli.BATCH_GC_THRESHOLDS


@dataclass(frozen=True)
class _Span:
    """The part of the log to play, in log time."""

    from_ns: int
    until_ns: int  # the last message's log time, or the --duration limit
    limited: bool  # --duration given (else the frames of the last CAN batch, which lie after
    # its log time, are played too)

    @property
    def limit_ns(self) -> int | None:
        return self.until_ns if self.limited else None

    @property
    def seconds(self) -> float:
        return (self.until_ns - self.from_ns) / 1e9


def _check_numbers(args: argparse.Namespace) -> None:
    """Ranges (sisa.cli has checked that every number is finite)."""
    check_port(args.pulses_port)
    if not args.rate >= MIN_RATE:
        raise InputError(f"--rate {args.rate:g}: at least {MIN_RATE:g} (a thousandth of real "
                         "time, which plays a minute of flight in 16.7 hours)")
    if args.start < 0 or (args.duration is not None and args.duration <= 0):
        raise InputError("--start must be ≥ 0 and --duration > 0")


def _span(args: argparse.Namespace, survey: Survey) -> _Span:
    length_s = (survey.end_ns - survey.start_ns) / 1e9
    if args.start > length_s:  # compared in seconds: 1e308 s has no int64 nanoseconds
        raise InputError(f"--start {args.start:g} s is beyond the end of the log "
                         f"({length_s:.1f} s)")
    start = min(survey.end_ns, survey.start_ns + round(args.start * 1e9))
    if args.duration is None:
        return _Span(start, survey.end_ns, limited=False)
    until = start + round(min(args.duration, length_s + 1.0) * 1e9)
    return _Span(start, min(survey.end_ns, until), limited=True)


def _chosen_wires(args: argparse.Namespace, survey: Survey) -> set[str] | None:
    """--topics as the wires to play (None: all), each one the log holds."""
    if args.topics is None:
        return None
    from recorder.replay import wires_named

    chosen = wires_named(args.topics)
    absent = sorted(w.value for w in chosen if w not in survey.first_ns)
    if absent:
        held = ", ".join(sorted(w.value for w in survey.first_ns))
        raise InputError(f"--topics {args.topics}: the log holds no {', '.join(absent)} to "
                         f"play (it holds {held})")
    return {w.value for w in chosen}


def _run(args: argparse.Namespace) -> int:
    from emulators.bridge import CanTarget
    from recorder.replay import Wire, survey_log

    _check_numbers(args)
    check_endpoints_path(args.endpoints)
    paths = flight_parts(args.files)
    target = CanTarget.parse(args.can)
    survey = survey_log(paths)
    args.wires = _chosen_wires(args, survey)
    span = _span(args, survey)
    _report_damage(survey)
    sys.setswitchinterval(0.0005)  # the pacing thread gets the GIL back within 0.5 ms
    if args.realtime:
        _realtime()  # before the ports: their threads inherit it
    if args.live is not None:
        from sisa.wiring.live import listen_address

        listen_address(args.live)  # a bad address is refused before anything starts
        scenario_from_args(args)  # and a scenario that does not load
    ports = _ReplayPorts(target, args.pulses_port, camera=Wire.CAMERA in survey.first_ns
                         and (args.wires is None or "camera" in args.wires))
    recorder: _LiveRecorder | None = None
    try:
        _announce(ports.endpoints(), paths, span, args)
        if args.endpoints is not None:
            write_endpoints(args.endpoints, ports.endpoints())
        player = _Player(ports, survey, span, paths, args)
        if args.live is not None:
            recorder = _LiveRecorder(args, ports.endpoints(), player.wires)
            player.watch = recorder.check
        with _Keyboard(enabled=not args.once) as keys:
            player.keys = keys
            player.run()
        if recorder is not None:
            recorder.stop()
    finally:
        if recorder is not None:
            recorder.close()
        ports.close()
    print(player.summary(), flush=True)
    refused = ports.pulses.refused_note() if ports.pulses is not None else None
    if refused is not None:
        say_warning("replay", refused)
    return 0


def _realtime() -> None:
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(REALTIME_PRIORITY))
    except (OSError, AttributeError) as exc:
        print(f"--realtime: not granted ({exc}); playing with normal scheduling",
              file=sys.stderr)


def _report_damage(survey: Survey) -> None:
    for fs in survey.stats.files:
        if fs.truncated:
            print(f"{fs.path}: truncated (no summary): read {fs.chunks_read} complete chunks",
                  file=sys.stderr)
        if fs.chunks_skipped:
            print(f"{fs.path}: {fs.chunks_skipped} damaged chunks skipped", file=sys.stderr)


def _announce(endpoints: dict[str, str], paths: list[Path], span: _Span,
              args: argparse.Namespace) -> None:
    print(f"GPS receiver (NMEA + Ashtech, RS-232):  {endpoints['gps']}")
    print(f"Scanner frame headers (RS-232):        {endpoints['scanner']}")
    print(f"INS records (CAN):                     {endpoints['ins']}")
    print(f"Pulse lines (timestamped edges, TCP):  {endpoints['pulses']}")
    if "camera" in endpoints:
        print(f"Frame camera photo numbers (RS-232):   {endpoints['camera']}")
    parts = f" ({len(paths)} parts)" if len(paths) > 1 else ""
    keys = "" if args.once or not sys.stdin.isatty() else "; space pauses, q stops"
    only = "" if args.wires is None else f" ({', '.join(sorted(args.wires))} only)"
    print(f"Replaying {paths[0]}{parts}{only}: {span.seconds:.1f} s at {args.rate:g}x real time"
          f"{', looped' if args.loop else ''}{keys}; Ctrl-C to stop.", flush=True)


class _LiveRecorder:
    """`sisa record --live` on the replay's own ports, into a scratch folder: the live view of
    the recorded flight as the crew saw it in the air (the same recorder, sync filter, server
    and incremental sync, not a second copy of them)."""

    def __init__(self, args: argparse.Namespace, endpoints: dict[str, str],
                 wires: set[str]) -> None:
        import subprocess
        import tempfile

        self.scratch = Path(tempfile.mkdtemp(prefix="sisa-replay-live-"))
        devices = [arg for wire in ("gps", "scanner", "ins", "pulses", "camera") if wire in wires
                   for arg in (f"--{wire}", endpoints[wire])]
        scenario = (["--scenario", str(args.scenario)] if args.scenario is not None else
                    ["--preset", args.preset])
        self.proc: subprocess.Popen[str] | None = subprocess.Popen(
            [sys.executable, "-m", "sisa.cli", "record", "--quiet", *devices, *scenario,
             "--live", args.live, "--out", str(self.scratch / "flight.mcap")],
            stdout=subprocess.DEVNULL, text=True)  # stderr is ours: the address, the summary
        self._next_check_s = 0.0

    def check(self) -> None:
        """Between items, at most every LIVE_CHECK_S: a recorder that ended by itself (a port
        in use) ends the replay."""
        now = time.monotonic()
        if self.proc is None or now < self._next_check_s:
            return
        self._next_check_s = now + LIVE_CHECK_S
        if (code := self.proc.poll()) is not None:
            self.proc = None
            raise InputError(f"--live: sisa record ended (exit {code}) before the replay did")

    def stop(self) -> None:
        """Ask the recorder to end (its incremental sync's last pass included) and wait."""
        from sisa.commands.children import stop_child

        if self.proc is not None:
            stop_child(self.proc, LIVE_STOP_S, ask=True)
            self.proc = None

    def close(self) -> None:
        if self.proc is not None:  # the replay failed or was stopped hard: no last pass
            self.proc.kill()
            self.proc.wait()
            self.proc = None
        shutil.rmtree(self.scratch, ignore_errors=True)


# --- ports ----------------------------------------------------------------------------------------

class _EdgeLink(Protocol):
    """What the player needs of the pulse endpoint."""

    address: str
    edges_dropped: int

    def refused_note(self) -> str | None: ...

    @property
    def has_client(self) -> bool: ...

    def send(self, edge: Edge) -> None: ...

    def close(self) -> None: ...


def _verbatim_pulses(on_edge: Callable[[Edge], None], port: int) -> _EdgeLink:
    """A PulseEndpoint that sends each edge with the link number the recording gave it, so a
    recorder logs the same `link_seq` again (the original link's gaps stay gaps)."""
    from emulators.ports import PulseEndpoint

    class VerbatimPulseEndpoint(PulseEndpoint):
        def send(self, edge: Edge) -> None:
            self._seq[edge.line] = edge.seq  # the endpoint numbers from here: this very number
            super().send(edge)

        @property
        def has_client(self) -> bool:
            with self._lock:
                return self._client is not None

    try:
        return VerbatimPulseEndpoint(on_edge, port=port)
    except OSError as exc:
        raise ConfigError(f"cannot listen on 127.0.0.1:{port}: {exc.strerror or exc}") from None


class _ReplayPorts:
    """The endpoints of `sisa emulate` (emulators.ports pieces), driven from the schedule."""

    def __init__(self, can_target: CanTarget, pulse_port: int, camera: bool = False) -> None:
        from emulators.bridge import CanOutput
        from emulators.ports import PtyPort

        self.edges_back = 0  # the sync unit's pulses sent to us: the flight has them already
        self.gps: PtyPort = PtyPort()
        self.scanner: PtyPort = PtyPort()
        # a pty for the frame camera only when the flight had one (as `sisa emulate` opens it)
        self.camera: PtyPort | None = PtyPort() if camera else None
        self.can: CanOutput | None = None
        self.pulses: _EdgeLink | None = None
        try:
            self.can = CanOutput(can_target)
            self.pulses = _verbatim_pulses(self._edge_back, pulse_port)
        except BaseException:
            self.close()
            raise

    def _edge_back(self, _edge: Edge) -> None:
        self.edges_back += 1

    def send_can(self, msg: can.Message) -> None:
        if self.can is not None:
            self.can.send(msg)

    def clients_ready(self, wires: set[str]) -> bool:
        """Every wire that can tell has a client: the pulse link is connected and the CAN
        host opened the channel (`sisa record` opens both after its serial ports)."""
        pulses_ok = "pulses" not in wires or self.pulses is None or self.pulses.has_client
        can_ok = "ins" not in wires or self.can is None or self.can.host_open
        return pulses_ok and can_ok

    def endpoints(self) -> dict[str, str]:
        ins = self.can.channel if self.can is not None else ""
        pulses = self.pulses.address if self.pulses is not None else ""
        out = {"gps": self.gps.name, "scanner": self.scanner.name, "ins": ins, "pulses": pulses}
        if self.camera is not None:
            out["camera"] = self.camera.name
        return out

    def serial(self, wire: str) -> PtyPort:
        """The pty of a serial wire (gps, scanner, camera)."""
        port = {"gps": self.gps, "scanner": self.scanner, "camera": self.camera}[wire]
        if port is None:
            raise KeyError(wire)
        return port

    def dropped(self) -> str:
        edges = self.pulses.edges_dropped if self.pulses is not None else 0
        frames = self.can.frames_dropped if self.can is not None else 0
        ptys = [p for p in (self.gps, self.scanner, self.camera) if p is not None]
        return (f"pty bytes {sum(p.bytes_dropped for p in ptys)}, "
                f"CAN frames {frames}, edges {edges}")

    def close(self) -> None:
        if self.pulses is not None:
            self.pulses.close()
        if self.can is not None:
            self.can.close()
        self.gps.close()
        self.scanner.close()
        if self.camera is not None:
            self.camera.close()


# --- keyboard -------------------------------------------------------------------------------------

class _Keyboard:
    """Space toggles pause, q stops, when stdin is a terminal (cbreak mode, restored on exit)."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled and sys.stdin.isatty()
        self.commands: queue.SimpleQueue[str] = queue.SimpleQueue()
        self._saved: list[Any] | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def __enter__(self) -> _Keyboard:
        if self.enabled:
            import termios
            import tty

            fd = sys.stdin.fileno()
            self._saved = termios.tcgetattr(fd)
            tty.setcbreak(fd)
            self._thread = threading.Thread(target=self._read, args=(fd,), name="keys",
                                            daemon=True)
            self._thread.start()
        return self

    def _read(self, fd: int) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([fd], [], [], 0.1)
            if not ready:
                continue
            key = os.read(fd, 1)
            if key == b" ":
                self.commands.put("pause")
            elif key in (b"q", b"Q", b""):
                self.commands.put("quit")

    def __exit__(self, *_exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        if self._saved is not None:
            import termios

            termios.tcsetattr(sys.stdin.fileno(), termios.TCSADRAIN, self._saved)


# --- progress -------------------------------------------------------------------------------------

class _Display:
    """The GPS time being played: a rich bar on stderr when it is a terminal (drawn by the
    pacer when it has slack, never by a thread of its own); otherwise the plain timestamped
    lines of `sisa.commands.progress` every few seconds."""

    def __init__(self, span: _Span, gps: GpsClock, quiet: bool) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        from sisa.commands.progress import Progress as Plain

        self.span = span
        self.gps = gps
        console = Console(stderr=True)
        self.progress: Progress | None = None
        self.task: TaskID | None = None
        self.plain: Plain | None = None
        if not quiet and not console.is_terminal:
            self.plain = Plain("replay", terminal=False)
            self.plain.step("waiting for clients", span.seconds, "s", rate=False)
        self._plain_state = "waiting"
        if not quiet and console.is_terminal:
            self.progress = Progress(TextColumn("{task.description}"), BarColumn(),
                                     TextColumn("{task.completed:.1f}/{task.total:.1f} s"),
                                     TimeElapsedColumn(), console=console, auto_refresh=False)
            self.progress.start()
            self.task = self.progress.add_task("waiting for clients", total=span.seconds)

    def show(self, t_log_ns: int, state: str) -> None:
        if self.plain is not None:
            self._show_plain(t_log_ns, state)
        if self.progress is None or self.task is None:
            return
        from sisa.core.timescale import datetime_from_gps_ns, gps_week_and_tow_ns

        t_gps = self.gps.gps_ns(t_log_ns)
        when = "GPS time unknown"
        if t_gps is not None:
            week, tow = gps_week_and_tow_ns(t_gps)
            stamp = datetime_from_gps_ns(t_gps).strftime("%Y-%m-%d %H:%M:%S.%f")[:-5]
            when = f"GPS {stamp} (week {week}, {tow / 1e9:.1f} s)"
        done = min(max((t_log_ns - self.span.from_ns) / 1e9, 0.0), self.span.seconds)
        self.progress.update(self.task, completed=done, description=f"{state:<8} {when}")
        self.progress.refresh()

    def _show_plain(self, t_log_ns: int, state: str) -> None:
        plain = self.plain
        assert plain is not None
        if state != self._plain_state:  # playing (a rate and time left), waiting, paused, ended
            self._plain_state = state
            plain.step({"waiting": "waiting for clients"}.get(state, state), self.span.seconds,
                       "s", rate=state.startswith("playing"))
        done = min(max((t_log_ns - self.span.from_ns) / 1e9, 0.0), self.span.seconds)
        t_gps = self.gps.gps_ns(t_log_ns)
        if t_gps is None:
            plain.update(completed=done, note="GPS time unknown")
        else:
            from sisa.core.timescale import gps_time_label

            plain.update(completed=done, note=gps_time_label(t_gps))

    def close(self) -> None:
        if self.progress is not None:
            self.progress.stop()
        if self.plain is not None:
            self.plain.close()


class _Lookahead:
    """Items read ahead of the play position, in the pacer's slack: reading the log (a chunk
    decodes in milliseconds) must never delay an item that is due."""

    def __init__(self, items: Iterator[Item]) -> None:
        self._items = items
        self._buf: deque[Item] = deque()
        self._done = False

    def fill(self, deadline_ns: int | None, horizon_ns: int) -> None:
        """Read until the buffer reaches `horizon_ns` of log time or the wall clock reaches
        `deadline_ns` (None: no deadline)."""
        while not self._done and (not self._buf or self._buf[-1].t_log_ns < horizon_ns):
            if deadline_ns is not None and time.perf_counter_ns() >= deadline_ns:
                return
            item = next(self._items, None)
            if item is None:
                self._done = True
            else:
                self._buf.append(item)

    def pop(self) -> Item | None:
        if not self._buf:
            self.fill(None, -(2**63) + 1)  # behind: one item now (an empty buffer reads one)
        return self._buf.popleft() if self._buf else None


# --- the player -----------------------------------------------------------------------------------

@dataclass
class _Counts:
    items: int = 0
    serial_bytes: dict[str, int] = field(
        default_factory=lambda: {"gps": 0, "scanner": 0, "camera": 0})
    can_frames: int = 0
    edges: int = 0
    passes: int = 0
    late_ns: list[int] = field(default_factory=list)


class _StopError(Exception):
    """Ctrl-C, SIGTERM or q: leave the pacing loop."""


class _Player:
    """Puts each item on its wire when the play clock says it is due."""

    def __init__(self, ports: _ReplayPorts, survey: Survey, span: _Span, paths: list[Path],
                 args: argparse.Namespace) -> None:
        from recorder.replay import BoardModel, GpsClock, LoopEdges, PlayClock, ScheduleStats

        self.ports = ports
        self.span = span
        self.paths = paths
        self.args = args
        self.timeline = survey.timeline(BoardModel())
        self.wires = {str(w) for w, t in survey.last_ns.items()
                      if t >= span.from_ns and survey.first_ns[w] <= span.until_ns
                      and (args.wires is None or str(w) in args.wires)}
        self.clock: PlayClock = PlayClock(args.rate, span.from_ns, time.perf_counter_ns())
        self.loop: LoopEdges = LoopEdges(span.until_ns - span.from_ns + LOOP_GAP_NS)
        self.display = _Display(span, GpsClock(survey.gps_pairs), args.quiet)
        self.keys: _Keyboard | None = None
        self.watch: Callable[[], None] | None = None  # between items: raises to end the replay
        self.counts = _Counts()
        self.schedule_stats = ScheduleStats()
        self.stopped = False
        self._next_refresh_ns = 0
        self._stop_flag = False

    # --- control ---------------------------------------------------------------------------

    def _on_signal(self, _sig: int, _frame: FrameType | None) -> None:
        self._stop_flag = True

    def _poll(self) -> None:
        """Keys and signals, between items."""
        if self._stop_flag:
            raise _StopError
        if self.watch is not None:
            self.watch()
        keys = self.keys
        while keys is not None and not keys.commands.empty():
            if keys.commands.get() == "quit":
                raise _StopError
            self.clock.toggle(time.perf_counter_ns())

    def run(self) -> None:
        signal.signal(signal.SIGINT, self._on_signal)
        signal.signal(signal.SIGTERM, self._on_signal)
        try:
            self._wait_for_clients()
            gc.collect()
            gc.freeze()  # set-up objects leave the collector's view: no multi-ms pauses later
            self._play_passes()
            if self.args.once:
                time.sleep(DRAIN_S)  # the reader takes the last bytes before the ports close
            else:
                self._hold()
        except _StopError:
            self.stopped = True
        finally:
            self.display.close()

    def _wait_for_clients(self) -> None:
        if self.args.no_wait:
            return
        if not self.ports.clients_ready(self.wires):  # said at once, on a terminal or not
            waiting = [f"{name} {address}" for name, address, wire in (
                ("the pulse link", self.ports.endpoints()["pulses"], "pulses"),
                ("the CAN channel", self.ports.endpoints()["ins"], "ins")) if wire in self.wires]
            print(f"sisa replay: waiting for a client on {' and '.join(waiting)} before "
                  "playing (--no-wait starts at once)", file=sys.stderr, flush=True)
        while not self.ports.clients_ready(self.wires):
            self._poll()
            if self.clock.paused:  # space while waiting: start now
                self.clock.resume(time.perf_counter_ns())
                return
            self.display.show(self.span.from_ns, "waiting")
            time.sleep(0.05)
        time.sleep(CLIENT_SETTLE_S)

    def _hold(self) -> None:
        """The end of the flight: the devices fall silent but stay, until Ctrl-C or q."""
        print("end of the recording: ports stay open (Ctrl-C or q to close)", flush=True)
        while True:
            self._poll()
            self.display.show(self.span.until_ns, "ended")
            time.sleep(0.1)

    def _play_passes(self) -> None:
        from recorder.replay import Wire, iter_schedule

        while True:
            self.counts.passes += 1
            chosen = None if self.args.wires is None else {Wire(w) for w in self.args.wires}
            ahead = _Lookahead(iter_schedule(self.paths, self.span.from_ns, self.span.limit_ns,
                                             self.schedule_stats, chosen))
            ahead.fill(None, self.span.from_ns + LOOKAHEAD_NS)
            self.clock.restart(self.span.from_ns, time.perf_counter_ns())
            while (item := ahead.pop()) is not None:
                self._wait_until(item.t_log_ns, ahead)
                self._send(item)
            if not self.args.loop:
                return
            self._wait_until(self.span.until_ns + LOOP_GAP_NS, None)
            self.loop.next_pass()

    def _wait_until(self, t_log_ns: int, ahead: _Lookahead | None) -> None:
        """Sleep in slices (serving keys, reading ahead), then spin the last SPIN_NS: sleep
        overshoots."""
        while True:
            self._poll()
            due = self.clock.due_wall_ns(t_log_ns)
            now = time.perf_counter_ns()
            if due is None:
                self._refresh(now, "paused")
                time.sleep(0.05)
                continue
            if due - now > DISPLAY_SLACK_NS:
                self._refresh(now, "playing")
            if due - now > SLACK_NS:
                if ahead is not None:
                    ahead.fill(due - SLACK_NS // 2, t_log_ns + LOOKAHEAD_NS)
                now = time.perf_counter_ns()
            if due - now > SLEEP_SLICE_NS:
                time.sleep(SLEEP_SLICE_NS / 1e9)
                continue
            if due - now > 2 * SPIN_NS:
                time.sleep((due - now - SPIN_NS) / 1e9)
            while (now := time.perf_counter_ns()) < due:
                pass
            self.counts.late_ns.append(now - due)
            return

    def _refresh(self, now_ns: int, state: str) -> None:
        if now_ns >= self._next_refresh_ns:
            self._next_refresh_ns = now_ns + REFRESH_NS
            label = state if self.counts.passes <= 1 else f"{state} #{self.counts.passes}"
            self.display.show(self.clock.log_now_ns(now_ns), label)

    # --- wires -----------------------------------------------------------------------------

    def _send(self, item: Item) -> None:
        from recorder.replay import CanFrame, RecordedEdge

        payload = item.payload
        self.counts.items += 1
        if isinstance(payload, bytes):
            self.ports.serial(str(item.wire)).write(payload)
            self.counts.serial_bytes[str(item.wire)] += len(payload)
        elif isinstance(payload, CanFrame):
            self.ports.send_can(_can_message(payload))
            self.counts.can_frames += 1
        elif isinstance(payload, RecordedEdge):
            self._send_edge(payload)

    def _send_edge(self, recorded: RecordedEdge) -> None:
        from acquisition.pulses import Edge, PulseLine

        try:
            line = PulseLine[recorded.line]
        except KeyError:
            self.schedule_stats.undecodable += 1  # not a line of ours: nothing to send
            return
        seq, t_ns = self.loop.edge(recorded, self.timeline.t_edge_ns(recorded.board_ns))
        if self.ports.pulses is not None:
            self.ports.pulses.send(Edge(line, seq, t_ns))
        self.counts.edges += 1

    def summary(self) -> str:
        c = self.counts
        late = sorted(c.late_ns)
        p99 = late[min(len(late) - 1, int(0.99 * len(late)))] / 1e6 if late else 0.0
        worst = late[-1] / 1e6 if late else 0.0
        stats = self.schedule_stats
        skipped = f"; {stats.undecodable} undecodable raw messages skipped" if \
            stats.undecodable else ""
        how = "stopped" if self.stopped else "done"
        camera = (f"camera {c.serial_bytes['camera']} B, " if self.ports.camera is not None
                  else "")
        return (f"replay {how}: {c.items} items in {c.passes} pass(es): GPS "
                f"{c.serial_bytes['gps']} B, scanner {c.serial_bytes['scanner']} B, "
                f"{camera}CAN "
                f"{c.can_frames} frames, {c.edges} edges; sent late by p99 {p99:.3f} ms, max "
                f"{worst:.3f} ms; {self.ports.edges_back} pulses from the sync unit; dropped: "
                f"{self.ports.dropped()}{skipped}")


def _can_message(frame: CanFrame) -> can.Message:
    import can

    return can.Message(arbitration_id=frame.arbitration_id, is_extended_id=frame.is_extended_id,
                       data=frame.data)
