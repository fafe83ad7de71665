"""NMEA/Ashtech codec: hand-worked checksums, round trips at ±1 LSB, pynmeagps as an independent
parser, and a streaming decoder that resynchronises and counts exactly what it drops."""

import dataclasses
import datetime as dt

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pynmeagps import VALCKSUM, VALMSGID, NMEAReader
from pynmeagps.nmeahelpers import calc_checksum

from acquisition.codec import ErrorPolicy
from acquisition.nmea import (
    MAX_SENTENCE_BYTES,
    SPECS,
    Blankable,
    ChecksumError,
    EncodeError,
    FixQuality,
    Gga,
    Gns,
    Gst,
    ModeIndicator,
    NavStatus,
    NmeaStreamDecoder,
    NmeaVersion,
    PashrPtt,
    PashrTtt,
    Rmc,
    RmcStatus,
    SentenceKind,
    Talker,
    Unit,
    UnknownSentence,
    Zda,
    checksum,
    decode_sentence,
    encode,
    gga_from_fix,
    gps_ns_from_time_of_week,
    gps_ns_from_utc,
    gps_ns_from_utc_time_of_day,
    ptt_from_gps_ns,
    rmc_from_fix,
    ttt_from_gps_ns,
    zda_from_gps_ns,
)
from sisa.core.errors import DecodeError
from sisa.core.timescale import NS_PER_DAY, NS_PER_S, NS_PER_WEEK, parse_gps_datetime
from tests.acquisition.nmea_oracle import disagreements, pynmeagps_read

LEAP_1998_S = 12
FLIGHT = parse_gps_datetime("1998-07-23T08:15:30")
UTC_LSB_NS = 10_000_000
TAG_LSB_NS = 100
SPEC_OF = {spec.build: spec for spec in SPECS}


