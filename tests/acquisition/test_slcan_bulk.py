"""The bulk-reading SLCAN bus on a real pty: every frame that has arrived in one read, and a line
corrupted on the adapter's serial link counted and skipped instead of ending the link."""

import os
import select
import time

from acquisition.slcan_bulk import BulkSlcanBus


def _bus_on_a_pty() -> tuple[BulkSlcanBus, int]:
    master, slave = os.openpty()
    bus = BulkSlcanBus(channel=os.ttyname(slave), timeout=0.0, sleep_after_open=0.0)
    os.close(slave)
    time.sleep(0.05)
    os.read(master, 4096)  # the open commands the bus sent to the adapter
    return bus, master


def _ready(bus: BulkSlcanBus) -> None:
    assert select.select([bus.fileno()], [], [], 2.0)[0], "nothing arrived"


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
        os.write(master, b"t1018001122t1028AABBCCDDEEFF0011\rt1038zz11223344556677\r"
                         b"t1048FFEEDDCCBBAA9988\r")
        time.sleep(0.05)
        _ready(bus)
        frames = bus.recv_ready()
        assert [f.arbitration_id for f in frames] == [0x104]
        assert bus.garbled == 2
        # and the bus goes on reading
        os.write(master, b"t1058FFEEDDCCBBAA9988\r")
        _ready(bus)
        assert [f.arbitration_id for f in bus.recv_ready()] == [0x105]
    finally:
        bus.shutdown()
        os.close(master)
