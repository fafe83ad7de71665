"""Attitude conventions against hand-worked cases and pyproj."""

import numpy as np
from pyproj import Transformer

from sisa.core.frames import (
    body_to_ned_matrix,
    euler_from_body_to_ned,
    ned_to_ecef_matrix,
)


def test_heading_90_flies_east():
    r = body_to_ned_matrix(0.0, 0.0, np.pi / 2)
    np.testing.assert_allclose(r @ [1, 0, 0], [0, 1, 0], atol=1e-15)  # nose points east


def test_positive_roll_lowers_the_right_wing():
    r = body_to_ned_matrix(np.radians(10), 0.0, 0.0)
    right_wing_ned = r @ [0, 1, 0]
    assert right_wing_ned[2] > 0  # down component positive


def test_positive_pitch_raises_the_nose():
    r = body_to_ned_matrix(0.0, np.radians(5), 0.0)
    assert (r @ [1, 0, 0])[2] < 0  # nose has an "up" (negative down) component


def test_rotation_order_is_heading_pitch_roll():
    roll, pitch, heading = 0.1, -0.2, 2.5
    rx = np.array([[1, 0, 0], [0, np.cos(roll), -np.sin(roll)], [0, np.sin(roll), np.cos(roll)]])
    ry = np.array([[np.cos(pitch), 0, np.sin(pitch)], [0, 1, 0],
                   [-np.sin(pitch), 0, np.cos(pitch)]])
    rz = np.array([[np.cos(heading), -np.sin(heading), 0], [np.sin(heading), np.cos(heading), 0],
                   [0, 0, 1]])
    np.testing.assert_allclose(body_to_ned_matrix(roll, pitch, heading), rz @ ry @ rx,
                               atol=1e-15)


def test_euler_round_trip_vectorised():
    rng = np.random.default_rng(3)
    roll = rng.uniform(-1.5, 1.5, 100)
    pitch = rng.uniform(-1.4, 1.4, 100)
    heading = rng.uniform(0, 2 * np.pi, 100)
    r, p, h = euler_from_body_to_ned(body_to_ned_matrix(roll, pitch, heading))
    np.testing.assert_allclose(r, roll, atol=1e-12)
    np.testing.assert_allclose(p, pitch, atol=1e-12)
    np.testing.assert_allclose(h, heading, atol=1e-12)


def test_ned_to_ecef_matches_pyproj_finite_differences():
    lat, lon, h = 42.15, 2.5, 500.0
    to_ecef = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    r = ned_to_ecef_matrix(np.radians(lat), np.radians(lon))
    p0 = np.array(to_ecef.transform(lon, lat, h))
    up = np.array(to_ecef.transform(lon, lat, h + 1.0)) - p0
    np.testing.assert_allclose(r @ [0, 0, -1], up, atol=1e-9)
    north = np.array(to_ecef.transform(lon, lat + 1e-6, h)) - p0
    np.testing.assert_allclose(r @ [1, 0, 0], north / np.linalg.norm(north), atol=1e-6)
