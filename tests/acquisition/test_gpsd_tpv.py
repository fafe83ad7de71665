"""Issue 34's acceptance against gpsd itself: the GGA, RMC and ZDA of gpsd's regression logs
(gpsd_corpus/, 80 logs), each paired with the TPV in which gpsd states its epoch
(tests/acquisition/gpsd_tpv.py says how gpsd's .chk is read and what "standard-valid" is).

Asserted: every standard-valid sentence decoded; of those gpsd states, ≥ 99 % with values
equal to gpsd's (time to gpsd's ms exactly, lat/lon within 1 mm, altMSL and altHAE within
1 mm); every other one falls under an exception named below, by design on gpsd's side, with
its count by log, so that any change shows; no crash; chunked and line-by-line feeding of
every log give what one feed gives. The figures: `python bench/gpsd_tpv.py`.
"""

from __future__ import annotations

import random
from pathlib import Path

import pytest

from acquisition.codec import Decoded, DecodeStats
from acquisition.nmea import FixQuality, Gga, NmeaMessage, NmeaStreamDecoder
from tests.acquisition.gpsd_tpv import KINDS, Sentence, Tally, Verdict, compare_file, files

CORPUS = Path(__file__).with_name("gpsd_corpus")
TARGET = 0.99

# The standard-valid sentences gpsd states nothing of, or states otherwise: each exception with
# why it is gpsd's design (driver_nmea0183.c at the commit of gpsd_corpus/SOURCE.md) and the
# number of sentences it covers, by log.
EXCEPTIONS: dict[str, dict[str, int]] = {
    # gpsd ignores the time, date and position of a void RMC (processRMC: status V sets mode 1
    # and nothing else); we decode them (status V is ours to judge, downstream).
    Verdict.VOID_RMC: {
        "GPSmap-76S.log": 12, "beidou-bd.log": 5, "beidou-gb.log": 3, "blumax-gps009.log": 4,
        "bn-9015.log": 4, "bu353-glonass.log": 10, "ch-4711.log": 7, "eXplorist110.log": 9,
        "garmin-10x.log": 5, "garmin-geko201.log": 18, "garmin25lp.log": 10, "geos-1m.log": 6,
        "gp-320fw-2019-04-07-coldboot.log": 15, "holux-gm-210.log": 11, "iTrek.log": 2,
        "magellan-ec10.log": 17, "meinberg-gps164.log": 20, "mtk-3301.log": 1,
        "myguide-3100.log": 4, "nl551e.log": 3, "rgm3800.log": 2, "rx210.log": 22,
        "skytraq.log": 17, "sl869.log": 7, "tomtom-mkII.log": 24, "tr737A+.log": 1,
        "ublox-lea-4h.log": 5, "ublox-lea-5q.log": 9},
    # gpsd dates a GGA with the year of the last RMC (status A) or ZDA; before one it takes no
    # time from it ("can't use GGA time until after ZDA or RMC has supplied a year"). Their
    # positions it states in mode 1 only (a void RMC or GLL of the same cycle, quality 0):
    # none of these reaches a TPV. Among them 28 of the 30 GGAs of quality 8 (simulator) of
    # the Garmin GPSmap 76S and Geko 201 (test_quality_8_...).
    Verdict.NO_YEAR: {
        "GPSmap-76S.log": 11, "beidou-gb.log": 3, "blumax-gps009.log": 4, "bn-9015.log": 4,
        "eXplorist110.log": 9, "garmin-geko201.log": 17, "garmin25lp.log": 9, "geos-1m.log": 5,
        "holux-gm-210.log": 11, "motorola-t805.log": 7, "myguide-3100.log": 2, "nl551e.log": 3,
        "rgm3800.log": 2, "rx210.log": 21, "skytraq.log": 1, "sl869.log": 7,
        "tn200-all.log": 9, "tn200.log": 19, "ublox-lea-5q.log": 9},
    # gpsd reports once a cycle, on the sentence it has learnt ends one; a sentence that opens
    # a cycle cleared before that report (a receiver's ZDA a second ahead of its GGA, the first
    # cycles before gpsd learns the ender, Garmin 48's split cycle), or whose values a later
    # sentence of the cycle replaced (GLL, GGA after RMC), reaches no TPV.
    Verdict.NOT_REPORTED: {
        "ac12.log": 1, "ac12_binary.log": 7, "beidou-bd.log": 1, "beidou-gb.log": 1,
        "blumax-gps009.log": 1, "bn-9015.log": 1, "bt451.log": 3, "bu353-glonass.log": 1,
        "ch-4711.log": 1, "firefly-II.log": 1, "garmin-10x.log": 1, "garmin48.log": 12,
        "geos-1m.log": 1, "gp-320fw-2019-03-28.log": 3, "gp-320fw-2019-04-06-overflow.log": 3,
        "gp-320fw-2019-04-07-coldboot.log": 3, "gr8013-w.log": 1, "isync.log": 1,
        "mt3339.log": 1, "mtk-3301.log": 1, "myguide-3100.log": 1, "rgm3800.log": 1,
        "tn204.log": 1, "tr737A+.log": 1, "ublox-lea-4s.log": 1, "ublox-lea-5h.log": 1},
    # the last cycle of a log: gpsd would report it on its ender, which never comes
    Verdict.LOG_ENDS: {
        "ait250.log": 1, "bt451.log": 1, "ch-4701.log": 1, "gps-360.log": 1, "isync.log": 2,
        "mr-350p.log": 1, "pharos-360.log": 1, "tcp-test.log": 1, "tcp-torture.log": 1,
        "ublox-lea-4h.log": 2, "ublox-lea-4s.log": 2, "udp-test.log": 1, "venus634lp.log": 1},
    # `$GPGGA,,,,,,0,00,99.99,,,,,,`, `$GPRMC,,V,,,,,,,,,,N`, `$GPZDA,,,,,,`: no time, no
    # position; gpsd takes nothing of them (of the first two it zeroes its date: no "time" in
    # the TPV), we decode the nulls
    Verdict.NULL: {"april6_2019.log": 1, "bt451.log": 12, "ericsson-gru04.log": 1},
    # the GP-320FW after a cold boot: void RMCs dated 1999-08-22 (its week-rollover bug) then
    # a GGA; gpsd keeps the date of an earlier valid sentence (2019-04-07), we take the
    # receiver's last RMC date as it is (status V included): one GGA 1024 weeks apart
    Verdict.VOID_RMC_DATE: {"gp-320fw-2019-04-07-coldboot.log": 1},
    # outside its regression mode (which a log's `# Date:` comment turns on; this log is fed
    # over TCP) gpsd_utc_resolve() takes a date before 2017 beside a leap second count of 18
    # for a week rollover and moves it on 1024 weeks (2007-12-23 -> 2027-08-08); we keep the
    # receiver's date
    Verdict.WEEK_ROLLOVER: {"tcp-torture.log": 1},
}

