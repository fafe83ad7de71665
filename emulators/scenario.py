"""The flight scenario: one pydantic model, loaded from TOML, that drives every emulator.

A scenario file may start from a preset (`base = "garrotxa"`) and override any table or field.
Every field carries its unit in its name; every range is checked at load time, so a bad file fails
with one line that names the field and its allowed range before anything runs.

Ranges are physical (what a survey aircraft or UAV, its sensors and its block can be) and keep
every derived quantity bounded: `Scenario` also checks what fields make together — the turn rate,
the length of the flight, the size of the DEM and of the scene raster — so that no valid scenario
can ask for a runaway allocation, a time past int64 nanoseconds or a date NMEA cannot write.
"""

from __future__ import annotations

import itertools
import math
import tomllib
from enum import StrEnum
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Final, Literal

from pydantic import Field, ValidationError, field_validator, model_validator

from emulators.block import STANDARD_GRAVITY_MPS2, block_extent_en_m, strip_lines
from recorder.settings import DEFAULT_HEADER_WINDOW_MS
from sisa.core.bounded import read_settings_text, toml_loads
from sisa.core.errors import ConfigError, one_line_text_problem, shown_value
from sisa.core.framecamera import FrameInterior, FrameMounting
from sisa.core.sensor import (
    Mounting,
    ScannerGeometry,
    StrictModel,
    first_non_finite,
    validation_text,
)
from sisa.core.timescale import parse_gps_datetime
from sisa.core.utm import central_meridian_deg, utm_zone

PRESETS = ("bench", "garrotxa", "bellmunt", "bench_camera")

# --- limits that keep every derived time, duration and array bounded -----------------------------

# GPS time is int64 ns from the GPS epoch (sisa.core.timescale), so nothing can start before it (and
# int64 would end in 2262). The binding upper limit is NMEA: RMC dates carry a two-digit year read
# as 1980..2079 (acquisition/nmea/wire.py, DateDdMmYy). A flight lasts at most MAX_FLIGHT_H, and UTC
# runs behind GPS time, so a start before the last day of 2079 keeps every sentence datable.
START_GPS_MIN = "1980-01-06T00:00:00"
START_GPS_MAX = "2079-12-31T00:00:00"  # exclusive
MIN_GROUND_SPEED_KMH = 10.0  # 2.8 m/s: slower than any survey aircraft or fixed-wing UAV
MAX_AIRFIELD_OFFSET_M = 200_000.0  # a ferry of up to ~1 h to the block
# The flight (alignment, take-off, climb, transit, strips and turns) may last at most this: the
# truth trajectory holds a spline node every 0.1 s (~45 MB per hour of flight while it is built).
MAX_FLIGHT_H = 24.0
# Coordinated turn rate g·tan(bank)/v. The trajectory smooths its path over ~1.5 s and plans arcs
# wider and faster by 1/k to make up for it (emulators.trajectory._Cruise): at 30°/s k = 0.73,
# beyond ~85°/s k reaches 0 and the planned turns cannot close. Survey turns are 3–15°/s.
MAX_TURN_RATE_DEG_S = 30.0
# The planning rules of emulators.trajectory, which `flight_duration_bound_s` follows: defined
# here and taken by that module (which imports scipy: this one must load without it).
_PLAN_SMOOTHING_SIGMA_S = 1.5
_PLAN_KERNEL_HALF_WIDTH_S = 3.0 * _PLAN_SMOOTHING_SIGMA_S  # triweight: σ = half-width / 3
_PLAN_CLIMB_OUT_MIN_S = 30.0
_PLAN_CLIMB_ACCELERATION_MPS2 = 1.0
_PLAN_CLIMB_RAMP_S = 3.0
# The synthetic DEM costs ~130 bytes per cell while it is made (FFT noise, ridges, river): 10
# million cells (e.g. 1 m over 3 × 3 km, 5 m over 15 × 15 km) take `sisa truth` to ~1.4 GB. Its
# extent is limited by the scanner emulator's ENU → UTM/height map, fitted to 1 mm up to ~1000 km.
MAX_DEM_CELLS = 10_000_000
MAX_DEM_SIDE_KM = 800.0
# The scene raster holds 4 bytes per texture cell over the DEM's extent: 250 million cells, 1 GB
# (`sisa truth` peaks at ~1.3 GB and takes ~2 min there).
MAX_SCENE_CELLS = 250_000_000
# Values per image line (pixels × bands): the scanner renders 128 lines at a time, ~10 bytes per
# value in flight. A CASI-1500 line (1500 × 288 = 432 000) fits and 2048 × 256 simulates in under
# 1 GB; a 65 536 × 288 line would need ~24 GB a block.
MAX_LINE_SAMPLES = 2**19
MAX_GROUND_POINTS = 10_000  # each of control and check points; Garrotxa has 111 and 96
# INS attitude errors (σ per axis): a navigation-grade INS is good to arcseconds to arcminutes.
# With at most 1° of bias and of noise, and a drift that adds at most 1° over the longest flight,
# even a 5σ draw leaves the attitude well inside what the INS records carry (pitch ±90°).
MAX_ATTITUDE_SIGMA_ARCSEC = 3600.0
MAX_ATTITUDE_DRIFT_ARCSEC_PER_H = MAX_ATTITUDE_SIGMA_ARCSEC / MAX_FLIGHT_H  # 150″/h
# Bytes of the receiver's sentences as acquisition.nmea writes them (at most; the tests check):
# the serial port must carry them all (`gps_serial_load`). A port loaded past GPS_LINK_WARN_LOAD
# queues sentences behind each other for long stretches; past 1, without end.
GGA_BYTES, RMC_BYTES, ZDA_BYTES, TAG_BYTES = 88, 82, 38, 34  # the longest of each
# NovAtel OEM7 ASCII logs as acquisition.novatel writes them (the longest of each)
BESTPOS_BYTES, TIME_LOG_BYTES, MARK_BYTES = 256, 168, 160
GPS_LINK_WARN_LOAD = 0.7


