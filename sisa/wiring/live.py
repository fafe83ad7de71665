"""The live view: a recording served over the Foxglove WebSocket protocol while it is made, so
the crew sees in the air what `sisa sync` would say after landing (docs/live.md).

The recorder's duties come first. The recorder hands each message to `LiveView.tap` after
writing it, already encoded: the tap passes the same bytes to a foxglove-sdk channel (the
SDK's server runs in its own native threads and drops the oldest messages of a client that
does not keep up; with no client subscribed the SDK drops the message at once) and notes a few
fields of the sync unit's and the health messages. A thread builds the derived topics once a
second, each only while a client is subscribed to it; the incremental sync runs in a process of
its own at a lower priority (`sisa.wiring.livesync`) and its passes come back through a pipe.
A failure of any of it is counted, never raised into the recording.

What a client does must not reach the recording (docs/live.md): the SDK's server threads run
at the incremental sync's lower priority, so a flood of connections competes with the sync
unit's real-time loop only for what the loop leaves; and the SDK's own log records (one for
every bad frame or failed handshake) are not forwarded into Python, where each took the
interpreter lock in a server thread and printed a line on the crew's terminal.

Topics served, besides every logged one with its schema:
    /live/sync            sisa.LiveSync: mode, LFSR, pulses forwarded and tagged, PPS lock, and
                          the incremental sync's progress and warnings
    /live/health          sisa.LiveHealth: decode errors, drops, late edges, reconnects, disk
                          free and time to full, the live view's own counts
    /live/position        foxglove.LocationFix: the antenna, coloured by sync state
    /live/map/strips      foxglove.GeoJSON: the planned strips' swaths
    /live/map/footprint   foxglove.GeoJSON: what has been recorded, coloured by sync state
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Final, Literal

import foxglove
from foxglove.channels import GeoJsonChannel, LocationFixChannel
from foxglove.messages import Color, GeoJson, LocationFix, Timestamp
from foxglove.websocket import WebSocketServer

from acquisition.clocks import wall_clock_ns
from recorder.messages import (
    GpsFix,
    GpsTimeTag,
    LoggedMessage,
    StreamHealth,
    SyncForward,
    SyncModeSwitch,
    SyncPps,
    SyncSession,
    Topic,
)
from recorder.writer import LOCATION_FIX_SCHEMA_NAME, SCHEMA_BYTES, TOPIC_TYPES, split_parts
from sisa.core.errors import InputError

if TYPE_CHECKING:
    from emulators.scenario import Scenario

PUBLISH_PERIOD_S: Final = 1.0
STRIPS_PERIOD_S: Final = 5.0  # a client that connects later gets the plan within this
PPS_LOCK_NS: Final = 2_500_000_000  # a PPS with its GPS second this recently: locked
DISK_RATE_WINDOW_S: Final = 30.0
SYNC_PERIOD_S: Final = 5.0
FINAL_PASS_TIMEOUT_S: Final = 120.0
STALE_SYNC_S: Final = 60.0  # no pass for this long: the crew is told the view is old
SERVER_NICENESS: Final = 10  # the SDK's threads: as the incremental sync (livesync.NICENESS)
GREEN: Final = Color(r=0.17, g=0.63, b=0.17, a=1.0)
AMBER: Final = Color(r=1.0, g=0.5, b=0.05, a=1.0)
RED: Final = Color(r=0.84, g=0.15, b=0.16, a=1.0)


def _schema(title: str, description: str, props: dict[str, str]) -> dict[str, Any]:
    """A JSON Schema whose every property is required, of the given JSON types."""
    return {"title": title, "description": description, "type": "object",
            "properties": {name: {"type": kind} for name, kind in props.items()},
            "required": list(props)}


LIVE_SYNC_SCHEMA: Final = _schema(
    "sisa.LiveSync", "The sync unit's state and the incremental sync's progress, once a second",
    {"t_host_ns": "integer", "mode": "integer", "session": "integer", "lfsr_state": "integer",
     "lfsr_bit": "integer", "pps_seen": "integer", "pps_locked": "boolean",
     "last_pps_gps_ns": "integer", "pulses_forwarded": "integer",
     "pulses_to_gps_event": "integer", "ttt_tags": "integer", "ptt_tags": "integer",
     "sync_pass": "integer", "ins_records": "integer", "ins_timed": "integer",
     "ins_timed_pct": "number", "ins_timed_until_gps_ns": "integer",
     "lines": "integer", "lines_timed": "integer", "lines_timed_until_gps_ns": "integer",
     "segment": "integer", "segment_lines": "integer", "segment_lines_timed_pct": "number",
     "sync_age_s": "number", "warning_count": "integer", "warnings": "array",
     "note": "string"})
LIVE_SYNC_SCHEMA["properties"]["warnings"]["items"] = {"type": "string"}

LIVE_HEALTH_SCHEMA: Final = _schema(
    "sisa.LiveHealth", "The recording's health, once a second: totals since it started",
    {"t_host_ns": "integer", "decode_errors": "integer", "bytes_skipped": "integer",
     "drops": "integer", "late_edges": "integer", "disconnects": "integer",
     "reconnects": "integer", "devices_away": "integer", "log_bytes": "integer",
     "disk_free_bytes": "integer", "write_rate_bps": "number", "time_to_full_s": "number",
     "served_messages": "integer", "serve_failures": "integer", "sync_passes": "integer",
     "sync_failures": "integer"})


def listen_address(text: str) -> tuple[str, int]:
    """--live [HOST:]PORT: loopback unless a host is given (the view holds the whole flight)."""
    host, sep, port_text = text.rpartition(":")
    host = host if sep else "127.0.0.1"
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not (port_text.isascii() and port_text.isdigit()) or not 0 <= int(port_text) <= 65535:
        raise InputError(f"--live {text}: give [HOST:]PORT, the port a number from 0 to 65535")
    return host or "127.0.0.1", int(port_text)


@dataclass
class _SyncUnit:
    """The latest of what the sync unit and the receiver logged."""

    mode: int = 0
    session: int = -1
    lfsr_state: int = -1
    lfsr_bit: int = -1
    pps_seen: int = 0
    last_pps_host_ns: int = -1
    last_pps_gps_ns: int = -1
    forwarded: int = 0
    to_gps_event: int = 0
    ttt: int = 0
    ptt: int = 0
    health: dict[str, StreamHealth] = field(default_factory=dict)
    fix: GpsFix | None = None

    def observe(self, msg: LoggedMessage) -> None:
        if isinstance(msg, SyncPps):
            self.pps_seen += 1
            self.mode, self.session = msg.mode, msg.session
            self.lfsr_state, self.lfsr_bit = msg.lfsr_state, msg.lfsr_bit
            if msg.gps_second_ns >= 0:
                self.last_pps_host_ns, self.last_pps_gps_ns = msg.t_host_ns, msg.gps_second_ns
        elif isinstance(msg, SyncForward):
            self.forwarded += 1
            self.to_gps_event += msg.to_gps_event
        elif isinstance(msg, GpsTimeTag):
            if msg.kind == "TTT":
                self.ttt += 1
            else:
                self.ptt += 1
        elif isinstance(msg, SyncModeSwitch):
            self.mode = msg.to_mode
        elif isinstance(msg, SyncSession):
            self.session = msg.session
        elif isinstance(msg, StreamHealth):
            self.health[msg.stream] = msg
        elif isinstance(msg, GpsFix) and msg.quality > 0:
            self.fix = msg


OBSERVED_TOPICS: Final = frozenset(
    cls.topic for cls in (SyncPps, SyncForward, GpsTimeTag, SyncModeSwitch, SyncSession,
                          StreamHealth, GpsFix))
"""What `_SyncUnit.observe` reads; the tap hands it nothing else (most messages are INS
records, headers, edges and raw bytes)."""


def start_server(host: str, port: int, context: foxglove.Context) -> WebSocketServer:
    """foxglove-sdk's server, its threads at SERVER_NICENESS: they are created by the thread
    that starts the server and take its priority (Linux keeps one per thread), so they are
    started from a short-lived thread that lowers its own first. Its log records stay in the
    SDK: the `foxglove` logger's level is set above CRITICAL first, and pyo3-log caches it, so
    a record (one per bad frame of a client) is dropped in the server thread without entering
    Python; forwarded, each took the interpreter lock and printed on the crew's terminal."""
    logging.getLogger("foxglove").setLevel(logging.CRITICAL + 1)
    started: list[WebSocketServer | BaseException] = []

    def start() -> None:
        with contextlib.suppress(OSError):  # not lowered: the server still serves
            os.setpriority(os.PRIO_PROCESS, 0, SERVER_NICENESS)  # this thread only (Linux)
        try:
            started.append(foxglove.start_server(name="sisa", host=host, port=port,
                                                 context=context))
        except BaseException as exc:  # handed to the caller's thread
            started.append(exc)

    starter = threading.Thread(target=start, name="sisa-live-start")
    starter.start()
    starter.join()
    if isinstance(started[0], BaseException):
        raise started[0]
    return started[0]


