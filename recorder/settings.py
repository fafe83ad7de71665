"""The recording settings a log keeps in its `sisa.recording` metadata (as text): what
post-processing may need to explain a result the log's messages cannot (docs/flight-log.md).
Written by the acquisition's wiring (`sisa.wiring.acqconfig.recording_settings`), read here."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Final

HEADER_WINDOW_KEY: Final = "header_window_ms"
READ_INTERVAL_KEY: Final = "read_interval_ms"
# where a frame camera's photo message may arrive (host time) after its mid-exposure pulse
CAMERA_WINDOW_KEY: Final = "camera_message_window_ms"
# the sync filter's default header window (ms after a frame's end), the scenario's default too
DEFAULT_HEADER_WINDOW_MS: Final = (-2.0, 10.0)


def recorded_header_window_ms(metadata: dict[str, str]) -> tuple[float, float] | None:
    """The header window a log was recorded with (`recording_settings`), None if it does not
    say (a log from before 2026-11-27, or another recorder's)."""
    try:
        lo, hi = (float(v) for v in metadata[HEADER_WINDOW_KEY].split(","))
    except (KeyError, ValueError):
        return None
    return (lo, hi) if lo < hi else None


def header_window_ms(metadata: dict[str, str]) -> tuple[float, float]:
    """The header window the sync filter used: as the log recorded it, else the default."""
    return recorded_header_window_ms(metadata) or DEFAULT_HEADER_WINDOW_MS


def recorded_camera_window_ms(metadata: dict[str, str]) -> tuple[float, float] | None:
    """The photo-message window a log with a camera was recorded with, None if it does not
    say (no camera, or another recorder's log)."""
    try:
        lo, hi = (float(v) for v in metadata[CAMERA_WINDOW_KEY].split(","))
    except (KeyError, ValueError):
        return None
    return (lo, hi) if lo < hi else None


def header_window_of_log(flight: Sequence[Path]) -> tuple[tuple[float, float], str | None]:
    """The header window a flight was recorded with, to explain untimed lines and to refuse
    segments whose ties it cannot have made (never to time anything): as the log's recording
    settings say it, with where from; else the default and None (a log recorded before it kept
    them)."""
    from recorder.parts import recording_metadata  # the scenario's default above stays light

    window = recorded_header_window_ms(recording_metadata(flight[0]))
    if window is None:
        return DEFAULT_HEADER_WINDOW_MS, None
    return window, f"as {flight[0].name} was recorded"