class GpsSolution(StrEnum):
    CODE = "code"
    PHASE = "phase"


class ReceiverModel(StrEnum):
    """What the GPS receiver speaks on its serial port (docs/protocols.md)."""

    ASHTECH_Z12 = "ashtech_z12"  # NMEA 2.3 (GP) + $PASHR,PTT / $PASHR,TTT time tags
    UBLOX_F9P = "ublox_f9p"  # NMEA 4.1 (GN) + UBX-TIM-TP / UBX-TIM-TM2 binary, one port
    NOVATEL_OEM7 = "novatel_oem7"  # NovAtel ASCII logs: BESTPOSA, TIMEA, MARK1TIMEA


class BlockSettings(StrictModel):
    """The photogrammetric block and the flight that covers it."""

    name: str = Field("bench", min_length=1, max_length=64)
    strips: int = Field(2, ge=1, le=200, description="main (N–S) strips")
    transversal_strips: int = Field(0, ge=0, le=50, description="E–W strips across the block")
    alternate_directions: bool = True
    strip_length_m: float = Field(3000.0, gt=0, le=500_000)
    side_overlap_pct: float = Field(50.0, ge=0, lt=100)
    flying_height_agl_m: float = Field(600.0, gt=10, le=20_000)
    ground_speed_kmh: float = Field(
        216.0, gt=0, le=1000, json_schema_extra={"minimum": MIN_GROUND_SPEED_KMH},
        description=f"at least {MIN_GROUND_SPEED_KMH:g} km/h (2.8 m/s): a survey aircraft or "
        "fixed-wing UAV",
    )
    start_gps: str = Field(
        "2026-06-15T09:00:00",
        description=f"GPS-scale ISO date-time, from the GPS epoch {START_GPS_MIN} to before "
        f"{START_GPS_MAX}: GPS time is counted from its epoch, and NMEA RMC dates carry a "
        f"two-digit year read as 1980–2079 (a flight lasts at most {MAX_FLIGHT_H:g} h)",
    )
    leap_seconds: int = Field(18, ge=0, le=60)
    centre_lat_deg: float = Field(41.6, ge=-85, le=85)
    centre_lon_deg: float = Field(2.0, ge=-180, le=180)
    first_strip_heading_deg: float = Field(
        0.0, ge=0, lt=360, description="true heading of the first strip (0 = flown north)"
    )

    @field_validator("name")
    @classmethod
    def _name_one_line(cls, name: str) -> str:
        """The name goes into messages and the sensor file's name (sisa.commands.process)."""
        if (problem := one_line_text_problem(name)) is not None:
            raise ValueError(problem)
        return name

    @field_validator("ground_speed_kmh")
    @classmethod
    def _speed_flies(cls, kmh: float) -> float:
        if not kmh >= MIN_GROUND_SPEED_KMH:
            raise ValueError(f"Input should be greater than or equal to {MIN_GROUND_SPEED_KMH:g}"
                             " km/h (2.8 m/s), the slowest survey aircraft or fixed-wing UAV")
        return kmh

    @field_validator("start_gps")
    @classmethod
    def _start_in_range(cls, text: str) -> str:
        t_ns = parse_gps_datetime(text)  # a ValueError names what is wrong with the text
        if not parse_gps_datetime(START_GPS_MIN) <= t_ns < parse_gps_datetime(START_GPS_MAX):
            raise ValueError(
                f"must be from {START_GPS_MIN} (the GPS epoch: GPS time counts from it) to "
                f"before {START_GPS_MAX} (NMEA dates carry a two-digit year read as 1980–2079, "
                f"and a flight may last {MAX_FLIGHT_H:g} h)")
        return text

    @property
    def t_start_gps_ns(self) -> int:
        return parse_gps_datetime(self.start_gps)

    @property
    def ground_speed_mps(self) -> float:
        return self.ground_speed_kmh / 3.6


_AirfieldOffsetM = Annotated[
    float, Field(ge=-MAX_AIRFIELD_OFFSET_M, le=MAX_AIRFIELD_OFFSET_M)]


class FlightSettings(StrictModel):
    """How the aircraft gets from the ground to the strips and between them."""

    static_alignment_s: float = Field(60.0, ge=0, le=7200, description="engines off on the ground")
    takeoff_acceleration_mps2: float = Field(2.5, ge=0.5, le=10, description="ground roll")
    rotation_speed_kmh: float = Field(150.0, gt=0, le=500)
    climb_rate_mps: float = Field(8.0, ge=0.5, le=50)
    turn_bank_deg: float = Field(
        30.0, gt=1, le=60,
        description=f"coordinated turns; the turn rate g·tan(bank)/speed may be at most "
        f"{MAX_TURN_RATE_DEG_S:g}°/s",
    )
    figure_eights: int = Field(1, ge=0, le=10, description="figure-eight manoeuvres after take-off")
    run_in_s: float = Field(10.0, ge=0, le=600, description="straight flight before/after a strip")
    airfield_offset_m: tuple[_AirfieldOffsetM, _AirfieldOffsetM] = Field(
        (-2000.0, -4000.0),
        description=f"runway start east, north of the block centre (each within "
        f"±{MAX_AIRFIELD_OFFSET_M / 1000:g} km)",
    )
    runway_heading_deg: float = Field(0.0, ge=0, lt=360)
    crab_deg: float = Field(1.5, ge=-30, le=30, description="constant wind crab while airborne")
    turbulence_attitude_deg: float = Field(0.3, ge=0, le=10, description="RMS roll/pitch/heading")
    turbulence_height_m: float = Field(1.0, ge=0, le=100, description="RMS vertical excursion")


