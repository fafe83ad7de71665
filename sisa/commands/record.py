"""`sisa record`: the real-time acquisition against real devices or the emulators: decode every
stream, run the sync filter, record everything to MCAP, show live status."""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import sys
import time
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

from sisa.commands import (
    SubParsers,
    add_command,
    add_scenario_args,
    new_file_arg,
    scenario_from_args,
)
from sisa.core.errors import InputError, RecorderError
from sisa.core.outdir import name_taken

if TYPE_CHECKING:
    from rich.table import Table

    from acquisition.live import LinkEvent, LiveSources, Source
    from acquisition.runner import Acquisition
    from emulators.scenario import Scenario
    from sisa.wiring.live import LiveView

STATUS_PERIOD_S = 1.0
TICK_S = 0.1
# A device that goes away is reopened by its reader while the others keep recording, however
# long it stays away (a USB hub reset in flight must not end the flight's recording): the
# recording ends on Ctrl-C / SIGTERM / --duration, or, with --give-up-after, when every device
# has been away that long. Devices away are said on stderr when they go, and again this long
# after the first of them went, then every AWAY_REPEAT_S.
AWAY_REMIND_S = 10.0
AWAY_REPEAT_S = 60.0
ENDED_ON_LOSS = 3  # the exit code of a recording that ended with a device away


def register(sub: SubParsers[argparse.ArgumentParser]) -> None:
    parser = add_command(sub, "record", "record a flight in real time: GPS, scanner and INS "
                         "streams, pulse lines, sync filter, to MCAP",
                         "sisa record --gps /dev/pts/4 --scanner /dev/pts/5 "
                         "--ins slcan:/dev/pts/6 --pulses tcp://127.0.0.1:40211 "
                         "--out runs/flight.mcap")
    parser.epilog = (f"exit {ENDED_ON_LOSS} if the recording ended with a device away (its "
                     "data since are missing): devices that go away are reopened until they "
                     f"come back or the recording is stopped\n\n{parser.epilog}")
    parser.add_argument("--gps", help="GPS receiver serial port")
    parser.add_argument("--scanner", help="scanner frame-header serial port")
    parser.add_argument("--ins", help="INS CAN bus as INTERFACE:CHANNEL (slcan:/dev/pts/6, "
                        "socketcan:can0, virtual:sisa)")
    parser.add_argument("--pulses", help="timing-board edge link, tcp://127.0.0.1:PORT")
    parser.add_argument("--camera", help="frame camera photo-number serial port (its "
                        "mid-exposure pulses come on the edge link)")
    parser.add_argument("--out", type=new_file_arg, required=True, help="new MCAP file")
    add_scenario_args(parser, "settings (rates, leap seconds, sync unit) from this")
    parser.add_argument("--split-minutes", type=float, default=None,
                        help="start a new file every N minutes of log time")
    parser.add_argument("--split-mb", type=float, default=None,
                        help="start a new file every N MB")
    parser.add_argument("--duration", type=float, default=None, help="stop after N seconds")
    parser.add_argument("--give-up-after", type=float, default=None, metavar="SECONDS",
                        help="end the recording when every device has been away this long "
                        f"(exit {ENDED_ON_LOSS}); default: never, it keeps reconnecting until "
                        "stopped")
    parser.add_argument("--quiet", action="store_true", help="no live status, summary only")
    parser.add_argument("--live", default=None, metavar="[HOST:]PORT",
                        help="serve the flight as it is recorded over the Foxglove WebSocket "
                        "protocol (loopback unless HOST is given; PORT 0: any free port), with "
                        "the incremental sync's progress and warnings (docs/live.md)")
    # the incremental sync's last tables (sisa bench --live keeps them beside the run)
    parser.add_argument("--live-sync-out", type=Path, default=None, help=argparse.SUPPRESS)
    # sisa bench records into a scratch folder renamed at the end: the status names the final one
    parser.add_argument("--shown-as", type=Path, default=None, help=argparse.SUPPRESS)
    parser.set_defaults(handler=_run, real_time_loop=True)  # see sisa.cli.BATCH_GC_THRESHOLDS


