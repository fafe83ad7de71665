"""Progress of a command's long steps, the one way every command shows it: on a terminal, a rich
bar on stderr with the count, rate and time left; otherwise (CI, logs, `| tee`) plain
timestamped lines on stderr every few seconds, so that a piped run is never silent for long.
stdout keeps only the command's own lines either way.

    with progress("simulate") as bar:
        bar.step("terrain and scene")            # a step of unknown length: elapsed time only
        bar.step("flight", total=549.0, unit="s")
        bar.advance(0.1)                          # ... or bar.update(completed=...)

Plain lines look like

    21:40:05 sisa simulate: flight 120/549 s (22%), 7.1 s/s, 1:00 left

The first comes FIRST_LINE_S into the command, then one every SISA_PROGRESS_S seconds (default
PERIOD_S; 0 or "off": none). rich is imported only for a terminal.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any, TextIO

from sisa.core.interrupt import raise_if_stopped

if TYPE_CHECKING:
    from rich.progress import Progress as RichProgress
    from rich.progress import TaskID

PERIOD_ENV = "SISA_PROGRESS_S"
PERIOD_S = 5.0  # between plain lines
FIRST_LINE_S = 2.0  # a command shorter than this says nothing when piped
MIN_RATE_S = 1.0  # into a step: a rate (and time left) from less would be noise


def plain_period_s() -> float | None:
    """Seconds between plain lines (None: no plain lines), from SISA_PROGRESS_S."""
    text = os.environ.get(PERIOD_ENV, "").strip().lower()
    if not text:
        return PERIOD_S
    if text in ("0", "off", "no", "none"):
        return None
    try:
        value = float(text)
    except ValueError:
        return PERIOD_S
    return value if value > 0 and value == value and value != float("inf") else PERIOD_S


def clock(seconds: float) -> str:
    """1:05, 1:02:03."""
    s = max(0, round(seconds))
    h, rest = divmod(s, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


def _number(value: float) -> str:
    return f"{value:.0f}" if abs(value) >= 100 or value == int(value) else f"{value:.1f}"


class Progress:
    """One command's progress over its steps; see the module docstring. Thread-safe enough for
    a reader thread to print while the work advances it (numbers are replaced whole)."""

    def __init__(self, command: str, *, terminal: bool | None = None, quiet: bool = False,
                 stream: TextIO | None = None, refresh_hz: float = 10.0) -> None:
        """`refresh_hz`: of the bar on a terminal (a real-time loop wants few redraws)."""
        self.command = command
        self.stream = stream if stream is not None else sys.stderr
        if terminal is None:
            terminal = _isatty(self.stream)
        self.label = ""
        self.unit = ""
        self.total: float | None = None
        self.completed = 0.0
        self.note = ""
        self.rate = True
        self._started = self._created = time.monotonic()
        self._step_cpu_s = time.process_time()
        self._done: dict[str, tuple[float, float]] = {}  # label: (wall s, CPU s), summed
        self._bar: RichProgress | None = None
        self._task: TaskID | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._follower: threading.Thread | None = None
        self._period = PERIOD_S
        period = plain_period_s()
        if quiet:
            return
        if terminal:
            self._bar = _rich_bar(self.stream, refresh_hz)
            self._bar.start()
            self._task = self._bar.add_task("", total=None, unit="")
        elif period is not None:
            self._period = period
            self._thread = threading.Thread(target=self._print_lines, name="progress",
                                            daemon=True)
            self._thread.start()

    # --- what the work tells it ------------------------------------------------------------

    def step(self, label: str, total: float | None = None, unit: str = "", *,
             rate: bool = True) -> None:
        """A new step: its count, rate and time left start again (`rate` False: a step that
        does not advance at a rate, e.g. paused, shows neither)."""
        _checkpoint()
        self._close_step()
        self.label, self.total, self.unit, self.completed, self.note = label, total, unit, 0.0, ""
        self.rate = rate
        self._started, self._step_cpu_s = time.monotonic(), time.process_time()
        if self._bar is not None and self._task is not None:  # a new task: rich cannot
            self._bar.remove_task(self._task)  # take a task's total back to None (unknown)
            self._task = self._bar.add_task(label, total=total, unit=unit)

    def _close_step(self) -> None:
        if not self.label:
            return
        wall, cpu = self._done.get(self.label, (0.0, 0.0))
        self._done[self.label] = (wall + time.monotonic() - self._started,
                                  cpu + time.process_time() - self._step_cpu_s)

    def splits(self) -> list[tuple[str, float, float]]:
        """(label, wall s, CPU s of this process) of every step so far, the current one to
        now; a label met again is summed. Where a command's time goes: `sisa process` printed
        one total."""
        self._close_step()
        self._started, self._step_cpu_s = time.monotonic(), time.process_time()
        return [(label, wall, cpu) for label, (wall, cpu) in self._done.items()]

    def set_total(self, total: float) -> None:
        self.total = total
        if self._bar is not None and self._task is not None:
            self._bar.update(self._task, total=total)

    def advance(self, n: float = 1) -> None:
        _checkpoint()
        self.completed += n
        if self._bar is not None and self._task is not None:
            self._bar.advance(self._task, n)

    def update(self, *, completed: float | None = None, note: str | None = None) -> None:
        """Set the count (not add to it), and/or a note shown after the figures."""
        _checkpoint()
        if completed is not None:
            self.completed = completed
        if note is not None:
            self.note = note
        if self._bar is not None and self._task is not None:
            desc = f"{self.label} {self.note}".strip()
            self._bar.update(self._task, completed=self.completed, description=desc)

    def follow(self, poll: Callable[[], None], every_s: float = 0.5) -> None:
        """Call `poll` (which updates this progress from the work's own state) every
        `every_s` from a thread of its own until closed: for work that cannot tell as it goes
        (a real-time loop that must not be slowed)."""
        if self._bar is None and self._thread is None:
            return  # quiet

        def run() -> None:
            while not self._stop.wait(every_s):
                poll()

        self._follower = threading.Thread(target=run, name="progress-poll", daemon=True)
        self._follower.start()

    def close(self) -> None:
        self._stop.set()
        if self._follower is not None:
            self._follower.join(timeout=1.0)
            self._follower = None
        if self._thread is not None:
            self._thread.join(timeout=1.0)
            self._thread = None
        if self._bar is not None:
            self._bar.stop()
            self._bar = None

    # --- the plain lines -------------------------------------------------------------------

    def line(self) -> str:
        """The plain line for now (without the timestamp)."""
        elapsed = time.monotonic() - self._started
        unit = f" {self.unit}" if self.unit else ""
        head = f"sisa {self.command}: {self.label or 'working'}"
        if self.total is None and not self.completed:
            figures = f" ({clock(elapsed)})"
        else:
            done = _number(self.completed)
            if self.total:
                share = min(self.completed / self.total, 1.0)
                figures = f" {done}/{_number(self.total)}{unit} ({share:.0%})"
            else:
                figures = f" {done}{unit}"
            rate = self.completed / elapsed if elapsed >= MIN_RATE_S and self.rate else 0.0
            if rate > 0:
                figures += f", {_number(rate)}{unit}/s"
                if self.total:
                    left = max(self.total - self.completed, 0.0) / rate
                    figures += f", {clock(left)} left"
            else:
                figures += f" ({clock(elapsed)})"
        return head + figures + (f"; {self.note}" if self.note else "")

    def _print_lines(self) -> None:
        """A line FIRST_LINE_S into the command, then every period, whatever its steps."""
        due = self._created + min(FIRST_LINE_S, self._period)
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= due:
                self._say(self.line())
                due = now + self._period
            else:
                self._stop.wait(due - now)

    def _say(self, text: str) -> None:
        try:
            print(f"{time.strftime('%H:%M:%S')} {text}", file=self.stream, flush=True)
        except (OSError, ValueError):  # stderr gone (a closed pipe): stop saying
            self._stop.set()


def split_lines(bar: Progress, wall_s: float, cpu_s: float) -> list[str]:
    """The command's time and CPU, then each step's (for the summary a command prints)."""
    rows = bar.splits()
    before = (wall_s - sum(w for _, w, _ in rows), cpu_s - sum(c for _, _, c in rows))
    if before[0] > 0.05:  # imports and checks of the inputs, before the first step
        rows.insert(0, ("starting (imports, inputs)", *before))
    width = max((len(label) for label, _, _ in rows), default=0)
    out = [f"  time {wall_s:.1f} s, CPU {100 * cpu_s / max(wall_s, 1e-9):.0f} % of a core:"]
    out += [f"    {label:<{width}}  {wall:6.1f} s  CPU {100 * cpu / max(wall, 1e-9):4.0f} %"
            for label, wall, cpu in rows]
    return out


def _isatty(stream: TextIO) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False


def _rich_bar(stream: TextIO, refresh_hz: float) -> RichProgress:
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        ProgressColumn,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )
    from rich.progress import Progress as RichProgress
    from rich.text import Text

    class Count(MofNCompleteColumn):
        def render(self, task: Any) -> Text:
            unit = task.fields.get("unit", "")
            unit = f" {unit}" if unit else ""
            if task.total is None:
                return Text(f"{_number(task.completed)}{unit}" if task.completed else "",
                            style="progress.download")
            done, total = _number(task.completed), _number(task.total)
            return Text(f"{done}/{total}{unit}", style="progress.download")

    class Rate(ProgressColumn):
        def render(self, task: Any) -> Text:
            speed = task.finished_speed or task.speed
            if speed is None:
                return Text("")
            unit = task.fields.get("unit", "")
            return Text(f"{_number(speed)} {unit}/s".replace(" /s", "/s"),
                        style="progress.data.speed")

    return RichProgress(TextColumn("[progress.description]{task.description}"), BarColumn(),
                        Count(), Rate(), TimeRemainingColumn(), TimeElapsedColumn(),
                        console=Console(file=stream), transient=True,
                        refresh_per_second=refresh_hz)


@contextmanager
def progress(command: str, label: str = "", total: float | None = None, unit: str = "", *,
             quiet: bool = False, terminal: bool | None = None, refresh_hz: float = 10.0
             ) -> Iterator[Progress]:
    """A Progress for the block (a first step `label`, if given), closed at its end."""
    bar = Progress(command, quiet=quiet, terminal=terminal, refresh_hz=refresh_hz)
    try:
        if label:
            bar.step(label, total, unit)
        yield bar
    finally:
        bar.close()


def _checkpoint() -> None:
    """The work's progress is where a stop (Ctrl-C) that C code lost is raised again
    (`sisa.core.interrupt`); in the main thread only, not in a thread following a real-time
    loop."""
    if threading.current_thread() is threading.main_thread():
        raise_if_stopped()
