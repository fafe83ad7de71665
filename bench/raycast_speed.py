"""Ray–DEM intersection (issue 38): `intersect`, whole call, against a reference kernel
written here from the issue's method, interleaved in one process; a numpy baseline; the
stage split of `intersect`; the accuracy of all three against the slow float64 reference.

    .venv/bin/python bench/raycast_speed.py [--lines 20000] [--pairs 6] [--check-lines 4]
                                            [--profile N] [--numba] [--one-thread N]

The scene is CASI-like: 512 pixels (15 µm, f = 9.33 mm), a 20 ms line period at 60 m/s (1.2 m
per line, a 24 km strip for 20 000 lines) flown due grid north ~1500 m above a synthetic 2 m
DEM in UTM 31N (sinusoidal hills and a smooth fractal field, a few hundred metres of relief),
with ~0.3° of smooth attitude turbulence. Every method gets the same rays; the first calls
(numba compilation, DEM preparation) are excluded. `intersect` and the reference kernel then
alternate in --pairs pairs (which goes first alternates too), each timing its whole call,
per-call set-up included (block maps, per-line terms); each pair prints M rays/s wall and per
CPU-second (summed over threads), the time ratio and the load average, because the machine
may be shared and only ratios within one run compare.

The reference kernel (numba) is the method as the issue describes it: float32 models local
to the DEM cell under each ray's start and heights relative to its start height, warm starts
from the same pixel on the previous line, two branch-free Newton steps on the bilinear DEM
with 8-byte gathers, one pass over the line per step (independent short chains); its own
block maps (pyproj, least squares) and per-line terms. It has no first-root test and no
fallback: a bound on speed, not a replacement; its accuracy is measured like the others'.

The baseline is what a careful numpy implementation does: the fast path's own set-up (fitted
local maps, per-line coefficients), then 8 fixed-point iterations over all rays at once
(range to the height of the DEM under the previous estimate), timed once. --profile N times
`intersect`'s stages separately (as cast.py runs them), N times, medians. `intersect` runs the
C kernel where the CPU has AVX2 and FMA (postproc/georef/raycast/fastpath.py); --numba also
times it on numba's kernel, the fallback, in every pair, and --one-thread N times the two
kernels alone on one thread, alternating (ns of CPU a ray). Accuracy is measured
on every pixel of --check-lines random lines and of the two lines over the steepest terrain,
against `reference_intersect` (pyproj at every point, bisection): the 3-D distance between
the ground points and the difference in range along the ray.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from typing import Any, NamedTuple, TypeVar, cast

import numba
import numpy as np
import numpy.typing as npt
from pyproj import Transformer
from scipy import fft as sfft
from scipy.ndimage import gaussian_filter1d

from postproc.georef import CastStats, Dem, GroundPoints, intersect, reference_intersect
from postproc.georef.raycast import blocks, fastpath, kernel, rays, reference, surface, tables
from sisa.core.frames import body_to_ned_matrix, ned_to_ecef_matrix
from sisa.core.sensor import R_NOMINAL_C_TO_B, ScannerGeometry

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]
_Fn = TypeVar("_Fn", bound=Callable[..., Any])
EPSG = 32631
CELL_M = 2.0
SPEED_MPS, LINE_PERIOD_S = 60.0, 0.020
AGL_M = 1500.0
TURBULENCE_DEG = 0.3


def synthetic_dem(length_m: float, width_m: float, seed: int = 7) -> Dem:
    """Sinusoidal hills (±150 m) plus a smooth fractal field (std 40 m), 2 m cells."""
    rows, cols = int(length_m / CELL_M) + 1, int(width_m / CELL_M) + 1
    rng = np.random.default_rng(seed)
    e0, n0 = 430_000.0, 4_600_000.0
    e = e0 + CELL_M * np.arange(cols)
    n = n0 + length_m - CELL_M * np.arange(rows)
    hills = (150.0 * np.sin(2 * np.pi * e / 3100.0)[None, :]
             * np.cos(2 * np.pi * n / 4700.0)[:, None])
    spec = sfft.rfft2(rng.standard_normal((rows, cols)).astype(np.float32), workers=-1)
    ky = sfft.fftfreq(rows, d=CELL_M)[:, None]
    kx = sfft.rfftfreq(cols, d=CELL_M)[None, :]
    spec *= ((ky**2 + kx**2 + 1.0 / 1500.0**2) ** -1.6).astype(np.float32)
    field = sfft.irfft2(spec, s=(rows, cols), workers=-1)
    field *= 40.0 / field.std()
    heights = (600.0 + hills + field).astype(np.float32)
    return Dem(heights, e0, n0 + length_m, CELL_M, CELL_M, EPSG)


def casi_strip(dem: Dem, lines: int, seed: int = 11) -> tuple[F64, F64, F64]:
    """Perspective centres (ECEF), camera → ECEF rotations and CASI look vectors."""
    rng = np.random.default_rng(seed)
    w, s, e, _n = dem.bounds_m
    east = np.full(lines, 0.5 * (w + e))
    north = s + 300.0 + SPEED_MPS * LINE_PERIOD_S * np.arange(lines)
    height = float(np.nanmean(dem.heights_m)) + AGL_M + 5.0 * np.sin(np.arange(lines) / 900.0)
    lon, lat = Transformer.from_crs(EPSG, 4326, always_xy=True).transform(east, north)
    x, y, z = Transformer.from_crs(4979, 4978, always_xy=True).transform(lon, lat, height)
    centre = np.stack([x, y, z], axis=-1)

    def turbulence() -> F64:
        w = gaussian_filter1d(rng.standard_normal(lines), 25.0)
        return np.asarray(np.radians(TURBULENCE_DEG) * w / w.std())

    r_bn = body_to_ned_matrix(turbulence(), turbulence(), turbulence())
    r_ne = ned_to_ecef_matrix(np.radians(lat), np.radians(lon))
    return centre, r_ne @ r_bn @ R_NOMINAL_C_TO_B, ScannerGeometry().look_vectors_camera()


def numpy_baseline(dem: Dem, centre: F64, rot: F64, look: F64, out: GroundPoints,
                   iterations: int = 8, chunk_lines: int = 256) -> None:
    """The fast path's set-up, then fixed-point iterations in numpy (range to the height of
    the DEM under the previous estimate), over chunks of lines that stay in cache."""
    surf = surface.surface_of(dem)
    unit = look / np.linalg.norm(look, axis=0)
    maps = blocks.fit_block_maps(surf, centre, rot, unit)
    coef = tables.line_coefficients(maps, centre, rot)
    look9 = tables.look_products(unit)
    blk = np.repeat(np.arange(maps.starts.size - 1), np.diff(maps.starts))
    z = dem.heights_m.ravel()
    cols, rows = dem.cols, dem.rows
    for i0 in range(0, centre.shape[0], chunk_lines):
        sl = slice(i0, i0 + chunk_lines)
        b, c = tables.ray_terms(coef[sl], look9)
        a = coef[sl, None, :3]
        e0 = maps.en0_m[blk[sl], 0][:, None] + a[..., 0] - dem.first_easting_m
        n0 = dem.first_northing_m - maps.en0_m[blk[sl], 1][:, None] - a[..., 1]
        h0 = maps.h0_m[blk[sl]][:, None] + a[..., 2]
        s = -a[..., 2] / b[..., 2]  # where the ray reaches the block's reference height
        for _ in range(iterations):
            x = (e0 + s * (b[..., 0] + s * c[..., 0])) / dem.cell_e_m
            y = (n0 - s * (b[..., 1] + s * c[..., 1])) / dem.cell_n_m
            cx = np.clip(np.floor(x), 0, cols - 2)
            cy = np.clip(np.floor(y), 0, rows - 2)
            fx, fy = x - cx, y - cy
            k = cy.astype(np.intp) * cols + cx.astype(np.intp)
            top = z[k] + fx * (z[k + 1] - z[k])
            bottom = z[k + cols] + fx * (z[k + cols + 1] - z[k + cols])
            gap = h0 + s * (b[..., 2] + s * c[..., 2]) - (top + fy * (bottom - top))
            s -= gap / (b[..., 2] + 2.0 * c[..., 2] * s)
        out.easting_m[sl] = e0 + dem.first_easting_m + s * (b[..., 0] + s * c[..., 0])
        out.northing_m[sl] = dem.first_northing_m - n0 + s * (b[..., 1] + s * c[..., 1])
        out.height_m[sl] = h0 + s * (b[..., 2] + s * c[..., 2])
    out.hit[:] = np.isfinite(out.height_m)


def errors_m(dem: Dem, centre: F64, got: GroundPoints, ref: GroundPoints, sel: npt.NDArray[
        np.intp]) -> tuple[float, float, float, float, int]:
    """(max, RMS range difference, max, RMS 3-D distance, rays compared)."""
    to_geo = Transformer.from_crs(EPSG, 4326, always_xy=True)
    to_ecef = Transformer.from_crs(4979, 4978, always_xy=True)

    def ecef(g: GroundPoints) -> F64:
        lon, lat = to_geo.transform(g.easting_m[sel], g.northing_m[sel])
        return np.stack(to_ecef.transform(lon, lat, g.height_m[sel]), axis=-1)

    both = got.hit[sel] & ref.hit[sel]
    c = centre[sel][:, None, :]
    dr = np.abs(np.linalg.norm(ecef(got) - c, axis=-1) - np.linalg.norm(ecef(ref) - c, axis=-1))
    d3 = np.sqrt((got.easting_m[sel] - ref.easting_m[sel]) ** 2
                 + (got.northing_m[sel] - ref.northing_m[sel]) ** 2
                 + (got.height_m[sel] - ref.height_m[sel]) ** 2)
    dr, d3 = dr[both], d3[both]
    return (float(dr.max()), float(np.sqrt((dr**2).mean())), float(d3.max()),
            float(np.sqrt((d3**2).mean())), int(both.sum()))


# ---------------------------------------------------------------------------------------------
# The reference kernel: written for this benchmark from the method the issue describes (numba,
# float32 local origins, warm starts from the previous line, two branch-free Newton steps with
# gathers, short independent chains over the pixels); of the package's kernel it takes only
# the 8-byte load.
# No first-root test, no fallback: its accuracy is measured like the others'.
# ---------------------------------------------------------------------------------------------

REF_BLOCK_LINES = 500  # lines per fitted map and per parallel work item
REF_COLD_PASSES = 4  # Newton rounds for a work item's first line


def _njit(inline: bool = False, parallel: bool = False) -> Callable[[_Fn], _Fn]:
    """Not cached: numba's cache would not see a change to the package's `_pair`."""
    return cast(Callable[[_Fn], _Fn],
                numba.njit(cache=False, parallel=parallel, error_model="numpy",
                           fastmath={"contract"}, inline="always" if inline else "never"))


# (dem[k], dem[k + 1]) of a float32 array as one 8-byte load, so that a vectorised loop
# gathers half as many elements: the one primitive the reference takes from the package
_two: Any = kernel._pair


class RefSetup(NamedTuple):
    coef: F64  # (lines, 30): column, row, height of ray (i, j) as quadratics in its range
    unit: F64  # (3, pixels): unit look vectors, camera frame


def reference_setup(dem: Dem, centre: F64, rot: F64, look: F64) -> RefSetup:
    """Per block of REF_BLOCK_LINES lines, a quadratic map from a local ENU frame to (DEM
    column, DEM row, ellipsoidal height), least squares on pyproj over a 5 x 5 x 3 grid of the
    block's swath box; per line, the column, row and height of each ray as a quadratic in its
    range s: x = ax + (ux·l)s + (lᵀQx l)s², etc."""
    to_geo = Transformer.from_crs(4978, 4979, always_xy=True)
    to_map = Transformer.from_crs(4326, dem.epsg, always_xy=True)
    from_map = Transformer.from_crs(dem.epsg, 4326, always_xy=True)
    to_ecef = Transformer.from_crs(4979, 4978, always_xy=True)
    unit = look / np.linalg.norm(look, axis=0)
    n = centre.shape[0]
    low, high = float(np.nanmin(dem.heights_m)) - 10.0, float(np.nanmax(dem.heights_m)) + 10.0
    lon, lat, hc = to_geo.transform(centre[:, 0], centre[:, 1], centre[:, 2])
    ec, nc = to_map.transform(lon, lat)
    reach = (float(np.max(hc)) - low) * float(np.max(np.hypot(unit[0], unit[1]) / -unit[2]))
    reach += 60.0
    g = np.linspace(-1.0, 1.0, 5)
    ge, gn, gh = (a.ravel() for a in np.meshgrid(g, g, np.linspace(0.0, 1.0, 3), indexing="ij"))
    iu = np.triu_indices(3)
    coef = np.empty((n, 30))
    for i0 in range(0, n, REF_BLOCK_LINES):
        sl = slice(i0, min(i0 + REF_BLOCK_LINES, n))
        w, e = float(ec[sl].min()) - reach, float(ec[sl].max()) + reach
        s, nn = float(nc[sl].min()) - reach, float(nc[sl].max()) + reach
        lon0, lat0 = from_map.transform(0.5 * (w + e), 0.5 * (s + nn))
        org = np.array(to_ecef.transform(lon0, lat0, 0.5 * (low + high)))
        sa, ca = np.sin(np.radians(lat0)), np.cos(np.radians(lat0))
        so, co = np.sin(np.radians(lon0)), np.cos(np.radians(lon0))
        enu = np.array([[-so, co, 0.0], [-sa * co, -sa * so, ca], [ca * co, ca * so, sa]])
        pe, pn = 0.5 * (w + e) + ge * 0.5 * (e - w), 0.5 * (s + nn) + gn * 0.5 * (nn - s)
        ph = low + gh * (high - low)
        x = np.stack(to_ecef.transform(*from_map.transform(pe, pn), ph), axis=-1)
        p = (x - org) @ enu.T
        pc, half = 0.5 * (p.min(0) + p.max(0)), 0.5 * (p.max(0) - p.min(0))
        q = (p - pc) / half
        mono = np.concatenate([np.ones((q.shape[0], 1)), q,
                               (q[:, :, None] * q[:, None, :])[:, iu[0], iu[1]]], axis=1)
        target = np.stack([(pe - dem.first_easting_m) / dem.cell_e_m,
                           (dem.first_northing_m - pn) / dem.cell_n_m, ph], axis=-1)
        c = np.linalg.lstsq(mono, target, rcond=None)[0]  # (10 monomials, 3 components)
        hq = np.zeros((3, 3, 3))  # [component, i, j]: Hessian in q
        for t, (a, b) in enumerate(zip(*iu, strict=True)):
            hq[:, a, b] += c[4 + t]
            hq[:, b, a] += c[4 + t]
        hp = hq / half[None, :, None] / half[None, None, :]  # Hessian in p
        qc = ((centre[sl] - org) @ enu.T - pc) / half  # the cameras, in q
        hqc = (qc @ hq.reshape(9, 3).T).reshape(-1, 3, 3)  # [line, component, i]
        val = c[0] + qc @ c[1:4] + 0.5 * np.einsum("lki,li->lk", hqc, qc)
        m = enu @ rot[sl]  # camera → local ENU
        u = ((c[1:4].T[None] + hqc) / half) @ m  # B = u·l
        qq = [0.5 * np.swapaxes(m, 1, 2) @ hp[k] @ m for k in range(3)]  # C = lᵀ qq l
        coef[sl, 0:3] = val
        for k in range(3):  # per component: u, then Q's upper triangle by rows, doubled off it
            q = qq[k]
            coef[sl, 3 + 9 * k:12 + 9 * k] = np.stack(
                [u[:, k, 0], u[:, k, 1], u[:, k, 2], q[:, 0, 0], 2 * q[:, 0, 1], 2 * q[:, 0, 2],
                 q[:, 1, 1], 2 * q[:, 1, 2], q[:, 2, 2]], axis=-1)
    return RefSetup(coef, np.ascontiguousarray(unit))


class RefScratch(NamedTuple):
    s: F64  # (work items, pixels): each ray's range on the previous line
    model: F32  # (work items, 15, pixels): float32 local models and limits
    origin: npt.NDArray[np.int64]  # (work items, pixels): the DEM cell of the local origin


def reference_scratch(lines: int, pixels: int) -> RefScratch:
    items = -(-lines // REF_BLOCK_LINES)
    return RefScratch(np.empty((items, pixels)), np.empty((items, 15, pixels), np.float32),
                      np.empty((items, pixels), np.int64))


def reference_kernel(dem: Dem, flat: F32, setup: RefSetup, scratch: RefScratch,
                     out: GroundPoints) -> None:
    _ref_kernel(flat, dem.cols, setup.coef, setup.unit, REF_BLOCK_LINES, dem.cell_e_m,
                dem.cell_n_m, dem.first_easting_m, dem.first_northing_m, out.easting_m,
                out.northing_m, out.height_m, scratch.s, scratch.model, scratch.origin)
    out.hit[:] = np.isfinite(out.height_m)


@_njit(parallel=True)
def _ref_kernel(z: Any, cols: int, coef: Any, look: Any, chunk: int, cell_e: float,
                cell_n: float, e0: float, n0: float, out_e: Any, out_n: Any, out_h: Any,
                s_all: Any, mod: Any, org: Any) -> None:
    """Work items of `chunk` lines in parallel; in each, lines in order, every ray starting from
    the same pixel's range on the previous line. Three passes over a line, each a loop over
    independent pixels (vectorised): float64 set-up of float32 models local to the cell under
    the start, two float32 Newton steps, float64 output. Scratch arrays are arguments, indexed
    directly: numba marks them noalias, which the vectoriser needs next to the gathers."""
    rows = z.size // cols
    p = look.shape[1]
    for c in numba.prange(-(-coef.shape[0] // chunk)):
        i0, i1 = c * chunk, min(coef.shape[0], c * chunk + chunk)
        bh = (coef[i0, 21] * look[0, p // 2] + coef[i0, 22] * look[1, p // 2]
              + coef[i0, 23] * look[2, p // 2])
        for j in range(p):  # cold start: where the middle ray meets the DEM's mean height
            s_all[c, j] = (coef[i0, 2] - 0.5 * (z[0] + z[-1])) / -bh
        for i in range(i0, i1):
            for _ in range(REF_COLD_PASSES if i == i0 else 1):
                _ref_setup_line(cols, rows, coef, look, i, c, s_all, mod, org)
                _ref_newton_line(z, cols, c, mod, org)
                _ref_output_line(coef, look, i, c, s_all, mod, cell_e, cell_n, e0, n0, out_e,
                                 out_n, out_h)


@_njit(inline=True)
def _ref_terms(coef: Any, look: Any, i: int, j: int) -> tuple[float, ...]:
    """(B, C) of x, y and h along ray (i, j): value = A + B·s + C·s²."""
    l0, l1, l2 = look[0, j], look[1, j], look[2, j]
    bx, cx = _ref_quadratic(coef, i, 3, l0, l1, l2)
    by, cy = _ref_quadratic(coef, i, 12, l0, l1, l2)
    bh, ch = _ref_quadratic(coef, i, 21, l0, l1, l2)
    return bx, by, bh, cx, cy, ch


@_njit(inline=True)
def _ref_quadratic(coef: Any, i: int, o: int, l0: float, l1: float, l2: float
                   ) -> tuple[float, float]:
    """B = u·l and C = lᵀQl from one component's nine terms (u, then Q by rows)."""
    b = coef[i, o] * l0 + coef[i, o + 1] * l1 + coef[i, o + 2] * l2
    c = (l0 * (coef[i, o + 3] * l0 + coef[i, o + 4] * l1 + coef[i, o + 5] * l2)
         + l1 * (coef[i, o + 6] * l1 + coef[i, o + 7] * l2) + coef[i, o + 8] * l2 * l2)
    return b, c


