"""The flight scenario: one pydantic model, loaded from TOML, that drives every emulator.

A scenario file may start from a preset (`base = "garrotxa"`) and override any table or field.
Every field carries its unit in its name; every range is checked at load time, so a bad file fails
with one line that names the field and its allowed range before anything runs.
"""

from __future__ import annotations

import tomllib
from enum import StrEnum
from importlib import resources
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, ValidationError, model_validator

from sisa.errors import ConfigError
from sisa.sensor import Mounting, ScannerGeometry, StrictModel, Vec3, first_non_finite
from sisa.timescale import parse_gps_datetime

PRESETS = ("bench", "garrotxa", "bellmunt")


class GpsSolution(StrEnum):
    CODE = "code"
    PHASE = "phase"


class BlockSettings(StrictModel):
    """The photogrammetric block and the flight that covers it."""

    name: str = Field("bench", min_length=1, max_length=64)
    strips: int = Field(2, ge=1, le=200, description="main (N–S) strips")
    transversal_strips: int = Field(0, ge=0, le=50, description="E–W strips across the block")
    alternate_directions: bool = True
    strip_length_m: float = Field(3000.0, gt=0, le=500_000)
    side_overlap_pct: float = Field(50.0, ge=0, lt=100)
    flying_height_agl_m: float = Field(600.0, gt=10, le=20_000)
    ground_speed_kmh: float = Field(216.0, gt=0, le=1500)
    start_gps: str = Field("2026-06-15T09:00:00", description="GPS-scale ISO date-time")
    leap_seconds: int = Field(18, ge=0, le=60)
    centre_lat_deg: float = Field(41.6, ge=-85, le=85)
    centre_lon_deg: float = Field(2.0, ge=-180, le=180)
    first_strip_heading_deg: float = Field(
        0.0, ge=0, lt=360, description="true heading of the first strip (0 = flown north)"
    )

    @model_validator(mode="after")
    def _start_parses(self) -> BlockSettings:
        try:
            parse_gps_datetime(self.start_gps)
        except ValueError as exc:
            raise ValueError(f"start_gps: {exc}") from None
        return self

    @property
    def t_start_gps_ns(self) -> int:
        return parse_gps_datetime(self.start_gps)

    @property
    def ground_speed_mps(self) -> float:
        return self.ground_speed_kmh / 3.6


class FlightSettings(StrictModel):
    """How the aircraft gets from the ground to the strips and between them."""

    static_alignment_s: float = Field(60.0, ge=0, le=7200, description="engines off on the ground")
    takeoff_acceleration_mps2: float = Field(2.5, gt=0, le=10)
    rotation_speed_kmh: float = Field(150.0, gt=0, le=500)
    climb_rate_mps: float = Field(8.0, gt=0, le=50)
    turn_bank_deg: float = Field(30.0, gt=1, le=60)
    figure_eights: int = Field(1, ge=0, le=10, description="figure-eight manoeuvres after take-off")
    run_in_s: float = Field(10.0, ge=0, le=600, description="straight flight before/after a strip")
    airfield_offset_m: tuple[float, float] = Field(
        (-2000.0, -4000.0), description="runway start east, north of the block centre"
    )
    runway_heading_deg: float = Field(0.0, ge=0, lt=360)
    crab_deg: float = Field(1.5, ge=-30, le=30, description="constant wind crab while airborne")
    turbulence_attitude_deg: float = Field(0.3, ge=0, le=10, description="RMS roll/pitch/heading")
    turbulence_height_m: float = Field(1.0, ge=0, le=100, description="RMS vertical excursion")


class TerrainSettings(StrictModel):
    """Synthetic DEM, scene texture and ground points over the block."""

    mean_height_m: float = Field(300.0, ge=-500, le=9000, description="ellipsoidal")
    relief_m: float = Field(80.0, ge=0, le=5000, description="peak-to-peak relief")
    dem_spacing_m: float = Field(10.0, gt=0, le=1000)
    margin_m: float = Field(1500.0, ge=0, le=50_000, description="DEM extent beyond the block")
    texture_cell_m: float = Field(2.0, gt=0, le=1000, description="finest scene texture scale")
    control_points: int = Field(10, ge=0, le=100_000)
    check_points: int = Field(10, ge=0, le=100_000)


