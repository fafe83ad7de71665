"""Photo exterior orientation (postproc.georef.photos) against a truth computed here from
pyproj and scipy's rotations alone: the perspective centre in ECEF, geodetic and UTM, the body
attitude, and ω φ κ in the UTM map frame whose grid axes the test finds by finite differences
through pyproj (not from the convergence angle the module uses); ground points projected into a
photo against an independent collinearity with the distortion written out here."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pytest
from pyproj import Transformer
from scipy.spatial.transform import Rotation

from postproc.georef import PhotoEo, Pose, photo_eo, project_to_photo
from sisa.core.errors import InputError
from sisa.core.framecamera import FrameCamera, FrameInterior, FrameMounting
from sisa.core.frames import body_to_ned_matrix, ned_to_ecef_matrix
from sisa.core.timescale import NS_PER_S, parse_gps_datetime

F64 = npt.NDArray[np.float64]
ARCSEC = math.pi / (180 * 3600)
MM = 1e-3
T0_NS = parse_gps_datetime("2026-06-15T09:00:00")
SPAN_S = 60
# 2.4° east of the central meridian of UTM 31N: a grid convergence of ~1.6°, which an
# EO that ignored it would get wrong by 5800″
LAT0, LON0, H0 = 41.9, 5.4, 2600.0
EPSG = 32631
HEADING0_DEG, SPEED_MPS = 37.0, 70.0
GAP_S = (40.0, 41.0)  # the navigation has no pose here (NaN), as in a GPS outage

CAMERA = FrameCamera(
    interior=FrameInterior(width_px=11_664, height_px=8_750, pixel_pitch_um=3.76,
                           focal_length_mm=80.0, principal_point_px=(12.3, -7.9),
                           k1=-0.08, k2=0.12, k3=-0.05, p1=3e-4, p2=-2e-4),
    mounting=FrameMounting(lever_arm_m=(0.9, -0.35, 0.6), boresight_arcsec=(120.0, -80.0, 900.0)))

_TO_GEO = Transformer.from_crs(4978, 4979, always_xy=True)
_TO_ECEF = Transformer.from_crs(4979, 4978, always_xy=True)
_ECEF_TO_UTM = Transformer.from_crs(4978, EPSG, always_xy=True)
_GEO_TO_UTM = Transformer.from_crs(4326, EPSG, always_xy=True)
_UTM_TO_GEO = Transformer.from_crs(EPSG, 4326, always_xy=True)


def ecef(lat: F64, lon: F64, h: F64) -> F64:
    x, y, z = _TO_ECEF.transform(lon, lat, h)
    return np.stack([x, y, z], axis=-1)


def attitude_deg(t_s: F64) -> tuple[F64, F64, F64]:
    """Roll, pitch, heading: a slow turn, a roll oscillation, a pitch drift."""
    return (4.0 * np.sin(2 * np.pi * t_s / 17.0) + 1.0, 2.0 - 0.02 * t_s,
            HEADING0_DEG + 0.3 * t_s)


def enu_axes(lat_deg: float, lon_deg: float) -> F64:
    """Rows: east, north, up in ECEF, closed form."""
    la, lo = math.radians(lat_deg), math.radians(lon_deg)
    return np.array([[-math.sin(lo), math.cos(lo), 0.0],
                     [-math.sin(la) * math.cos(lo), -math.sin(la) * math.sin(lo), math.cos(la)],
                     [math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)]])


@dataclass(frozen=True)
class Flight:
    """The navigation input (uses SISA's frames to build R_b^e; the truth below does not)."""

    @property
    def span_ns(self) -> tuple[int, int]:
        return T0_NS, T0_NS + SPAN_S * NS_PER_S

    def pose_at(self, t_gps_ns: npt.ArrayLike) -> Pose:
        t = np.asarray(t_gps_ns, np.int64)
        t_s = (t - T0_NS) / NS_PER_S
        ins = ins_ecef(t_s)
        lon, lat, _ = _TO_GEO.transform(ins[:, 0], ins[:, 1], ins[:, 2])
        r_bn = body_to_ned_matrix(*np.radians(attitude_deg(t_s)))
        r_eb = ned_to_ecef_matrix(np.radians(lat), np.radians(lon)) @ r_bn
        valid = ((t >= self.span_ns[0]) & (t <= self.span_ns[1])
                 & ~((t_s > GAP_S[0]) & (t_s < GAP_S[1])))
        ins[~valid], r_eb[~valid] = np.nan, np.nan
        return Pose(t, ins, r_eb, valid)


def ins_ecef(t_s: F64) -> F64:
    """A straight line at SPEED_MPS on the heading, in the origin's tangent plane."""
    axes = enu_axes(LAT0, LON0)
    h = math.radians(HEADING0_DEG)
    along = math.sin(h) * axes[0] + math.cos(h) * axes[1]
    start = ecef(np.array(LAT0), np.array(LON0), np.array(H0))
    return np.asarray(start + np.outer(SPEED_MPS * t_s, along))


# --- the truth, from pyproj and scipy only ---------------------------------------------------

def truth(t_ns: npt.NDArray[np.int64]) -> dict[str, F64]:
    t_s = (t_ns - T0_NS) / NS_PER_S
    ins = ins_ecef(t_s)
    roll, pitch, heading = attitude_deg(t_s)
    out: dict[str, list[object]] = {k: [] for k in (
        "centre", "lat", "lon", "h", "east", "north", "omega", "phi", "kappa", "r_ek")}
    bore = np.array(CAMERA.mounting.boresight_arcsec) * ARCSEC
    r_kb = np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]]) @ Rotation.from_euler(
        "XYZ", bore).as_matrix()
    for i in range(t_ns.size):
        lon_i, lat_i, _ = (float(v) for v in _TO_GEO.transform(*ins[i]))
        r_ne = enu_axes(lat_i, lon_i)[[1, 0, 2]].T * np.array([1.0, 1.0, -1.0])  # N, E, D cols
        r_bn = Rotation.from_euler("ZYX", [heading[i], pitch[i], roll[i]], degrees=True)
        r_eb = r_ne @ r_bn.as_matrix()
        centre = ins[i] + r_eb @ np.array(CAMERA.mounting.lever_arm_m)
        lon_c, lat_c, h_c = (float(v) for v in _TO_GEO.transform(*centre))
        east, north = _GEO_TO_UTM.transform(lon_c, lat_c)
        r_ek = r_eb @ r_kb
        r_mk = grid_axes(lat_c, lon_c) @ r_ek
        omega, phi, kappa = Rotation.from_matrix(r_mk).as_euler("XYZ")
        for k, v in zip(out, (centre, lat_c, lon_c, h_c, east, north, omega, phi, kappa, r_ek),
                        strict=True):
            out[k].append(v)
    return {k: np.array(v) for k, v in out.items()}


