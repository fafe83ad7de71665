"""NovAtel OEM7 ASCII logs: the CRC-32 against logs printed in NovAtel's public OEM7 reference,
against a bit-by-bit implementation and zlib; MARK1TIME, TIME and BESTPOS declared as field
lists, written and read back; a stream of NMEA and NovAtel logs interleaved, damaged, cut
anywhere, that loses no good message and counts what it lost; the acquisition's time tags and
fixes from NovAtel logs."""

from __future__ import annotations

import dataclasses
import math
import zlib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acquisition.codec import ErrorPolicy
from acquisition.novatel import (
    LOG_SPECS,
    BestPos,
    ClockStatus,
    LogHeader,
    MarkTime,
    NmeaNovatelStreamDecoder,
    NovatelRefusal,
    PositionType,
    SolutionStatus,
    TimeLog,
    TimeStatus,
    UnknownLog,
    crc32_novatel,
    crc32_reference,
    decode_log,
    encode_frame,
    encode_log,
    first_novatel_log,
    header_from_gps_ns,
    mark1time_from_gps_ns,
    time_for_pps,
)
from acquisition.novatel.logs import LogSpec
from acquisition.proof import first_gps_message
from acquisition.runner import Acquisition
from emulators.scenario import load_scenario
from recorder.messages import GpsFix, GpsTimeTag
from sisa.core.errors import DecodeError, EncodeError
from sisa.core.timescale import NS_PER_S, NS_PER_WEEK, parse_gps_datetime
from sisa.wiring.acqconfig import acquisition_config
from tests.acquisition.corpus import nmea_0183
from tests.acquisition.damaged_streams import (
    MessageKind,
    check_decoding,
    damaged_streams,
    nmea_kind,
)

T0 = parse_gps_datetime("2026-06-15T09:00:00")
SENTENCES = nmea_0183.CORPUS.read_bytes().splitlines(keepends=True)[::7]

# Logs printed in NovAtel's public OEM7 Commands and Logs reference (docs.novatel.com/OEM7), as
# examples of the TIME log (Logs/TIME.htm) and of BESTGNSSPOS (SPAN_Logs/BESTGNSSPOS.htm, the
# same fields as BESTPOS); their CRCs are as printed. (The MARK1TIME page's example,
# #MARK1TIMEA,COM1,0,77.5,...*d8502226, does not check: its printed CRC is not that of its
# printed text, which was evidently edited after it was logged; it is not used.)
PUBLISHED_TIME = (
    b"#TIMEA,USB1,0,50.5,FINESTEERING,2209,515163.000,02000020,9924,16809;VALID,"
    b"-2.501488425e-09,6.133312031e-10,-17.99999999630,2022,5,13,23,5,45000,VALID*1100ad64\r\n")
PUBLISHED_BESTGNSSPOS = (
    b"#BESTGNSSPOSA,USB1,0,65.0,FINESTEERING,2209,487877.000,02000020,c292,16809;"
    b"SOL_COMPUTED,PPP,51.15043712234,-114.03067870773,1097.3556,-17.0001,WGS84,0.0176,0.0123,"
    b'0.0317,"TSTR",17.000,0.000,42,38,38,37,00,00,3f,37*5fea7d4b\r\n')


def _body(raw: bytes) -> bytes:
    return raw[1:raw.index(b"*")]


@pytest.mark.parametrize("raw", [PUBLISHED_TIME, PUBLISHED_BESTGNSSPOS])
def test_the_crc_of_logs_published_by_novatel(raw: bytes) -> None:
    printed = int(raw[raw.index(b"*") + 1:raw.index(b"*") + 9], 16)
    assert crc32_novatel(_body(raw)) == crc32_reference(_body(raw)) == printed
    # zlib's CRC-32 is the same register, inverted at start and end
    assert crc32_novatel(_body(raw)) == zlib.crc32(_body(raw), 0xFFFFFFFF) ^ 0xFFFFFFFF


@given(st.binary(max_size=300))
def test_the_crc_is_the_bit_by_bit_reference(data: bytes) -> None:
    assert crc32_novatel(data) == crc32_reference(data)


