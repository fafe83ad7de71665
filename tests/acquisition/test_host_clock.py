"""The recorder's host clock never steps: the system clock does (chrony's makestep, a leap
second, an operator setting it), and every receive time after a step would move with it."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

from acquisition import clocks
from acquisition.clocks import HOST_CLOCK_ENV, wall_clock_ns


def test_a_step_of_the_system_clock_does_not_reach_the_host_clock(
        monkeypatch: pytest.MonkeyPatch) -> None:
    before_ns = wall_clock_ns()
    system_ns = time.time_ns
    monkeypatch.setattr(time, "time_ns", lambda: system_ns() - 3_600_000_000_000)
    after_ns = wall_clock_ns()
    assert 0 <= after_ns - before_ns < 50_000_000
    # and it still reads Unix time: the system clock's reading when the process started
    assert abs(wall_clock_ns() - system_ns()) < 1_000_000_000


def test_the_host_clock_runs_at_the_raw_clock_rate() -> None:
    raw0, host0 = time.clock_gettime_ns(time.CLOCK_MONOTONIC_RAW), wall_clock_ns()
    time.sleep(0.05)
    raw1, host1 = time.clock_gettime_ns(time.CLOCK_MONOTONIC_RAW), wall_clock_ns()
    assert abs((host1 - host0) - (raw1 - raw0)) < 1_000_000


def test_a_child_process_reads_its_parents_host_clock() -> None:
    """The live view's sync runs in a child process and compares its time with the log's."""
    assert os.environ[HOST_CLOCK_ENV] == str(clocks._RAW_TO_UNIX_NS)
    code = ("from acquisition.clocks import _RAW_TO_UNIX_NS, wall_clock_ns; "
            "print(_RAW_TO_UNIX_NS, wall_clock_ns())")
    env = {**os.environ, HOST_CLOCK_ENV: str(clocks._RAW_TO_UNIX_NS + 7_000_000_000)}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True).stdout.split()
    assert int(out[0]) == clocks._RAW_TO_UNIX_NS + 7_000_000_000
    assert 6.5e9 < int(out[1]) - wall_clock_ns() < 7.5e9
    # an unreadable value is not taken: the child anchors on its own system clock
    bad = {**os.environ, HOST_CLOCK_ENV: "soon"}
    out = subprocess.run([sys.executable, "-c", code], env=bad, capture_output=True, text=True,
                         check=True).stdout.split()
    assert abs(int(out[1]) - time.time_ns()) < 5_000_000_000
