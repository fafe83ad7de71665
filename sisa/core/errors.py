"""One exception root for the whole toolkit, with subclasses by the phase that fails; and how
a value from outside goes into a one-line message."""

from __future__ import annotations

import unicodedata
from typing import Any


class SisaError(Exception):
    """Root of every error SISA raises on purpose; the CLI turns it into a one-line message."""


class ConfigError(SisaError):
    """A scenario, calibration or command-line value is invalid (set-up phase)."""


class InputError(SisaError):
    """An input file is missing, unreadable or of the wrong kind (set-up phase)."""


class EncodeError(SisaError, ValueError):
    """A value that cannot go on the wire: missing, not finite, or outside its declared range."""


class RecorderError(SisaError):
    """Writing a recording failed (operation phase): the flight log, or what an emulator records
    beside it (the scanner's own recording, the truth tables); what was on disk stays
    readable."""


class DecodeError(SisaError):
    """Bytes that do not decode as the expected message (operation phase)."""

    def __init__(self, message: str, *, offset: int = -1, raw: bytes = b"") -> None:
        super().__init__(message)
        self.offset = offset
        self.raw = raw


# -- values from outside in one-line messages -----------------------------------------------

def shown_value(value: Any, max_chars: int = 60) -> str:
    """A value for a one-line message: numbers with :.12g (a 300-digit integer would flood it),
    text as a repr cut to max_chars."""
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, int | float):
        try:
            return f"{value:.12g}"
        except OverflowError:  # an int past float range (TOML integers go to 4300 digits)
            return "an integer too large for a float"
    text = repr(value)
    return text if len(text) <= max_chars else text[:max_chars - 1] + "…"


def one_line_text_problem(text: str) -> str | None:
    """What keeps text from printing as part of one line: a control, format (e.g. bidi
    override) or line/paragraph separator character, or None."""
    for i, ch in enumerate(text):
        if unicodedata.category(ch) in ("Cc", "Cf", "Cs", "Zl", "Zp"):
            return (f"must be printable text on one line: character {i + 1} is {ch!r} "
                    "(a control or formatting character)")
    return None


def shown_text(text: str, max_chars: int = 120) -> str:
    """Text read from a file (a log's metadata, a name) for a message or a listing: as it is,
    unless it would not print as part of a line (control characters such as a terminal's
    escape sequences, a line break, or more than max_chars, as damage can leave), then as a
    cut repr."""
    if len(text) <= max_chars and one_line_text_problem(text) is None:
        return text
    return shown_value(text, max_chars)