# The sentences with a right checksum that are not standard-valid, by defect and log (left out
# of the measure: gpsd's dialect tolerance, not ours to match).
NOT_STANDARD = {
    ("GGA", "field count 13", "saab-r4.log"): 12,  # Saab R4: GGA cut after the quality
    ("GGA", "field count 15", "beidou-bd.log"): 10,  # a 15th, empty field
    ("GGA", "position", "mtk-3301.log"): 6,  # 8960.000000: 60 minutes (no-fix filler)
    ("GGA", "position", "tr737A+.log"): 1,  # the same
    ("GGA", "time", "tcp-torture.log"): 1,  # '|' delay cookies inside the fields
    ("RMC", "date", "april6_2019.log"): 1,  # 2208-1
    ("RMC", "magnetic variation", "motorola-t805.log"): 25,  # SiRF III: 0,A / 0,N
    ("RMC", "magnetic variation", "saab-r4.log"): 12,  # ,A
    ("RMC", "position", "mtk-3301.log"): 6,  # 8960.000000
    ("RMC", "position", "tn200-all.log"): 9,  # 36000.0000,N / 72000.0000,E
    ("RMC", "position", "tn200.log"): 19,
    ("RMC", "position", "tr737A+.log"): 2,
}


@pytest.fixture(scope="module")
def judged() -> list[Sentence]:
    return [s for name, data, chk in files(CORPUS) for s in compare_file(name, data, chk)]