class ScannerSettings(ScannerGeometry):
    """The pushbroom scanner: geometry plus the timing of its frames."""

    bands: int = Field(4, ge=1, le=288)
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
        return self


class InsSettings(StrictModel):
    """The navigation-grade INS: its record stream, its clock and its attitude errors."""

    rate_hz: float = Field(64.0, gt=0, le=2000)
    counter_bits: int = Field(16, ge=8, le=32, description="record counter width (wraps)")
    clock_offset_s: float = Field(12.5, ge=-1e6, le=1e6, description="INS clock at start")
    clock_drift_ppm: float = Field(35.0, ge=-1000, le=1000)
    clock_resolution_ns: int = Field(1000, ge=1, le=1_000_000, description="clock/latch tick")
    output_delay_ms: float = Field(55.0, ge=0, le=1000, description="measurement → output")
    attitude_bias_arcsec: Vec3 = Field((10.0, 10.0, 30.0), description="σ roll, pitch, heading")
    attitude_drift_arcsec_per_h: Vec3 = Field((5.0, 5.0, 15.0), description="σ of linear drift")
    attitude_noise_arcsec: Vec3 = Field((2.0, 2.0, 3.0), description="white noise σ")
    rate_noise_rps: float = Field(5e-6, ge=0, le=1.0, description="white body-rate noise σ")
    velocity_noise_mps: float = Field(2e-3, ge=0, le=10.0, description="white NED velocity noise σ")


class GpsSettings(StrictModel):
    """The geodetic receiver: NMEA stream, PPS and event input."""

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
        (-2.0, 10.0), description="where a frame header's host time may fall after its frame "
        "ends; headers tie to frames on time alone only if this is narrower than a line period"
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

    @model_validator(mode="after")
    def _all_finite(self) -> Scenario:
        where = first_non_finite(self.model_dump())
        if where is not None:
            raise ValueError(f"{where}: must be a finite number (not NaN or infinity)")
        return self


def _merge(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    merged = dict(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _merge(merged[key], value)
        else:
            merged[key] = value
    return merged


def _preset_table(name: str) -> dict[str, Any]:
    text = resources.files("emulators.presets").joinpath(f"{name}.toml").read_text("utf-8")
    return tomllib.loads(text)


def _format_validation_error(source: str, exc: ValidationError) -> str:
    err = exc.errors()[0]
    loc = ".".join(str(p) for p in err["loc"])
    more = f" (and {exc.error_count() - 1} more)" if exc.error_count() > 1 else ""
    if err["type"] == "extra_forbidden":
        return f"{source}: unknown field {loc!r}{more}"  # repr: a key may hold a newline
    msg = err["msg"].removeprefix("Value error, ")
    got = err.get("input")
    shown = "" if isinstance(got, dict) else f" (got {got!r})"
    return f"{source}: {loc + ': ' if loc else ''}{msg}{shown}{more}"


def scenario_from_table(table: dict[str, Any], source: str = "scenario") -> Scenario:
    """Validate a TOML-shaped table, resolving `base = PRESET` first."""
    table = dict(table)
    base = table.pop("base", None)
    if base is not None:
        if base not in PRESETS:
            raise ConfigError(f"{source}: base: unknown preset {base!r} (one of {PRESETS})")
        table = _merge(_preset_table(base), table)
    try:
        return Scenario.model_validate(table)
    except ValidationError as exc:
        raise ConfigError(_format_validation_error(source, exc)) from None


def load_scenario(name_or_path: str | Path) -> Scenario:
    """A preset by name, or a TOML file."""
    text = str(name_or_path)
    if text in PRESETS:
        return scenario_from_table(_preset_table(text), source=f"preset {text}")
    path = Path(text)
    if not path.is_file():
        raise ConfigError(f"no preset or scenario file named {text!r} (presets: {PRESETS})")
    try:
        table = tomllib.loads(path.read_text("utf-8"))
    except (OSError, ValueError) as exc:  # TOMLDecodeError, bad UTF-8, an int > 4300 digits
        raise ConfigError(f"{path}: not a readable TOML file: {exc}") from None
    return scenario_from_table(table, source=str(path))
