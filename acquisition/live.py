"""Real-time sources for the acquisition: every port and bus watched by one event loop.

`LiveSources.poll` waits on all device handles at once (`select`), reads whatever has arrived
and returns it as `Arrival`s in the order read; the caller (one thread: the sync filter needs
one ordered stream) decodes and records them. One loop instead of a reader thread per device:
no hand-over of every read between threads, which at a few hundred reads a second is most of
a threaded recorder's CPU. Each item is stamped with the host clock the moment its read
returns. Pulse edges come from the timing-board link (TCP on loopback) and the sync unit's
output edges go back on the same link.

A device that goes away (a read error or end of file: a pty whose other side closed, an unplugged
USB adapter, a CAN channel lost, the pulse link dropped) does not stop the others: `poll`
returns a `LinkEvent` (lost) for it, then keeps reopening the same port / channel / address with
a bounded back-off (`RETRY_FIRST_S` doubling to `RETRY_MAX_S`) between waits, and returns a
second `LinkEvent` (restored) when the device is back. Only the first open, at start, is
strict: a port that cannot be opened then is an input error. A python-can interface without a
file descriptor to wait on is asked for frames every `UNWAITABLE_POLL_S`.

A serial device or SLCAN adapter that opens again is not taken on its path alone
(`acquisition.proof`): it is reopened through its stable udev name when it has one, and held on
probation, nothing of it recorded and nothing written to it, until it speaks its protocol; a
port that turns out to be something else (a pty number the kernel gave to another program) is
given up with a `LinkEvent` (rejected) saying why, and that device node is not opened again.

With `read_interval_s` > 0 the loop reads on a clock instead of on every arrival: `poll` sleeps
to the next read time and takes whatever has arrived on every device. An INS's ~450 CAN frames
a second come a fifth of a millisecond apart, interleaved with headers and pulse edges; woken by
each, the loop spends as much on waking as on decoding. Read every 5 ms, each wake-up takes a
burst. The price is host receive times up to `read_interval_s` late: they were never better than
a USB or pty latency, pulse edges carry the timing board's own times, and only the scanner
headers' latency window must allow for it (`scenario show` notes when it does not).
"""

from __future__ import annotations

import contextlib
import ipaddress
import os
import selectors
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, Generic, TypeVar

import can
import serial

from acquisition.canspec import parse_can_spec
from acquisition.clocks import wall_clock_ns
from acquisition.codec import DecodeStats, ErrorPolicy
from acquisition.proof import (
    SLCAN_LISTEN_S,
    DeviceInstance,
    ProbePort,
    Prover,
    SlcanProof,
    Verdict,
    camera_proof,
    device_instance,
    gps_proof,
    scanner_proof,
    stable_serial_path,
)
from acquisition.pulses import Edge, EdgeStreamDecoder, encode_edge
from acquisition.slcan_bulk import BulkSlcanBus
from sisa.core.errors import InputError

READ_SIZE = 65536
RETRY_FIRST_S = 0.2  # first reopen attempt this long after the loss ...
RETRY_MAX_S = 2.0  # ... then doubling up to this
RECONNECT_TIMEOUT_S = 0.5  # a TCP connect attempt while reconnecting (loopback: refused at once)
PROBATION_TICK_S = 0.05  # a device on probation: its timeouts and probe are looked at this often
UNWAITABLE_POLL_S = 0.002  # a CAN interface without a file descriptor is polled this often
# an edge the timing board does not take in this long is not sent, and the link is dropped and
# reopened: a board that stopped reading (hung, its socket still open) filled the link's buffer,
# and then held every later edge, and with it every device's reading, this long
SEND_TIMEOUT_S = 0.5

H = TypeVar("H")


class Source(StrEnum):
    GPS = "gps"
    SCANNER = "scanner"
    INS = "ins"
    PULSES = "pulses"
    CAMERA = "camera"