@_njit(inline=True)
def _ref_setup_line(cols: int, rows: int, coef: Any, look: Any, i: int, c: int, s_all: Any,
                    mod: Any, org: Any) -> None:
    f32 = np.float32
    ax, ay, ah = coef[i, 0], coef[i, 1], coef[i, 2]
    for j in range(look.shape[1]):
        bx, by, bh, cx, cy, ch = _ref_terms(coef, look, i, j)
        s0 = s_all[c, j]
        x64 = ax + s0 * (bx + s0 * cx)
        y64 = ay + s0 * (by + s0 * cy)
        ox = min(max(np.floor(x64), 0.0), cols - 2.0)  # the ray's float32 local origin
        oy = min(max(np.floor(y64), 0.0), rows - 2.0)
        org[c, j] = np.int64(oy) * cols + np.int64(ox)
        mod[c, 0, j] = f32(x64 - ox)
        mod[c, 1, j] = f32(bx + 2.0 * cx * s0)
        mod[c, 2, j] = f32(cx)
        mod[c, 3, j] = f32(y64 - oy)
        mod[c, 4, j] = f32(by + 2.0 * cy * s0)
        mod[c, 5, j] = f32(cy)
        h64 = ah + s0 * (bh + s0 * ch)
        href = f32(h64)  # heights relative to this (exact in float32, as are the DEM's)
        mod[c, 6, j] = f32(h64 - np.float64(href))
        mod[c, 14, j] = href
        mod[c, 7, j] = f32(bh + 2.0 * ch * s0)
        mod[c, 8, j] = f32(ch)
        mod[c, 10, j] = f32(-ox)
        mod[c, 11, j] = f32(cols - 2.0 - ox)
        mod[c, 12, j] = f32(-oy)
        mod[c, 13, j] = f32(rows - 2.0 - oy)


