"""Fault injection on the wire: lost and corrupted bytes, CAN frames and pulse edges, and
spurious pulses. Device-internal faults (PPS outage, INS clock jump and reboot, dropped scanner
frames) live in the device models, which read the same profile. Every fault is written to the
truth table `faults`.
"""

from __future__ import annotations

from collections.abc import Sequence

import can
import numpy as np

from acquisition.pulses import Edge, PulseLine
from emulators.runtime import Device, Output, Port
from emulators.scenario import FaultProfile
from emulators.truth import TruthTable
from sisa.core.timescale import NS_PER_S


def fault_table() -> TruthTable:
    return TruthTable("faults", {
        "t_gps_ns": "when the fault acted (GPS ns, emulation timeline)",
        "kind": "lost_pulse | spurious_pulse | corrupt_byte | lost_byte | lost_can_frame | "
                "corrupt_can_frame | pps_outage | ins_clock_jump | ins_reboot | dropped_frame | "
                "sync_restart",
        "target": "port or pulse line",
        "detail": "free text: sequence number, byte offset, jump size",
    }, "faults injected into the emulated devices and wires")


class WireFaults:
    """Applies the profile's per-item faults to one output; returns None when it is lost."""

    def __init__(self, profile: FaultProfile, rng: np.random.Generator, truth: TruthTable
                 ) -> None:
        self.profile = profile
        self.rng = rng
        self.truth = truth

    @property
    def active(self) -> bool:
        p = self.profile
        return any((p.lost_pulse_fraction, p.corrupt_byte_rate, p.lost_byte_rate,
                    p.lost_can_frame_fraction, p.corrupt_can_frame_fraction))

    def apply(self, out: Output) -> Output | None:
        payload = out.payload
        if isinstance(payload, Edge):
            return self._edge(out, payload)
        if isinstance(payload, can.Message):
            return self._can(out, payload)
        return self._bytes(out, payload)

    def _edge(self, out: Output, edge: Edge) -> Output | None:
        if self.rng.random() < self.profile.lost_pulse_fraction:
            self.truth.append(t_gps_ns=edge.t_ns, kind="lost_pulse", target=edge.line.name,
                              detail=f"seq {edge.seq}")
            return None
        return out

    def _can(self, out: Output, msg: can.Message) -> Output | None:
        p = self.profile
        if self.rng.random() < p.lost_can_frame_fraction:
            self.truth.append(t_gps_ns=out.t_ns, kind="lost_can_frame",
                              target=f"0x{msg.arbitration_id:03X}", detail="")
            return None
        if msg.dlc and self.rng.random() < p.corrupt_can_frame_fraction:
            data = bytearray(msg.data)
            at = int(self.rng.integers(len(data)))
            data[at] ^= 1 << int(self.rng.integers(8))
            self.truth.append(t_gps_ns=out.t_ns, kind="corrupt_can_frame",
                              target=f"0x{msg.arbitration_id:03X}", detail=f"byte {at}")
            bad = can.Message(arbitration_id=msg.arbitration_id, data=bytes(data),
                              is_extended_id=msg.is_extended_id, timestamp=msg.timestamp)
            return Output(out.t_ns, out.port, bad)
        return out

    def _bytes(self, out: Output, data: bytes) -> Output | None:
        p = self.profile
        if not (p.corrupt_byte_rate or p.lost_byte_rate):
            return out
        arr = np.frombuffer(data, dtype=np.uint8).copy()
        flip = self.rng.random(arr.size) < p.corrupt_byte_rate
        keep = self.rng.random(arr.size) >= p.lost_byte_rate
        for at in np.flatnonzero(flip):
            arr[at] ^= np.uint8(1 << int(self.rng.integers(8)))
            self.truth.append(t_gps_ns=out.t_ns, kind="corrupt_byte", target=out.port.value,
                              detail=f"offset {at}")
        for at in np.flatnonzero(~keep):
            self.truth.append(t_gps_ns=out.t_ns, kind="lost_byte", target=out.port.value,
                              detail=f"offset {at}")
        kept = arr[keep].tobytes()
        return Output(out.t_ns, out.port, kept) if kept else None


class SpuriousPulses(Device):
    """Pulses that no device meant to send (ground bounce, a loose connector), at a Poisson rate,
    on the given lines. With `pps_near_second_ns` > 0, those on the PPS line fall within that
    much of a whole GPS second, where the true PPS edge is (a glitch next to the edge: the
    hardest spurious PPS for the sync unit to refuse)."""

    name = "spurious"

    def __init__(self, rate_hz: float, lines: Sequence[PulseLine], t_start_ns: int,
                 t_end_ns: int, rng: np.random.Generator, truth: TruthTable,
                 pps_near_second_ns: int = 0) -> None:
        self.rate_hz = rate_hz
        self.lines = tuple(lines)
        self.t_end_ns = t_end_ns
        self.rng = rng
        self.truth = truth
        self.pps_near_second_ns = pps_near_second_ns
        self._seq = 0
        self._base: int | None = t_start_ns  # the Poisson process
        self._next: int | None = t_start_ns  # the next pulse (moved next to a second)
        self._line = self.lines[0]
        self._advance()

    def _advance(self) -> None:
        if self._base is None or self.rate_hz <= 0:
            self._base = self._next = None
            return
        self._base += int(self.rng.exponential(1e9 / self.rate_hz))
        if self._base > self.t_end_ns:
            self._base = self._next = None
            return
        self._line = self.lines[int(self.rng.integers(len(self.lines)))]
        previous = self._next if self._next is not None else self._base
        self._next = self._base
        if self._line is PulseLine.PPS and self.pps_near_second_ns > 0:
            near = self.pps_near_second_ns
            second = (self._base + NS_PER_S // 2) // NS_PER_S * NS_PER_S
            self._next = max(previous, second + int(self.rng.integers(-near, near + 1)))

    def next_time_ns(self) -> int | None:
        return self._next

    def emit(self, t_ns: int) -> list[Output]:
        line = self._line
        self._seq += 1
        self.truth.append(t_gps_ns=t_ns, kind="spurious_pulse", target=line.name,
                          detail=f"seq {self._seq}")
        self._advance()
        return [Output(t_ns, Port.PULSES, Edge(line, 0, t_ns))]
