"""Exterior orientation of every photo of the frame camera, for the photogrammetry tools.

    eo = photo_eo(traj, labels, t_mid_gps_ns, camera.mounting)   # epsg: UTM of the flight
    col, row = project_to_photo(eo, i, ground_ecef_m, camera.interior)

The pose is the scan lines' (`exterior.exterior_orientation`, sampled at each photo's
mid-exposure GPS time): perspective centre r^e_PC = r^e_INS(t) + R^e_b(t)·a^b in ECEF and
geodetic, body attitude roll/pitch/true heading, and R_k^e = R_b^e·R_k^b.

Map-frame angles (docs/conventions.md, "Frame camera"): the map frame m of a photo is the
projected CRS (UTM of the flight unless told) taken as Cartesian AT ITS PERSPECTIVE CENTRE:
x grid east, y grid north, z up along the ellipsoid normal there. Grid north is true north
turned clockwise by the grid convergence γ (pyproj's `meridian_convergence`, ~1° at 3° from a
UTM central meridian), so R_k^m = Rz(γ)·R_ned^enu·R_e^n(PC)·R_k^e: the convergence IS
accounted for, the vertical is the ellipsoid's (not the plumb line: no deflection of the
vertical), and the scale factor of the projection changes no angle. ω, φ, κ are Pix4D's
(PATB): R_k^m = Rx(ω)·Ry(φ)·Rz(κ), a map vector = R times a camera vector, with the camera
frame x right, y up, z back in the image; all three zero = looking straight down with the
top of the image to grid north. A tool that treats E, N, h as one Cartesian frame over a whole
block sees earth curvature the angles do not hold (1.6 mrad per 10 km).

A photo without a time (t < 0) or outside the trajectory is invalid (NaN, valid False): the
exports skip it and say how many; if no photo at all has a pose, InputError.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Final, NamedTuple

import numpy as np
import numpy.typing as npt
from pydantic import Field
from pyproj import Proj

from postproc.georef.exterior import CameraMount, LineEo, exterior_orientation
from postproc.georef.navigation import Trajectory, gps_times, transformer
from sisa.core.errors import InputError, shown_value
from sisa.core.framecamera import FrameInterior, camera_to_image
from sisa.core.frames import ned_to_ecef_matrix
from sisa.core.sensor import StrictModel
from sisa.core.utm import utm_epsg

F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]

# A label names the photo in every export: a file name for its sidecar and one token of a
# whitespace-separated geo.txt line, so letters, digits and . _ + - only, not starting with '.'
LABEL_PATTERN: Final = re.compile(r"[A-Za-z0-9_+\-][A-Za-z0-9._+\-]{0,199}")
MAX_PHOTOS: Final = 10_000_000
R_ENU_FROM_NED: Final = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


class PhotoSigma(StrictModel):
    """A-priori standard deviations of each photo's EO, for the tools' weights (one sigma).
    The navigation solution carries no covariance: these come from the navigation's own
    specification or the campaign's experience."""

    horizontal_m: float = Field(0.05, gt=0.0, le=1000.0)
    vertical_m: float = Field(0.10, gt=0.0, le=1000.0)
    attitude_deg: float = Field(0.005, gt=0.0, le=180.0)


class PhotoEo(NamedTuple):
    """EO of N photos (invalid rows NaN); angles in radians, map frame in module docstring."""

    labels: tuple[str, ...]
    pose: LineEo  # t, centre (ECEF), R_k^e, lat/lon/h, roll/pitch/heading, valid
    epsg: int  # projected CRS of the map frame
    easting_m: F64
    northing_m: F64
    convergence_rad: F64  # γ at the perspective centre: grid north clockwise of true north
    r_map_from_camera: F64  # (N, 3, 3) R_k^m
    omega_rad: F64
    phi_rad: F64
    kappa_rad: F64

    @property
    def valid(self) -> Bool:
        return self.pose.valid


def checked_labels(labels: Sequence[str], n: int) -> tuple[str, ...]:
    """The labels as given, or InputError: one per time, unique, each a safe name."""
    out = tuple(labels)
    if len(out) != n:
        raise InputError(f"{len(out)} photo labels for {n} photo times")
    for label in out:
        if not isinstance(label, str) or not LABEL_PATTERN.fullmatch(label):
            raise InputError(f"photo label {shown_value(label)}: use 1-200 letters, digits "
                             "and . _ + - (not starting with '.')")
    if len(set(out)) != n:
        dup = next(lb for lb in out if out.count(lb) > 1)
        raise InputError(f"photo label {shown_value(dup)} is given twice")
    return out


