"""gpsd itself as the reference: each GGA, RMC and ZDA we decode from gpsd's regression logs,
paired with the TPV report in which gpsd states that sentence's epoch, compared value by value.

What gpsd's `.log.chk` holds (gpsfake's output, read from gpsd's drivers/driver_nmea0183.c,
gpsd/libgpsd_core.c and gpsd/gpsd_json.c at the commit of gpsd_corpus/SOURCE.md): every sentence
gpsd accepted, echoed as it came, followed by the JSON reports it made on it. A TPV states
gpsd's fix *after* that sentence: gpsd merges the sentences of one reporting cycle into one fix,
field by field, each field holding the value of the last sentence of the cycle that set it.

- A cycle starts on a sentence that registers a time of day more than 10 ms from the last
  registered one (GGA, GLL, GNS, GBS, PSRFEPE and PASHR,POS with a time; RMC only with status A,
  time and date; ZDA only with all of its time and date): gpsd clears its fix there.
- Which sentence ends a cycle gpsd learns from the stream (the one last before a time change).
  It reports a TPV there, and, until it has learnt one, on every sentence that sets a position
  or a mode. We do not need to know which: the TPVs are in the file, after their sentence.
- `time`: RMC's date and time (status A only); ZDA's; a GGA's (or GLL's, GNS's) time of day on
  the date of the last RMC or ZDA that gave one. gpsd takes no time from a GGA before any date,
  and none at all from a void RMC. Printed to the ms (rounded).
- `lat`, `lon`: GGA's whenever its four position fields are there (any quality); RMC's with
  status A; GLL's with status A; GNS's unless its mode is N or null. Printed only when the
  TPV's `mode` is 2 (2D) or 3 (3D): mode 0 is "not seen", 1 "no fix" (gpsd's judgement: a GGA
  of quality 0 or with under 3 satellites, a void RMC, a GGA repeating the last one's time).
- `altMSL` is GGA's altitude field (above the geoid, as NMEA defines it); `geoidSep` GGA's
  separation, or gpsd's own geoid model when the field is null; `altHAE` = altMSL + geoidSep,
  computed once a cycle, on the first altitude (a later GGA of the cycle changes altMSL only);
  `alt` is altMSL (deprecated). Heights printed only in mode ≥ 2.

Ours: the messages NmeaStreamDecoder yields for the whole log. A GGA's date is the one the
runner logs its fix with: the day nearest the receiver's last RMC/ZDA date and time or the
last fix, whichever came last (acquisition.nmea's `gps_ns_from_utc_time_of_day`). The runner's
earlier rule (the last date, a day on when that put the fix 12 h before the last one) logged
6 GGAs of gp-320fw-2019-04-07-coldboot that gpsd states a day late (the receiver's void RMCs
jump back from 2010 to 1999), and at midnight every fix of a receiver whose ZDA runs ahead of
its GGA (as ac12's does).

A GGA/RMC/ZDA is *standard-valid* (`standard_defect`, our reading of NMEA 0183 versions 2.0
to 4.11, without any decoder): checksum right; the field count of a version (GGA 14, RMC 11 for
2.0–2.2, 12 for 2.3–4.0 with the mode indicator, 13 for 4.1+ with the navigational status,
ZDA 6); every field null or well formed: time hhmmss with optional decimals (hh < 24, mm < 60,
ss < 60 or 23:59:60), latitude ddmm.m… (minutes < 60, ≤ 90°) with N/S, longitude dddmm.m…
(≤ 180°) with E/W, GGA quality 0–8, satellites 0–99, HDOP, altitude and separation decimal
numbers with unit M, DGPS age a number and station 0–1023; RMC status A/V, speed and course
numbers, date ddmmyy of a real day, magnetic variation a number with E/W, mode indicator one of
A D E F M N P R S, navigational status one of S C U V; ZDA day 01–31, month 01–12, a 4-digit
year, zone hours −13..+13 and minutes 00–59.
"""

