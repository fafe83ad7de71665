"""pynmeagps as the independent decoder of NMEA sentences: what it reads from the same bytes,
compared field by field with what acquisition.nmea decoded; and the sentences of a corpus
judged with it (`judge_sentences`: used by tests and by bench/nmea_corpus.py).

Agreement means: the same talker; times equal to the microsecond (pynmeagps's resolution);
latitude and longitude within 1 mm on the ground; heights, separations and σ within 1 mm;
every other value equal; a field null on one side exactly where it is null on the other.

A candidate sentence (`$ttGGA/RMC/ZDA/GNS/GST,...*hh` with a right checksum) is standard-valid
when it has a field count some NMEA version gives that sentence (GGA 14, RMC 11–13, ZDA 6, GNS
12–13, GST 8), pynmeagps parses it, and the rules pynmeagps does not check hold
(`breaks_a_rule_pynmeagps_leaves`).
"""

from __future__ import annotations

import datetime as dt
import math
import re
from collections import Counter
from pathlib import Path
from typing import Any

from pynmeagps import VALCKSUM, NMEAReader

from acquisition.nmea import Gga, Gns, Gst, NmeaMessage, Rmc, Zda, decode_sentence
from acquisition.nmea.wire import KNOTS_PER_M_S
from sisa.core.errors import DecodeError
from sisa.core.nmea import checksum

M_PER_DEG = 111_320.0  # a degree of latitude, and of longitude on the equator, to < 1 %
MM = 1e-3
NS_PER_US = 1_000


def pynmeagps_read(raw: bytes, *, check_checksum: bool = True) -> Any:
    """pynmeagps's message of one sentence (raises its own errors)."""
    return NMEAReader.parse(raw, validate=VALCKSUM if check_checksum else 0)


def _blank(value: Any) -> bool:
    return value == "" or value is None


