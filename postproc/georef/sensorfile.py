"""The sensor file: what georeferencing must know about the instrument, as one TOML file.

    name = "CASI-501 #2 on EC-FXX"
    time_delay_ms = 0.0          # the scanner's true exposure is this much after its time tag

    [scanner]                     # interior geometry incl. self-calibration (sisa.core.sensor)
    pixels = 512
    focal_length_mm = 9.33
    delta_focal_mm = 0.65
    ...
    [mounting]                    # lever arm, antenna offset (body frame, m), boresight (arcsec)
    lever_arm_m = [0.0, 0.0, 0.3]
    ...

Calibration (`sisa calibrate`) writes the same format with the estimated values, so its output
is what `sisa georef --sensor` takes. Unknown keys are errors: a misspelt field must not silently
fall back to a default.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import tomli_w
from pydantic import Field, ValidationError, field_validator, model_validator

from sisa.core.bounded import read_settings_text, toml_loads
from sisa.core.errors import InputError, one_line_text_problem, shown_value
from sisa.core.sensor import (
    Mounting,
    ScannerGeometry,
    StrictModel,
    first_non_finite,
    validation_text,
)

# A name is a label for messages and reports: one line, and short enough to read in them.
# `sisa calibrate` names its output after its input plus CALIBRATED_SUFFIX, which a name at the
# limit must still take (postproc.calibration.adjust.calibrated_sensor).
MAX_NAME_CHARS = 200
CALIBRATED_SUFFIX = " (calibrated)"


class SensorModel(StrictModel):
    """Scanner geometry, its mounting on the INS and the scanner–navigation time delay."""

    name: str = Field("CASI-501 (nominal)", description="which instrument this describes")
    time_delay_ms: float = Field(0.0, ge=-10_000, le=10_000,
                                 description="true exposure − tagged line time")
    scanner: ScannerGeometry = ScannerGeometry()
    mounting: Mounting = Mounting()

    @field_validator("name")
    @classmethod
    def _name_one_short_line(cls, name: str) -> str:
        """The name goes into one-line messages: no newline or control character, no essay."""
        if (problem := one_line_text_problem(name)) is not None:
            raise ValueError(problem)
        if len(name.removesuffix(CALIBRATED_SUFFIX)) > MAX_NAME_CHARS:
            raise ValueError(f"at most {MAX_NAME_CHARS} characters (this one has {len(name)})")
        return name

    @property
    def time_delay_ns(self) -> int:
        return round(self.time_delay_ms * 1e6)

    @classmethod
    def load(cls, path: Path) -> SensorModel:
        """One-line InputError naming the file and the first bad field."""
        try:
            data = toml_loads(read_settings_text(Path(path)))
        except OSError as exc:
            raise InputError(f"{path}: cannot read the sensor file: {exc.strerror}") from None
        except ValueError as exc:  # TOMLDecodeError, bad UTF-8, an integer of > 4300 digits,
            # nested too deep, too large
            raise InputError(f"{path}: not a TOML sensor file: {exc}") from None
        if not _has_a_field(data):  # else every value would silently be the nominal one
            raise InputError(f"{path}: empty sensor file (no fields): for the nominal sensor, "
                             "leave out --sensor")
        try:
            return cls.model_validate(data)
        except ValidationError as exc:
            raise InputError(f"{path}: {validation_text(exc)}") from None

    def to_toml(self) -> str:
        return tomli_w.dumps(self.model_dump(mode="json"))

    @model_validator(mode="after")
    def _all_finite(self) -> SensorModel:
        where = first_non_finite(self.model_dump())
        if where is not None:
            raise ValueError(f"{where}: must be a finite number (not NaN or infinity)")
        return self

    def check_pixels(self, pixels: int, where: str) -> None:
        """A sensor file for another instrument must not be applied to this recording."""
        if pixels != self.scanner.pixels:
            raise InputError(f"{where}: {pixels} pixels per line, but the sensor file "
                             f"{shown_value(self.name)} describes {self.scanner.pixels}: wrong "
                             "sensor file?")


def _has_a_field(table: dict[str, Any]) -> bool:
    """Whether a TOML document sets any value, not only (empty) tables."""
    return any(not isinstance(v, dict) or _has_a_field(v) for v in table.values())