def test_the_published_time_log_decodes_and_is_written_back_byte_for_byte() -> None:
    log = decode_log(PUBLISHED_TIME)
    assert isinstance(log, TimeLog)
    assert log.header == LogHeader("TIME", "USB1", 0, 50.5, TimeStatus.FINESTEERING, 2209,
                                   515_163 * NS_PER_S, 0x02000020, 0x9924, 16809)
    assert (log.clock_status, log.utc_year, log.utc_month, log.utc_day, log.utc_hour,
            log.utc_minute, log.utc_ms) == (ClockStatus.VALID, 2022, 5, 13, 23, 5, 45_000)
    assert log.offset_s == -2.501488425e-09
    assert encode_log(log) == PUBLISHED_TIME
    # the UTC it states is the header's GPS time less 18 leap seconds, as ours is
    ours = time_for_pps(log.header.gps_ns, 6e-10, 18)
    assert (ours.utc_year, ours.utc_month, ours.utc_day, ours.utc_hour, ours.utc_minute,
            ours.utc_ms) == (2022, 5, 13, 23, 5, 45_000)


def test_bestpos_reads_the_published_fields() -> None:
    body = _body(PUBLISHED_BESTGNSSPOS).replace(b"BESTGNSSPOSA", b"BESTPOSA")
    raw = b"#" + body + b"*" + f"{crc32_novatel(body):08x}".encode() + b"\r\n"
    log = decode_log(raw)
    assert isinstance(log, BestPos)
    assert (log.solution_status, log.position_type, log.datum, log.station_id) == (
        SolutionStatus.SOL_COMPUTED, PositionType.PPP, "WGS84", "TSTR")
    assert (log.lat_deg, log.lon_deg, log.height_msl_m, log.undulation_m) == (
        51.15043712234, -114.03067870773, 1097.3556, -17.0001)
    assert math.isclose(log.height_ellipsoidal_m, 1080.3555)
    assert (log.svs_tracked, log.svs_used, log.galileo_beidou_mask, log.gps_glonass_mask) == (
        42, 38, 0x3F, 0x37)
    assert encode_log(log) == raw
    # a log we have no field list for is kept, with its fields
    unknown = decode_log(PUBLISHED_BESTGNSSPOS)
    assert isinstance(unknown, UnknownLog)
    assert unknown.header.name == "BESTGNSSPOS"
    assert encode_log(unknown) == PUBLISHED_BESTGNSSPOS


@pytest.mark.parametrize("spec", LOG_SPECS, ids=lambda s: s.name)
def test_every_field_list_names_exactly_its_dataclass_fields(spec: LogSpec[object]) -> None:
    assert ["header", *(name for name, _ in spec.fields)] == [
        f.name for f in dataclasses.fields(spec.build)]  # type: ignore[arg-type]


TIMES = st.integers(0, parse_gps_datetime("2079-12-31T00:00:00"))


@given(TIMES, st.integers(0, 10_000))
def test_marks_and_pulses_give_back_their_instants(t_gps_ns: int, std_ns: int) -> None:
    mark = decode_log(encode_log(mark1time_from_gps_ns(t_gps_ns, std_ns * 1e-9, 18)))
    assert isinstance(mark, MarkTime)
    assert mark.gps_ns == t_gps_ns  # 9 decimals: every ns
    assert mark.header.gps_ns == (t_gps_ns + 500_000) // 1_000_000 * 1_000_000
    second = t_gps_ns // NS_PER_S * NS_PER_S
    pulse = decode_log(encode_log(time_for_pps(second, 1e-8, 18)))
    assert isinstance(pulse, TimeLog)
    assert pulse.pps_gps_ns == second


def _bestpos(t_gps_ns: int, lat: float, lon: float, h: float) -> BestPos:
    return BestPos(header_from_gps_ns("BESTPOS", t_gps_ns), SolutionStatus.SOL_COMPUTED,
                   PositionType.NARROW_INT, lat, lon, h, 50.0, "WGS84", 0.03, 0.03, 0.05, "0",
                   1.0, 0.0, 12, 9, 9, 9, 0, 0, 0, 0x33)


