"""Real-time sources for the acquisition: one reader thread per port or bus, all feeding one
queue that a single thread drains in arrival order (the sync filter needs one ordered stream).

Every item is stamped with the host clock the moment its read returns. Pulse edges come from the
timing-board link (TCP on loopback) and the sync unit's output edges go back on the same link.

A device that goes away (a read error or end of file: a pty whose other side closed, an unplugged
USB adapter, a CAN channel lost, the pulse link dropped) does not end its reader: the reader
queues a `LinkEvent` (lost), then keeps reopening the same port / channel / address with a bounded
back-off (`RETRY_FIRST_S` doubling to `RETRY_MAX_S`) until it opens again, and queues a second
`LinkEvent` (restored). Each source retries in its own thread, so the others keep recording.
Only the first open, at start, is strict: a port that cannot be opened then is an input error.
"""

from __future__ import annotations

import contextlib
import os
import queue
import socket
import threading
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, Generic, TypeVar

import can
import serial

from acquisition.canspec import parse_can_spec
from acquisition.clocks import wall_clock_ns
from acquisition.codec import ErrorPolicy
from acquisition.pulses import Edge, EdgeStreamDecoder, encode_edge
from acquisition.slcan_bulk import BulkSlcanBus
from sisa.errors import InputError

READ_TIMEOUT_S = 0.05
RETRY_FIRST_S = 0.2  # first reopen attempt this long after the loss ...
RETRY_MAX_S = 2.0  # ... then doubling up to this
RECONNECT_TIMEOUT_S = 1.0  # a TCP connect attempt while reconnecting

H = TypeVar("H")


class Source(StrEnum):
    GPS = "gps"
    SCANNER = "scanner"
    INS = "ins"
    PULSES = "pulses"


class LinkState(StrEnum):
    LOST = "lost"
    RESTORED = "restored"


@dataclass(frozen=True)
class LinkEvent:
    """A device went away (`LOST`: why in `error`) or came back (`RESTORED`: after `attempts`
    opens). `lost_t_host_ns` is the host time the device went away, in both."""

    state: LinkState
    lost_t_host_ns: int
    error: str = ""
    attempts: int = 0


@dataclass(frozen=True)
class Arrival:
    """One read: bytes (serial), a CAN frame, an edge, or a change of the source's link."""

    t_host_ns: int
    source: Source
    payload: bytes | can.Message | Edge | LinkEvent


class _LostError(Exception):
    """The device behind a reader went away."""


class _Link(Generic[H]):
    """How to open, read and close one source; `read` returns payloads or raises `_LostError`."""

    def __init__(self, open_: Callable[[], H], read: Callable[[H], list[Any]],
                 close: Callable[[H], None]) -> None:
        self.open, self.read, self.close = open_, read, close