@_njit(inline=True)
def _ref_newton_line(z: Any, cols: int, c: int, mod: Any, org: Any) -> None:
    """Two Newton steps for every ray of a line, one pass per step: within a pass every
    iteration is independent of the others (short dependency chains, each ray's gathers
    waiting only on its own arithmetic)."""
    for step in range(2):
        for j in range(mod.shape[2]):
            m = (mod[c, 0, j], mod[c, 1, j], mod[c, 2, j], mod[c, 3, j], mod[c, 4, j],
                 mod[c, 5, j], mod[c, 6, j], mod[c, 7, j], mod[c, 8, j], mod[c, 10, j],
                 mod[c, 11, j], mod[c, 12, j], mod[c, 13, j], mod[c, 14, j])
            t = mod[c, 9, j] if step == 1 else np.float32(0.0)
            mod[c, 9, j] = _ref_step(t, z, cols, org[c, j], m)


@_njit(inline=True)
def _ref_step(t: Any, z: Any, cols: int, k0: int, m: Any) -> Any:
    """One Newton step on gap = h − DEM along the ray, on the bilinear patch of the cell under
    the point at offset t (clamped into the DEM), branch-free."""
    x, xd, xdd, y, yd, ydd, h, hd, hdd, lx0, lx1, ly0, ly1, href = m
    u = x + t * (xd + t * xdd)
    v = y + t * (yd + t * ydd)
    cu = np.floor(u)
    cv = np.floor(v)
    cu = cu if cu >= lx0 else lx0  # selects: min/max do not vectorise
    cu = cu if cu <= lx1 else lx1
    cv = cv if cv >= ly0 else ly0
    cv = cv if cv <= ly1 else ly1
    k = k0 + np.int64(cv) * cols + np.int64(cu)
    z00, z01 = _two(z, k)
    z10, z11 = _two(z, k + cols)
    z00, z01, z10, z11 = z00 - href, z01 - href, z10 - href, z11 - href  # exact: all near href
    fu, fv = u - cu, v - cv
    twist = z11 - z10 - z01 + z00
    dzx = z01 - z00 + fv * twist
    dzy = z10 - z00 + fu * twist
    gap = h + t * (hd + t * hdd) - (z00 + fu * (z01 - z00) + fv * dzy)
    rate = hd + (t + t) * hdd - dzx * (xd + (t + t) * xdd) - dzy * (yd + (t + t) * ydd)
    return t - gap / rate


