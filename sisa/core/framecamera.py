"""The digital frame camera every stage shares: interior orientation with Brown distortion, and
its mounting on the INS (docs/conventions.md, "Frame camera").

Conventions:
- Camera frame k (photogrammetric, as Pix4D's and Metashape's ω φ κ use it): x to the right of
  the image (increasing column), y to its top (decreasing row), z out of the back of the
  camera; the camera looks along −z.
- Pixel (col, row), 0-based, is a pixel CENTRE: the image spans col ∈ [−0.5, width − 0.5],
  row ∈ [−0.5, height − 0.5], rows run down. The image centre is ((width − 1)/2,
  (height − 1)/2); the principal point is `principal_point_px` (columns right, rows down) from
  it, so Metashape's cx, cy (measured from w/2 with the top-left pixel's centre at 0.5) are
  the same two numbers.
- Normalised image coordinates, as OpenCV's: (x, y) = (x_k / −z_k, −y_k / −z_k), x right and
  y DOWN. Brown distortion in OpenCV's form (k1 k2 k3 radial, p1 p2 decentring):
      x_d = x·L + 2·p1·x·y + p2·(r² + 2x²),   y_d = y·L + p1·(r² + 2y²) + 2·p2·x·y,
      L = 1 + k1·r² + k2·r⁴ + k3·r⁶,  r² = x² + y²;
  then col = c_col + f_px·x_d, row = c_row + f_px·y_d with f_px = focal / pitch.
- Body frame b: x forward, y right, z down. Nominal mounting: looking down, the top of the
  image towards the nose and its right towards the right wing, R_nom = [[0,1,0],[1,0,0],[0,0,−1]]
  (camera → body); the boresight misalignment (ω, φ, κ) follows it:
  R_k^b = R_nom · Rx(ω) · Ry(φ) · Rz(κ). Lever arm: INS centre → perspective centre, body frame.

Undistorting (pixel → ray) is Newton's method on the two distortion equations from the
distorted point: quadratic convergence wherever the distortion map's Jacobian stays positive,
which `FrameInterior` checks over the whole frame (corners included) when it is built, so every
point of the frame converges to < 1e-14 in normalised units (< 1e-9 px) within a few steps.
Projecting (ray → pixel) is limited to the circle through the frame's corners: farther out the
polynomial is not checked and may fold a ray from outside the field back into the image.
"""

from __future__ import annotations

from typing import Annotated, Final

import numpy as np
import numpy.typing as npt
from pydantic import Field, model_validator

from sisa.core.sensor import (
    ARCSEC_RAD,
    MAX_BORESIGHT_ARCSEC,
    MAX_MOUNT_OFFSET_M,
    MIN_FOCAL_LENGTH_MM,
    MIN_PIXEL_PITCH_UM,
    StrictModel,
    rot_x,
    rot_y,
    rot_z,
)

F64 = npt.NDArray[np.float64]

R_NOMINAL_K_TO_B: Final = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])

NEWTON_STEPS: Final = 30  # bound of the undistortion; a point of a checked frame needs < 10
NEWTON_TOLERANCE: Final = 1e-14  # normalised image units (× f_px for pixels)
CHECK_GRID: Final = 41  # points per side of the grid the distortion is checked on
FIELD_MARGIN: Final = 1e-9  # relative, on the field radius: the corners themselves are in

# Distortion: a coefficient beyond these is a typo (fisheye lenses need another model).
MAX_RADIAL: Final = 10.0
MAX_DECENTRING: Final = 0.1
MAX_IMAGE_PX: Final = 200_000  # pixels per side: the largest aerial sensors have ~30 000
MAX_PRINCIPAL_POINT_PX: Final = 10_000.0

_OffsetM = Annotated[float, Field(ge=-MAX_MOUNT_OFFSET_M, le=MAX_MOUNT_OFFSET_M)]
_BoresightArcsec = Annotated[float, Field(ge=-MAX_BORESIGHT_ARCSEC, le=MAX_BORESIGHT_ARCSEC)]
_PrincipalPx = Annotated[float, Field(ge=-MAX_PRINCIPAL_POINT_PX, le=MAX_PRINCIPAL_POINT_PX)]
_Radial = Annotated[float, Field(ge=-MAX_RADIAL, le=MAX_RADIAL)]
_Decentring = Annotated[float, Field(ge=-MAX_DECENTRING, le=MAX_DECENTRING)]


