"""The UBX messages we speak, each declared once as a binary layout (`acquisition.fields`):
UBX-TIM-TM2 (a time mark on the event input) and UBX-TIM-TP (the time of the next time
pulse). Facts from u-blox's public interface descriptions (M8/F9), in our own words:

TIM-TM2, class 0x0D id 0x03, 28 bytes: the channel (EXTINT pin), flags (bit 0 running mode,
bit 1 stopped, bit 2 a new falling edge, bits 3–4 the time base 0 receiver / 1 GNSS / 2 UTC,
bit 5 UTC available, bit 6 time valid, bit 7 a new rising edge), the rising-edge counter, the
week of the last rising and of the last falling edge, their time of week in ms and the
sub-millisecond part in ns, and the accuracy estimate in ns.

TIM-TP, class 0x0D id 0x01, 16 bytes: the time of the *next* time pulse as time of week in ms
plus a sub-millisecond part in 2^-32 ms, the pulse's quantization error in ps, the week, flags
(bit 0 time base UTC rather than GNSS, bit 1 UTC available, bits 2–3 RAIM, bit 4 qErr not
valid, bit 5 time pulse not locked) and reference information (GNSS and UTC standard).

Values stay raw integers (exact); properties give GPS times in ns.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum, StrEnum
from typing import Any, Generic, TypeVar

from acquisition.codec import RefusedError
from acquisition.fields import Field, Layout, WireType
from acquisition.ubx.frame import UbxRefusal, encode_frame, split_frame
from sisa.core.errors import DecodeError
from sisa.core.timescale import NS_PER_WEEK

M = TypeVar("M")
NS_PER_MS = 1_000_000
MS_PER_WEEK = NS_PER_WEEK // NS_PER_MS
SUB_MS_UNITS = 1 << 32  # TIM-TP's sub-millisecond LSB is 2^-32 ms


class UbxClass(IntEnum):
    TIM = 0x0D


class UbxName(StrEnum):
    """Name under which a message is counted in `DecodeStats.by_kind`."""

    TIM_TM2 = "TIM-TM2"
    TIM_TP = "TIM-TP"
    UNKNOWN = "UBX-unknown"


class TimeBase(IntEnum):
    """TIM-TM2's time base."""

    RECEIVER = 0
    GNSS = 1
    UTC = 2


@dataclass(frozen=True)
class UbxSpec(Generic[M]):
    """A message declared as data: its class, id and payload layout; the dataclass holds the
    layout's fields, as raw integers."""

    name: UbxName
    msg_class: int
    msg_id: int
    layout: Layout
    build: Callable[..., M]


def _bit(name: str, byte: int, bit: int, length: int = 1) -> Field:
    return Field(name, 8 * byte + bit, length)


_TOW_MS_MAX = MS_PER_WEEK - 1
_SUB_MS_NS_MAX = NS_PER_MS - 1


@dataclass(frozen=True)
class TimTm2:
    """UBX-TIM-TM2: the time of the last rising and falling edge on an event input."""

    channel: int
    running: int  # 0 single, 1 running
    stopped: int  # 0 armed, 1 stopped
    new_falling_edge: int
    time_base: int  # TimeBase
    utc_available: int
    time_valid: int
    new_rising_edge: int
    count: int  # rising edges, wraps at 2^16
    rising_week: int
    falling_week: int
    rising_tow_ms: int
    rising_sub_ms_ns: int
    falling_tow_ms: int
    falling_sub_ms_ns: int
    accuracy_ns: int

    @property
    def rising_gps_ns(self) -> int:
        """Time of the rising edge, ns since the GPS epoch (time base GNSS: GPS time)."""
        return (self.rising_week * NS_PER_WEEK + self.rising_tow_ms * NS_PER_MS
                + self.rising_sub_ms_ns)


TIM_TM2 = UbxSpec(UbxName.TIM_TM2, UbxClass.TIM, 0x03, Layout("UBX-TIM-TM2", 28, (
    Field.at_byte("channel", 0, WireType.U8),
    _bit("running", 1, 0), _bit("stopped", 1, 1), _bit("new_falling_edge", 1, 2),
    _bit("time_base", 1, 3, 2), _bit("utc_available", 1, 5), _bit("time_valid", 1, 6),
    _bit("new_rising_edge", 1, 7),
    Field.at_byte("count", 2, WireType.U16),
    Field.at_byte("rising_week", 4, WireType.U16),
    Field.at_byte("falling_week", 6, WireType.U16),
    Field.at_byte("rising_tow_ms", 8, WireType.U32, unit="ms", maximum=_TOW_MS_MAX),
    Field.at_byte("rising_sub_ms_ns", 12, WireType.U32, unit="ns", maximum=_SUB_MS_NS_MAX),
    Field.at_byte("falling_tow_ms", 16, WireType.U32, unit="ms", maximum=_TOW_MS_MAX),
    Field.at_byte("falling_sub_ms_ns", 20, WireType.U32, unit="ns", maximum=_SUB_MS_NS_MAX),
    Field.at_byte("accuracy_ns", 24, WireType.U32, unit="ns"),
)), TimTm2)