def grid_axes(lat: float, lon: float, step_deg: float = 1e-5) -> F64:
    """Rows: grid east, grid north, up in ECEF at a point: the tangent-plane directions along
    which UTM northing, then easting, stay constant, from central differences of pyproj's
    geodetic → UTM over the ellipsoid (radii of curvature in closed form here)."""
    a, f = 6378137.0, 1 / 298.257223563
    e2 = f * (2 - f)
    w = 1 - e2 * math.sin(math.radians(lat)) ** 2
    rho, nu = a * (1 - e2) / w**1.5, a / math.sqrt(w)  # meridian, prime vertical
    step = math.radians(step_deg)
    jac = np.empty((2, 2))  # d(E, N) / d(east, north), metres on the ellipsoid
    for k, (dlon, dlat, metres) in enumerate([(step_deg, 0.0, nu * math.cos(math.radians(lat))
                                               * step), (0.0, step_deg, rho * step)]):
        plus = np.array(_GEO_TO_UTM.transform(lon + dlon, lat + dlat))
        minus = np.array(_GEO_TO_UTM.transform(lon - dlon, lat - dlat))
        jac[:, k] = (plus - minus) / (2 * metres)
    grid_e = np.array([jac[1, 1], -jac[1, 0]])  # N constant
    grid_n = np.array([-jac[0, 1], jac[0, 0]])  # E constant
    grid_e /= np.linalg.norm(grid_e)
    grid_n /= np.linalg.norm(grid_n)
    assert abs(grid_e @ grid_n) < 1e-9  # conformal: the grid axes are square
    enu = enu_axes(lat, lon)
    return np.array([grid_e[0] * enu[0] + grid_e[1] * enu[1],
                     grid_n[0] * enu[0] + grid_n[1] * enu[1], enu[2]])


