"""Sentences declared as data (their fields in wire order) and the one walker that encodes and
decodes them."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, Generic, TypeVar

from acquisition.nmea.wire import WireFormat, _bad
from sisa.errors import DecodeError

M = TypeVar("M")

class Unit(StrEnum):
    """Unit of a message attribute, stated in the field table (and in the attribute's name)."""

    NANOSECOND = "ns"
    SECOND = "s"
    DEGREE = "deg"
    METRE = "m"
    METRE_PER_SECOND = "m/s"
    COUNT = "count"
    NONE = ""


class SentenceKind(StrEnum):
    """Name under which a sentence is counted in `DecodeStats.by_kind`."""

    GGA = "GGA"
    RMC = "RMC"
    ZDA = "ZDA"
    PTT = "PTT"
    TTT = "TTT"
    UNKNOWN = "unknown"


# ---------------------------------------------------------------------------------------------
# Field tables and the walker.


@dataclass(frozen=True)
class Field:
    """One message attribute: its name in the dataclass, its wire format and its unit."""

    name: str
    wire: WireFormat[Any]
    unit: Unit = Unit.NONE

    @property
    def width(self) -> int:
        return self.wire.width


@dataclass(frozen=True)
class Constant:
    """A token that is always the same (a unit letter, an unused field)."""

    token: str
    width: int = 1


@dataclass(frozen=True)
class SentenceSpec(Generic[M]):
    """A sentence declared as data: its header tokens and its fields in wire order."""

    kind: SentenceKind
    header: tuple[str, ...]
    build: Callable[..., M]
    items: tuple[Field | Constant, ...]

    @property
    def fields(self) -> tuple[Field, ...]:
        return tuple(item for item in self.items if isinstance(item, Field))

    @property
    def width(self) -> int:
        return sum(item.width for item in self.items)


def _encode_tokens(spec: SentenceSpec[Any], message: object) -> list[str]:
    tokens = list(spec.header)
    for item in spec.items:
        if isinstance(item, Constant):
            tokens.append(item.token)
        else:
            tokens.extend(item.wire.encode(getattr(message, item.name)))
    return tokens


def _decode_tokens(spec: SentenceSpec[M], payload: Sequence[str]) -> M:
    if len(payload) != spec.width:
        raise _bad(f"{spec.kind}: {len(payload)} fields, expected {spec.width}")
    values: dict[str, Any] = {}
    start = 0
    for item in spec.items:
        tokens = payload[start:start + item.width]
        start += item.width
        if isinstance(item, Constant):
            if tokens[0] != item.token:
                raise _bad(f"{spec.kind}: expected {item.token!r}, got {tokens[0]!r}")
        else:
            try:
                values[item.name] = item.wire.decode(tokens)
            except DecodeError as err:
                raise _bad(f"{spec.kind}.{item.name}: {err}") from err
    return spec.build(**values)

