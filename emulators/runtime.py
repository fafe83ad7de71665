"""The device runtime: one event loop that runs the same device code in virtual time (as fast as
the CPU allows, deterministic for a seed) or in real time (paced by the wall clock, optionally
scaled).

A device schedules its own outputs (bytes on a serial port, CAN frames, pulse edges) on the
emulation timeline, `t_ns` = true GPS ns, and accepts input edges (its sync or event input) that
act at the edge's own timestamp. A sink receives every output in time order; in virtual time the
sink may answer with input edges (the sync unit forwarding a pulse), delivered at once. An edge
may give its device an output sooner than the one it had planned (the GPS receiver's TTT for an
event): every device an edge reaches is asked for its next time again.
"""

from __future__ import annotations

import heapq
import queue
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import StrEnum

import can

from acquisition.pulses import Edge

PACE_EARLY_NS = 50_000  # an emission this close to due goes out at once
PACE_SLICE_S = 0.25  # a longer wait for an emission (a slow --speed) is slept in slices,
# asking between them whether to stop: Ctrl-C waited for the next emission, ~16 s at 0.001


class Port(StrEnum):
    """Where a device output goes."""

    GPS_SERIAL = "gps"
    SCANNER_SERIAL = "scanner"
    CAMERA_SERIAL = "camera"
    INS_CAN = "ins"
    PULSES = "pulses"


@dataclass(frozen=True, slots=True)
class Output:
    """One device output: `payload` is bytes (serial), a can.Message (CAN) or an Edge (pulses)."""

    t_ns: int
    port: Port
    payload: bytes | can.Message | Edge


class Device(ABC):
    """A device model on the emulation timeline."""

    name: str = "device"

    @abstractmethod
    def next_time_ns(self) -> int | None:
        """Time of this device's next output, or None when it has nothing more to say."""

    @abstractmethod
    def emit(self, t_ns: int) -> list[Output]:
        """Every output due at `t_ns` (the value next_time_ns() returned)."""

    def on_edge(self, edge: Edge) -> None:  # noqa: B027 - most devices have no input
        """An input pulse; it acts at edge.t_ns, which is never earlier than the current time."""

    def finish(self) -> None:  # noqa: B027
        """The run is over: close files, flush truth."""


Sink = Callable[[Output], Sequence[Edge]]


class Router:
    """Delivers input edges to the devices that listen on their line."""

    def __init__(self, devices: Sequence[Device]) -> None:
        self._listeners: dict[int, list[Device]] = {}
        for dev in devices:
            for line in getattr(dev, "input_lines", ()):
                self._listeners.setdefault(int(line), []).append(dev)

    def deliver(self, edge: Edge) -> list[Device]:
        """Hand the edge to its listeners; the devices it reached."""
        devices = self._listeners.get(int(edge.line), [])
        for dev in devices:
            dev.on_edge(edge)
        return devices


