"""Real-time sources for the acquisition: one reader thread per port or bus, all feeding one
queue that a single thread drains in arrival order (the sync filter needs one ordered stream).

Every item is stamped with the host clock the moment its read returns. Pulse edges come from the
timing-board link (TCP on loopback) and the sync unit's output edges go back on the same link.
"""

from __future__ import annotations

import contextlib
import queue
import socket
import threading
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import can
import serial

from acquisition.canspec import parse_can_spec
from acquisition.clocks import wall_clock_ns
from acquisition.codec import ErrorPolicy
from acquisition.pulses import Edge, EdgeStreamDecoder, encode_edge
from acquisition.slcan_bulk import BulkSlcanBus
from sisa.errors import InputError

READ_TIMEOUT_S = 0.05


class Source(StrEnum):
    GPS = "gps"
    SCANNER = "scanner"
    INS = "ins"
    PULSES = "pulses"


@dataclass(frozen=True)
class Arrival:
    """One read: bytes (serial), a CAN frame, an edge, or None when the source closed."""

    t_host_ns: int
    source: Source
    payload: bytes | can.Message | Edge | None


class LiveSources:
    """Opens the ports, runs the reader threads, and sends edges back to the timing board."""

    def __init__(self, gps_port: str | None, scanner_port: str | None, ins_bus: str | None,
                 pulses: str | None) -> None:
        self.arrivals: queue.SimpleQueue[Arrival] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._closers: list[Callable[[], None]] = []
        self._pulse_sock: socket.socket | None = None
        self.open_sources: set[Source] = set()
        try:
            if gps_port:
                self._serial(Source.GPS, gps_port)
            if scanner_port:
                self._serial(Source.SCANNER, scanner_port)
            if ins_bus:
                self._can(ins_bus)
            if pulses:
                self._pulses(pulses)
        except BaseException:
            self.close()
            raise

    def _start(self, source: Source, target: Callable[[], None]) -> None:
        thread = threading.Thread(target=target, name=f"read-{source}", daemon=True)
        self.open_sources.add(source)
        self._threads.append(thread)
        thread.start()

    def _serial(self, source: Source, port: str) -> None:
        try:
            ser = serial.Serial(port, 115200, timeout=READ_TIMEOUT_S)
        except (serial.SerialException, OSError) as exc:
            raise InputError(f"cannot open {source} port {port}: {exc}") from None
        self._closers.append(ser.close)

        def read() -> None:
            while not self._stop.is_set():
                try:
                    # what is waiting, or block for the first byte: read(4096) would hold
                    # bytes back until 4096 arrive or the timeout ends, stamping them late
                    data = ser.read(max(1, ser.in_waiting))
                except (serial.SerialException, OSError, TypeError):
                    break
                if data:
                    self.arrivals.put(Arrival(wall_clock_ns(), source, data))
            self.arrivals.put(Arrival(wall_clock_ns(), source, None))

        self._start(source, read)

    def _can(self, spec: str) -> None:
        interface, channel = parse_can_spec(spec)
        options: dict[str, Any] = {}
        if interface == "slcan":
            options["timeout"] = READ_TIMEOUT_S  # the port's read timeout: block, don't spin
            if channel.startswith("/dev/pts/"):
                options["sleep_after_open"] = 0.0  # an adapter on a pty does not reset on open
        bus: can.BusABC
        try:
            if interface == "slcan":
                bus = BulkSlcanBus(channel=channel, **options)
            else:
                bus = can.Bus(interface=interface, channel=channel, **options)
        except (can.CanError, ValueError, OSError, ImportError) as exc:
            raise InputError(f"cannot open CAN {spec}: {exc}") from None
        self._closers.append(bus.shutdown)

        def read() -> None:
            while not self._stop.is_set():
                try:
                    msg = bus.recv(timeout=READ_TIMEOUT_S)
                except (can.CanError, OSError, ValueError):
                    break
                if msg is not None:
                    self.arrivals.put(Arrival(wall_clock_ns(), Source.INS, msg))
            self.arrivals.put(Arrival(wall_clock_ns(), Source.INS, None))

        self._start(Source.INS, read)

    def _pulses(self, endpoint: str) -> None:
        host, _, port = endpoint.removeprefix("tcp://").rpartition(":")
        if host not in ("127.0.0.1", "localhost", "::1"):
            raise InputError(f"pulse endpoint {endpoint}: only loopback addresses are allowed")
        try:
            sock = socket.create_connection((host, int(port)), timeout=5.0)
        except (OSError, ValueError) as exc:
            raise InputError(f"cannot connect to pulse endpoint {endpoint}: {exc}") from None
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.settimeout(READ_TIMEOUT_S)
        self._pulse_sock = sock
        self._closers.append(sock.close)
        decoder = EdgeStreamDecoder(ErrorPolicy.COUNT)
        self.pulse_decoder = decoder

        def read() -> None:
            while not self._stop.is_set():
                try:
                    data = sock.recv(4096)
                except TimeoutError:
                    continue
                except OSError:
                    break
                if not data:
                    break
                t_host = wall_clock_ns()
                for item in decoder.feed(data):
                    self.arrivals.put(Arrival(t_host, Source.PULSES, item.message))
            self.arrivals.put(Arrival(wall_clock_ns(), Source.PULSES, None))

        self._start(Source.PULSES, read)

    def send_edge(self, edge: Edge) -> None:
        if self._pulse_sock is None:
            return
        with contextlib.suppress(OSError):  # the link is gone; its reader reports the close
            self._pulse_sock.sendall(encode_edge(edge))

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=1.0)
        for closer in self._closers:
            with contextlib.suppress(OSError, can.CanError):
                closer()