@_njit(inline=True)
def _ref_output_line(coef: Any, look: Any, i: int, c: int, s_all: Any, mod: Any,
                     cell_e: float, cell_n: float, e0: float, n0: float, out_e: Any,
                     out_n: Any, out_h: Any) -> None:
    ax, ay, ah = coef[i, 0], coef[i, 1], coef[i, 2]
    for j in range(look.shape[1]):
        bx, by, bh, cx, cy, ch = _ref_terms(coef, look, i, j)
        s1 = s_all[c, j] + np.float64(mod[c, 9, j])
        s_all[c, j] = s1
        out_e[i, j] = e0 + (ax + s1 * (bx + s1 * cx)) * cell_e
        out_n[i, j] = n0 - (ay + s1 * (by + s1 * cy)) * cell_n
        out_h[i, j] = ah + s1 * (bh + s1 * ch)


# ---------------------------------------------------------------------------------------------
# Timing, stage split, accuracy
# ---------------------------------------------------------------------------------------------


class Timed(NamedTuple):
    wall_s: float
    cpu_s: float  # summed over threads


def timed(fn: Callable[[], object]) -> Timed:
    t0, c0 = time.perf_counter(), time.process_time()
    fn()
    return Timed(time.perf_counter() - t0, time.process_time() - c0)


