"""The sensor model every stage shares: scanner interior geometry and its mounting on the INS.

Conventions (docs/conventions.md):
- Camera frame c: x along flight, y to the left, z up; the scanner looks along −z.
  Pixel j (0-based, pixel centre) looks along
  (x0 + δx0, (j − c)·pitch + y0 + δy0, −(f + δf)) with c = (pixels − 1) / 2,
  so pixel 0 looks to the right of the flight direction and the raw image is not mirrored.
- Body frame b (INS): x forward, y right, z down. Nominal mounting R_c^b = diag(1, −1, −1);
  the boresight misalignment (ω, φ, κ) is a small rotation applied after it:
  R_c^b = R_nominal · Rx(ω) · Ry(φ) · Rz(κ).
- Lever arm a^b: INS centre → scanner perspective centre; antenna offset g^b: INS centre →
  antenna phase centre; both in metres in the body frame.
"""

from __future__ import annotations

import math
from typing import Annotated, Any

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from sisa.core.errors import shown_text, shown_value

ARCSEC_RAD = np.pi / (180.0 * 3600.0)
R_NOMINAL_C_TO_B = np.diag([1.0, -1.0, -1.0])

# --- physical ranges: a file outside them is a typo, and the numbers it makes overflow ----------

# Lever arm and antenna offset: the largest aircraft (An-225: 84 m long, 88 m span) fits in a
# 100 m box, so no point of one airframe is farther than this from its INS along any axis.
MAX_MOUNT_OFFSET_M = 100.0
# Boresight: ±180° about each axis covers every rotation (beyond, an angle repeats).
MAX_BORESIGHT_ARCSEC = 180.0 * 3600.0
# Interior geometry: the shortest focal lengths (phone and endoscope lenses) are ~1 mm and the
# finest detector pixels ~0.5 µm, both well above these minima; a principal point (or its
# correction) lies on the detector, and 10 cm is more than half the width of any real one.
MIN_FOCAL_LENGTH_MM = 0.1
MIN_PIXEL_PITCH_UM = 0.1
MAX_PRINCIPAL_POINT_UM = 1e5

_OffsetM = Annotated[float, Field(ge=-MAX_MOUNT_OFFSET_M, le=MAX_MOUNT_OFFSET_M)]
_BoresightArcsec = Annotated[float, Field(ge=-MAX_BORESIGHT_ARCSEC, le=MAX_BORESIGHT_ARCSEC)]
_FocalPlaneUm = Annotated[float, Field(ge=-MAX_PRINCIPAL_POINT_UM, le=MAX_PRINCIPAL_POINT_UM)]


