"""The frame camera model (sisa.core.framecamera): image point ↔ ray round trips over the whole
frame, the axes and pixel-centre conventions on hand-worked cases, the mounting against scipy's
rotations, and the models' refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError
from scipy.spatial.transform import Rotation

from sisa.core.framecamera import (
    FrameCamera,
    FrameInterior,
    FrameMounting,
    camera_to_image,
    distort,
    image_to_camera,
)

# A medium-format aerial camera (Phase One iXM-100 size) with a consumer-grade lens's distortion
# (~60 px at the corners) and decentring, principal point off the centre.
STRONG = FrameInterior(width_px=11_664, height_px=8_750, pixel_pitch_um=3.76,
                       focal_length_mm=80.0, principal_point_px=(12.3, -7.9),
                       k1=-0.08, k2=0.12, k3=-0.05, p1=3e-4, p2=-2e-4)
# A metric camera: a few micrometres of distortion.
METRIC = FrameInterior(width_px=17_310, height_px=11_310, pixel_pitch_um=3.9,
                       focal_length_mm=100.0, principal_point_px=(0.4, -0.3),
                       k1=-2e-4, k2=1e-4, k3=0.0, p1=1e-6, p2=-2e-6)
SIDE = 257  # grid points per side of the frame in the round trips


def frame_grid(iop: FrameInterior) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates over the whole frame, edges and the four outer corners in."""
    col = np.linspace(-0.5, iop.width_px - 0.5, SIDE)
    row = np.linspace(-0.5, iop.height_px - 0.5, SIDE)
    cc, rr = np.meshgrid(col, row)
    return cc.ravel(), rr.ravel()


@pytest.mark.parametrize("iop", [STRONG, METRIC], ids=["strong", "metric"])
def test_pixel_to_ray_to_pixel_round_trip_below_1e_6_px(iop: FrameInterior) -> None:
    col, row = frame_grid(iop)
    ray = image_to_camera(col, row, iop)
    assert np.isfinite(ray).all()
    np.testing.assert_allclose(np.linalg.norm(ray, axis=-1), 1.0, atol=1e-15)
    back_col, back_row = camera_to_image(ray, iop)
    err = np.hypot(back_col - col, back_row - row)
    assert err.max() < 1e-6
    corners = image_to_camera(*iop.corners_px(), iop)
    np.testing.assert_allclose(camera_to_image(corners, iop), iop.corners_px(), atol=1e-6)


@pytest.mark.parametrize("iop", [STRONG, METRIC], ids=["strong", "metric"])
def test_ray_to_pixel_to_ray_round_trip(iop: FrameInterior) -> None:
    rng = np.random.default_rng(3)
    half_w = iop.width_px * iop.pixel_pitch_um * 1e-3 / 2 / iop.focal_length_mm
    half_h = iop.height_px * iop.pixel_pitch_um * 1e-3 / 2 / iop.focal_length_mm
    d = np.stack([rng.uniform(-half_w, half_w, 5000), rng.uniform(-half_h, half_h, 5000),
                  -np.ones(5000)], axis=-1) * rng.uniform(0.1, 1e4, (5000, 1))
    ray = image_to_camera(*camera_to_image(d, iop), iop)
    unit = d / np.linalg.norm(d, axis=-1, keepdims=True)
    assert np.abs(ray - unit).max() * iop.focal_px < 1e-6  # as pixels on the focal plane


def test_the_distortion_really_is_strong() -> None:
    """The round trips above would be trivial without distortion: ~60 px at the corners."""
    ray = image_to_camera(*STRONG.corners_px(), STRONG)
    c_col, c_row = STRONG.principal_point  # where the rays would be imaged without distortion:
    col = c_col + STRONG.focal_px * ray[:, 0] / -ray[:, 2]
    row = c_row + STRONG.focal_px * -ray[:, 1] / -ray[:, 2]
    shift = np.hypot(col - STRONG.corners_px()[0], row - STRONG.corners_px()[1])
    assert shift.min() > 50.0
    assert shift.max() < 70.0