def checked_times(t_photo_gps_ns: npt.ArrayLike) -> npt.NDArray[np.int64]:
    """Mid-exposure times as int64 GPS ns, or InputError (none, too many, or not integers: a
    float time, NaN included, is refused rather than rounded)."""
    try:
        t = gps_times(t_photo_gps_ns)
    except TypeError:
        raise InputError("photo times must be integer GPS nanoseconds (a float time, NaN "
                         "included, is refused)") from None
    if t.size == 0:
        raise InputError("no photos: the list of photo times is empty")
    if t.size > MAX_PHOTOS:
        raise InputError(f"{t.size} photos: more than {MAX_PHOTOS} in one call")
    return t


def grid_convergence_rad(epsg: int, lat_deg: F64, lon_deg: F64) -> F64:
    """γ of a projected CRS at geodetic points: the angle from true north clockwise to grid
    north (positive east of a northern UTM zone's central meridian)."""
    factors = Proj(f"EPSG:{epsg}").get_factors(lon_deg, lat_deg)
    return np.radians(np.asarray(factors.meridian_convergence, np.float64))


def r_map_from_ecef(lat_deg: F64, lon_deg: F64, convergence_rad: F64) -> F64:
    """R_e^m (N, 3, 3): ECEF → map frame (grid east, grid north, ellipsoidal up) at points."""
    r_en = np.swapaxes(ned_to_ecef_matrix(np.radians(lat_deg), np.radians(lon_deg)), -1, -2)
    c, s = np.cos(convergence_rad), np.sin(convergence_rad)
    rz = np.zeros((*c.shape, 3, 3))
    rz[..., 0, 0], rz[..., 0, 1], rz[..., 1, 0], rz[..., 1, 1] = c, -s, s, c
    rz[..., 2, 2] = 1.0
    return np.asarray(rz @ R_ENU_FROM_NED @ r_en)


def omega_phi_kappa(r_map_from_camera: F64) -> tuple[F64, F64, F64]:
    """(ω, φ, κ) radians of R = Rx(ω)·Ry(φ)·Rz(κ), shape (..., 3, 3); φ in [−π/2, π/2]."""
    r = r_map_from_camera
    omega = np.arctan2(-r[..., 1, 2], r[..., 2, 2])
    phi = np.arcsin(np.clip(r[..., 0, 2], -1.0, 1.0))
    kappa = np.arctan2(-r[..., 0, 1], r[..., 0, 0])
    return omega, phi, kappa


def photo_eo(traj: Trajectory, labels: Sequence[str], t_photo_gps_ns: npt.ArrayLike,
             mounting: CameraMount, *, epsg: int | None = None, time_delay_ns: int = 0
             ) -> PhotoEo:
    """EO of every photo at its mid-exposure time (+ time_delay_ns), in ECEF, geodetic and
    the map frame of `epsg` (default: the UTM zone of the photos' mean position)."""
    t = checked_times(t_photo_gps_ns)
    names = checked_labels(labels, t.size)
    pose = exterior_orientation(traj, t, mounting, time_delay_ns=time_delay_ns)
    # a pose the trajectory calls valid but gives as NaN (a source that marks no gaps) has none
    finite = (np.isfinite(pose.centre_ecef_m).all(axis=1)
              & np.isfinite(pose.r_ecef_from_camera).all(axis=(1, 2)))
    pose = pose._replace(valid=pose.valid & finite)
    ok = pose.valid
    if not ok.any():
        lo, hi = traj.span_ns
        raise InputError(f"none of the {t.size} photos has a navigation pose (their times "
                         f"lie outside the trajectory, GPS ns {lo} to {hi}, or in its gaps)")
    if epsg is None:
        epsg = utm_epsg(float(np.mean(pose.lon_deg[ok])), float(np.mean(pose.lat_deg[ok])))
    n = t.size
    east, north, gamma = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    r_mk = np.full((n, 3, 3), np.nan)
    lat, lon = pose.lat_deg[ok], pose.lon_deg[ok]
    e, nn = transformer(4326, epsg).transform(lon, lat)
    east[ok], north[ok] = e, nn
    gamma[ok] = grid_convergence_rad(epsg, lat, lon)
    r_mk[ok] = r_map_from_ecef(lat, lon, gamma[ok]) @ pose.r_ecef_from_camera[ok]
    omega, phi, kappa = omega_phi_kappa(r_mk)
    return PhotoEo(names, pose, epsg, east, north, gamma, r_mk, omega, phi, kappa)


def project_to_photo(eo: PhotoEo, index: int, ground_ecef_m: npt.ArrayLike,
                     interior: FrameInterior) -> tuple[F64, F64]:
    """(col, row) in photo `index` of ECEF ground points (..., 3), through the collinearity
    and the distortion; NaN behind the camera or for an invalid photo."""
    g = np.asarray(ground_ecef_m, np.float64)
    d_ecef = g - eo.pose.centre_ecef_m[index]
    d_camera = d_ecef @ eo.pose.r_ecef_from_camera[index]  # R^T·d, row vectors
    return camera_to_image(d_camera, interior)
