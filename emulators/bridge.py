"""Real-time wiring of the emulated devices to virtual ports other processes open.

GPS and scanner serial lines → ptys; the INS → an SLCAN adapter on a pty (or any python-can bus);
pulse lines → a loopback TCP endpoint carrying edges both ways. Edges coming back (the sync unit's
pulses to the INS sync input and the GPS event input) go to the runner's inbox and act at their
own timestamps.
"""

from __future__ import annotations

import json
import queue
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import can

from acquisition.canspec import parse_can_spec
from acquisition.pulses import Edge
from emulators.ports import PtyPort, PulseEndpoint, SlcanAdapter
from emulators.runtime import Output, Port
from sisa.errors import ConfigError


@dataclass(frozen=True)
class CanTarget:
    """Where INS frames go: 'slcan' (an adapter on a new pty) or INTERFACE:CHANNEL for python-can
    (e.g. 'virtual:sisa' in one process, 'socketcan:can0' on a real bus)."""

    interface: str
    channel: str | None = None

    @classmethod
    def parse(cls, text: str) -> CanTarget:
        if text == "slcan":
            return cls("slcan")
        return cls(*parse_can_spec(text))


class RealTimeBridge:
    """The sink of a real-time run: owns the ports and routes every output to its wire."""

    def __init__(self, can_target: CanTarget, inbox: queue.SimpleQueue[Edge],
                 pulse_port: int = 0) -> None:
        self.gps = PtyPort()
        self.scanner = PtyPort()
        self.slcan: SlcanAdapter | None = None
        self.bus: can.BusABC | None = None
        if can_target.interface == "slcan":
            self.slcan = SlcanAdapter()
        else:
            try:
                self.bus = can.Bus(interface=can_target.interface, channel=can_target.channel)
            except (can.CanError, ValueError, OSError, ImportError) as exc:
                raise ConfigError(f"cannot open CAN {can_target.interface}:"
                                  f"{can_target.channel}: {exc}") from None
        self.can_target = can_target
        self.pulses = PulseEndpoint(inbox.put, port=pulse_port)
        self.can_frames_failed = 0

    def __call__(self, out: Output) -> Sequence[Edge]:
        payload = out.payload
        if out.port is Port.GPS_SERIAL and isinstance(payload, bytes):
            self.gps.write(payload)
        elif out.port is Port.SCANNER_SERIAL and isinstance(payload, bytes):
            self.scanner.write(payload)
        elif isinstance(payload, can.Message):
            self._send_can(payload)
        elif isinstance(payload, Edge):
            self.pulses.send(payload)
        return ()

    def _send_can(self, msg: can.Message) -> None:
        if self.slcan is not None:
            self.slcan.send(msg)
        elif self.bus is not None:
            try:
                self.bus.send(msg)
            except can.CanError:
                self.can_frames_failed += 1

    @property
    def can_channel(self) -> str:
        if self.slcan is not None:
            return f"slcan:{self.slcan.name}"
        return f"{self.can_target.interface}:{self.can_target.channel}"

    def endpoints(self) -> dict[str, str]:
        return {"gps": self.gps.name, "scanner": self.scanner.name, "ins": self.can_channel,
                "pulses": self.pulses.address}

    def write_endpoints(self, path: Path) -> None:
        path.write_text(json.dumps(self.endpoints(), indent=2) + "\n", encoding="utf-8")

    def close(self) -> None:
        self.pulses.close()
        if self.slcan is not None:
            self.slcan.close()
        if self.bus is not None:
            self.bus.shutdown()
        self.gps.close()
        self.scanner.close()