def test_axes_and_pixel_centres_by_hand() -> None:
    iop = FrameInterior(width_px=4, height_px=3, pixel_pitch_um=10.0, focal_length_mm=10.0)
    # f = 1000 px; image centre at col 1.5, row 1.0 (pixel centres 0..3 and 0..2)
    col, row = camera_to_image(np.array([0.0, 0.0, -5.0]), iop)
    assert (float(col), float(row)) == (1.5, 1.0)
    col, row = camera_to_image(np.array([[1e-3, 0.0, -1.0], [0.0, 1e-3, -1.0]]), iop)
    np.testing.assert_allclose(col, [2.5, 1.5], atol=1e-12)  # camera x: to the right
    np.testing.assert_allclose(row, [1.0, 0.0], atol=1e-12)  # camera y: up, rows run down
    shifted = FrameInterior(**{**iop.model_dump(), "principal_point_px": (0.25, -0.5)})
    col, row = camera_to_image(np.array([0.0, 0.0, -1.0]), shifted)
    assert (float(col), float(row)) == (1.75, 0.5)
    c, r = iop.corners_px()
    assert c.tolist() == [-0.5, 3.5, 3.5, -0.5]
    assert r.tolist() == [-0.5, -0.5, 2.5, 2.5]


def test_brown_distortion_in_opencvs_form() -> None:
    """Hand-worked: x = 0.1, y = −0.2 (r² = 0.05)."""
    iop = FrameInterior(k1=0.1, k2=0.01, k3=0.001, p1=0.002, p2=-0.003)
    radial = 1 + 0.1 * 0.05 + 0.01 * 0.05**2 + 0.001 * 0.05**3
    xd = 0.1 * radial + 2 * 0.002 * 0.1 * -0.2 - 0.003 * (0.05 + 2 * 0.01)
    yd = -0.2 * radial + 0.002 * (0.05 + 2 * 0.04) + 2 * -0.003 * 0.1 * -0.2
    got = distort(0.1, -0.2, iop)
    assert float(got[0]) == pytest.approx(xd, abs=1e-16)
    assert float(got[1]) == pytest.approx(yd, abs=1e-16)


def test_a_direction_behind_the_camera_has_no_image() -> None:
    col, row = camera_to_image(np.array([[0.1, 0.1, 1.0], [0.0, 0.0, 0.0]]), STRONG)
    assert np.isnan(col).all()
    assert np.isnan(row).all()


def test_a_far_ray_is_not_folded_back_into_the_image() -> None:
    """STRONG's polynomial turns back ~55° off-axis: a ray at r = 1.86 (62°, far outside the
    field of r = 0.35) would land at x_d ≈ 0.16, inside the frame, were projection not limited
    to the frame's field."""
    x = 1.86
    xd, _ = distort(x, 0.0, STRONG)
    assert 0.1 < float(xd) < 0.2  # the fold is real
    col, row = camera_to_image(np.array([[x, 0.0, -1.0], [0.25, 0.19, -1.0]]), STRONG)
    assert np.isnan(col[0])
    assert np.isnan(row[0])
    assert np.isfinite(col[1])  # just inside the corner: imaged
    corners = image_to_camera(*STRONG.corners_px(), STRONG)
    assert np.isfinite(camera_to_image(corners, STRONG)[0]).all()


def test_nominal_mounting_looks_down_with_the_image_top_forward() -> None:
    r_kb = FrameMounting(boresight_arcsec=(0.0, 0.0, 0.0)).boresight_matrix()
    np.testing.assert_array_equal(r_kb @ [0.0, 0.0, -1.0], [0.0, 0.0, 1.0])  # look: body down
    np.testing.assert_array_equal(r_kb @ [0.0, 1.0, 0.0], [1.0, 0.0, 0.0])  # image top: nose
    np.testing.assert_array_equal(r_kb @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])  # right: right wing
    assert np.linalg.det(r_kb) == pytest.approx(1.0)


def test_boresight_is_a_small_rotation_after_the_nominal_mounting() -> None:
    bore = (40.0, -25.0, 300.0)
    got = FrameMounting(boresight_arcsec=bore).boresight_matrix()
    arcsec = math.pi / (180 * 3600)
    nominal = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    want = nominal @ Rotation.from_euler("XYZ", np.array(bore) * arcsec).as_matrix()
    np.testing.assert_allclose(got, want, atol=1e-15)


def test_a_distortion_that_folds_the_frame_is_refused() -> None:
    with pytest.raises(ValidationError, match="distortion"):
        FrameInterior(focal_length_mm=20.0, k1=-3.0)  # the corners fold back inwards


@pytest.mark.parametrize("field", ["k1", "p2", "focal_length_mm", "pixel_pitch_um"])
def test_non_finite_parameters_are_refused(field: str) -> None:
    with pytest.raises(ValidationError):
        FrameInterior(**{field: math.nan})


def test_unknown_fields_are_refused() -> None:
    with pytest.raises(ValidationError, match="extra"):
        FrameCamera.model_validate({"interior": {"k4": 0.1}})