def project_truth(ground_ecef: F64, centre: F64, r_ek: F64, iop: FrameInterior
                  ) -> tuple[F64, F64]:
    """Collinearity, written out: camera vector, perspective division, OpenCV's Brown terms,
    pixel-centre coordinates."""
    d = (ground_ecef - centre) @ r_ek  # rows: R_ek^T (X - C)
    x, y = d[:, 0] / -d[:, 2], -d[:, 1] / -d[:, 2]
    r2 = x**2 + y**2
    radial = 1 + iop.k1 * r2 + iop.k2 * r2**2 + iop.k3 * r2**3
    xd = x * radial + 2 * iop.p1 * x * y + iop.p2 * (r2 + 2 * x**2)
    yd = y * radial + iop.p1 * (r2 + 2 * y**2) + 2 * iop.p2 * x * y
    f_px = iop.focal_length_mm * 1000 / iop.pixel_pitch_um
    col0 = (iop.width_px - 1) / 2 + iop.principal_point_px[0]
    row0 = (iop.height_px - 1) / 2 + iop.principal_point_px[1]
    return col0 + f_px * xd, row0 + f_px * yd


T_PHOTOS = T0_NS + np.array([2.0, 9.5, 17.25, 25.0, 33.125, 47.0, 58.5]) * NS_PER_S
T_PHOTOS = T_PHOTOS.astype(np.int64) + np.array([0, 1, 2, 3, 4, 5, 6])  # odd nanoseconds
LABELS = [f"IMG_{k:04d}.tif" for k in range(T_PHOTOS.size)]


@pytest.fixture(scope="module")
def eo_and_truth() -> tuple[PhotoEo, dict[str, F64]]:
    return photo_eo(Flight(), LABELS, T_PHOTOS, CAMERA.mounting), truth(T_PHOTOS)


def test_position_within_1mm_of_the_truth(eo_and_truth: tuple[PhotoEo, dict[str, F64]]
                                          ) -> None:
    eo, want = eo_and_truth
    assert eo.valid.all()
    assert eo.epsg == EPSG
    pose = eo.pose
    assert np.linalg.norm(pose.centre_ecef_m - want["centre"], axis=1).max() < 1 * MM
    assert np.abs(pose.height_m - want["h"]).max() < 1 * MM
    metres_per_deg = 111_000.0
    assert np.abs(pose.lat_deg - want["lat"]).max() * metres_per_deg < 1 * MM
    assert np.abs(pose.lon_deg - want["lon"]).max() * metres_per_deg < 1 * MM
    assert np.abs(eo.easting_m - want["east"]).max() < 1 * MM
    assert np.abs(eo.northing_m - want["north"]).max() < 1 * MM


def test_attitude_within_001_arcsec_of_the_truth(eo_and_truth: tuple[PhotoEo, dict[str, F64]]
                                                 ) -> None:
    eo, want = eo_and_truth
    for name in ("omega", "phi", "kappa"):
        got = getattr(eo, f"{name}_rad")
        err = np.angle(np.exp(1j * (got - want[name])))
        assert np.abs(err).max() < 0.01 * ARCSEC, name
    t_s = (T_PHOTOS - T0_NS) / NS_PER_S
    roll, pitch, heading = (np.radians(a) for a in attitude_deg(t_s))
    pose = eo.pose
    for got, exp in ((pose.roll_rad, roll), (pose.pitch_rad, pitch),
                     (pose.heading_rad, heading)):
        assert np.abs(np.angle(np.exp(1j * (got - exp)))).max() < 0.01 * ARCSEC
    np.testing.assert_allclose(pose.r_ecef_from_camera, want["r_ek"], atol=1e-13)


def test_the_grid_convergence_matters_here(eo_and_truth: tuple[PhotoEo, dict[str, F64]]
                                           ) -> None:
    """κ differs from the true-north one by ~1.6°: the test would catch the convergence
    being left out or taken with the wrong sign."""
    eo, _ = eo_and_truth
    gamma = np.degrees(eo.convergence_rad)
    assert (gamma > 1.5).all()
    assert (gamma < 1.7).all()