def _run(args: argparse.Namespace) -> int:
    from acquisition.live import LiveSources
    from acquisition.runner import Acquisition
    from recorder.writer import FlightRecorder
    from sisa.wiring.acqconfig import acquisition_config, recording_settings

    if not any((args.gps, args.scanner, args.ins, args.pulses, args.camera)):
        raise InputError("nothing to record: give at least one of --gps, --scanner, --ins, "
                         "--pulses, --camera")
    if name_taken(args.out, "--out"):
        raise InputError(f"{args.out} already exists: recordings are never overwritten")
    _check_options(args)
    scn = scenario_from_args(args)
    config = acquisition_config(scn)
    live = _start_live(args, scn) if args.live is not None else None
    try:
        sources = LiveSources(args.gps, args.scanner, args.ins, args.pulses,
                              read_interval_s=config.read_interval_ns / 1e9,
                              camera_port=args.camera)
    except BaseException:
        if live is not None:
            live.close()
        raise
    stop = _install_stop_handlers()
    split_s = args.split_minutes * 60 if args.split_minutes else None
    split_b = int(args.split_mb * 1e6) if args.split_mb else None
    wall0, cpu0 = time.monotonic(), time.process_time()
    try:
        with FlightRecorder(args.out, split_duration_s=split_s, split_size_bytes=split_b,
                            metadata={"settings": scn.block.name,
                                      **recording_settings(config)},
                            tap=live.tap if live is not None else None) as rec:
            acq = Acquisition(config, rec.write, sources.send_edge,
                              pulse_stats=sources.pulse_stats)
            away = _loop(acq, sources, stop, args)
    except RecorderError as exc:  # a recording is kept whatever happens: say how to use it
        raise RecorderError(f"{exc}; the file is readable up to its last complete chunk and "
                            "`sisa log recover` makes it whole") from exc
    finally:
        sources.close()
        if live is not None:  # the incremental sync's last pass, on the finished file
            live.close()
            print(f"sisa record: {live.summary()}", file=sys.stderr, flush=True)
    _summary(acq, args.out, time.monotonic() - wall0, time.process_time() - cpu0)
    if away:
        print(f"sisa record: recording ended with {away}: what it sent since is missing "
              f"(exit {ENDED_ON_LOSS})", file=sys.stderr, flush=True)
        return ENDED_ON_LOSS
    return 0


def _start_live(args: argparse.Namespace, scn: Scenario) -> LiveView:
    """The live view's server and incremental sync, before the recording starts."""
    from sisa.wiring.live import LiveView, listen_address, planned_strips

    host, port = listen_address(args.live)
    strips, half_swath_m = planned_strips(scn)
    live = LiveView(host, port, args.out, strips_geojson=strips, half_swath_m=half_swath_m,
                    sync_out=args.live_sync_out, camera=args.camera is not None)
    print(f"sisa record: live view on ws://{host}:{live.port} (Foxglove: open connection, "
          "Foxglove WebSocket; layout docs/live-layout.json)", file=sys.stderr, flush=True)
    return live


PTY_MULTIPLEXERS = ("/dev/ptmx", "/dev/pts/ptmx")
MIN_SPLIT_MINUTES = 0.1  # shorter parts are no flight log: a part for every few messages
MIN_SPLIT_MB = 1.0
MAX_SPLIT_MINUTES = 100_000.0  # 69 days; longer overflowed the writer's nanoseconds
MAX_SPLIT_MB = 1e9  # a petabyte; larger overflowed the byte count (1e308)


def _check_options(args: argparse.Namespace) -> None:
    if args.duration is not None and args.duration <= 0:
        raise InputError(f"--duration {args.duration:g}: must be > 0 seconds")
    if args.give_up_after is not None and args.give_up_after <= 0:
        raise InputError(f"--give-up-after {args.give_up_after:g}: must be > 0 seconds (leave "
                         "it out to keep reconnecting until stopped)")
    if args.split_minutes is not None and args.split_minutes < MIN_SPLIT_MINUTES:
        raise InputError(f"--split-minutes {args.split_minutes:g}: must be at least "
                         f"{MIN_SPLIT_MINUTES:g}")
    if args.split_mb is not None and args.split_mb < MIN_SPLIT_MB:
        raise InputError(f"--split-mb {args.split_mb:g}: must be at least {MIN_SPLIT_MB:g}")
    for option, value, most in (("--split-minutes", args.split_minutes, MAX_SPLIT_MINUTES),
                                ("--split-mb", args.split_mb, MAX_SPLIT_MB)):
        if value is not None and value > most:
            raise InputError(f"{option} {value:g}: at most {most:g} (leave it out for one "
                             "file)")
    if args.live is not None:
        from sisa.wiring.live import listen_address

        listen_address(args.live)  # a bad address is refused before anything starts
    if args.pulses:
        args.pulses = pulse_endpoint(args.pulses)
    ports = [(name, getattr(args, name)) for name in ("gps", "scanner", "ins", "camera")
             if getattr(args, name)]
    seen: dict[str, str] = {}
    for name, spec in ports:
        device = os.path.realpath(spec.split(":", 1)[1] if name == "ins" and ":" in spec
                                  else spec)
        if device in PTY_MULTIPLEXERS:  # it opened, and the recording ran with nothing in it
            raise InputError(f"--{name} {spec}: the pty multiplexer, not a port: opening it "
                             "makes a new pty that nothing writes to (give the port itself, "
                             "/dev/pts/N as `sisa emulate` prints it)")
        if device in seen:
            raise InputError(f"--{seen[device]} and --{name} name the same device {spec}")
        seen[device] = name


