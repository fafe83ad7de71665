"""Tests of the flight recorder: writer, tolerant reader, recover, crashes, an independent reader.

`sample_messages()` gives one message of every logged type on every topic, with the awkward
values a real log holds (bytes with NULs, empty bytes, NaN, infinities, negative numbers).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from recorder.messages import (
    CameraPhotoLog,
    FrameHeaderLog,
    GpsFix,
    GpsTimeTag,
    InsRecordLog,
    LoggedMessage,
    PulseEdgeLog,
    RawBytes,
    RawCanFrames,
    StreamHealth,
    SyncCameraPulse,
    SyncForward,
    SyncModeSwitch,
    SyncPps,
    SyncSession,
    Topic,
)
from recorder.writer import FlightRecorder

T0_NS = 1_700_000_000 * 10**9  # host clock (Unix ns)


def overwrite_middle(src: Path, dst: Path, n_bytes: int = 20_000, seed: int = 0) -> Path:
    """A copy of the log `src` at `dst` with `n_bytes` of noise over its middle: a chunk or
    more damaged, the rest whole."""
    data = bytearray(src.read_bytes())
    mid = len(data) // 2
    data[mid:mid + n_bytes] = np.random.default_rng(seed).bytes(n_bytes)
    dst.write_bytes(bytes(data))
    return dst


def sample_messages(t0_ns: int = T0_NS) -> list[tuple[LoggedMessage, Topic | None]]:
    t = t0_ns
    return [
        (RawBytes(t, "gps", b"$GPGGA,1*00\r\n\x00\xff"), Topic.GPS_RAW),
        (RawBytes(t + 1, "scanner", b""), Topic.SCANNER_RAW),
        (RawCanFrames(t + 2, [0, 250_000], [0x18FF1234 | 0x8000_0000, 0x100], [8, 3],
                      bytes(range(11))), None),
        (GpsFix(t + 3, 1_300_000_000 * 10**9, 42.123456789, -2.5, 612.25, 2, 9, 0.8), None),
        (GpsTimeTag(t + 4, "TTT", 345_600_123_456_789, 1_300_000_000 * 10**9 + 1), None),
        (InsRecordLog(t + 5, 65535, 2**48 - 1, 0.01, -0.02, 3.14, 1e-5, float("nan"), -1e-5,
                      60.0, float("inf"), float("-inf"), 7, True, 123), None),
        (FrameHeaderLog(t + 6, 4_000_000_000, 48_000, 1, 0, 19), None),
        (PulseEdgeLog(t + 7, "PPS", -5, 0), Topic.PULSE_IN),
        (PulseEdgeLog(t + 8, "INS_SYNC", 10**15, 1), Topic.PULSE_OUT),
        (SyncSession(t + 9, 0, 10**12, 4, [4, 3], 1, 20, 1_000_000_000, True), None),
        (SyncPps(t + 10, 0, 10**12, 1_300_000_001 * 10**9, 1, 9, 1, True), None),
        (SyncForward(t + 11, 0, 0, 10**12, 1, "PPS", True, -1, -1, "n/a"), None),
        (SyncModeSwitch(t + 12, 0, 10**12, 1, 2, "scanner on: ppf seen"), None),
        (StreamHealth(t + 13, "gps", 100, 10.0, 10.0, 0, 1, 0, 5, 0, 0), None),
        (RawBytes(t + 14, "camera", b"\xc5\x5c\x08"), Topic.CAMERA_RAW),
        (CameraPhotoLog(t + 15, 2**32 - 1, 1_000), None),
        (SyncCameraPulse(t + 16, 0, 3, 10**12 + 5, False), None),
    ]


def write_sample_log(path: Path, **recorder_options: Any) -> FlightRecorder:
    """`path`: a complete log of sample_messages(); the recorder that wrote it."""
    with FlightRecorder(path, **recorder_options) as rec:
        for msg, topic in sample_messages():
            rec.write(msg, topic)
    return rec
