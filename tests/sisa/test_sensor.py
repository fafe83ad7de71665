import numpy as np

from sisa.sensor import ARCSEC_RAD, Mounting, ScannerGeometry


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
