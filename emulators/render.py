"""The scanner emulator's FORWARD model: true pose → pixel ray → ground point on the DEM →
scene radiance → DN. Post-processing has its own inverse; this module is only for emulation and
for the tests that check it.

Geometry (docs/conventions.md): the perspective centre is r^e_INS + R_b^e·a^b, and pixel j looks
along R_n^e·R_b^n·R_c^b·look_c(j), all at the frame's true mid-exposure time.

Why the intersection is done the way it is: the DEM is a bilinear surface of ELLIPSOIDAL height
over a UTM grid, so UTM E/N/h are not Cartesian: over a 2 km ray, earth curvature alone bends
"straight down" by metres. Rays are straight in ECEF, and so in an east-north-up tangent frame at
the DEM centre (an exact rigid transform of ECEF). The map ENU → (UTM E, N, h) is smooth, so it
is fitted once by a low-degree polynomial to pyproj (checked to < 1 mm at independent points).
Along one ray, E, N and h are then smooth functions of the range s, interpolated by a quadratic
through three points of that map. The search is narrowed to where the ray is between the lowest
and highest DEM heights under its own footprint (per-tile extremes), marched in steps of half a
DEM cell against the DEM's own bilinear surface (nothing is resampled) and refined by regula
falsi to 0.1 mm. The slow oracle `exact_ground_point` does the same with pyproj at every step
and shares none of this code.
"""

from __future__ import annotations

import itertools
import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, TypeVar, cast

import numba
import numpy as np
import numpy.typing as npt
import rasterio
from pyproj import Transformer
from rasterio.errors import NotGeoreferencedWarning

from emulators.scenario import ScannerSettings
from emulators.terrain import Scene, Terrain, bilinear_at
from emulators.trajectory import TrajectoryState
from sisa.core.framecamera import FrameMounting
from sisa.core.frames import body_to_ned_matrix, ned_to_ecef_matrix
from sisa.core.sensor import Mounting

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
U16 = npt.NDArray[np.uint16]
_Fn = TypeVar("_Fn", bound=Callable[..., Any])

MAP_TOLERANCE_M: Final = 1e-3  # worst error of the fitted ENU → UTM/h map at check points
MAX_MAP_DEGREE: Final = 6
BRACKET_MARGIN_M: Final = 2.0  # ray search starts this far above the highest DEM cell
MEAN_EARTH_RADIUS_M: Final = 6_371_000.0  # only to guess the search bracket; checked exactly
ROOT_TOLERANCE_M: Final = 1e-4
SHRINK_SLACK_M: Final = 1e-3  # the narrowed search band reaches this far beyond the DEM's span
TILE_CELLS: Final = 8  # DEM cells per side of the tiles whose height extremes bound the search


def _jit(parallel: bool = False) -> Callable[[_Fn], _Fn]:
    """numba.njit, cached on disk, with IEEE division (no ZeroDivisionError checks), without
    the GIL (the scanner renders on a thread of its own while the emulation runs on)."""
    return cast(Callable[[_Fn], _Fn], numba.njit(cache=True, parallel=parallel,
                                                 error_model="numpy", nogil=True))


def render_on_one_thread() -> None:
    """Real time: render on the calling thread alone. A parallel kernel waits for a worker on
    the other core, which the recorder under test is using: blocks of 8 lines, ~2 ms on one
    thread, then took up to 33 ms, and the emulator sent frame pulses that late (4-18 late
    edges in 25 s of a bench strip, none with this)."""
    numba.set_num_threads(1)


# ---------------------------------------------------------------------------------------------
# Frames and the fitted map
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TangentFrame:
    """East-north-up frame tangent to the ellipsoid at a point: ENU = R·(ECEF − origin)."""

    origin_ecef_m: F64
    r_enu_from_ecef: F64

    @classmethod
    def at(cls, lat_deg: float, lon_deg: float) -> TangentFrame:
        to_ecef = Transformer.from_crs(4979, 4978, always_xy=True)
        origin = np.array(to_ecef.transform(lon_deg, lat_deg, 0.0), dtype=np.float64)
        r_ne = ned_to_ecef_matrix(math.radians(lat_deg), math.radians(lon_deg))
        return cls(origin, np.stack([r_ne[:, 1], r_ne[:, 0], -r_ne[:, 2]]))

    def to_enu(self, ecef_m: npt.ArrayLike) -> F64:
        return np.asarray((np.asarray(ecef_m, float) - self.origin_ecef_m) @ self.r_enu_from_ecef.T)

    def to_ecef(self, enu_m: npt.ArrayLike) -> F64:
        return np.asarray(np.asarray(enu_m, float) @ self.r_enu_from_ecef + self.origin_ecef_m)


