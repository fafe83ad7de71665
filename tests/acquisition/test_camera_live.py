"""The frame camera's port in real time: `sisa emulate`'s bridge gives it a pty, `sisa record`'s
sources read it (proved by a photo message whose CRC holds), the acquisition logs its bytes and
photo numbers (issue 37)."""

from __future__ import annotations

import queue
import time

from acquisition.camera_photo import PhotoMessage, encode_photo
from acquisition.handover import dispatch
from acquisition.live import LiveSources, Source
from acquisition.runner import Acquisition, AcquisitionConfig
from acquisition.syncfilter import SyncFilterConfig
from emulators.bridge import CanTarget, RealTimeBridge
from emulators.runtime import Output, Port
from recorder.messages import CameraPhotoLog, LoggedMessage, RawBytes, Topic


def test_a_photo_message_goes_from_the_emulator_pty_to_the_log() -> None:
    bridge = RealTimeBridge(CanTarget.parse("virtual:sisa-cam"), queue.SimpleQueue(),
                            camera=True)
    logged: list[tuple[LoggedMessage, Topic | None]] = []
    config = AcquisitionConfig(leap_s=18, sync=SyncFilterConfig(), ins_rate_hz=64.0,
                               nmea_rate_hz=1.0, line_rate_hz=62.5, camera_rate_hz=2.0)
    acq = Acquisition(config, lambda m, t: logged.append((m, t)), lambda _e: None)
    try:
        port = bridge.endpoints()["camera"]
        assert bridge.camera is not None
        sources = LiveSources(None, None, None, None, camera_port=port)
        try:
            wire = b"".join(encode_photo(PhotoMessage(n, 1000)) for n in (41, 42))
            bridge(Output(0, Port.CAMERA_SERIAL, wire))
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline and not any(
                    isinstance(m, CameraPhotoLog) and m.photo_number == 42 for m, _ in logged):
                for item in sources.poll(0.05):
                    if item.source is Source.CAMERA and isinstance(item.payload, bytes):
                        dispatch(acq, item)
        finally:
            sources.close()
    finally:
        bridge.close()
    photos = [m.photo_number for m, _ in logged if isinstance(m, CameraPhotoLog)]
    assert photos == [41, 42]
    raw = b"".join(m.data for m, t in logged if isinstance(m, RawBytes))
    assert raw == wire
    assert {t for m, t in logged if isinstance(m, RawBytes)} == {Topic.CAMERA_RAW}
    assert acq.streams["camera"].messages == 2


def test_without_a_camera_the_bridge_has_no_port_and_drops_camera_bytes() -> None:
    bridge = RealTimeBridge(CanTarget.parse("virtual:sisa-nocam"), queue.SimpleQueue())
    try:
        assert "camera" not in bridge.endpoints()
        assert bridge(Output(0, Port.CAMERA_SERIAL, b"\xc5\x5c")) == ()
    finally:
        bridge.close()