class TerrainSettings(StrictModel):
    """Synthetic DEM, scene texture and ground points over the block."""

    mean_height_m: float = Field(300.0, ge=-500, le=9000, description="ellipsoidal")
    relief_m: float = Field(80.0, ge=0, le=5000, description="peak-to-peak relief")
    dem_spacing_m: float = Field(
        10.0, ge=0.1, le=1000,
        description=f"DEM grid spacing; the DEM over the block and its margin may have at most "
        f"{MAX_DEM_CELLS:,} cells and {MAX_DEM_SIDE_KM:g} km a side".replace(",", " "),
    )
    margin_m: float = Field(1500.0, ge=0, le=50_000, description="DEM extent beyond the block")
    texture_cell_m: float = Field(
        2.0, ge=0.01, le=1000,
        description=f"finest scene texture scale; the scene raster over the DEM may have at most "
        f"{MAX_SCENE_CELLS:,} cells".replace(",", " "),
    )
    control_points: int = Field(10, ge=0, le=MAX_GROUND_POINTS)
    check_points: int = Field(10, ge=0, le=MAX_GROUND_POINTS)


class ScannerSettings(ScannerGeometry):
    """The pushbroom scanner: geometry plus the timing of its frames."""

    bands: int = Field(4, ge=1, le=288, description=f"pixels × bands ≤ {MAX_LINE_SAMPLES}")
    line_period_ms: float = Field(16.0, gt=0.1, le=10_000, description="time between lines")
    integration_time_ms: float = Field(12.0, gt=0, le=10_000)
    frame_counter_bits: int = Field(16, ge=8, le=32)
    line_clock_jitter_ns: float = Field(50.0, ge=0, le=1e6, description="RMS ppf jitter")
    line_clock_drift_ppm: float = Field(15.0, ge=-1000, le=1000)
    header_latency_ms: tuple[float, float] = Field(
        (1.0, 3.0), description="frame end → header on the wire: uniform between these"
    )

    @model_validator(mode="after")
    def _integration_fits(self) -> ScannerSettings:
        if self.integration_time_ms > self.line_period_ms:
            raise ValueError(
                f"integration_time_ms = {self.integration_time_ms} must be ≤ line_period_ms "
                f"= {self.line_period_ms}"
            )
        lo, hi = self.header_latency_ms
        if not 0 <= lo <= hi <= 10_000:
            raise ValueError(f"header_latency_ms = ({lo}, {hi}) needs 0 ≤ min ≤ max ≤ 10000")
        if self.pixels * self.bands > MAX_LINE_SAMPLES:
            raise ValueError(
                f"pixels × bands = {self.pixels} × {self.bands} = {self.pixels * self.bands} "
                f"values per line, more than {MAX_LINE_SAMPLES} (a CASI-1500 line is 1500 × 288):"
                " fewer pixels or bands")
        return self


# a photo message's window (CameraSettings.message_window_ms), ms: it opens this much before
# the pulse (host stamps of two links) and closes this much after the longest latency and the
# read interval (wire, USB, queueing)
CAMERA_WINDOW_EARLY_MS: Final = 1.0
CAMERA_WINDOW_LATE_MS: Final = 5.0


class CameraFaults(StrictModel):
    """The frame camera's own faults, as rates; every one is written to the truth."""

    lost_pulse_fraction: float = Field(
        0.0, ge=0, le=1, description="exposures whose mid-exposure pulse never leaves the camera")
    lost_photo_number_fraction: float = Field(
        0.0, ge=0, le=1, description="exposures whose photo message is never sent")
    spurious_pulse_rate_hz: float = Field(
        0.0, ge=0, le=100, description="pulses on the camera's pulse line that no exposure "
        "made (Poisson)")
    on_frame_fraction: float = Field(
        0.0, ge=0, le=1, description="exposures moved onto a scanner frame's mid-exposure: "
        "the camera's pulse and the scanner's pulse at once (the sync unit's event input "
        "takes one)")


