"""A corpus of standard-valid NMEA 0183 sentences, written from the standard's rules with string
templates (not with acquisition.nmea's encoder, so that the two can disagree):

- talkers GP, GL, GA, GB, BD, GQ, GI, GN;
- GGA: fixes of every quality (0–8), times with 0, 2 or 3 decimals, positions with 2 to 7
  decimals of minutes, both hemispheres, negative altitudes and separations, DGPS age and
  station, a blank geoid separation with its unit, and the no-fix form with an empty time;
- RMC: NMEA 2.0 (11 fields, no mode), 2.3+ (mode indicator), 4.1 (navigational status), with
  and without magnetic variation, void with empty position, and the cold-start form with
  nothing but status and mode;
- ZDA: local zone 00/00, east and west zones, a blank zone, and the empty form;
- GNS: NMEA 4.0 (12 fields) and 4.1 (13), one to six mode indicators, no fix;
- GST: filled and null fields;
- checksums in upper and in lower case; lines ended with CRLF.

Dates lie in 1980–2068, where a two-digit year means the same to every reader (Python's %y,
which pynmeagps uses, reads 69–99 as 19yy).

    python -m tests.acquisition.corpus.nmea_0183      # rewrites nmea_0183.txt next to it

A test keeps the file equal to what this writes.
"""

from __future__ import annotations

import random
import sys
from collections.abc import Callable, Iterator
from functools import reduce
from operator import xor
from pathlib import Path

CORPUS = Path(__file__).with_name("nmea_0183.txt")
SEED = 20261128
PER_TEMPLATE = 3  # sentences per template and talker
TALKERS = ("GP", "GL", "GA", "GB", "BD", "GQ", "GI", "GN")


def _checksummed(body: str, lower: bool) -> str:
    digits = f"{reduce(xor, body.encode('ascii'), 0):02X}"
    return f"${body}*{digits.lower() if lower else digits}\r\n"


class _Draw:
    """Random field texts in the forms the standard allows."""

    def __init__(self, rng: random.Random) -> None:
        self.rng = rng

    def time(self, decimals: int | None = None) -> str:
        r = self.rng
        decimals = r.choice((0, 2, 2, 3)) if decimals is None else decimals
        text = f"{r.randrange(24):02d}{r.randrange(60):02d}{r.randrange(60):02d}"
        return text + (f".{r.randrange(10**decimals):0{decimals}d}" if decimals else "")

    def angle(self, degree_digits: int, maximum: int, letters: str) -> str:
        r = self.rng
        decimals = r.choice((2, 4, 5, 7))
        degrees = r.randrange(maximum)
        minutes = f"{r.randrange(60):02d}.{r.randrange(10**decimals):0{decimals}d}"
        return f"{degrees:0{degree_digits}d}{minutes},{r.choice(letters)}"

    def position(self) -> str:
        return f"{self.angle(2, 90, 'NS')},{self.angle(3, 180, 'EW')}"

    def number(self, low: float, high: float, decimals: int) -> str:
        return f"{self.rng.uniform(low, high):.{decimals}f}"

    def date_ddmmyy(self) -> str:
        r = self.rng
        yy = r.choice((r.randint(80, 99), r.randint(0, 68)))
        return f"{r.randint(1, 28):02d}{r.randint(1, 12):02d}{yy:02d}"

    def zone(self) -> str:
        r = self.rng
        hours = r.randint(-13, 13)
        return f"{'-' if hours < 0 else ''}{abs(hours):02d},{r.choice((0, 30, 45)):02d}"

    def date_zda(self) -> str:
        r = self.rng
        return f"{r.randint(1, 28):02d},{r.randint(1, 12):02d},{r.randint(1980, 2068)}"

    def mode(self) -> str:
        return self.rng.choice("ADEFMNPRS")


def _gga(d: _Draw) -> Iterator[Callable[[], str]]:
    def fix(quality: int) -> Callable[[], str]:
        return lambda: (f"GGA,{d.time()},{d.position()},{quality},{d.rng.randint(4, 24):02d},"
                        f"{d.number(0.5, 5, 1)},{d.number(-50, 9000, d.rng.choice((1, 2, 3)))},"
                        f"M,{d.number(-100, 100, d.rng.choice((1, 3)))},M,,")
    yield from (fix(q) for q in range(9))
    yield lambda: (f"GGA,{d.time()},{d.position()},2,{d.rng.randint(4, 12):02d},"
                   f"{d.number(0.5, 3, 1)},{d.number(0, 3000, 1)},M,{d.number(-60, 60, 1)},M,"
                   f"{d.number(0, 30, 1)},{d.rng.randint(0, 1023):04d}")
    yield lambda: (f"GGA,{d.time()},{d.position()},1,{d.rng.randint(4, 12):02d},"
                   f"{d.number(0.5, 3, 1)},{d.number(0, 3000, 1)},M,,,,")  # no separation
    yield lambda: (f"GGA,{d.time()},{d.position()},1,{d.rng.randint(4, 12):02d},"
                   f"{d.number(0.5, 3, 1)},{d.number(0, 3000, 1)},M,,M,,")
    yield lambda: "GGA,,,,,,0,00,99.99,,,,,,"  # no fix, no time
    yield lambda: f"GGA,{d.time()},,,,,0,00,,,M,,M,,"  # no fix, time known