def pulse_endpoint(text: str) -> str:
    """--pulses as tcp://HOST:PORT, its port one a connection can be made to (a port out of
    range was refused as 'connection refused', or by getaddrinfo's 'servname not supported');
    an IPv6 address may be in brackets. Whether HOST is loopback is the pulse link's check."""
    host, sep, port_text = text.removeprefix("tcp://").rpartition(":")
    if not sep or not port_text:
        raise InputError(f"--pulses {text}: no port number (tcp://127.0.0.1:PORT)")
    if not (port_text.isascii() and port_text.isdigit()) or not 1 <= int(port_text) <= 65535:
        raise InputError(f"--pulses {text}: the port is a number from 1 to 65535")
    if host.startswith("[") and host.endswith("]"):
        return f"tcp://{host[1:-1]}:{port_text}"
    return text


def _install_stop_handlers() -> list[bool]:
    stop = [False]

    def on_signal(_sig: int, _frame: FrameType | None) -> None:
        stop[0] = True

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    return stop


def _loop(acq: Acquisition, sources: LiveSources, stop: list[bool],
          args: argparse.Namespace) -> str:
    """Record until stopped; what was away at the end ("" if nothing was), in words."""
    from acquisition.clocks import wall_clock_ns
    from acquisition.handover import Handover
    from acquisition.live import LinkEvent

    status = _Status(acq, args.out, args.shown_as or args.out, quiet=args.quiet)
    handover = Handover(acq)
    started = time.monotonic()
    next_tick = next_status = started
    down: dict[Source, float] = {}  # the devices away, since when (monotonic)
    remind_at = 0.0
    while not stop[0]:
        arrivals = sources.poll(TICK_S / 2)
        now = time.monotonic()
        for item in arrivals:
            if isinstance(item.payload, LinkEvent):
                handover.flush()
                _link_event(acq, item.t_host_ns, item.source, item.payload, down, now)
                if not down:
                    remind_at = 0.0
            else:
                handover.put(item)
        if now >= next_tick:
            handover.tick(wall_clock_ns())
            next_tick = now + TICK_S
        if now >= next_status:
            status.show()
            next_status = now + STATUS_PERIOD_S
        if args.duration is not None and now - started >= args.duration:
            break
        if down:
            every = down.keys() >= sources.open_sources
            all_away_s = now - max(down.values())  # since the last of them went
            if every and args.give_up_after is not None and all_away_s >= args.give_up_after:
                print(f"sisa record: every device away for {args.give_up_after:g} s "
                      "(--give-up-after): recording ended", file=sys.stderr, flush=True)
                break
            remind_at = remind_at or min(down.values()) + AWAY_REMIND_S
            if now >= remind_at:
                print(f"sisa record: WARNING: {_away(down, now)}"
                      f"{' (every device)' if every else ''}: still recording and "
                      "reconnecting; Ctrl-C ends the recording", file=sys.stderr, flush=True)
                remind_at = now + AWAY_REPEAT_S
    handover.flush()
    acq.finish(wall_clock_ns())
    status.close()
    return _away(down, time.monotonic())


def _away(down: dict[Source, float], now: float) -> str:
    """The devices away and for how long, in words ("" if none)."""
    return ", ".join(f"{source} away for {now - since:.1f} s"
                     for source, since in sorted(down.items(), key=lambda item: item[1]))