class CameraSettings(StrictModel):
    """A digital frame camera beside the scanner (issue 37): its model, its mounting, when it
    is triggered (only over the strips), and its wire timing (docs/frames.md, "Emulated
    camera"). Optional: a scenario without `[camera]` has none."""

    model: FrameInterior = Field(default_factory=FrameInterior)
    mounting: FrameMounting = Field(default_factory=FrameMounting)
    trigger_interval_s: float | None = Field(
        None, gt=0, le=3600, description="a photo every this many seconds over each strip "
        "(give this or trigger_distance_m)")
    trigger_distance_m: float | None = Field(
        None, gt=0, le=100_000, description="a photo every this many metres along track over "
        "each strip (give this or trigger_interval_s)")
    min_cycle_s: float = Field(
        0.5, ge=0.05, le=60, description="the camera's shortest time between exposures; the "
        "trigger may not ask for photos faster")
    exposure_time_ms: float = Field(1.0, gt=0, le=1000, description="shutter open")
    message_latency_ms: tuple[float, float] = Field(
        (20.0, 40.0), description="exposure end → photo message on the wire: uniform between "
        "these")
    photo_counter_bits: int = Field(16, ge=8, le=32, description="photo number width (wraps)")
    first_photo_number: int = Field(1, ge=0, le=2**32 - 1)
    faults: CameraFaults = Field(default_factory=CameraFaults)

    @model_validator(mode="after")
    def _trigger_and_timing(self) -> CameraSettings:
        if (self.trigger_interval_s is None) == (self.trigger_distance_m is None):
            raise ValueError("give one of trigger_interval_s and trigger_distance_m")
        if self.trigger_interval_s is not None and self.trigger_interval_s < self.min_cycle_s:
            raise ValueError(f"trigger_interval_s = {self.trigger_interval_s:g} is shorter than "
                             f"the camera's min_cycle_s = {self.min_cycle_s:g}")
        if self.exposure_time_ms > 1000.0 * self.min_cycle_s:
            raise ValueError(f"exposure_time_ms = {self.exposure_time_ms:g} must be ≤ "
                             f"min_cycle_s = {self.min_cycle_s:g} s")
        lo, hi = self.message_latency_ms
        if not 0 <= lo <= hi <= 10_000:
            raise ValueError(f"message_latency_ms = ({lo}, {hi}) needs 0 ≤ min ≤ max ≤ 10000")
        if self.first_photo_number >= 1 << self.photo_counter_bits:
            raise ValueError(f"first_photo_number = {self.first_photo_number} needs fewer than "
                             f"photo_counter_bits = {self.photo_counter_bits} bits")
        return self

    def message_window_ms(self, read_interval_ms: float) -> tuple[float, float]:
        """When a photo message may reach the recorder after its pulse (mid-exposure → read,
        host clock): from CAMERA_WINDOW_EARLY_MS before the pulse (the two links' host stamps)
        to half the exposure + the longest stated latency + the read interval +
        CAMERA_WINDOW_LATE_MS (wire, USB, queueing). It does not start at the shortest latency:
        an emulator run faster than real time (`sisa bench --speed 2`) delivers every latency
        that much shorter on the host clock, and the camera's next pulse is min_cycle_s away."""
        hi = self.message_latency_ms[1]
        return (-CAMERA_WINDOW_EARLY_MS,
                self.exposure_time_ms / 2 + hi + read_interval_ms + CAMERA_WINDOW_LATE_MS)

    def photo_rate_hz(self, ground_speed_mps: float) -> float:
        """Photos a second while triggered: by interval, or by distance at this speed."""
        if self.trigger_interval_s is not None:
            return 1.0 / self.trigger_interval_s
        return ground_speed_mps / (self.trigger_distance_m or math.inf)


_AttitudeSigmaArcsec = Annotated[float, Field(ge=0, le=MAX_ATTITUDE_SIGMA_ARCSEC)]
_AttitudeDriftArcsecPerH = Annotated[float, Field(ge=0, le=MAX_ATTITUDE_DRIFT_ARCSEC_PER_H)]


class InsSettings(StrictModel):
    """The navigation-grade INS: its record stream, its clock and its attitude errors."""

    rate_hz: float = Field(64.0, gt=0, le=2000)
    counter_bits: int = Field(16, ge=8, le=32, description="record counter width (wraps)")
    clock_offset_s: float = Field(12.5, ge=-1e6, le=1e6, description="INS clock at start")
    clock_drift_ppm: float = Field(35.0, ge=-1000, le=1000)
    clock_resolution_ns: int = Field(1000, ge=1, le=1_000_000, description="clock/latch tick")
    output_delay_ms: float = Field(55.0, ge=0, le=1000, description="measurement → output")
    attitude_bias_arcsec: tuple[
        _AttitudeSigmaArcsec, _AttitudeSigmaArcsec, _AttitudeSigmaArcsec] = Field(
        (10.0, 10.0, 30.0), description=f"σ roll, pitch, heading (each ≤ "
        f"{MAX_ATTITUDE_SIGMA_ARCSEC:g}″ = 1°)")
    attitude_drift_arcsec_per_h: tuple[
        _AttitudeDriftArcsecPerH, _AttitudeDriftArcsecPerH, _AttitudeDriftArcsecPerH] = Field(
        (5.0, 5.0, 15.0), description=f"σ of linear drift (each ≤ "
        f"{MAX_ATTITUDE_DRIFT_ARCSEC_PER_H:g}″/h: 1° over a {MAX_FLIGHT_H:g} h flight)")
    attitude_noise_arcsec: tuple[
        _AttitudeSigmaArcsec, _AttitudeSigmaArcsec, _AttitudeSigmaArcsec] = Field(
        (2.0, 2.0, 3.0), description=f"white noise σ (each ≤ {MAX_ATTITUDE_SIGMA_ARCSEC:g}″)")
    rate_noise_rps: float = Field(5e-6, ge=0, le=1.0, description="white body-rate noise σ")
    velocity_noise_mps: float = Field(2e-3, ge=0, le=10.0, description="white NED velocity noise σ")


