"""The line clock's coarse pieces on header host times."""

from __future__ import annotations

import warnings

import numpy as np

from postproc.sync import HeaderColumns
from postproc.sync import lines as ln


def test_headers_faster_than_the_read_clock_unwrap_without_a_zero_period() -> None:
    """Lines of 0.11 ms read on a 5 ms clock: most headers share a host time, their median
    interval was 0 and the wrap count divided by it (numpy warnings; found by a bad-input
    sweep). The mean interval is the line period, and the counter unwraps."""
    n, period_ns, modulus = 20_000, 110_000, 4096
    t_host_ns = (np.arange(n) * period_ns // 5_000_000 + 1) * 5_000_000
    counter = np.arange(n, dtype=np.int64) % modulus
    hdr = HeaderColumns(t_host_ns.astype(np.int64), counter, np.zeros(n, np.int64))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        period_s = ln.header_period_s(hdr, modulus)
        assert abs(period_s - period_ns * 1e-9) < 0.01 * period_ns * 1e-9
        np.testing.assert_array_equal(ln.unwrap_headers(hdr, modulus, period_s), np.arange(n))
    # a read per header: the median, as before
    hdr = HeaderColumns(np.arange(n, dtype=np.int64) * 16_000_000, counter,
                        np.zeros(n, np.int64))
    assert ln.header_period_s(hdr, modulus) == 0.016