class LiveSources:
    """Opens the ports, runs the reader threads, and sends edges back to the timing board."""

    def __init__(self, gps_port: str | None, scanner_port: str | None, ins_bus: str | None,
                 pulses: str | None) -> None:
        self.arrivals: queue.SimpleQueue[Arrival] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._closers: dict[Source, Callable[[], None]] = {}
        self._lock = threading.Lock()
        self._pulse_sock: socket.socket | None = None
        self.open_sources: set[Source] = set()
        self.down: set[Source] = set()  # sources whose device is away right now
        self.retry_first_s = RETRY_FIRST_S
        self.retry_max_s = RETRY_MAX_S
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

    # --- one reader per source, reconnecting ---------------------------------------------------

    def _start(self, source: Source, link: _Link[H], handle: H) -> None:
        thread = threading.Thread(target=self._run, args=(source, link, handle),
                                  name=f"read-{source}", daemon=True)
        self.open_sources.add(source)
        self._set_closer(source, link, handle)
        self._threads.append(thread)
        thread.start()

    def _set_closer(self, source: Source, link: _Link[H], handle: H | None) -> None:
        with self._lock:
            if handle is None:
                self._closers.pop(source, None)
            else:
                self._closers[source] = lambda: link.close(handle)

    def _run(self, source: Source, link: _Link[H], handle: H) -> None:
        while True:
            error = self._read_until_lost(source, link, handle)
            self._set_closer(source, link, None)
            _quietly(link.close, handle)
            if error is None:
                return  # stopping
            lost_ns = wall_clock_ns()
            self.down.add(source)
            self.arrivals.put(Arrival(lost_ns, source, LinkEvent(LinkState.LOST, lost_ns, error)))
            reopened = self._reopen(link)
            if reopened is None:
                return
            handle, attempts = reopened
            self._set_closer(source, link, handle)
            self.down.discard(source)
            self.arrivals.put(Arrival(wall_clock_ns(), source,
                                      LinkEvent(LinkState.RESTORED, lost_ns, "", attempts)))
            if self._stop.is_set():
                self._set_closer(source, link, None)
                _quietly(link.close, handle)
                return

    def _read_until_lost(self, source: Source, link: _Link[H], handle: H) -> str | None:
        """Read until the device goes away (its error) or the sources stop (None)."""
        while not self._stop.is_set():
            try:
                payloads = link.read(handle)
            except _LostError as exc:
                return str(exc) or "lost"
            if payloads:
                t_host = wall_clock_ns()
                for payload in payloads:
                    self.arrivals.put(Arrival(t_host, source, payload))
        return None

    def _reopen(self, link: _Link[H]) -> tuple[H, int] | None:
        """Open again with a bounded back-off: (handle, attempts), or None when stopping."""
        delay, attempts = self.retry_first_s, 0
        while not self._stop.wait(delay):
            attempts += 1
            try:
                return link.open(), attempts
            except _LostError:
                delay = min(2 * delay, self.retry_max_s)
        return None

    # --- the sources ----------------------------------------------------------------------

    def _serial(self, source: Source, port: str) -> None:
        def open_() -> serial.Serial:
            try:
                return serial.Serial(port, 115200, timeout=READ_TIMEOUT_S)
            except (serial.SerialException, OSError, ValueError) as exc:
                raise _LostError(f"cannot open {port}: {exc}") from None

        def read(ser: serial.Serial) -> list[bytes]:
            try:
                # what is waiting, or block for the first byte: read(4096) would hold
                # bytes back until 4096 arrive or the timeout ends, stamping them late
                data = ser.read(max(1, ser.in_waiting))
            except (serial.SerialException, OSError, TypeError) as exc:
                raise _LostError(f"{port}: {exc}") from None
            return [data] if data else []

        try:
            first = open_()
        except _LostError as exc:
            raise InputError(f"cannot open {source} port {port}: {exc}") from None
        self._start(source, _Link(open_, read, serial.Serial.close), first)

    def _can(self, spec: str) -> None:
        interface, channel = parse_can_spec(spec)
        options: dict[str, Any] = {}
        if interface == "slcan":
            options["timeout"] = READ_TIMEOUT_S  # the port's read timeout: block, don't spin
            if os.path.realpath(channel).startswith("/dev/pts/"):
                options["sleep_after_open"] = 0.0  # an adapter on a pty does not reset on open

        def open_() -> can.BusABC:
            try:
                if interface == "slcan":
                    return BulkSlcanBus(channel=channel, **options)
                return can.Bus(interface=interface, channel=channel, **options)
            except (can.CanError, ValueError, OSError, serial.SerialException) as exc:
                raise _LostError(f"cannot open CAN {spec}: {exc}") from None

        def read(bus: can.BusABC) -> list[can.Message]:
            try:
                msg = bus.recv(timeout=READ_TIMEOUT_S)
            except (can.CanError, OSError, ValueError, serial.SerialException) as exc:
                raise _LostError(f"CAN {spec}: {exc}") from None
            return [] if msg is None else [msg]

        try:
            first = open_()
        except ImportError as exc:
            raise InputError(f"cannot open CAN {spec}: {exc}") from None
        except _LostError as exc:
            raise InputError(str(exc)) from None
        self._start(Source.INS, _Link(open_, read, _shutdown_bus), first)

    def _pulses(self, endpoint: str) -> None:
        host, _, port_text = endpoint.removeprefix("tcp://").rpartition(":")
        if host not in ("127.0.0.1", "localhost", "::1"):
            raise InputError(f"pulse endpoint {endpoint}: only loopback addresses are allowed")
        try:
            port = int(port_text)
        except ValueError:
            raise InputError(f"pulse endpoint {endpoint}: no port number") from None

        def connect(timeout_s: float) -> tuple[socket.socket, EdgeStreamDecoder]:
            try:
                sock = socket.create_connection((host, port), timeout=timeout_s)
            except OSError as exc:
                raise _LostError(f"cannot connect to pulse endpoint {endpoint}: {exc}") from None
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            sock.settimeout(READ_TIMEOUT_S)
            decoder = EdgeStreamDecoder(ErrorPolicy.COUNT)  # a new link numbers edges afresh
            self._pulse_sock, self.pulse_decoder = sock, decoder
            return sock, decoder

        def read(link: tuple[socket.socket, EdgeStreamDecoder]) -> list[Edge]:
            sock, decoder = link
            try:
                data = sock.recv(4096)
            except TimeoutError:
                return []
            except OSError as exc:
                raise _LostError(f"pulse link {endpoint}: {exc}") from None
            if not data:
                raise _LostError(f"pulse link {endpoint}: closed by the timing board")
            return [item.message for item in decoder.feed(data)]

        def close(link: tuple[socket.socket, EdgeStreamDecoder]) -> None:
            if self._pulse_sock is link[0]:
                self._pulse_sock = None
            link[0].close()

        try:
            first = connect(5.0)
        except _LostError as exc:
            raise InputError(str(exc)) from None
        self._start(Source.PULSES, _Link(lambda: connect(RECONNECT_TIMEOUT_S), read, close),
                    first)

    def send_edge(self, edge: Edge) -> None:
        sock = self._pulse_sock
        if sock is None:
            return  # the link is away: its reader reports the loss and reconnects
        with contextlib.suppress(OSError):
            sock.sendall(encode_edge(edge))

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=1.0)
        with self._lock:
            closers = list(self._closers.values())
            self._closers.clear()
        for closer in closers:
            _quietly(closer)


def _shutdown_bus(bus: can.BusABC) -> None:
    try:
        bus.shutdown()
    finally:  # an adapter that vanished fails its close command: release the port anyway
        port = getattr(bus, "serialPortOrig", None)
        if port is not None:
            _quietly(port.close)


def _quietly(fn: Callable[..., None], *args: Any) -> None:
    """Close something that may already be gone (its device vanished)."""
    with contextlib.suppress(OSError, can.CanError, serial.SerialException, ValueError,
                             TypeError):
        fn(*args)
