"""Replaying a flight log: the raw channels as one time-ordered schedule of what went on each wire,
and the pure arithmetic that plays it back (pacing, pause, loops, the pulse edges' timeline).

Why it is built this way:
- Only the raw channels are replayed (`/gps/raw`, `/scanner/raw`, `/ins/raw_can`, `/pulses/in`,
  and `/camera/raw` when the flight carried a frame camera):
  they are what the devices said, so any acquisition software, ours or not, decodes them afresh.
  Each item is due at its recorded host receive time (the MCAP log time; every CAN frame at its
  own receive time), so a replay at x1 puts bytes on the wires with the recorded timing.
- The log is streamed, never loaded: a long flight is millions of CAN frames. Messages are written
  to the file when a batch closes, so file order is log-time order only within a short window; a
  small heap (`REORDER_WINDOW_NS`) restores the order.
- A pulse edge travels with its time on the emulation's timeline, but the log holds only what the
  recorder's timing board made of it (`board_ns`, with its own start count and drift). The edge
  time is recovered by inverting the board model exactly, so a recorder with the same board model
  logs the very same counters again; the timeline is anchored to GPS time by the logged PPS
  seconds (`/sisa/pps`), as the emulator's edges are.
- Nothing here opens a port or reads a clock: the wiring (`sisa.commands.replay`) passes the wall
  time in, so the pacing, pause and loop arithmetic is tested without waiting.
"""

from __future__ import annotations

import base64
import bisect
import heapq
from collections.abc import Collection, Iterator
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, Final

from recorder.framing import Paths
from recorder.messages import CAN_EXTENDED_FLAG, Topic
from recorder.reader import LogReader
from recorder.stats import LogStats
from sisa.core.bounded import json_loads
from sisa.core.errors import InputError, shown_text

REORDER_WINDOW_NS: Final = 2_000_000_000  # a CAN batch is written ≤ ~0.3 s after its first frame
PPM: Final = 1e-6


class Wire(StrEnum):
    """The virtual devices a replay drives, named as `sisa emulate` names its endpoints."""

    GPS = "gps"
    SCANNER = "scanner"
    INS = "ins"
    PULSES = "pulses"
    CAMERA = "camera"  # the frame camera's photo messages (its pulses travel on PULSES)


RAW_TOPICS: Final[dict[str, Wire]] = {
    Topic.GPS_RAW: Wire.GPS,
    Topic.SCANNER_RAW: Wire.SCANNER,
    Topic.INS_RAW: Wire.INS,
    Topic.PULSE_IN: Wire.PULSES,
    Topic.CAMERA_RAW: Wire.CAMERA,
}


@dataclass(frozen=True, slots=True)
class CanFrame:
    arbitration_id: int  # without CAN_EXTENDED_FLAG
    is_extended_id: bool
    data: bytes


@dataclass(frozen=True, slots=True)
class RecordedEdge:
    """An input edge as the recorder logged it."""

    line: str  # PPS | PPF | INS_SYNC | GPS_EVENT
    link_seq: int
    board_ns: int


Payload = bytes | CanFrame | RecordedEdge


@dataclass(frozen=True, slots=True)
class Item:
    """One thing to put on a wire at `t_log_ns` (the recording's host receive time)."""

    t_log_ns: int
    wire: Wire
    payload: Payload


# --- the timing board, inverted -------------------------------------------------------------------

@dataclass(frozen=True)
class BoardModel:
    """The recorder's timing board: counter = start + dt + round(dt·drift), dt since its first
    edge (`acquisition.clocks.TimingBoard`; its defaults are the recorder's)."""

    drift_ppm: float = 12.0
    start_count_ns: int = 1_000_000_000

    def count_ns(self, dt_ns: int) -> int:
        """The counter `dt_ns` after the first edge (the same float expression as the board)."""
        return self.start_count_ns + dt_ns + round(dt_ns * self.drift_ppm * PPM)

    def elapsed_ns(self, board_ns: int) -> int:
        """The dt since the first edge whose count is `board_ns` (the nearest one if the count
        cannot occur: a board of another model)."""
        counts = board_ns - self.start_count_ns
        dt = round(counts / (1.0 + self.drift_ppm * PPM))
        while self.count_ns(dt) < board_ns:
            dt += 1
        while self.count_ns(dt) > board_ns:
            dt -= 1
        below, above = self.count_ns(dt), self.count_ns(dt + 1)  # below ≤ board_ns < above
        return dt + 1 if above - board_ns < board_ns - below else dt