@dataclass(frozen=True)
class MapPolynomial:
    """(UTM easting, northing, ellipsoidal height) as a polynomial in ENU, on normalised
    coordinates u = (enu − centre)·scale ∈ [−1, 1]³ of the fitted box."""

    exponents: npt.NDArray[np.int64]  # (terms, 3)
    coef: F64  # (terms, 3)
    centre_m: F64
    scale_per_m: F64
    max_error_m: float

    @property
    def degree(self) -> int:
        return int(self.exponents.sum(axis=1).max())

    @classmethod
    def fit(cls, frame: TangentFrame, epsg: int, lo_m: F64, hi_m: F64) -> MapPolynomial:
        """Lowest degree whose error at random check points is below MAP_TOLERANCE_M."""
        exact = _ExactMap(frame, epsg)
        centre, scale = (lo_m + hi_m) / 2.0, 2.0 / (hi_m - lo_m)
        check = np.random.default_rng(0).uniform(lo_m, hi_m, (4000, 3))
        truth = exact(check)
        for degree in range(2, MAX_MAP_DEGREE + 1):
            poly = cls._fit_degree(exact, degree, centre, scale)
            err = float(np.abs(poly(check) - truth).max())
            if err < MAP_TOLERANCE_M:
                return cls(poly.exponents, poly.coef, centre, scale, err)
        raise ValueError(f"ENU → UTM map not fitted to {MAP_TOLERANCE_M} m up to degree "
                         f"{MAX_MAP_DEGREE} (error {err:.3g} m): the DEM is too large")

    @classmethod
    def _fit_degree(cls, exact: _ExactMap, degree: int, centre: F64, scale: F64
                    ) -> MapPolynomial:
        exps = np.array([e for e in itertools.product(range(degree + 1), repeat=3)
                         if sum(e) <= degree], dtype=np.int64)
        nodes = [np.cos(np.pi * (np.arange(m) + 0.5) / m)
                 for m in (degree + 4, degree + 4, degree + 2)]  # Chebyshev nodes per axis
        u = np.stack([g.ravel() for g in np.meshgrid(*nodes, indexing="ij")], axis=-1)
        coef = np.linalg.lstsq(_monomials(u, exps), exact(centre + u / scale), rcond=None)[0]
        return cls(exps, np.asarray(coef, dtype=np.float64), centre, scale, math.inf)

    def __call__(self, enu_m: npt.ArrayLike) -> F64:
        """(..., 3) ENU → (..., 3) easting, northing, height (numpy; the kernels inline this)."""
        u = (np.asarray(enu_m, float) - self.centre_m) * self.scale_per_m
        return np.asarray(_monomials(u, self.exponents) @ self.coef)


def _monomials(u: F64, exps: npt.NDArray[np.int64]) -> F64:
    return np.asarray(np.prod(u[..., None, :] ** exps, axis=-1))


class _ExactMap:
    """ENU → (E, N, h) through pyproj: the reference the polynomial is fitted to."""

    def __init__(self, frame: TangentFrame, epsg: int) -> None:
        self.frame = frame
        self._to_geo = Transformer.from_crs(4978, 4979, always_xy=True)
        self._to_utm = Transformer.from_crs(4326, epsg, always_xy=True)

    def __call__(self, enu_m: F64) -> F64:
        p = self.frame.to_ecef(enu_m)
        lon, lat, h = self._to_geo.transform(p[..., 0], p[..., 1], p[..., 2])
        e, n = self._to_utm.transform(lon, lat)
        return np.stack([e, n, h], axis=-1)


# ---------------------------------------------------------------------------------------------
# Jitted ray intersection
# ---------------------------------------------------------------------------------------------


@_jit()
def _map_at(x: float, y: float, z: float, exps: Any, coef: Any, box: Any, powers: Any
            ) -> tuple[float, float, float]:
    """(E, N, h) at an ENU point from the fitted polynomial; `powers` is (3, degree + 1)
    scratch."""
    deg = powers.shape[1] - 1
    powers[0, 0] = powers[1, 0] = powers[2, 0] = 1.0
    u = (x - box[0, 0]) * box[1, 0]
    v = (y - box[0, 1]) * box[1, 1]
    w = (z - box[0, 2]) * box[1, 2]
    for k in range(1, deg + 1):
        powers[0, k] = powers[0, k - 1] * u
        powers[1, k] = powers[1, k - 1] * v
        powers[2, k] = powers[2, k - 1] * w
    e = n = h = 0.0
    for t in range(exps.shape[0]):
        m = powers[0, exps[t, 0]] * powers[1, exps[t, 1]] * powers[2, exps[t, 2]]
        e += coef[t, 0] * m
        n += coef[t, 1] * m
        h += coef[t, 2] * m
    return e, n, h