def stage_split(dem: Dem, centre: F64, rot: F64, look: F64, out: GroundPoints
                ) -> dict[str, Timed]:
    """`intersect`'s body stage by stage (as in postproc/georef/raycast/cast.py), each timed;
    the map fits (pyproj and least squares) and the footprints that size their boxes are timed
    inside the block maps."""
    inner: dict[str, list[Timed]] = {"  of which map fits (pyproj)": [],
                                     "  of which footprints": []}

    def timing(name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        def wrapped(*a: Any) -> Any:
            t0, c0 = time.perf_counter(), time.process_time()
            got = fn(*a)
            inner[name].append(Timed(time.perf_counter() - t0, time.process_time() - c0))
            return got
        return wrapped

    fit, foot = getattr(blocks, "fit_maps"), getattr(blocks, "_footprints")  # noqa: B009
    setattr(blocks, "fit_maps", timing("  of which map fits (pyproj)", fit))  # noqa: B010
    setattr(blocks, "_footprints", timing("  of which footprints", foot))  # noqa: B010
    try:
        return _stages(dem, centre, rot, look, out) | {
            k: Timed(sum(t.wall_s for t in v), sum(t.cpu_s for t in v))
            for k, v in inner.items()}
    finally:
        setattr(blocks, "fit_maps", fit)  # noqa: B010
        setattr(blocks, "_footprints", foot)  # noqa: B010


def _stages(dem: Dem, centre: F64, rot: F64, look: F64, out: GroundPoints) -> dict[str, Timed]:
    got: dict[str, Any] = {}
    n, p = centre.shape[0], look.shape[1]

    def run(name: str, fn: Callable[[], Any]) -> None:
        t0, c0 = time.perf_counter(), time.process_time()
        got[name] = fn()
        times[name] = Timed(time.perf_counter() - t0, time.process_time() - c0)

    times: dict[str, Timed] = {}
    run("checks", lambda: rays.checked_rays(centre, rot, look))
    c, r, lk, _ = got["checks"]
    surf = surface.surface_of(dem)
    unit = lk / np.linalg.norm(lk, axis=0)
    run("block maps", lambda: blocks.fit_block_maps(surf, c, r, unit))
    maps = got["block maps"]
    run("per-line coefficients", lambda: tables.line_coefficients(maps, c, r))
    run("kernel tables, scratch", lambda: (tables.kernel_tables(surf, maps),
                                           kernel.scratch(p), tables.look_products(unit)))
    (blk, consts), sc, look9 = got["kernel tables, scratch"]
    flag, counts = np.zeros(n, np.uint8), np.zeros((maps.starts.size - 1, 4), np.int64)
    coef, hit = got["per-line coefficients"], out.hit.view(np.uint8)
    if fastpath.usable(surf.flat.size):  # as cast.py: the C kernel, then the safe path
        safe = np.zeros(n, np.uint8)
        run("cast kernel (C, AVX2)", lambda: fastpath.cast_fast(
            surf.flat, surf.rows, surf.cols, surf.slope_table, surf.log2, coef, look9,
            maps.starts, blk, consts, out.easting_m, out.northing_m, out.height_m, hit, safe,
            counts))
        if safe.any():
            run("safe path (numba)", lambda: kernel.safe_pass(
                surf.flat, surf.cols, coef, look9, maps.starts, blk, consts, out.easting_m,
                out.northing_m, out.height_m, hit, safe, flag, counts))
    else:
        run("cast kernel (numba)", lambda: kernel.cast_blocks(
            surf.flat, surf.flat, surf.cols, surf.slope_table, surf.log2, coef, look9,
            maps.starts, blk, consts, out.easting_m, out.northing_m, out.height_m, hit, flag,
            counts, *sc))
    run("reference method (rays off the maps)",
        lambda: reference.resolve_exact(dem, out, flag, c, r, unit))
    return times


def one_thread_kernels(dem: Dem, centre: F64, rot: F64, look: F64, repeats: int) -> None:
    """The cast kernel alone on one thread, C and numba's alternating (the set-up once): ns of
    CPU a ray (the thread's own CPU time), medians and ranges."""
    surf = surface.surface_of(dem)
    unit = look / np.linalg.norm(look, axis=0)
    maps = blocks.fit_block_maps(surf, centre, rot, unit)
    coef = tables.line_coefficients(maps, centre, rot)
    blk, consts = tables.kernel_tables(surf, maps)
    look9 = tables.look_products(unit)
    n, p = centre.shape[0], look.shape[1]
    out = GroundPoints.empty(n, p)
    hit = out.hit.view(np.uint8)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    sc = kernel.scratch(p)

    def c_kernel() -> None:
        fastpath.cast_fast(surf.flat, surf.rows, surf.cols, surf.slope_table, surf.log2, coef,
                           look9, maps.starts, blk, consts, out.easting_m, out.northing_m,
                           out.height_m, hit, np.zeros(n, np.uint8),
                           np.zeros((maps.starts.size - 1, 4), np.int64))

    def numba_kernel() -> None:
        kernel.cast_blocks(surf.flat, surf.flat, surf.cols, surf.slope_table, surf.log2, coef,
                           look9, maps.starts, blk, consts, out.easting_m, out.northing_m,
                           out.height_m, hit, np.zeros(n, np.uint8),
                           np.zeros((maps.starts.size - 1, 4), np.int64), *sc)

    kernels = {"C": c_kernel, "numba": numba_kernel} if fastpath.LIB is not None else {
        "numba": numba_kernel}
    ns: dict[str, list[float]] = {name: [] for name in kernels}
    try:
        for fn in kernels.values():
            fn()
        for k in range(repeats):
            for name, fn in (list(kernels.items())[::1 if k % 2 == 0 else -1]):
                c0 = time.thread_time()
                fn()
                ns[name].append((time.thread_time() - c0) / (n * p) * 1e9)
    finally:
        numba.set_num_threads(threads)
    print(f"cast kernel alone, one thread, {repeats} runs alternating (load "
          f"{os.getloadavg()[0]:.1f}): " + "; ".join(
              f"{name} {np.median(v):.2f} ns of CPU a ray ({min(v):.2f}–{max(v):.2f})"
              for name, v in ns.items()))


def check_lines(dem: Dem, out: GroundPoints, count: int) -> npt.NDArray[np.intp]:
    """`count` random lines, plus the line whose ground points lie on the steepest DEM cells
    (every pixel of a line is checked: both strip edges)."""
    lines = out.hit.shape[0]
    picked = set(np.random.default_rng(3).choice(lines, count, replace=False).tolist())
    slope = surface.cell_slopes(dem)
    x = np.clip((out.easting_m - dem.first_easting_m) / dem.cell_e_m, 0, dem.cols - 2)
    y = np.clip((dem.first_northing_m - out.northing_m) / dem.cell_n_m, 0, dem.rows - 2)
    ok = np.isfinite(x) & np.isfinite(y)
    under = np.where(ok, slope[np.nan_to_num(y).astype(np.intp),
                               np.nan_to_num(x).astype(np.intp)], 0.0)
    picked.add(int(np.argmax(under.max(axis=1))))
    picked.add(int(np.argmax(np.percentile(under, 90, axis=1))))
    return np.array(sorted(picked), dtype=np.intp)


def accuracy(dem: Dem, centre: F64, rot: F64, look: F64, lines: npt.NDArray[np.intp],
             outputs: dict[str, GroundPoints]) -> None:
    t0 = time.perf_counter()
    ref = reference_intersect(dem, centre[lines], rot[lines], look)
    t_ref = time.perf_counter() - t0
    print(f"accuracy on lines {lines.tolist()} (all {look.shape[1]} pixels; random lines and "
          f"the two over the steepest terrain), against reference_intersect (float64, pyproj at "
          f"every point, bisection; {lines.size * look.shape[1] / t_ref / 1e3:.1f} k rays/s):")
    sub = np.arange(lines.size)
    for name, out in outputs.items():
        view = GroundPoints(out.easting_m[lines], out.northing_m[lines], out.height_m[lines],
                            out.hit[lines])
        r_max, r_rms, d_max, d_rms, n = errors_m(dem, centre[lines], view, ref, sub)
        print(f"  {name:17s} ({n} rays, hits agree {bool((view.hit == ref.hit).all())}): "
              f"3-D max {d_max * 1e3:.4f} mm, RMS {d_rms * 1e3:.4f} mm; range max "
              f"{r_max * 1e3:.4f} mm, RMS {r_rms * 1e3:.4f} mm")


def print_stages(dem: Dem, centre: F64, rot: F64, look: F64, out: GroundPoints,
                 repeats: int) -> None:
    runs = [stage_split(dem, centre, rot, look, out) for _ in range(repeats)]
    total = [sum(t.wall_s for k, t in r.items() if not k.startswith(" ")) for r in runs]
    print(f"stage split of intersect (medians of {repeats}, wall / CPU ms; load "
          f"{os.getloadavg()[0]:.1f}); stages together {np.median(total) * 1e3:.0f} ms wall:")
    for name in runs[0]:
        wall = float(np.median([r[name].wall_s for r in runs]))
        cpu = float(np.median([r[name].cpu_s for r in runs]))
        print(f"  {name:40s} {wall * 1e3:7.1f} / {cpu * 1e3:7.1f}   "
              f"{100.0 * wall / float(np.median(total)):5.1f} %")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lines", type=int, default=20_000)
    ap.add_argument("--pairs", type=int, default=6)
    ap.add_argument("--check-lines", type=int, default=4)
    ap.add_argument("--profile", type=int, default=0, metavar="N",
                    help="also time intersect's stages separately, N times")
    ap.add_argument("--one-thread", type=int, default=0, metavar="N",
                    help="also time the cast kernel alone on one thread, C and numba's "
                         "alternating, N times each")
    ap.add_argument("--numba", action="store_true",
                    help="also time intersect on numba's kernel (the fallback for CPUs without "
                         "AVX2/FMA) in every pair")
    args = ap.parse_args()
    length = SPEED_MPS * LINE_PERIOD_S * args.lines + 600.0
    t0 = time.perf_counter()
    dem = synthetic_dem(length, 1800.0)
    centre, rot, look = casi_strip(dem, args.lines)
    n, p = args.lines, look.shape[1]
    rays_m = n * p / 1e6
    slope = surface.cell_slopes(dem)
    print(f"scene: {n} lines x {p} px = {rays_m:.2f} M rays, DEM {dem.rows} x {dem.cols} cells "
          f"of {CELL_M} m, relief {np.ptp(dem.heights_m):.0f} m, max slope "
          f"{np.degrees(np.arctan(slope.max())):.0f}° (built in {time.perf_counter() - t0:.1f} s)"
          f"; {os.cpu_count()} cores, numba threads {numba.get_num_threads()}")

    names = ["intersect", "reference kernel", "numpy baseline"] + (
        ["intersect (numba)"] if args.numba else [])
    outs = {name: GroundPoints.empty(n, p) for name in names}
    print(f"intersect's kernel: {'C (AVX2, FMA)' if fastpath.LIB is not None else 'numba'}")
    flat = np.ascontiguousarray(dem.heights_m, dtype=np.float32).ravel()
    scratch = reference_scratch(n, p)
    stats = CastStats()
    setup: list[RefSetup] = []

    def fast() -> None:
        intersect(dem, centre, rot, look, out=outs["intersect"], stats=stats)

    def fast_numba() -> None:
        lib = fastpath.LIB
        fastpath.LIB = None
        try:
            intersect(dem, centre, rot, look, out=outs["intersect (numba)"])
        finally:
            fastpath.LIB = lib

    def ref_setup() -> None:
        setup[:] = [reference_setup(dem, centre, rot, look)]

    def ref_kernel() -> None:
        reference_kernel(dem, flat, setup[0], scratch, outs["reference kernel"])

    for warm in (fast, ref_setup, ref_kernel) + ((fast_numba,) if args.numba else ()):  # caches
        warm()
    print(f"{args.pairs} pairs, alternating which goes first; M rays/s wall (per CPU-second); "
          "the reference's whole call is its set-up (maps, per-line terms) plus its kernel")
    ratios, ratios_k = [], []
    fast_t: list[Timed] = []
    ref_t: list[Timed] = []
    numba_t: list[Timed] = []
    for k in range(args.pairs):
        load = os.getloadavg()[0]
        if k % 2 == 0:
            tf, ts, tk = timed(fast), timed(ref_setup), timed(ref_kernel)
        else:
            ts, tk, tf = timed(ref_setup), timed(ref_kernel), timed(fast)
        if args.numba:
            numba_t.append(timed(fast_numba))
        tr = Timed(ts.wall_s + tk.wall_s, ts.cpu_s + tk.cpu_s)
        fast_t.append(tf)
        ref_t.append(tr)
        ratios.append(tf.wall_s / tr.wall_s)
        ratios_k.append(tf.wall_s / tk.wall_s)
        print(f"  pair {k + 1}, load {load:4.1f}: intersect {rays_m / tf.wall_s:6.1f} "
              f"({rays_m / tf.cpu_s:5.1f}); reference {rays_m / tr.wall_s:6.1f} "
              f"({rays_m / tr.cpu_s:5.1f}), its kernel alone {rays_m / tk.wall_s:6.1f} "
              f"({rays_m / tk.cpu_s:5.1f}); time ratio intersect / reference "
              f"{ratios[-1]:.2f} (/ its kernel {ratios_k[-1]:.2f})"
              + (f"; on numba's kernel {rays_m / numba_t[-1].wall_s:6.1f} "
                 f"({rays_m / numba_t[-1].cpu_s:5.1f})" if args.numba else ""))
    print(f"intersect:        {rays_m / max(t.wall_s for t in fast_t):.1f}–"
          f"{rays_m / min(t.wall_s for t in fast_t):.1f} M rays/s, per CPU-second "
          f"{rays_m / np.median([t.cpu_s for t in fast_t]):.1f} M (median)")
    if args.numba:
        print(f"on numba's kernel: {rays_m / max(t.wall_s for t in numba_t):.1f}–"
              f"{rays_m / min(t.wall_s for t in numba_t):.1f} M rays/s, per CPU-second "
              f"{rays_m / np.median([t.cpu_s for t in numba_t]):.1f} M (median)")
    print(f"reference kernel: {rays_m / max(t.wall_s for t in ref_t):.1f}–"
          f"{rays_m / min(t.wall_s for t in ref_t):.1f} M rays/s, per CPU-second "
          f"{rays_m / np.median([t.cpu_s for t in ref_t]):.1f} M (median), whole call")
    print(f"time ratio intersect / reference: {min(ratios):.2f}–{max(ratios):.2f} (median "
          f"{np.median(ratios):.2f}); against the reference's kernel alone {min(ratios_k):.2f}–"
          f"{max(ratios_k):.2f}; load average now {os.getloadavg()[0]:.1f}")
    print(f"  intersect's rays: {stats.fast} fast, {stats.safe_hit} + {stats.safe_miss} safe "
          f"path (hit + miss), {stats.exact} reference; {stats.blocks} blocks, map error "
          f"{stats.map_error_m * 1e6:.2f} µm")
    tb = timed(lambda: numpy_baseline(dem, centre, rot, look, outs["numpy baseline"]))
    t_fast = float(np.median([t.wall_s for t in fast_t]))
    print(f"numpy baseline (8 fixed-point iterations): {rays_m / tb.wall_s:.1f} M rays/s "
          f"({rays_m / tb.cpu_s:.1f} per CPU-second), x{tb.wall_s / t_fast:.0f} intersect's "
          "median time")
    if args.profile:
        print_stages(dem, centre, rot, look, GroundPoints.empty(n, p), args.profile)
    if args.one_thread:
        one_thread_kernels(dem, centre, rot, look, args.one_thread)
    accuracy(dem, centre, rot, look, check_lines(dem, outs["intersect"], args.check_lines),
             outs)


if __name__ == "__main__":
    main()
