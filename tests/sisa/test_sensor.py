import numpy as np
import pytest
from pydantic import ValidationError

from sisa.core.errors import one_line_text_problem, shown_value
from sisa.core.sensor import (
    ARCSEC_RAD,
    Mounting,
    ScannerGeometry,
    toml_location,
)


def test_pixel_zero_looks_right_and_last_pixel_left_in_body_frame():
    geom = ScannerGeometry()
    look_b = Mounting().boresight_matrix() @ geom.look_vectors_camera()
    assert look_b[1, 0] > 0  # pixel 0: to the right of the flight direction
    assert look_b[1, -1] < 0
    assert np.all(look_b[2] > 0)  # every pixel looks down


def test_centre_pixels_symmetric_about_nadir():
    look = ScannerGeometry(pixels=512).look_vectors_camera()
    np.testing.assert_allclose(look[1, 255], -look[1, 256])
    np.testing.assert_allclose(look[1, 256] - look[1, 255], 15e-6)


def test_fov_and_ifov_of_a_casi_like_scanner():
    geom = ScannerGeometry(pixels=512, pixel_pitch_um=15.0, focal_length_mm=9.33)
    assert abs(geom.ifov_rad - 15e-3 / 9.33) < 1e-15
    assert 44.0 < geom.fov_deg < 45.5


def test_boresight_is_a_small_rotation_after_the_nominal_mounting():
    m = Mounting(boresight_arcsec=(3600.0, 0.0, 0.0))
    r = m.boresight_matrix()
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-15)
    # a positive ω rotates the camera's nadir ray about the flight axis by 1°
    nadir_b = r @ [0, 0, -1]
    angle = np.arctan2(nadir_b[1], nadir_b[2])
    np.testing.assert_allclose(abs(angle), 3600 * ARCSEC_RAD, rtol=1e-12)


def test_error_locations_read_as_the_toml_spells_them() -> None:
    assert toml_location(("mounting", "antenna_offset_m", 0)) == "mounting.antenna_offset_m[0]"
    assert toml_location(("faults", "pps_outages", 1, "at_s")) == "faults.pps_outages[1].at_s"
    assert toml_location(()) == ""


def test_shown_values_stay_short() -> None:
    assert shown_value(10**299) == "1e+299"
    assert shown_value(10**400) == "an integer too large for a float"
    assert shown_value(100.00000001) == "100.00000001"
    assert shown_value(True) == "True"
    assert shown_value("a\nb") == "'a\\nb'"
    long = shown_value("x" * 5000)
    assert len(long) == 60
    assert long.endswith("…")


def test_one_line_text_refuses_controls_and_separators() -> None:
    assert one_line_text_problem("CASI-501 #2 on EC-FXX (calibrated) é ✓") is None
    for bad in ("a\nb", "a\rb", "a\x1b[31m", "a\u2028b", "a\u202eb", "a\x00"):
        assert one_line_text_problem(bad) is not None, repr(bad)


def test_delta_focal_may_not_cancel_the_focal_length() -> None:
    ScannerGeometry(focal_length_mm=50.0, delta_focal_mm=-49.9)  # 0.1 mm left: allowed
    with pytest.raises(ValidationError, match="focal_length_mm \\+ delta_focal_mm"):
        ScannerGeometry(focal_length_mm=9.33, delta_focal_mm=-9.33)