from __future__ import annotations

import datetime as dt
import json
import math
import re
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from acquisition.codec import Decoded
from acquisition.nmea import (
    Gga,
    NmeaMessage,
    NmeaStreamDecoder,
    Rmc,
    RmcStatus,
    Zda,
    checksum,
    gps_ns_from_utc,
    gps_ns_from_utc_time_of_day,
)
from sisa.core.timescale import GPS_EPOCH, NS_PER_DAY

KINDS = ("GGA", "RMC", "ZDA")
M_PER_DEG = 111_320.0  # a degree of latitude (and of longitude on the equator), to < 1 %
MM = 1e-3
NS_PER_MS = 1_000_000
FRAME_TOLERANCE_S = 0.01  # gpsd: a registered time more than 10 ms off starts a cycle
FIELDS = ("time", "position", "altMSL", "altHAE")

# --- standard-valid, per NMEA 0183 --------------------------------------------------------

_SENTENCE = re.compile(r"\$([A-Z][A-Z0-9])(GGA|RMC|ZDA),([^*$]*)\*([0-9A-Fa-f]{2})")
_TIME = re.compile(r"(\d\d)(\d\d)(\d\d)(?:\.\d+)?")
_LAT = re.compile(r"(\d\d)(\d\d(?:\.\d+)?)")
_LON = re.compile(r"(\d\d\d)(\d\d(?:\.\d+)?)")
_NUMBER = re.compile(r"\d+(?:\.\d*)?|\.\d+")
_SIGNED = re.compile(r"-?(?:\d+(?:\.\d*)?|\.\d+)")
_INT = re.compile(r"\d+")
STANDARD_FIELDS = {"GGA": (14,), "RMC": (11, 12, 13), "ZDA": (6,)}


def _time_ok(token: str) -> bool:
    found = _TIME.fullmatch(token)
    if found is None:
        return False
    h, m, s = (int(g) for g in found.groups())
    return h < 24 and m < 60 and (s < 60 or (h, m, s) == (23, 59, 60))


def _angle_ok(token: str, letter: str, pattern: re.Pattern[str], limit: int, signs: str) -> bool:
    if token == "" and letter == "":
        return True
    found = pattern.fullmatch(token)
    if found is None or letter not in signs:
        return False
    degrees, minutes = int(found.group(1)), float(found.group(2))
    return minutes < 60 and degrees + minutes / 60 <= limit


def _null_or(token: str, pattern: re.Pattern[str]) -> bool:
    return token == "" or pattern.fullmatch(token) is not None


def _with_unit(number: str, unit: str) -> bool:
    return (number == "" and unit in ("", "M")) or (
        _SIGNED.fullmatch(number) is not None and unit == "M")


def _in(token: str, low: int, high: int) -> bool:
    return token == "" or (_INT.fullmatch(token.lstrip("+-")) is not None
                           and low <= int(token) <= high)


def _ddmmyy_ok(token: str) -> bool:
    if token == "":
        return True
    if re.fullmatch(r"\d{6}", token) is None:
        return False
    try:
        dt.date(2000 + int(token[4:]), int(token[2:4]), int(token[:2]))
    except ValueError:
        return False
    return True


