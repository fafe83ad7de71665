"""A command's child processes (`sisa bench`'s emulator and recorder, `sisa replay --live`'s
recorder): how one that has ended is described, and how one is asked to stop."""

from __future__ import annotations

import contextlib
import signal
import subprocess
from typing import NamedTuple


class Ended(NamedTuple):
    """A child process that has ended: its exit code, what it last wrote to its pipes, and
    its error line (without its `sisa CMD: error: `), if it said one."""

    code: int
    stdout: str
    stderr: str
    error: str = ""


def stop_child(proc: subprocess.Popen[str], grace_s: float = 15.0, *, ask: bool = False
               ) -> Ended:
    """Wait for a process that should end by itself (with `ask`, at once: ask it with SIGTERM,
    which a child still starting dies of silently and a running one takes as a stop), then
    ask it, then insist; with what it wrote to its pipes from then on."""
    if not ask:
        with contextlib.suppress(subprocess.TimeoutExpired):
            out, err = proc.communicate(timeout=grace_s)
            return Ended(proc.returncode, out or "", err or "")
    proc.send_signal(signal.SIGTERM)
    try:
        out, err = proc.communicate(timeout=grace_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
    return Ended(proc.returncode, out or "", err or "")
