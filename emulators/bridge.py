"""Real-time wiring of the emulated devices to virtual ports other processes open.

GPS, scanner (and frame camera) serial lines → ptys; the INS → an SLCAN adapter on a pty (or any
python-can bus); pulse lines → a loopback TCP endpoint carrying edges both ways. Edges coming
back (the sync unit's pulses to the INS sync input and the GPS event input) go to the runner's
inbox and act at their own timestamps.
"""

from __future__ import annotations

import queue
from collections.abc import Sequence
from dataclasses import dataclass

import can

from acquisition.canspec import parse_can_spec
from acquisition.pulses import Edge
from emulators.ports import PtyPort, PulseEndpoint, SlcanAdapter
from emulators.runtime import Output, Port
from sisa.core.errors import ConfigError


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


class CanOutput:
    """The INS's side of the bus: an SLCAN adapter on a new pty, or any python-can bus; a frame
    the bus refuses is counted, not raised (a real INS does not stop for a bus error)."""

    def __init__(self, target: CanTarget) -> None:
        self.target = target
        self.slcan: SlcanAdapter | None = None
        self.bus: can.BusABC | None = None
        self.frames_failed = 0
        if target.interface == "slcan":
            self.slcan = SlcanAdapter()
            return
        try:
            self.bus = can.Bus(interface=target.interface, channel=target.channel)
        except (can.CanError, ValueError, OSError, ImportError) as exc:
            raise ConfigError(f"cannot open CAN {target.interface}:{target.channel}: "
                              f"{exc}") from None
        except Exception as exc:  # a python-can plugin's own bug (kvaser
            # without its library: a NameError) is still the bus that cannot be opened
            raise ConfigError(f"cannot open CAN {target.interface}:{target.channel}: "
                              f"{type(exc).__name__}: {exc}") from None

    def send(self, msg: can.Message) -> None:
        if self.slcan is not None:
            self.slcan.send(msg)
        elif self.bus is not None:
            try:
                self.bus.send(msg)
            except can.CanError:
                self.frames_failed += 1

    @property
    def channel(self) -> str:
        if self.slcan is not None:
            return f"slcan:{self.slcan.name}"
        return f"{self.target.interface}:{self.target.channel}"

    @property
    def frames_dropped(self) -> int:
        return (self.slcan.frames_dropped if self.slcan is not None else 0) + self.frames_failed

    @property
    def host_open(self) -> bool:
        """Whether the host has opened the channel (only an SLCAN adapter can tell)."""
        return self.slcan is None or self.slcan.is_open

    def close(self) -> None:
        if self.slcan is not None:
            self.slcan.close()
        if self.bus is not None:
            self.bus.shutdown()


class RealTimeBridge:
    """The sink of a real-time run: owns the ports and routes every output to its wire."""

    def __init__(self, can_target: CanTarget, inbox: queue.SimpleQueue[Edge],
                 pulse_port: int = 0, gps_copy: bool = False, camera: bool = False) -> None:
        """`camera`: a frame camera's port too (a scenario with `[camera]`)."""
        self.gps = PtyPort()
        # a second pty with the same GPS bytes, for a second reader (gpsd): two readers of
        # one pty would each get part of the stream
        self.gps_copy = PtyPort() if gps_copy else None
        self.scanner = PtyPort()
        self.camera = PtyPort() if camera else None
        self.can = CanOutput(can_target)
        self.pulses = PulseEndpoint(inbox.put, port=pulse_port)

    def __call__(self, out: Output) -> Sequence[Edge]:
        payload = out.payload
        if out.port is Port.GPS_SERIAL and isinstance(payload, bytes):
            self.gps.write(payload)
            if self.gps_copy is not None:
                self.gps_copy.write(payload)
        elif out.port is Port.SCANNER_SERIAL and isinstance(payload, bytes):
            self.scanner.write(payload)
        elif out.port is Port.CAMERA_SERIAL and isinstance(payload, bytes):
            if self.camera is not None:
                self.camera.write(payload)
        elif isinstance(payload, can.Message):
            self.can.send(payload)
        elif isinstance(payload, Edge):
            self.pulses.send(payload)
        return ()

    def endpoints(self) -> dict[str, str]:
        copy = {} if self.gps_copy is None else {"gps_copy": self.gps_copy.name}
        camera = {} if self.camera is None else {"camera": self.camera.name}
        return {"gps": self.gps.name, "scanner": self.scanner.name, "ins": self.can.channel,
                "pulses": self.pulses.address, **copy, **camera}

    def close(self) -> None:
        self.pulses.close()
        self.can.close()
        self.gps.close()
        if self.gps_copy is not None:
            self.gps_copy.close()
        self.scanner.close()
        if self.camera is not None:
            self.camera.close()