@dataclass(frozen=True)
class TimTp:
    """UBX-TIM-TP: the time of the next time pulse (PPS)."""

    tow_ms: int
    tow_sub_ms: int  # 2^-32 ms
    quantization_error_ps: int
    week: int
    time_base_utc: int  # 0 GNSS, 1 UTC
    utc_available: int
    raim: int
    q_err_invalid: int
    not_locked: int
    time_ref_gnss: int
    utc_standard: int

    @property
    def pulse_gps_ns(self) -> int:
        """Time of the next pulse, ns since the GPS epoch (the sub-ms part to the nearest ns)."""
        sub_ns = (self.tow_sub_ms * NS_PER_MS + SUB_MS_UNITS // 2) // SUB_MS_UNITS
        return self.week * NS_PER_WEEK + self.tow_ms * NS_PER_MS + sub_ns


TIM_TP = UbxSpec(UbxName.TIM_TP, UbxClass.TIM, 0x01, Layout("UBX-TIM-TP", 16, (
    Field.at_byte("tow_ms", 0, WireType.U32, unit="ms", maximum=_TOW_MS_MAX),
    Field.at_byte("tow_sub_ms", 4, WireType.U32),
    Field.at_byte("quantization_error_ps", 8, WireType.I32, unit="ps"),
    Field.at_byte("week", 12, WireType.U16),
    _bit("time_base_utc", 14, 0), _bit("utc_available", 14, 1), _bit("raim", 14, 2, 2),
    _bit("q_err_invalid", 14, 4), _bit("not_locked", 14, 5),
    _bit("time_ref_gnss", 15, 0, 4), _bit("utc_standard", 15, 4, 4),
)), TimTp)


@dataclass(frozen=True)
class UnknownUbx:
    """A well-framed UBX message we have no layout for: kept, counted."""

    msg_class: int
    msg_id: int
    payload: bytes


UbxMessage = TimTm2 | TimTp | UnknownUbx
UBX_SPECS: tuple[UbxSpec[Any], ...] = (TIM_TM2, TIM_TP)
_SPEC_BY_TYPE: dict[Any, UbxSpec[Any]] = {spec.build: spec for spec in UBX_SPECS}
_SPEC_BY_ID = {(spec.msg_class, spec.msg_id): spec for spec in UBX_SPECS}


def ubx_name(message: object) -> str:
    """The counter name of a message."""
    spec = _SPEC_BY_TYPE.get(type(message))
    return (UbxName.UNKNOWN if spec is None else spec.name).value


def encode_ubx(message: UbxMessage) -> bytes:
    """The whole frame of a message (EncodeError for a value its field cannot hold)."""
    if isinstance(message, UnknownUbx):
        return encode_frame(message.msg_class, message.msg_id, message.payload)
    spec = _SPEC_BY_TYPE[type(message)]
    return encode_frame(spec.msg_class, spec.msg_id,
                        spec.layout.pack_raw(dataclasses.asdict(message)))


def decode_ubx(raw: bytes) -> UbxMessage:
    """The message of a whole frame; RefusedError (a DecodeError) naming the reason."""
    msg_class, msg_id, payload = split_frame(raw)
    spec = _SPEC_BY_ID.get((msg_class, msg_id))
    if spec is None:
        return UnknownUbx(msg_class, msg_id, payload)
    try:
        raws = spec.layout.unpack_raw(payload)
    except DecodeError as err:
        raise RefusedError(UbxRefusal.LENGTH, f"{spec.name}: {err}", raw=raw) from err
    bad = spec.layout.out_of_range(raws)
    if bad:
        raise RefusedError(UbxRefusal.FIELD_VALUE, f"{spec.name}: {', '.join(bad)} out of range",
                           raw=raw)
    message: UbxMessage = spec.build(**raws)
    return message


# ---------------------------------------------------------------------------------------------
# Messages from GPS instants (the emulator's side).

TM2_RESOLUTION_NS = 1  # the sub-millisecond part is in whole ns


def tim_tm2_from_gps_ns(t_gps_ns: int, count: int, accuracy_ns: int) -> TimTm2:
    """The time mark of a rising edge at `t_gps_ns` (GNSS time base, time valid, a new rising
    edge, running mode, channel 0); no falling edge reported (its fields 0)."""
    week, rest_ns = divmod(t_gps_ns, NS_PER_WEEK)
    tow_ms, sub_ns = divmod(rest_ns, NS_PER_MS)
    return TimTm2(channel=0, running=1, stopped=0, new_falling_edge=0,
                  time_base=TimeBase.GNSS, utc_available=1, time_valid=1, new_rising_edge=1,
                  count=count % (1 << 16), rising_week=week, falling_week=0,
                  rising_tow_ms=tow_ms, rising_sub_ms_ns=sub_ns, falling_tow_ms=0,
                  falling_sub_ms_ns=0, accuracy_ns=accuracy_ns)


def tim_tp_for_pulse(t_pulse_gps_ns: int, quantization_error_ps: int = 0) -> TimTp:
    """TIM-TP announcing the pulse at `t_pulse_gps_ns` (GNSS time base, locked)."""
    week, rest_ns = divmod(t_pulse_gps_ns, NS_PER_WEEK)
    tow_ms, sub_ns = divmod(rest_ns, NS_PER_MS)
    sub_units = (sub_ns * SUB_MS_UNITS + NS_PER_MS // 2) // NS_PER_MS
    return TimTp(tow_ms=tow_ms, tow_sub_ms=min(sub_units, SUB_MS_UNITS - 1),
                 quantization_error_ps=quantization_error_ps, week=week, time_base_utc=0,
                 utc_available=1, raim=0, q_err_invalid=0, not_locked=0, time_ref_gnss=0,
                 utc_standard=0)