class StrictModel(BaseModel):
    """Base for every configuration model: unknown fields are errors, values are immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


class ScannerGeometry(StrictModel):
    """Interior geometry of the line scanner, with the self-calibration terms."""

    pixels: int = Field(512, ge=2, le=65_536, description="spatial pixels per line")
    pixel_pitch_um: float = Field(15.0, ge=MIN_PIXEL_PITCH_UM, le=1000,
                                  description="detector pixel pitch")
    focal_length_mm: float = Field(9.33, ge=MIN_FOCAL_LENGTH_MM, le=10_000,
                                   description="nominal focal length")
    principal_point_um: tuple[_FocalPlaneUm, _FocalPlaneUm] = Field(
        (0.0, 0.0), description="x0 (along track), y0 (across track) on the focal plane"
    )
    delta_focal_mm: float = Field(0.0, ge=-100, le=100, description="self-calibration δf")
    delta_principal_point_um: tuple[_FocalPlaneUm, _FocalPlaneUm] = Field(
        (0.0, 0.0), description="self-calibration δx0, δy0"
    )

    @model_validator(mode="after")
    def _focal_length_positive(self) -> ScannerGeometry:
        """δf may not cancel f: the pixels would look up, or along the focal plane."""
        focal_mm = self.focal_length_mm + self.delta_focal_mm
        if not focal_mm >= MIN_FOCAL_LENGTH_MM:
            raise ValueError(
                f"focal_length_mm + delta_focal_mm = {self.focal_length_mm:g} + "
                f"({self.delta_focal_mm:g}) = {focal_mm:g} mm: the effective focal length must "
                f"be at least {MIN_FOCAL_LENGTH_MM:g} mm")
        return self

    @property
    def centre_pixel(self) -> float:
        return (self.pixels - 1) / 2.0

    @property
    def fov_deg(self) -> float:
        half_width_mm = self.pixels * self.pixel_pitch_um * 1e-3 / 2.0
        return float(2.0 * np.degrees(np.arctan(half_width_mm / self.focal_length_mm)))

    @property
    def ifov_rad(self) -> float:
        return self.pixel_pitch_um * 1e-3 / self.focal_length_mm

    def look_vectors_camera(self) -> npt.NDArray[np.float64]:
        """Unnormalised look vectors in the camera frame, shape (3, pixels), metres."""
        j = np.arange(self.pixels, dtype=np.float64)
        x0_um, y0_um = self.principal_point_um
        dx0_um, dy0_um = self.delta_principal_point_um
        look = np.empty((3, self.pixels))
        look[0] = (x0_um + dx0_um) * 1e-6
        look[1] = ((j - self.centre_pixel) * self.pixel_pitch_um + y0_um + dy0_um) * 1e-6
        look[2] = -(self.focal_length_mm + self.delta_focal_mm) * 1e-3
        return look


class Mounting(StrictModel):
    """Where the scanner and the GPS antenna sit relative to the INS (body frame, metres)."""

    lever_arm_m: tuple[_OffsetM, _OffsetM, _OffsetM] = Field(
        (0.0, 0.0, 0.3), description="INS centre → perspective centre")
    antenna_offset_m: tuple[_OffsetM, _OffsetM, _OffsetM] = Field(
        (0.0, 0.0, -1.5), description="INS centre → antenna")
    boresight_arcsec: tuple[_BoresightArcsec, _BoresightArcsec, _BoresightArcsec] = Field(
        (0.0, 0.0, 0.0), description="misalignment ω, φ, κ about camera x, y, z"
    )

    def boresight_matrix(self) -> npt.NDArray[np.float64]:
        """R_c^b: camera frame → body frame, including the nominal mounting."""
        omega, phi, kappa = (a * ARCSEC_RAD for a in self.boresight_arcsec)
        return R_NOMINAL_C_TO_B @ rot_x(omega) @ rot_y(phi) @ rot_z(kappa)


def rot_x(angle_rad: float) -> npt.NDArray[np.float64]:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle_rad: float) -> npt.NDArray[np.float64]:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle_rad: float) -> npt.NDArray[np.float64]:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def first_non_finite(value: Any, where: str = "") -> str | None:
    """Dotted name of the first NaN or infinity in a dumped model (TOML can write both)."""
    if isinstance(value, float):
        return None if math.isfinite(value) else where
    if isinstance(value, dict):
        children = [(f"{where}.{k}" if where else str(k), v) for k, v in value.items()]
    elif isinstance(value, list | tuple):
        children = [(f"{where}[{i}]", v) for i, v in enumerate(value)]
    else:
        return None
    return next((bad for name, v in children if (bad := first_non_finite(v, name))), None)


# pydantic's range errors: NaN fails every bound, and says so as "should be less than ..."
MAX_KEY_SHOWN = 80  # characters of a field's name in a message (a key may be a megabyte)
MAX_REASON_SHOWN = 300  # ... of what is wrong with it
_BOUND_ERRORS = frozenset({"greater_than", "greater_than_equal", "less_than", "less_than_equal"})


def validation_text(exc: ValidationError) -> str:
    """A configuration's first problem in one line: the field as the TOML spells it, what is
    wrong, the value given, and how many more problems there are."""
    err = exc.errors()[0]
    where = toml_location(err["loc"])
    more = f" (and {exc.error_count() - 1} more)" if exc.error_count() > 1 else ""
    if err["type"] == "extra_forbidden":
        return f"unknown field {shown_value(where, MAX_KEY_SHOWN)}{more}"
    # a quoted TOML key may hold a newline, or be a megabyte long: one line, cut
    where = shown_text(where, MAX_KEY_SHOWN)
    msg = str(err["msg"]).removeprefix("Value error, ")
    got = err.get("input")
    if err["type"] in _BOUND_ERRORS and isinstance(got, float) and not math.isfinite(got):
        msg = "must be a finite number (not NaN or infinity)"
    elif not isinstance(got, dict):
        msg += f" (got {shown_value(got)})"
    msg = shown_text(msg, MAX_REASON_SHOWN)  # (a validator's own words may quote the input)
    return f"{where}: {msg}{more}" if where else f"{msg}{more}"


def toml_location(loc: tuple[int | str, ...]) -> str:
    """A pydantic error location as the TOML spells it: `mounting.lever_arm_m[0]`."""
    where = ""
    for part in loc:
        where += f"[{part}]" if isinstance(part, int) else (f".{part}" if where else str(part))
    return where