def _link_event(acq: Acquisition, t_host_ns: int, source: Source, event: LinkEvent,
                down: dict[Source, float], now: float) -> None:
    """A device went away, came back, or its port opened with something else behind it: into
    the health channel, and said on stderr."""
    from acquisition.live import LinkState

    if event.state is LinkState.LOST:
        down[source] = now
        acq.on_link_lost(t_host_ns, str(source), event.error)
        print(f"sisa record: {source} lost ({event.error}); reconnecting", file=sys.stderr,
              flush=True)
    elif event.state is LinkState.REJECTED:
        acq.on_link_rejected(t_host_ns, str(source), event.lost_t_host_ns, event.error)
        print(f"sisa record: {source} not reconnected: {event.error}; still waiting for the "
              f"{source}", file=sys.stderr, flush=True)
    else:
        down.pop(source, None)
        acq.on_link_restored(t_host_ns, str(source), event.lost_t_host_ns, event.attempts)
        away_s = (t_host_ns - event.lost_t_host_ns) / 1e9
        print(f"sisa record: {source} reconnected after {away_s:.1f} s", file=sys.stderr,
              flush=True)


class _Status:
    """Live status (rich): per-stream rate vs expected, errors, drops, sync mode, last PPS,
    free disk space."""

    def __init__(self, acq: Acquisition, out: Path, shown_as: Path, quiet: bool) -> None:
        from rich.console import Console
        from rich.live import Live

        self.acq = acq
        self.out, self.shown_as = out, shown_as
        self.console = Console(stderr=True)
        self.live: Live | None = None
        if not quiet and self.console.is_terminal:
            self.live = Live(self._table(), console=self.console, auto_refresh=False)
            self.live.start()

    def _table(self) -> Table:
        from rich.table import Table

        table = Table(title=f"sisa record → {self.shown_as}", expand=False)
        from acquisition.runner import STREAM_SOURCE

        # headers no wider than their column needs, never cut ("expected Hz" showed as
        # "expect…" in an 80-column terminal): the unit goes in the caption
        for col in ("stream", "messages", "rate", "expected", "gaps", "errors", "drops",
                    "late", "link"):
            table.add_column(col, justify="right", min_width=len(col), no_wrap=True)
        for name, c in self.acq.streams.items():
            link = self.acq.links[STREAM_SOURCE[name]]
            state = "away" if link.lost_t_host_ns is not None else "up"
            table.add_row(name, str(c.messages), f"{c.rate_hz:.1f}", f"{c.expected_hz:.1f}",
                          str(c.gaps), str(c.stats.errors), str(c.drops), str(c.deadline_misses),
                          f"{state} ({link.reconnects} reconnects)" if link.disconnects
                          else state)
        from sisa.core.timescale import gps_time_label

        free_gb = shutil.disk_usage(self.out.parent).free / 1e9
        pps = self.acq.last_pps_gps_ns
        table.caption = (f"rates in Hz; sync mode {self.acq.filter.mode}, session "
                         f"{self.acq.session}, "
                         f"last PPS {'-' if pps is None else gps_time_label(pps)}, "
                         f"disk free {free_gb:.1f} GB")
        return table

    def show(self) -> None:
        if self.live is not None:
            self.live.update(self._table(), refresh=True)

    def close(self) -> None:
        if self.live is not None:
            self.live.stop()


def _summary(acq: Acquisition, out: Path, wall_s: float, cpu_s: float) -> None:
    s = acq.streams
    errors = sum(c.stats.errors for c in s.values())
    drops = sum(c.drops for c in s.values())
    late = sum(c.deadline_misses for c in s.values())
    lost = sum(link.disconnects for link in acq.links.values())
    back = sum(link.reconnects for link in acq.links.values())
    restarts = (f" ({acq.timeline_restarts} begun by a pulse source that came back on an "
                "earlier timeline)" if acq.timeline_restarts else "")
    per_link = ", ".join(f"{name} {link.disconnects}/{link.reconnects}"
                         for name, link in acq.links.items() if link.disconnects)
    camera = (f", photo messages {s['camera'].messages}, camera pulses "
              f"{s['camera_pulse'].messages}" if "camera" in s else "")
    print(f"recorded {out}: INS {s['ins'].messages}, GPS sentences {s['gps'].messages}, "
          f"frame headers {s['scanner'].messages}, PPS {s['pps'].messages}, ppf "
          f"{s['ppf'].messages}{camera}; {errors} decode errors, {drops} drops, {late} late edges, "
          f"{lost} disconnects, {back} reconnects"
          f"{f' ({per_link} lost/back)' if per_link else ''}, "
          f"{acq.session + 1} sync session(s)"
          f"{restarts}; cpu {cpu_s:.2f} s in {wall_s:.1f} s "
          f"({100 * cpu_s / max(wall_s, 1e-9):.1f}% of a core)", flush=True)
