"""The bulk-reading SLCAN bus on a real pty: every frame that has arrived in one read, and a line
corrupted on the adapter's serial link counted and skipped instead of ending the link."""

import os
import select
import time

import can

from acquisition.slcan_bulk import BulkSlcanBus, encode_frame_line, parse_frame_line


def _bus_on_a_pty() -> tuple[BulkSlcanBus, int]:
    master, slave = os.openpty()
    bus = BulkSlcanBus(channel=os.ttyname(slave), timeout=0.0, sleep_after_open=0.0)
    os.close(slave)
    time.sleep(0.05)
    os.read(master, 4096)  # the open commands the bus sent to the adapter
    return bus, master


def _ready(bus: BulkSlcanBus) -> None:
    assert select.select([bus.fileno()], [], [], 2.0)[0], "nothing arrived"


def _ids_after_writing(bus: BulkSlcanBus, master: int, data: bytes) -> list[int]:
    os.write(master, data)
    time.sleep(0.05)
    _ready(bus)
    return [f.arbitration_id for f in bus.recv_ready()]


def test_frames_of_one_burst_come_in_one_read() -> None:
    bus, master = _bus_on_a_pty()
    try:
        os.write(master, b"".join(b"t10%d8%s\r" % (i, b"0011223344556677") for i in range(7)))
        time.sleep(0.05)
        _ready(bus)
        frames = bus.recv_ready()
        assert [f.arbitration_id for f in frames] == [0x100 + i for i in range(7)]
        assert bytes(frames[0].data) == bytes.fromhex("0011223344556677")
        assert bus.garbled == 0
    finally:
        bus.shutdown()
        os.close(master)


def test_a_garbled_line_is_counted_and_skipped() -> None:
    bus, master = _bus_on_a_pty()
    try:
        # a frame whose tail was dropped by an overrun, glued to the next: not hex where data is
        garbled = (b"t1018001122t1028AABBCCDDEEFF0011\rt1038zz11223344556677\r"
                   b"t1048FFEEDDCCBBAA9988\r")
        assert _ids_after_writing(bus, master, garbled) == [0x104]
        assert bus.garbled == 2
        # and the bus goes on reading
        assert _ids_after_writing(bus, master, b"t1058FFEEDDCCBBAA9988\r") == [0x105]
    finally:
        bus.shutdown()
        os.close(master)


def test_frame_lines_parse_like_python_can() -> None:
    std = parse_frame_line(b"t1238DEADBEEF00112233")
    assert std is not None
    assert (std.arbitration_id, std.is_extended_id, std.dlc) == (0x123, False, 8)
    assert bytes(std.data) == bytes.fromhex("DEADBEEF00112233")
    ext = parse_frame_line(b"T1ABCDEF02A0B1")
    assert ext is not None
    assert (ext.arbitration_id, ext.is_extended_id, bytes(ext.data)) == (0x1ABCDEF0, True,
                                                                         b"\xa0\xb1")
    stamped = parse_frame_line(b"t12320011" + b"1F2E")
    assert stamped is not None
    assert bytes(stamped.data) == b"\x00\x11"
    remote = parse_frame_line(b"r7FF4")
    assert remote is not None
    assert (remote.is_remote_frame, remote.dlc) == (True, 4)
    assert parse_frame_line(b"t1000") is not None  # no data bytes
    for reply in (b"", b"z", b"Z"):
        assert parse_frame_line(reply) is None


def test_lines_that_are_not_classic_frames_raise() -> None:
    for bad in (b"t12380011", b"t1238" + b"00" * 8 + b"112233", b"t123900", b"tXYZ100",
                b"d1238" + b"00" * 8, b"V1013", b"t12", b"t1238zz11223344556677"):
        try:
            parse_frame_line(bad)
        except (ValueError, IndexError):
            continue
        raise AssertionError(f"{bad!r} parsed")