class _Latched:
    """A channel whose latest message a newly subscribed client gets at once (the plan, the
    footprint), and nothing is sent while no client is subscribed."""

    def __init__(self, channel: GeoJsonChannel) -> None:
        self.channel = channel
        self.latest: str = ""
        self._subscribed = False

    def put(self, geojson: str) -> None:
        self.latest = geojson
        if self.channel.has_sinks():
            self.channel.log(GeoJson(geojson=geojson), log_time=wall_clock_ns())

    def resend_if_new_subscriber(self, again_at: float) -> bool:
        """Send the latest again if a client has subscribed since the last look, or at
        `again_at` (monotonic s; a second client subscribed beside the first); whether sent."""
        subscribed = self.channel.has_sinks()
        fresh, self._subscribed = subscribed and not self._subscribed, subscribed
        if self.latest and subscribed and (fresh or time.monotonic() >= again_at):
            self.channel.log(GeoJson(geojson=self.latest), log_time=wall_clock_ns())
            return True
        return False


class LiveView:
    """A Foxglove WebSocket server for one recording; `tap` is the recorder's."""

    def __init__(self, host: str, port: int, log: Path, *, strips_geojson: str = "",
                 half_swath_m: float = 0.0, sync_out: Path | None = None,
                 sync_period_s: float = SYNC_PERIOD_S, camera: bool = False) -> None:
        """`camera`: a frame camera is recorded, so its topics are served (a flight without
        one advertises no channel that can never carry a message)."""
        self.log = log
        self._ctx = foxglove.Context()
        try:
            self.server = start_server(host, port, self._ctx)
        except Exception as exc:  # the SDK's own error type: a port in use, a bad address
            raise InputError(f"--live {host}:{port}: cannot serve: {exc}") from None
        self.port = self.server.port
        self._channels = {
            str(topic): foxglove.Channel(
                str(topic), context=self._ctx, message_encoding="json",
                schema=foxglove.Schema(name=name, encoding="jsonschema",
                                       data=SCHEMA_BYTES[name]))
            for topic, name in _logged_schemas(camera).items()}
        self._sync_ch = foxglove.Channel("/live/sync", schema=LIVE_SYNC_SCHEMA,
                                         context=self._ctx)
        self._health_ch = foxglove.Channel("/live/health", schema=LIVE_HEALTH_SCHEMA,
                                           context=self._ctx)
        self._position_ch = LocationFixChannel("/live/position", context=self._ctx)
        self._strips = _Latched(GeoJsonChannel("/live/map/strips", context=self._ctx))
        self._strips.latest = strips_geojson
        self._footprint = _Latched(GeoJsonChannel("/live/map/footprint", context=self._ctx))
        self.unit = _SyncUnit()
        self.served = 0
        self.failures = 0
        self._sync: dict[str, Any] = {}
        self._sync_wall_ns = 0
        self.sync_passes = 0
        self.sync_failures = 0
        self._sizes: list[tuple[float, int]] = []
        self._started_ns = wall_clock_ns()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        cmd = [sys.executable, "-m", "sisa.wiring.livesync", "--log", str(log),
               "--period", str(sync_period_s), "--half-swath-m", str(half_swath_m)]
        if sync_out is not None:
            cmd += ["--out", str(sync_out)]
        self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                      stderr=subprocess.DEVNULL, start_new_session=True)
        self._reader = threading.Thread(target=self._read_passes, name="sisa-live-sync",
                                        daemon=True)
        self._reader.start()
        self._publisher = threading.Thread(target=self._publish_loop, name="sisa-live",
                                           daemon=True)
        self._publisher.start()

    # --- in the recorder's thread: keep it short ---------------------------------------------

    def tap(self, topic: Topic, _schema_name: str, msg: LoggedMessage, log_ns: int,
            data: bytes) -> None:
        """A message the recorder has just written: to its channel, as written."""
        try:
            self._channels[topic].log(data, log_time=log_ns)
            self.served += 1
            if topic in OBSERVED_TOPICS:  # (not GPS_LOCATION: the fix comes on its own)
                self.unit.observe(msg)
        except Exception:  # the view loses a message, never the log
            self.failures += 1

    # --- beside it ---------------------------------------------------------------------------

    def _read_passes(self) -> None:
        stdout = self._proc.stdout
        if stdout is None:
            return
        for line in stdout:
            try:
                result = json.loads(line)
                if "error" in result:
                    self.sync_failures += 1
                    continue
                with self._lock:
                    self._sync, self._sync_wall_ns = result, wall_clock_ns()
                    self.sync_passes += 1
                self._footprint.put(result["footprint"])
            except (ValueError, KeyError, TypeError):
                self.sync_failures += 1

    def _publish_loop(self) -> None:
        next_strips = 0.0
        while not self._stop.wait(PUBLISH_PERIOD_S):
            try:
                self.publish()
                if self._strips.resend_if_new_subscriber(next_strips):
                    next_strips = time.monotonic() + STRIPS_PERIOD_S
                self._footprint.resend_if_new_subscriber(float("inf"))
            except Exception:  # the next second tries again
                self.failures += 1

    def publish(self, *, every: bool = False) -> None:
        """The derived topics, now: those a client is subscribed to (`every`: all of them)."""
        now_ns = wall_clock_ns()
        want_sync, want_fix = self._sync_ch.has_sinks(), self._position_ch.has_sinks()
        if every or self._health_ch.has_sinks():
            self._health_ch.log(self.health(now_ns), log_time=now_ns)
        if not (every or want_sync or want_fix):
            return
        state = self.sync_state(now_ns)
        if every or want_sync:
            self._sync_ch.log(state, log_time=now_ns)
        fix = self.unit.fix
        if fix is not None and (every or want_fix):
            colour = RED if state["warning_count"] else GREEN if state["ins_timed"] else AMBER
            self._position_ch.log(LocationFix(
                timestamp=Timestamp(sec=fix.t_host_ns // 10**9, nsec=fix.t_host_ns % 10**9),
                frame_id="gps_antenna", latitude=fix.lat_deg, longitude=fix.lon_deg,
                altitude=fix.height_m, color=colour), log_time=now_ns)

    def sync_state(self, now_ns: int) -> dict[str, Any]:
        u = self.unit
        with self._lock:
            sync, sync_wall = dict(self._sync.get("state", {})), self._sync_wall_ns
            warnings = list(self._sync.get("warnings", []))
        locked = u.last_pps_host_ns >= 0 and now_ns - u.last_pps_host_ns < PPS_LOCK_NS
        age_s = (now_ns - sync_wall) / 1e9 if sync_wall else -1.0
        code = self._proc.poll()
        if code is not None and not self._stop.is_set():
            warnings.append(f"incremental sync stopped (exit {code}): what it says is its "
                            "last pass; the recording goes on")
        elif (age_s if sync_wall else (now_ns - self._started_ns) / 1e9) > STALE_SYNC_S:
            warnings.append(f"incremental sync silent for over {STALE_SYNC_S:g} s (a busy "
                            "machine?): what it says is its last pass")
        return {
            "t_host_ns": now_ns, "mode": u.mode, "session": u.session,
            "lfsr_state": u.lfsr_state, "lfsr_bit": u.lfsr_bit, "pps_seen": u.pps_seen,
            "pps_locked": locked, "last_pps_gps_ns": u.last_pps_gps_ns,
            "pulses_forwarded": u.forwarded, "pulses_to_gps_event": u.to_gps_event,
            "ttt_tags": u.ttt, "ptt_tags": u.ptt, "sync_pass": int(self._sync.get("pass", 0)),
            "ins_records": int(sync.get("ins_records", 0)),
            "ins_timed": int(sync.get("ins_timed", 0)),
            "ins_timed_pct": float(sync.get("ins_timed_pct", 0.0)),
            "ins_timed_until_gps_ns": int(sync.get("ins_timed_until_gps_ns", -1)),
            "lines": int(sync.get("lines", 0)), "lines_timed": int(sync.get("lines_timed", 0)),
            "lines_timed_until_gps_ns": int(sync.get("lines_timed_until_gps_ns", -1)),
            "segment": int(sync.get("segment", -1)),
            "segment_lines": int(sync.get("segment_lines", 0)),
            "segment_lines_timed_pct": float(sync.get("segment_lines_timed_pct", 0.0)),
            "sync_age_s": round(age_s, 1),
            "warning_count": len(warnings), "warnings": warnings,
            "note": str(sync.get("note", "")),
        }

    def health(self, now_ns: int) -> dict[str, Any]:
        reports = list(self.unit.health.values())
        log_bytes = sum(p.stat().st_size for p in split_parts(self.log) if p.exists())
        free = shutil.disk_usage(self.log.parent).free
        now = time.monotonic()
        self._sizes = [s for s in self._sizes if now - s[0] <= DISK_RATE_WINDOW_S]
        self._sizes.append((now, log_bytes))
        span = now - self._sizes[0][0]
        rate = (log_bytes - self._sizes[0][1]) / span if span > 0 else 0.0
        return {
            "t_host_ns": now_ns,
            "decode_errors": sum(r.checksum_errors + r.framing_errors for r in reports),
            "bytes_skipped": sum(r.bytes_skipped for r in reports),
            "drops": sum(r.drops for r in reports),
            "late_edges": sum(r.deadline_misses for r in reports),
            "disconnects": sum(r.disconnects for r in reports),
            "reconnects": sum(r.reconnects for r in reports),
            "devices_away": sum(r.link_lost_ns >= 0 for r in reports),
            "log_bytes": log_bytes, "disk_free_bytes": free, "write_rate_bps": round(rate, 1),
            "time_to_full_s": round(free / rate, 0) if rate > 0 else -1.0,
            "served_messages": self.served, "serve_failures": self.failures,
            "sync_passes": self.sync_passes, "sync_failures": self.sync_failures,
        }

    def close(self) -> None:
        """After the recording has closed: the incremental sync's last pass on the finished
        file, published, then the server stops."""
        stdin: IO[bytes] | None = self._proc.stdin
        if stdin is not None:
            with contextlib.suppress(OSError):
                stdin.close()
        try:
            self._proc.wait(timeout=FINAL_PASS_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        self._reader.join(timeout=5.0)
        self._stop.set()
        self._publisher.join(timeout=5.0)
        with contextlib.suppress(Exception):
            self.publish(every=True)
        self.server.stop()

    def summary(self) -> str:
        """One line for the end of the recording."""
        with self._lock:
            state = dict(self._sync.get("state", {}))
        timed = (f"; last pass: INS records {state.get('ins_timed', 0)}/"
                 f"{state.get('ins_records', 0)} timed, scan lines {state.get('lines_timed', 0)}/"
                 f"{state.get('lines', 0)}" if state else "")
        return (f"live view: {self.served} messages served, {self.failures} serving failures; "
                f"incremental sync: {self.sync_passes} passes, {self.sync_failures} failed"
                f"{timed}")


CAMERA_TOPICS: Final = frozenset({str(Topic.CAMERA_RAW), str(Topic.CAMERA_PHOTO),
                                  str(Topic.SYNC_CAMERA)})


def _logged_schemas(camera: bool) -> dict[str, str]:
    """Every topic the recorder writes (the frame camera's only with one), with its schema's
    name."""
    table = {str(topic): cls.schema_name for topic, cls in TOPIC_TYPES.items()
             if camera or str(topic) not in CAMERA_TOPICS}
    table[str(Topic.GPS_LOCATION)] = LOCATION_FIX_SCHEMA_NAME
    return table


def planned_strips(scn: Scenario) -> tuple[str, float]:
    """(GeoJSON of every planned strip's swath on the ground, half the swath width in metres),
    from the scenario the flight was planned with."""
    from emulators.block import block_figures, strip_lines
    from emulators.localplane import LocalPlane

    plane = LocalPlane.for_scenario(scn)
    half = block_figures(scn).swath_width_m / 2.0
    features = []
    for strip in strip_lines(scn):
        (e0, n0), (e1, n1) = strip.start_en_m, strip.end_en_m
        length = strip.length_m
        if length <= 0:
            continue
        re, rn = (n1 - n0) / length * half, -(e1 - e0) / length * half  # to the right
        east = [e0 + re, e1 + re, e1 - re, e0 - re, e0 + re]
        north = [n0 + rn, n1 + rn, n1 - rn, n0 - rn, n0 + rn]
        lat, lon = plane.plane_to_geodetic(east, north)
        features.append({
            "type": "Feature",
            "geometry": {"type": "Polygon", "coordinates": [
                [[round(float(a), 7), round(float(b), 7)] for a, b in zip(lon, lat, strict=True)]]},
            "properties": {"name": f"planned strip {strip.index} ({strip.kind})",
                           "strip": strip.index,
                           "style": {"color": "#1f77b4", "weight": 1, "opacity": 0.8,
                                     "fillOpacity": 0.05}},
        })
    return json.dumps({"type": "FeatureCollection", "features": features},
                      separators=(",", ":")), half


def layout_json() -> str:
    """The Foxglove layout of the live view (docs/live-layout.json is this, written by
    `python -m sisa.wiring.live`): the map with the strips, the footprint and the antenna; the
    sync mode and warnings as state transitions; how far the sync has timed, as a plot;
    indicators for PPS lock, warnings and late edges; the raw sync and health messages."""
    import foxglove.layouts as fl

    def split(direction: Literal["row", "column"],
              *items: tuple[float, fl.BasePanel | fl.SplitContainer]) -> fl.SplitContainer:
        return fl.SplitContainer(direction=direction, items=[
            fl.SplitItem(proportion=p, content=c) for p, c in items])

    def indicator(title: str, path: str, rules: list[fl.IndicatorRule], fallback: str
                  ) -> fl.IndicatorPanel:
        return fl.IndicatorPanel(title=title, config=fl.IndicatorConfig(
            path=path, style="background", rules=rules, fallback_color="#888888",
            fallback_label=fallback))

    map_panel = fl.MapPanel(title="strips, footprint (green: timed), antenna", config=fl.MapConfig(
        follow_topic="/live/position", layer="map", topic_colors={"/gps/location_fix": "#1f77b4"},
        disabled_topics=[]))
    states = fl.StateTransitionsPanel(
        title="sync mode and warnings", config=fl.StateTransitionsConfig(paths=[
            fl.StateTransitionsSeries(value="/live/sync.mode", label="mode (1 PPS, 2 frames)"),
            fl.StateTransitionsSeries(value="/live/sync.pps_locked", label="PPS lock"),
            fl.StateTransitionsSeries(value="/live/sync.warning_count", label="warnings")]))
    plot = fl.PlotPanel(title="timed by the incremental sync (%)", config=fl.PlotConfig(paths=[
        fl.PlotSeries(value="/live/sync.ins_timed_pct", label="INS records timed %"),
        fl.PlotSeries(value="/live/sync.segment_lines_timed_pct", label="lines timed % (strip)"),
    ], show_legend=True))
    lights = split(
        "row",
        (1, indicator("PPS", "/live/sync.pps_locked", [
            fl.IndicatorRule(operator="=", raw_value="true", color="#2ca02c", label="PPS locked")],
            "no PPS")),
        (1, indicator("sync", "/live/sync.warning_count", [
            fl.IndicatorRule(operator="=", raw_value="0", color="#2ca02c", label="sync OK")],
            "WARNING: see /live/sync")),
        (1, indicator("late edges", "/live/health.late_edges", [
            fl.IndicatorRule(operator="=", raw_value="0", color="#2ca02c", label="0 late edges")],
            "late edges")))
    raw = split("row", (1, fl.RawMessagesPanel(title="sync", config=fl.RawMessagesConfig(
                    topic_path="/live/sync"))),
                (1, fl.RawMessagesPanel(title="health", config=fl.RawMessagesConfig(
                    topic_path="/live/health"))))
    right = split("column", (1, lights), (2, states), (2, plot), (3, raw))
    layout = fl.Layout(content=split("row", (3, map_panel), (2, right)))
    return json.dumps(json.loads(layout.to_json()), indent=2) + "\n"


if __name__ == "__main__":
    sys.stdout.write(layout_json())