def _time(ns: int | None, theirs: Any) -> str | None:
    if ns is None or _blank(theirs):
        return None if (ns is None) == _blank(theirs) else f"time {ns} / {theirs!r}"
    if ns % NS_PER_US:
        return f"time {ns} ns has sub-µs digits pynmeagps cannot hold"
    clock = (dt.datetime.min + dt.timedelta(microseconds=ns // NS_PER_US)).time()
    return None if clock == theirs else f"time {clock} / {theirs}"


def _number(name: str, ours: float | None, theirs: Any, tolerance: float) -> str | None:
    if ours is None or _blank(theirs):
        return None if (ours is None) == _blank(theirs) else f"{name} {ours!r} / {theirs!r}"
    ok = abs(float(theirs) - ours) <= tolerance * (1 + 1e-9)
    return None if ok else f"{name} {ours!r} / {theirs!r}"


def _equal(name: str, ours: Any, theirs: Any) -> str | None:
    if ours is None or _blank(theirs):
        return None if (ours is None) == _blank(theirs) else f"{name} {ours!r} / {theirs!r}"
    ours = getattr(ours, "value", ours)
    return None if ours == theirs else f"{name} {ours!r} / {theirs!r}"


def _signed(magnitude: Any, letter: Any, negative: str) -> float | str:
    """pynmeagps's unsigned value and its letter as one signed number ("" when null)."""
    if _blank(magnitude):
        return ""
    return -float(magnitude) if letter == negative else float(magnitude)


def _position(ours: Gga | Rmc | Gns, theirs: Any) -> list[str | None]:
    lat = ours.lat_deg if ours.lat_deg is not None else 0.0
    lon_tol = MM / (M_PER_DEG * max(math.cos(math.radians(lat)), 1e-6))
    return [_number("lat", ours.lat_deg, theirs.lat, MM / M_PER_DEG),  # pynmeagps signs them
            _number("lon", ours.lon_deg, theirs.lon, lon_tol)]


def _fix(ours: Gga | Gns, theirs: Any) -> list[str | None]:
    return [*_position(ours, theirs),
            _equal("satellites", ours.satellites, theirs.numSV),
            _number("hdop", ours.hdop, theirs.HDOP, 0.0),
            _number("altitude", ours.altitude_msl_m, theirs.alt, MM),
            _number("separation", ours.geoid_separation_m, theirs.sep, MM),
            _number("dgps age", ours.dgps_age_s, theirs.diffAge, 0.0),
            _equal("dgps station", ours.dgps_station, theirs.diffStation)]


def _differences(ours: NmeaMessage, theirs: Any) -> list[str | None]:
    if isinstance(ours, Gga):
        return [*_fix(ours, theirs), _equal("quality", ours.quality, theirs.quality)]
    if isinstance(ours, Gns):
        modes = None if ours.modes is None else "".join(m.value for m in ours.modes)
        return [*_fix(ours, theirs), _equal("modes", modes, theirs.posMode),
                _equal("nav status", ours.nav_status, getattr(theirs, "navStatus", ""))]
    if isinstance(ours, Rmc):
        speed_kn = None if ours.speed_m_s is None else ours.speed_m_s * KNOTS_PER_M_S
        return [*_position(ours, theirs), _equal("status", ours.status, theirs.status),
                _number("speed", speed_kn, theirs.spd, 1e-6),
                _number("course", ours.course_true_deg, theirs.cog, 0.0),
                _equal("date", ours.utc_date, theirs.date),
                _number("variation", ours.magnetic_variation_deg,
                        _signed(theirs.mv, theirs.mvEW, "W"), 0.0),
                _equal("mode", ours.mode, getattr(theirs, "posMode", "")),
                _equal("nav status", ours.nav_status, getattr(theirs, "navStatus", ""))]
    if isinstance(ours, Zda):
        date = None if ours.utc_date is None else (
            ours.utc_date.day, ours.utc_date.month, ours.utc_date.year)
        theirs_date = "" if _blank(theirs.year) else (theirs.day, theirs.month, theirs.year)
        return [_equal("date", date, theirs_date),
                _equal("zone hours", ours.zone_hours,
                       "" if _blank(theirs.ltzh) else int(theirs.ltzh)),
                _equal("zone minutes", ours.zone_minutes,
                       "" if _blank(theirs.ltzn) else int(theirs.ltzn))]
    if isinstance(ours, Gst):
        return [_number(name, getattr(ours, attr), getattr(theirs, key), MM)
                for name, attr, key in (
                    ("rms", "range_rms_m", "rangeRms"), ("major", "sigma_major_m", "stdMajor"),
                    ("minor", "sigma_minor_m", "stdMinor"), ("lat σ", "sigma_lat_m", "stdLat"),
                    ("lon σ", "sigma_lon_m", "stdLong"), ("alt σ", "sigma_alt_m", "stdAlt"))] + [
            _number("orientation", ours.major_orientation_deg, theirs.orient, 0.0)]
    return [f"no comparison for {type(ours).__name__}"]


def disagreements(ours: NmeaMessage, theirs: Any) -> list[str]:
    """Where our message and pynmeagps's differ ([] when they agree)."""
    found: list[str | None] = [_equal("talker", getattr(ours, "talker", None), theirs.talker),
                               _equal("formatter", type(ours).__name__.upper(), theirs.msgID)]
    time_ns = getattr(ours, "utc_time_of_day_ns", None)
    found.append(_time(time_ns, theirs.time))
    found += _differences(ours, theirs)
    return [d for d in found if d is not None]


# --- a corpus judged ---------------------------------------------------------------------

STANDARD_FIELDS = {"GGA": {14}, "RMC": {11, 12, 13}, "ZDA": {6}, "GNS": {12, 13}, "GST": {8}}
CANDIDATE = re.compile(rb"\$([A-Z][A-Z0-9])(GGA|RMC|ZDA|GNS|GST),"
                       rb"([\x20-\x23\x25-\x29\x2b-\x7e]*)\*([0-9A-Fa-f]{2})")


def files_of(paths: list[Path]) -> list[Path]:
    """The files given, and the `*.log` files of the folders given."""
    out: list[Path] = []
    for path in paths:
        out += sorted(path.glob("*.log")) if path.is_dir() else [path]
    return out


class SentenceTally:
    """Outcomes of the candidate sentences, by formatter, with examples."""

    def __init__(self) -> None:
        self.counts: Counter[tuple[str, str]] = Counter()  # (formatter, outcome)
        self.examples: dict[str, list[str]] = {}

    def note(self, formatter: str, outcome: str, example: str = "") -> None:
        self.counts[formatter, outcome] += 1
        if example:
            self.examples.setdefault(outcome, []).append(example)

    def of(self, outcome: str, formatter: str | None = None) -> int:
        return sum(n for (f, o), n in self.counts.items()
                   if o == outcome and formatter in (None, f))


POSITION_AT = {"GGA": (1, 3), "RMC": (2, 4), "GNS": (1, 3)}  # lat, lon token after address
RMC_VARIATION_DIRECTION, RMC_DATE = 10, 8
DEGREES_MINUTES = re.compile(r"(\d*)(\d\d(?:\.\d*)?)")
TIME = re.compile(r"(\d\d\d\d\d\d(?:\.\d*)?)?")
DATE = re.compile(r"(\d{6})?")


def breaks_a_rule_pynmeagps_leaves(formatter: str, tokens: list[str]) -> str | None:
    """The first standard rule the sentence breaks that pynmeagps does not check, or None:
    positions as (d)ddmm.mm… with minutes below 60 and at most 90° / 180°, times as
    hhmmss.ss…, RMC dates as ddmmyy, magnetic variation direction E or W."""
    if TIME.fullmatch(tokens[0]) is None:
        return f"time {tokens[0]!r}"
    for at, limit in zip(POSITION_AT.get(formatter, ()), (90, 180), strict=False):
        found = DEGREES_MINUTES.fullmatch(tokens[at])
        if tokens[at] and found is None:
            return f"position {tokens[at]!r}"
        if found is not None and (float(found.group(2)) >= 60
                                  or int(found.group(1) or 0) + float(found.group(2)) / 60 > limit):
            return f"position {tokens[at]!r} beyond the range or minutes not below 60"
    if formatter == "RMC" and DATE.fullmatch(tokens[RMC_DATE]) is None:
        return f"date {tokens[RMC_DATE]!r}"
    if formatter == "RMC" and tokens[RMC_VARIATION_DIRECTION] not in ("", "E", "W"):
        return f"magnetic variation direction {tokens[RMC_VARIATION_DIRECTION]!r}"
    return None


def _judge(raw: bytes, formatter: str, tokens: list[str], tally: SentenceTally) -> None:
    if len(tokens) not in STANDARD_FIELDS[formatter]:
        tally.note(formatter, "not standard: field count", raw.decode().strip())
        return
    try:
        theirs = pynmeagps_read(raw)
    except Exception as err:  # pynmeagps's own errors: not standard-valid for the reference
        tally.note(formatter, "pynmeagps refuses", f"{raw.decode().strip()}  ({err})")
        return
    broken = breaks_a_rule_pynmeagps_leaves(formatter, tokens)
    if broken is not None:
        tally.note(formatter, "not standard: a value", f"{raw.decode().strip()}  ({broken})")
        return
    tally.note(formatter, "standard-valid")
    try:
        ours: NmeaMessage = decode_sentence(raw)
    except DecodeError as err:
        tally.note(formatter, "refused by us", f"{raw.decode().strip()}  ({err})")
        return
    found = disagreements(ours, theirs)
    if found:
        tally.note(formatter, "values differ", f"{raw.decode().strip()}  {found}")
    else:
        tally.note(formatter, "agree")


def judge_sentences(data: bytes, tally: SentenceTally) -> None:
    for m in CANDIDATE.finditer(data):
        raw = m.group(0)
        if checksum(raw[1:raw.rindex(b"*")]) != int(m.group(4), 16):
            tally.note(m.group(2).decode(), "damaged in the log")
            continue
        _judge(raw + b"\r\n", m.group(2).decode(), m.group(3).decode().split(","), tally)