def test_replies_between_frames_are_passed_over() -> None:
    bus, master = _bus_on_a_pty()
    try:
        for _ in range(2):  # two frames sent: their acknowledgements are due, with the open's OK
            bus.send(can.Message(arbitration_id=0x7FF, data=b"\x01", is_extended_id=False))
        mixed = b"t1018FFEEDDCCBBAA9988\r\rz\r\a" b"T000001022AABB\r"
        assert _ids_after_writing(bus, master, mixed) == [0x101, 0x102]
        assert bus.garbled == 0
        assert _ids_after_writing(bus, master, b"t1028FFEE") == []  # half a line: kept
        assert _ids_after_writing(bus, master, b"DDCCBBAA9988\r") == [0x102]
    finally:
        bus.shutdown()
        os.close(master)


def test_the_fast_parse_agrees_with_python_can() -> None:
    lines = [b"t1238DEADBEEF00112233", b"T1ABCDEF02A0B1", b"r7FF4", b"t1000", b"R000000013",
             b"t12320011" + b"1F2E"]
    bus, master = _bus_on_a_pty()
    try:
        os.write(master, b"".join(line + b"\r" for line in lines))
        time.sleep(0.05)
        theirs = [bus.recv(timeout=1.0) for _ in lines]  # python-can's own parse
    finally:
        bus.shutdown()
        os.close(master)
    for line, their in zip(lines, theirs, strict=True):
        ours = parse_frame_line(line)
        assert ours is not None
        assert their is not None
        assert ours.equals(their, timestamp_delta=None), (line, ours, their)


def test_bytes_without_a_terminator_do_not_pile_up() -> None:
    """An adapter sending no terminator (garbage, a wrong baud rate) grew the line buffer with
    every read, without bound; past PENDING_MAX bytes they are dropped and counted, and the
    frames after them come through."""
    from acquisition.slcan_bulk import PENDING_MAX

    bus, master = _bus_on_a_pty()
    try:
        junk = b"x" * 1000
        for _ in range(3 * PENDING_MAX // len(junk)):
            assert _ids_after_writing(bus, master, junk) == []
        assert len(bus._buffer) <= PENDING_MAX
        assert bus.garbled >= 1
        assert bus.garbled_bytes > PENDING_MAX  # what was dropped is accounted as bytes
        frames = b"\rt10180011223344556677\rt1028AABBCCDDEEFF0011\r"
        assert _ids_after_writing(bus, master, frames) == [0x101, 0x102]
    finally:
        bus.shutdown()
        os.close(master)


def test_garbled_bytes_are_counted_as_bytes() -> None:
    """A bad line counted as one line only: 6 MB of noise showed as 48 bytes skipped in the
    health channel. Its bytes (and terminator) are counted too."""
    bus, master = _bus_on_a_pty()
    try:
        bad = b"t1038zz11223344556677\r"  # not hex where data is: 22 bytes with its \r
        assert _ids_after_writing(bus, master, bad + b"t1018AABBCCDDEEFF0011\r") == [0x101]
        assert (bus.garbled, bus.garbled_bytes) == (1, len(bad))
    finally:
        bus.shutdown()
        os.close(master)


def test_replies_to_nothing_written_are_counted() -> None:
    """A flood of bare terminators read as OK replies, none of it counted (hostile-device
    sweep); only as many replies as lines the bus wrote are passed over."""
    bus, master = _bus_on_a_pty()  # wrote one command: its reply is due
    try:
        assert _ids_after_writing(bus, master, b"\r" * 3000 + b"t1018FFEEDDCCBBAA9988\r"
                                  ) == [0x101]
        assert (bus.garbled, bus.garbled_bytes) == (2999, 2999)
        assert _ids_after_writing(bus, master, b"\a\r\a") == []
        assert (bus.garbled, bus.garbled_bytes) == (3002, 3002)
    finally:
        bus.shutdown()
        os.close(master)


def test_frame_lines_encode_and_parse_back() -> None:
    """One codec both ways: the emulator's adapter and the bench's re-reading write the lines
    the recorder parses, standard and extended identifiers alike."""
    for ident, extended, data in ((0x123, False, b"\x01\x02"), (0x1ABCDE0F, True, bytes(8)),
                                  (0x7FF, False, b"")):
        line = encode_frame_line(ident, extended, data)
        assert line.endswith(b"\r")
        msg = parse_frame_line(line[:-1])
        assert msg is not None
        assert (msg.arbitration_id, msg.is_extended_id, bytes(msg.data)) == (ident, extended, data)
