"""In real time the scanner renders its lines on one thread: a parallel kernel waited for a
worker on the core the recorder under test was using, and the emulator sent frame pulses up
to 33 ms late (the recorder counted them as late edges). In virtual time it keeps every core."""

from __future__ import annotations

import subprocess
import sys

import pytest

SCRIPT = """
import sys, tempfile, numba
from pathlib import Path
from emulators.scenario import load_scenario
from emulators.system import EmulatedSystem
EmulatedSystem(load_scenario("bench"), Path(tempfile.mkdtemp()) / "scanner",
               real_time=sys.argv[1] == "real")
print(numba.get_num_threads(), numba.config.NUMBA_NUM_THREADS)
"""


@pytest.mark.parametrize("mode", ["real", "virtual"])
def test_render_threads(mode: str) -> None:
    """A child process each: the thread count is the process's (the tests' own ray casts keep
    theirs)."""
    done = subprocess.run([sys.executable, "-c", SCRIPT, mode], capture_output=True, text=True,
                          timeout=120, check=True)
    used, available = (int(v) for v in done.stdout.split())
    assert used == (1 if mode == "real" else available)