class GpsSettings(StrictModel):
    """The geodetic receiver: NMEA stream, PPS and event input."""

    receiver: ReceiverModel = Field(
        ReceiverModel.ASHTECH_Z12, description="its protocol: ashtech_z12 (NMEA + $PASHR time "
        "tags), ublox_f9p (NMEA 4.1 + UBX-TIM-TP and UBX-TIM-TM2, interleaved) or "
        "novatel_oem7 (NovAtel ASCII logs BESTPOSA, TIMEA and MARK1TIMEA)"
    )
    nmea_rate_hz: float = Field(1.0, gt=0, le=20)
    solution: GpsSolution = GpsSolution.PHASE
    horizontal_noise_m: float | None = Field(
        None, ge=0, le=100, description="σ; default 1.0 for code, 0.03 for phase"
    )
    vertical_noise_m: float | None = Field(
        None, ge=0, le=100, description="σ; default 1.5 for code, 0.05 for phase"
    )
    noise_correlation_s: float = Field(60.0, gt=0, le=86_400, description="Gauss–Markov τ")
    pps_jitter_ns: float = Field(20.0, ge=0, le=1e6, description="RMS")
    event_tag_resolution_ns: int = Field(100, ge=1, le=1_000_000)
    max_event_rate_hz: float = Field(1.0, gt=0, le=1000)
    geoid_separation_m: float = Field(
        50.0, ge=-120, le=120, description="receiver's geoid: GGA altitude = height − this"
    )
    nmea_latency_ms: float = Field(40.0, ge=0, le=900, description="epoch → first sentence")
    serial_baud: int = Field(
        115_200, ge=1200, le=921_600, description="the receiver's serial port (8N1); it must "
        "carry the fixes and a TTT tag for every forwarded pulse (an Ashtech Z-12 ships at 9600)")

    @property
    def horizontal_sigma_m(self) -> float:
        if self.horizontal_noise_m is not None:
            return self.horizontal_noise_m
        return 1.0 if self.solution is GpsSolution.CODE else 0.03

    @property
    def vertical_sigma_m(self) -> float:
        if self.vertical_noise_m is not None:
            return self.vertical_noise_m
        return 1.5 if self.solution is GpsSolution.CODE else 0.05


class SisaSettings(StrictModel):
    """The synchronisation unit."""

    lfsr_bits: int = Field(4, ge=2, le=16, description="register length (period 2^n − 1 s)")
    lfsr_taps: tuple[int, ...] | None = Field(
        None, description="feedback taps (1-based); default from the maximal-length table"
    )
    one_of_n: int | Literal["auto"] = Field(
        "auto", description="forward 1 of every n frame pulses; auto = fastest the GPS accepts"
    )
    event_input_in_mode1: bool = Field(False, description="also send mode-1 pulses to the GPS")
    read_interval_ms: float = Field(
        5.0, ge=0, le=50, description="the recorder reads its devices on this clock (0: on "
        "every arrival); host receive times are up to this much late"
    )
    header_window_ms: tuple[float, float] = Field(
        DEFAULT_HEADER_WINDOW_MS,
        description="where a frame header's host time may fall after its frame "
        "ends; headers tie to frames on time alone only if this is narrower than a line period"
    )
    pps_gate_us: float = Field(
        5.0, gt=0, lt=1000, description="once locked on the PPS train, a PPS edge further than "
        "this from the timing board's prediction is spurious (keep it ≥ 6 × gps.pps_jitter_ns)"
    )
    accept_nmea_without_checksum: bool = Field(
        False, description="take NMEA sentences that carry no *hh checksum (some old receivers "
        "send none); by default they are refused and counted (nmea.no_checksum)"
    )

    @model_validator(mode="after")
    def _taps_in_range(self) -> SisaSettings:
        if self.lfsr_taps is not None:
            bad = [t for t in self.lfsr_taps if not 1 <= t <= self.lfsr_bits]
            if bad or not self.lfsr_taps:
                raise ValueError(f"lfsr_taps must lie in 1..lfsr_bits = {self.lfsr_bits}")
        if isinstance(self.one_of_n, int) and not 1 <= self.one_of_n <= 100_000:
            raise ValueError("one_of_n must be 'auto' or 1 ≤ n ≤ 100000")
        lo, hi = self.header_window_ms
        if not -10_000 <= lo < hi <= 10_000:
            raise ValueError(f"header_window_ms = ({lo}, {hi}) needs -10000 ≤ min < max ≤ 10000")
        return self


class TimedFault(StrictModel):
    """A fault that starts at a given time after the scenario start."""

    at_s: float = Field(ge=0, le=1e6)
    duration_s: float = Field(0.0, ge=0, le=1e6)
    jump_ms: float = Field(0.0, ge=-1e6, le=1e6, description="clock jumps only")


class FaultProfile(StrictModel):
    """Faults to inject; empty by default. Every injected fault is written to the truth."""

    lost_pulse_fraction: float = Field(0.0, ge=0, le=1)
    spurious_pulse_rate_hz: float = Field(0.0, ge=0, le=100)
    spurious_pps_near_second_ms: float = Field(
        0.0, ge=0, le=400, description="0: spurious pulses anywhere; else those on the PPS line "
        "fall within this of a whole GPS second, next to the true edge")
    corrupt_byte_rate: float = Field(0.0, ge=0, le=0.5, description="per byte")
    lost_byte_rate: float = Field(0.0, ge=0, le=0.5, description="per byte")
    lost_can_frame_fraction: float = Field(0.0, ge=0, le=1)
    corrupt_can_frame_fraction: float = Field(0.0, ge=0, le=1)
    dropped_frame_fraction: float = Field(0.0, ge=0, le=1, description="scanner frames")
    pps_outages: tuple[TimedFault, ...] = ()
    ins_clock_jumps: tuple[TimedFault, ...] = ()
    ins_reboots: tuple[TimedFault, ...] = ()
    sync_restarts: tuple[TimedFault, ...] = ()

    @property
    def empty(self) -> bool:
        return self == FaultProfile()