@given(TIMES, st.floats(-90, 90), st.floats(-180, 180), st.floats(-500, 9000))
def test_bestpos_round_trips_to_its_decimals(t: int, lat: float, lon: float, h: float) -> None:
    log = decode_log(encode_log(_bestpos(t, lat, lon, h)))
    assert isinstance(log, BestPos)
    assert abs(log.lat_deg - lat) <= 0.5e-11 + 1e-13
    assert abs(log.lon_deg - lon) <= 0.6e-11
    assert abs(log.height_msl_m - h) <= 0.5e-4 + 1e-9
    assert encode_log(log) == encode_log(_bestpos(t, lat, lon, h))


def test_bad_values_are_refused_both_ways_by_reason() -> None:
    with pytest.raises(EncodeError):
        encode_log(dataclasses.replace(_bestpos(T0, 1, 2, 3), svs_used=300))
    with pytest.raises(EncodeError):
        encode_log(dataclasses.replace(_bestpos(T0, 1, 2, 3), station_id='a"b'))

    def reason(raw: bytes) -> str:
        with pytest.raises(DecodeError) as err:
            decode_log(raw)
        return str(getattr(err.value, "reason", ""))

    good = encode_log(mark1time_from_gps_ns(T0, 2e-8, 18))
    flipped = good.replace(b"VALID", b"VALIE")
    assert reason(flipped) == NovatelRefusal.CRC

    def resealed(body: bytes) -> bytes:
        return b"#" + body + b"*" + f"{crc32_novatel(body):08x}".encode() + b"\r\n"

    assert reason(resealed(_body(good).replace(b"VALID", b"VALIE"))) == \
        NovatelRefusal.FIELD_VALUE
    assert reason(resealed(_body(good) + b",1")) == NovatelRefusal.FIELD_COUNT
    week_seconds = _body(good).split(b";")[1].split(b",")[1]
    assert reason(resealed(_body(good).replace(week_seconds, b"604800.000000000"))) == \
        NovatelRefusal.FIELD_VALUE
    assert reason(resealed(_body(good).replace(b";", b","))) == NovatelRefusal.MALFORMED
    # numbers as a receiver writes them: no nan, inf, spaces, signs or underscores Python takes
    for old, new in ((b",-18.000000000,", b",nan,"), (b",-18.000000000,", b",-1_8.0,"),
                     (b";2423,", b"; 2423,"),
                     (b",80.0,", b",inf,"), (b",80.0,", b",180.0,"), (b",0,80", b",+0,80")):
        assert old in _body(good)
        assert reason(resealed(_body(good).replace(old, new, 1))) == \
            NovatelRefusal.FIELD_VALUE, new
    assert reason(good[:-12] + b"\r\n") == NovatelRefusal.MALFORMED


def test_a_port_proves_itself_by_a_log_whose_crc_holds() -> None:
    good = encode_log(time_for_pps(T0, 1e-8, 18))
    bad = good.replace(b"VALID", b"VALIE")
    assert first_novatel_log(b"#junk*12345678\r\n" + bad + good) == 16 + len(bad)
    assert first_novatel_log(bad) == -1
    assert first_gps_message(b"noise" + good) == 5


# --------------------------------------------------------------------------- mixed streams

