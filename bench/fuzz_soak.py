"""A long fuzzing soak: the fuzzers of tests/fuzz/ with many more examples.

    .venv/bin/python bench/fuzz_soak.py                      # 2000 examples per fuzzer
    .venv/bin/python bench/fuzz_soak.py --examples 20000 --only mcap nmea
    .venv/bin/python bench/fuzz_soak.py --minutes 30        # round after round until time is up

Prints, per fuzzer, the examples run, the decode errors the decoders counted (they must count
errors: the inputs are damaged on purpose) and any failure, shrunk by hypothesis, with the blob
to reproduce it. A failure's input belongs in tests/fuzz/corpus/ (see tests/fuzz/__init__.py).
Exit status 1 if anything failed.
"""

from __future__ import annotations

import argparse
import sys
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hypothesis import HealthCheck, settings  # noqa: E402

from tests.fuzz import Fuzzer, Tally, run_fuzzer  # noqa: E402
from tests.fuzz.test_fuzz_codecs import FUZZERS as CODEC_FUZZERS  # noqa: E402
from tests.fuzz.test_fuzz_files import FUZZERS as FILE_FUZZERS  # noqa: E402
from tests.fuzz.test_fuzz_inputs import FUZZERS as INPUT_FUZZERS  # noqa: E402


def soak_settings(examples: int) -> settings:
    return settings(max_examples=examples, deadline=None, database=None, print_blob=True,
                    derandomize=False, report_multiple_bugs=False,
                    suppress_health_check=list(HealthCheck))


def run_one(fuzzer: Fuzzer, examples: int) -> tuple[Tally, str | None, float]:
    tally = Tally()
    start = time.perf_counter()
    try:
        run_fuzzer(fuzzer, soak_settings(examples), tally)
    except Exception:  # a failing example: report it and go on with the other fuzzers
        return tally, traceback.format_exc(limit=-8), time.perf_counter() - start
    return tally, None, time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--examples", type=int, default=2000, help="per fuzzer and round")
    parser.add_argument("--minutes", type=float, default=None,
                        help="repeat rounds until this much time has passed")
    parser.add_argument("--only", nargs="*", default=None, metavar="PREFIX",
                        help="only fuzzers whose name starts with one of these")
    args = parser.parse_args(argv)
    fuzzers = [f for f in (*CODEC_FUZZERS, *FILE_FUZZERS, *INPUT_FUZZERS)
               if not args.only or any(f.name.startswith(p) for p in args.only)]
    if not fuzzers:
        parser.error("no fuzzer matches --only")
    deadline = None if args.minutes is None else time.monotonic() + 60 * args.minutes
    totals = {f.name: Tally() for f in fuzzers}
    failures: dict[str, str] = {}
    rounds = 0
    while True:
        rounds += 1
        for fuzzer in fuzzers:
            if fuzzer.name in failures:
                continue
            tally, failure, seconds = run_one(fuzzer, args.examples)
            total = totals[fuzzer.name]
            total.examples += tally.examples
            total.errors_counted += tally.errors_counted
            state = "FAILED" if failure else "ok"
            print(f"round {rounds} {fuzzer.name:<32} {tally.examples:>7} examples "
                  f"{tally.errors_counted:>8} errors counted {seconds:>7.1f} s  {state}",
                  flush=True)
            if failure:
                failures[fuzzer.name] = failure
                print(failure, flush=True)
        if deadline is None or time.monotonic() >= deadline or len(failures) == len(fuzzers):
            break
    print(f"\n{'fuzzer':<32} {'examples':>9} {'errors counted':>15}  result")
    for name, total in totals.items():
        print(f"{name:<32} {total.examples:>9} {total.errors_counted:>15}  "
              f"{'FAILED' if name in failures else 'ok'}")
    print(f"{sum(t.examples for t in totals.values())} examples in {rounds} round(s), "
          f"{len(failures)} failure(s)")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