class Scenario(StrictModel):
    """Everything a simulated flight needs; see `sisa scenario schema` for the full schema."""

    seed: int = Field(1, ge=0, le=2**32 - 1)
    block: BlockSettings = BlockSettings()
    flight: FlightSettings = FlightSettings()
    terrain: TerrainSettings = TerrainSettings()
    scanner: ScannerSettings = ScannerSettings()
    ins: InsSettings = InsSettings()
    gps: GpsSettings = GpsSettings()
    mounting: Mounting = Mounting()
    sisa: SisaSettings = SisaSettings()
    faults: FaultProfile = FaultProfile()
    camera: CameraSettings | None = Field(
        None, description="a frame camera beside the scanner; none unless this table is given")

    @model_validator(mode="after")
    def _all_finite_and_bounded(self) -> Scenario:
        where = first_non_finite(self.model_dump())
        if where is not None:
            raise ValueError(f"{where}: must be a finite number (not NaN or infinity)")
        _check_turn_rate(self)
        _check_gps_link(self)
        _check_flight_duration(self)
        _check_terrain_size(self)
        _check_camera_cycle(self)
        return self


def _check_camera_cycle(scn: Scenario) -> None:
    """A trigger distance flown at the block's ground speed must not ask the camera for photos
    faster than it can take them; a photo message's window must be shorter than its cycle."""
    cam = scn.camera
    if cam is None:
        return
    lo, hi = cam.message_window_ms(scn.sisa.read_interval_ms)
    if hi - lo >= 1000.0 * cam.min_cycle_s:
        raise ValueError(
            f"camera.message_latency_ms = {list(cam.message_latency_ms)}: a photo message may "
            f"reach the recorder anywhere in a window {hi - lo:g} ms wide (with the exposure "
            "and sisa.read_interval_ms), not shorter than camera.min_cycle_s = "
            f"{cam.min_cycle_s:g} s: two pulses could fall in one message's window and no "
            "photo number could be tied to its pulse")
    if cam.trigger_distance_m is None:
        return
    interval_s = cam.trigger_distance_m / scn.block.ground_speed_mps
    if interval_s < cam.min_cycle_s:
        raise ValueError(
            f"camera.trigger_distance_m: {cam.trigger_distance_m:g} m at "
            f"{scn.block.ground_speed_kmh:g} km/h (block.ground_speed_kmh) is a photo every "
            f"{interval_s:.3g} s, faster than camera.min_cycle_s = {cam.min_cycle_s:g} s")


def turn_rate_deg_s(scn: Scenario) -> float:
    """Rate of a coordinated turn at the block speed and the flight's bank: g·tan(bank)/v."""
    bank = math.radians(scn.flight.turn_bank_deg)
    return math.degrees(STANDARD_GRAVITY_MPS2 * math.tan(bank) / scn.block.ground_speed_mps)


def _check_turn_rate(scn: Scenario) -> None:
    rate = turn_rate_deg_s(scn)
    if rate <= MAX_TURN_RATE_DEG_S:
        return
    kmh = scn.block.ground_speed_kmh
    max_bank = math.degrees(math.atan(math.radians(MAX_TURN_RATE_DEG_S)
                                      * scn.block.ground_speed_mps / STANDARD_GRAVITY_MPS2))
    raise ValueError(
        f"flight.turn_bank_deg: a {scn.flight.turn_bank_deg:g}° bank at {kmh:g} km/h "
        f"(block.ground_speed_kmh) turns at {rate:.3g}°/s, more than {MAX_TURN_RATE_DEG_S:g}°/s "
        f"(the trajectory rolls turns in over ~1.5 s): bank at most {max_bank:.2f}° at this "
        "speed, or fly faster")


def gps_event_rate_hz(scn: Scenario) -> float:
    """Pulses a second the sync unit sends to the receiver's event input at most: 1 of n frame
    pulses in mode 2 (held to the receiver's maximum event rate), one-bits in mode 1 if sent,
    and a frame camera's pulses (the input takes none faster than its maximum rate)."""
    from emulators.block import resolve_one_of_n  # emulators.block imports this module

    mode2 = min(1000.0 / scn.scanner.line_period_ms / resolve_one_of_n(scn),
                scn.gps.max_event_rate_hz)
    rate = max(mode2, 1.0 if scn.sisa.event_input_in_mode1 else 0.0)
    if scn.camera is not None:  # the camera's pulses share the input (at most its rate)
        rate = min(rate + scn.camera.photo_rate_hz(scn.block.ground_speed_mps),
                   scn.gps.max_event_rate_hz)
    return rate


