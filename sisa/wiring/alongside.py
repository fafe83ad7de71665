"""A simulated run's accuracy against truth worked out alongside the rest of `sisa process`
(issue 38): in a thread of its own, from the command's start (the truth built and its first
blocks cast while the main thread reads the log on one core), then segment by segment as the
georeferencing casts them, while the main thread casts the next segments and makes the
orthos, the mosaic and the strip registration. The truth's ray casting (numba, nogil, run on
this thread alone: a kernel split over both cores waited for the half the main thread held
up) and the IGM reads release the GIL, so the two share the cores; the figures are
`RunAccuracy`'s, summed in the same order.

    with AccuracyAlongside(scn, run) as judge:   # its thread starts: the truth, cast ahead
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
from typing import TYPE_CHECKING, Any, Final, cast

from emulators.render import render_on_one_thread
from sisa.wiring.accuracy import BLOCK_LINES, RunAccuracy, TruthGround

if TYPE_CHECKING:
    from pathlib import Path

    from emulators.scenario import Scenario
    from postproc.georef import AntennaFixes, Handoff, SegmentResult


AHEAD_BYTES: Final = 256 << 20  # truth cast ahead while the log is read (~10 blocks)


class AccuracyAlongside:
    """The accuracy of a run's segments, judged in a worker thread as they are given. The
    thread starts with the `with` block: while the main thread reads the log (one core), it
    builds the truth and casts the first blocks of lines ahead (AHEAD_BYTES at most, until
    the first segment is cast: the products' peak memory comes later)."""

    def __init__(self, scn: Scenario, run: Path) -> None:
        self._scn, self._run = scn, run
        self._todo: queue.SimpleQueue[SegmentResult | None] = queue.SimpleQueue()
        self._synced: queue.SimpleQueue[tuple[AntennaFixes, int] | None] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._outcome: dict[str, Any] | BaseException | None = None
        self.span_s: tuple[float, float] = (0.0, 0.0)  # perf_counter at its start and end
        self.cpu_s = 0.0  # of its thread (its kernels run on it alone)
        self.ahead_lines = 0  # cast before the first segment was
        self._thread = threading.Thread(target=self._work, name="sisa-accuracy")

    def start(self, handoff: Handoff, epsg: int) -> None:
        """The log is synchronised: its GPS fixes check the scenario against the run, and the
        output CRS is known."""
        self._synced.put((handoff.log_fixes, epsg))

    def add(self, seg: SegmentResult) -> None:
        """A segment whose IGM is written whole."""
        self._todo.put(seg)

    def result(self) -> dict[str, Any]:
        """Every segment given, judged: `RunAccuracy.summary`'s dict; the thread's error raised."""
        self._todo.put(None)
        self._synced.put(None)  # never synchronised: the thread ends (with an error)
        self._thread.join()
        if isinstance(self._outcome, BaseException):
            raise self._outcome
        return cast(dict[str, Any], self._outcome)

    def _work(self) -> None:
        started, cpu_started = time.perf_counter(), time.thread_time()
        try:
            render_on_one_thread()  # the other core is the main thread's
            self._outcome = self._judge()
        except BaseException as exc:  # raised in the caller's thread by `result`
            self._outcome = exc
        finally:
            self.span_s = (started, time.perf_counter())
            self.cpu_s = time.thread_time() - cpu_started

    def _judge(self) -> dict[str, Any]:
        truth = TruthGround(self._scn, self._run, None, check_log=False)
        self._cast_ahead(truth)
        synced = self._synced.get()
        if synced is None:
            raise RuntimeError("AccuracyAlongside.result before start")
        log_fixes, epsg = synced
        acc = RunAccuracy(self._scn, self._run, epsg, log_fixes, truth=truth)
        while (seg := self._todo.get()) is not None and not self._stop.is_set():
            acc.add(seg, self._stop)
        return acc.summary()

    def _cast_ahead(self, truth: TruthGround) -> None:
        """The truth's first blocks, in the order `segment_accuracy` asks for them, until the
        first segment is cast, AHEAD_BYTES are held or a stop."""
        held = 0
        for segment, lines in truth.segment_lines().items():
            t = truth.line_times(segment, lines)
            for lo in range(0, lines, BLOCK_LINES):
                if held >= AHEAD_BYTES or not self._todo.empty() or self._stop.is_set():
                    return
                hi = min(lo + BLOCK_LINES + 1, lines)
                held += truth.cast_ahead(segment, lo, t[lo:hi])
                self.ahead_lines += hi - lo

    def __enter__(self) -> AccuracyAlongside:
        self._thread.start()
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        """An early exit stops the thread and waits for it (a block of lines at most)."""
        self._stop.set()
        self._todo.put(None)
        self._synced.put(None)
        self._thread.join()