@_jit()
def _sphere_range(c: Any, d: Any, target_m: float) -> float:
    """Range at which the ray reaches `target_m` over a sphere tangent at the ENU origin: a
    guess, checked by the caller; NaN if the ray never gets that low."""
    a = (d[0] * d[0] + d[1] * d[1]) / (2.0 * MEAN_EARTH_RADIUS_M)
    b = d[2] + (c[0] * d[0] + c[1] * d[1]) / MEAN_EARTH_RADIUS_M
    k = c[2] + (c[0] * c[0] + c[1] * c[1]) / (2.0 * MEAN_EARTH_RADIUS_M) - target_m
    disc = b * b - 4.0 * a * k
    if disc < 0.0 or b >= 0.0:
        return np.nan
    return float(2.0 * k / (-b + math.sqrt(disc)))


@_jit()
def _bracket_end(c: Any, d: Any, s: float, target_m: float, above: bool, exps: Any,
                 coef: Any, box: Any, powers: Any) -> tuple[float, float, float, float]:
    """(s, E, N, h): the guessed range moved until the ray is truly above (or below)
    target_m, never behind the camera (a camera below the highest DEM cell searches from
    itself); s is NaN if that fails."""
    e = n = h = np.nan
    for _ in range(20):
        e, n, h = _map_at(c[0] + s * d[0], c[1] + s * d[1], c[2] + s * d[2], exps, coef, box,
                          powers)
        miss = h - target_m
        if (above and (miss >= 0.0 or s <= 0.0)) or (not above and miss <= 0.0):
            return s, e, n, h
        s = max(s + miss / d[2] + (-1.0 if above else 1.0), 0.0)
    return np.nan, e, n, h


_Quad = tuple[float, float, float, float, float, float, float, float, float]


@_jit()
def _coefficients(span: float, y0: float, ym: float, y1: float) -> tuple[float, float, float]:
    """(a, b, c) of a + b·t + c·t² through (0, y0), (span/2, ym), (span, y1)."""
    if span <= 0.0:
        return y0, 0.0, 0.0
    c = 2.0 * (y1 - 2.0 * ym + y0) / (span * span)
    return y0, (y1 - y0) / span - c * span, c


@_jit()
def _quadratic(span: float, v0: Any, vm: Any, v1: Any) -> _Quad:
    """E, N, h ≈ a + b·t + c·t² for t ∈ [0, span] (t = s − s0), through three exact points,
    as (aE, bE, cE, aN, bN, cN, ah, bh, ch)."""
    e = _coefficients(span, v0[0], vm[0], v1[0])
    n = _coefficients(span, v0[1], vm[1], v1[1])
    h = _coefficients(span, v0[2], vm[2], v1[2])
    return (e[0], e[1], e[2], n[0], n[1], n[2], h[0], h[1], h[2])


@_jit()
def _along(q: _Quad, t: float) -> tuple[float, float, float]:
    return (q[0] + t * (q[1] + t * q[2]), q[3] + t * (q[4] + t * q[5]),
            q[6] + t * (q[7] + t * q[8]))


@_jit()
def _gap(q: _Quad, t: float, dem: Any, geo: Any) -> float:
    """Height of the ray above the DEM at t along it (NaN off the DEM)."""
    e, n, h = _along(q, t)
    return h - bilinear_at(dem, geo[0], geo[1], geo[2], e, n)


@_jit()
def _tile_span(e0: float, n0: float, e1: float, n1: float, geo: Any, tiles: Any
               ) -> tuple[float, float]:
    """(lowest, highest) DEM height under the box spanned by two ground positions, from the
    per-tile extremes."""
    k = geo[3]
    x0 = ((min(e0, e1) - geo[0]) / geo[2] - 0.5) / k
    x1 = ((max(e0, e1) - geo[0]) / geo[2] - 0.5) / k
    y0 = ((geo[1] - max(n0, n1)) / geo[2] - 0.5) / k
    y1 = ((geo[1] - min(n0, n1)) / geo[2] - 0.5) / k
    rows, cols = tiles.shape[1], tiles.shape[2]
    lo, hi = np.inf, -np.inf
    for r in range(min(max((math.floor(y0)), 0), rows - 1),
                   min(max((math.floor(y1)), 0), rows - 1) + 1):
        for c in range(min(max((math.floor(x0)), 0), cols - 1),
                       min(max((math.floor(x1)), 0), cols - 1) + 1):
            lo = min(lo, tiles[0, r, c])
            hi = max(hi, tiles[1, r, c])
    return lo, hi


@_jit()
def _when_height(q: _Quad, height_m: float, t: float) -> float:
    """t at which the ray's height is height_m (Newton from t; h is nearly linear in t)."""
    for _ in range(3):
        slope = q[7] + 2.0 * q[8] * t
        if slope >= 0.0:
            return np.nan
        t -= (q[6] + t * (q[7] + t * q[8]) - height_m) / slope
    return t


