"""Where each scanner ray first meets the DEM: the post-processor's ray casting.

Geometry. Rays are straight in ECEF; the DEM is a bilinear surface of ELLIPSOIDAL height over a
projected (UTM) grid, and (E, N, h) are not Cartesian (curvature drops a point 1 km from nadir
by ~8 cm; the UTM scale varies). Lines are grouped in blocks; for each block a local East-North-Up
frame is fitted with a QUADRATIC map p ↦ (E, N, h), least squares on pyproj at Chebyshev nodes
of a box holding every ray's path through the DEM's height range, and checked at other points
(< MAP_TOLERANCE_M, else the block is split). Along one ray E, N and h are then exact quadratics
in the range s, with per-line coefficients, so a ray costs a few multiply-adds to set up.

Fast path (numba, parallel over blocks, lines in order within a block). Each ray starts from the
range of the same pixel in the previous line (float64 set-up of float32 quadratic models of the
grid position and height in t = s − start, relative to the block) and takes two branch-free
float32 Newton steps on g = h − DEM(E, N), both on the bilinear patch of the cell under the
start (vectorised; its four corner heights are two 8-byte gathers, and the cells a few lines
ahead are prefetched); the few rays (~2 %) whose first step leaves that cell restart from there.
Inside one DEM cell g is a quadratic in t, so the last step bounds the remaining error: a ray is
accepted only if |g''|·step²/(2|g'|) < ROOT_TOLERANCE_M, that step stayed in the cell, and the
root is provably the FIRST one: g falls monotonically along the ray's whole path through the
DEM's height range when the steepest DEM slope under the paths of a group of rays (a sparse
table of per-tile slope maxima) times the ray's horizontal/vertical rate is below 1. Float32
rounding relative to the block leaves < 0.1 mm; the output is evaluated in float64. Every other
ray takes the safe path (float64): a cell-by-cell walk along the ray from the top of the DEM's
height range, solving the (quadratic-in-s) gap exactly inside each cell, so a ray grazing a
ridge or occluded by a cliff finds its first crossing.

Misses (hit False, NaN): rays that never come down to the DEM's highest sample, that pass off
the DEM or over a nodata cell (one with ANY nodata corner) while within the DEM's height range
(nothing is invented about unknown terrain), and cameras below the surface. The few rays whose
path leaves the box a block's map was fitted to are solved by the reference method.

The DEM must hold terrain: NaN for no data, heights within SURFACE_HEIGHTS_M (InputError
otherwise: a void marker such as -9999 left in the heights would make a 10 km pit, which no
block map fits, and send every ray to the reference method). Every loop is bounded: the cell
walk to 10 million cells (then the reference method), root refinement to 100 steps, the
reference march to REFERENCE_MAX_STEPS per ray (a ray still marching then is a miss, counted
in CastStats.unresolved).

`reference_intersect` is the slow oracle sharing no code with the fast path: pyproj at every
point, DEM heights from `Dem.height_at`, steps no longer than gap / (1 + steepest slope within
reach) so no crossing can be skipped, then bisection to 1e-7 m.
"""

from __future__ import annotations

import itertools
import math
import weakref
from dataclasses import dataclass
from functools import lru_cache
from typing import Final, cast

import numba
import numpy as np
import numpy.typing as npt
from pyproj import Transformer

from postproc.georef.dem import SURFACE_HEIGHTS_M, Dem
from postproc.georef.raycast.kernel import (
    TILE_CELLS,
    cast_blocks,
    coefficients_kernel,
    footprint_kernel,
    pose_check,
    scratch,
)
from sisa.core.errors import InputError

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
U8 = npt.NDArray[np.uint8]
B1 = npt.NDArray[np.bool_]

BLOCK_LINES: Final = 512  # lines sharing one fitted map (and one parallel work item)
MAP_TOLERANCE_M: Final = 3e-5  # fitted map vs pyproj at check points
BOX_MARGIN_M: Final = 60.0  # map box beyond the sampled footprints...
BOX_MARGIN_FRACTION: Final = 0.1  # ...plus this fraction of its size
BAND_PAD_M: Final = 10.0  # map box reaches this far above / below the DEM's heights
FOOTPRINT_LEVELS: Final = 17  # heights spanning the DEM's range; a block's band is widened
# to the nearest of them (its map box is sized by footprints there)
REFERENCE_MIN_STEP_M: Final = 1e-4
REFERENCE_MAX_STEPS: Final = 100_000  # march steps per ray; a ray still marching then: missed
REFERENCE_TOLERANCE_M: Final = 1e-7


