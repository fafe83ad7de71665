"""Binary message layouts declared once, as data, and packed and unpacked by one generic walker.

A `Field` says where a value lives (start bit and length), how the raw integer maps to a physical
value (physical = raw · scale + offset, exactly as in a DBC file) and which physical range is legal.
A `Layout` is a fixed-size list of fields. The emulators encode with it and the acquisition decodes
with it, so a message's layout is written once and cannot disagree with itself.

Bit numbering is little-endian ("Intel", DBC `@1`): bit k of a layout is bit k % 8 of byte k // 8,
and a field's start bit is its least significant bit. A byte-aligned multi-byte field is therefore a
plain little-endian integer. Signed fields are two's complement.

Encoding rounds to the nearest LSB (never truncates) and refuses a value outside the declared range
unless the caller asks to clamp it. Decoding returns whatever the wire holds; `Layout.out_of_range`
names the fields whose raw value lies outside the declared range, so a reader can treat them as
corrupt data instead of passing them on.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from enum import Enum
from functools import cached_property

from sisa.core.errors import DecodeError, EncodeError, SisaError

_EDGE_SLACK_LSB = 1e-6  # so that a range edge such as 1000 m/s at 1 mm/s counts as an exact LSB


class LayoutError(SisaError):
    """A layout declaration is inconsistent: a programming error, raised when the module loads."""


class WireType(Enum):
    """Byte-aligned integer types, for layouts written as byte offsets."""

    U8 = (8, False)
    I8 = (8, True)
    U16 = (16, False)
    I16 = (16, True)
    U24 = (24, False)
    I24 = (24, True)
    U32 = (32, False)
    I32 = (32, True)
    U48 = (48, False)
    U64 = (64, False)

    @property
    def bits(self) -> int:
        return self.value[0]

    @property
    def signed(self) -> bool:
        return self.value[1]


def _raw_bound(physical: float, offset: float, scale: float, *, upper: bool) -> int:
    """The innermost raw value inside a physical range edge (an edge on an LSB is kept)."""
    exact = (physical - offset) / scale
    nearest = round(exact)
    if abs(exact - nearest) <= _EDGE_SLACK_LSB:
        return nearest
    return math.floor(exact) if upper else math.ceil(exact)


@dataclass(frozen=True)
class Field:
    """One value in a layout: position, raw ↔ physical scaling, unit and legal range."""

    name: str
    start_bit: int
    length_bits: int
    signed: bool = False
    scale: float = 1.0
    offset: float = 0.0
    unit: str = ""
    minimum: float | None = None  # physical; default: smallest representable
    maximum: float | None = None  # physical; default: largest representable
    comment: str = ""

    @classmethod
    def at_byte(cls, name: str, byte_offset: int, wire: WireType, *, scale: float = 1.0,
                offset: float = 0.0, unit: str = "", minimum: float | None = None,
                maximum: float | None = None, comment: str = "") -> Field:
        """A byte-aligned field, declared by byte offset and wire type."""
        return cls(name, 8 * byte_offset, wire.bits, wire.signed, scale, offset, unit,
                   minimum, maximum, comment)

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise LayoutError(f"field name {self.name!r} is not an identifier")
        if self.start_bit < 0 or not 1 <= self.length_bits <= 64:
            raise LayoutError(f"{self.name}: bad position {self.start_bit}|{self.length_bits}")
        if not (math.isfinite(self.scale) and self.scale > 0 and math.isfinite(self.offset)):
            raise LayoutError(f"{self.name}: scale must be finite and > 0, offset finite")
        if not self.wire_min <= self.raw_min <= self.raw_max <= self.wire_max:
            raise LayoutError(f"{self.name}: declared range [{self.low}, {self.high}] is empty or "
                              f"not representable in {self.length_bits} bits")

    @cached_property
    def wire_min(self) -> int:
        return -(1 << (self.length_bits - 1)) if self.signed else 0

    @cached_property
    def wire_max(self) -> int:
        return (1 << (self.length_bits - 1 if self.signed else self.length_bits)) - 1

    @cached_property
    def raw_min(self) -> int:
        """Smallest raw value inside the declared range."""
        if self.minimum is None:
            return self.wire_min
        return _raw_bound(self.minimum, self.offset, self.scale, upper=False)

    @cached_property
    def raw_max(self) -> int:
        """Largest raw value inside the declared range."""
        if self.maximum is None:
            return self.wire_max
        return _raw_bound(self.maximum, self.offset, self.scale, upper=True)

    @cached_property
    def low(self) -> float:
        """Smallest legal physical value."""
        return self.to_physical(self.wire_min) if self.minimum is None else self.minimum

    @cached_property
    def high(self) -> float:
        """Largest legal physical value."""
        return self.to_physical(self.wire_max) if self.maximum is None else self.maximum

    def to_physical(self, raw: int) -> float:
        return raw * self.scale + self.offset

    def to_raw(self, value: float, *, clamp: bool = False) -> int:
        """Nearest raw value; out of range raises EncodeError, or clamps when asked to."""
        if not math.isfinite(value):
            raise EncodeError(f"{self.name}: {value!r} is not finite")
        if not self.low <= value <= self.high:
            if not clamp:
                raise EncodeError(f"{self.name} = {value!r} {self.unit} is outside "
                                  f"[{self.low!r}, {self.high!r}] {self.unit}".rstrip())
            value = min(max(value, self.low), self.high)
        raw = round((value - self.offset) / self.scale)
        return min(max(raw, self.raw_min), self.raw_max)

    def insert(self, word: int, raw: int) -> int:
        """Put a raw value into a layout-sized little-endian integer."""
        if not self.wire_min <= raw <= self.wire_max:
            raise EncodeError(f"{self.name}: raw {raw} does not fit {self.length_bits} bits")
        mask = (1 << self.length_bits) - 1
        return word | ((raw & mask) << self.start_bit)

    def extract(self, word: int) -> int:
        """Take this field's raw value out of a layout-sized little-endian integer."""
        raw = (word >> self.start_bit) & ((1 << self.length_bits) - 1)
        if self.signed and raw >> (self.length_bits - 1):
            raw -= 1 << self.length_bits
        return raw


