"""A stop asked of a batch command (Ctrl-C, SIGTERM) is never lost.

Python turns SIGINT into KeyboardInterrupt in the main thread at its next bytecode, or inside a
C extension that calls back into Python. Not every extension checks for it there: numpy's
string formatting (`np.char.mod`, numpy 2.4) went on with the interrupt pending, and some later
call cleared it. `sisa process`, interrupted while it wrote an EO table, then finished with
exit 0 and its outputs in place, or died of SIGINT as it exited (exit -2). So the handlers here
also note the stop, and every checkpoint raises it again: each progress step and advance, and
the moment an output is renamed into place, which therefore never happens after a stop.

The real-time commands (record, emulate, replay, bench) install their own handlers, which stop
them at their next loop turn; these then do nothing."""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Final


class Terminated(KeyboardInterrupt):
    """SIGTERM (timeout, a batch scheduler, systemd): unwinds like Ctrl-C, so whatever a
    command was writing is removed, not left half-written."""


INTERRUPTED_EXIT: Final = 130  # 128 + SIGINT, as a shell says a Ctrl-C
TERMINATED_EXIT: Final = 143  # 128 + SIGTERM
STOPPED_EXITS: Final = (INTERRUPTED_EXIT, TERMINATED_EXIT)


def exit_code(stop: KeyboardInterrupt) -> int:
    """A stopped command's exit code: 143 for SIGTERM, 130 for Ctrl-C."""
    return TERMINATED_EXIT if isinstance(stop, Terminated) else INTERRUPTED_EXIT


_noted: list[type[KeyboardInterrupt]] = []  # the stop asked for, once one was


def stop_noted() -> type[KeyboardInterrupt] | None:
    """KeyboardInterrupt or Terminated once a stop was asked for (since `stops_noted` began)."""
    return _noted[0] if _noted else None


def raise_if_stopped() -> None:
    """A checkpoint: raise the stop asked for, if one was (again, if C code lost it)."""
    if _noted:
        raise _noted[0]


def stop_answered() -> None:
    """The command has answered the stop itself (`sisa bench` keeps a run stopped early): the
    checkpoints let its outputs through, until another stop."""
    _noted.clear()


def _noting(kind: type[KeyboardInterrupt]) -> Callable[[int, FrameType | None], None]:
    """A signal handler that notes `kind` (the first stop asked for stays) and raises it."""

    def handler(_sig: int, _frame: FrameType | None) -> None:
        _noted[:] = _noted or [kind]
        raise kind

    return handler


@contextmanager
def stops_noted() -> Iterator[None]:
    """Ctrl-C raises KeyboardInterrupt and SIGTERM Terminated inside the block, both noted for
    the checkpoints; after it, the handlers before are put back and the stop is
    forgotten (the block's caller has answered it). Outside the main thread (a test
    calling a command from a thread) signals cannot be handled: nothing is installed."""
    _noted.clear()
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = (signal.signal(signal.SIGINT, _noting(KeyboardInterrupt)),
              signal.signal(signal.SIGTERM, _noting(Terminated)))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, before[0])
        signal.signal(signal.SIGTERM, before[1])
        _noted.clear()  # the block's stop ends with it: no checkpoint after it raises it