def standard_defect(kind: str, tokens: list[str]) -> str | None:
    """Why a GGA/RMC/ZDA (its fields after the address, checksum already right) is not
    standard-valid, or None when it is: see the module's docstring."""
    if len(tokens) not in STANDARD_FIELDS[kind]:
        return f"field count {len(tokens)}"
    if not (tokens[0] == "" or _time_ok(tokens[0])):
        return "time"
    checks: list[tuple[str, bool]]
    if kind == "GGA":
        checks = [
            ("position", _angle_ok(tokens[1], tokens[2], _LAT, 90, "NS")
             and _angle_ok(tokens[3], tokens[4], _LON, 180, "EW")),
            ("quality", _in(tokens[5], 0, 8)), ("satellites", _in(tokens[6], 0, 99)),
            ("hdop", _null_or(tokens[7], _NUMBER)),
            ("altitude", _with_unit(tokens[8], tokens[9])),
            ("separation", _with_unit(tokens[10], tokens[11])),
            ("dgps age", _null_or(tokens[12], _NUMBER)), ("dgps station", _in(tokens[13], 0, 1023)),
        ]
    elif kind == "RMC":
        checks = [
            ("status", tokens[1] in ("", "A", "V")),
            ("position", _angle_ok(tokens[2], tokens[3], _LAT, 90, "NS")
             and _angle_ok(tokens[4], tokens[5], _LON, 180, "EW")),
            ("speed", _null_or(tokens[6], _NUMBER)), ("course", _null_or(tokens[7], _NUMBER)),
            ("date", _ddmmyy_ok(tokens[8])),
            ("magnetic variation", (tokens[9] == "" and tokens[10] in ("", "E", "W"))
             or (_NUMBER.fullmatch(tokens[9]) is not None and tokens[10] in ("E", "W"))),
            ("mode", len(tokens) < 12 or tokens[11] in ("", *"ADEFMNPRS")),
            ("navigational status", len(tokens) < 13 or tokens[12] in ("", *"SCUV")),
        ]
    else:
        checks = [
            ("day", _in(tokens[1], 1, 31)), ("month", _in(tokens[2], 1, 12)),
            ("year", tokens[3] == "" or re.fullmatch(r"\d{4}", tokens[3]) is not None),
            ("zone hours", _in(tokens[4], -13, 13)), ("zone minutes", _in(tokens[5], 0, 59)),
        ]
    for name, ok in checks:
        if not ok:
            return name
    return None


# --- the files -------------------------------------------------------------------------------


@dataclass
class Sentence:
    """A GGA/RMC/ZDA of a log with a right checksum, and what became of it."""

    file: str
    offset: int  # in the log
    text: str  # `$...*hh`
    kind: str
    tokens: list[str]
    defect: str | None  # None: standard-valid
    ours: NmeaMessage | None = None  # what we decoded (None: refused)
    echoed: bool = False  # gpsd accepted it (echoed it in its .chk)
    # field -> (gpsd's value, ours, equal) of each TPV in which gpsd reports it from this sentence
    compared: dict[str, list[tuple[Any, Any, bool]]] = field(default_factory=dict)
    # field ("*": all) -> why gpsd states it in no TPV
    unreported: dict[str, str] = field(default_factory=dict)
    our_time: str | None = None  # ours, as gpsd prints a time (with the date we give a GGA)
    dated_by_void_rmc: bool = False  # (a GGA) the date we gave it came from an RMC of status V

    @property
    def name(self) -> str:
        return f"{self.file}@{self.offset}"


def decode(data: bytes) -> list[Decoded[NmeaMessage]]:
    decoder = NmeaStreamDecoder()
    return [*decoder.feed(data), *decoder.finish()]


def _placed(data: bytes, items: list[Decoded[NmeaMessage]]) -> dict[int, NmeaMessage]:
    """Our messages by their offset in the log."""
    out, at = {}, 0
    for item in items:
        at = data.index(item.raw, at)
        out[at] = item.message
        at += len(item.raw)
    return out


def sentences_of(name: str, data: bytes) -> list[Sentence]:
    """Every GGA/RMC/ZDA with a right checksum in a log, judged, with our decoding."""
    ours = _placed(data, decode(data))
    text = data.decode("latin-1")
    out = []
    for m in _SENTENCE.finditer(text):
        body = m.group(0)[1:m.group(0).rindex("*")]
        if checksum(body.encode("latin-1")) != int(m.group(4), 16):
            continue
        tokens = m.group(3).split(",")
        defect = standard_defect(m.group(2), tokens)
        message = ours.get(m.start())
        if not isinstance(message, Gga | Rmc | Zda):
            message = None
        out.append(Sentence(name, m.start(), m.group(0), m.group(2), tokens, defect, message))
    return out


