"""Reading on a clock (`read_interval_s`): a device writing every millisecond is read a burst at a
time, no byte lost or reordered, reads never ahead of the clock; without it, every write wakes
the loop. Real ptys."""

from __future__ import annotations

import time
from pathlib import Path

from acquisition.live import LiveSources
from tests.acquisition.test_reconnect import Feeder, PlugPty

INTERVAL_S = 0.02
FEED_S = 0.6


def _read_times_and_bytes(tmp_path: Path, read_interval_s: float) -> tuple[list[int], bytes]:
    gps = PlugPty(tmp_path / f"tty{read_interval_s}")
    sources = LiveSources(str(gps.link), None, None, None, read_interval_s=read_interval_s)
    feeder = Feeder(0.001, lambda i: gps.write(b"%06d\n" % i))
    stamps: list[int] = []
    data = b""
    try:
        end = time.monotonic() + FEED_S
        while time.monotonic() < end:
            for arrival in sources.poll(0.05):
                assert isinstance(arrival.payload, bytes)
                stamps.append(arrival.t_host_ns)
                data += arrival.payload
        feeder.stop()
        end = time.monotonic() + 3 * INTERVAL_S
        while time.monotonic() < end:
            for arrival in sources.poll(0.05):
                assert isinstance(arrival.payload, bytes)
                stamps.append(arrival.t_host_ns)
                data += arrival.payload
    finally:
        feeder.stop()
        sources.close()
        gps.unplug()
    return stamps, data


def _intact(data: bytes) -> int:
    """Lines written 0, 1, 2, ...: all there, in order; how many."""
    lines = data.split(b"\n")
    assert lines[-1] == b""
    numbers = [int(x) for x in lines[:-1]]
    assert numbers == list(range(len(numbers)))
    return len(numbers)


def test_reads_on_a_clock_take_bursts_and_lose_nothing(tmp_path: Path) -> None:
    stamps, data = _read_times_and_bytes(tmp_path, INTERVAL_S)
    written = _intact(data)
    assert written > 200  # the feeder ran (about one line a millisecond)
    # The reads keep a fixed cadence: a late wake is followed by a shorter gap, never by reads
    # running ahead of the clock (the k-th read comes at least k - 1 intervals after the first).
    ahead_s = [(k - 1) * INTERVAL_S - (t - stamps[0]) / 1e9 for k, t in enumerate(stamps)]
    assert max(ahead_s) <= 0.001, max(ahead_s)
    pairs_s = [(c - a) / 1e9 for a, c in zip(stamps, stamps[2:], strict=False)]
    assert min(pairs_s) >= INTERVAL_S, min(pairs_s)  # never three reads within one interval
    assert len(stamps) <= (FEED_S + 3 * INTERVAL_S) / INTERVAL_S + 2
    assert written / len(stamps) >= 10  # a burst of ~20 lines per read


def test_without_an_interval_every_write_wakes_the_loop(tmp_path: Path) -> None:
    stamps, data = _read_times_and_bytes(tmp_path, 0.0)
    written = _intact(data)
    assert len(stamps) >= written / 3  # most writes read on their own
    assert len(stamps) > 2 * (FEED_S / INTERVAL_S)
