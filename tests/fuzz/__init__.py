"""Fuzzing every decoder and every input file SISA reads.

Each fuzzer is a `Fuzzer`: a hypothesis strategy and a property (a plain function of one drawn
value that asserts and returns how many decode errors the decoder counted). The tests run every
fuzzer with a small, bounded number of examples; `bench/fuzz_soak.py` runs the same fuzzers with
many more. Every input that ever failed is kept in `tests/fuzz/corpus/` and replayed by
`test_fuzz_files.py::test_the_regression_corpus_replays_clean`.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

CORPUS = Path(__file__).resolve().parent / "corpus"
EXAMPLE_TIME_LIMIT_S = 10.0  # a decoder that takes longer on one small input hangs


class Hang(Exception):  # noqa: N818 - it is what it is
    """An example ran past its time limit."""


@contextlib.contextmanager
def time_limit(seconds: float) -> Iterator[None]:
    """Raise Hang in the block after `seconds` (SIGALRM, main thread); elsewhere, check after."""
    if threading.current_thread() is not threading.main_thread():
        start = time.monotonic()
        yield
        if time.monotonic() - start > seconds:
            raise Hang(f"took more than {seconds} s")
        return

    def on_alarm(_sig: int, _frame: object) -> None:
        raise Hang(f"took more than {seconds} s")

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


@dataclass
class Tally:
    """What a fuzzer did: examples run and decode errors the decoders counted."""

    examples: int = 0
    errors_counted: int = 0


@dataclass(frozen=True)
class Fuzzer:
    name: str
    strategy: st.SearchStrategy[Any]
    prop: Callable[[Any], int]  # asserts; returns the decode errors counted
    examples: int = 60  # in the CI run


def ci_settings(examples: int) -> settings:
    return settings(max_examples=examples, deadline=None, database=None, print_blob=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.filter_too_much,
                                           HealthCheck.large_base_example])


def run_fuzzer(fuzzer: Fuzzer, config: settings, tally: Tally | None = None) -> Tally:
    """Run one fuzzer under `config`; raises the first (shrunk) failure."""
    tally = tally if tally is not None else Tally()

    def check(value: Any) -> None:
        with time_limit(EXAMPLE_TIME_LIMIT_S):
            errors = fuzzer.prop(value)
        tally.examples += 1
        tally.errors_counted += errors

    given(fuzzer.strategy)(config(check))()
    return tally