# ---------------------------------------------------------------------------------------------
# Public API
# ---------------------------------------------------------------------------------------------


@dataclass
class GroundPoints:
    """First intersection of every ray with the DEM, in the DEM's CRS: easting, northing and
    ellipsoidal height (lines, pixels), NaN where the ray misses (hit False)."""

    easting_m: F64
    northing_m: F64
    height_m: F64
    hit: B1

    @classmethod
    def empty(cls, lines: int, pixels: int) -> GroundPoints:
        """Uninitialised buffers: allocate once, pass as `out=` for every chunk of lines."""
        shape = (lines, pixels)
        return cls(np.empty(shape), np.empty(shape), np.empty(shape), np.empty(shape, np.bool_))

    @property
    def shape(self) -> tuple[int, int]:
        return cast(tuple[int, int], self.easting_m.shape)


@dataclass
class CastStats:
    """How the rays of one `intersect` call were resolved (for benchmarks and reports)."""

    fast: int = 0  # accepted from the Newton path
    safe_hit: int = 0  # cell walk, hit
    safe_miss: int = 0  # cell walk, miss
    exact: int = 0  # outside the fitted maps: reference method
    unresolved: int = 0  # of those, still marching after REFERENCE_MAX_STEPS steps: missed
    blocks: int = 0
    map_error_m: float = 0.0  # worst fitted-map error at the check points


def intersect(dem: Dem, centre_ecef_m: F64, r_ecef_from_camera: F64, look_camera: F64, *,
              out: GroundPoints | None = None, stats: CastStats | None = None) -> GroundPoints:
    """Ground point of every pixel of every line: ray i, j is
    centre_ecef_m[i] + s · r_ecef_from_camera[i] @ look_camera[:, j], s ≥ 0.

    centre_ecef_m (n, 3), r_ecef_from_camera (n, 3, 3) rotations, look_camera (3, p)
    unnormalised camera-frame look vectors. Coordinates in the DEM's CRS, accurate to
    < 1 mm of range. A line whose pose is NaN (no time) gives NaN, hit False. `out` buffers
    are reused when given (shape (n, p)); `stats`, when given, is filled in."""
    centre, rot, look, posed = _checked_rays(centre_ecef_m, r_ecef_from_camera, look_camera)
    n, p = centre.shape[0], look.shape[1]
    out = _output(out, n, p)
    if n == 0 or p == 0:
        return out
    if not posed.all():  # lines without a pose: NaN, the others as usual
        sub = intersect(dem, centre[posed], rot[posed], look, stats=stats)
        for full, part in ((out.easting_m, sub.easting_m), (out.northing_m, sub.northing_m),
                           (out.height_m, sub.height_m)):
            full[posed], full[~posed] = part, np.nan
        out.hit[posed], out.hit[~posed] = sub.hit, False
        return out
    surf = _surface(dem)
    unit = look / np.linalg.norm(look, axis=0)
    maps = _fit_block_maps(surf, centre, rot, unit)
    coef = _line_coefficients(maps, centre, rot)
    blk, consts = _kernel_tables(surf, maps)
    line_flag = np.zeros(n, np.uint8)
    counts = np.zeros((maps.starts.size - 1, 4), np.int64)
    cast_blocks(surf.flat, surf.flat, surf.cols, surf.slope_table, surf.log2, coef,
                _look_products(unit), maps.starts, blk, consts, out.easting_m, out.northing_m,
                out.height_m, out.hit.view(np.uint8), line_flag, counts, *scratch(p))
    exact, unresolved = _resolve_exact(dem, out, line_flag, centre, rot, unit)
    if stats is not None:
        total = counts.sum(axis=0)
        stats.fast, stats.safe_hit, stats.safe_miss = int(total[0]), int(total[1]), int(total[2])
        stats.exact, stats.unresolved = exact, unresolved
        stats.blocks = int(maps.starts.size - 1)
        stats.map_error_m = float(maps.error_m.max())
    return out


