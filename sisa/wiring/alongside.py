"""A simulated run's accuracy against truth worked out alongside the rest of `sisa process`
(issue 38): in a thread of its own, segment by segment as the georeferencing casts them, while
the main thread casts the next segments and makes the orthos, the mosaic and the strip
registration. The truth's ray casting (numba, nogil, on its own thread pool) and the IGM
reads release the GIL, so the two share the cores; the figures are `run_accuracy`'s, summed
in the same order.

    with AccuracyAlongside(scn, run) as judge:
        ...  judge.start(handoff, epsg) once the log is synchronised, judge.add(seg) per
        ...  segment cast
        acc = judge.result()    # waits; the thread's error raised here, where it was met before

Leaving the block early (an error, Ctrl-C) stops the thread at its next block of lines and
waits for it, so nothing reads the staged output folder once it is removed.
"""

from __future__ import annotations

import queue
import threading
import time
from types import TracebackType
from typing import TYPE_CHECKING, Any, cast

if TYPE_CHECKING:
    from pathlib import Path

    from emulators.scenario import Scenario
    from postproc.georef import AntennaFixes, Handoff, SegmentResult


class AccuracyAlongside:
    """The accuracy of a run's segments, judged in a worker thread as they are given."""

    def __init__(self, scn: Scenario, run: Path) -> None:
        self._scn, self._run = scn, run
        self._todo: queue.SimpleQueue[SegmentResult | None] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._outcome: dict[str, Any] | BaseException | None = None
        self.span_s: tuple[float, float] = (0.0, 0.0)  # perf_counter at its start and end

    def start(self, handoff: Handoff, epsg: int) -> None:
        """The log is synchronised (its GPS fixes check the scenario against the run): build
        the truth and judge segments as they come."""
        self._thread = threading.Thread(target=self._work, args=(handoff.log_fixes, epsg),
                                        name="sisa-accuracy")
        self._thread.start()

    def add(self, seg: SegmentResult) -> None:
        """A segment whose IGM is written whole."""
        self._todo.put(seg)

    def result(self) -> dict[str, Any]:
        """Every segment given, judged: `run_accuracy`'s dict; the thread's error raised."""
        if self._thread is None:
            raise RuntimeError("AccuracyAlongside.result before start")
        self._todo.put(None)
        self._thread.join()
        if isinstance(self._outcome, BaseException):
            raise self._outcome
        return cast(dict[str, Any], self._outcome)

    def _work(self, log_fixes: AntennaFixes, epsg: int) -> None:
        from sisa.wiring.accuracy import RunAccuracy

        started = time.perf_counter()
        try:
            acc = RunAccuracy(self._scn, self._run, epsg, log_fixes)
            while (seg := self._todo.get()) is not None and not self._stop.is_set():
                acc.add(seg, self._stop)
            self._outcome = acc.summary()
        except BaseException as exc:  # raised in the caller's thread by `result`
            self._outcome = exc
        finally:
            self.span_s = (started, time.perf_counter())

    def __enter__(self) -> AccuracyAlongside:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        """An early exit stops the thread and waits for it (a block of lines at most)."""
        if self._thread is None:
            return
        self._stop.set()
        self._todo.put(None)
        self._thread.join()
