"""The acquisition's settings from a scenario file: what an operator tells the logging computer
(rates, leap seconds, the sync unit's register and 1-of-n). Light on imports: `sisa record` starts
fast."""

from __future__ import annotations

from acquisition.runner import AcquisitionConfig
from acquisition.syncfilter import SyncFilterConfig
from emulators.block import resolve_one_of_n
from emulators.scenario import ReceiverModel, Scenario
from recorder.settings import CAMERA_WINDOW_KEY, HEADER_WINDOW_KEY, READ_INTERVAL_KEY


def acquisition_config(scn: Scenario) -> AcquisitionConfig:
    """What the acquisition is told by its operator: rates, leap seconds, sync settings."""
    line_period_ns = round(scn.scanner.line_period_ms * 1e6)
    sync = SyncFilterConfig(
        lfsr_bits=scn.sisa.lfsr_bits,
        lfsr_taps=scn.sisa.lfsr_taps,
        one_of_n=resolve_one_of_n(scn),
        max_event_rate_hz=scn.gps.max_event_rate_hz,
        event_input_in_mode1=scn.sisa.event_input_in_mode1,
        line_period_ns=line_period_ns,
        frame_counter_bits=scn.scanner.frame_counter_bits,
        header_latency_min_ns=round(scn.sisa.header_window_ms[0] * 1e6),
        header_latency_max_ns=round(scn.sisa.header_window_ms[1] * 1e6),
        pps_gate_ns=round(scn.sisa.pps_gate_us * 1e3),
    )
    return AcquisitionConfig(leap_s=scn.block.leap_seconds, sync=sync,
                             ins_rate_hz=scn.ins.rate_hz, nmea_rate_hz=scn.gps.nmea_rate_hz,
                             line_rate_hz=1e9 / line_period_ns,
                             read_interval_ns=round(scn.sisa.read_interval_ms * 1e6),
                             accept_nmea_without_checksum=scn.sisa.accept_nmea_without_checksum,
                             gps_ubx=scn.gps.receiver is ReceiverModel.UBLOX_F9P,
                             gps_novatel=scn.gps.receiver is ReceiverModel.NOVATEL_OEM7,
                             camera_rate_hz=None if scn.camera is None
                             else 1.0 / scn.camera.min_cycle_s,
                             camera_message_window_ms=camera_message_window_ms(scn))


def camera_message_window_ms(scn: Scenario) -> tuple[float, float] | None:
    """When a frame camera's photo message may reach the host after its pulse
    (`CameraSettings.message_window_ms`), what the operator tells the logging computer of it;
    None without a camera."""
    if scn.camera is None:
        return None
    return scn.camera.message_window_ms(scn.sisa.read_interval_ms)


def recording_settings(config: AcquisitionConfig) -> dict[str, str]:
    """The sync filter's header window and the read clock, for the log's metadata: `sisa sync`
    names them when they left every frame pulse untied (a scanner faster than the window)."""
    sync = config.sync
    settings = {HEADER_WINDOW_KEY: f"{sync.header_latency_min_ns / 1e6:g},"
                                   f"{sync.header_latency_max_ns / 1e6:g}",
                READ_INTERVAL_KEY: f"{config.read_interval_ns / 1e6:g}"}
    if config.camera_message_window_ms is not None:
        lo, hi = config.camera_message_window_ms
        settings[CAMERA_WINDOW_KEY] = f"{lo:g},{hi:g}"
    return settings