def reference_intersect(dem: Dem, centre_ecef_m: F64, r_ecef_from_camera: F64,
                        look_camera: F64) -> GroundPoints:
    """Same result as `intersect`, slowly and independently: float64 throughout, pyproj
    (ECEF → geodetic → map) at every point of a march whose steps cannot skip a crossing
    (gap / (1 + steepest DEM slope), at most half a cell in the DEM's height range), then
    bisection to REFERENCE_TOLERANCE_M."""
    centre, rot, look, posed_lines = _checked_rays(centre_ecef_m, r_ecef_from_camera,
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


def _checked_rays(centre: F64, rot: F64, look: F64) -> tuple[F64, F64, F64, B1]:
    """Contiguous float64 inputs and the lines with a pose (finite centre and rotation)."""
    c = np.ascontiguousarray(centre, dtype=np.float64)
    r = np.ascontiguousarray(rot, dtype=np.float64)
    lk = np.ascontiguousarray(look, dtype=np.float64)
    n = c.shape[0] if c.ndim == 2 else -1
    if c.shape != (n, 3) or r.shape != (n, 3, 3) or lk.ndim != 2 or lk.shape[0] != 3:
        raise ValueError(f"expected centre (n, 3), rotation (n, 3, 3), look (3, p); got "
                         f"{c.shape}, {r.shape}, {lk.shape}")
    if not np.isfinite(lk).all() or (lk.shape[1] and not (np.linalg.norm(lk, axis=0) > 0.0).all()):
        raise ValueError("look vectors must be finite and non-zero")
    ok = np.empty(n, np.bool_)
    if pose_check(c, r, ok.view(np.uint8)) > 1e-6:
        raise ValueError("r_ecef_from_camera must be rotation matrices")
    return c, r, lk, ok


def _output(out: GroundPoints | None, n: int, p: int) -> GroundPoints:
    if out is None:
        return GroundPoints.empty(n, p)
    arrays = (out.easting_m, out.northing_m, out.height_m)
    if (any(a.shape != (n, p) or a.dtype != np.float64 or not a.flags.c_contiguous
            for a in arrays) or out.hit.shape != (n, p) or out.hit.dtype != np.bool_
            or not out.hit.flags.c_contiguous):
        raise ValueError(f"out buffers must be C-contiguous float64/bool of shape {(n, p)}")
    return out


# ---------------------------------------------------------------------------------------------
# The prepared DEM
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class _Surface:
    """What the kernel needs of a DEM, built once per DEM: flat heights, their range, and a
    sparse table of per-tile slope maxima (inf where a tile touches nodata)."""

    dem: Dem
    flat: F32
    rows: int
    cols: int
    low_m: float
    high_m: float
    slope_table: F32  # (levels, tile rows, tile cols): max over 2**level tiles from col
    log2: I64  # floor(log2(k)) for k = 0..tile cols
    coarse_map: _Maps  # over the whole DEM: only to size the blocks' boxes

    @classmethod
    def build(cls, dem: Dem) -> _Surface:
        h = dem.heights_m
        if not np.isfinite(h).any():
            raise InputError("the DEM has no valid height (every sample is NaN)")
        low, high = float(np.nanmin(h)), float(np.nanmax(h))
        if not SURFACE_HEIGHTS_M[0] <= low <= high <= SURFACE_HEIGHTS_M[1]:
            raise InputError(f"the DEM has heights from {low:g} to {high:g} m, outside any "
                             f"terrain ({SURFACE_HEIGHTS_M[0]:g}..{SURFACE_HEIGHTS_M[1]:g} m): "
                             "void markers (-9999, -32768, ...) must be NaN")
        slope = cell_slopes(dem)
        table = _sparse_table(_tile_max(slope, TILE_CELLS))
        log2 = np.zeros(table.shape[2] + 1, np.int64)
        log2[2:] = np.floor(np.log2(np.arange(2, table.shape[2] + 1))).astype(np.int64)
        coarse = _fit_maps(np.array([dem.bounds_m], dtype=np.float64), low, high, dem.epsg)
        return cls(dem, np.ascontiguousarray(h).ravel(), dem.rows, dem.cols, low, high, table,
                   log2, coarse)


_SURFACES: weakref.WeakKeyDictionary[Dem, _Surface] = weakref.WeakKeyDictionary()


def _surface(dem: Dem) -> _Surface:
    surf = _SURFACES.get(dem)
    if surf is None:
        surf = _SURFACES[dem] = _Surface.build(dem)
    return surf


def cell_slopes(dem: Dem) -> F32:
    """Upper bound of |grad h| (m/m) over each cell's bilinear patch, (rows-1, cols-1); inf
    where a corner is nodata. Float32 (rounding is far inside the margins it is used with)."""
    z = dem.heights_m
    gx = np.maximum(np.abs(z[:-1, 1:] - z[:-1, :-1]), np.abs(z[1:, 1:] - z[1:, :-1]))
    gy = np.maximum(np.abs(z[1:, :-1] - z[:-1, :-1]), np.abs(z[1:, 1:] - z[:-1, 1:]))
    s = np.hypot(gx * np.float32(1.0 / dem.cell_e_m), gy * np.float32(1.0 / dem.cell_n_m))
    s[np.isnan(s)] = np.inf
    return np.asarray(s, dtype=np.float32)


def _tile_max(cells: F32, k: int) -> F32:
    rows, cols = cells.shape
    tr, tc = -(-rows // k), -(-cols // k)
    pad = np.zeros((tr * k, tc * k), np.float32)
    pad[:rows, :cols] = cells
    return np.asarray(pad.reshape(tr, k, tc, k).max(axis=(1, 3)), dtype=np.float32)


def _sparse_table(tiles: F32) -> F32:
    """table[k, r, c] = max(tiles[r, c : c + 2**k]) (clipped at the last column)."""
    levels = max(1, math.floor(math.log2(tiles.shape[1])) + 1)
    table = np.empty((levels, *tiles.shape), np.float32)
    table[0] = tiles
    for k in range(1, levels):
        half = 1 << (k - 1)
        table[k] = table[k - 1]
        table[k, :, :-half] = np.maximum(table[k - 1, :, :-half], table[k - 1, :, half:])
    return table


# ---------------------------------------------------------------------------------------------
# Fitted maps: local ENU → (E, N, h), one per block of lines
# ---------------------------------------------------------------------------------------------


@lru_cache(maxsize=16)
def _transformers(epsg: int) -> tuple[Transformer, Transformer, Transformer, Transformer]:
    """(ECEF → geodetic, geodetic → map, map → geodetic, geodetic → ECEF), built once."""
    return (Transformer.from_crs(4978, 4979, always_xy=True),
            Transformer.from_crs(4326, epsg, always_xy=True),
            Transformer.from_crs(epsg, 4326, always_xy=True),
            Transformer.from_crs(4979, 4978, always_xy=True))


def _enu_rotation(lat_rad: F64, lon_rad: F64) -> F64:
    """(..., 3, 3) rows east, north, up in ECEF."""
    sl, cl, so, co = np.sin(lat_rad), np.cos(lat_rad), np.sin(lon_rad), np.cos(lon_rad)
    z = np.zeros_like(sl)
    return np.stack([np.stack([-so, co, z], -1), np.stack([-sl * co, -sl * so, cl], -1),
                     np.stack([cl * co, cl * so, sl], -1)], -2)


_EXPONENTS: Final = np.array([e for e in itertools.product(range(3), repeat=3) if sum(e) <= 2])


def _monomials(u: F64) -> F64:
    return np.asarray(np.prod(u[..., None, :] ** _EXPONENTS, axis=-1))


def _chebyshev_nodes() -> F64:
    axes = [np.cos(np.pi * (np.arange(m) + 0.5) / m) for m in (4, 4, 3)]
    return np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=-1)


_NODES: Final = _chebyshev_nodes()
_FIT: Final = np.linalg.pinv(_monomials(_NODES))
_CHECKS: Final = np.concatenate([
    np.array(list(itertools.product((-1.0, 1.0), repeat=3))),
    np.random.default_rng(20_260_615).uniform(-1.0, 1.0, (8, 3))])
_CHECK_MONOMIALS: Final = _monomials(_CHECKS)


@dataclass(frozen=True)
class _Maps:
    """Per block: line range, ENU origin and rotation, the quadratic map
    (E − E0, N − N0, h − h0) = a + g·p + ½ pᵀHp, and the DEM-grid box it is valid in."""

    starts: I64  # (blocks + 1,)
    origin_ecef_m: F64  # (b, 3)
    rot: F64  # (b, 3, 3) ENU rows
    a: F64  # (b, 3)
    g: F64  # (b, 3, 3) [component, axis]
    hess: F64  # (b, 3, 3, 3) [component, axis, axis]
    en0_m: F64  # (b, 2) E0, N0
    h0_m: F64  # (b,)
    box_en_m: F64  # (b, 4) west, south, east, north where the map is valid
    error_m: F64  # (b,) worst check-point error
    low_m: F64  # (b,) lowest and highest terrain the block's rays can meet (see
    high_m: F64  # _fit_block_maps): the height band of the map and of the kernel's search


_PER_BLOCK: Final = ("origin_ecef_m", "rot", "a", "g", "hess", "en0_m", "h0_m", "box_en_m",
                      "error_m", "low_m", "high_m")  # _Maps' fields after `starts`, in order


def _fit_maps(boxes: F64, low_m: npt.ArrayLike, high_m: npt.ArrayLike, epsg: int) -> _Maps:
    """Quadratic ENU → (E, N, h) maps over each EN box × [low, high] (padded; per box or one
    for all), by least squares on pyproj at Chebyshev nodes; error at independent check
    points."""
    to_geo, to_map, from_map, to_ecef = _transformers(epsg)
    b = boxes.shape[0]
    low = np.broadcast_to(np.asarray(low_m, np.float64), (b,)).copy()
    high = np.broadcast_to(np.asarray(high_m, np.float64), (b,)).copy()
    en0 = np.round(0.5 * (boxes[:, :2] + boxes[:, 2:]))
    h0 = np.round(0.5 * (low + high))
    lon0, lat0 = from_map.transform(en0[:, 0], en0[:, 1])
    origin = np.stack(to_ecef.transform(lon0, lat0, h0), axis=-1)
    rot = _enu_rotation(np.radians(lat0), np.radians(lon0))
    # p-box: ENU bounding box of the EN box's corners, edge midpoints and centre at both heights
    t = np.array([0.0, 0.5, 1.0])
    fe, fn, fh = (g.ravel() for g in np.meshgrid(t, t, [0.0, 1.0], indexing="ij"))
    e = boxes[:, None, 0] + fe * (boxes[:, None, 2] - boxes[:, None, 0])
    n = boxes[:, None, 1] + fn * (boxes[:, None, 3] - boxes[:, None, 1])
    h = (low[:, None] - BAND_PAD_M) + fh * (high - low + 2.0 * BAND_PAD_M)[:, None] + 0.0 * e
    p = _map_to_enu(e, n, h, origin, rot, epsg)
    centre = 0.5 * (p.min(axis=1) + p.max(axis=1))
    half = 0.5 * (p.max(axis=1) - p.min(axis=1)) + 2.0

    def exact(u: F64) -> F64:
        q = centre[:, None] + u[None] * half[:, None]
        x = origin[:, None] + q @ rot
        lon, lat, hh = to_geo.transform(x[..., 0], x[..., 1], x[..., 2])
        ee, nn = to_map.transform(lon, lat)
        return np.stack([ee - en0[:, None, 0], nn - en0[:, None, 1], hh - h0[:, None]], -1)

    coef = _FIT @ exact(_NODES)  # (b, 10 terms, 3)
    err = np.abs(_CHECK_MONOMIALS @ coef - exact(_CHECKS))
    a, g, hess = _expand(coef, centre, half)
    return _Maps(np.zeros(0, np.int64), origin, rot, a, g, hess, en0, h0, boxes.copy(),
                 err.max(axis=(1, 2)), low, high)


def _map_to_enu(e: F64, n: F64, h: F64, origin: F64, rot: F64, epsg: int) -> F64:
    _, _, from_map, to_ecef = _transformers(epsg)
    lon, lat = from_map.transform(e, n)
    x = np.stack(to_ecef.transform(lon, lat, h), axis=-1)
    return np.asarray((x - origin[:, None]) @ np.swapaxes(rot, 1, 2))


def _expand(coef: F64, centre: F64, half: F64) -> tuple[F64, F64, F64]:
    """Polynomial in u = (p − centre)/half → a + g·p + ½ pᵀHp (per block and component)."""
    b = coef.shape[0]
    lin = np.zeros((b, 3, 3))  # [b, k, axis] coefficient of u_axis
    quad = np.zeros((b, 3, 3, 3))  # [b, k, i, j] so that ½ uᵀ quad u is the quadratic part
    const = np.zeros((b, 3))
    for t, ex in enumerate(_EXPONENTS):
        idx = [i for i in range(3) for _ in range(ex[i])]
        if len(idx) == 0:
            const += coef[:, t]
        elif len(idx) == 1:
            lin[:, :, idx[0]] += coef[:, t]
        elif idx[0] == idx[1]:
            quad[:, :, idx[0], idx[0]] += 2.0 * coef[:, t]
        else:
            quad[:, :, idx[0], idx[1]] += coef[:, t]
            quad[:, :, idx[1], idx[0]] += coef[:, t]
    inv = 1.0 / half  # (b, 3)
    hess = quad * inv[:, None, :, None] * inv[:, None, None, :]
    g0 = lin * inv[:, None, :]
    g = g0 - np.einsum("bkij,bj->bki", hess, centre)
    a = (const - np.einsum("bki,bi->bk", g0, centre)
         + 0.5 * np.einsum("bi,bkij,bj->bk", centre, hess, centre))
    return a, g, hess


def _fit_block_maps(surf: _Surface, centre: F64, rot: F64, unit: F64) -> _Maps:
    """Blocks of BLOCK_LINES lines, each with a map fitted over the box its rays' paths
    through its height band cover (from a coarse whole-DEM map). The band is first the DEM's
    whole range; a block whose map misses MAP_TOLERANCE_M then takes its own band, and is
    halved until it fits (a single line that cannot is left with an empty box: its rays go to
    the reference method). Where every block fits at first, nothing changes.

    A block's height band is the terrain's range inside the box its rays' paths cover through
    the whole DEM's range (margins as for every box): above the band those paths pass over
    nothing as high, below it nothing is as low, so the first crossing is within it. Bands
    keep the maps small where the DEM spans more relief than one block sees (alpine terrain:
    3.8 km of relief sent every ray to the reference method). A box with a void keeps the
    DEM's whole range (a ray over a void while in that range is a miss, as before)."""
    dem = surf.dem
    n = centre.shape[0]
    hull = np.array(dem.bounds_m, dtype=np.float64)
    lines = _every(n, 8)
    pix = _every(unit.shape[1], 16)
    levels = np.linspace(surf.low_m, surf.high_m, FOOTPRINT_LEVELS)
    foot: dict[int, F64] = {}  # footprints (sampled lines, 4) at the levels asked for so far

    def footprints(*ks: I64) -> dict[int, F64]:
        new = sorted({int(k) for k in np.concatenate(ks)} - foot.keys())
        if new:
            got = _footprints(surf.coarse_map, centre[lines], rot[lines], unit[:, pix],
                              levels[new], hull)
            foot.update({k: got[:, i] for i, k in enumerate(new)})
        return foot

    # equal blocks, as many as a multiple of the threads: the kernel's static schedule is
    # balanced
    threads = numba.get_num_threads()
    count = min(n, math.ceil(math.ceil(n / BLOCK_LINES) / threads) * threads)
    bounds = (np.arange(count + 1, dtype=np.int64) * n) // count
    start, stop = bounds[:-1], bounds[1:]
    banded = np.zeros(start.size, np.bool_)  # blocks given their own height band
    parts: list[tuple[I64, _Maps]] = []
    for _ in range(64):
        k_lo, k_hi = np.zeros_like(start), np.full_like(start, FOOTPRINT_LEVELS - 1)
        low, high = np.full(start.size, surf.low_m), np.full(start.size, surf.high_m)
        if banded.any():
            reach = _block_boxes(footprints(k_lo, k_hi), lines, start[banded], stop[banded],
                                 hull, k_lo[banded], k_hi[banded])
            low[banded], high[banded] = _box_heights(surf, reach)
            k_lo[banded], k_hi[banded] = _level_span(levels, low[banded], high[banded])
        boxes = _block_boxes(footprints(k_lo, k_hi), lines, start, stop, hull, k_lo, k_hi)
        maps = _fit_maps(boxes, low, high, dem.epsg)
        keep = (maps.error_m <= MAP_TOLERANCE_M) | (banded & (stop - start == 1))
        parts.append((start[keep], _take(maps, keep)))
        # a block that misses with the DEM's whole range tries its own band first, then halves
        retry, halve = ~keep & ~banded, ~keep & banded
        mid = (start + stop) // 2
        start, stop, banded = (np.concatenate([start[retry], start[halve], mid[halve]]),
                               np.concatenate([stop[retry], mid[halve], stop[halve]]),
                               np.ones(int(retry.sum() + 2 * halve.sum()), np.bool_))
        if start.size == 0:
            break
    starts = np.concatenate([p[0] for p in parts])
    order = np.argsort(starts)
    maps = _concat([p[1] for p in parts], order)
    bad = maps.error_m > MAP_TOLERANCE_M
    maps.box_en_m[bad] = [np.inf, np.inf, -np.inf, -np.inf]
    return _with_starts(maps, np.append(starts[order], n).astype(np.int64))


def _box_heights(surf: _Surface, boxes: F64) -> tuple[F64, F64]:
    """Lowest and highest DEM sample of each EN box (b, 4), with the cells around its edges;
    the DEM's whole range where a box holds a void or no sample."""
    dem = surf.dem
    low, high = np.full(boxes.shape[0], surf.low_m), np.full(boxes.shape[0], surf.high_m)
    heights = surf.flat.reshape(surf.rows, surf.cols)
    for k, (w, s, e, n) in enumerate(boxes):
        c0 = max(math.floor((w - dem.first_easting_m) / dem.cell_e_m), 0)
        c1 = min(math.ceil((e - dem.first_easting_m) / dem.cell_e_m) + 1, surf.cols)
        r0 = max(math.floor((dem.first_northing_m - n) / dem.cell_n_m), 0)
        r1 = min(math.ceil((dem.first_northing_m - s) / dem.cell_n_m) + 1, surf.rows)
        if r1 <= r0 or c1 <= c0:
            continue
        window = heights[r0:r1, c0:c1]
        lo, hi = float(window.min()), float(window.max())
        if math.isfinite(lo) and math.isfinite(hi):  # NaN (a void) propagates: whole range
            low[k], high[k] = lo, hi
    return low, high


def _level_span(levels: F64, low: F64, high: F64) -> tuple[I64, I64]:
    """Per block, the footprint levels that bracket [low, high]."""
    k_lo = np.clip(np.searchsorted(levels, low, side="right") - 1, 0, levels.size - 1)
    k_hi = np.clip(np.searchsorted(levels, high, side="left"), 0, levels.size - 1)
    return k_lo.astype(np.int64), np.maximum(k_hi, k_lo).astype(np.int64)


def _every(n: int, k: int) -> I64:
    """0, k, 2k, ... and n - 1 (sorted, unique)."""
    idx = np.arange(0, n, k, dtype=np.int64)
    return idx if idx[-1] == n - 1 else np.append(idx, np.int64(n - 1))


def _take(maps: _Maps, keep: B1) -> _Maps:
    return _Maps(maps.starts, *(getattr(maps, f)[keep] for f in _PER_BLOCK))


def _concat(parts: list[_Maps], order: I64) -> _Maps:
    return _Maps(np.zeros(0, np.int64),
                 *(np.concatenate([getattr(p, f) for p in parts])[order] for f in _PER_BLOCK))


def _with_starts(maps: _Maps, starts: I64) -> _Maps:
    return _Maps(starts, *(getattr(maps, f) for f in _PER_BLOCK))


def _footprints(coarse: _Maps, centre: F64, rot: F64, unit: F64, levels: F64, hull: F64
                ) -> F64:
    """Per line and height level (lines, levels, 4): approximate EN box (west, south, east,
    north) of where its rays cross that height (the camera itself when below), clipped to the
    DEM; the camera's own position when no ray comes down."""
    coarse = _with_starts(coarse, np.array([0, centre.shape[0]], np.int64))
    coef = _line_coefficients(coarse, centre, rot)
    out = np.empty((centre.shape[0], levels.size, 4))
    footprint_kernel(coef, _look_products(unit), levels - coarse.h0_m[0], coarse.en0_m[0],
                     hull, out)
    return out


def _block_boxes(foot: dict[int, F64], lines: I64, start: I64, stop: I64, hull: F64,
                 k_lo: I64, k_hi: I64) -> F64:
    """EN boxes (blocks, 4: west, south, east, north) for lines [start, stop): the sampled
    footprints of the lines around them at the levels k_lo and k_hi of each block (a ray's
    path between two heights lies between its crossings of them), grown by BOX_MARGIN_M and
    BOX_MARGIN_FRACTION, within the DEM."""
    lo = np.searchsorted(lines, start - 8)
    hi = np.maximum(np.searchsorted(lines, stop + 8), lo + 1)
    idx = np.stack([lo, hi], axis=1).ravel()
    used = np.union1d(k_lo, k_hi)
    per_level = np.empty((used.size, start.size, 4))
    for m, k in enumerate(used.tolist()):
        pad = np.vstack([foot[k], foot[k][-1:]])
        per_level[m] = np.stack([np.minimum.reduceat(pad[:, 0], idx)[::2],
                                 np.minimum.reduceat(pad[:, 1], idx)[::2],
                                 np.maximum.reduceat(pad[:, 2], idx)[::2],
                                 np.maximum.reduceat(pad[:, 3], idx)[::2]], axis=1)
    blocks = np.arange(start.size)
    a = per_level[np.searchsorted(used, k_lo), blocks]
    z = per_level[np.searchsorted(used, k_hi), blocks]
    box = np.concatenate([np.minimum(a[:, :2], z[:, :2]), np.maximum(a[:, 2:], z[:, 2:])],
                         axis=1)
    grow = BOX_MARGIN_M + BOX_MARGIN_FRACTION * np.maximum(box[:, 2] - box[:, 0],
                                                           box[:, 3] - box[:, 1])
    box += grow[:, None] * np.array([-1.0, -1.0, 1.0, 1.0])
    return np.asarray(np.clip(box, np.tile(hull[:2], 2), np.tile(hull[2:], 2)))


def _line_coefficients(maps: _Maps, centre: F64, rot: F64) -> F64:
    """Per line i, in its block's frame: E, N, h (relative to the block origin) along ray j are
    A + B·s + C·s² with B = u·l_j and C = l_jᵀQl_j. Packed (n, 30): A (3), u (3 × 3),
    ½Q as (q00, q11, q22, q01, q02, q12) × 3, matching `_look_products`."""
    blk = np.repeat(np.arange(maps.starts.size - 1), np.diff(maps.starts))
    out = np.empty((centre.shape[0], 30))
    coefficients_kernel(blk, maps.origin_ecef_m, maps.rot, maps.a, maps.g, maps.hess, centre,
                        rot, out)
    return out


def _look_products(unit: F64) -> F64:
    """(9, p): l0, l1, l2, l0², l1², l2², 2·l0·l1, 2·l0·l2, 2·l1·l2 of unit look vectors."""
    l0, l1, l2 = unit
    return np.ascontiguousarray(np.stack([l0, l1, l2, l0 * l0, l1 * l1, l2 * l2,
                                          2 * l0 * l1, 2 * l0 * l2, 2 * l1 * l2]))


def _ray_terms(coef: F64, look9: F64) -> tuple[F64, F64]:
    """B and C (lines, pixels, 3) of every ray (numpy; the kernel inlines the same sums)."""
    u = coef[:, 3:12].reshape(-1, 3, 3)
    q = coef[:, 12:30].reshape(-1, 3, 6)
    return (np.einsum("nki,ip->npk", u, look9[:3]), np.einsum("nkm,mp->npk", q, look9[3:]))


def _kernel_tables(surf: _Surface, maps: _Maps) -> tuple[F64, F64]:
    """Per block (b, 14): fractional grid offset of the block origin (x, y), its integer grid
    origin (x, y), the valid box in local grid coordinates (x0, x1, y0, y1), E0, N0, h0, (unused),
    the lowest and highest terrain its rays can meet. Constants: 1/cell_e, 1/cell_n."""
    dem = surf.dem
    gx = (maps.en0_m[:, 0] - dem.first_easting_m) / dem.cell_e_m
    gy = (dem.first_northing_m - maps.en0_m[:, 1]) / dem.cell_n_m
    ox, oy = np.round(gx), np.round(gy)
    box = maps.box_en_m
    with np.errstate(invalid="ignore"):
        vx0 = np.clip((box[:, 0] - dem.first_easting_m) / dem.cell_e_m, 0, dem.cols - 1)
        vx1 = np.clip((box[:, 2] - dem.first_easting_m) / dem.cell_e_m, 0, dem.cols - 1)
        vy0 = np.clip((dem.first_northing_m - box[:, 3]) / dem.cell_n_m, 0, dem.rows - 1)
        vy1 = np.clip((dem.first_northing_m - box[:, 1]) / dem.cell_n_m, 0, dem.rows - 1)
    empty = ~np.isfinite(box).all(axis=1)
    vx0[empty], vx1[empty] = 1.0, 0.0
    blk = np.stack([gx - ox, gy - oy, ox, oy, vx0 - ox, vx1 - ox, vy0 - oy, vy1 - oy,
                    maps.en0_m[:, 0], maps.en0_m[:, 1], maps.h0_m, np.zeros_like(ox),
                    maps.low_m, maps.high_m], axis=1)
    consts = np.array([1.0 / dem.cell_e_m, 1.0 / dem.cell_n_m])
    return np.ascontiguousarray(blk), consts


# ---------------------------------------------------------------------------------------------
# Reference method
# ---------------------------------------------------------------------------------------------


def _resolve_exact(dem: Dem, out: GroundPoints, line_flag: U8, centre: F64, rot: F64,
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
    """(E, N, h) where each ray first meets the DEM, NaN for misses, by the rules of the module
    docstring, and the number of rays left unresolved. Above the DEM's highest sample a step
    is the height above it (|dh/ds| ≤ 1); within the height range it is gap / rate (rate
    bounds |d gap / ds| over the cells within reach, `_local_rates`), at most half a cell (so
    no nodata cell is stepped over). A ray still marching after REFERENCE_MAX_STEPS steps is
    left missed (NaN) and counted as unresolved: every call ends."""
    to_geo, to_map, _, _ = _transformers(dem.epsg)
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
