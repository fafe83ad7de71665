"""UBX: the frame and its checksum by hand, TIM-TM2 and TIM-TP declared as layouts and read by
pyubx2 (the independent decoder) as we write them and by us as pyubx2 writes them; a stream of
NMEA and UBX interleaved, damaged, cut anywhere, that loses no good message and counts what it
lost; the acquisition's time tags from UBX."""

from __future__ import annotations

import dataclasses

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pyubx2 import UBXMessage, UBXReader

from acquisition.codec import ErrorPolicy
from acquisition.nmea import decode_sentence
from acquisition.runner import Acquisition
from acquisition.ubx import (
    TIM_TM2,
    TIM_TP,
    UBX_SPECS,
    NmeaUbxStreamDecoder,
    TimeBase,
    TimTm2,
    TimTp,
    UbxRefusal,
    UnknownUbx,
    decode_ubx,
    encode_frame,
    encode_ubx,
    fletcher8,
    tim_tm2_from_gps_ns,
    tim_tp_for_pulse,
)
from acquisition.ubx.messages import UbxSpec
from emulators.scenario import load_scenario
from recorder.messages import GpsTimeTag
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

# pyubx2's attribute names of our fields
PYUBX2_NAMES = {
    "TIM-TM2": {"channel": "ch", "running": "mode", "stopped": "run",
                "new_falling_edge": "newFallingEdge", "time_base": "timeBase",
                "utc_available": "utc",
                "time_valid": "time", "new_rising_edge": "newRisingEdge", "count": "count",
                "rising_week": "wnR", "falling_week": "wnF", "rising_tow_ms": "towMsR",
                "rising_sub_ms_ns": "towSubMsR", "falling_tow_ms": "towMsF",
                "falling_sub_ms_ns": "towSubMsF", "accuracy_ns": "accEst"},
    "TIM-TP": {"tow_ms": "towMS", "tow_sub_ms": "towSubMS", "quantization_error_ps": "qErr",
               "week": "week", "time_base_utc": "timeBase", "utc_available": "utc",
               "raim": "raim", "q_err_invalid": "qErrInvalid", "not_locked": "TpNotLocked",
               "time_ref_gnss": "timeRefGnss", "utc_standard": "utcStandard"},
}
SUB_MS_LSB = 2.0**-32  # TIM-TP's towSubMS in ms, as pyubx2 scales it


def test_the_checksum_of_a_published_poll_frame() -> None:
    # The MON-VER poll printed in u-blox's interface descriptions: B5 62 0A 04 00 00 0E 34.
    assert encode_frame(0x0A, 0x04, b"") == bytes.fromhex("b5620a0400000e34")
    assert fletcher8(bytes.fromhex("0a040000")) == (0x0E, 0x34)


@pytest.mark.parametrize("spec", UBX_SPECS, ids=lambda s: s.name.value)
def test_every_layout_names_exactly_its_dataclass_fields(spec: UbxSpec[object]) -> None:
    assert list(spec.layout.names) == [f.name for f in dataclasses.fields(spec.build)]
    assert set(PYUBX2_NAMES[spec.name.value]) == set(spec.layout.names)


def _messages(spec: UbxSpec[object]) -> st.SearchStrategy[object]:
    return st.fixed_dictionaries({
        f.name: st.integers(f.raw_min, f.raw_max) for f in spec.layout.fields
    }).map(lambda raws: spec.build(**raws))


MESSAGES = st.one_of(_messages(TIM_TM2), _messages(TIM_TP))


def _theirs_equal(message: TimTm2 | TimTp, theirs: UBXMessage) -> None:
    names = PYUBX2_NAMES["TIM-TM2" if isinstance(message, TimTm2) else "TIM-TP"]
    for ours, attr in names.items():
        value = getattr(theirs, attr)
        if ours == "tow_sub_ms":
            value = round(value / SUB_MS_LSB)
        assert value == getattr(message, ours), ours


@settings(max_examples=200)
@given(MESSAGES)
def test_round_trip_and_pyubx2_reads_what_we_write(message: TimTm2 | TimTp) -> None:
    raw = encode_ubx(message)
    assert decode_ubx(raw) == message
    _theirs_equal(message, UBXReader.parse(raw))


@settings(max_examples=100)
@given(MESSAGES)
def test_we_read_what_pyubx2_writes(message: TimTm2 | TimTp) -> None:
    name = "TIM-TM2" if isinstance(message, TimTm2) else "TIM-TP"
    kwargs = {attr: getattr(message, ours) for ours, attr in PYUBX2_NAMES[name].items()}
    if name == "TIM-TP":
        kwargs["towSubMS"] = message.tow_sub_ms * SUB_MS_LSB
    raw = UBXMessage("TIM", name, 0, **kwargs).serialize()  # 0: output (GET)
    assert decode_ubx(raw) == message