@_jit()
def _shrink(q: _Quad, ta: float, tb: float, geo: Any, tiles: Any) -> tuple[float, float]:
    """Narrow [ta, tb] to where the ray is between the lowest and highest DEM heights under
    its own footprint: the first hit cannot lie outside, so fewer steps are marched."""
    for _ in range(3):
        ea, na, _ = _along(q, ta)
        eb, nb, _ = _along(q, tb)
        lo, hi = _tile_span(ea, na, eb, nb, geo, tiles)
        new_a = _when_height(q, hi + SHRINK_SLACK_M, ta)
        new_b = _when_height(q, lo - SHRINK_SLACK_M, tb)
        if not ta < new_a:  # also NaN: the ray starts below the local top (low camera)
            new_a = ta
        if not new_b < tb:
            new_b = tb
        if new_a > new_b:
            return ta, tb
        ta, tb = new_a, new_b
    return ta, tb


@_jit()
def _first_crossing(q: _Quad, ta: float, tb: float, steps: int, dem: Any, geo: Any
                    ) -> tuple[float, float, float, float]:
    """First step interval where the ray passes from above the DEM to on/below it; NaN if none
    (or if it first meets the DEM from below, through the DEM's side)."""
    t0, f0 = np.nan, np.nan
    for k in range(steps + 1):
        t = ta + (tb - ta) * k / steps
        f = _gap(q, t, dem, geo)
        if f <= 0.0:
            if f0 > 0.0:
                return t0, f0, t, f
            break
        t0, f0 = t, f
    return np.nan, np.nan, np.nan, np.nan


@_jit()
def _refine(q: _Quad, ta: float, fa: float, tb: float, fb: float, dem: Any, geo: Any) -> float:
    """Illinois regula falsi inside [ta, tb] where the gap goes from > 0 to ≤ 0."""
    side = 0
    t = tb
    for _ in range(60):
        if fb == 0.0 or tb - ta < ROOT_TOLERANCE_M:
            return tb if fb == 0.0 else t
        t = (ta * fb - tb * fa) / (fb - fa)
        f = _gap(q, t, dem, geo)
        if abs(f) < 0.1 * ROOT_TOLERANCE_M:
            return t
        if f > 0.0:
            ta, fa = t, f
            if side == 1:
                fb *= 0.5
            side = 1
        else:
            tb, fb = t, f
            if side == -1:
                fa *= 0.5
            side = -1
    return t


@_jit()
def _ray_hit(c: Any, d: Any, exps: Any, coef: Any, box: Any, powers: Any, dem: Any, geo: Any,
             tiles: Any, h_range: Any) -> tuple[float, float, float]:
    """(E, N, h) where the ray c + s·d (ENU, |d| = 1) first meets the DEM, or NaNs."""
    miss = (np.nan, np.nan, np.nan)
    s1 = _sphere_range(c, d, h_range[0] - BRACKET_MARGIN_M)
    if not s1 > 0.0:
        return miss
    s0 = _sphere_range(c, d, h_range[1] + BRACKET_MARGIN_M)
    s0, e0, n0, h0 = _bracket_end(c, d, s0 if s0 > 0.0 else 0.0, h_range[1], True, exps, coef,
                                  box, powers)
    s1, e1, n1, h1 = _bracket_end(c, d, s1, h_range[0], False, exps, coef, box, powers)
    if not (s0 >= 0.0 and s1 >= s0):
        return miss
    sm = 0.5 * (s0 + s1)
    vm = _map_at(c[0] + sm * d[0], c[1] + sm * d[1], c[2] + sm * d[2], exps, coef, box, powers)
    q = _quadratic(s1 - s0, (e0, n0, h0), vm, (e1, n1, h1))
    ta, tb = _shrink(q, 0.0, s1 - s0, geo, tiles)
    ea, na, _ = _along(q, ta)
    eb, nb, _ = _along(q, tb)
    steps = max(1, math.ceil(math.hypot(eb - ea, nb - na) / (0.5 * geo[2])))
    ta, fa, tb, fb = _first_crossing(q, ta, tb, steps, dem, geo)
    if not fa > 0.0:
        return miss
    return _along(q, _refine(q, ta, fa, tb, fb, dem, geo))


