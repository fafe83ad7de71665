"""Tests of the live view (sisa.wiring.live, sisa.wiring.livesync), with clients of our own
that misbehave and an independent one (tests/live/js, @foxglove/ws-protocol)."""

from __future__ import annotations

import base64
import json
import os
import socket
import time
from typing import Any

SUBPROTOCOL = "foxglove.sdk.v1"  # what foxglove-sdk's server speaks (the ws-protocol's v1)


class RawClient:
    """A WebSocket client on a bare socket, so a test can make it misbehave: read nothing,
    send what no client should."""

    def __init__(self, port: int, *, receive_buffer: int | None = None,
                 timeout_s: float = 10.0) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        if receive_buffer is not None:  # before connecting, or the window is already open
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer)
        self.sock.settimeout(timeout_s)
        self.sock.connect(("127.0.0.1", port))
        self.port = port

    def handshake(self) -> None:
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{self.port}\r\nUpgrade: websocket\r\n"
            f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
            f"Sec-WebSocket-Protocol: {SUBPROTOCOL}\r\n\r\n".encode())
        reply = b""
        while b"\r\n\r\n" not in reply:
            chunk = self.sock.recv(4096)
            if not chunk:
                raise ConnectionError("closed during the handshake")
            reply += chunk
        if not reply.startswith(b"HTTP/1.1 101"):
            raise ConnectionError(reply.split(b"\r\n", 1)[0].decode(errors="replace"))
        self._pending = reply.split(b"\r\n\r\n", 1)[1]

    def send_frame(self, payload: bytes, opcode: int = 1, *, declared: int | None = None
                   ) -> None:
        """One masked frame; `declared` lies about its length."""
        n = len(payload) if declared is None else declared
        if n < 126:
            head = bytes([0x80 | opcode, 0x80 | n])
        elif n < 65536:
            head = bytes([0x80 | opcode, 0x80 | 126]) + n.to_bytes(2, "big")
        else:
            head = bytes([0x80 | opcode, 0x80 | 127]) + n.to_bytes(8, "big")
        mask = os.urandom(4)
        self.sock.sendall(head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload)))

    def _read(self, n: int) -> bytes:
        while len(self._pending) < n:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise ConnectionError("closed")
            self._pending += chunk
        out, self._pending = self._pending[:n], self._pending[n:]
        return out

    def read_frame(self) -> tuple[int, bytes]:
        b0, b1 = self._read(2)
        n = b1 & 0x7F
        if n == 126:
            n = int.from_bytes(self._read(2), "big")
        elif n == 127:
            n = int.from_bytes(self._read(8), "big")
        return b0 & 0x0F, self._read(n)

    def subscribe_all(self, deadline_s: float = 30.0) -> int:
        """Wait for the channels' advertisement and subscribe to every one; how many."""
        end = time.monotonic() + deadline_s
        while time.monotonic() < end:
            opcode, payload = self.read_frame()
            if opcode == 1:
                msg: dict[str, Any] = json.loads(payload)
                if msg.get("op") == "advertise":
                    subs = [{"id": i, "channelId": c["id"]}
                            for i, c in enumerate(msg["channels"])]
                    self.send_frame(json.dumps({"op": "subscribe",
                                                "subscriptions": subs}).encode())
                    return len(subs)
        raise TimeoutError("no advertisement")

    def close(self) -> None:
        self.sock.close()