def test_level_flight_north_looking_down_has_zero_angles_at_the_central_meridian() -> None:
    """Hand-worked: on the central meridian grid north is true north, so a level aircraft
    heading north with the nominal mounting gives ω = φ = κ = 0."""

    @dataclass(frozen=True)
    class Still:
        span_ns = (T0_NS, T0_NS + NS_PER_S)

        def pose_at(self, t_gps_ns: npt.ArrayLike) -> Pose:
            t = np.asarray(t_gps_ns, np.int64)
            ins = np.repeat(ecef(np.array([45.0]), np.array([3.0]), np.array([1000.0])),
                            t.size, axis=0)
            r_eb = np.repeat(ned_to_ecef_matrix(np.radians(45.0), np.radians(3.0))[None],
                             t.size, axis=0)
            return Pose(t, ins, r_eb, np.ones(t.size, np.bool_))

    eo = photo_eo(Still(), ["a"], np.array([T0_NS]),
                  FrameMounting(lever_arm_m=(0.0, 0.0, 0.0)))
    assert eo.epsg == 32631
    for a in (eo.omega_rad, eo.phi_rad, eo.kappa_rad):
        assert abs(float(a[0])) < 1e-12
    np.testing.assert_allclose(eo.r_map_from_camera[0], np.eye(3), atol=1e-12)


def test_ground_points_project_into_the_photo_as_the_collinearity_says(
        eo_and_truth: tuple[PhotoEo, dict[str, F64]]) -> None:
    eo, want = eo_and_truth
    rng = np.random.default_rng(11)
    iop = CAMERA.interior
    worst = 0.0
    for i in range(T_PHOTOS.size):
        east = want["east"][i] + rng.uniform(-700, 700, 400)
        north = want["north"][i] + rng.uniform(-500, 500, 400)
        h = rng.uniform(150.0, 900.0, 400)
        lon, lat = _UTM_TO_GEO.transform(east, north)
        ground = ecef(np.asarray(lat), np.asarray(lon), h)
        col, row = project_to_photo(eo, i, ground, iop)
        col_t, row_t = project_truth(ground, want["centre"][i], want["r_ek"][i], iop)
        inside = (col_t > -0.5) & (col_t < iop.width_px) & (row_t > -0.5) & (row_t < iop.height_px)
        assert inside.sum() > 100  # most of them fall in the frame
        assert np.isfinite(col[inside]).all()
        imaged = np.isfinite(col)  # (NaN only outside the circle through the corners)
        worst = max(worst, float(np.hypot(col - col_t, row - row_t)[imaged].max()))
    assert worst < 0.01


def test_photos_outside_the_trajectory_or_in_a_gap_are_invalid_not_guessed() -> None:
    t = np.array([T0_NS - 1, T0_NS + 5 * NS_PER_S, T0_NS + int(40.5 * NS_PER_S),
                  T0_NS + (SPAN_S + 1) * NS_PER_S, -1])
    eo = photo_eo(Flight(), ["a", "b", "c", "d", "e"], t, CAMERA.mounting)
    assert eo.valid.tolist() == [False, True, False, False, False]
    assert np.isnan(eo.omega_rad[~eo.valid]).all()
    assert np.isnan(eo.easting_m[~eo.valid]).all()


def test_a_nan_pose_the_trajectory_calls_valid_is_skipped_not_exported() -> None:
    @dataclass(frozen=True)
    class Careless(Flight):
        def pose_at(self, t_gps_ns: npt.ArrayLike) -> Pose:
            pose = Flight().pose_at(t_gps_ns)
            pose.ins_ecef_m[1] = np.nan  # and valid left True
            return pose._replace(valid=np.isfinite(pose.r_ecef_from_body).all(axis=(1, 2)))

    eo = photo_eo(Careless(), LABELS[:3], T_PHOTOS[:3], CAMERA.mounting)
    assert eo.valid.tolist() == [True, False, True]
    assert np.isnan(eo.easting_m[1])
    assert np.isfinite(eo.easting_m[[0, 2]]).all()


@pytest.mark.parametrize(("times", "labels", "match"), [
    (np.array([], np.int64), [], "no photos"),
    (np.array([T0_NS - 10 * NS_PER_S]), ["a"], "none of the 1 photos"),
    (np.array([float(T0_NS), math.nan]), ["a", "b"], "integer GPS nanoseconds"),
    (np.array([T0_NS, T0_NS]), ["a"], "2 photo times"),
    (np.array([T0_NS, T0_NS]), ["a", "a"], "given twice"),
    (np.array([T0_NS]), ["a b"], "photo label"),
    (np.array([T0_NS]), ["../x"], "photo label"),
    (np.array([T0_NS]), [".hidden"], "photo label"),
])
def test_bad_photo_lists_are_clear_errors(times: npt.NDArray[np.generic], labels: list[str],
                                          match: str) -> None:
    with pytest.raises(InputError, match=match):
        photo_eo(Flight(), labels, times, CAMERA.mounting)