@given(st.integers(0, parse_gps_datetime("2079-12-31T00:00:00")), st.integers(0, 200_000))
def test_time_marks_and_pulses_give_back_their_instants(t_gps_ns: int, count: int) -> None:
    mark = decode_ubx(encode_ubx(tim_tm2_from_gps_ns(t_gps_ns, count, 20)))
    assert isinstance(mark, TimTm2)
    assert (mark.rising_gps_ns, mark.count) == (t_gps_ns, count % 65536)
    assert (mark.time_base, mark.time_valid, mark.new_rising_edge) == (TimeBase.GNSS, 1, 1)
    pulse = decode_ubx(encode_ubx(tim_tp_for_pulse(t_gps_ns)))
    assert isinstance(pulse, TimTp)
    assert abs(pulse.pulse_gps_ns - t_gps_ns) <= 1  # sub-ms in 2^-32 ms ≈ 0.23 ps, read to 1 ns
    assert tim_tp_for_pulse(t_gps_ns // NS_PER_S * NS_PER_S).tow_sub_ms == 0


def test_out_of_range_values_are_refused_both_ways() -> None:
    with pytest.raises(EncodeError):
        encode_ubx(dataclasses.replace(tim_tm2_from_gps_ns(T0, 1, 20), count=70_000))
    payload = bytearray(TIM_TM2.layout.pack_raw(dataclasses.asdict(tim_tm2_from_gps_ns(T0, 1,
                                                                                       20))))
    payload[8:12] = (NS_PER_WEEK // 1_000_000).to_bytes(4, "little")  # tow = one week
    with pytest.raises(DecodeError) as err:
        decode_ubx(encode_frame(0x0D, 0x03, bytes(payload)))
    assert getattr(err.value, "reason", None) == UbxRefusal.FIELD_VALUE
    with pytest.raises(DecodeError) as err:
        decode_ubx(encode_frame(0x0D, 0x03, bytes(payload[:20])))
    assert getattr(err.value, "reason", None) == UbxRefusal.LENGTH


def test_an_unknown_message_is_kept_and_counted() -> None:
    raw = encode_frame(0x01, 0x07, bytes(92))  # NAV-PVT: not ours
    decoder = NmeaUbxStreamDecoder(ErrorPolicy.RAISE)
    (item,) = decoder.feed(raw)
    assert item.message == UnknownUbx(0x01, 0x07, bytes(92))
    assert decoder.stats.by_kind == {"UBX-unknown": 1}


# --------------------------------------------------------------------------- mixed streams


MIXED = damaged_streams([nmea_kind(SENTENCES), MessageKind(
    MESSAGES.map(encode_ubx), lambda raw: (6, len(raw) - 3), st.integers(0, 255))],
    tail=SENTENCES[0])


@settings(max_examples=300, deadline=None)
@given(MIXED, st.integers(1, 64))
def test_a_damaged_mixed_stream_loses_no_good_message_and_says_how_many_it_lost(
        case: tuple[bytes, list[bytes], int], chunk: int) -> None:
    check_decoding(NmeaUbxStreamDecoder(), case, chunk)


def test_a_ubx_frame_right_after_a_sentence_cut_short_is_decoded() -> None:
    sentence, frame = SENTENCES[1], encode_ubx(tim_tp_for_pulse(T0))
    decoder = NmeaUbxStreamDecoder()
    out = decoder.feed(sentence[:30] + frame + sentence)
    assert [d.raw for d in out] == [frame, sentence]
    assert decoder.stats.refused == {"nmea.cut_short": 1}
    assert decode_sentence(sentence) == out[1].message


def test_a_corrupted_ubx_frame_is_one_checksum_error_and_what_follows_decodes() -> None:
    frame = bytearray(encode_ubx(tim_tm2_from_gps_ns(T0 + 123, 7, 20)))
    frame[10] ^= 0x40
    frame[12] = 0x24  # a '$' inside its payload
    decoder = NmeaUbxStreamDecoder()
    out = decoder.feed(bytes(frame) + SENTENCES[2] + encode_ubx(tim_tp_for_pulse(T0)))
    assert [d.raw for d in out][1:] == [encode_ubx(tim_tp_for_pulse(T0))]
    assert out[0].raw == SENTENCES[2]
    assert decoder.stats.refused == {UbxRefusal.CHECKSUM: 1}
    assert decoder.stats.checksum_errors == 1


# --------------------------------------------------------------------------- acquisition


def test_the_acquisition_makes_the_same_time_tags_of_ubx() -> None:
    config = dataclasses.replace(acquisition_config(load_scenario("bench")), gps_ubx=True)
    logged: list[object] = []
    acq = Acquisition(config, lambda m, _t: logged.append(m), lambda _e: None)
    second = T0 // NS_PER_S * NS_PER_S
    event = second + 123_456_700
    acq.on_gps_bytes(1_000, encode_ubx(tim_tp_for_pulse(second + NS_PER_S))
                     + encode_ubx(tim_tm2_from_gps_ns(event, 3, 20))
                     + encode_ubx(dataclasses.replace(tim_tm2_from_gps_ns(event, 4, 20),
                                                      time_valid=0)))
    tags = [m for m in logged if isinstance(m, GpsTimeTag)]
    assert tags == [GpsTimeTag(1_000, "PTT", second % NS_PER_WEEK, second),
                    GpsTimeTag(1_000, "TTT", event % NS_PER_WEEK, event)]
    assert acq.last_pps_gps_ns == second


NOISE = st.lists(st.one_of(st.binary(max_size=80), st.sampled_from(SENTENCES),
                           MESSAGES.map(encode_ubx),
                           st.sampled_from([b"\xb5", b"\xb5\x62", b"\xb5\x62\x0d\x03\xff\xff",
                                            b"$", b"\r\n", b"*"])),
                 max_size=40)


@settings(max_examples=300, deadline=None)
@given(NOISE)
def test_fuzz_never_raises_holds_little_and_accounts_for_every_byte(chunks: list[bytes]) -> None:
    decoder = NmeaUbxStreamDecoder()
    out, fed = [], 0
    for chunk in chunks:
        out += decoder.feed(chunk)
        fed += len(chunk)
        assert decoder.buffered_bytes <= 6 + 4096 + 2
    out += decoder.finish()
    assert sum(len(d.raw) for d in out) + decoder.stats.bytes_skipped == fed
    assert decoder.stats.errors == sum(decoder.stats.refused.values())