def chk_items(text: str) -> Iterator[tuple[str, Any]]:
    """("sentence", text) and ("tpv", object) of a .chk, in order (other reports left out)."""
    for line in text.splitlines():
        if line.startswith("{"):
            report = json.loads(line)
            if report.get("class") == "TPV":
                yield "tpv", report
        elif line.startswith(("$", "!")):
            yield "sentence", line.rstrip("\r")


# --- gpsd's merge, with the sentence each field came from --------------------------------------


def _hms(token: str) -> float | None:
    """gpsd's decode_hhmmss: six digits, decimals after a '.'; seconds of day, or None."""
    if len(token) < 6 or not token[:6].isdigit():
        return None
    seconds = float(int(token[:2]) * 3600 + int(token[2:4]) * 60 + int(token[4:6]))
    digits = re.match(r"\.(\d+)", token[6:])
    return seconds + (int(digits.group(1)) / 10 ** len(digits.group(1)) if digits else 0.0)


def _latlon_ok(f: list[str]) -> bool:
    """gpsd's do_lat_lon on four fields: all present, both numbers with a '.'."""
    return all(f[:4]) and all(re.match(r"[+-]?\d*\.", f[i]) is not None for i in (0, 2))


# the fewest fields (address included) gpsd takes of a sentence: fewer is "too short", ignored
_GPSD_MINIMUM = {"GGA": 13, "RMC": 8, "ZDA": 4, "GLL": 7, "GNS": 13, "GBS": 7, "PSRFEPE": 7,
                 "PASHR": 3, "PGRMZ": 4}


@dataclass
class _Source:
    sentence: Sentence | None  # None: a sentence not ours to compare (GLL, GNS, PGRMZ, ...)
    what: str  # its formatter