@_jit(parallel=True)
def _intersect_kernel(cam: Any, rot: Any, look: Any, exps: Any, coef: Any, box: Any, dem: Any,
                      geo: Any, tiles: Any, h_range: Any, out: Any) -> None:
    """out[l, j] = ground (E, N, h) of pixel j of line l; rot[l] maps camera → ENU."""
    lines, pixels = cam.shape[0], look.shape[1]
    deg = int(exps.max())
    for i in numba.prange(lines):
        powers = np.empty((3, deg + 1))
        c = (cam[i, 0], cam[i, 1], cam[i, 2])
        r = rot[i]
        for j in range(pixels):
            dx = r[0, 0] * look[0, j] + r[0, 1] * look[1, j] + r[0, 2] * look[2, j]
            dy = r[1, 0] * look[0, j] + r[1, 1] * look[1, j] + r[1, 2] * look[2, j]
            dz = r[2, 0] * look[0, j] + r[2, 1] * look[1, j] + r[2, 2] * look[2, j]
            norm = math.sqrt(dx * dx + dy * dy + dz * dz)
            out[i, j, 0], out[i, j, 1], out[i, j, 2] = _ray_hit(
                c, (dx / norm, dy / norm, dz / norm), exps, coef, box, powers, dem, geo, tiles,
                h_range)


# ---------------------------------------------------------------------------------------------
# Public geometry
# ---------------------------------------------------------------------------------------------


def camera_pose_ecef(state: TrajectoryState, mounting: Mounting | FrameMounting
                     ) -> tuple[F64, F64]:
    """Perspective centres (N, 3) and camera → ECEF rotations (N, 3, 3) at the INS states:
    r^e = r^e_INS + R_b^e·a^b, R_c^e = R_n^e·R_b^n·R_c^b (the scanner's or the frame
    camera's mounting: each gives its own R_c^b, nominal mounting included)."""
    r_ne = ned_to_ecef_matrix(np.radians(state.lat_deg), np.radians(state.lon_deg))
    r_be = r_ne @ body_to_ned_matrix(state.roll_rad, state.pitch_rad, state.heading_rad)
    centre = state.ecef_m + r_be @ np.asarray(mounting.lever_arm_m, float)
    return centre, np.asarray(r_be @ mounting.boresight_matrix())


def pixel_rays_ecef(state: TrajectoryState, scanner: ScannerSettings, mounting: Mounting,
                    pixel: npt.ArrayLike) -> tuple[F64, F64]:
    """Perspective centre and unit look direction (ECEF) of pixel[i] at state i (N rays)."""
    centre, r_ce = camera_pose_ecef(state, mounting)
    look = scanner.look_vectors_camera()[:, np.asarray(pixel, dtype=np.int64)]
    d = np.einsum("nij,jn->ni", r_ce, look)
    return centre, d / np.linalg.norm(d, axis=1, keepdims=True)


class GroundIntersector:
    """Where rays meet the DEM: built once per terrain (a tangent frame at the DEM centre and
    the fitted ENU → UTM/h map), then fast and thread-parallel for any number of rays."""

    def __init__(self, terrain: Terrain) -> None:
        w, s, e, n = terrain.bounds_m
        to_geo = Transformer.from_crs(terrain.epsg, 4326, always_xy=True)
        lon0, lat0 = to_geo.transform((w + e) / 2.0, (s + n) / 2.0)
        self.frame = TangentFrame.at(float(lat0), float(lon0))
        self.epsg = terrain.epsg
        self.h_range_m = np.array([float(terrain.heights.min()), float(terrain.heights.max())])
        self.map = MapPolynomial.fit(self.frame, terrain.epsg, *self._box(terrain, to_geo))
        self._dem = np.ascontiguousarray(terrain.heights)
        self._geo = np.array([w, n, terrain.spacing_m, TILE_CELLS])
        self._tiles = _tile_extremes(self._dem, TILE_CELLS)
        self._box_arr = np.stack([self.map.centre_m, self.map.scale_per_m])

    def _box(self, terrain: Terrain, to_geo: Transformer) -> tuple[F64, F64]:
        """ENU box holding the DEM extent (a cell beyond) between its lowest and highest
        heights, with room for the bracket margins and the earth's curvature."""
        w, s, e, n = terrain.bounds_m
        pad = terrain.spacing_m
        te = np.linspace(w - pad, e + pad, 9)
        tn = np.linspace(s - pad, n + pad, 9)
        ee, nn = (g.ravel() for g in np.meshgrid(te, tn))
        lon, lat = to_geo.transform(ee, nn)
        lo_h, hi_h = self.h_range_m + np.array([-2.0, 2.0]) * BRACKET_MARGIN_M
        pts = []
        to_ecef = Transformer.from_crs(4979, 4978, always_xy=True)
        for h in (lo_h, hi_h):
            x, y, z = to_ecef.transform(lon, lat, np.full_like(lon, h))
            pts.append(self.frame.to_enu(np.stack([x, y, z], axis=-1)))
        enu = np.concatenate(pts)
        return enu.min(axis=0) - 1.0, enu.max(axis=0) + 1.0

    def intersect_lines(self, centre_ecef_m: F64, r_cam_to_ecef: F64, look_c: F64) -> F64:
        """Ground (E, N, h) of every pixel of every line, shape (lines, pixels, 3); NaN where
        the ray misses the DEM."""
        cam = np.ascontiguousarray(self.frame.to_enu(centre_ecef_m))
        rot = np.ascontiguousarray(self.frame.r_enu_from_ecef @ r_cam_to_ecef)
        out = np.empty((cam.shape[0], look_c.shape[1], 3))
        _intersect_kernel(cam, rot, np.ascontiguousarray(look_c, dtype=np.float64),
                          self.map.exponents, self.map.coef, self._box_arr, self._dem,
                          self._geo, self._tiles, self.h_range_m, out)
        return out

    def intersect_rays(self, centre_ecef_m: F64, dir_ecef: F64) -> F64:
        """Ground (E, N, h) of N rays given in ECEF, shape (N, 3); NaN for misses."""
        n = centre_ecef_m.shape[0]
        rot = np.zeros((n, 3, 3))
        rot[:, :, 2] = dir_ecef  # the look vector (0, 0, 1) maps to the ray's direction
        return self.intersect_lines(centre_ecef_m, rot, np.array([[0.0], [0.0], [1.0]]))[:, 0]