@dataclass(frozen=True)
class Layout:
    """A fixed-size binary message: its fields may not overlap and must fit in size_bytes."""

    name: str
    size_bytes: int
    fields: tuple[Field, ...]

    def __post_init__(self) -> None:
        used = 0
        for f in self.fields:
            bits = ((1 << f.length_bits) - 1) << f.start_bit
            if f.start_bit + f.length_bits > 8 * self.size_bytes:
                raise LayoutError(f"{self.name}.{f.name} ends beyond {self.size_bytes} bytes")
            if used & bits:
                raise LayoutError(f"{self.name}.{f.name} overlaps another field")
            used |= bits
        if len({f.name for f in self.fields}) != len(self.fields):
            raise LayoutError(f"{self.name}: duplicate field names")

    @cached_property
    def names(self) -> tuple[str, ...]:
        return tuple(f.name for f in self.fields)

    def field(self, name: str) -> Field:
        for f in self.fields:
            if f.name == name:
                return f
        raise KeyError(f"{self.name} has no field {name!r}")

    def pack(self, values: Mapping[str, float], *, clamp: bool = False) -> bytes:
        """Physical values → bytes; every field must be given, and no other name."""
        self._check_names(values)
        return self._pack(values, clamp)

    def pack_from(self, values: Mapping[str, float]) -> bytes:
        """Physical values → bytes, this layout's fields taken from `values`, which may hold
        other names too: a record spread over several layouts (an INS record's seven CAN
        frames) packs each from one mapping."""
        missing = [f.name for f in self.fields if f.name not in values]
        if missing:
            raise EncodeError(f"{self.name}: missing fields {missing}")
        return self._pack(values, False)

    def _pack(self, values: Mapping[str, float], clamp: bool) -> bytes:
        """Field.to_raw and Field.insert of every field, their checks kept: a value inside
        its legal range (never a NaN or an infinity) is rounded and put in place here, any
        other goes through Field.to_raw, which refuses it or clamps it. (An encoder sends
        hundreds of messages a second; the calls and attribute lookups were most of it.)"""
        word = 0
        for f, name, start, mask, scale, offset, low, high, raw_min, raw_max in self._packers:
            value = values[name]
            if low <= value <= high:
                raw = round((value - offset) / scale)
                raw = raw_min if raw < raw_min else raw_max if raw > raw_max else raw
            else:
                raw = f.to_raw(value, clamp=clamp)
            word |= (raw & mask) << start
        return word.to_bytes(self.size_bytes, "little")

    @cached_property
    def _packers(self) -> tuple[tuple[Field, str, int, int, float, float, float, float, int,
                                      int], ...]:
        """What `_pack` needs of every field, looked up once. (raw_min and raw_max lie inside
        the wire range: Field checks it, so a clamped raw always fits its bits.)"""
        return tuple((f, f.name, f.start_bit, (1 << f.length_bits) - 1, f.scale, f.offset,
                      f.low, f.high, f.raw_min, f.raw_max) for f in self.fields)

    def unpack(self, data: bytes) -> dict[str, float]:
        """Bytes → physical values (no range check: see out_of_range)."""
        return {f.name: f.to_physical(raw) for f, raw in zip(self.fields, self._walk(data),
                                                             strict=True)}

    def pack_raw(self, raws: Mapping[str, int]) -> bytes:
        """Raw integers → bytes; unused bits are zero."""
        self._check_names(raws)
        word = 0
        for f in self.fields:
            word = f.insert(word, raws[f.name])
        return word.to_bytes(self.size_bytes, "little")

    def unpack_raw(self, data: bytes) -> dict[str, int]:
        """Bytes → raw integers."""
        return dict(zip(self.names, self._walk(data), strict=True))

    def unpack_raw_into(self, data: bytes, raws: dict[str, int]) -> list[str]:
        """Bytes → raw integers put into `raws` (a record spread over several layouts is
        gathered in one dict); the names of those outside their declared range, as
        out_of_range gives them."""
        if len(data) != self.size_bytes:
            raise DecodeError(f"{self.name}: {len(data)} bytes, expected {self.size_bytes}",
                              raw=bytes(data))
        word = int.from_bytes(data, "little")
        bad = []
        for name, shift, mask, sign, low, high in self._unpackers:
            raw = (word >> shift) & mask
            if raw & sign:
                raw -= mask + 1
            raws[name] = raw
            if not low <= raw <= high:
                bad.append(name)
        return bad

    @cached_property
    def _unpackers(self) -> tuple[tuple[str, int, int, int, int, int], ...]:
        """(name, shift, mask, sign bit or 0, raw_min, raw_max) of every field."""
        return tuple((name, *extract, low, high) for extract, (name, low, high)
                     in zip(self._extractors, self._ranges, strict=True))

    def out_of_range(self, raws: Mapping[str, int]) -> list[str]:
        """Names of the fields whose raw value lies outside the declared range."""
        return [name for name, low, high in self._ranges if not low <= raws[name] <= high]

    @cached_property
    def _ranges(self) -> tuple[tuple[str, int, int], ...]:
        return tuple((f.name, f.raw_min, f.raw_max) for f in self.fields)

    @cached_property
    def _extractors(self) -> tuple[tuple[int, int, int], ...]:
        """(shift, mask, sign bit or 0) of every field: a decoder reads thousands of messages
        a second, and attribute lookups were most of its cost."""
        return tuple((f.start_bit, (1 << f.length_bits) - 1,
                      1 << (f.length_bits - 1) if f.signed else 0) for f in self.fields)

    def _walk(self, data: bytes) -> list[int]:
        if len(data) != self.size_bytes:
            raise DecodeError(f"{self.name}: {len(data)} bytes, expected {self.size_bytes}",
                              raw=bytes(data))
        word = int.from_bytes(data, "little")
        raws = []
        for shift, mask, sign in self._extractors:
            raw = (word >> shift) & mask
            raws.append(raw - ((mask + 1) if raw & sign else 0))
        return raws

    def _check_names(self, values: Mapping[str, object]) -> None:
        missing = set(self.names) - set(values)
        extra = set(values) - set(self.names)
        if missing or extra:
            raise EncodeError(f"{self.name}: missing fields {sorted(missing)}, "
                              f"unknown fields {sorted(extra)}")
