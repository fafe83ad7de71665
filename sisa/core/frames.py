"""Attitude and local-level frames, vectorised over leading axes.

Body frame: x forward, y right, z down. Local level: NED. Attitude: roll φ, pitch θ, true heading ψ
(radians), with R_b^n = Rz(ψ)·Ry(θ)·Rx(φ): heading 90° flies east, positive pitch raises the nose,
positive roll lowers the right wing.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


def body_to_ned_matrix(roll_rad: npt.ArrayLike, pitch_rad: npt.ArrayLike,
                       heading_rad: npt.ArrayLike) -> FloatArray:
    """R_b^n, shape (..., 3, 3), for arrays of roll, pitch and true heading."""
    r, p, h = np.broadcast_arrays(np.asarray(roll_rad, dtype=np.float64),
                                  np.asarray(pitch_rad, dtype=np.float64),
                                  np.asarray(heading_rad, dtype=np.float64))
    cr, sr, cp, sp, ch, sh = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(h), np.sin(h)
    m = np.empty((*r.shape, 3, 3))
    m[..., 0, 0] = ch * cp
    m[..., 0, 1] = ch * sp * sr - sh * cr
    m[..., 0, 2] = ch * sp * cr + sh * sr
    m[..., 1, 0] = sh * cp
    m[..., 1, 1] = sh * sp * sr + ch * cr
    m[..., 1, 2] = sh * sp * cr - ch * sr
    m[..., 2, 0] = -sp
    m[..., 2, 1] = cp * sr
    m[..., 2, 2] = cp * cr
    return m


def euler_from_body_to_ned(r_bn: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Roll, pitch, heading (heading in [0, 2π)) from R_b^n, shape (..., 3, 3)."""
    roll = np.arctan2(r_bn[..., 2, 1], r_bn[..., 2, 2])
    pitch = -np.arcsin(np.clip(r_bn[..., 2, 0], -1.0, 1.0))
    heading = np.mod(np.arctan2(r_bn[..., 1, 0], r_bn[..., 0, 0]), 2 * np.pi)
    return roll, pitch, heading


def ned_to_ecef_matrix(lat_rad: npt.ArrayLike, lon_rad: npt.ArrayLike) -> FloatArray:
    """R_n^e, shape (..., 3, 3): columns are north, east, down expressed in ECEF."""
    lat, lon = np.broadcast_arrays(np.asarray(lat_rad, dtype=np.float64),
                                   np.asarray(lon_rad, dtype=np.float64))
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    m = np.empty((*lat.shape, 3, 3))
    m[..., 0, 0], m[..., 1, 0], m[..., 2, 0] = -sl * co, -sl * so, cl
    m[..., 0, 1], m[..., 1, 1], m[..., 2, 1] = -so, co, 0.0
    m[..., 0, 2], m[..., 1, 2], m[..., 2, 2] = -cl * co, -cl * so, -sl
    return m


def body_rates_from_euler_rates(roll_rad: FloatArray, pitch_rad: FloatArray,
                                roll_rate: FloatArray, pitch_rate: FloatArray,
                                heading_rate: FloatArray) -> FloatArray:
    """ω_nb^b (rad/s, shape (..., 3)): body rates relative to the local-level frame."""
    sr, cr = np.sin(roll_rad), np.cos(roll_rad)
    sp, cp = np.sin(pitch_rad), np.cos(pitch_rad)
    p = roll_rate - heading_rate * sp
    q = pitch_rate * cr + heading_rate * cp * sr
    r = -pitch_rate * sr + heading_rate * cp * cr
    return np.stack([p, q, r], axis=-1)