def _round(t_ns, step):
    return (t_ns + step // 2) // step * step


# --------------------------------------------------------------------------- strategies

lat = st.floats(-90.0, 90.0, allow_nan=False)
lon = st.floats(-180.0, 180.0, allow_nan=False)
utc_tod = st.integers(0, NS_PER_DAY - UTC_LSB_NS // 2 - 1)  # does not round up to 24:00
tow = st.integers(0, NS_PER_WEEK - TAG_LSB_NS // 2 - 1)
dates = st.dates(dt.date(1980, 1, 6), dt.date(2079, 12, 31))

talkers = st.sampled_from(Talker) | st.from_regex(r"[A-OQ-Z][A-Z0-9]", fullmatch=True)
ggas = st.builds(
    Gga, st.none() | utc_tod, st.none() | lat, st.none() | lon,
    st.none() | st.sampled_from(FixQuality), st.none() | st.integers(0, 99),
    st.none() | st.floats(0.0, 99.9), st.none() | st.floats(-9999.0, 99999.0),
    st.none() | st.floats(-999.0, 999.0), st.none() | st.floats(0.0, 999.9),
    st.none() | st.integers(0, 1023), talkers,
)
rmcs = st.builds(
    Rmc, st.none() | utc_tod, st.none() | st.sampled_from(RmcStatus), st.none() | lat,
    st.none() | lon, st.none() | st.floats(0.0, 5000.0),
    st.none() | st.floats(0.0, 360.0, exclude_max=True), st.none() | dates,
    magnetic_variation_deg=st.none() | st.floats(-180.0, 180.0),
    mode=st.none() | st.sampled_from(ModeIndicator),
    nav_status=st.none() | st.sampled_from(NavStatus), talker=talkers,
)
zdas = st.builds(Zda, st.none() | utc_tod, st.none() | dates, st.none() | st.integers(-13, 13),
                 st.none() | st.integers(0, 59), talkers)
sigmas = st.none() | st.floats(0.0, 99_999.0)
gnss = st.builds(
    Gns, st.none() | utc_tod, st.none() | lat, st.none() | lon,
    st.none() | st.lists(st.sampled_from(ModeIndicator), min_size=1, max_size=6).map(tuple),
    st.none() | st.integers(0, 99), st.none() | st.floats(0.0, 99.9),
    st.none() | st.floats(-9999.0, 99999.0), st.none() | st.floats(-999.0, 999.0),
    st.none() | st.floats(0.0, 999.9), st.none() | st.integers(0, 1023),
    st.none() | st.sampled_from(NavStatus), talkers,
)
gsts = st.builds(Gst, st.none() | utc_tod, sigmas, sigmas, sigmas,
                 st.none() | st.floats(0.0, 360.0, exclude_max=True), sigmas, sigmas, sigmas,
                 talkers)
ptts = st.builds(PashrPtt, tow)
ttts = st.builds(PashrTtt, tow)
messages = st.one_of(ggas, rmcs, zdas, gnss, gsts, ptts, ttts)
gps_instants = st.integers(0, parse_gps_datetime("2079-12-31T00:00:00"))

SAMPLES = [
    gga_from_fix(FLIGHT, LEAP_1998_S, 41.9794, 2.8214, 2380.123, 49.871, FixQuality.RTK_FIXED,
                 8, 1.1, dgps_age_s=1.0, dgps_station=17),
    gga_from_fix(FLIGHT, LEAP_1998_S, -33.85, -151.21, 12.5, -3.25, FixQuality.GPS, 5, 2.3),
    rmc_from_fix(FLIGHT, LEAP_1998_S, 41.9794, 2.8214, 73.06, 123.45, ModeIndicator.DIFFERENTIAL),
    rmc_from_fix(FLIGHT, LEAP_1998_S, -0.5, -179.5, 118.3, 0.5),
    zda_from_gps_ns(FLIGHT, LEAP_1998_S),
    Zda(12 * 3600 * NS_PER_S, dt.date(2024, 2, 29), -5, 30),
    ptt_from_gps_ns(FLIGHT),
    ttt_from_gps_ns(FLIGHT + 123_456_700),
]


def _wire_of(field):
    return field.wire.inner if isinstance(field.wire, Blankable) else field.wire


def _assert_within_half_lsb(sent, got):
    """Every field equal, except scaled ones: within half an LSB (modulo 360 for angles)."""
    assert type(got) is type(sent)
    assert getattr(got, "talker", None) == getattr(sent, "talker", None)
    for field in SPEC_OF[type(sent)].fields:
        a, b = getattr(sent, field.name), getattr(got, field.name)
        lsb = field.wire.resolution
        if lsb is None or a is None:
            assert a == b, field.name
            continue
        diff = b - a
        modulus = getattr(_wire_of(field), "modulus", None)
        if modulus is not None:
            diff = (diff + modulus / 2) % modulus - modulus / 2
        assert abs(diff) <= lsb / 2 * (1 + 1e-9) + 1e-12, (field.name, a, b)


# --------------------------------------------------------------------------- the tables


@pytest.mark.parametrize("spec", SPECS, ids=lambda s: s.kind.value)
def test_every_table_names_exactly_its_dataclass_fields(spec):
    talker = [] if spec.proprietary else ["talker"]  # a standard sentence's, from its address
    assert [f.name for f in spec.fields] + talker == [
        f.name for f in dataclasses.fields(spec.build)]


SUFFIX_UNITS = {"_ns": Unit.NANOSECOND, "_deg": Unit.DEGREE, "_m_s": Unit.METRE_PER_SECOND,
                "_m": Unit.METRE, "_s": Unit.SECOND}


@pytest.mark.parametrize("spec", SPECS, ids=lambda s: s.kind.value)
def test_unit_in_the_table_matches_the_unit_in_the_name(spec):
    for field in spec.fields:
        suffix = next((s for s in SUFFIX_UNITS if field.name.endswith(s)), None)
        assert field.unit == SUFFIX_UNITS.get(suffix, field.unit), field.name
        if field.wire.resolution is not None and field.unit is not Unit.NONE:
            assert suffix is not None, f"scaled field {field.name} has no unit in its name"


def test_longest_sentences_fit_the_stream_cap():
    widest = Gga(NS_PER_DAY - UTC_LSB_NS, -89.9999999, -179.9999999, FixQuality.RTK_FLOAT, 99,
                 99.9, 99_999.999, -999.999, 999.9, 1023)
    assert len(encode(widest)) <= MAX_SENTENCE_BYTES
    assert len(encode(widest)) > 82  # beyond NMEA's 82: why the cap is larger


# --------------------------------------------------------------------------- checksums by hand


def test_checksum_hand_worked_ttt_at_the_gps_epoch():
    # PASHR,TTT,1,00:00:00.0000000: pairs cancel in an XOR, leaving one each of
    # P A S H R T , 1 0 .  (three T, three commas, thirteen 0, two colons):
    # 50^41=11, ^53=42, ^48=0A, ^52=58, ^54=0C, ^2C=20, ^31=11, ^30=21, ^2E=0F.
    assert checksum(b"PASHR,TTT,1,00:00:00.0000000") == 0x0F
    assert encode(ttt_from_gps_ns(0)) == b"$PASHR,TTT,1,00:00:00.0000000*0F\r\n"


def test_checksum_of_the_textbook_gga_and_rmc():
    # The examples printed in most NMEA references, with their published checksums.
    assert checksum(b"GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,") == 0x47
    assert checksum(b"GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W") == 0x6A


def test_textbook_gga_decodes():
    gga = decode_sentence(b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n")
    assert gga == Gga(((12 * 60 + 35) * 60 + 19) * NS_PER_S, pytest.approx(48 + 7.038 / 60),
                      pytest.approx(11 + 31 / 60), FixQuality.GPS, 8, 0.9, 545.4, 46.9)


def test_textbook_rmc_of_nmea_2_0_with_magnetic_variation_and_no_mode():
    rmc = decode_sentence(
        b"$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A\r\n")
    assert rmc == Rmc(((12 * 60 + 35) * 60 + 19) * NS_PER_S, RmcStatus.ACTIVE,
                      pytest.approx(48 + 7.038 / 60), pytest.approx(11 + 31 / 60),
                      pytest.approx(22.4 * 1852 / 3600), 84.4, dt.date(1994, 3, 23),
                      magnetic_variation_deg=-3.1, mode=None, nav_status=None)


def _sentence(body: str) -> bytes:
    return b"$%s*%02X\r\n" % (body.encode(), checksum(body.encode()))


@pytest.mark.parametrize(("body", "lat"), [
    ("GPRMC,212632.000,A,4839.9411,N,00214.9065,E,0.00,,181207,0,A", 48 + 39.9411 / 60),  # SiRF
    ("GPRMC,130722.00,A,5012.792600,N,00806.879600,W,0.5,2.5,010611,,A", 50 + 12.7926 / 60),
])
def test_an_rmc_with_a_mode_letter_where_the_variation_direction_belongs_keeps_the_rest(
        body, lat):
    """SiRF III and Saab R4 write RMC's 11 fields with 2.3's mode where the variation's E/W
    belongs: the variation is null, date, time and position are read (gpsd reads them too;
    refused, they left every GGA of such a receiver without a date)."""
    rmc = decode_sentence(_sentence(body))
    assert isinstance(rmc, Rmc)
    assert rmc.magnetic_variation_deg is None
    assert rmc.mode is None
    assert rmc.utc_date is not None
    assert rmc.lat_deg == pytest.approx(lat)
    with pytest.raises(DecodeError):  # a variation without its sign letter: which sign?
        decode_sentence(_sentence("GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,"
                                  "003.1,"))


@pytest.mark.parametrize("message", SAMPLES, ids=lambda m: type(m).__name__)
def test_every_sentence_is_framed_with_a_checksum_and_crlf(message):
    raw = encode(message)
    assert raw.startswith(b"$")
    assert raw.endswith(b"\r\n")
    body, digits = raw[1:-2].split(b"*")
    assert int(digits, 16) == checksum(body)
    assert digits == calc_checksum(body.decode()).encode()  # pynmeagps's own helper agrees


# --------------------------------------------------------------------------- round trips


@settings(max_examples=300)
@given(messages)
def test_round_trip_within_half_an_lsb(message):
    raw = encode(message, NmeaVersion.V4_11)
    back = decode_sentence(raw)
    _assert_within_half_lsb(message, back)
    assert encode(back, NmeaVersion.V4_11) == raw


def _lsb_cases():
    for sample in SAMPLES:
        for field in SPEC_OF[type(sample)].fields:
            if field.wire.resolution is not None and getattr(sample, field.name) is not None:
                yield pytest.param(sample, field, id=f"{type(sample).__name__}.{field.name}")


@pytest.mark.parametrize(("sample", "field"), list(_lsb_cases()))
@pytest.mark.parametrize(("offset_lsb", "expect_lsb"),
                         [(0, 0), (1, 1), (-1, -1), (0.4, 0), (0.6, 1), (-0.4, 0), (-0.6, -1)])
def test_every_scaled_field_rounds_to_the_nearest_lsb(sample, field, offset_lsb, expect_lsb):
    value = getattr(sample, field.name)
    if isinstance(value, int):  # ns times: exact integers
        lsb = int(field.wire.resolution)
        centre = value // lsb * lsb
        expected = centre + expect_lsb * lsb
        value = centre + int(offset_lsb * lsb)
    else:
        lsb = field.wire.resolution
        centre = round(value / lsb) * lsb
        expected = pytest.approx(centre + expect_lsb * lsb, abs=lsb * 1e-3)
        value = centre + offset_lsb * lsb
    back = decode_sentence(encode(dataclasses.replace(sample, **{field.name: value})))
    assert getattr(back, field.name) == expected


@given(lat, lon)
def test_lat_lon_signs_and_hemispheres(lat_deg, lon_deg):
    raw = encode(gga_from_fix(FLIGHT, LEAP_1998_S, lat_deg, lon_deg, 100.0, 50.0,
                              FixQuality.GPS, 6, 1.0))
    back, fields = decode_sentence(raw), raw.split(b",")
    assert fields[3] == (b"S" if back.lat_deg < 0 else b"N")
    assert fields[5] == (b"W" if back.lon_deg < 0 else b"E")
    assert back.lat_deg * lat_deg >= 0
    assert back.lon_deg * lon_deg >= 0


def test_longitude_near_the_antimeridian():
    for lon_deg, text in [(179.9999999999, b"18000.0000000,E"), (-180.0, b"18000.0000000,W"),
                          (-179.9999999, b"17959.9999940,W")]:
        raw = encode(rmc_from_fix(FLIGHT, LEAP_1998_S, 0.0, lon_deg, 50.0, 90.0))
        assert text in raw
        assert decode_sentence(raw).lon_deg == pytest.approx(lon_deg, abs=1e-9)


@pytest.mark.parametrize("bad", [
    {"lat_deg": 90.0000001}, {"lon_deg": -180.000001}, {"lat_deg": float("nan")},
    {"hdop": 100.0}, {"altitude_msl_m": 1e6}, {"satellites": 100},
    {"utc_time_of_day_ns": NS_PER_DAY - 1}, {"utc_time_of_day_ns": -1},
])
def test_encoder_refuses_what_the_wire_cannot_carry(bad):
    with pytest.raises(EncodeError):
        encode(dataclasses.replace(SAMPLES[0], **bad))


# --------------------------------------------------------------------------- time helpers


def test_day_of_week_of_a_1998_flight_is_thursday():
    ttt = ttt_from_gps_ns(parse_gps_datetime("1998-07-23T10:00:00"))
    assert ttt.day_of_week == 5  # Thursday, with Sunday = 1
    assert encode(ttt).startswith(b"$PASHR,TTT,5,10:00:00.0000000*")


@given(gps_instants)
def test_ttt_is_the_instant_rounded_to_100_ns(t_gps_ns):
    raw = encode(ttt_from_gps_ns(t_gps_ns))
    back = decode_sentence(raw)
    rounded = _round(t_gps_ns, TAG_LSB_NS)
    assert back.gps_time_of_week_ns == rounded % NS_PER_WEEK
    assert gps_ns_from_time_of_week(back.gps_time_of_week_ns, t_gps_ns) == rounded
    calendar = dt.datetime(1980, 1, 6) + dt.timedelta(microseconds=rounded // 1000)
    assert back.day_of_week == calendar.isoweekday() % 7 + 1  # datetime as the oracle


@pytest.mark.parametrize(("t_gps_ns", "expected"), [
    (NS_PER_WEEK * 971 - 30, b"1,00:00:00.0000000"),  # carry into the next week
    (NS_PER_WEEK * 971 + 5 * NS_PER_DAY - 50, b"6,00:00:00.0000000"),  # into the next day
    (NS_PER_WEEK * 971 + 7 * NS_PER_S - 51, b"1,00:00:06.9999999"),  # nearest, not up
    (NS_PER_WEEK * 971 + 7 * NS_PER_S - 50, b"1,00:00:07.0000000"),  # a tie goes up
    (NS_PER_WEEK * 971 + 7 * NS_PER_S - 99, b"1,00:00:06.9999999"),  # not truncated down
])
def test_time_tag_rounding_carries(t_gps_ns, expected):
    assert encode(ptt_from_gps_ns(t_gps_ns)).split(b"*")[0].endswith(expected)
    assert encode(ttt_from_gps_ns(t_gps_ns)).split(b"*")[0].endswith(expected)


def test_a_time_of_week_that_rounds_into_next_week_is_refused_without_the_helper():
    with pytest.raises(EncodeError):
        encode(PashrTtt(NS_PER_WEEK - 10))


def test_utc_rounding_carries_into_the_date():
    utc = parse_gps_datetime("1998-12-31T23:59:59") + 996_000_000  # rounds to 1999-01-01
    t_gps_ns = utc + LEAP_1998_S * NS_PER_S
    rmc = rmc_from_fix(t_gps_ns, LEAP_1998_S, 41.0, 2.0, 60.0, 180.0)
    assert (rmc.utc_date, rmc.utc_time_of_day_ns) == (dt.date(1999, 1, 1), 0)
    assert b",000000.00,A," in encode(rmc)
    assert b",010199,,," in encode(rmc)
    zda = zda_from_gps_ns(t_gps_ns, LEAP_1998_S)
    assert encode(zda).startswith(b"$GPZDA,000000.00,01,01,1999,00,00*")


@given(gps_instants, st.integers(0, 18))
def test_utc_sentences_give_back_the_gps_instant(t_gps_ns, leap_s):
    rounded = _round(t_gps_ns, UTC_LSB_NS)
    rmc = decode_sentence(encode(rmc_from_fix(t_gps_ns, leap_s, 1.0, 2.0, 3.0, 4.0)))
    zda = decode_sentence(encode(zda_from_gps_ns(t_gps_ns, leap_s)))
    gga = decode_sentence(encode(gga_from_fix(t_gps_ns, leap_s, 1.0, 2.0, 3.0, 4.0,
                                              FixQuality.GPS, 6, 1.0)))
    assert gps_ns_from_utc(rmc.utc_date, rmc.utc_time_of_day_ns, leap_s) == rounded
    assert gps_ns_from_utc(zda.utc_date, zda.utc_time_of_day_ns, leap_s) == rounded
    assert gps_ns_from_utc_time_of_day(gga.utc_time_of_day_ns, leap_s, t_gps_ns) == rounded


def test_gga_altitude_is_height_minus_geoid_separation():
    gga = gga_from_fix(FLIGHT, LEAP_1998_S, 42.0, 2.5, 2431.2345, 49.8712, FixQuality.RTK_FIXED,
                       9, 0.9)
    back = decode_sentence(encode(gga))
    assert back.altitude_msl_m == pytest.approx(2381.363, abs=1e-9)
    assert back.geoid_separation_m == pytest.approx(49.871, abs=1e-9)
    assert back.height_ellipsoidal_m == pytest.approx(2431.2345, abs=1e-3)  # two mm roundings


# --------------------------------------------------------------------------- pynmeagps


def _pynmea(raw):
    return NMEAReader.parse(raw, validate=VALCKSUM | VALMSGID)


def _as_time(time_of_day_ns):
    return (dt.datetime.min + dt.timedelta(microseconds=time_of_day_ns // 1000)).time()


ORACLE_TALKERS = st.sampled_from([t.value for t in Talker])  # pynmeagps knows these
ORACLE_DATES = st.dates(dt.date(1980, 1, 6), dt.date(2068, 12, 31))  # %y: 69..99 is 19yy


@settings(max_examples=200, suppress_health_check=[HealthCheck.too_slow])
@given(st.one_of(ggas, rmcs, zdas, gnss, gsts), ORACLE_TALKERS, ORACLE_DATES,
       st.sampled_from(NmeaVersion))
def test_pynmeagps_reads_our_standard_sentences(message, talker, date, version):
    if hasattr(message, "utc_date") and message.utc_date is not None:
        message = dataclasses.replace(message, utc_date=date)
    if version < NmeaVersion.V4_1 and getattr(message, "nav_status", None) is not None:
        message = dataclasses.replace(message, nav_status=None)
    if version < NmeaVersion.V2_3 and getattr(message, "mode", None) is not None:
        message = dataclasses.replace(message, mode=None)
    raw = encode(dataclasses.replace(message, talker=talker), version)
    assert disagreements(decode_sentence(raw), pynmeagps_read(raw)) == []


@given(gps_instants)
def test_pynmeagps_reads_the_ashtech_time_tags(t_gps_ns):
    ptt_raw, ttt_raw = encode(ptt_from_gps_ns(t_gps_ns)), encode(ttt_from_gps_ns(t_gps_ns))
    ptt, ttt = _pynmea(ptt_raw), _pynmea(ttt_raw)  # checksums validated (VALCKSUM)
    tag = ptt_raw.split(b",")[3].split(b"*")[0].decode()
    assert (ptt.msgId, ptt.dow, ptt.timeTag) == ("PTT", decode_sentence(ptt_raw).day_of_week, tag)
    # pynmeagps 1.1.8 declares the TTT time tag as NMEA hhmmss.ss, which cannot hold the
    # Ashtech hh:mm:ss.sssssss, so it yields "" there; the raw payload and day still match.
    assert (ttt.msgId, ttt.dow, ttt.payload[2]) == ("TTT", ptt.dow, tag)


# --------------------------------------------------------------------------- streaming


STREAM = [encode(m) for m in SAMPLES]
_GSA = b"GNGSA,A,3,04,05,,09,12,,,24,,,,,2.5,1.3,2.1"  # another talker: not ours
UNKNOWN = b"$%s*%02X\r\n" % (_GSA, checksum(_GSA))


def _decode_all(chunks, policy=ErrorPolicy.COUNT):
    decoder = NmeaStreamDecoder(policy)
    out = [item for chunk in chunks for item in decoder.feed(chunk)]
    return decoder, out


def _accounted(decoder, out, fed):
    """Every byte fed is in a raw, counted as skipped, or still buffered."""
    kept = sum(len(d.raw) for d in out)
    return kept + decoder.stats.bytes_skipped + decoder.buffered_bytes == fed


def test_unknown_sentences_are_kept_and_counted_not_errors():
    decoder, out = _decode_all([UNKNOWN, STREAM[0]])
    assert [d.raw for d in out] == [UNKNOWN, STREAM[0]]
    assert out[0].message == UnknownSentence("GNGSA", tuple(UNKNOWN[7:-5].decode().split(",")))
    assert decoder.stats.by_kind == {SentenceKind.UNKNOWN.value: 1, SentenceKind.GGA.value: 1}
    assert decoder.stats.errors == 0


def _flip(sentence, index, byte):
    return sentence[:index] + bytes([byte]) + sentence[index + 1:]


OVERLONG = b"$GPGGA," + b"9" * 200 + b"\r\n"
BAD_STREAM = [
    (STREAM[0], "ok"),
    (b"\x00garbage\xff\r\nmore\r\n", "framing"),
    (STREAM[1][:25], "framing"),  # cut short by the next '$'
    (STREAM[2], "ok"),
    (_flip(STREAM[3], 10, STREAM[3][10] ^ 1), "checksum"),  # a digit becomes another digit
    (b"\r\n", "ok"),  # a stray line break is tolerated
    (STREAM[4], "ok"),
    (_flip(STREAM[5], 12, 0xC3), "framing"),  # non-ASCII
    (OVERLONG, "framing"),
    (UNKNOWN, "ok"),
    (STREAM[6], "ok"),
    (b"$GPZDA,1*00\r\n", "checksum"),
    (b"$GPZDA,1*" + b"%02X" % checksum(b"GPZDA,1") + b"\r\n", "framing"),  # too few fields
    (STREAM[7], "ok"),
]


def _good_raws():
    return [raw for raw, kind in BAD_STREAM if kind == "ok" and raw.startswith(b"$")]


@pytest.mark.parametrize("chunk", [1, 7, 4096])
def test_resynchronises_and_counts_each_bad_stretch_once(chunk):
    data = b"".join(raw for raw, _ in BAD_STREAM)
    decoder, out = _decode_all([data[i:i + chunk] for i in range(0, len(data), chunk)])
    assert [d.raw for d in out] == _good_raws()
    assert decoder.stats.framing_errors == sum(kind == "framing" for _, kind in BAD_STREAM)
    assert decoder.stats.checksum_errors == sum(kind == "checksum" for _, kind in BAD_STREAM)
    assert decoder.stats.messages == len(_good_raws())
    assert decoder.stats.bytes_skipped == len(data) - sum(map(len, _good_raws()))
    assert decoder.buffered_bytes == 0


def test_raise_policy_reports_offset_and_raw_then_carries_on():
    decoder = NmeaStreamDecoder(ErrorPolicy.RAISE)
    assert [d.raw for d in decoder.feed(STREAM[0])] == [STREAM[0]]
    bad = _flip(STREAM[1], 8, ord("X"))
    with pytest.raises(DecodeError, match="checksum") as err:
        decoder.feed(bad)
    assert (err.value.offset, err.value.raw) == (len(STREAM[0]), bad)
    with pytest.raises(DecodeError) as err:
        decoder.feed(b"junk" + STREAM[2])
    assert (err.value.offset, err.value.raw) == (len(STREAM[0]) + len(bad), b"junk")
    assert [d.raw for d in decoder.feed(b"")] == [STREAM[2]]


def test_a_sentence_left_unfinished_is_counted_at_the_end():
    decoder, out = _decode_all([STREAM[0], STREAM[1][:30]])
    assert len(out) == 1
    assert decoder.stats.framing_errors == 0
    decoder.finish()
    assert (decoder.stats.framing_errors, decoder.buffered_bytes) == (1, 0)
    assert decoder.stats.bytes_skipped == 30


@given(st.lists(st.sampled_from([*STREAM, UNKNOWN]), max_size=20), st.data())
def test_random_chunking_gives_the_same_result_as_one_feed(sentences, data):
    stream = b"".join(sentences)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=30)))
    chunks = [stream[a:b] for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True)]
    one, out_one = _decode_all([stream])
    many, out_many = _decode_all(chunks)
    assert out_many == out_one
    assert [d.raw for d in out_one] == sentences
    assert many.stats == one.stats


PRINTABLE_NOT_RESERVED = [b for b in range(0x20, 0x7F) if b not in b"$*"]
JUNK = st.binary(min_size=1, max_size=40).map(
    lambda b: bytes(x for x in b if x not in b"$") or b"?")


@st.composite
def corrupted_streams(draw):
    """Good sentences, some damaged in a way whose count is known; returns (stream, expected)."""
    pieces, good, expected = [], [], {"framing": 0, "checksum": 0}
    for raw in draw(st.lists(st.sampled_from(STREAM), min_size=1, max_size=15)):
        damage = draw(st.sampled_from(["none", "none", "junk", "cut", "flip", "high"]))
        index = draw(st.integers(1, raw.index(b"*") - 1))
        after_cut = bool(pieces) and not pieces[-1].endswith(b"\n")  # junk would join the cut
        if damage == "junk" and not after_cut:
            pieces.append(draw(JUNK))
            expected["framing"] += bool(pieces[-1].strip(b"\r\n"))
        if damage == "cut":
            pieces.append(raw[:index])
            expected["framing"] += 1
        elif damage == "flip":
            byte = draw(st.sampled_from([b for b in PRINTABLE_NOT_RESERVED if b != raw[index]]))
            pieces.append(_flip(raw, index, byte))
            expected["checksum"] += 1
        elif damage == "high":
            pieces.append(_flip(raw, index, draw(st.integers(0x80, 0xFF))))
            expected["framing"] += 1
        else:
            pieces.append(raw)
            good.append(raw)
    pieces.append(STREAM[0])  # so a cut sentence at the end is ended by a '$'
    good.append(STREAM[0])
    return b"".join(pieces), good, expected


@settings(max_examples=150)
@given(corrupted_streams(), st.integers(1, 64))
def test_damaged_streams_keep_every_good_sentence_and_count_errors_exactly(case, chunk):
    stream, good, expected = case
    decoder, out = _decode_all([stream[i:i + chunk] for i in range(0, len(stream), chunk)])
    assert [d.raw for d in out] == good
    assert decoder.stats.framing_errors == expected["framing"]
    assert decoder.stats.checksum_errors == expected["checksum"]
    assert _accounted(decoder, out, len(stream))


NOISE = st.lists(st.one_of(st.binary(max_size=60), st.sampled_from([*STREAM, UNKNOWN]),
                           st.sampled_from([b"$", b"*", b",", b"\r\n", b"\n", b"$GPGGA,"])),
                 max_size=40)


@settings(max_examples=200)
@given(NOISE)
def test_fuzz_never_raises_and_the_buffer_stays_bounded(chunks):
    decoder = NmeaStreamDecoder(ErrorPolicy.COUNT)
    out, fed = [], 0
    for chunk in chunks:
        out += decoder.feed(chunk)
        fed += len(chunk)
        assert decoder.buffered_bytes < MAX_SENTENCE_BYTES
    assert _accounted(decoder, out, fed)
    for item in out:
        assert decode_sentence(item.raw) == item.message


def test_decode_sentence_tells_a_checksum_error_from_a_framing_error():
    with pytest.raises(ChecksumError):
        decode_sentence(_flip(STREAM[0], 9, STREAM[0][9] ^ 1))
    for broken in (STREAM[0][:-5] + b"\r\n", b"GPZDA" + STREAM[4], _flip(STREAM[4], 9, ord("$"))):
        with pytest.raises(DecodeError) as err:
            decode_sentence(broken)
        assert not isinstance(err.value, ChecksumError)
