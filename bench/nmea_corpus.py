"""How much of a corpus of NMEA 0183 sentences acquisition.nmea decodes, and whether it decodes
them as pynmeagps (the independent reference) does.

    .venv/bin/python bench/nmea_corpus.py                       # the corpus written from the rules
    .venv/bin/python bench/nmea_corpus.py path/to/gpsd/test/daemon --show 20

A path is a file or a folder of `*.log` files (gpsd's regression logs are receivers' captures,
some with binary protocols between the sentences). Two measures:

1. Sentences. Every `$ttGGA/RMC/ZDA/GNS/GST,...*hh` in the files whose checksum is right is a
   candidate; it is standard-valid when it has a field count some NMEA version gives that
   sentence (GGA 14, RMC 11–13, ZDA 6, GNS 12–13, GST 8), pynmeagps parses it, and the
   rules pynmeagps does not check hold (the forms of time, position and date, minutes below
   60, latitude to 90° and longitude to 180°, RMC's magnetic variation direction E or W or
   null). Of those, the share we decode with every value equal to pynmeagps's (times to the
   µs, positions and heights within 1 mm), by formatter: tests/acquisition/nmea_oracle.py.
2. Streams. Each file fed whole to NmeaStreamDecoder, in random chunks, and line by line:
   crashes (any exception), whether the three agree, messages, and refusals by reason.

Exit status 1 if under 99 % of the standard-valid sentences agree, on a crash, or if the three
feedings disagree.
"""

from __future__ import annotations

import argparse
import random
import sys
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from acquisition.codec import Decoded  # noqa: E402
from acquisition.nmea import NmeaMessage, NmeaStreamDecoder  # noqa: E402
from tests.acquisition.corpus.nmea_0183 import CORPUS  # noqa: E402
from tests.acquisition.nmea_oracle import (  # noqa: E402
    STANDARD_FIELDS,
    SentenceTally,
    files_of,
    judge_sentences,
)

TARGET = 0.99
CANDIDATE_OUTCOMES = ("standard-valid", "damaged in the log", "not standard: field count",
                      "pynmeagps refuses", "not standard: a value")


def _feed(pieces: list[bytes]) -> tuple[list[Decoded[NmeaMessage]], NmeaStreamDecoder]:
    decoder = NmeaStreamDecoder()
    out = [item for piece in pieces for item in decoder.feed(piece)]
    out += decoder.finish()
    return out, decoder


def streams(data: bytes, rng: random.Random) -> tuple[bool, NmeaStreamDecoder]:
    """(chunked and line-by-line feeding agree with one feed, the one-feed decoder)."""
    whole, one = _feed([data])
    cuts = sorted(rng.sample(range(1, len(data)), min(len(data) - 1, len(data) // 7)))
    chunks = [data[a:b] for a, b in zip([0, *cuts], [*cuts, len(data)], strict=True)]
    chunked, many = _feed(chunks)
    by_line, lines = _feed(data.splitlines(keepends=True))
    agree = whole == chunked == by_line and one.stats == many.stats == lines.stats
    return agree, one


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("paths", nargs="*", type=Path, default=[CORPUS])
    parser.add_argument("--show", type=int, default=5, help="examples shown per outcome")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    tally, rng = SentenceTally(), random.Random(args.seed)
    crashes, disagreeing, messages = 0, [], 0
    refused: Counter[str] = Counter()
    files = files_of(args.paths)
    for path in files:
        data = path.read_bytes()
        judge_sentences(data, tally)
        try:
            agree, decoder = streams(data, rng)
        except Exception as err:  # the measure: any exception is a crash
            crashes += 1
            print(f"CRASH {path}: {err!r}")
            continue
        if not agree:
            disagreeing.append(path.name)
        messages += decoder.stats.messages
        refused.update(decoder.stats.refused)
    print(f"{len(files)} file(s)")
    print(f"{'formatter':9} {'candidates':>10} {'standard':>9} {'agree':>7} {'share':>8}")
    for formatter in [*STANDARD_FIELDS, None]:
        candidates = sum(tally.of(o, formatter) for o in CANDIDATE_OUTCOMES)
        valid, agreeing = tally.of("standard-valid", formatter), tally.of("agree", formatter)
        share = agreeing / valid if valid else float("nan")
        print(f"{formatter or 'all':9} {candidates:10d} {valid:9d} {agreeing:7d} {share:8.2%}")
    valid, agreeing = tally.of("standard-valid"), tally.of("agree")
    failed = not valid or agreeing < TARGET * valid
    print(f"target: ≥ {TARGET:.0%} of the standard-valid sentences agree: "
          f"{'met' if not failed else 'NOT MET'}")
    for outcome in (*CANDIDATE_OUTCOMES[1:], "refused by us", "values differ"):
        print(f"  {outcome}: {tally.of(outcome)}")
        for example in tally.examples.get(outcome, [])[:args.show]:
            print(f"      {example[:220]}")
    fed = "agree with one feed in every file" if not disagreeing else (
        "DIFFER in " + ", ".join(disagreeing))
    print(f"streams: {crashes} crash(es); chunked and line-by-line feeding {fed}; "
          f"{messages} sentences decoded")
    print("  refused by reason: " + (", ".join(f"{r} {n}" for r, n in refused.most_common())
                                     or "none"))
    failed |= bool(crashes or disagreeing)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