class FrameInterior(StrictModel):
    """Interior orientation of a frame camera (module docstring for every convention)."""

    width_px: int = Field(11_664, ge=2, le=MAX_IMAGE_PX, description="image columns")
    height_px: int = Field(8_750, ge=2, le=MAX_IMAGE_PX, description="image rows")
    pixel_pitch_um: float = Field(3.76, ge=MIN_PIXEL_PITCH_UM, le=1000)
    focal_length_mm: float = Field(80.0, ge=MIN_FOCAL_LENGTH_MM, le=10_000)
    principal_point_px: tuple[_PrincipalPx, _PrincipalPx] = Field(
        (0.0, 0.0), description="from the image centre: columns right, rows down")
    k1: _Radial = 0.0
    k2: _Radial = 0.0
    k3: _Radial = 0.0
    p1: _Decentring = 0.0
    p2: _Decentring = 0.0

    @property
    def focal_px(self) -> float:
        return self.focal_length_mm * 1e3 / self.pixel_pitch_um

    @property
    def principal_point(self) -> tuple[float, float]:
        """(col, row) of the principal point, pixel-centre coordinates."""
        return ((self.width_px - 1) / 2.0 + self.principal_point_px[0],
                (self.height_px - 1) / 2.0 + self.principal_point_px[1])

    def corners_px(self) -> tuple[F64, F64]:
        """(col, row) of the image's four outer corners: top-left, top-right, bottom-right,
        bottom-left (the outer edges of the corner pixels, not their centres)."""
        w, h = self.width_px - 0.5, self.height_px - 0.5
        return np.array([-0.5, w, w, -0.5]), np.array([-0.5, -0.5, h, h])

    @model_validator(mode="after")
    def _distortion_invertible(self) -> FrameInterior:
        """Every point of the frame must undistort to one ray: the distortion map's Jacobian
        stays positive over it (else two rays meet in one pixel, and Newton may not converge)."""
        col = np.linspace(-0.5, self.width_px - 0.5, CHECK_GRID)
        row = np.linspace(-0.5, self.height_px - 0.5, CHECK_GRID)
        cc, rr = np.meshgrid(col, row)
        x, y, ok = _undistort(*_normalised(self, cc.ravel(), rr.ravel()), self)
        if not ok.all():
            raise ValueError("the distortion cannot be inverted over the whole frame "
                             "(Newton's method does not converge at some of its points)")
        r = np.linspace(0.0, float(np.hypot(x, y).max()), 4 * CHECK_GRID * CHECK_GRID)
        radial_slope = 1.0 + r * r * (3 * self.k1 + r * r * (5 * self.k2 + 7 * self.k3 * r * r))
        if not ((_jacobian_det(x, y, self) > 0.0).all() and (radial_slope > 0.0).all()):
            raise ValueError("the distortion folds the frame over (its Jacobian is not "
                             "positive everywhere): two rays would meet in one pixel")
        return self

    def field_radius(self) -> float:
        """Largest undistorted normalised radius in the frame (at a corner): beyond it the
        distortion polynomial is not checked, and may fold far rays back into the image."""
        x, y, _ = _undistort(*_normalised(self, *self.corners_px()), self)
        return float(np.hypot(x, y).max())


class FrameMounting(StrictModel):
    """Where the frame camera sits on the INS: lever arm (body frame, metres) and boresight."""

    lever_arm_m: tuple[_OffsetM, _OffsetM, _OffsetM] = Field(
        (0.0, 0.0, 0.3), description="INS centre → perspective centre")
    boresight_arcsec: tuple[_BoresightArcsec, _BoresightArcsec, _BoresightArcsec] = Field(
        (0.0, 0.0, 0.0), description="misalignment ω, φ, κ about camera x, y, z")

    def boresight_matrix(self) -> F64:
        """R_k^b: camera frame → body frame, including the nominal mounting."""
        omega, phi, kappa = (a * ARCSEC_RAD for a in self.boresight_arcsec)
        return R_NOMINAL_K_TO_B @ rot_x(omega) @ rot_y(phi) @ rot_z(kappa)


class FrameCamera(StrictModel):
    """A frame camera: interior orientation and mounting."""

    interior: FrameInterior = Field(default_factory=FrameInterior)
    mounting: FrameMounting = Field(default_factory=FrameMounting)


# --- image point ↔ camera ray ------------------------------------------------------------------

