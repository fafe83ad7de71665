"""Sentences declared as data (their fields in wire order, each with the NMEA 0183 version that
added it) and the one walker that encodes and decodes them.

NMEA 0183 grows sentences only at their end: version 2.3 added RMC's mode indicator, 4.1 its
navigation status. A field's `since` says which version brought it, so one table reads every
version of a sentence (a sentence from an older version ends before the newer fields, which
decode as None) and writes the version asked for.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import IntEnum, StrEnum
from functools import cached_property
from typing import Any, Generic, TypeVar

from acquisition.codec import RefusedError
from acquisition.nmea.wire import WireFormat
from sisa.core.errors import DecodeError, EncodeError

M = TypeVar("M")


class NmeaVersion(IntEnum):
    """NMEA 0183 versions that changed the sentences we read (value: major·100 + minor)."""

    V2_0 = 200
    V2_3 = 230  # RMC and GLL mode indicator; GGA qualities 6–8
    V3_0 = 300
    V4_0 = 400  # GNS from multi-constellation receivers
    V4_1 = 410  # RMC and GNS navigational status
    V4_11 = 411

    def __str__(self) -> str:
        major, minor = divmod(self.value, 100)
        return f"{major}.{minor // 10 if minor % 10 == 0 else minor}"


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
    GNS = "GNS"
    GST = "GST"
    PTT = "PTT"
    TTT = "TTT"
    UNKNOWN = "unknown"


class Refusal(StrEnum):
    """Why a sentence is refused: the key it is counted under in `DecodeStats.refused`."""

    CHECKSUM = "nmea.checksum"  # the `*hh` does not match
    NO_CHECKSUM = "nmea.no_checksum"  # none, and the decoder was not told to accept that
    MALFORMED = "nmea.malformed"  # a '*' without two hex digits, a reserved character, no address
    FIELD_COUNT = "nmea.field_count"  # a known sentence with a count of fields no version has
    FIELD_VALUE = "nmea.field_value"  # a field that does not read as what the table declares
    CUT_SHORT = "nmea.cut_short"  # a new '$' or a byte no sentence holds before the line end
    TOO_LONG = "nmea.too_long"  # no line end within MAX_SENTENCE_BYTES


@dataclass(frozen=True)
class Field:
    """One message attribute: its name in the dataclass, its wire format, its unit, and the
    NMEA version that added it to the sentence."""

    name: str
    wire: WireFormat[Any]
    unit: Unit = Unit.NONE
    since: NmeaVersion = NmeaVersion.V2_0

    @property
    def width(self) -> int:
        return self.wire.width


@dataclass(frozen=True)
class SentenceSpec(Generic[M]):
    """A sentence declared as data: its header and its fields in wire order.

    A standard sentence's header is its formatter (`GGA`); any talker may send it, and the
    message keeps the talker in its `talker` attribute. A proprietary one's header is its whole
    address and sub-id (`PASHR`, `PTT`)."""

    kind: SentenceKind
    header: tuple[str, ...]
    build: Callable[..., M]
    fields: tuple[Field, ...]
    proprietary: bool = False

    def __post_init__(self) -> None:
        versions = [f.since for f in self.fields]
        if versions != sorted(versions):
            raise ValueError(f"{self.kind}: a later version's fields must come after the others")

    def width(self, version: NmeaVersion) -> int:
        """Tokens after the header in `version` of the sentence."""
        return sum(f.width for f in self.fields if f.since <= version)

    @cached_property
    def plan(self) -> tuple[tuple[str, WireFormat[Any], int, NmeaVersion], ...]:
        """(name, wire format, width, since) of every field: what the walker reads per
        sentence, looked up once."""
        return tuple((f.name, f.wire, f.width, f.since) for f in self.fields)

    @cached_property
    def version_by_width(self) -> dict[int, NmeaVersion]:
        """Each field count the sentence has had, with the first version that had it."""
        out: dict[int, NmeaVersion] = {}
        for version in NmeaVersion:
            out.setdefault(self.width(version), version)
        return out


def encode_fields(spec: SentenceSpec[Any], message: object, version: NmeaVersion) -> list[str]:
    """The tokens after the header, as `version` of the sentence has them. A value in a field
    the version does not have is refused (EncodeError), never dropped."""
    tokens: list[str] = []
    for f in spec.fields:
        value = getattr(message, f.name)
        if f.since > version:
            if value is not None:
                raise EncodeError(f"{spec.kind}.{f.name} came with NMEA {f.since}, not in "
                                  f"{version}")
            continue
        tokens.extend(f.wire.encode(value))
    return tokens


def decode_fields(spec: SentenceSpec[M], payload: Sequence[str], talker: str) -> M:
    """The message of the tokens after the header (`talker`: a standard sentence's)."""
    version = spec.version_by_width.get(len(payload))
    if version is None:
        widths = "/".join(str(w) for w in spec.version_by_width)
        raise RefusedError(Refusal.FIELD_COUNT,
                      f"{spec.kind}: {len(payload)} fields, expected {widths}")
    values: dict[str, Any] = {} if spec.proprietary else {"talker": talker}
    start = 0
    for name, wire, width, since in spec.plan:
        if since > version:
            values[name] = None
            continue
        tokens = payload[start:start + width]
        start += width
        try:
            values[name] = wire.decode(tokens)
        except DecodeError as err:
            raise RefusedError(Refusal.FIELD_VALUE, f"{spec.kind}.{name}: {err}") from err
    return spec.build(**values)
