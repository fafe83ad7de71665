"""What every device codec shares: an error policy, error counters, and decoded items that keep
their raw bytes.

Streaming decoders never raise on bad input under ErrorPolicy.COUNT (live logging): they skip to
the next plausible message start, count what they skipped, and carry on. Tests run them with
ErrorPolicy.RAISE so the first bad byte fails loudly.

Every refusal is counted twice: as a checksum or a framing error (the two counters every stream
has had from the start) and under its reason (`DecodeStats.refused`, e.g. `nmea.no_checksum`),
which the health channel carries, so a log says why its receiver's bytes were refused.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum, StrEnum
from typing import Generic, TypeVar

from sisa.core.errors import DecodeError

MessageT = TypeVar("MessageT")


class ErrorPolicy(Enum):
    COUNT = "count"  # count, skip, resynchronise
    RAISE = "raise"  # raise DecodeError on the first bad message


class ErrorKind(StrEnum):
    """The two error counters of `DecodeStats`."""

    CHECKSUM = "checksum"
    FRAMING = "framing"


class RefusedError(DecodeError):
    """A message refused for a named reason (`reason`, the key it is counted under), which is a
    checksum error or a framing error (`kind`)."""

    def __init__(self, reason: str, message: str, *, kind: ErrorKind = ErrorKind.FRAMING,
                 offset: int = -1, raw: bytes = b"") -> None:
        super().__init__(message, offset=offset, raw=raw)
        self.reason = reason
        self.kind = kind


@dataclass
class DecodeStats:
    """Running counts for one stream; recorded in the health channel."""

    messages: int = 0
    checksum_errors: int = 0
    framing_errors: int = 0
    bytes_skipped: int = 0
    by_kind: dict[str, int] = field(default_factory=dict)
    refused: dict[str, int] = field(default_factory=dict)  # errors by reason

    @property
    def errors(self) -> int:
        return self.checksum_errors + self.framing_errors

    def count_message(self, kind: str) -> None:
        self.messages += 1
        self.by_kind[kind] = self.by_kind.get(kind, 0) + 1


@dataclass(frozen=True)
class Decoded(Generic[MessageT]):
    """One decoded message with the exact bytes it came from."""

    raw: bytes
    message: MessageT


_CHECKSUM, _RAISE = ErrorKind.CHECKSUM, ErrorPolicy.RAISE  # module names: called per bad byte


def report_error(policy: ErrorPolicy, stats: DecodeStats, kind: str, message: str,
                 offset: int, raw: bytes, reason: str = "") -> None:
    """Count a decode error (as a checksum or framing error, and under its reason: the kind
    when none is given), or raise it under ErrorPolicy.RAISE."""
    if kind == _CHECKSUM:
        stats.checksum_errors += 1
    else:
        stats.framing_errors += 1
    reason = reason or kind
    stats.refused[reason] = stats.refused.get(reason, 0) + 1
    if policy is _RAISE:
        raise RefusedError(reason, message, kind=ErrorKind(kind), offset=offset, raw=raw)