@pytest.fixture(scope="module")
def tally(judged: list[Sentence]) -> Tally:
    out = Tally()
    for s in judged:
        out.add(s)
    return out


def test_every_standard_valid_sentence_is_decoded(tally: Tally) -> None:
    for kind in KINDS:
        assert tally.of("decoded", kind) == tally.of("standard-valid", kind) > 200


def test_what_gpsd_states_we_decode_equal(tally: Tally) -> None:
    matched, equal = tally.of("matched"), tally.of(Verdict.EQUAL)
    assert matched > 1700
    assert equal >= TARGET * matched
    for kind in KINDS:
        assert tally.of(Verdict.EQUAL, kind) >= TARGET * tally.of("matched", kind)
    for name in ("time", "position", "altMSL", "altHAE"):
        assert tally.of(f"{name} compared") > 200, name


def test_every_other_standard_valid_sentence_is_a_named_exception(tally: Tally) -> None:
    assert {v: dict(by_file) for v, by_file in tally.exceptions.items()} == EXCEPTIONS
    for unexplained in (Verdict.DIFFERS, Verdict.UNSTATED, Verdict.REFUSED, Verdict.NOT_ECHOED):
        assert unexplained not in tally.exceptions, tally.examples[unexplained][:5]
    excused = sum(sum(by_file.values()) for by_file in EXCEPTIONS.values())
    valid = tally.of("standard-valid")
    assert tally.of(Verdict.EQUAL) >= TARGET * (valid - excused)


def test_the_sentences_left_out_are_the_non_standard_ones_named(tally: Tally) -> None:
    assert {tuple(k.split(" ", 1)) for k in tally.defects} == {k[:2] for k in NOT_STANDARD}
    assert sum(tally.defects.values()) == sum(NOT_STANDARD.values())


def test_times_are_exact_at_gpsds_millisecond(judged: list[Sentence]) -> None:
    """gpsd prints times to the ms: no sentence of the corpus has a finer digit, so equal
    printed times are equal times."""
    for s in judged:
        tod = getattr(s.ours, "utc_time_of_day_ns", None)
        assert tod is None or tod % 1_000_000 == 0, s.name


def test_quality_8_simulated_fixes_are_stated_as_gpsd_states_them(
        judged: list[Sentence]) -> None:
    """Garmin GPSmap 76S and Geko 201 send quality 8 (simulator) in GGA with real positions;
    gpsd reports them as fixes of status 8 (STATUS_SIM) and mode 3, we decode quality
    SIMULATION, the consumer's to refuse. Where gpsd states their position, it is ours."""
    simulated = [s for s in judged
                 if isinstance(s.ours, Gga) and s.ours.quality is FixQuality.SIMULATION]
    assert {s.file for s in simulated} == {"GPSmap-76S.log", "garmin-geko201.log"}
    assert len(simulated) == 30
    stated = [s for s in simulated if "position" in s.compared]
    assert len(stated) == 2
    assert all(equal for s in stated for *_, equal in s.compared["position"])


def _feed(pieces: list[bytes]) -> tuple[list[Decoded[NmeaMessage]], DecodeStats]:
    decoder = NmeaStreamDecoder()
    out = [item for piece in pieces for item in decoder.feed(piece)] + decoder.finish()
    return out, decoder.stats


def test_chunked_and_line_by_line_feeding_of_every_log_agree() -> None:
    rng = random.Random(34)
    for name, data, _ in files(CORPUS):
        whole = _feed([data])
        cuts, at = [], 0
        while at < len(data):
            at += rng.randint(1, 200)
            cuts.append(min(at, len(data)))
        chunks = [data[a:b] for a, b in zip([0, *cuts[:-1]], cuts, strict=True)]
        assert _feed(chunks) == whole, name
        assert _feed(data.splitlines(keepends=True)) == whole, name