class Runner:
    """Merges the devices' outputs in time order and hands them to the sink.

    `speed` = None runs in virtual time; a float paces emission on the wall clock at that many
    times real time (1.0 = real time).
    """

    def __init__(self, devices: Sequence[Device], sink: Sink, speed: float | None = None) -> None:
        if speed is not None and speed <= 0:
            raise ValueError("speed must be positive")
        self.devices = list(devices)
        self.sink = sink
        self.speed = speed
        self.router = Router(self.devices)
        self._index = {id(d): i for i, d in enumerate(self.devices)}
        self._heap: list[tuple[int, int, int]] = []  # (time, device, entry number)
        self._due: dict[int, tuple[int, int]] = {}  # device → (time, number) of its valid entry
        self._entries = 0
        self.outputs = 0
        self.late_ns_max = 0
        self.t_ns: int | None = None  # the time reached (of the last emission, skipped or not)
        # edges from another process (real time): drained before every emission
        self.inbox: queue.SimpleQueue[Edge] = queue.SimpleQueue()

    def run(self, until_ns: int | None = None, should_stop: Callable[[], bool] | None = None,
            skip_until_ns: int | None = None) -> None:
        """Emit in time order until `until_ns`. Outputs before `skip_until_ns` are produced as
        fast as possible and dropped (a start offset: the devices' state runs on)."""
        # each device has one valid entry: an edge can move a device's next output earlier (the
        # receiver's TTT for an event, 30 ms on), which then waited for the output it had
        # planned before (the next PPS, up to a second later); superseded entries are skipped
        self._heap, self._due = [], {}
        for i in range(len(self.devices)):
            self._reschedule(i)
        heap = self._heap
        skip = skip_until_ns if skip_until_ns is not None else -(2**63)
        wall0: int | None = None  # the wall clock is anchored at the first paced emission
        t0 = max(heap[0][0] if heap else 0, skip)
        try:
            while heap:
                t_ns, i, entry = heapq.heappop(heap)
                if self._due.get(i) != (t_ns, entry):
                    continue  # superseded: the device was rescheduled by an edge
                del self._due[i]
                if until_ns is not None and t_ns > until_ns:
                    break
                self.t_ns = t_ns
                if should_stop is not None and should_stop():
                    break
                dev = self.devices[i]
                if t_ns < skip:
                    dev.emit(t_ns)
                else:
                    if self.speed is not None:
                        if wall0 is None:
                            wall0 = time.perf_counter_ns() - int((t_ns - t0) / self.speed)
                        if not self._pace(wall0 + int((t_ns - t0) / self.speed),
                                          should_stop):
                            break
                    self._drain_inbox()
                    self._deliver(dev.emit(t_ns))
                self._reschedule(i)
        finally:
            self._finish_all()

    def _finish_all(self) -> None:
        """Every device's finish, even after one raised (a disk error writing the scanner's
        last lines must not leave the other devices' truth unwritten); then the first error."""
        error: BaseException | None = None
        for dev in self.devices:
            try:
                dev.finish()
            except BaseException as exc:
                error = error or exc
        if error is not None:
            raise error

    def _reschedule(self, i: int) -> None:
        """Ask device i for its next time; a new time replaces its entry in the heap."""
        nxt = self.devices[i].next_time_ns()
        due = self._due.get(i)
        if nxt is None:
            self._due.pop(i, None)
        elif due is None or due[0] != nxt:
            self._entries += 1
            self._due[i] = (nxt, self._entries)
            heapq.heappush(self._heap, (nxt, i, self._entries))

    def _edge(self, edge: Edge) -> None:
        for dev in self.router.deliver(edge):
            self._reschedule(self._index[id(dev)])

    def _deliver(self, outputs: list[Output]) -> None:
        for out in outputs:
            self.outputs += 1
            for edge in self.sink(out):
                self._edge(edge)

    def _drain_inbox(self) -> None:
        """(Asked before every emission, and nearly always empty: an exception per asking
        cost more than the emission in a virtual-time run. Only this thread takes from the
        inbox, so what it holds when asked is there to take.)"""
        inbox = self.inbox
        while not inbox.empty():
            self._edge(inbox.get_nowait())

    def _pace(self, due_wall_ns: int, should_stop: Callable[[], bool] | None) -> bool:
        """Sleep until the emission is due, never spin: what a device emits carries its own
        time (edges their timestamps, records their clock), so sleeping's ~0.1 ms overshoot
        costs no fidelity, and a spinning emulator would take the CPU the recorder under test
        needs. Less than PACE_EARLY_NS ahead goes out at once (a sleep that short only adds a
        wake-up). False if asked to stop while waiting (in slices of PACE_SLICE_S)."""
        while (ahead_ns := due_wall_ns - time.perf_counter_ns()) > PACE_EARLY_NS:
            if ahead_ns > PACE_SLICE_S * 1e9 and should_stop is not None and should_stop():
                return False
            time.sleep(min(ahead_ns / 1e9, PACE_SLICE_S))
        self.late_ns_max = max(self.late_ns_max, time.perf_counter_ns() - due_wall_ns)
        return True