class GpsdModel:
    """gpsd's NMEA cycle and merge (driver_nmea0183.c, libgpsd_core.c), tracking for each
    field of its fix the sentence it came from, and the sentences of the current cycle."""

    def __init__(self) -> None:
        self.has_year = False  # nmea.date.tm_year != 0: an RMC (A) or ZDA gave a date
        self.this_frac = 0.0
        self.fix: dict[str, _Source] = {}
        self.cycle: list[Sentence] = []  # ours of the cycle whose time gpsd took
        self.hae_set = False

    def _clear(self, by: str) -> None:
        reason = f"cycle cleared by a {by} of a new time before any TPV"
        for source in self.fix.values():
            _lost(source, reason)
        for s in self.cycle:
            if not s.compared:
                _note(s, "*", reason)
        self.fix.clear()
        self.cycle.clear()
        self.hae_set = False

    def end(self) -> None:
        """The log ends: what the last cycle set and no TPV stated, gpsd never reports."""
        for source in self.fix.values():
            _lost(source, LOG_ENDS)
        for s in self.cycle:
            if not s.compared:
                _note(s, "*", LOG_ENDS)

    def _register(self, seconds: float | None, by: str) -> None:
        if seconds is None:
            return
        last, self.this_frac = self.this_frac, seconds
        if abs(seconds - last) > FRAME_TOLERANCE_S:
            self._clear(by)

    def _set(self, name: str, source: _Source) -> None:
        old = self.fix.get(name)
        if old is not None and old.sentence is not source.sentence:
            _lost(old, f"{name} replaced by a later {source.what} of the cycle before any TPV",
                  name)
        self.fix[name] = source

    def _time(self, source: _Source) -> None:
        self._set("time", source)
        if source.sentence is not None:
            self.cycle.append(source.sentence)

    def _altitude(self, source: _Source) -> None:
        """An altitude above the geoid: altMSL; altHAE only on the cycle's first."""
        self._set("altMSL", source)
        if not self.hae_set:
            self._set("altHAE", source)
            self.hae_set = True

    def feed(self, text: str, ours: Sentence | None) -> None:
        """One sentence gpsd accepted (`ours`: the GGA/RMC/ZDA it is, when it is one)."""
        body = text[1:text.rindex("*")] if "*" in text else text[1:]
        f = body.split(",")
        formatter = f[0] if f[0].startswith("P") else f[0][2:]
        source = _Source(ours, formatter)
        if len(f) < _GPSD_MINIMUM.get(formatter, 0):
            _note(ours, "*", "gpsd: too few fields, ignored")
            return
        count = len(f)
        f += [""] * 40
        if formatter == "GGA":
            quality = int(f[6]) if f[6].lstrip("-").isdigit() else -1
            if quality == 0 and f[1] == "":
                self.has_year = False
                self._set("time", _Source(None, "GGA without time (gpsd: time 0)"))
            if f[1]:
                seconds = _hms(f[1])
                self._register(seconds, formatter)
                if seconds is not None and self.has_year:
                    self._time(source)
                elif seconds is not None:
                    _note(ours, "time", "gpsd: no year yet (no RMC of status A, no ZDA)")
            if _latlon_ok(f[2:6]):
                self._set("position", source)
                if f[9]:
                    self._altitude(source)
        elif formatter == "RMC":
            if f[2] != "A":
                _note(ours, "*", "gpsd takes nothing of an RMC of status V")
                if f[1] == "" or f[9] == "":
                    self.has_year = False
                    self._set("time", _Source(None, "void RMC without time (gpsd: time 0)"))
                return
            seconds = _hms(f[1]) if f[1] and count > 9 and f[9] else None
            if seconds is not None and _ddmmyy_ok(f[9]):
                self.has_year = True
                self._register(seconds, formatter)
                self._time(source)
            if _latlon_ok(f[3:7]):
                self._set("position", source)
        elif formatter == "ZDA":
            seconds = _hms(f[1]) if all(f[1:5]) else None
            year, month, day = (int(x) if x.isdigit() else 0 for x in (f[4], f[3], f[2]))
            if seconds is not None and 1900 <= year <= 2200 and 1 <= month <= 12 \
                    and 1 <= day <= 31:
                self.has_year = True
                self._register(seconds, formatter)
                self._time(source)
            else:
                _note(ours, "*", "gpsd: ZDA without its time and date")
        elif formatter in ("GLL", "GNS", "PSRFEPE"):
            at = 5 if formatter == "GLL" else 1
            seconds = _hms(f[at]) if f[at] else None
            self._register(seconds, formatter)
            if seconds is not None and self.has_year:
                self._set("time", source)
            if formatter == "GLL" and f[6] == "A" and (count < 8 or f[7] != "N") \
                    and _latlon_ok(f[1:5]):
                self._set("position", source)
            if formatter == "GNS" and f[6] not in ("", "N") and f[13] not in ("U", "V") \
                    and _latlon_ok(f[2:6]):
                self._set("position", source)
                if f[9]:
                    self._altitude(source)
        elif formatter == "GBS":
            self._register(_hms(f[1]), formatter)
        elif formatter == "PGRMZ" and f[1]:
            self._set("altMSL", source)  # Garmin's altitude, in whole feet
        elif formatter == "PASHR" and f[1] == "POS":
            self._clear(formatter)  # gpsd clears on every PASHR,POS
            seconds = _hms(f[4]) if f[2] else None
            self._register(seconds, formatter)
            if seconds is not None:
                self._set("time", source)
            if f[2] and _latlon_ok(f[5:9]):
                self._set("position", source)
                if f[9]:
                    self._set("altHAE", source)
                    self.hae_set = True


LOG_ENDS = "the log ends before gpsd reports the cycle"


def _note(sentence: Sentence | None, name: str, reason: str) -> None:
    if sentence is not None:
        sentence.unreported.setdefault(name, reason)