def _tile_extremes(dem: F32, k: int) -> F64:
    """(2, tile rows, tile cols): lowest and highest of the cell centres that bilinear
    interpolation uses anywhere in each k × k tile of centre-to-centre spans (its closing row
    and column included)."""
    rows, cols = dem.shape
    tr, tc = -(-(rows - 1) // k), -(-(cols - 1) // k)
    pad = np.full((tr * k + 1, tc * k + 1), np.nan, np.float64)
    pad[:rows, :cols] = dem
    out = np.empty((2, tr, tc))
    for reduce_, idx in ((np.fmin, 0), (np.fmax, 1)):
        body = reduce_.reduce(reduce_.reduce(
            pad[:-1, :-1].reshape(tr, k, tc, k), axis=3), axis=1)
        edge_r = reduce_.reduce(pad[k::k, :-1].reshape(tr, tc, k), axis=2)
        edge_c = reduce_.reduce(pad[:-1, k::k].reshape(tr, k, tc), axis=1)
        out[idx] = reduce_(reduce_(body, edge_r), reduce_(edge_c, pad[k::k, k::k]))
    return out


def exact_ground_point(terrain: Terrain, centre_ecef_m: F64, dir_ecef: F64,
                       step_m: float = 0.5) -> F64:
    """The slow oracle: (E, N, h) where each ECEF ray first meets the DEM, by marching in
    `step_m` steps with pyproj at every point (ECEF → geodetic → UTM) and Terrain.height_at,
    then bisecting to 1e-6 m. NaN rows for rays that miss. Shares no code with the fast path."""
    to_geo = Transformer.from_crs(4978, 4979, always_xy=True)
    to_utm = Transformer.from_crs(4326, terrain.epsg, always_xy=True)
    d = dir_ecef / np.linalg.norm(dir_ecef, axis=1, keepdims=True)

    def ground(s: F64) -> tuple[F64, F64, F64, F64]:
        p = centre_ecef_m + s[:, None] * d
        lon, lat, h = to_geo.transform(p[:, 0], p[:, 1], p[:, 2])
        e, n = to_utm.transform(lon, lat)
        return np.asarray(e), np.asarray(n), np.asarray(h), h - terrain.height_at(e, n)

    top = _exact_range_to(ground, centre_ecef_m.shape[0], float(terrain.heights.max()) + 1.0)
    bottom = _exact_range_to(ground, centre_ecef_m.shape[0], float(terrain.heights.min()) - 1.0)
    lo, hi = _exact_first_crossing(ground, top, bottom, step_m)
    for _ in range(64):
        mid = 0.5 * (lo + hi)
        above = ground(np.nan_to_num(mid))[3] > 0.0
        lo, hi = np.where(above, mid, lo), np.where(above, hi, mid)
    e, n, h, _ = ground(np.nan_to_num(hi))
    out = np.stack([e, n, h], axis=-1)
    out[np.isnan(hi)] = np.nan
    return out


_Ground = Callable[[F64], tuple[F64, F64, F64, F64]]


def _exact_range_to(ground: _Ground, n: int, height_m: float) -> F64:
    """Range at which each ray's ellipsoidal height is height_m (Newton on pyproj heights; the
    height is nearly linear in range, so a few steps converge)."""
    s = np.zeros(n)
    for _ in range(8):
        h = ground(s)[2]
        dh_per_m = ground(s + 1.0)[2] - h
        s = s - (h - height_m) / np.where(dh_per_m < 0.0, dh_per_m, np.nan)
    return s


def _exact_first_crossing(ground: _Ground, top: F64, bottom: F64, step_m: float
                          ) -> tuple[F64, F64]:
    """Step from `top` to `bottom`; the first step where the gap to the DEM turns ≤ 0. NaN
    for rays that never go down through the DEM's height range."""
    lo = np.full(top.shape, np.nan)
    hi = np.full(top.shape, np.nan)
    top = np.maximum(top, 0.0)  # a camera below the DEM's highest point searches from itself
    ok = np.isfinite(top) & np.isfinite(bottom) & (bottom >= top)
    if not ok.any():
        return lo, hi
    top, bottom = np.where(ok, top, 0.0), np.where(ok, bottom, 0.0)
    prev, s_prev = ground(top)[3], top
    for k in range(1, int(np.ceil(np.max(bottom - top) / step_m)) + 2):
        s = np.minimum(top + k * step_m, bottom)
        gap = ground(s)[3]
        new = ok & np.isnan(hi) & (prev > 0.0) & (gap <= 0.0)
        lo[new], hi[new] = s_prev[new], s[new]
        prev, s_prev = gap, s
    return lo, hi


# ---------------------------------------------------------------------------------------------
# Radiometry and the renderer
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SensorResponse:
    """Radiance factor → DN of a 12-bit CASI-class detector with the integration time set for
    the scene: dark offset, linear gain, shot and read noise, saturation. A miss is DN 0."""

    dark_dn: float = 150.0
    gain_dn: float = 3000.0  # signal DN for a radiance factor of 1
    electrons_per_dn: float = 25.0
    read_noise_dn: float = 1.5
    full_scale_dn: float = 4095.0


@_jit(parallel=True)
def _to_dn(radiance: Any, noise: Any, params: Any, out: Any) -> None:
    """radiance (bands, lines, pixels) + unit normal noise (lines, bands, pixels) → out (BIL)."""
    dark, gain, e_per_dn, read, full = params[0], params[1], params[2], params[3], params[4]
    bands, lines, pixels = radiance.shape
    for i in numba.prange(lines):
        for b in range(bands):
            for j in range(pixels):
                r = radiance[b, i, j]
                if not math.isfinite(r):
                    out[i, b, j] = 0
                    continue
                signal = max(gain * r, 0.0)
                sigma = math.sqrt(read * read + signal / e_per_dn)
                dn = dark + signal + sigma * noise[i, b, j]
                out[i, b, j] = np.uint16(min(max(round(dn), 1.0), full))


class LineRenderer:
    """Renders whole scan lines from true poses: rays → DEM → scene → DN (lines, bands, pixels)."""

    def __init__(self, scanner: ScannerSettings, mounting: Mounting, terrain: Terrain,
                 scene: Scene, rng: np.random.Generator,
                 response: SensorResponse | None = None,
                 intersector: GroundIntersector | None = None) -> None:
        if scene.bands != scanner.bands:
            raise ValueError(f"scene has {scene.bands} bands, the scanner {scanner.bands}")
        self.scanner = scanner
        self.mounting = mounting
        self.scene = scene
        self.rng = rng
        self.response = response or SensorResponse()
        self.intersector = intersector or GroundIntersector(terrain)
        self._look = scanner.look_vectors_camera()
        self.rays = 0
        self.missed_rays = 0

    def ground(self, state: TrajectoryState) -> F64:
        """Ground (E, N, h) of every pixel of the lines at these states, (lines, pixels, 3)."""
        centre, r_ce = camera_pose_ecef(state, self.mounting)
        return self.intersector.intersect_lines(centre, r_ce, self._look)

    def render(self, state: TrajectoryState) -> U16:
        """DN of the lines at these states, shape (lines, bands, pixels): BIL order."""
        hits = self.ground(state)
        lines, pixels = hits.shape[:2]
        self.rays += lines * pixels
        self.missed_rays += int(np.isnan(hits[..., 0]).sum())
        rad = self.scene.radiance(hits[..., 0].ravel(), hits[..., 1].ravel())
        return dn_from_radiance(rad.reshape(-1, lines, pixels), self.rng, self.response)


def dn_from_radiance(radiance: F32, rng: np.random.Generator, response: SensorResponse) -> U16:
    """Radiance factors (bands, lines, pixels) → DN (lines, bands, pixels), BIL order, with the
    detector's noise drawn from `rng` (NaN, a ray that missed: DN 0)."""
    bands, lines, pixels = radiance.shape
    noise = rng.standard_normal((lines, bands, pixels), dtype=np.float32)
    out = np.empty((lines, bands, pixels), np.uint16)
    r = response
    _to_dn(radiance, noise, np.array([r.dark_dn, r.gain_dn, r.electrons_per_dn,
                                      r.read_noise_dn, r.full_scale_dn]), out)
    return out


# ---------------------------------------------------------------------------------------------
# Quicklook
# ---------------------------------------------------------------------------------------------


def raw_dn_envi_header(*, description: str, samples: int, lines: int, bands: int,
                       sensor_type: str, extra: dict[str, str] | None = None) -> str:
    """ENVI header of an emulated raw-DN BIL image (data type 12 = uint16, byte order 0 =
    little-endian, DN 0 = no data: a ray that missed the DEM), then the `extra` fields."""
    fields = {
        "description": f"{{{description}}}",
        "samples": str(samples),
        "lines": str(lines),
        "bands": str(bands),
        "header offset": "0",
        "file type": "ENVI Standard",
        "data type": "12",
        "interleave": "bil",
        "byte order": "0",
        "data ignore value": "0",
        "sensor type": sensor_type,
        **(extra or {}),
    }
    return "ENVI\n" + "".join(f"{k} = {v}\n" for k, v in fields.items())


def read_envi_header(hdr_path: str | Path) -> dict[str, str]:
    """Fields of an ENVI header as raw strings (braces stripped), lower-case keys."""
    text = Path(hdr_path).read_text(encoding="utf-8")
    if not text.startswith("ENVI"):
        raise ValueError(f"{hdr_path}: not an ENVI header")
    fields: dict[str, str] = {}
    key = ""
    parts: list[str] = []
    for line in text.splitlines()[1:]:
        if not parts and "=" in line:
            key, value = (x.strip() for x in line.split("=", 1))
            parts = [value]
        elif parts:
            parts.append(line.strip())
        if parts and (not parts[0].startswith("{") or parts[-1].endswith("}")):
            fields[key.lower()] = " ".join(parts).strip("{} ")
            parts = []
    return fields


def write_quicklook_png(bil_path: str | Path, png_path: str | Path,
                        max_size_px: int = 4096) -> None:
    """RGB PNG of a recorded BIL segment (true colour, or colour infrared when the bands cannot
    make true colour), lines down the image as recorded, each channel stretched 2–98 % over
    valid pixels; block-averaged so that neither side exceeds max_size_px."""
    bil = Path(bil_path)
    hdr = read_envi_header(bil.with_suffix(".hdr"))
    if hdr.get("interleave") != "bil" or hdr.get("data type") != "12":
        raise ValueError(f"{bil}: expected uint16 BIL, got {hdr}")
    lines, bands, pixels = (int(hdr[k]) for k in ("lines", "bands", "samples"))
    wl = np.array([float(x) for x in hdr["wavelength"].split(",")])
    cube = np.memmap(bil, dtype="<u2", mode="r", shape=(lines, bands, pixels))
    k = max(1, math.ceil(max(lines, pixels) / max_size_px))
    h, w = lines // k, pixels // k
    rgb = np.empty((3, h, w), np.uint8)
    for c, b in enumerate(quicklook_bands(wl)):
        band = cube[: h * k, b, : w * k].astype(np.float32)
        band[band == 0] = np.nan  # rays that missed the DEM
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-missing blocks stay NaN
            rgb[c] = _stretch(np.nanmean(band.reshape(h, k, w, k), axis=(1, 3)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(Path(png_path), "w", driver="PNG", width=w, height=h, count=3,
                           dtype="uint8") as ds:
            ds.write(rgb)


TRUE_COLOUR_NM: Final = (640.0, 550.0, 470.0)
COLOUR_INFRARED_NM: Final = (860.0, 650.0, 550.0)
TRUE_COLOUR_TOLERANCE_NM: Final = 40.0


def quicklook_bands(wavelengths_nm: F64) -> list[int]:
    """Band indices for red, green, blue: true colour if a band lies near each of 640, 550 and
    470 nm, else the colour-infrared composite (NIR, red, green) that few bands still give."""
    def nearest(targets: tuple[float, float, float]) -> list[int]:
        return [int(np.abs(wavelengths_nm - nm).argmin()) for nm in targets]

    rgb = nearest(TRUE_COLOUR_NM)
    close = np.abs(wavelengths_nm[rgb] - TRUE_COLOUR_NM) <= TRUE_COLOUR_TOLERANCE_NM
    return rgb if len(set(rgb)) == 3 and close.all() else nearest(COLOUR_INFRARED_NM)


def _stretch(channel: F64) -> npt.NDArray[np.uint8]:
    """2–98 % of the valid values → 1..255; missing pixels 0 (black)."""
    valid = np.isfinite(channel)
    if not valid.any():
        return np.zeros(channel.shape, np.uint8)
    lo, hi = (float(v) for v in np.percentile(channel[valid], [2.0, 98.0]))
    scaled = np.clip((channel - lo) / max(hi - lo, 1e-6), 0.0, 1.0) * 254.0 + 1.0
    return np.where(valid, np.rint(scaled), 0.0).astype(np.uint8)