class LinkState(StrEnum):
    LOST = "lost"
    RESTORED = "restored"
    REJECTED = "rejected"  # a port opened again, but not the device: given up, still away


@dataclass(frozen=True)
class LinkEvent:
    """A device went away (`LOST`: why in `error`), came back (`RESTORED`: after `attempts`
    opens), or its port opened again with something else behind it (`REJECTED`: why in
    `error`; still away). `lost_t_host_ns` is the host time the device went away, in all."""

    state: LinkState
    lost_t_host_ns: int
    error: str = ""
    attempts: int = 0


@dataclass(frozen=True)
class GarbledCanLines:
    """Lines from a CAN adapter that did not parse as frames (corrupted on its serial link),
    and their bytes."""

    lines: int
    bytes_skipped: int = 0


@dataclass(frozen=True)
class Arrival:
    """One read: bytes (serial), the CAN frames that had arrived, an edge, or a change of the
    source's link."""

    t_host_ns: int
    source: Source
    payload: bytes | list[can.Message] | GarbledCanLines | Edge | LinkEvent


class _LostError(Exception):
    """The device behind a source went away."""


@dataclass(frozen=True)
class _Probation(Generic[H]):
    """How a reopened device is held until it proves itself (`acquisition.proof`): its node
    (`path`, followed), a new prover, and how to take it once proven: open it for good (a
    handle on the same node as the probe, or `_LostError`) with the payloads its proof
    carried."""

    path: str
    new_prover: Callable[[float], Prover]
    accept: Callable[[ProbePort, Verdict], tuple[H, list[Any]]]


class _Link(Generic[H]):
    """One source: how to open it, the descriptor to wait on (None: poll it), how to read what
    has arrived without blocking (payloads, or `_LostError`), how to close it; how a reopened
    device proves itself (None: it is taken as it opens); and its state."""

    def __init__(self, source: Source, open_: Callable[[], H],
                 fileno: Callable[[H], int | None], read: Callable[[H], list[Any]],
                 close: Callable[[H], None], probation: _Probation[H] | None = None) -> None:
        self.source = source
        self.open, self.fileno, self.read, self.close = open_, fileno, read, close
        self.probation = probation
        self.probe: ProbePort | None = None  # a reopened device on probation ...
        self.prover: Prover | None = None  # ... and what judges it
        self.rejected: set[DeviceInstance] = set()  # nodes that proved to be something else
        self.handle: H | None = None
        self.fd: int | None = None
        self.lost_ns = 0
        self.retry_at_s = 0.0
        self.retry_delay_s = 0.0
        self.attempts = 0


