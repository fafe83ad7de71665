"""Virtual ports with real clients: pyserial on a pty, python-can slcan on the SLCAN adapter,
a TCP socket on the pulse endpoint."""

import socket
import time

import can
import serial

from acquisition.pulses import Edge, EdgeStreamDecoder, PulseLine, encode_edge
from emulators.ports import PtyPort, PulseEndpoint, SlcanAdapter


def test_pty_bytes_pass_unchanged_to_pyserial():
    port = PtyPort()
    try:
        with serial.Serial(port.name, 115200, timeout=1.0) as client:
            payload = b"$GPZDA,120000.00,23,07,1998,00,00*6C\r\n" + bytes(range(256))
            port.write(payload)
            assert client.read(len(payload)) == payload
    finally:
        port.close()


def test_slcan_adapter_serves_python_can():
    adapter = SlcanAdapter()
    try:
        bus = can.Bus(interface="slcan", channel=adapter.name, bitrate=500_000)
        try:
            deadline = time.monotonic() + 2.0
            while not adapter.is_open and time.monotonic() < deadline:
                time.sleep(0.01)
            assert adapter.is_open
            sent = [can.Message(arbitration_id=0x100 + i, data=bytes([i] * 8),
                                is_extended_id=False) for i in range(7)]
            for msg in sent:
                adapter.send(msg)
            got = [bus.recv(timeout=1.0) for _ in sent]
            assert [(m.arbitration_id, bytes(m.data)) for m in got] == [
                (m.arbitration_id, bytes(m.data)) for m in sent]
        finally:
            bus.shutdown()
    finally:
        adapter.close()


def test_pulse_endpoint_both_ways_on_loopback():
    received = []
    endpoint = PulseEndpoint(received.append)
    try:
        host, port = endpoint.address.removeprefix("tcp://").split(":")
        assert host == "127.0.0.1"
        with socket.create_connection((host, int(port)), timeout=2.0) as sock:
            deadline = time.monotonic() + 2.0
            while endpoint._client is None and time.monotonic() < deadline:
                time.sleep(0.01)
            endpoint.send(Edge(PulseLine.PPS, 99, 5_000_000_000))
            endpoint.send(Edge(PulseLine.PPS, 99, 6_000_000_000))
            dec = EdgeStreamDecoder()
            got = []
            while len(got) < 2:
                got += [d.message for d in dec.feed(sock.recv(100))]
            assert [e.t_ns for e in got] == [5_000_000_000, 6_000_000_000]
            assert [e.seq for e in got] == [0, 1]  # numbered by the link
            sock.sendall(encode_edge(Edge(PulseLine.INS_SYNC, 0, 7_000_000_000)))
            deadline = time.monotonic() + 2.0
            while not received and time.monotonic() < deadline:
                time.sleep(0.01)
        assert received == [Edge(PulseLine.INS_SYNC, 0, 7_000_000_000)]
    finally:
        endpoint.close()


def test_bridge_sends_ins_frames_to_any_python_can_bus():
    import queue

    from emulators.bridge import CanTarget, RealTimeBridge
    from emulators.runtime import Output, Port

    bridge = RealTimeBridge(CanTarget.parse("virtual:sisa-test"), queue.SimpleQueue())
    listener = can.Bus(interface="virtual", channel="sisa-test")
    try:
        frame = can.Message(arbitration_id=0x101, data=bytes(range(8)), is_extended_id=False)
        bridge(Output(0, Port.INS_CAN, frame))
        got = listener.recv(timeout=1.0)
        assert got is not None
        assert bytes(got.data) == bytes(range(8))
        assert bridge.endpoints()["ins"] == "virtual:sisa-test"
    finally:
        listener.shutdown()
        bridge.close()


def test_can_target_refuses_udp_multicast_and_bad_forms():
    import pytest

    from emulators.bridge import CanTarget
    from sisa.core.errors import ConfigError

    with pytest.raises(ConfigError, match="loopback"):
        CanTarget.parse("udp_multicast:224.0.0.1")
    with pytest.raises(ConfigError, match="INTERFACE:CHANNEL"):
        CanTarget.parse("virtual")


def _wait(condition, timeout_s: float = 2.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.01)


def test_a_second_client_of_the_pulse_link_is_refused_and_named():
    """Any local process could connect to the pulse link (no authentication) and send edges to
    the devices; it waited in the backlog behind the recorder and took the link when the
    recorder reconnected (issue 39, item 8). Refused at once, unread, counted and named."""
    received = []
    endpoint = PulseEndpoint(received.append)
    host, port = endpoint.address.removeprefix("tcp://").split(":")
    try:
        with socket.create_connection((host, int(port)), timeout=2.0) as first:
            _wait(lambda: endpoint._client is not None)
            with socket.create_connection((host, int(port)), timeout=2.0) as intruder:
                peer = "{}:{}".format(*intruder.getsockname())
                intruder.sendall(encode_edge(Edge(PulseLine.INS_SYNC, 0, 1_000_000_000)))
                intruder.settimeout(2.0)
                try:  # closed by the endpoint: an end of file, or a reset (its bytes unread)
                    got = intruder.recv(100)
                except ConnectionResetError:
                    got = b""
                assert got == b""
            _wait(lambda: endpoint.clients_refused == 1)
            first.sendall(encode_edge(Edge(PulseLine.INS_SYNC, 0, 2_000_000_000)))
            _wait(lambda: bool(received))
        assert received == [Edge(PulseLine.INS_SYNC, 0, 2_000_000_000)]  # the client's only
        assert endpoint.clients_refused == 1
        assert endpoint.refused_peers == [peer]
        note = endpoint.refused_note()
        assert note is not None
        assert peer in note
        assert endpoint.address in note
        # the first client gone, the next one is served
        _wait(lambda: endpoint._client is None)
        with socket.create_connection((host, int(port)), timeout=2.0) as again:
            _wait(lambda: endpoint._client is not None)
            again.sendall(encode_edge(Edge(PulseLine.INS_SYNC, 1, 3_000_000_000)))
            _wait(lambda: len(received) == 2)
        assert received[-1] == Edge(PulseLine.INS_SYNC, 1, 3_000_000_000)
        assert endpoint.clients_refused == 1
    finally:
        endpoint.close()


def test_a_pulse_link_without_intruders_says_nothing():
    endpoint = PulseEndpoint(lambda _e: None)
    try:
        assert endpoint.refused_note() is None
    finally:
        endpoint.close()
