"""NMEA 0183 as receivers send it: a corpus written from the standard's rules (and gpsd's
regression logs, when given) decoded as pynmeagps decodes it; chunked and line-by-line feeding
agree; sentences without checksum refused unless accepted; every refusal counted by reason, up
to the health channel; any talker's fixes logged alike."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acquisition.codec import ErrorPolicy
from acquisition.nmea import (
    FixQuality,
    Gga,
    Gns,
    ModeIndicator,
    NmeaStreamDecoder,
    NmeaVersion,
    Refusal,
    Rmc,
    decode_sentence,
    encode,
    gga_from_fix,
    rmc_from_fix,
    zda_from_gps_ns,
)
from acquisition.runner import Acquisition
from emulators.scenario import load_scenario
from recorder.messages import GpsFix, StreamHealth
from sisa.core.errors import DecodeError
from sisa.core.nmea import checksum
from sisa.core.timescale import NS_PER_S, parse_gps_datetime
from sisa.wiring.acqconfig import acquisition_config
from tests.acquisition.corpus import nmea_0183
from tests.acquisition.nmea_oracle import (
    SentenceTally,
    disagreements,
    files_of,
    judge_sentences,
    pynmeagps_read,
)

CORPUS_LINES = nmea_0183.CORPUS.read_bytes().splitlines(keepends=True)
# gpsd's regression logs: the subset kept here (gpsd_corpus/SOURCE.md), or SISA_GPSD_CORPUS for all
GPSD_CORPUS = os.environ.get("SISA_GPSD_CORPUS") or str(Path(__file__).with_name("gpsd_corpus"))
T0 = parse_gps_datetime("2026-06-15T09:00:00")
LEAP_S = 18


def test_the_corpus_file_is_what_its_generator_writes() -> None:
    assert nmea_0183.CORPUS.read_bytes() == nmea_0183.corpus_text().encode("ascii"), (
        "run `python -m tests.acquisition.corpus.nmea_0183`")


def test_every_corpus_sentence_decodes_as_pynmeagps_reads_it() -> None:
    failures = []
    for raw in CORPUS_LINES:
        try:
            found = disagreements(decode_sentence(raw), pynmeagps_read(raw))
        except DecodeError as err:
            found = [str(err)]
        if found:
            failures.append((raw, found))
    assert failures == []
    assert len(CORPUS_LINES) == 840


def test_the_corpus_covers_what_the_standard_allows() -> None:
    text = b"".join(CORPUS_LINES)
    for talker in nmea_0183.TALKERS:
        assert f"${talker}GGA,".encode() in text
    assert any(raw[-4:-2].islower() for raw in CORPUS_LINES)  # lower-case hex checksums
    rmcs = [m for m in map(decode_sentence, CORPUS_LINES) if isinstance(m, Rmc)]
    kinds = {(m.mode is None, m.nav_status is None, m.magnetic_variation_deg is None)
             for m in rmcs}
    assert (True, True, False) in kinds  # 2.0 with magnetic variation
    assert (False, True, True) in kinds  # 2.3
    assert (False, False, True) in kinds  # 4.1
    assert b"GGA,,,,,,0,00,99.99,,,,,," in text  # no fix, no time


def test_gpsd_regression_logs_decode_as_pynmeagps_reads_them() -> None:
    tally = SentenceTally()
    for path in files_of([Path(str(GPSD_CORPUS))]):
        judge_sentences(path.read_bytes(), tally)
    valid = tally.of("standard-valid")
    assert valid > 2000
    assert tally.of("agree") >= 0.99 * valid, tally.examples


# --------------------------------------------------------------------------- streams

NOISE = st.sampled_from([b"\x00\xff garbage", b"$GPGGA,1", b"\r\n", b"\xb5\x62\x01\x07",
                         b"$GPZDA,1*00\r\n", b"*", b"$"])


@settings(max_examples=100, deadline=None)
@given(st.lists(st.one_of(st.sampled_from(CORPUS_LINES), NOISE), max_size=40), st.data())
def test_chunked_and_line_by_line_feeding_agree(pieces: list[bytes], data: st.DataObject) -> None:
    stream = b"".join(pieces)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=30)))
    feedings = ([stream], [stream[a:b] for a, b in zip([0, *cuts], [*cuts, len(stream)],
                                                        strict=True)],
                stream.splitlines(keepends=True))
    results = []
    for feeding in feedings:
        decoder = NmeaStreamDecoder()
        out = [item for piece in feeding for item in decoder.feed(piece)] + decoder.finish()
        results.append((out, decoder.stats))
    assert results[0] == results[1] == results[2]
    good = [p for p in pieces if p in CORPUS_LINES]
    assert len(results[0][0]) >= len(good) - sum(p in (b"$GPGGA,1", b"$") for p in pieces)


def _without_checksum(raw: bytes) -> bytes:
    return raw[:raw.rindex(b"*")] + b"\r\n"


def test_a_sentence_without_checksum_is_refused_and_counted_unless_accepted() -> None:
    raw = _without_checksum(CORPUS_LINES[0])
    with pytest.raises(DecodeError) as err:
        decode_sentence(raw)
    assert getattr(err.value, "reason", None) == Refusal.NO_CHECKSUM
    assert decode_sentence(raw, accept_missing_checksum=True) == decode_sentence(CORPUS_LINES[0])
    strict, lenient = NmeaStreamDecoder(), NmeaStreamDecoder(accept_missing_checksum=True)
    assert strict.feed(raw + CORPUS_LINES[1])[0].raw == CORPUS_LINES[1]
    assert strict.stats.refused == {Refusal.NO_CHECKSUM: 1}
    assert strict.stats.framing_errors == 1
    assert [d.raw for d in lenient.feed(raw + CORPUS_LINES[1])] == [raw, CORPUS_LINES[1]]
    assert lenient.stats.errors == 0


def test_every_refusal_is_counted_by_its_reason() -> None:
    good = CORPUS_LINES[0]
    bad_sum = good.replace(good[-4:-2], b"%02X" % (int(good[-4:-2], 16) ^ 1))
    fields = b"GPGGA,1"
    cases = {
        Refusal.CHECKSUM: bad_sum,
        Refusal.NO_CHECKSUM: _without_checksum(good),
        Refusal.MALFORMED: b"$GPGGA,1*4\r\n",
        Refusal.FIELD_COUNT: b"$%s*%02X\r\n" % (fields, checksum(fields)),
        Refusal.FIELD_VALUE: b"$GPZDA,251530.00,04,07,2002,,*%02X\r\n" % checksum(
            b"GPZDA,251530.00,04,07,2002,,"),
        Refusal.CUT_SHORT: good[:20],
        Refusal.TOO_LONG: b"$GPGGA," + b"9" * 200 + b"\r\n",
        "junk": b"\x00garbage\r\n",
    }
    decoder = NmeaStreamDecoder()
    out = decoder.feed(b"".join(raw + good for raw in cases.values()))
    assert len(out) == len(cases)
    assert decoder.stats.refused == dict.fromkeys(cases, 1)
    assert decoder.stats.errors == len(cases)


# --------------------------------------------------------------------------- acquisition


def _acquire(data: bytes, *, accept_missing_checksum: bool = False) -> list[object]:
    config = dataclasses.replace(acquisition_config(load_scenario("bench")),
                                 accept_nmea_without_checksum=accept_missing_checksum)
    logged: list[object] = []
    acq = Acquisition(config, lambda m, _t: logged.append(m), lambda _e: None)
    acq.on_gps_bytes(1_000, data)
    acq.finish(2 * NS_PER_S)
    return logged


def _second(k: int, talker: str = "GP") -> list[bytes]:
    t = T0 + k * NS_PER_S
    gga = gga_from_fix(t, LEAP_S, 41.6, 2.0, 500.0, 50.0, FixQuality.RTK_FIXED, 12, 0.8)
    rmc = rmc_from_fix(t, LEAP_S, 41.6, 2.0, 60.0, 10.0, ModeIndicator.RTK_FIXED)
    zda = zda_from_gps_ns(t, LEAP_S)
    return [encode(dataclasses.replace(m, talker=talker), NmeaVersion.V4_11)
            for m in (zda, rmc, gga)]


def _fixes(logged: list[object]) -> list[GpsFix]:
    return [m for m in logged if isinstance(m, GpsFix)]


@pytest.mark.parametrize("talker", ["GN", "GL", "GA", "GB", "BD", "GQ"])
def test_a_fix_from_any_talker_is_logged_as_from_gp(talker: str) -> None:
    gp = _fixes(_acquire(b"".join(_second(0) + _second(1))))
    other = _fixes(_acquire(b"".join(_second(0, talker) + _second(1, talker))))
    assert len(gp) == 2
    assert other == gp


def _gns(gga_raw: bytes) -> bytes:
    gga = decode_sentence(gga_raw)
    assert isinstance(gga, Gga)
    gns = Gns(gga.utc_time_of_day_ns, gga.lat_deg, gga.lon_deg,
              (ModeIndicator.RTK_FIXED, ModeIndicator.RTK_FLOAT), gga.satellites, gga.hdop,
              gga.altitude_msl_m, gga.geoid_separation_m)
    return encode(gns)


def test_a_receiver_that_sends_gns_and_no_gga_gives_the_same_fixes() -> None:
    seconds = [_second(0), _second(1)]
    with_gga = _fixes(_acquire(b"".join(s for second in seconds for s in second)))
    with_gns = _fixes(_acquire(b"".join(zda + rmc + _gns(gga) for zda, rmc, gga in seconds)))
    assert with_gns == with_gga
    both = _fixes(_acquire(b"".join(zda + rmc + gga + _gns(gga) for zda, rmc, gga in seconds)))
    assert both == with_gga  # GNS ignored beside GGA: one fix an epoch


def test_a_no_fix_gga_with_an_empty_time_logs_no_fix() -> None:
    nofix = b"$GPGGA,,,,,,0,00,99.99,,,,,,*48\r\n"
    assert decode_sentence(nofix) == Gga(None, None, None, FixQuality.INVALID, 0, 99.99, None,
                                         None)
    assert _fixes(_acquire(b"".join(_second(0)[:2]) + nofix)) == []


def test_refusals_reach_the_health_channel_by_reason() -> None:
    zda, rmc, gga = _second(0)
    logged = _acquire(zda + rmc + _without_checksum(gga) + gga[:30] + b"\x00\x01" + gga)
    (gps,) = [m for m in logged if isinstance(m, StreamHealth) and m.stream == "gps"]
    assert dict(zip(gps.refused_reasons, gps.refused_counts, strict=True)) == {
        Refusal.NO_CHECKSUM: 1, Refusal.CUT_SHORT: 1}
    assert gps.framing_errors == 2
    assert len(_fixes(logged)) == 1
    accepted = _acquire(zda + rmc + _without_checksum(gga), accept_missing_checksum=True)
    assert len(_fixes(accepted)) == 1


def test_the_policy_raise_names_the_reason() -> None:
    decoder = NmeaStreamDecoder(ErrorPolicy.RAISE)
    with pytest.raises(DecodeError) as err:
        decoder.feed(_without_checksum(CORPUS_LINES[3]))
    assert getattr(err.value, "reason", None) == Refusal.NO_CHECKSUM
    assert err.value.offset == 0


def _sentence(body: str) -> bytes:
    return b"$%s*%02X\r\n" % (body.encode(), checksum(body.encode()))


def _gga(clock: str) -> bytes:
    return _sentence(f"GPGGA,{clock},4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,")


def test_fixes_keep_their_day_across_midnight_when_the_date_runs_ahead_or_behind() -> None:
    """A receiver whose ZDA runs a second ahead of its GGA (gpsd's ac12 log) gives the next
    day's date before the day's last GGA; a receiver without ZDA gives none until its next
    RMC. Each fix keeps its own day (the last date + a day when the fix fell 12 h before the
    last one logged the first case a day late, and every fix after it)."""
    data = b"".join([
        _sentence("GPZDA,235959.00,31,12,2025,00,00"), _gga("235958.00"),
        _sentence("GPZDA,000000.00,01,01,2026,00,00"), _gga("235959.00"),
        _sentence("GPZDA,000001.00,01,01,2026,00,00"), _gga("000000.00"),
        _gga("000001.00"),  # no ZDA before it
    ])
    first = parse_gps_datetime("2025-12-31T23:59:58") + LEAP_S * NS_PER_S
    assert [f.t_gps_ns for f in _fixes(_acquire(data))] == [first + k * NS_PER_S
                                                            for k in range(4)]
    rmc_dated = _sentence("GPRMC,235959.00,A,4807.038,N,01131.000,E,0.0,0.0,311225,,,A")
    late = _fixes(_acquire(rmc_dated + _gga("235959.00") + _gga("000000.00")))
    assert [f.t_gps_ns for f in late] == [first + NS_PER_S, first + 2 * NS_PER_S]
