"""One exception root for the whole toolkit, with subclasses by the phase that fails."""

from __future__ import annotations


class SisaError(Exception):
    """Root of every error SISA raises on purpose; the CLI turns it into a one-line message."""


class ConfigError(SisaError):
    """A scenario, calibration or command-line value is invalid (set-up phase)."""


class InputError(SisaError):
    """An input file is missing, unreadable or of the wrong kind (set-up phase)."""


class EncodeError(SisaError, ValueError):
    """A value that cannot go on the wire: missing, not finite, or outside its declared range."""


class RecorderError(SisaError):
    """Writing the flight log failed (operation phase); what was on disk stays readable."""


class DecodeError(SisaError):
    """Bytes that do not decode as the expected message (operation phase)."""

    def __init__(self, message: str, *, offset: int = -1, raw: bytes = b"") -> None:
        super().__init__(message)
        self.offset = offset
        self.raw = raw
