"""What every device codec shares: an error policy, error counters, and decoded items that keep
their raw bytes.

Streaming decoders never raise on bad input under ErrorPolicy.COUNT (live logging): they skip to
the next plausible message start, count what they skipped, and carry on. Tests run them with
ErrorPolicy.RAISE so the first bad byte fails loudly.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum
from typing import Generic, TypeVar

from sisa.core.errors import DecodeError

MessageT = TypeVar("MessageT")


class ErrorPolicy(Enum):
    COUNT = "count"  # count, skip, resynchronise
    RAISE = "raise"  # raise DecodeError on the first bad message


@dataclass
class DecodeStats:
    """Running counts for one stream; recorded in the health channel."""

    messages: int = 0
    checksum_errors: int = 0
    framing_errors: int = 0
    bytes_skipped: int = 0
    by_kind: dict[str, int] = field(default_factory=dict)

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


def report_error(policy: ErrorPolicy, stats: DecodeStats, kind: str, message: str,
                 offset: int, raw: bytes) -> None:
    """Count a decode error, or raise it under ErrorPolicy.RAISE."""
    if kind == "checksum":
        stats.checksum_errors += 1
    else:
        stats.framing_errors += 1
    if policy is ErrorPolicy.RAISE:
        raise DecodeError(message, offset=offset, raw=raw)