def distort(x: npt.ArrayLike, y: npt.ArrayLike, interior: FrameInterior) -> tuple[F64, F64]:
    """Distorted normalised coordinates of undistorted ones (x right, y down)."""
    x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
    r2 = x * x + y * y
    radial = 1.0 + r2 * (interior.k1 + r2 * (interior.k2 + r2 * interior.k3))
    xd = x * radial + 2.0 * interior.p1 * x * y + interior.p2 * (r2 + 2.0 * x * x)
    yd = y * radial + interior.p1 * (r2 + 2.0 * y * y) + 2.0 * interior.p2 * x * y
    return xd, yd


def _jacobian(x: F64, y: F64, iop: FrameInterior) -> tuple[F64, F64, F64, F64]:
    r2 = x * x + y * y
    radial = 1.0 + r2 * (iop.k1 + r2 * (iop.k2 + r2 * iop.k3))
    d_radial = iop.k1 + r2 * (2.0 * iop.k2 + 3.0 * r2 * iop.k3)  # dL/d(r²)
    xx = radial + 2.0 * x * x * d_radial + 2.0 * iop.p1 * y + 6.0 * iop.p2 * x
    xy = 2.0 * x * y * d_radial + 2.0 * iop.p1 * x + 2.0 * iop.p2 * y
    yy = radial + 2.0 * y * y * d_radial + 6.0 * iop.p1 * y + 2.0 * iop.p2 * x
    return xx, xy, xy, yy


def _jacobian_det(x: F64, y: F64, iop: FrameInterior) -> F64:
    a, b, c, d = _jacobian(x, y, iop)
    return np.asarray(a * d - b * c)


def _undistort(xd: F64, yd: F64, iop: FrameInterior) -> tuple[F64, F64, npt.NDArray[np.bool_]]:
    """Newton from the distorted point; (x, y, converged)."""
    x, y = xd.copy(), yd.copy()
    done = np.zeros(x.shape, np.bool_)
    for _ in range(NEWTON_STEPS):
        fx, fy = distort(x, y, iop)
        ex, ey = fx - xd, fy - yd
        done = np.hypot(ex, ey) < NEWTON_TOLERANCE
        if done.all():
            break
        a, b, c, d = _jacobian(x, y, iop)
        det = a * d - b * c
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            x = x - (d * ex - b * ey) / det
            y = y - (a * ey - c * ex) / det
    return x, y, done & np.isfinite(x) & np.isfinite(y)


def _normalised(iop: FrameInterior, col: npt.ArrayLike, row: npt.ArrayLike) -> tuple[F64, F64]:
    c_col, c_row = iop.principal_point
    c, r = np.broadcast_arrays(np.asarray(col, np.float64), np.asarray(row, np.float64))
    return (c - c_col) / iop.focal_px, (r - c_row) / iop.focal_px


def image_to_camera(col: npt.ArrayLike, row: npt.ArrayLike, interior: FrameInterior) -> F64:
    """Unit ray (..., 3) in the camera frame k of image points (pixel-centre coordinates),
    undistorted by Newton's method; NaN for a point that does not converge (far outside a
    frame whose distortion `FrameInterior` checked)."""
    x, y, ok = _undistort(*_normalised(interior, col, row), interior)
    ray = np.stack([x, -y, -np.ones_like(x)], axis=-1)
    ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
    ray[~ok] = np.nan
    return ray


def camera_to_image(direction_k: npt.ArrayLike, interior: FrameInterior) -> tuple[F64, F64]:
    """(col, row) where camera-frame directions (..., 3), any length, are imaged, distorted;
    NaN for a direction not in front of the camera (z_k ≥ 0) or outside the circle through
    the frame's corners (`FrameInterior.field_radius`), where the distortion polynomial, not
    checked, could fold a far ray back into the image."""
    d = np.asarray(direction_k, np.float64)
    front = d[..., 2] < 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where(front, d[..., 0] / -d[..., 2], np.nan)
        y = np.where(front, d[..., 1] / d[..., 2], np.nan)
    outside = np.hypot(x, y) > interior.field_radius() * (1.0 + FIELD_MARGIN)
    x, y = np.where(outside, np.nan, x), np.where(outside, np.nan, y)
    xd, yd = distort(x, y, interior)
    c_col, c_row = interior.principal_point
    return c_col + interior.focal_px * xd, c_row + interior.focal_px * yd