def gps_serial_load(scn: Scenario) -> tuple[float, float]:
    """(bytes a second the receiver's port must send, the fraction of its capacity): GGA and RMC
    every epoch, ZDA and PTT every second, a TTT for every pulse on the event input (a NovAtel:
    BESTPOS every epoch, TIME every second, MARK1TIME for every pulse)."""
    g = scn.gps
    if g.receiver is ReceiverModel.NOVATEL_OEM7:
        per_s = (g.nmea_rate_hz * BESTPOS_BYTES + TIME_LOG_BYTES
                 + gps_event_rate_hz(scn) * MARK_BYTES)
        return per_s, per_s / (g.serial_baud / 10.0)
    per_s = (g.nmea_rate_hz * (GGA_BYTES + RMC_BYTES) + min(g.nmea_rate_hz, 1.0) * ZDA_BYTES
             + TAG_BYTES + gps_event_rate_hz(scn) * TAG_BYTES)
    return per_s, per_s / (g.serial_baud / 10.0)


def _tag_bytes(scn: Scenario) -> int:
    return MARK_BYTES if scn.gps.receiver is ReceiverModel.NOVATEL_OEM7 else TAG_BYTES


def _check_gps_link(scn: Scenario) -> None:
    per_s, load = gps_serial_load(scn)
    if load <= 1.0:
        return
    raise ValueError(
        f"gps.serial_baud: {scn.gps.serial_baud} baud carries {scn.gps.serial_baud // 10} bytes "
        f"a second; the receiver would have to send {per_s:.0f} (fixes at gps.nmea_rate_hz, a "
        f"{_tag_bytes(scn)}-byte time tag for each of {gps_event_rate_hz(scn):.3g} forwarded "
        "pulses a second): its tags would queue without end. A faster port, a larger "
        "sisa.one_of_n, or a lower gps.max_event_rate_hz")


def flight_duration_bound_s(scn: Scenario) -> dict[str, float]:
    """An upper bound on the flight's length, by part, from the planning rules of
    emulators.trajectory (what `scenario show` reports as flight_duration_s never exceeds the
    sum): take-off and climb, transit to the first strip, the strips with their run-in and
    run-out, and the turns between them. A Dubins path between poses d apart with planned arc
    radius R is no longer than the better of its turn–straight–turn words in one sense (right,
    right or left, left): arcs of at most 3π in all, a straight of at most d + 2R. Arcs are
    planned at R = r/k and flown at v/k, where k = Σ w·cos(ωτ) ≥ 1 − (ωσ)²/2 for the smoothing
    kernel w of second moment σ²."""
    f, v = scn.flight, scn.block.ground_speed_mps
    omega = math.radians(turn_rate_deg_s(scn))
    circle_s = 2.0 * math.pi / omega
    k = 1.0 - 0.5005 * (omega * _PLAN_SMOOTHING_SIGMA_S) ** 2  # the discrete kernel: σ² + 6e-7
    planned_radius_m = v / omega / k

    def dubins_s(distance_m: float) -> float:
        return (distance_m + (2.0 + 3.0 * math.pi) * planned_radius_m) / v

    v_rot = f.rotation_speed_kmh / 3.6
    t_motion = f.static_alignment_s + _PLAN_KERNEL_HALF_WIDTH_S
    takeoff_s = v_rot / f.takeoff_acceleration_mps2
    accel_s = abs(v - v_rot) / _PLAN_CLIMB_ACCELERATION_MPS2
    cruise_s = max(_PLAN_CLIMB_OUT_MIN_S - accel_s, _PLAN_KERNEL_HALF_WIDTH_S)
    climb_out_m = (v_rot**2 / (2.0 * f.takeoff_acceleration_mps2)
                   + abs(v**2 - v_rot**2) / (2.0 * _PLAN_CLIMB_ACCELERATION_MPS2) + v * cruise_s)
    steady_s = scn.block.flying_height_agl_m / f.climb_rate_mps
    climb_end = (t_motion + takeoff_s + 2.0 * _PLAN_KERNEL_HALF_WIDTH_S + steady_s
                 + min(_PLAN_CLIMB_RAMP_S, steady_s))
    straight_m = v * max(f.run_in_s, _PLAN_KERNEL_HALF_WIDTH_S)

    lines = strip_lines(scn)
    ends = []  # (run-in start, run-out end) of every strip, local plane metres
    for line in lines:
        h = math.radians(line.heading_deg)
        ue, un = math.sin(h), math.cos(h)
        ends.append(((line.start_en_m[0] - ue * straight_m, line.start_en_m[1] - un * straight_m),
                     (line.end_en_m[0] + ue * straight_m, line.end_en_m[1] + un * straight_m)))
    transit_m = math.hypot(*f.airfield_offset_m) + climb_out_m + math.hypot(*ends[0][0])
    before_survey = (t_motion + takeoff_s + accel_s + cruise_s
                     + f.figure_eights * 2.0 * circle_s + dubins_s(transit_m))
    first_run_in = max(before_survey, climb_end + circle_s)  # holding circles end the climb
    return {
        "take-off, climb and transit": first_run_in,
        "strips": sum(line.length_m + 2.0 * straight_m for line in lines) / v,
        "turns": sum(dubins_s(math.dist(a[1], b[0])) for a, b in itertools.pairwise(ends)),
    }


def _check_flight_duration(scn: Scenario) -> None:
    parts = flight_duration_bound_s(scn)
    total_h = sum(parts.values()) / 3600.0
    if total_h <= MAX_FLIGHT_H:
        return
    shown = ", ".join(f"{name} {s / 3600.0:.3g} h" for name, s in parts.items())
    raise ValueError(
        f"block: the flight would last up to {total_h:.3g} h ({shown}), more than "
        f"{MAX_FLIGHT_H:g} h: fewer or shorter block.strips / block.strip_length_m, a higher "
        "block.ground_speed_kmh or flight.turn_bank_deg, or a nearer flight.airfield_offset_m")