LOGS = st.one_of(
    st.builds(lambda t: mark1time_from_gps_ns(t, 2e-8, 18), TIMES),
    st.builds(lambda t: time_for_pps(t // NS_PER_S * NS_PER_S, 1e-8, 18), TIMES),
    st.builds(_bestpos, TIMES, st.floats(-90, 90), st.floats(-180, 180), st.floats(-500, 9000)),
)


MIXED = damaged_streams([nmea_kind(SENTENCES, b"$#*"), MessageKind(
    LOGS.map(encode_log), lambda raw: (1, raw.index(b"*") - 1),
    st.integers(0x20, 0x7E).filter(lambda b: b not in b"$#*"))], tail=SENTENCES[0])


@settings(max_examples=300, deadline=None)
@given(MIXED, st.integers(1, 64))
def test_a_damaged_mixed_stream_loses_no_good_message_and_says_how_many_it_lost(
        case: tuple[bytes, list[bytes], int], chunk: int) -> None:
    decoder = NmeaNovatelStreamDecoder()
    check_decoding(decoder, case, chunk)
    assert decoder.stats.errors == sum(decoder.stats.refused.values())


def test_a_log_after_a_sentence_cut_short_and_a_sentence_after_a_log_cut_short() -> None:
    sentence, log = SENTENCES[1], encode_log(mark1time_from_gps_ns(T0 + 123, 2e-8, 18))
    decoder = NmeaNovatelStreamDecoder(ErrorPolicy.COUNT)
    out = decoder.feed(sentence[:30] + log + log[:40] + sentence + b"\x00\xffjunk" + log)
    assert [d.raw for d in out] == [log, sentence, log]
    assert decoder.stats.refused == {"nmea.cut_short": 1, NovatelRefusal.CUT_SHORT: 1,
                                     "junk": 1}
    assert decoder.stats.by_kind["MARK1TIMEA"] == 2


def test_a_corrupted_log_is_one_checksum_error_and_a_line_without_end_is_bounded() -> None:
    log = bytearray(encode_log(time_for_pps(T0, 1e-8, 18)))
    log[40] ^= 0x01
    decoder = NmeaNovatelStreamDecoder()
    out = decoder.feed(bytes(log) + SENTENCES[2])
    assert [d.raw for d in out] == [SENTENCES[2]]
    assert decoder.stats.refused == {NovatelRefusal.CRC: 1}
    assert decoder.stats.checksum_errors == 1
    decoder = NmeaNovatelStreamDecoder()
    decoder.feed(b"#" + b"A" * 10_000)
    assert decoder.buffered_bytes < 4096
    assert decoder.stats.refused == {NovatelRefusal.TOO_LONG: 1}


def test_encoding_refuses_what_would_break_the_frame() -> None:
    with pytest.raises(EncodeError):
        encode_frame(LogHeader("TIME"), ["a#b"])
    with pytest.raises(EncodeError):
        encode_frame(LogHeader("TIME", week=70_000), [])


# --------------------------------------------------------------------------- acquisition


def test_the_acquisition_makes_time_tags_and_fixes_of_novatel_logs() -> None:
    config = dataclasses.replace(acquisition_config(load_scenario("bench")), gps_novatel=True)
    logged: list[object] = []
    acq = Acquisition(config, lambda m, _t: logged.append(m), lambda _e: None)
    second = T0 // NS_PER_S * NS_PER_S
    event = second + 123_456_700
    coarse = dataclasses.replace(
        mark1time_from_gps_ns(event + 5, 2e-8, 18),
        header=dataclasses.replace(header_from_gps_ns("MARK1TIME", event),
                                   time_status=TimeStatus.COARSE))
    unsure = dataclasses.replace(mark1time_from_gps_ns(event + 7, 2e-8, 18),
                                 status=ClockStatus.CONVERGING)
    fix = _bestpos(second, 41.5, 2.25, 300.0)
    lost = dataclasses.replace(fix, header=header_from_gps_ns("BESTPOS", second + NS_PER_S),
                               solution_status=SolutionStatus.INSUFFICIENT_OBS,
                               position_type=PositionType.NONE)
    acq.on_gps_bytes(1_000, b"".join(encode_log(m) for m in (
        time_for_pps(second, 1e-8, 18), mark1time_from_gps_ns(event, 2e-8, 18), coarse, unsure,
        fix, lost)))
    tags = [m for m in logged if isinstance(m, GpsTimeTag)]
    assert tags == [GpsTimeTag(1_000, "PTT", second % NS_PER_WEEK, second),
                    GpsTimeTag(1_000, "TTT", event % NS_PER_WEEK, event)]
    assert acq.last_pps_gps_ns == second
    fixes = [m for m in logged if isinstance(m, GpsFix)]
    assert [(f.t_gps_ns, f.quality, f.satellites) for f in fixes] == [
        (second, 4, 9), (second + NS_PER_S, 0, 9)]
    assert (fixes[0].lat_deg, fixes[0].lon_deg, fixes[0].height_m) == (41.5, 2.25, 350.0)
    assert math.isnan(fixes[0].hdop)
