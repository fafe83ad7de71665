"""The live loop's hand-over of what it reads to the acquisition: held back, handed over in batches.

Python work done right after a wake-up costs this kind of host several times what it costs back
to back (docs/benchmarks.md, "Recorder CPU"): handing each 5 ms read's few items to the decoders,
the sync filter and the writer at once kept the recorder at 3–5 % of a core for 0.7 % of work.
So `Handover` holds the arrivals (and the loop's clock ticks) back and hands them over in the
order they came, in one batch, `HOLD_NS` after the first or sooner when `HOLD_UNITS` of work
are held (CAN frames, edges, 64-byte pieces of serial data: ~3 ms of handling; the loop reads
nothing while it hands a batch over, so a batch of high rates' 200 ms made every device's host
times up to 50 ms late and the edges past their deadline) — with one exception, the sync unit's
real-time duty: a pulse edge that could be forwarded is handed over at once, after everything
held before it. Which edges could is asked of the acquisition (`Acquisition.ppf_may_forward`),
counting the ppf still held; a PPS or camera edge always could. Nothing else forwards, so the
acquisition sees the same events in the same order with the same host times (stamped at the
read) as when each read is handed over at once, and logs the same records; only their writing
comes up to `HOLD_NS` later, well inside the second a crash may lose. A forward that does come
out of a held batch (it never should) is counted as a missed deadline of the ppf stream.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

from acquisition.pulses import PulseLine

if TYPE_CHECKING:
    from acquisition.live import Arrival, GarbledCanLines
    from acquisition.pulses import Edge
    from acquisition.runner import Acquisition

HOLD_NS = 200_000_000
HOLD_UNITS = 256
SERIAL_UNIT_BYTES = 64


class EdgeClock:
    """The edge timeline's 'now', extrapolated from the last edge by the host clock."""

    def __init__(self) -> None:
        self.t_edge_ns: int | None = None
        self.t_host_ns = 0

    def seen(self, t_host_ns: int, t_edge_ns: int) -> None:
        self.t_edge_ns, self.t_host_ns = t_edge_ns, t_host_ns

    def now(self, t_host_ns: int) -> int | None:
        if self.t_edge_ns is None:
            return None
        return self.t_edge_ns + (t_host_ns - self.t_host_ns)


def dispatch(acq: Acquisition, item: Arrival) -> None:
    """One arrival to the acquisition, by its source (Source values: no import per call)."""
    payload, source = item.payload, item.source
    if source == "pulses":
        acq.on_edge(item.t_host_ns, cast("Edge", payload))
    elif source == "ins":
        if isinstance(payload, list):
            acq.on_can_frames(item.t_host_ns, payload)
        else:
            garbled = cast("GarbledCanLines", payload)
            acq.on_can_garbled(item.t_host_ns, garbled.lines, garbled.bytes_skipped)
    elif source == "gps":
        acq.on_gps_bytes(item.t_host_ns, cast(bytes, payload))
    elif source == "camera":
        acq.on_camera_bytes(item.t_host_ns, cast(bytes, payload))
    else:
        acq.on_scanner_bytes(item.t_host_ns, cast(bytes, payload))


@dataclass(frozen=True, slots=True)
class _Tick:
    """The loop's clock: time passing with nothing arriving (scanner off, health reports)."""

    t_host_ns: int
    t_edge_ns: int


class Handover:
    """Arrivals and ticks to `acq`, in order: held for a batch, or at once when an edge could be
    forwarded (module docstring)."""

    def __init__(self, acq: Acquisition, hold_ns: int = HOLD_NS) -> None:
        self.acq = acq
        self.hold_ns = hold_ns
        self.edge_clock = EdgeClock()
        self._held: list[Arrival | _Tick] = []
        self._first_held_ns = 0
        self._ppf_held = 0
        self._units_held = 0
        self._last_ppf_t_ns: int | None = None
        self.batches = 0

    def put(self, item: Arrival) -> None:
        """A read's item (not a link event: `flush` first, then tell the acquisition)."""
        if item.source == "pulses":
            edge = cast("Edge", item.payload)
            self.edge_clock.seen(item.t_host_ns, edge.t_ns)
            if self._could_forward(edge):
                self.flush()
                dispatch(self.acq, item)
                return
            self._ppf_held += 1
            self._hold(item, item.t_host_ns, 1)
            return
        payload = item.payload
        units = (len(payload) if isinstance(payload, list)
                 else 1 + len(payload) // SERIAL_UNIT_BYTES if isinstance(payload, bytes) else 1)
        self._hold(item, item.t_host_ns, units)

    def tick(self, t_host_ns: int) -> None:
        """The loop's clock (every `TICK_S`): held like an arrival; also what lets a batch go
        when nothing arrives."""
        t_edge_ns = self.edge_clock.now(t_host_ns)
        if t_edge_ns is not None:
            self._hold(_Tick(t_host_ns, t_edge_ns), t_host_ns, 1)
        elif self._held and self._expired(t_host_ns):
            self.flush()

    def flush(self) -> None:
        """Everything held, to the acquisition, in order."""
        if not self._held:
            return
        held, self._held, self._ppf_held, self._units_held = self._held, [], 0, 0
        self.batches += 1
        acq = self.acq
        forwards = acq.forwards_sent
        for item in held:
            if isinstance(item, _Tick):
                acq.tick(item.t_host_ns, item.t_edge_ns)
            else:
                dispatch(acq, item)
        acq.streams["ppf"].deadline_misses += acq.forwards_sent - forwards

    def _hold(self, item: Arrival | _Tick, t_host_ns: int, units: int) -> None:
        if not self._held:
            self._first_held_ns = t_host_ns
        self._held.append(item)
        self._units_held += units
        if self._units_held >= HOLD_UNITS or self._expired(t_host_ns):
            self.flush()

    def _expired(self, t_host_ns: int) -> bool:
        """The batch is `hold_ns` old, or the host clock stepped back."""
        return not 0 <= t_host_ns - self._first_held_ns < self.hold_ns

    def _could_forward(self, edge: Edge) -> bool:
        if edge.line is not PulseLine.PPF:
            return True
        gap_ns = None if self._last_ppf_t_ns is None else edge.t_ns - self._last_ppf_t_ns
        self._last_ppf_t_ns = edge.t_ns
        return self.acq.ppf_may_forward(self._ppf_held, gap_ns)
