"""Surfaces for calibration: the DEM (surface control, check-point rays) or given heights.

A narrow-FOV line scanner sees a tie point from nearly the same direction in both strips
(base/height ≈ 0.4 or less), so its height is weak; a DEM observation h(X) = DEM(E(X), N(X)) ± σ
fixes it (seed 001: σ_Z falls to σ_DEM). Heights are ellipsoidal, as in postproc.georef.dem.
"""

from __future__ import annotations

from functools import cache
from typing import Final, Protocol

import numpy as np
import numpy.typing as npt
from pyproj import Transformer

from postproc.georef import Dem, ecef_to_geodetic

F64 = npt.NDArray[np.float64]

RAY_ITERATIONS: Final = 30
RAY_TOL_M: Final = 1e-4


class Surface(Protocol):
    def heights(self, ecef_m: F64) -> tuple[F64, F64]:
        """(ellipsoidal height of each point, surface height below/above it), metres."""
        ...


@cache
def _to_map(epsg: int) -> Transformer:
    return Transformer.from_crs(4326, epsg, always_xy=True)


class DemSurface:
    """The DEM, bilinear between cell centres; NaN off the grid."""

    def __init__(self, dem: Dem) -> None:
        self.dem = dem

    def heights(self, ecef_m: F64) -> tuple[F64, F64]:
        lat, lon, h = ecef_to_geodetic(ecef_m)
        e, n = _to_map(self.dem.epsg).transform(lon, lat)
        return np.asarray(h, np.float64), self.dem.height_at(e, n)


class GivenHeights:
    """One known height per ray (the check point's surveyed height, seed 000 §6)."""

    def __init__(self, height_m: F64) -> None:
        self.height_m = np.asarray(height_m, np.float64)

    def heights(self, ecef_m: F64) -> tuple[F64, F64]:
        _, _, h = ecef_to_geodetic(ecef_m)
        return np.asarray(h, np.float64), self.height_m


def intersect_rays(surface: Surface, centre_ecef_m: F64, dir_ecef: F64) -> F64:
    """Where rays (unit directions) meet the surface, ECEF (N, 3); NaN where they do not.
    Secant iteration on h(point) − h(surface) along the range."""
    n = centre_ecef_m.shape[0]
    up = centre_ecef_m / np.linalg.norm(centre_ecef_m, axis=1, keepdims=True)
    down = np.maximum(-np.einsum("ni,ni->n", dir_ecef, up), 0.05)

    def gap(s: F64) -> F64:
        hp, hs = surface.heights(centre_ecef_m + s[:, None] * dir_ecef)
        return np.asarray(hp - hs, np.float64)

    h_c, h_below = surface.heights(centre_ecef_m)
    s0 = np.where(np.isfinite(h_below), (h_c - h_below) / down, 1000.0)
    s1 = s0 + 10.0
    g0, g1 = gap(s0), gap(s1)
    for _ in range(RAY_ITERATIONS):
        denom = g1 - g0
        ok = np.isfinite(denom) & (np.abs(denom) > 1e-12)
        s2 = np.where(ok, s1 - g1 * (s1 - s0) / np.where(ok, denom, 1.0), s1 + g1 / down)
        s0, g0, s1 = s1, g1, s2
        g1 = gap(s1)
        if np.all(~np.isfinite(g1) | (np.abs(g1) < RAY_TOL_M)):
            break
    out = centre_ecef_m + s1[:, None] * dir_ecef
    out[~(np.abs(g1) < 10 * RAY_TOL_M)] = np.nan
    return out if n else np.zeros((0, 3))
