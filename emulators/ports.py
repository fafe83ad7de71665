"""Virtual ports for real-time emulation: ptys for RS-232, an SLCAN adapter on a pty for the CAN
bus between processes (the way a USB–CAN adapter appears), and a loopback TCP endpoint for the
pulse lines (timestamped edges both ways).

The client side opens these with ordinary tools: pyserial on the pty path, python-can
`interface="slcan"` on the adapter's pty path, a TCP socket on 127.0.0.1.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import threading
import tty
from collections.abc import Callable

import can

from acquisition.codec import ErrorPolicy
from acquisition.pulses import Edge, EdgeStreamDecoder, encode_edge
from acquisition.slcan_bulk import encode_frame_line

LOOPBACK = "127.0.0.1"


class PtyPort:
    """A pty pair: the emulator writes to the master; clients open `name` (the slave path)."""

    def __init__(self) -> None:
        self.master_fd, self._slave_fd = os.openpty()
        tty.setraw(self._slave_fd)  # no echo, no CR/LF translation: bytes pass unchanged
        os.set_blocking(self.master_fd, False)
        self.name = os.ttyname(self._slave_fd)
        self.bytes_dropped = 0

    def write(self, data: bytes) -> None:
        """Write without blocking; bytes that do not fit the pty buffer are counted as dropped."""
        try:
            sent = os.write(self.master_fd, data)
        except BlockingIOError:
            sent = 0
        self.bytes_dropped += len(data) - sent

    def read_available(self) -> bytes:
        try:
            return os.read(self.master_fd, 65536)
        except (BlockingIOError, OSError):
            return b""

    def close(self) -> None:
        for fd in (self.master_fd, self._slave_fd):
            with contextlib.suppress(OSError):
                os.close(fd)


class SlcanAdapter:
    """The firmware of a USB–SLCAN adapter, on a pty: answers the host's ASCII commands and
    forwards CAN frames to it as `tIIILDD..\\r` lines once the host has opened the channel."""

    VERSION_REPLY = b"V1013\r"
    SERIAL_REPLY = b"NSISA\r"

    def __init__(self) -> None:
        self.port = PtyPort()
        self.name = self.port.name
        self.is_open = False
        self.frames_sent = 0
        self.frames_dropped = 0  # offered while the host had not opened the channel
        self._buf = bytearray()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="slcan", daemon=True)
        self._thread.start()

    def send(self, msg: can.Message) -> None:
        if not self.is_open:
            self.frames_dropped += 1
            return
        self.port.write(encode_frame_line(msg.arbitration_id, msg.is_extended_id,
                                          bytes(msg.data)))
        self.frames_sent += 1

    def _serve(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self.port.master_fd], [], [], 0.05)
            if ready:
                self._buf += self.port.read_available()
                self._answer_commands()

    def _answer_commands(self) -> None:
        while (end := self._buf.find(b"\r")) >= 0:
            cmd = bytes(self._buf[:end])
            del self._buf[: end + 1]
            self.port.write(self._reply(cmd))

    def _reply(self, cmd: bytes) -> bytes:
        head = cmd[:1]
        if head == b"O" or head == b"L":
            self.is_open = True
        elif head == b"C":
            self.is_open = False
        elif head == b"V":
            return self.VERSION_REPLY
        elif head == b"N":
            return self.SERIAL_REPLY
        return b"\r"

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self.port.close()


MAX_PEERS_NAMED = 4  # refused pulse-link connections named (all are counted)


class PulseEndpoint:
    """Loopback TCP server carrying edges: device outputs go to the connected client; edges the
    client sends (the sync unit's pulses) are handed to `on_edge` from the receiving thread.

    Sequence numbers belong to the link, not to the devices: the endpoint numbers what it sends
    per line, so a receiver can count edges lost in transport (a spurious pulse on a real wire
    is indistinguishable from a true one, and is numbered like one).

    The link has no authentication (a bench on loopback, like gpsd's port): one client at a
    time. A connection made while a client is connected is closed at once, unread, and counted
    and named (`clients_refused`, `refused_peers`): an edge another local process sends cannot
    reach the devices, and one queued behind the recorder's connection cannot take its place
    when the recorder reconnects."""

    def __init__(self, on_edge: Callable[[Edge], None], port: int = 0) -> None:
        self._server = socket.create_server((LOOPBACK, port))
        self._server.settimeout(0.1)  # lets the accept loop notice close()
        self.address = f"tcp://{LOOPBACK}:{self._server.getsockname()[1]}"
        self._on_edge = on_edge
        self._client: socket.socket | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.decoder = EdgeStreamDecoder(ErrorPolicy.COUNT)
        self.edges_dropped = 0  # produced while no client was connected
        self.clients_refused = 0  # connections made while a client was connected
        self.refused_peers: list[str] = []  # the first few of them, "HOST:PORT"
        self._seq: dict[int, int] = {}
        self._thread = threading.Thread(target=self._serve, name="pulses", daemon=True)
        self._thread.start()

    def send(self, edge: Edge) -> None:
        with self._lock:
            client = self._client
        if client is None:
            self.edges_dropped += 1
            return
        seq = self._seq.get(edge.line, 0)
        self._seq[edge.line] = seq + 1
        try:
            client.sendall(encode_edge(Edge(edge.line, seq, edge.t_ns)))
        except OSError:
            self.edges_dropped += 1

    def _serve(self) -> None:
        """Accept connections for as long as the endpoint is open: the first becomes the
        client (read in a thread of its own), any other while it is connected is refused."""
        while not self._stop.is_set():
            try:
                conn, peer = self._server.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            with self._lock:
                busy = self._client is not None
                if not busy:
                    self._client = conn
            if busy:
                self._refuse(conn, peer)
                continue
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            threading.Thread(target=self._serve_client, args=(conn,), name="pulses-client",
                             daemon=True).start()

    def refused_note(self) -> str | None:
        """The connections refused while a client was connected, in words (None: none): said,
        since any local process could have made them."""
        n = self.clients_refused
        if not n:
            return None
        more = ", ..." if n > len(self.refused_peers) else ""
        return (f"{n} connection{'s' if n != 1 else ''} to the pulse link {self.address} "
                f"refused while a client was connected (from {', '.join(self.refused_peers)}"
                f"{more}): the link takes one client, and nothing they sent was read")

    def _refuse(self, conn: socket.socket, peer: tuple[str, int]) -> None:
        self.clients_refused += 1
        if len(self.refused_peers) < MAX_PEERS_NAMED:
            self.refused_peers.append(f"{peer[0]}:{peer[1]}")
        conn.close()

    def _serve_client(self, conn: socket.socket) -> None:
        try:
            self._receive(conn)
        finally:
            with self._lock:
                if self._client is conn:
                    self._client = None
            conn.close()

    def _receive(self, conn: socket.socket) -> None:
        conn.settimeout(0.1)
        while not self._stop.is_set():
            try:
                data = conn.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                return
            if not data:
                return
            for item in self.decoder.feed(data):
                self._on_edge(item.message)

    def close(self) -> None:
        self._stop.set()
        with self._lock:
            if self._client is not None:
                self._client.close()
        self._server.close()
        self._thread.join(timeout=1.0)