def _rmc(d: _Draw) -> Iterator[Callable[[], str]]:
    def variation() -> str:
        return f"{d.number(0, 30, 1)},{d.rng.choice('EW')}"

    def moving() -> str:
        return (f"{d.time()},A,{d.position()},{d.number(0, 400, d.rng.choice((1, 2, 3)))},"
                f"{d.number(0, 359.9, d.rng.choice((1, 2)))},{d.date_ddmmyy()}")
    yield lambda: f"RMC,{moving()},{variation()}"  # NMEA 2.0: no mode
    yield lambda: f"RMC,{moving()},,"
    yield lambda: f"RMC,{moving()},{variation()},{d.mode()}"  # 2.3
    yield lambda: f"RMC,{moving()},,,{d.mode()}"
    yield lambda: f"RMC,{moving()},,,{d.mode()},{d.rng.choice('SCUV')}"  # 4.1
    yield lambda: f"RMC,{moving()},{variation()},{d.mode()},{d.rng.choice('SCUV')}"
    yield lambda: f"RMC,{d.time()},V,,,,,,,{d.date_ddmmyy()},,,N"  # void
    yield lambda: f"RMC,{d.time()},V,,,,,,,{d.date_ddmmyy()},,,N,V"
    yield lambda: "RMC,,V,,,,,,,,,,N"  # cold start
    yield lambda: "RMC,,V,,,,,,,,,"  # cold start, NMEA 2.0


def _zda(d: _Draw) -> Iterator[Callable[[], str]]:
    yield lambda: f"ZDA,{d.time()},{d.date_zda()},00,00"
    yield lambda: f"ZDA,{d.time()},{d.date_zda()},,"  # zone not set
    yield lambda: f"ZDA,{d.time()},{d.date_zda()},{d.zone()}"  # east and west of Greenwich
    yield lambda: "ZDA,,,,,,"


def _gns(d: _Draw) -> Iterator[Callable[[], str]]:
    def modes() -> str:
        return "".join(d.mode() for _ in range(d.rng.randint(1, 6)))

    def fix() -> str:
        return (f"{d.time()},{d.position()},{modes()},{d.rng.randint(4, 40):02d},"
                f"{d.number(0.5, 5, 1)},{d.number(-50, 9000, 1)},{d.number(-100, 100, 1)}")
    yield lambda: f"GNS,{fix()},,"  # 4.0
    yield lambda: f"GNS,{fix()},{d.number(0, 30, 1)},{d.rng.randint(0, 1023):04d}"
    yield lambda: f"GNS,{fix()},,,{d.rng.choice('SCUV')}"  # 4.1
    yield lambda: f"GNS,{d.time()},,,,,NNN,00,,,,,,V"


def _gst(d: _Draw) -> Iterator[Callable[[], str]]:
    yield lambda: (f"GST,{d.time()}," + ",".join(d.number(0, 50, 3) for _ in range(3))
                   + f",{d.number(0, 180, 1)}," + ",".join(d.number(0, 50, 3) for _ in range(3)))
    yield lambda: f"GST,{d.time()},,,,,{d.number(0, 9, 2)},{d.number(0, 9, 2)},{d.number(0, 9, 2)}"
    yield lambda: f"GST,{d.time()},,,,,,,"


def sentences(seed: int = SEED) -> list[str]:
    rng = random.Random(seed)
    d = _Draw(rng)
    out = []
    for family in (_gga, _rmc, _zda, _gns, _gst):
        for template in family(d):
            for talker in TALKERS:
                for _ in range(PER_TEMPLATE):
                    out.append(_checksummed(talker + template(), lower=rng.random() < 0.25))
    return out


def corpus_text() -> str:
    return "".join(sentences())


def main() -> int:
    CORPUS.write_text(corpus_text(), encoding="ascii", newline="")
    print(f"{CORPUS}: {len(sentences())} sentences")
    return 0


if __name__ == "__main__":
    sys.exit(main())
