"""The reference method: the slow oracle that shares no code with the fast path's search
(pyproj at every point of a march that cannot step over a crossing, then bisection), and the
rays the kernel leaves to it."""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from postproc.georef.dem import Dem
from postproc.georef.raycast.maps import transformers
from postproc.georef.raycast.rays import GroundPoints, checked_rays
from postproc.georef.raycast.surface import cell_slopes

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
U8 = npt.NDArray[np.uint8]

REFERENCE_MIN_STEP_M: Final = 1e-4
REFERENCE_MAX_STEPS: Final = 100_000  # march steps per ray; a ray still marching then: missed
REFERENCE_TOLERANCE_M: Final = 1e-7


def reference_intersect(dem: Dem, centre_ecef_m: F64, r_ecef_from_camera: F64,
                        look_camera: F64) -> GroundPoints:
    """Same result as `intersect`, slowly and independently: float64 throughout, pyproj
    (ECEF → geodetic → map) at every point of a march whose steps cannot skip a crossing
    (gap / (1 + steepest DEM slope), at most half a cell in the DEM's height range), then
    bisection to REFERENCE_TOLERANCE_M."""
    centre, rot, look, posed_lines = checked_rays(centre_ecef_m, r_ecef_from_camera,
                                                  look_camera)
    n, p = centre.shape[0], look.shape[1]
    posed = np.repeat(posed_lines, p)
    d = np.einsum("nij,jp->npi", rot, look).reshape(-1, 3)
    c = np.repeat(centre, p, axis=0)
    c[~posed], d[~posed] = [0.0, 0.0, 1e7], [0.0, 0.0, 1.0]  # unposed: far up, looking up
    e, nn, h, _ = _reference_rays(dem, c, d)
    for a in (e, nn, h):
        a[~posed] = np.nan
    return GroundPoints(e.reshape(n, p), nn.reshape(n, p), h.reshape(n, p),
                        np.isfinite(e).reshape(n, p))


def resolve_exact(dem: Dem, out: GroundPoints, line_flag: U8, centre: F64, rot: F64,
                  unit: F64) -> tuple[int, int]:
    """Rays the kernel left outside every fitted map (+inf height): reference method.
    Returns (rays, rays left unresolved by its step budget: missed)."""
    lines = np.flatnonzero(line_flag)
    if lines.size == 0:
        return 0, 0
    li, pj = np.nonzero(np.isposinf(out.height_m[lines]))
    li = lines[li]
    d = np.einsum("nij,jn->ni", rot[li], unit[:, pj])
    e, n, h, unresolved = _reference_rays(dem, centre[li], d)
    out.easting_m[li, pj], out.northing_m[li, pj], out.height_m[li, pj] = e, n, h
    out.hit[li, pj] = np.isfinite(e)
    return int(li.size), unresolved


def _local_rates(dem: Dem) -> F64:
    """Per DEM cell (rows-1, cols-1): 1.02 · (1 + the steepest slope of the 3 x 3 cells around
    it), a bound of |d gap / ds| over any step of at most half a cell from a point in that
    cell (it stays among those cells: the map scale is within 2 % of 1). Nodata cells count
    0: the gap there is NaN, a miss."""
    slopes = cell_slopes(dem).astype(np.float64)
    slopes[~np.isfinite(slopes)] = 0.0
    pad = np.pad(slopes, 1)
    rows, cols = slopes.shape
    near = slopes.copy()
    for dr in range(3):
        for dc in range(3):
            np.maximum(near, pad[dr:dr + rows, dc:dc + cols], out=near)
    return np.asarray(1.02 * (1.0 + near))


def _reference_rays(dem: Dem, centre: F64, direction: F64
                    ) -> tuple[F64, F64, F64, int]:
    """(E, N, h) where each ray first meets the DEM, NaN for misses, by the rules of the package
    docstring, and the number of rays left unresolved. Above the DEM's highest sample a step
    is the height above it (|dh/ds| ≤ 1); within the height range it is gap / rate (rate
    bounds |d gap / ds| over the cells within reach, `_local_rates`), at most half a cell (so
    no nodata cell is stepped over). A ray still marching after REFERENCE_MAX_STEPS steps is
    left missed (NaN) and counted as unresolved: every call ends."""
    to_geo, to_map, _, _ = transformers(dem.epsg)
    d = direction / np.linalg.norm(direction, axis=1, keepdims=True)
    high = float(np.nanmax(dem.heights_m))
    rates = _local_rates(dem)
    cap = 0.5 * min(dem.cell_e_m, dem.cell_n_m)

    def sample(s: F64, idx: I64) -> tuple[F64, F64, F64, F64, F64]:
        p = centre[idx] + s[:, None] * d[idx]
        lon, lat, h = (np.asarray(v) for v in to_geo.transform(p[:, 0], p[:, 1], p[:, 2]))
        e, n = (np.asarray(v) for v in to_map.transform(lon, lat))
        up = np.stack([np.cos(np.radians(lat)) * np.cos(np.radians(lon)),
                       np.cos(np.radians(lat)) * np.sin(np.radians(lon)),
                       np.sin(np.radians(lat))], axis=-1)
        rising = np.einsum("ni,ni->n", d[idx], up) >= 0.0
        return e, n, h, h - dem.height_at(e, n), rising.astype(np.float64)

    def rate_at(e: F64, n: F64) -> F64:
        with np.errstate(invalid="ignore"):
            x = np.nan_to_num((e - dem.first_easting_m) / dem.cell_e_m)
            y = np.nan_to_num((dem.first_northing_m - n) / dem.cell_n_m)
        c = np.clip(np.floor(x), 0, dem.cols - 2).astype(np.intp)
        r = np.clip(np.floor(y), 0, dem.rows - 2).astype(np.intp)
        return np.asarray(rates[r, c])

    m = centre.shape[0]
    s = np.zeros(m)
    lo = np.full(m, np.nan)
    hi = np.full(m, np.nan)
    active = np.ones(m, bool)
    for _ in range(REFERENCE_MAX_STEPS):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        e, n, h, gap, rising = sample(s[idx], idx)
        above = h > high
        with np.errstate(invalid="ignore"):
            crossed = ~above & (gap <= 0.0)
            step = np.where(above, np.maximum(h - high, REFERENCE_MIN_STEP_M),
                            np.clip(gap / rate_at(e, n), REFERENCE_MIN_STEP_M, cap))
        miss = (above & (rising > 0.0)) | (~above & np.isnan(gap)) | (crossed & (s[idx] == 0.0))
        found = crossed & ~miss
        hi[idx[found]] = s[idx[found]]
        active[idx[miss | found]] = False
        go = ~(miss | found)
        lo[idx[go]] = s[idx[go]]
        s[idx[go]] += step[go]
    unresolved = int(active.sum())
    ok = np.flatnonzero(np.isfinite(hi))
    a, b = lo[ok], hi[ok]
    while ok.size and float((b - a).max()) > REFERENCE_TOLERANCE_M:
        mid = 0.5 * (a + b)
        gap = sample(mid, ok)[3]
        with np.errstate(invalid="ignore"):
            above = gap > 0.0
        a, b = np.where(above, mid, a), np.where(above, b, mid)
    e = np.full(m, np.nan)
    n = np.full(m, np.nan)
    h = np.full(m, np.nan)
    if ok.size:
        ee, nn, hh, gap, _ = sample(b, ok)
        good = np.isfinite(gap)
        e[ok[good]], n[ok[good]], h[ok[good]] = ee[good], nn[good], hh[good]
    return e, n, h, unresolved