def dem_extent_m(scn: Scenario) -> tuple[float, float]:
    """East–west and north–south extent of the DEM (a UTM box holding every strip's swath, plus
    terrain.margin_m on each side), to within a per cent: the block's extent in its local plane,
    turned by the UTM grid convergence at the block centre and scaled by at most 1.01."""
    e0, n0, e1, n1 = block_extent_en_m(scn)
    lat, lon = scn.block.centre_lat_deg, scn.block.centre_lon_deg
    central_meridian = central_meridian_deg(utm_zone(lon, lat))  # LocalPlane.utm_epsg's zone
    gamma = math.atan(math.tan(math.radians(lon - central_meridian))
                      * math.sin(math.radians(lat)))
    c, s = abs(math.cos(gamma)), abs(math.sin(gamma))
    w, h = 1.01 * (e1 - e0), 1.01 * (n1 - n0)
    margin = 2.0 * scn.terrain.margin_m
    return w * c + h * s + margin, h * c + w * s + margin


def _check_terrain_size(scn: Scenario) -> None:
    width_m, height_m = dem_extent_m(scn)
    if max(width_m, height_m) > MAX_DEM_SIDE_KM * 1000.0:
        raise ValueError(
            f"terrain: the DEM over the block and terrain.margin_m would span "
            f"{width_m / 1000:.0f} × {height_m / 1000:.0f} km, more than {MAX_DEM_SIDE_KM:g} km "
            "a side (the scanner emulator maps ground coordinates to 1 mm only that far): fewer "
            "or shorter block.strips / block.strip_length_m, or a smaller terrain.margin_m")
    ts = scn.terrain

    def cells(cell_m: float) -> float:
        return (math.ceil(width_m / cell_m) + 1) * (math.ceil(height_m / cell_m) + 1)

    def finest_m(limit: int) -> float:
        """The smallest cell, rounded up to two digits, with (w/c + 2)·(h/c + 2) ≤ limit."""
        a, b = width_m * height_m, 2.0 * (width_m + height_m)
        inverse = (-b + math.sqrt(b * b - 4.0 * a * (4.0 - limit))) / (2.0 * a)
        step = 10.0 ** (math.floor(math.log10(1.0 / inverse)) - 1)
        return math.ceil(1.0 / inverse / step) * step

    def millions(count: float) -> str:
        return f"{count / 1e6:,.0f}".replace(",", " ") if count >= 1e7 else f"{count / 1e6:.2g}"

    size = f"{width_m / 1000:.3g} × {height_m / 1000:.3g} km"
    for name, cell_m, raster, limit, remedy in (
            ("dem_spacing_m", ts.dem_spacing_m, "DEM over the block and terrain.margin_m",
             MAX_DEM_CELLS, "spacing"),
            ("texture_cell_m", ts.texture_cell_m, "scene raster over the DEM", MAX_SCENE_CELLS,
             "cell")):
        if (count := cells(cell_m)) > limit:
            raise ValueError(
                f"terrain.{name}: a {cell_m:g} m {raster} ({size}) would have about "
                f"{millions(count)} million cells, more than {limit / 1e6:g} million: a {remedy} "
                f"of at least {finest_m(limit):.3g} m, or a smaller block or margin")


def _merge(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    merged = dict(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _merge(merged[key], value)
        else:
            merged[key] = value
    return merged


def _preset_table(name: str) -> dict[str, Any]:
    """A preset's table, its own `base` (a preset on another: bench_camera) resolved."""
    text = resources.files("emulators.presets").joinpath(f"{name}.toml").read_text("utf-8")
    table = tomllib.loads(text)
    base = table.pop("base", None)
    return table if base is None else _merge(_preset_table(base), table)


def scenario_from_table(table: dict[str, Any], source: str = "scenario") -> Scenario:
    """Validate a TOML-shaped table, resolving `base = PRESET` first. A `[derived]` table (the
    figures `sisa scenario show` prints after the settings) is output, not settings: left out,
    so that the printed scenario can be saved and flown again."""
    table = dict(table)
    if isinstance(table.get("derived"), dict):
        del table["derived"]
    base = table.pop("base", None)
    if base is not None:
        if base not in PRESETS:
            raise ConfigError(f"{source}: base: unknown preset {shown_value(base)} (one of "
                              f"{PRESETS})")
        table = _merge(_preset_table(base), table)
    try:
        return Scenario.model_validate(table)
    except ValidationError as exc:
        raise ConfigError(f"{source}: {validation_text(exc)}") from None


def load_scenario(name_or_path: str | Path) -> Scenario:
    """A preset by name, or a TOML file."""
    text = str(name_or_path)
    if text in PRESETS:
        return scenario_from_table(_preset_table(text), source=f"preset {text}")
    path = Path(text)
    if not path.is_file():
        raise ConfigError(f"no preset or scenario file named {shown_value(text, 200)} (presets: "
                          f"{', '.join(PRESETS)})")
    try:
        table = toml_loads(read_settings_text(path))
    except (OSError, ValueError) as exc:  # TOMLDecodeError, bad UTF-8, an int > 4300 digits,
        # nested too deep, too large
        raise ConfigError(f"{path}: not a readable TOML file: {exc}") from None
    return scenario_from_table(table, source=str(path))