class LiveSources:
    """Opens the ports, waits on them all in `poll`, and sends edges back to the timing board."""

    def __init__(self, gps_port: str | None, scanner_port: str | None, ins_bus: str | None,
                 pulses: str | None, read_interval_s: float = 0.0,
                 camera_port: str | None = None) -> None:
        self._selector = selectors.DefaultSelector()
        self.read_interval_s = read_interval_s
        self._next_read_s = 0.0  # monotonic: with a read interval, when to read next
        self._links: dict[Source, _Link[Any]] = {}
        self._pulse_sock: socket.socket | None = None
        self._pulse_stuck = ""  # why the pulse link is being dropped from the sending side
        # the pulse link's decode counts (bytes that were no edge), over all its connections:
        # the acquisition reports them (`Acquisition` takes them with `send_edge`)
        self.pulse_stats = DecodeStats()
        self.pulse_decoder = EdgeStreamDecoder(ErrorPolicy.COUNT, self.pulse_stats)
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
            if camera_port:
                self._serial(Source.CAMERA, camera_port)
        except BaseException:
            self.close()
            raise

    # --- the loop ------------------------------------------------------------------------------

    def poll(self, timeout_s: float) -> list[Arrival]:
        """What arrives within `timeout_s` (returns as soon as anything does; with a read
        interval, what has arrived at the next read time), plus link events."""
        now = time.monotonic()
        wait = timeout_s
        for link in self._links.values():
            if link.probe is not None:
                wait = min(wait, PROBATION_TICK_S)
            elif link.handle is None:
                wait = min(wait, max(0.0, link.retry_at_s - now))
            elif link.fd is None:
                wait = min(wait, UNWAITABLE_POLL_S)
        if self.read_interval_s > 0:
            self._sleep_to_read_time(now, wait)
            wait = 0.0  # take what has arrived
        ready = self._selector.select(wait) if self._selector.get_map() else _sleep(wait)
        arrivals: list[Arrival] = []
        for key, _ in ready:
            self._read(key.data, arrivals)
        for link in self._links.values():
            if link.handle is not None and link.fd is None:
                self._read(link, arrivals)
        now = time.monotonic()
        for link in self._links.values():
            if link.prover is not None:
                self._judge(link, link.prover.tick(now), arrivals)
            elif link.handle is None and now >= link.retry_at_s:
                self._retry(link, arrivals)
        return arrivals

    def _sleep_to_read_time(self, now: float, wait: float) -> None:
        """Sleep to the next read time, or for `wait` if that comes first (a reopen is due)."""
        ahead = self._next_read_s - now
        if ahead >= wait:
            time.sleep(wait)
            return
        if ahead > 0:
            time.sleep(ahead)
        self._next_read_s = max(self._next_read_s, now) + self.read_interval_s

    def _read(self, link: _Link[Any], arrivals: list[Arrival]) -> None:
        if link.probe is not None:
            self._read_on_probation(link, link.probe, arrivals)
            return
        try:
            payloads = link.read(link.handle)
        except _LostError as exc:
            self._lost(link, str(exc) or "lost", arrivals)
            return
        if payloads:
            t_host = wall_clock_ns()
            arrivals.extend(Arrival(t_host, link.source, p) for p in payloads)

    def _lost(self, link: _Link[Any], error: str, arrivals: list[Arrival]) -> None:
        self._drop_handle(link)
        if link.source in self.down:  # went again while on probation: still the same outage
            self._retry_later(link)
            return
        link.lost_ns = wall_clock_ns()
        link.retry_delay_s = self.retry_first_s
        link.retry_at_s = time.monotonic() + link.retry_delay_s
        link.attempts = 0
        self.down.add(link.source)
        arrivals.append(Arrival(link.lost_ns, link.source,
                                LinkEvent(LinkState.LOST, link.lost_ns, error)))

    def _retry_later(self, link: _Link[Any]) -> None:
        link.retry_delay_s = min(2 * link.retry_delay_s, self.retry_max_s)
        link.retry_at_s = time.monotonic() + link.retry_delay_s

    def _retry(self, link: _Link[Any], arrivals: list[Arrival]) -> None:
        probation = link.probation
        if probation is not None:
            self._open_on_probation(link, probation, arrivals)
            return
        link.attempts += 1
        try:
            handle = link.open()
        except _LostError:
            self._retry_later(link)
            return
        self._attach(link, handle)
        self._restored(link, arrivals)

    def _open_on_probation(self, link: _Link[H], probation: _Probation[H],
                           arrivals: list[Arrival]) -> None:
        """Open the device's node as a probe (nothing written, a pty's settings untouched),
        unless it is one that proved to be something else."""
        if device_instance(probation.path) in link.rejected:
            self._retry_later(link)  # not opened again: it would only be read from
            return
        link.attempts += 1
        try:
            probe = ProbePort(probation.path)
        except OSError:
            self._retry_later(link)
            return
        if probe.instance in link.rejected:  # the path changed since the stat
            probe.close()
            self._retry_later(link)
            return
        now = time.monotonic()
        link.probe, link.prover = probe, probation.new_prover(now)
        self._selector.register(probe.fd, selectors.EVENT_READ, link)
        self._judge(link, link.prover.tick(now), arrivals)

    def _restored(self, link: _Link[Any], arrivals: list[Arrival]) -> int:
        self.down.discard(link.source)
        t_host = wall_clock_ns()
        arrivals.append(Arrival(t_host, link.source,
                                LinkEvent(LinkState.RESTORED, link.lost_ns, "", link.attempts)))
        return t_host

    def _read_on_probation(self, link: _Link[Any], probe: ProbePort,
                           arrivals: list[Arrival]) -> None:
        assert link.prover is not None
        try:
            data = probe.read()
        except OSError:  # gone again
            self._lost(link, "", arrivals)
            return
        self._judge(link, link.prover.feed(data, time.monotonic()), arrivals)

    def _judge(self, link: _Link[Any], verdict: Verdict, arrivals: list[Arrival]) -> None:
        """Act on a probation's verdict: write what the prover asks, take the device back, or
        give the port up (that node is not opened again) and say why."""
        probe, probation = link.probe, link.probation
        assert probe is not None
        assert probation is not None
        try:
            if verdict.write:
                probe.write(verdict.write)
            if verdict.proven:
                handle, payloads = probation.accept(probe, verdict)
        except (OSError, _LostError):  # gone again
            self._lost(link, "", arrivals)
            return
        if verdict.proven:
            with contextlib.suppress(KeyError, ValueError):
                self._selector.unregister(probe.fd)
            link.probe = link.prover = None
            if handle is not probe:  # the device is open for good beside it
                _quietly(probe.close)
            self._attach(link, handle)
            t_host = self._restored(link, arrivals)
            arrivals.extend(Arrival(t_host, link.source, p) for p in payloads)
        elif verdict.rejected:
            link.rejected.add(probe.instance)
            written = (f"only {probe.written!r} written to it" if probe.written
                       else "nothing written to it")
            self._drop_handle(link)
            self._retry_later(link)
            arrivals.append(Arrival(wall_clock_ns(), link.source, LinkEvent(
                LinkState.REJECTED, link.lost_ns,
                f"{probation.path} opened, but is not the {link.source}: {verdict.rejected}; "
                f"nothing recorded from it, {written}, not opened again", link.attempts)))

    def _attach(self, link: _Link[H], handle: H) -> None:
        link.handle, link.fd = handle, link.fileno(handle)
        if link.fd is not None:
            self._selector.register(link.fd, selectors.EVENT_READ, link)

    def _drop_handle(self, link: _Link[Any]) -> None:
        """Close the device, or the probe on it (closed as it is: nothing written to it)."""
        fd = link.probe.fd if link.probe is not None else link.fd
        if fd is not None:
            with contextlib.suppress(KeyError, ValueError):
                self._selector.unregister(fd)
        if link.probe is not None:
            _quietly(link.probe.close)
        elif link.handle is not None:
            _quietly(link.close, link.handle)
        link.handle, link.fd, link.probe, link.prover = None, None, None, None

    def _add(self, link: _Link[H], first: H) -> None:
        self._links[link.source] = link
        self.open_sources.add(link.source)
        self._attach(link, first)

    # --- the sources ----------------------------------------------------------------------

    def _serial(self, source: Source, port: str) -> None:
        def open_at(path: str) -> serial.Serial:
            try:
                return serial.Serial(path, 115200, timeout=0)
            except (serial.SerialException, OSError, ValueError) as exc:
                raise _LostError(f"cannot open {path}: {exc}") from None

        def read(ser: serial.Serial | ProbePort) -> list[bytes]:
            try:
                data = _read_fd(ser.fileno())
            except OSError as exc:
                raise _LostError(f"{port}: {exc}") from None
            if data is None:
                raise _LostError(f"{port}: end of file (the device closed)")
            return [data] if data else []

        def accept(probe: ProbePort, verdict: Verdict) -> tuple[ProbePort, list[bytes]]:
            return probe, [verdict.data] if verdict.data else []  # it is only ever read

        try:
            first = open_at(port)
        except _LostError as exc:
            raise InputError(f"cannot open {source} port {port}: {exc}") from None
        again = stable_serial_path(port)  # reopened by its udev name if it has one
        proof = {Source.GPS: gps_proof, Source.CAMERA: camera_proof}.get(source, scanner_proof)
        link: _Link[serial.Serial | ProbePort] = _Link(
            source, lambda: open_at(again), _fileno, read, _close,
            _Probation(again, lambda _now: proof(), accept))
        self._add(link, first)

    def _can(self, spec: str) -> None:
        interface, channel = parse_can_spec(spec)
        options: dict[str, Any] = {}
        if interface == "slcan":
            options["timeout"] = 0.0
            if os.path.realpath(channel).startswith("/dev/pts/"):
                options["sleep_after_open"] = 0.0  # an adapter on a pty does not reset on open
        again = stable_serial_path(channel) if interface == "slcan" else channel

        def open_(name: str = channel) -> can.BusABC:
            try:
                if interface == "slcan":
                    return BulkSlcanBus(channel=name, **options)
                return can.Bus(interface=interface, channel=name, **options)
            except (can.CanError, ValueError, OSError, serial.SerialException) as exc:
                raise _LostError(f"cannot open CAN {spec}: {exc}") from None

        def fileno(bus: can.BusABC) -> int | None:
            try:
                fd = bus.fileno()
            except (NotImplementedError, OSError, ValueError):
                return None
            return fd if isinstance(fd, int) and fd >= 0 else None

        def read(bus: can.BusABC) -> list[list[can.Message] | GarbledCanLines]:
            garbled: list[list[can.Message] | GarbledCanLines] = []
            try:
                if isinstance(bus, BulkSlcanBus):
                    before, before_bytes = bus.garbled, bus.garbled_bytes
                    frames = bus.recv_ready()
                    if bus.garbled > before:
                        garbled.append(GarbledCanLines(bus.garbled - before,
                                                       bus.garbled_bytes - before_bytes))
                else:
                    frames = []
                    while (msg := bus.recv(timeout=0.0)) is not None:
                        frames.append(msg)
            except (can.CanError, OSError, ValueError, serial.SerialException) as exc:
                raise _LostError(f"CAN {spec}: {exc}") from None
            return garbled + ([frames] if frames else [])

        def accept(probe: ProbePort, _verdict: Verdict) -> tuple[can.BusABC, list[Any]]:
            # proven an SLCAN adapter: python-can opens it (`O\r`), on the node that proved it
            options["sleep_after_open"] = 0.0  # the probation gave it its time
            return _on_node(open_(again), probe, fileno, _shutdown_bus), []

        # an adapter that resets when its port opens (python-can sleeps 2 s for that) is given
        # as long to send frames before it is asked the version query
        listen_s = (SLCAN_LISTEN_S if options.get("sleep_after_open") == 0.0
                    else float(BulkSlcanBus._SLEEP_AFTER_SERIAL_OPEN))
        probation = (_Probation(again, lambda now: SlcanProof(now, listen_s), accept)
                     if interface == "slcan" else None)
        try:
            first = open_()
        except ImportError as exc:
            raise InputError(f"cannot open CAN {spec}: {exc}") from None
        except _LostError as exc:
            raise InputError(str(exc)) from None
        except Exception as exc:  # a python-can plugin's own bug (kvaser
            # without its library: a NameError) is still the bus that cannot be opened
            raise InputError(f"cannot open CAN {spec}: {type(exc).__name__}: {exc}") from None
        self._add(_Link(Source.INS, lambda: open_(again), fileno, read, _shutdown_bus,
                        probation), first)

    def _pulses(self, endpoint: str) -> None:
        host, _, port_text = endpoint.removeprefix("tcp://").rpartition(":")
        if not _is_loopback(host):
            raise InputError(f"pulse endpoint {endpoint}: only loopback addresses are allowed")
        try:
            port = int(port_text)
        except ValueError:
            raise InputError(f"pulse endpoint {endpoint}: no port number") from None

        def connect(timeout_s: float) -> socket.socket:
            try:
                sock = socket.create_connection((host, port), timeout=timeout_s)
            except OSError as exc:
                raise _LostError(f"cannot connect to pulse endpoint {endpoint}: {exc}") from None
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            sock.settimeout(SEND_TIMEOUT_S)  # reads only when select says so; a send may wait
            self._pulse_sock, self._pulse_stuck = sock, ""
            # a new link numbers afresh; its errors add to the link's
            self.pulse_decoder = EdgeStreamDecoder(ErrorPolicy.COUNT, self.pulse_stats)
            return sock

        def read(sock: socket.socket) -> list[Edge]:
            try:
                data = sock.recv(READ_SIZE)
            except OSError as exc:
                raise _LostError(f"pulse link {endpoint}: {exc}") from None
            if not data:
                raise _LostError(self._pulse_stuck
                                 or f"pulse link {endpoint}: closed by the timing board")
            return [item.message for item in self.pulse_decoder.feed(data)]

        def close(sock: socket.socket) -> None:
            if self._pulse_sock is sock:
                self._pulse_sock = None
            sock.close()

        try:
            first = connect(5.0)
        except _LostError as exc:
            raise InputError(str(exc)) from None
        self._add(_Link(Source.PULSES, lambda: connect(RECONNECT_TIMEOUT_S), socket.socket.fileno,
                        read, close), first)

    def send_edge(self, edge: Edge) -> None:
        sock = self._pulse_sock
        if sock is None:
            return  # the link is away: `poll` reports the loss and reconnects
        try:
            sock.sendall(encode_edge(edge))
        except TimeoutError:
            self._drop_stuck_pulse_link(sock)
        except OSError:
            pass  # the link is gone: its read says so

    def _drop_stuck_pulse_link(self, sock: socket.socket) -> None:
        """The timing board took no edge for SEND_TIMEOUT_S: no more edges go to this socket,
        and its read side is shut, so `poll` sees an end of file, reports the link lost and
        reconnects (a board that is alive takes the new connection with empty buffers)."""
        self._pulse_sock = None
        self._pulse_stuck = (f"pulse link: the timing board took no edge for "
                             f"{SEND_TIMEOUT_S:g} s (dropped to reconnect)")
        with contextlib.suppress(OSError):
            sock.shutdown(socket.SHUT_RD)

    def close(self) -> None:
        for link in self._links.values():
            self._drop_handle(link)
        self._selector.close()


def _read_fd(fd: int) -> bytes | None:
    """What has arrived on a device (b"": nothing yet; None: end of file, it closed)."""
    try:
        data = os.read(fd, READ_SIZE)
    except BlockingIOError:
        return b""
    return data or None


def _fileno(port: serial.Serial | ProbePort) -> int:
    return port.fileno()


def _close(port: serial.Serial | ProbePort) -> None:
    port.close()


def _on_node(handle: H, probe: ProbePort, fileno: Callable[[H], int | None],
             close: Callable[[H], None]) -> H:
    """`handle`, opened on the path a probe proved: if the path now leads elsewhere (another
    node took it since), closed, and `_LostError`."""
    fd = fileno(handle)
    if fd is None or device_instance(fd=fd) != probe.instance:
        _quietly(close, handle)
        raise _LostError("the device's path changed while it proved itself")
    return handle


def _is_loopback(host: str) -> bool:
    """localhost, 127.0.0.0/8 or ::1: every address that stays on this machine."""
    try:
        return host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _sleep(wait_s: float) -> list[tuple[selectors.SelectorKey, int]]:
    """Every device away: nothing to select on, only the next reopen to wait for."""
    time.sleep(wait_s)
    return []


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
