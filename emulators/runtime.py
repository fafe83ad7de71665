"""The device runtime: one event loop that runs the same device code in virtual time (as fast as
the CPU allows, deterministic for a seed) or in real time (paced by the wall clock, optionally
scaled).

A device schedules its own outputs (bytes on a serial port, CAN frames, pulse edges) on the
emulation timeline, `t_ns` = true GPS ns, and accepts input edges (its sync or event input) that
act at the edge's own timestamp. A sink receives every output in time order; in virtual time the
sink may answer with input edges (the sync unit forwarding a pulse), delivered at once.

An input edge may bring a device's next output forward (the GPS receiver sends a TTT 30 ms after
a pulse on its event input): after every delivery the runner asks the device again. It did not:
the tag waited for the receiver's next scheduled output (its next PPS or NMEA epoch, up to ~0.95
s later) and went out stamped then: at 20.8 tags/s their host receive times fell ~0.4 s behind
on average, the host → GPS map fitted them at −870 ppm, and no INS record was timed.
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
        """Hand the edge to its listeners; the devices it went to."""
        listeners = self._listeners.get(int(edge.line), [])
        for dev in listeners:
            dev.on_edge(edge)
        return listeners


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
        self.outputs = 0
        self.late_ns_max = 0
        # edges from another process (real time): drained before every emission
        self.inbox: queue.SimpleQueue[Edge] = queue.SimpleQueue()
        self._index = {id(d): i for i, d in enumerate(self.devices)}
        self._due: list[int | None] = [None] * len(self.devices)  # each device's heap entry
        self._heap: list[tuple[int, int]] = []

    def _schedule(self, i: int) -> None:
        """(Re)enter device i at its next output time; an entry it no longer has is stale."""
        t = self.devices[i].next_time_ns()
        if t is not None and t != self._due[i]:
            heapq.heappush(self._heap, (t, i))
        self._due[i] = t

    def _rescheduled(self, devices: Sequence[Device]) -> None:
        for dev in devices:
            self._schedule(self._index[id(dev)])

    def run(self, until_ns: int | None = None, should_stop: Callable[[], bool] | None = None,
            skip_until_ns: int | None = None) -> None:
        """Emit in time order until `until_ns`. Outputs before `skip_until_ns` are produced as
        fast as possible and dropped (a start offset: the devices' state runs on)."""
        heap = self._heap
        heap.clear()
        for i in range(len(self.devices)):
            self._due[i] = None
            self._schedule(i)
        skip = skip_until_ns if skip_until_ns is not None else -(2**63)
        wall0: int | None = None  # the wall clock is anchored at the first paced emission
        t0 = max(min(heap)[0] if heap else 0, skip)
        try:
            while heap:
                t_ns, i = heapq.heappop(heap)
                if t_ns != self._due[i]:
                    continue  # stale: an input edge moved this device's next output
                self._due[i] = None
                if until_ns is not None and t_ns > until_ns:
                    break
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
                self._schedule(i)
        finally:
            for dev in self.devices:
                dev.finish()

    def _deliver(self, outputs: list[Output]) -> None:
        for out in outputs:
            self.outputs += 1
            for edge in self.sink(out):
                self._rescheduled(self.router.deliver(edge))

    def _drain_inbox(self) -> None:
        while True:
            try:
                edge = self.inbox.get_nowait()
            except queue.Empty:
                return
            self._rescheduled(self.router.deliver(edge))

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