def _lost(source: _Source, reason: str, name: str = "*") -> None:
    s = source.sentence
    if s is not None and not s.compared:
        _note(s, name, reason)


# --- our values, gpsd's values ---------------------------------------------------------------


def _iso_ms(date: dt.date, time_of_day_ns: int) -> str:
    """A UTC date and time of day as gpsd prints it: ISO 8601, rounded to the ms."""
    ms = (time_of_day_ns + NS_PER_MS // 2) // NS_PER_MS
    instant = dt.datetime.combine(date, dt.time()) + dt.timedelta(milliseconds=ms)
    return instant.strftime("%Y-%m-%dT%H:%M:%S.") + f"{instant.microsecond // 1000:03d}Z"


@dataclass
class OurDates:
    """The date the runner gives each GGA: the day that puts it nearest the last RMC or ZDA
    date and time decoded, or the last GGA with time and position, whichever came last (UTC
    throughout: no leap seconds enter)."""

    last_dated_ns: int | None = None
    from_void_rmc: bool = False

    def see(self, message: NmeaMessage) -> None:
        if (isinstance(message, Rmc | Zda) and message.utc_date is not None
                and message.utc_time_of_day_ns is not None):
            self.last_dated_ns = gps_ns_from_utc(message.utc_date,
                                                 message.utc_time_of_day_ns, 0)
            self.from_void_rmc = isinstance(message, Rmc) and message.status is not RmcStatus.ACTIVE

    def time_of(self, message: NmeaMessage) -> str | None:
        tod = getattr(message, "utc_time_of_day_ns", None)
        if tod is None:
            return None
        if isinstance(message, Rmc | Zda):
            date = message.utc_date
            return None if date is None else _iso_ms(date, tod)
        if self.last_dated_ns is None:
            return None
        instant = gps_ns_from_utc_time_of_day(tod, 0, self.last_dated_ns)
        if getattr(message, "lat_deg", None) is not None:
            self.last_dated_ns = instant  # a fix the runner logs
        days, tod = divmod(instant, NS_PER_DAY)
        return _iso_ms(GPS_EPOCH.date() + dt.timedelta(days=days), tod)


def _close(ours: float | None, theirs: float, tolerance: float) -> bool:
    return ours is not None and abs(ours - theirs) <= tolerance * (1 + 1e-9)


def _compare(name: str, sentence: Sentence, tpv: dict[str, Any],
             ) -> tuple[Any, Any, bool] | None:
    """gpsd's value of one field in a TPV and ours from the sentence it came from; None when
    the TPV does not state it."""
    ours = sentence.ours
    if name == "time":
        if "time" not in tpv:
            return None
        return tpv["time"], sentence.our_time, tpv["time"] == sentence.our_time
    if name == "position":
        if "lat" not in tpv or "lon" not in tpv:
            return None
        lat, lon = getattr(ours, "lat_deg", None), getattr(ours, "lon_deg", None)
        if lat is None or lon is None:
            return (tpv["lat"], tpv["lon"]), (lat, lon), False
        lon_tol = MM / (M_PER_DEG * max(math.cos(math.radians(lat)), 1e-6))
        equal = _close(lat, tpv["lat"], MM / M_PER_DEG) and _close(lon, tpv["lon"], lon_tol)
        return (tpv["lat"], tpv["lon"]), (lat, lon), equal
    if name == "altMSL":
        if "altMSL" not in tpv:
            return None
        msl = getattr(ours, "altitude_msl_m", None)
        return tpv["altMSL"], msl, _close(msl, tpv["altMSL"], MM)
    if "altHAE" not in tpv:
        return None
    hae = getattr(ours, "height_ellipsoidal_m", None)
    if hae is None and getattr(ours, "altitude_msl_m", None) is not None:
        return None  # a null separation: gpsd took its own geoid model (GEOID_MODEL)
    return tpv["altHAE"], hae, _close(hae, tpv["altHAE"], MM)


GEOID_MODEL = "altHAE: GGA's separation null, gpsd adds its own geoid model's"


def compare_file(name: str, data: bytes, chk: str) -> list[Sentence]:
    """Every GGA/RMC/ZDA of a log, with what gpsd's TPVs say of it (`compared`, `unreported`).

    At each TPV: the time of every sentence of the cycle whose time gpsd took is compared
    with the TPV's (they state one epoch); position and heights only with the sentence gpsd
    took them from (a later one of the cycle replaces them: its own rounding)."""
    sentences = sentences_of(name, data)
    by_text: dict[str, list[Sentence]] = {}
    for s in sentences:
        by_text.setdefault(s.text, []).append(s)
    used: Counter[str] = Counter()
    model, dates = GpsdModel(), OurDates()
    for kind, item in chk_items(chk):
        if kind == "sentence":
            text = item[:item.rindex("*") + 3] if "*" in item else item
            candidates = by_text.get(text, [])
            ours = None
            if used[text] < len(candidates):
                ours = candidates[used[text]]
                used[text] += 1
                ours.echoed = True
                if ours.ours is not None:
                    ours.our_time = dates.time_of(ours.ours)
                    ours.dated_by_void_rmc = dates.from_void_rmc
                    dates.see(ours.ours)
            model.feed(text, ours)
            continue
        _report(model, item)
    model.end()
    return sentences


def _report(model: GpsdModel, tpv: dict[str, Any]) -> None:
    pairs = [("time", s) for s in model.cycle]
    pairs += [(n, src.sentence) for n, src in model.fix.items()
              if n != "time" and src.sentence is not None]
    for fname, s in pairs:
        if s.ours is None:
            _note(s, fname, "we refused the sentence")
            continue
        result = _compare(fname, s, tpv)
        if result is None:
            if fname != "altHAE" or "altMSL" in tpv:
                _note(s, fname, f"gpsd's TPV (mode {tpv.get('mode')}) states no {fname}"
                      if fname != "altHAE" else GEOID_MODEL)
            continue
        s.compared.setdefault(fname, []).append(result)


def files(folder: Path) -> list[tuple[str, bytes, str]]:
    """(name, log, gpsd's .chk) of the logs of a folder that have their .chk."""
    pairs = [(log, log.parent / f"{log.name}.chk") for log in sorted(folder.glob("*.log"))]
    return [(log.name, log.read_bytes(), chk.read_text("latin-1"))
            for log, chk in pairs if chk.exists()]


# --- verdicts ----------------------------------------------------------------------------------


class Verdict:
    """What became of a standard-valid sentence: EQUAL, or the named exception it falls in."""

    EQUAL = "equal"
    REFUSED = "refused by us"
    NOT_ECHOED = "gpsd did not accept it"
    # gpsd states nothing of it (no TPV field comes from it, and no TPV states its epoch)
    NULL = "null time and position: nothing to state"
    VOID_RMC = "RMC of status V: gpsd takes neither its time nor its position"
    ZDA_UNDATED = "ZDA without its date: gpsd takes nothing of it"
    NO_YEAR = "GGA before any RMC (status A) or ZDA: gpsd has no year, takes no time"
    NOT_REPORTED = ("gpsd's cycle detector: the next cycle began, or a later sentence replaced "
                    "its values, before any TPV")
    LOG_ENDS = LOG_ENDS
    # gpsd states it with values unlike ours
    WEEK_ROLLOVER = "gpsd's 1024-week rollover guess: its time is ours + 1024 weeks"
    VOID_RMC_DATE = ("GGA dated differently: we take the date of the receiver's last RMC even "
                     "of status V, gpsd that of its last RMC of status A or ZDA")
    UNDATED_BY_US = ("GGA we cannot date: the receiver's RMCs are not standard (magnetic "
                     "variation direction 'A' or 'N'), we refuse them; gpsd reads their date")
    DIFFERS = "values differ (unexplained)"
    UNSTATED = "gpsd states nothing of it (unexplained)"


WEEK_1024 = dt.timedelta(weeks=1024)


def _parse_iso(text: str) -> dt.datetime:
    return dt.datetime.strptime(text, "%Y-%m-%dT%H:%M:%S.%fZ")


def _time_difference(s: Sentence) -> str:
    for theirs, ours, equal in s.compared.get("time", []):
        if equal:
            continue
        if ours is None:
            return Verdict.UNDATED_BY_US if s.kind == "GGA" else Verdict.DIFFERS
        if s.kind == "GGA" and s.dated_by_void_rmc:
            return Verdict.VOID_RMC_DATE
        if _parse_iso(theirs) - _parse_iso(ours) == WEEK_1024:
            return Verdict.WEEK_ROLLOVER
        return Verdict.DIFFERS
    return Verdict.DIFFERS


def verdict(s: Sentence) -> str:
    """EQUAL or the exception of a standard-valid sentence (see `Verdict`)."""
    if s.ours is None:
        return Verdict.REFUSED
    if not s.echoed:
        return Verdict.NOT_ECHOED
    if s.compared:
        if all(equal for results in s.compared.values() for *_, equal in results):
            return Verdict.EQUAL
        if all(equal for name, results in s.compared.items() if name != "time"
               for *_, equal in results):
            return _time_difference(s)
        return Verdict.DIFFERS
    reasons = set(s.unreported.values())
    if getattr(s.ours, "utc_time_of_day_ns", None) is None \
            and getattr(s.ours, "lat_deg", None) is None:
        return Verdict.NULL
    if any(r.startswith("gpsd takes nothing of an RMC") for r in reasons):
        return Verdict.VOID_RMC
    if any(r.startswith("gpsd: ZDA without") for r in reasons):
        return Verdict.ZDA_UNDATED
    if any(r.startswith("gpsd: no year") for r in reasons):
        return Verdict.NO_YEAR
    if LOG_ENDS in reasons:
        return Verdict.LOG_ENDS
    if any(r.startswith(("cycle cleared", "time replaced", "position replaced"))
           for r in reasons):
        return Verdict.NOT_REPORTED
    return Verdict.UNSTATED


@dataclass
class Tally:
    """Counts by sentence type: candidates (right checksum), standard-valid, decoded, matched
    (a TPV states it), equal; the exceptions by verdict and file; the defects of the others."""

    counts: Counter[tuple[str, str]] = field(default_factory=Counter)  # (kind, what)
    exceptions: dict[str, Counter[str]] = field(default_factory=dict)  # verdict -> file -> n
    defects: Counter[str] = field(default_factory=Counter)
    examples: dict[str, list[str]] = field(default_factory=dict)

    def add(self, s: Sentence) -> None:
        self.counts[s.kind, "candidates"] += 1
        if s.defect is not None:
            self.defects[f"{s.kind} {s.defect}"] += 1
            return
        self.counts[s.kind, "standard-valid"] += 1
        self.counts[s.kind, "decoded"] += s.ours is not None
        self.counts[s.kind, "matched"] += bool(s.compared)
        for name in FIELDS:
            self.counts[s.kind, f"{name} compared"] += name in s.compared
        found = verdict(s)
        self.counts[s.kind, found] += 1
        if found != Verdict.EQUAL:
            self.exceptions.setdefault(found, Counter())[s.file] += 1
            self.examples.setdefault(found, []).append(f"{s.name} {s.text}")

    def of(self, what: str, kind: str | None = None) -> int:
        return sum(n for (k, w), n in self.counts.items() if w == what and kind in (None, k))


def tally_folder(folder: Path) -> Tally:
    tally = Tally()
    for name, data, chk in files(folder):
        for s in compare_file(name, data, chk):
            tally.add(s)
    return tally
