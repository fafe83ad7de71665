"""Helpers for tests of a command whose output is piped (CI, logs, `| tee`)."""

from __future__ import annotations

import os
import select
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PROGRESS_LINE = r"\d\d:\d\d:\d\d sisa {command}: "


def start(*args: object, period_s: float = 0.3) -> subprocess.Popen[str]:
    """`sisa ARGS` with stdout and stderr pipes, progress lines every `period_s`, in a process
    group of its own (a Ctrl-C from a terminal reaches the whole group)."""
    return subprocess.Popen([sys.executable, "-m", "sisa.cli", *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True,
                            env={**os.environ, "SISA_PROGRESS_S": str(period_s),
                                 "PYTHONPATH": str(ROOT)})


def stderr_lines_until(proc: subprocess.Popen[str], wanted: str, timeout_s: float) -> list[str]:
    """The child's stderr lines, read as it writes them, up to the first holding `wanted`
    (AssertionError if it does not come in time or the child ends first)."""
    assert proc.stderr is not None
    deadline = time.monotonic() + timeout_s
    lines: list[str] = []
    while time.monotonic() < deadline:
        if select.select([proc.stderr], [], [], 0.1)[0]:
            line = proc.stderr.readline()
            assert line, f"stderr closed before {wanted!r}: {lines}"
            lines.append(line)
            if wanted in line:
                return lines
    raise AssertionError(f"no {wanted!r} on stderr in {timeout_s} s: {lines}")