@dataclass(frozen=True)
class EdgeTimeline:
    """Recorded board counters → edge times to send (GPS ns on the replay's timeline)."""

    board: BoardModel
    anchor_ns: int  # the edge time of board count start_count_ns

    def t_edge_ns(self, board_ns: int) -> int:
        return self.anchor_ns + self.board.elapsed_ns(board_ns)


def anchor_from_pps(board: BoardModel, pps: list[tuple[int, int]]) -> int | None:
    """The edge time of the board's start count, from (board_ns, gps_second_ns) of logged PPS:
    each PPS edge is at its GPS second (± its jitter); the median ignores a few wrong ones."""
    offsets = sorted(gps - board.elapsed_ns(b) for b, gps in pps)
    return offsets[len(offsets) // 2] if offsets else None  # integers: no float median


# --- the first pass: what the log holds -----------------------------------------------------------

@dataclass
class Survey:
    """What one cheap pass over the log found: the raw channels' spans, the PPS seconds that
    anchor the edges, the host ↔ GPS pairs for the progress display, the file statistics."""

    first_ns: dict[Wire, int] = field(default_factory=dict)
    last_ns: dict[Wire, int] = field(default_factory=dict)
    counts: dict[Wire, int] = field(default_factory=dict)
    pps: list[tuple[int, int]] = field(default_factory=list)  # (board_ns, gps_second_ns)
    first_edge: tuple[int, int] | None = None  # (log_time_ns, board_ns)
    gps_pairs: list[tuple[int, int]] = field(default_factory=list)  # (t_host_ns, t_gps_ns)
    stats: LogStats = field(default_factory=LogStats)

    @property
    def start_ns(self) -> int:
        return min(self.first_ns.values())

    @property
    def end_ns(self) -> int:
        return max(self.last_ns.values())

    def timeline(self, board: BoardModel) -> EdgeTimeline:
        """GPS-anchored when the log has PPS seconds; else the first edge's host time."""
        anchor = anchor_from_pps(board, self.pps)
        if anchor is None and self.first_edge is not None:
            t_log, board_ns = self.first_edge
            anchor = t_log - board.elapsed_ns(board_ns)
        return EdgeTimeline(board, anchor if anchor is not None else 0)


def _json(data: bytes) -> dict[str, Any] | None:
    try:
        obj = json_loads(data)  # nesting bounded: a hostile message is one skipped
    except ValueError:
        return None
    return obj if isinstance(obj, dict) else None


def _note_gps(survey: Survey, topic: str, obj: dict[str, Any]) -> None:
    if topic == Topic.SYNC_PPS:
        board, second, bit = obj.get("board_ns"), obj.get("gps_second_ns"), obj.get("lfsr_bit")
        if isinstance(board, int) and isinstance(second, int) and second >= 0 and bit != -1:
            survey.pps.append((board, second))
    elif topic in (Topic.GPS_FIX, Topic.GPS_TIME_TAG):
        t_host, t_gps = obj.get("t_host_ns"), obj.get("t_gps_ns")
        if isinstance(t_host, int) and isinstance(t_gps, int):
            survey.gps_pairs.append((t_host, t_gps))


def survey_log(paths: Paths) -> Survey:
    """One pass that decodes only the low-rate topics; InputError if nothing can be replayed."""
    reader = LogReader(paths)
    survey = Survey(stats=reader.stats)
    wanted = (Topic.SYNC_PPS, Topic.GPS_FIX, Topic.GPS_TIME_TAG)
    for channel, msg in reader.raw():
        wire = RAW_TOPICS.get(channel.topic)
        if wire is not None:
            t = msg.log_time
            survey.first_ns[wire] = min(survey.first_ns.get(wire, t), t)
            survey.last_ns[wire] = max(survey.last_ns.get(wire, t), t)
            survey.counts[wire] = survey.counts.get(wire, 0) + 1
            if wire is Wire.PULSES and survey.first_edge is None:
                obj = _json(msg.data)
                if obj is not None and isinstance(obj.get("board_ns"), int):
                    survey.first_edge = (t, obj["board_ns"])
        elif channel.topic in wanted:
            obj = _json(msg.data)
            if obj is not None:
                _note_gps(survey, channel.topic, obj)
    if not survey.first_ns:
        names = ", ".join(RAW_TOPICS)
        raise InputError(f"{reader.paths[0]}: no raw channel to replay ({names})")
    survey.gps_pairs.sort()
    return survey


# --- the schedule ---------------------------------------------------------------------------------

def wires_named(text: str) -> set[Wire]:
    """The wires a comma list names, each by its name (gps, scanner, ins, pulses, camera) or its raw
    topic (/gps/raw, ...); InputError naming the choices for anything else."""
    by_topic = {str(topic): wire for topic, wire in RAW_TOPICS.items()}
    chosen: set[Wire] = set()
    for name in (n.strip() for n in text.split(",")):
        wire = by_topic.get(name) or next((w for w in Wire if w.value == name), None)
        if wire is None:
            choices = ", ".join(f"{w.value} ({t})" for t, w in by_topic.items())
            raise InputError(f"--topics: {shown_text(name)}: not a wire of the replay; "
                             f"choose from {choices}")
        chosen.add(wire)
    return chosen


def _raw_items(topic: str, log_time_ns: int, obj: dict[str, Any]) -> list[Item]:
    """The items of one raw message; KeyError/TypeError/ValueError if it is not SISA's schema."""
    wire = RAW_TOPICS[topic]
    if wire is Wire.PULSES:
        edge = RecordedEdge(str(obj["line"]), int(obj["link_seq"]), int(obj["board_ns"]))
        return [Item(log_time_ns, wire, edge)]
    data = base64.b64decode(obj["data"], validate=True)
    if wire is not Wire.INS:
        return [Item(log_time_ns, wire, data)]
    t0, offsets, ids, dlcs = (int(obj["t_host_ns"]), obj["t_offsets_ns"], obj["arbitration_ids"],
                              obj["dlcs"])
    if not len(offsets) == len(ids) == len(dlcs) or sum(dlcs) != len(data):
        raise ValueError("frame lists and data do not agree")
    items, at = [], 0
    for offset, ident, dlc in zip(offsets, ids, dlcs, strict=True):
        frame = CanFrame(int(ident) & ~CAN_EXTENDED_FLAG, bool(int(ident) & CAN_EXTENDED_FLAG),
                         data[at: at + int(dlc)])
        items.append(Item(t0 + int(offset), wire, frame))
        at += int(dlc)
    return items


@dataclass
class ScheduleStats:
    items: int = 0
    undecodable: int = 0  # raw messages that are not SISA's schema: skipped
    reordered: int = 0  # items found in the file later than the window allows: sent at once


def iter_schedule(paths: Paths, from_ns: int | None = None, until_ns: int | None = None,
                  stats: ScheduleStats | None = None, wires: Collection[Wire] | None = None
                  ) -> Iterator[Item]:
    """Every raw item with from_ns ≤ t_log_ns ≤ until_ns (of `wires` only, if given), in
    log-time order (file order among equal times), streamed with a bounded reorder buffer."""
    out = _InOrder(from_ns, until_ns, stats if stats is not None else ScheduleStats())
    heap: list[tuple[int, int, Item]] = []
    order = 0
    newest = -(2**63)
    for channel, msg in LogReader(paths).raw():
        wire = RAW_TOPICS.get(channel.topic)
        if wire is None or (wires is not None and wire not in wires):
            continue
        obj = _json(msg.data)
        try:
            items = _raw_items(channel.topic, msg.log_time, obj if obj is not None else {})
        except (KeyError, TypeError, ValueError):
            out.stats.undecodable += 1
            continue
        for item in items:
            heapq.heappush(heap, (item.t_log_ns, order, item))
            order += 1
            newest = max(newest, item.t_log_ns)
        while heap and heap[0][0] <= newest - REORDER_WINDOW_NS:
            yield from out.accept(heapq.heappop(heap)[2])
        if newest - REORDER_WINDOW_NS > out.hi:
            break  # the rest of the log is after the span
    while heap:
        yield from out.accept(heapq.heappop(heap)[2])


class _InOrder:
    """The range filter at the heap's output; an item the window could not place in order is
    sent at the time of the one before (never earlier) and counted."""

    def __init__(self, from_ns: int | None, until_ns: int | None, stats: ScheduleStats) -> None:
        self.lo = from_ns if from_ns is not None else -(2**63)
        self.hi = until_ns if until_ns is not None else 2**63 - 1
        self.stats = stats
        self.last_ns = -(2**63)

    def accept(self, item: Item) -> list[Item]:
        if not self.lo <= item.t_log_ns <= self.hi:
            return []
        if item.t_log_ns < self.last_ns:
            self.stats.reordered += 1
            item = Item(self.last_ns, item.wire, item.payload)
        self.stats.items += 1
        self.last_ns = item.t_log_ns
        return [item]


# --- pacing, pause, loops -------------------------------------------------------------------------

class PlayClock:
    """Log time ↔ wall time at `rate` times real time, with pause: while paused the log time
    stands still, and resuming re-anchors the clock, so nothing due in the pause comes in a burst.
    Wall times are whatever monotonic ns clock the caller passes (time.perf_counter_ns)."""

    def __init__(self, rate: float, t_log0_ns: int, wall0_ns: int) -> None:
        if not rate > 0:
            raise ValueError("rate must be positive")
        self.rate = rate
        self._t_log0_ns = t_log0_ns
        self._wall0_ns = wall0_ns
        self._paused_at_ns: int | None = None

    @property
    def paused(self) -> bool:
        return self._paused_at_ns is not None

    def due_wall_ns(self, t_log_ns: int) -> int | None:
        """Wall time at which the item at `t_log_ns` is due; None while paused."""
        if self._paused_at_ns is not None:
            return None
        return self._wall0_ns + round((t_log_ns - self._t_log0_ns) / self.rate)

    def log_now_ns(self, wall_ns: int) -> int:
        """The log time being played at `wall_ns` (frozen while paused)."""
        at = self._paused_at_ns if self._paused_at_ns is not None else wall_ns
        return self._t_log0_ns + round((at - self._wall0_ns) * self.rate)

    def pause(self, wall_ns: int) -> None:
        if self._paused_at_ns is None:
            self._paused_at_ns = wall_ns

    def resume(self, wall_ns: int) -> None:
        if self._paused_at_ns is not None:
            self._wall0_ns += wall_ns - self._paused_at_ns
            self._paused_at_ns = None

    def toggle(self, wall_ns: int) -> None:
        if self.paused:
            self.resume(wall_ns)
        else:
            self.pause(wall_ns)

    def restart(self, t_log0_ns: int, wall0_ns: int) -> None:
        """Play `t_log0_ns` at `wall0_ns` from now on (a new pass of a loop)."""
        self._t_log0_ns, self._wall0_ns = t_log0_ns, wall0_ns
        if self._paused_at_ns is not None:
            self._paused_at_ns = wall0_ns


class LoopEdges:
    """Edges of pass k of a looped replay: k loop periods later on the edge timeline, and their
    link numbers running on from the pass before, so a receiver sees one continuous link (a
    timeline that jumps back, or numbers that repeat, would read as faults)."""

    def __init__(self, period_ns: int) -> None:
        self.period_ns = period_ns
        self.pass_index = 0
        self._first_seq: dict[str, int] = {}  # per line, in the first pass
        self._last_out: dict[str, int] = {}
        self._shift: dict[str, int] = {}

    def next_pass(self) -> None:
        self.pass_index += 1
        self._shift = {line: last + 1 - self._first_seq[line]
                       for line, last in self._last_out.items()}

    def edge(self, edge: RecordedEdge, t_edge_ns: int) -> tuple[int, int]:
        """(link_seq, t_edge_ns) to send for a recorded edge."""
        self._first_seq.setdefault(edge.line, edge.link_seq)
        seq = edge.link_seq + self._shift.get(edge.line, 0)
        self._last_out[edge.line] = seq
        return seq, t_edge_ns + self.pass_index * self.period_ns


class GpsClock:
    """Host time → GPS time for the progress display, from the log's fixes and time tags: the
    last pair before, carried forward by the host clock."""

    def __init__(self, pairs: list[tuple[int, int]]) -> None:
        self._host = [h for h, _ in pairs]
        self._gps = [g for _, g in pairs]

    def gps_ns(self, t_host_ns: int) -> int | None:
        i = bisect.bisect_right(self._host, t_host_ns) - 1
        if i < 0:
            if not self._host:
                return None
            i = 0
        return self._gps[i] + (t_host_ns - self._host[i])
