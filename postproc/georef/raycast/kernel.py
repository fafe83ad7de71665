"""Every compiled loop of the ray caster (numba): the set-up kernels (poses, per-line
coefficients, the footprints that size the blocks' maps) and the cast itself: the fast path
(Newton steps from the previous line's range), the first-root certification, and the safe path
(a cell-by-cell walk) for every ray the fast path could not certify. The method is in the
package's docstring. Where the CPU has AVX2 and FMA the fast path and certification run in C
instead (`_castkernel.c`, through fastpath.py, reading the constants here), and `safe_pass`
takes the rays it leaves; `cast_blocks` is the fast path everywhere else.

All of it stays in this one file, with every constant it reads: numba's on-disk cache is
invalidated only by a change to the file that defines the cached function, not by a change to
a function, intrinsic, constant or decorator option it takes from another file (it would go on
running the old compiled code). Python code elsewhere in the package reads the constants here.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from typing import Any, Final, TypeVar, cast

import numba
import numpy as np
import numpy.typing as npt
from llvmlite import ir  # type: ignore[import-untyped]
from numba.core import cgutils as _cgutils
from numba.core import types as _types
from numba.extending import intrinsic

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
U8 = npt.NDArray[np.uint8]
_Fn = TypeVar("_Fn", bound=Callable[..., Any])

GROUP_LINES: Final = 16  # lines certified together (first-root test) before the next group
CHUNK_PIXELS: Final = 64  # pixels whose paths share one slope bound
TILE_CELLS: Final = 8  # DEM cells per side of the tiles holding slope maxima
COLD_PASSES: Final = 4  # rounds of Newton steps for a block's first line (cold start)
PREFETCH_LINES: Final = 2  # DEM cells are prefetched for the line this far ahead...
PREFETCH_STRIDE: Final = 4  # ...under every this many pixels
ROOT_TOLERANCE_M: Final = 1e-6  # error bound of the last Newton step
MAX_NEWTON_STEP_M: Final = 0.01  # a larger final step is not trusted
SLOPE_MARGIN: Final = 0.98  # first-root test: slope × rate must stay below this
SAFE_SEGMENT_M: Final = 4.0  # longest stretch of ray solved as one quadratic in the safe path

_LITTLE_ENDIAN: Final = sys.byteorder == "little"
cgutils: Any = _cgutils  # untyped: for the intrinsics' code generation
types: Any = _types

# Per-ray outcome codes of the kernel.
_HIT: Final = 0
_MISS: Final = 1
_EXACT: Final = 2  # outside the fitted map: solved by the reference method


def _jit(parallel: bool = False, inline: bool = False) -> Callable[[_Fn], _Fn]:
    """numba.njit, cached on disk, IEEE division (needed to vectorise). Of fastmath only
    `contract`: a product and a sum may become one fused multiply-add (one rounding instead
    of two; the cast kernel took ~8 % less CPU, docs/benchmarks.md); the rest of fastmath
    stays off (NaN tests must hold; nothing reassociated, no approximate division)."""
    return cast(Callable[[_Fn], _Fn],
                numba.njit(cache=True, parallel=parallel, error_model="numpy",
                           fastmath={"contract"}, inline="always" if inline else "never"))


# ---------------------------------------------------------------------------------------------
# Set-up kernels: poses, per-line coefficients, footprints
# ---------------------------------------------------------------------------------------------


@_jit()
def pose_check(centre: Any, rot: Any, posed: Any) -> float:
    """One pass over the poses: posed[i] = 1 where centre and rotation are finite (a line
    without a pose, NaN, gives NaN ground points); returns the largest |RᵀR − I| of the posed
    lines (0 if none)."""
    worst = 0.0
    for i in range(centre.shape[0]):
        fin = True
        for a in range(3):
            fin = fin and math.isfinite(centre[i, a])
            for c in range(3):
                fin = fin and math.isfinite(rot[i, a, c])
        posed[i] = 1 if fin else 0
        if fin:
            for a in range(3):
                for c in range(3):
                    d = (rot[i, 0, a] * rot[i, 0, c] + rot[i, 1, a] * rot[i, 1, c]
                         + rot[i, 2, a] * rot[i, 2, c]) - (1.0 if a == c else 0.0)
                    worst = max(worst, abs(d))
    return worst


@_jit(parallel=True)
def coefficients_kernel(blk: Any, origin: Any, rb: Any, a: Any, g: Any, hess: Any,
                        centre: Any, rot: Any, out: Any) -> None:
    """Lines in parallel chunks (see `_coefficients_chunk`)."""
    n = centre.shape[0]
    chunks = -(-n // 512)
    for k in numba.prange(chunks):
        _coefficients_chunk(k * 512, min(n, k * 512 + 512), blk, origin, rb, a, g, hess,
                            centre, rot, out)


@_jit()
def _coefficients_chunk(i0: int, i1: int, blk: Any, origin: Any, rb: Any, a: Any, g: Any,
                        hess: Any, centre: Any, rot: Any, out: Any) -> None:
    """cp = R_b(c − O_b), M = R_b·R; A = a + g·cp + ½cpᵀH·cp, u = Mᵀ(g + H·cp), ½MᵀHM."""
    cp = np.empty(3)
    m = np.empty((3, 3))
    w = np.empty(3)
    for i in range(i0, i1):
        b = blk[i]
        cp[:] = 0.0
        m[:] = 0.0
        for r in range(3):
            for c in range(3):
                cp[r] += rb[b, r, c] * (centre[i, c] - origin[b, c])
                for v in range(3):
                    m[r, c] += rb[b, r, v] * rot[i, v, c]
        for k in range(3):
            acc = a[b, k]
            for r in range(3):
                hc = 0.0
                for c in range(3):
                    hc += hess[b, k, r, c] * cp[c]
                w[r] = g[b, k, r] + hc
                acc += (g[b, k, r] + 0.5 * hc) * cp[r]
            out[i, k] = acc
            for c in range(3):
                out[i, 3 + 3 * k + c] = m[0, c] * w[0] + m[1, c] * w[1] + m[2, c] * w[2]
            for t in range(6):
                x = 0 if t in (0, 3, 4) else (1 if t in (1, 5) else 2)
                y = 0 if t == 0 else (1 if t in (1, 3) else 2)
                q = 0.0
                for r in range(3):
                    for c in range(3):
                        q += m[r, x] * hess[b, k, r, c] * m[c, y]
                out[i, 12 + 6 * k + t] = 0.5 * q


@_jit(parallel=True)
def footprint_kernel(coef: Any, look9: Any, levels: Any, en0: Any, hull: Any, out: Any
                     ) -> None:
    for i in numba.prange(coef.shape[0]):
        for k in range(levels.size):
            w, s, e, n = np.inf, np.inf, -np.inf, -np.inf
            for j in range(look9.shape[1]):
                be, ce, bn, cn, bh, ch = _terms(coef, look9, i, j)
                r = _first_at_or_below(coef[i, 2], bh, ch, levels[k], 0.0)
                if r == r:
                    x = en0[0] + coef[i, 0] + r * (be + r * ce)
                    y = en0[1] + coef[i, 1] + r * (bn + r * cn)
                    w, e = min(w, x), max(e, x)
                    s, n = min(s, y), max(n, y)
            if w > e:
                w = e = en0[0] + coef[i, 0]
                s = n = en0[1] + coef[i, 1]
            out[i, k, 0] = min(max(w, hull[0]), hull[2])
            out[i, k, 1] = min(max(s, hull[1]), hull[3])
            out[i, k, 2] = min(max(e, hull[0]), hull[2])
            out[i, k, 3] = min(max(n, hull[1]), hull[3])


# ---------------------------------------------------------------------------------------------
# A ray's terms, and where a quadratic first comes down to a level
# ---------------------------------------------------------------------------------------------


@_jit(inline=True)
def _terms(coef: Any, look9: Any, i: int, j: int) -> tuple[float, float, float, float, float,
                                                          float]:
    """(B_E, C_E, B_N, C_N, B_h, C_h) of ray (i, j): E = A_E + B_E·s + C_E·s², etc."""
    l0, l1, l2 = look9[0, j], look9[1, j], look9[2, j]
    m0, m1, m2, m3, m4, m5 = (look9[3, j], look9[4, j], look9[5, j], look9[6, j], look9[7, j],
                              look9[8, j])
    be = coef[i, 3] * l0 + coef[i, 4] * l1 + coef[i, 5] * l2
    bn = coef[i, 6] * l0 + coef[i, 7] * l1 + coef[i, 8] * l2
    bh = coef[i, 9] * l0 + coef[i, 10] * l1 + coef[i, 11] * l2
    ce = (coef[i, 12] * m0 + coef[i, 13] * m1 + coef[i, 14] * m2 + coef[i, 15] * m3
          + coef[i, 16] * m4 + coef[i, 17] * m5)
    cn = (coef[i, 18] * m0 + coef[i, 19] * m1 + coef[i, 20] * m2 + coef[i, 21] * m3
          + coef[i, 22] * m4 + coef[i, 23] * m5)
    ch = (coef[i, 24] * m0 + coef[i, 25] * m1 + coef[i, 26] * m2 + coef[i, 27] * m3
          + coef[i, 28] * m4 + coef[i, 29] * m5)
    return be, ce, bn, cn, bh, ch


@_jit()
def _first_at_or_below(a: float, b: float, c: float, level: float, after: float) -> float:
    """Smallest s ≥ after with a + b·s + c·s² ≤ level; NaN if none."""
    k = a - level
    if k + after * (b + after * c) <= 0.0:
        return after
    if c == 0.0:
        return -k / b if b < 0.0 else np.nan
    disc = b * b - 4.0 * c * k
    if disc < 0.0:
        return np.nan
    q = -0.5 * (b + math.copysign(math.sqrt(disc), b))
    r1, r2 = q / c, k / q if q != 0.0 else np.nan
    lo, hi = min(r1, r2), max(r1, r2)
    if lo >= after:
        return lo
    if c < 0.0 and hi >= after:
        return hi
    return np.nan


# ---------------------------------------------------------------------------------------------
# Two intrinsics: a float32 pair in one load, a prefetch
# ---------------------------------------------------------------------------------------------


def _pair_intrinsic(typingctx: Any, heights: Any, k: Any) -> Any:
    """(heights[k], heights[k + 1]) of a float32 array by ONE 8-byte load. Vectorised, that is a
    gather of 8-byte elements: half the gathered elements of two 4-byte loads (the gathers and
    their cache misses are most of the Newton steps' time). The caller keeps k + 1 inside the
    array."""
    if not (isinstance(heights, types.Array) and heights.dtype == types.float32
            and heights.ndim == 1 and heights.layout == "C"):
        return None
    sig = types.UniTuple(types.float32, 2)(heights, types.intp)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        ary = context.make_array(signature.args[0])(context, builder, value=args[0])
        ptr = cgutils.gep(builder, ary.data, args[1], inbounds=True)
        word = builder.load(builder.bitcast(ptr, ir.IntType(64).as_pointer()), align=4)
        lo = builder.bitcast(builder.trunc(word, ir.IntType(32)), ir.FloatType())
        hi = builder.bitcast(builder.trunc(builder.lshr(word, ir.Constant(ir.IntType(64), 32)),
                                           ir.IntType(32)), ir.FloatType())
        first, second = (lo, hi) if _LITTLE_ENDIAN else (hi, lo)
        return context.make_tuple(builder, signature.return_type, [first, second])

    return sig, codegen


_pair: Any = intrinsic(_pair_intrinsic)


def _prefetch_intrinsic(typingctx: Any, heights: Any, k: Any) -> Any:
    """Hint that heights[k] will be read soon (no fault, no effect on results)."""
    if not (isinstance(heights, types.Array) and heights.ndim == 1 and heights.layout == "C"):
        return None
    sig = types.void(heights, types.intp)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        ary = context.make_array(signature.args[0])(context, builder, value=args[0])
        ptr = builder.bitcast(cgutils.gep(builder, ary.data, args[1]), ir.IntType(8).as_pointer())
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(ir.VoidType(), [ptr.type, i32, i32, i32]),
            "llvm.prefetch.p0")
        builder.call(fn, [ptr, i32(0), i32(3), i32(1)])  # read, keep in all levels, data
        return context.get_dummy_value()

    return sig, codegen


_prefetch: Any = intrinsic(_prefetch_intrinsic)


# ---------------------------------------------------------------------------------------------
# The fast path
# ---------------------------------------------------------------------------------------------


@_jit(inline=True)
def _models(s: float, coef: Any, look9: Any, i: int, j: int, blk: Any, b: int, consts: Any
            ) -> tuple[Any, ...]:
    """Float64 set-up of ray (i, j) from start range s: in t = s − start, float32 quadratic
    models of x, y (grid cells from the block's grid origin) and h (relative to z_ref, the
    start's ellipsoidal height rounded to float32): x, x', x''/2, y, y', y''/2, h, h', h''/2,
    z_ref. Rounding them to float32 moves the point by < 0.1 mm (|x| < ~1000 cells); heights
    relative to z_ref, itself a float32 like the DEM's samples, lose nothing in the
    differences of the Newton steps (relative to the block's height, 500 m away on an alpine
    DEM, they lost up to 3e-5 m each: 0.11 mm on slopes of 50°)."""
    fx, fy = blk[b, 0], blk[b, 1]
    inv_e, inv_n = consts[0], consts[1]
    ae, an, ah = coef[i, 0], coef[i, 1], coef[i, 2]
    be, ce, bn, cn, bh, ch = _terms(coef, look9, i, j)
    f32 = np.float32
    h = blk[b, 10] + ah + s * (bh + s * ch)
    z_ref = f32(h)
    return (f32((ae + s * (be + s * ce)) * inv_e + fx), f32((be + 2.0 * ce * s) * inv_e),
            f32(ce * inv_e), f32(fy - (an + s * (bn + s * cn)) * inv_n),
            f32(-(bn + 2.0 * cn * s) * inv_n), f32(-cn * inv_n), f32(h - np.float64(z_ref)),
            f32(bh + 2.0 * ch * s), f32(ch), z_ref)


@_jit(inline=True)
def _start_line(i: int, tid: int, coef: Any, look9: Any, s64: Any, cold: int, blk: Any, b: int,
                consts: Any, lin: Any) -> None:
    """Float64 set-up of line i: the start range s64[tid, 1] (the previous line's s64[tid, 0],
    or where the middle ray reaches the block's reference height) and the float32 models
    lin[tid, 0:9] and lin[tid, 10] of `_models`."""
    p = look9.shape[1]
    _, _, _, _, bh_mid, _ = _terms(coef, look9, i, p // 2)
    guess = -coef[i, 2] / bh_mid  # where the middle ray reaches the block's reference height
    for j in range(p):
        s = s64[tid, 0, j]
        s = s if (s == s and cold == 0) else guess
        s64[tid, 1, j] = s
        m0, m1, m2, m3, m4, m5, m6, m7, m8, zr = _models(s, coef, look9, i, j, blk, b, consts)
        lin[tid, 0, j] = m0
        lin[tid, 1, j] = m1
        lin[tid, 2, j] = m2
        lin[tid, 3, j] = m3
        lin[tid, 4, j] = m4
        lin[tid, 5, j] = m5
        lin[tid, 6, j] = m6
        lin[tid, 7, j] = m7
        lin[tid, 8, j] = m8
        lin[tid, 10, j] = zr


@_jit(inline=True)
def _newton(m: Any, dem: Any, cols: int, rows: int, blk: Any, b: int, consts: Any
            ) -> tuple[Any, ...]:
    """Two branch-free float32 Newton steps on g = h − DEM(x, y) along the models m, both on
    the bilinear patch of the cell under the start (its four corners are two 8-byte loads;
    the cell is clamped into the DEM, so a NaN lands on a valid cell and the test rejects it),
    then the acceptance test.

    Accepted: the last step < MAX_NEWTON_STEP_M and ends inside that cell, where the gap is a
    quadratic in t, so the remaining error is |g''|·step²/(2|g'|) < ROOT_TOLERANCE_M; the ray
    descends and crosses the surface downwards; its path back up to the highest DEM sample
    lies in the block's box. (A root certified inside the start cell on its own patch is a
    root of the DEM whichever cell the first step passed through.)

    Returns (start cell's index, t, redo, ok, squared horizontal/vertical rate, tile range x0,
    x1, y0, y1 of the path back up). redo and ok are uint8 (boolean results stop the
    vectorisation): redo when not accepted and the first step left the start cell; t is then
    that first step's offset (the caller restarts from there)."""
    f32 = np.float32
    m0, m1, m2, m3, m4, m5, m6, m7, m8, zr = m
    ox, oy = blk[b, 2], blk[b, 3]
    lim0, lim1 = f32(-ox), f32(cols - 2.0 - ox)
    lim2, lim3 = f32(-oy), f32(rows - 2.0 - oy)
    cx = np.floor(m0)
    cy = np.floor(m3)
    cx = cx if cx >= lim0 else lim0
    cx = cx if cx <= lim1 else lim1
    cy = cy if cy >= lim2 else lim2
    cy = cy if cy <= lim3 else lim3
    k = np.int64(oy) * cols + np.int64(ox) + np.int64(cy) * cols + np.int64(cx)
    z00, z01 = _pair(dem, k)
    z10, z11 = _pair(dem, k + cols)
    z00 = z00 - zr
    z10 = z10 - zr
    dxt = z01 - zr - z00
    twist = (z11 - zr - z10) - dxt
    dy0 = z10 - z00
    u = m0 - cx  # step 1, from t = 0
    v = m3 - cy
    bx = dxt + v * twist
    by = dy0 + u * twist
    t1 = -(m6 - (z00 + u * dxt + v * by)) / (m7 - (bx * m1 + by * m4))
    xs = m0 + t1 * (m1 + t1 * m2)  # step 2, from t1 on the same patch
    ys = m3 + t1 * (m4 + t1 * m5)
    xd = m1 + (t1 + t1) * m2
    yd = m4 + (t1 + t1) * m5
    u = xs - cx
    v = ys - cy
    bx = dxt + v * twist
    by = dy0 + u * twist
    gd = m7 + (t1 + t1) * m8 - (bx * xd + by * yd)
    step = -(m6 + t1 * (m7 + t1 * m8) - (z00 + u * dxt + v * by)) / gd
    t = t1 + step
    x = m0 + t * (m1 + t * m2)
    y = m3 + t * (m4 + t * m5)
    h = m6 + t * (m7 + t * m8)
    xd = m1 + (t + t) * m2
    yd = m4 + (t + t) * m5
    hd = m7 + (t + t) * m8
    gdd = (m8 + m8) - f32(2.0) * (twist * xd * yd + bx * m2 + by * m5)
    ok = ((x >= cx) & (x <= cx + f32(1.0)) & (y >= cy) & (y <= cy + f32(1.0))
          & (abs(step) <= f32(MAX_NEWTON_STEP_M))
          & (abs(gdd) * step * step <= f32(2.0 * ROOT_TOLERANCE_M) * abs(gd))
          & (gd < f32(-1e-3)) & (hd < f32(0.0)))
    back = (f32(blk[b, 13]) - zr - h) / hd
    xa, xb = x, x + xd * back
    ya, yb = y, y + yd * back
    pad = f32(0.5)  # cells: covers the path's curvature over any in-range stretch
    x0 = (xa if xa < xb else xb) - pad  # selects, not min/max: those do not vectorise
    x1 = (xb if xa < xb else xa) + pad
    y0 = (ya if ya < yb else yb) - pad
    y1 = (yb if ya < yb else ya) + pad
    ok = (ok & (x0 >= f32(blk[b, 4])) & (x1 <= f32(blk[b, 5])) & (y0 >= f32(blk[b, 6]))
          & (y1 <= f32(blk[b, 7])))
    x1 = x1 if x1 < lim1 else lim1
    y1 = y1 if y1 < lim3 else lim3
    inv_tile = f32(1.0 / TILE_CELLS)
    gox, goy = f32(ox), f32(oy)
    ratio = ((xd * f32(1.0 / consts[0])) ** 2 + (yd * f32(1.0 / consts[1])) ** 2) / (hd * hd)
    left = (xs < cx) | (xs > cx + f32(1.0)) | (ys < cy) | (ys > cy + f32(1.0))
    redo = left & (ok ^ True)
    return (k, t1 if redo else t, np.uint8(1) if redo else np.uint8(0),
            np.uint8(1) if ok else np.uint8(0), ratio,
            np.int32((x0 + gox) * inv_tile) if ok else np.int32(1 << 30),
            np.int32((x1 + gox) * inv_tile) if ok else np.int32(-1),
            np.int32((y0 + goy) * inv_tile) if ok else np.int32(1 << 30),
            np.int32((y1 + goy) * inv_tile) if ok else np.int32(-1))


@_jit(inline=True)
def _newton_line(dem: Any, cols: int, tid: int, gl: int, lin: Any, blk: Any, b: int,
                 consts: Any, st: Any, ratio: Any, tiles: Any, redo: Any, cell: Any) -> int:
    """`_newton` for every ray of the line (vectorised; the corner loads are gathers): the
    range offset to lin[tid, 9], the restart flags to redo[tid], and for the certification
    the acceptance flags, the squared rates, and the tile ranges (empty when not accepted)
    merged into those of the group's earlier lines (tiles[tid], per pixel); the
    start cells' indices to cell[tid, 0], where the ray may be PREFETCH_LINES later (from the
    previous line's) to cell[tid, 1].
    Returns the number of rays to restart."""
    rows = dem.size // cols
    again = 0
    for j in range(lin.shape[2]):
        m = (lin[tid, 0, j], lin[tid, 1, j], lin[tid, 2, j], lin[tid, 3, j], lin[tid, 4, j],
             lin[tid, 5, j], lin[tid, 6, j], lin[tid, 7, j], lin[tid, 8, j], lin[tid, 10, j])
        k, t, rd, ok, rt, tx0, tx1, ty0, ty1 = _newton(m, dem, cols, rows, blk, b, consts)
        was = cell[tid, 0, j]
        cell[tid, 0, j] = k
        cell[tid, 1, j] = k + PREFETCH_LINES * (k - was)
        lin[tid, 9, j] = t
        redo[tid, j] = rd
        again += rd
        st[tid, gl, j] = ok
        ratio[tid, gl, j] = rt
        a0, a1 = tiles[tid, 0, j], tiles[tid, 1, j]
        a2, a3 = tiles[tid, 2, j], tiles[tid, 3, j]
        tiles[tid, 0, j] = tx0 if (gl == 0) | (tx0 < a0) else a0  # selects: they vectorise
        tiles[tid, 1, j] = tx1 if (gl == 0) | (tx1 > a1) else a1
        tiles[tid, 2, j] = ty0 if (gl == 0) | (ty0 < a2) else a2
        tiles[tid, 3, j] = ty1 if (gl == 0) | (ty1 > a3) else a3
    return again


@_jit(inline=True)
def _output_line(i: int, gl: int, tid: int, lin: Any, blk: Any, b: int, consts: Any, s64: Any,
                 out_e: Any, out_n: Any, out_h: Any, out_hit: Any, st: Any) -> None:
    """Ground point of every ray of line i from its Newton offset (float64 from here on), the
    next line's start ranges, and the acceptance flags as hits (the certification may still
    send a ray to the safe path, which overwrites its output)."""
    fx, fy = blk[b, 0], blk[b, 1]
    e0, n0 = blk[b, 8], blk[b, 9]
    cell_e, cell_n = 1.0 / consts[0], 1.0 / consts[1]
    for j in range(lin.shape[2]):
        t = np.float64(lin[tid, 9, j])
        s = s64[tid, 1, j] + t
        s64[tid, 0, j] = s
        x = lin[tid, 0, j] + t * (lin[tid, 1, j] + t * lin[tid, 2, j])
        y = lin[tid, 3, j] + t * (lin[tid, 4, j] + t * lin[tid, 5, j])
        out_e[i, j] = e0 + (x - fx) * cell_e
        out_n[i, j] = n0 - (y - fy) * cell_n
        out_h[i, j] = (np.float64(lin[tid, 10, j]) + lin[tid, 6, j]
                       + t * (lin[tid, 7, j] + t * lin[tid, 8, j]))
        ok = (st[tid, gl, j] == 1) & (s > 0.0)
        st[tid, gl, j] = np.uint8(1) if ok else np.uint8(0)
        out_hit[i, j] = np.uint8(1) if ok else np.uint8(0)


@_jit(inline=True)
def _redo_line(i: int, gl: int, tid: int, again: int, dem: Any, cols: int, coef: Any,
               look9: Any, blk: Any, b: int, consts: Any, s64: Any, redo: Any, st: Any,
               ratio: Any, tiles: Any, out_e: Any, out_n: Any, out_h: Any, out_hit: Any
               ) -> None:
    """The rays of line i whose first Newton step left the start cell, one by one: `_newton`
    again from where that step ended (s64[tid, 0]), on that cell; not accepted if it leaves
    the cell again. Their output, start range for the next line and certification data are
    replaced."""
    rows = dem.size // cols
    e0, n0, h0 = blk[b, 8], blk[b, 9], blk[b, 10]
    ae, an, ah = coef[i, 0], coef[i, 1], coef[i, 2]
    j = -1
    while again > 0:  # not a counted loop: LLVM must not vectorise it (masked, over every ray)
        j += 1
        if redo[tid, j] == 0:
            continue
        again -= 1
        s = s64[tid, 0, j]
        m = _models(s, coef, look9, i, j, blk, b, consts)
        _, t, _, ok, rt, tx0, tx1, ty0, ty1 = _newton(m, dem, cols, rows, blk, b, consts)
        s = s + np.float64(t)
        s64[tid, 0, j] = s
        be, ce, bn, cn, bh, ch = _terms(coef, look9, i, j)
        out_e[i, j] = e0 + ae + s * (be + s * ce)
        out_n[i, j] = n0 + an + s * (bn + s * cn)
        out_h[i, j] = h0 + ah + s * (bh + s * ch)
        hit = (ok == 1) & (s > 0.0)
        st[tid, gl, j] = np.uint8(1) if hit else np.uint8(0)
        out_hit[i, j] = np.uint8(1) if hit else np.uint8(0)
        ratio[tid, gl, j] = rt
        tiles[tid, 0, j] = min(tiles[tid, 0, j], tx0)  # the first try added nothing
        tiles[tid, 1, j] = max(tiles[tid, 1, j], tx1)
        tiles[tid, 2, j] = min(tiles[tid, 2, j], ty0)
        tiles[tid, 3, j] = max(tiles[tid, 3, j], ty1)


@_jit(inline=True)
def _cast_line(i: int, gl: int, tid: int, cold: int, dem: Any, cols: int, coef: Any,
               look9: Any, blk: Any, b: int, consts: Any, s64: Any, lin: Any, redo: Any,
               cell: Any, st: Any, ratio: Any, tiles: Any, out_e: Any, out_n: Any, out_h: Any,
               out_hit: Any) -> None:
    """Every ray of line i: start ranges and models, Newton steps, output, restarts. Separate
    passes over the line (each vectorises at its own width: float64 set-up and output,
    float32 Newton steps) over scratch that stays in L1. The DEM rows a line needs are mostly
    new ones (flying along the columns), and gathers stall on each cache miss, so the cells of
    every PREFETCH_STRIDE-th ray a few lines ahead are prefetched."""
    _start_line(i, tid, coef, look9, s64, cold, blk, b, consts, lin)
    again = _newton_line(dem, cols, tid, gl, lin, blk, b, consts, st, ratio, tiles, redo, cell)
    last = dem.size - cols - 2
    for j in range(0, look9.shape[1], PREFETCH_STRIDE):
        k = min(max(cell[tid, 1, j], 0), last)
        _prefetch(dem, k)
        _prefetch(dem, k + cols)
    _output_line(i, gl, tid, lin, blk, b, consts, s64, out_e, out_n, out_h, out_hit, st)
    if again > 0:
        _redo_line(i, gl, tid, again, dem, cols, coef, look9, blk, b, consts, s64, redo, st,
                   ratio, tiles, out_e, out_n, out_h, out_hit)


# ---------------------------------------------------------------------------------------------
# The first-root certification
# ---------------------------------------------------------------------------------------------


@_jit()
def _slope_bound(table: Any, log2: Any, tx0: Any, tx1: Any, ty0: Any, ty1: Any) -> float:
    """Largest tile slope over tiles [ty0, ty1] × [tx0, tx1] (two lookups per tile row)."""
    k = log2[tx1 - tx0 + 1]
    right = tx1 - (1 << k) + 1
    worst = 0.0
    for r in range(ty0, ty1 + 1):
        worst = max(worst, table[k, r, tx0], table[k, r, right])
    return worst


@_jit()
def _certify_group(i0: int, lines: int, tid: int, dem: Any, cols: int, table: Any, log2: Any,
                   coef: Any, look9: Any, blk: Any, b: int, consts: Any, st: Any, ratio: Any,
                   tiles: Any, limit: Any, out_e: Any, out_n: Any, out_h: Any, out_hit: Any,
                   line_flag: Any, counts: Any) -> None:
    """First-root test for a group of lines, chunk by chunk: the steepest slope under the
    accepted rays' paths (tiles: their tile ranges, reduced over the group's lines); a ray
    passes if its rate × that slope < SLOPE_MARGIN. The rest take the safe path. The loops
    over rays run over whole lines (per-pixel limits): loops as short as a chunk do not
    reach the vectorised code."""
    p = look9.shape[1]
    for c0 in range(0, p, CHUNK_PIXELS):
        c1 = min(c0 + CHUNK_PIXELS, p)
        tx0, ty0 = np.int32(1 << 30), np.int32(1 << 30)
        tx1, ty1 = np.int32(-1), np.int32(-1)
        for j in range(c0, c1):
            a0, a1 = tiles[tid, 0, j], tiles[tid, 1, j]
            b0, b1 = tiles[tid, 2, j], tiles[tid, 3, j]
            tx0 = a0 if a0 < tx0 else tx0
            tx1 = a1 if a1 > tx1 else tx1
            ty0 = b0 if b0 < ty0 else ty0
            ty1 = b1 if b1 > ty1 else ty1
        slope2 = np.inf  # squared: rays store their squared rate
        if tx0 <= tx1 and ty0 <= ty1:
            slope2 = _slope_bound(table, log2, tx0, tx1, ty0, ty1) ** 2
        for j in range(c0, c1):
            limit[tid, j] = np.float32(SLOPE_MARGIN**2 / slope2)
    for g in range(lines):
        passed = 0
        for j in range(p):  # branch-free count first: most lines pass whole
            passed += 1 if (st[tid, g, j] == 1) & (ratio[tid, g, j] < limit[tid, j]) else 0
        counts[b, 0] += passed
        if passed == p:
            continue
        for j in range(p):
            if not (st[tid, g, j] == 1 and ratio[tid, g, j] < limit[tid, j]):
                code = _safe_to_output(i0 + g, j, dem, cols, coef, look9, blk, b, consts,
                                       out_e, out_n, out_h, out_hit)
                counts[b, 1 + code] += 1
                if code == _EXACT:
                    line_flag[i0 + g] = 1


# ---------------------------------------------------------------------------------------------
# The safe path
# ---------------------------------------------------------------------------------------------


@_jit()
def _safe_to_output(i: int, j: int, dem: Any, cols: int, coef: Any, look9: Any, blk: Any,
                    b: int, consts: Any, out_e: Any, out_n: Any, out_h: Any,
                    out_hit: Any) -> int:
    """Safe path for ray (i, j) and its output: the point, or NaN (+inf height marks a ray
    left to the reference method)."""
    be, ce, bn, cn, bh, ch = _terms(coef, look9, i, j)
    ae, an, ah = coef[i, 0], coef[i, 1], coef[i, 2]
    code, s = _safe_ray(dem, cols, ae, be, ce, an, bn, cn, ah, bh, ch, blk, b, consts)
    if code == _HIT:
        out_e[i, j] = blk[b, 8] + ae + s * (be + s * ce)
        out_n[i, j] = blk[b, 9] + an + s * (bn + s * cn)
        out_h[i, j] = blk[b, 10] + ah + s * (bh + s * ch)
        out_hit[i, j] = 1
    else:
        out_e[i, j] = np.nan
        out_n[i, j] = np.nan
        out_h[i, j] = np.inf if code == _EXACT else np.nan
        out_hit[i, j] = 0
    return code


@_jit()
def _safe_ray(dem: Any, cols: int, ae: float, be: float, ce: float, an: float, bn: float,
              cn: float, ah: float, bh: float, ch: float, blk: Any, b: int, consts: Any
              ) -> tuple[int, float]:
    """Walk the ray cell by cell from where it comes down to the DEM's highest sample, solving
    the gap inside each cell (a quadratic in s over at most SAFE_SEGMENT_M), until the first
    crossing (hit), the DEM's lowest sample, an edge or nodata (miss), or the map's box
    (exact)."""
    fx, fy, ox, oy = blk[b, 0], blk[b, 1], blk[b, 2], blk[b, 3]
    vx0, vx1, vy0, vy1 = blk[b, 4], blk[b, 5], blk[b, 6], blk[b, 7]
    h0 = blk[b, 10]
    inv_e, inv_n = consts[0], consts[1]
    lo_rel, hi_rel = blk[b, 12] - h0, blk[b, 13] - h0
    rows = dem.size // cols
    s = _first_at_or_below(ah, bh, ch, hi_rel, 0.0)
    if not s >= 0.0:
        return _MISS, np.nan
    s_end = _first_at_or_below(ah, bh, ch, lo_rel - 1e-6, s)
    if not s_end >= s:
        s_end = s + 1e7  # stays in the height range: it will leave the DEM
    first = True
    for _ in range(10_000_000):
        x = (ae + s * (be + s * ce)) * inv_e + fx
        y = fy - (an + s * (bn + s * cn)) * inv_n
        if not (x + ox >= 0.0 and x + ox <= cols - 1.0 and y + oy >= 0.0
                and y + oy <= rows - 1.0):
            return _MISS, np.nan
        if not (x >= vx0 and x <= vx1 and y >= vy0 and y <= vy1):
            return _EXACT, np.nan
        xd = (be + 2.0 * ce * s) * inv_e
        yd = -(bn + 2.0 * cn * s) * inv_n
        cx = math.floor(x) if xd >= 0.0 else math.ceil(x) - 1.0
        cy = math.floor(y) if yd >= 0.0 else math.ceil(y) - 1.0
        cx = min(max(cx, -ox), cols - 2.0 - ox)
        cy = min(max(cy, -oy), rows - 2.0 - oy)
        k = np.int64(cy + oy) * cols + np.int64(cx + ox)
        z00, z01 = np.float64(dem[k]) - h0, np.float64(dem[k + 1]) - h0
        z10, z11 = np.float64(dem[k + cols]) - h0, np.float64(dem[k + cols + 1]) - h0
        zsum = z00 + z01 + z10 + z11  # NaN if ANY corner is (max() drops a NaN)
        if zsum != zsum:
            return _MISS, np.nan
        zmax = max(max(z00, z01), max(z10, z11))
        s_next = min(s + SAFE_SEGMENT_M, s_end)
        if xd > 0.0:
            s_next = min(s_next, s + (cx + 1.0 - x) / xd)
        elif xd < 0.0:
            s_next = min(s_next, s + (cx - x) / xd)
        if yd > 0.0:
            s_next = min(s_next, s + (cy + 1.0 - y) / yd)
        elif yd < 0.0:
            s_next = min(s_next, s + (cy - y) / yd)
        s_next = max(s_next, s + 1e-9)
        span = s_next - s
        h_a = ah + s * (bh + s * ch)
        h_b = ah + s_next * (bh + s_next * ch)
        if min(h_a, h_b) - abs(ch) * span * span * 0.25 - 1e-9 <= zmax:
            corners = (z00, z01, z10, z11, cx, cy)
            g0 = _cell_gap(s, ae, be, ce, an, bn, cn, ah, bh, ch, fx, fy, inv_e, inv_n, corners)
            if g0 <= 0.0:
                return (_MISS, np.nan) if (first and s == 0.0) else (_HIT, s)
            tau = _first_root_in(s, span, g0, ae, be, ce, an, bn, cn, ah, bh, ch, fx, fy,
                                 inv_e, inv_n, corners)
            if tau == tau:
                return _HIT, s + tau
        first = False
        s = s_next
        if s >= s_end:
            return _MISS, np.nan
    return _EXACT, np.nan


@_jit()
def _cell_gap(s: float, ae: float, be: float, ce: float, an: float, bn: float, cn: float,
              ah: float, bh: float, ch: float, fx: float, fy: float, inv_e: float,
              inv_n: float, corners: tuple[float, float, float, float, float, float]) -> float:
    """Height of the ray above one cell's bilinear patch (extended beyond the cell) at s."""
    z00, z01, z10, z11, cx, cy = corners
    u = (ae + s * (be + s * ce)) * inv_e + fx - cx
    v = fy - (an + s * (bn + s * cn)) * inv_n - cy
    top = z00 + u * (z01 - z00)
    bottom = z10 + u * (z11 - z10)
    return float(ah + s * (bh + s * ch) - (top + v * (bottom - top)))


@_jit()
def _first_root_in(s: float, span: float, g0: float, ae: float, be: float, ce: float,
                   an: float, bn: float, cn: float, ah: float, bh: float, ch: float, fx: float,
                   fy: float, inv_e: float, inv_n: float,
                   corners: tuple[float, float, float, float, float, float]) -> float:
    """First τ in (0, span] where the gap (> 0 at τ = 0) reaches 0: the gap through three
    points is a quadratic (exact up to terms ~1e-7 of the cell's size), bracketed, then
    refined on the exact gap by regula falsi; NaN if it stays above."""
    gm = _cell_gap(s + 0.5 * span, ae, be, ce, an, bn, cn, ah, bh, ch, fx, fy, inv_e, inv_n,
                   corners)
    g1 = _cell_gap(s + span, ae, be, ce, an, bn, cn, ah, bh, ch, fx, fy, inv_e, inv_n,
                   corners)
    qa = 2.0 * (g1 - 2.0 * gm + g0) / (span * span)
    qb = (g1 - g0) / span - qa * span
    hi, ghi = np.nan, np.nan
    if g1 <= 0.0:
        hi, ghi = span, g1
    elif qa > 0.0:
        tv = -qb / (2.0 * qa)
        if 0.0 < tv < span:
            gv = _cell_gap(s + tv, ae, be, ce, an, bn, cn, ah, bh, ch, fx, fy, inv_e, inv_n,
                           corners)
            if gv <= 0.0:
                hi, ghi = tv, gv
    if hi != hi:
        return np.nan
    lo, glo = 0.0, g0
    side = 0  # Illinois: halve the stale end's value when one end repeats
    for _ in range(100):
        if hi - lo <= 1e-10 or ghi == 0.0:
            break
        t = (lo * ghi - hi * glo) / (ghi - glo)
        if not (lo < t < hi):
            t = 0.5 * (lo + hi)
        gt = _cell_gap(s + t, ae, be, ce, an, bn, cn, ah, bh, ch, fx, fy, inv_e, inv_n, corners)
        if gt > 0.0:
            lo, glo = t, gt
            if side == 1:
                ghi *= 0.5
            side = 1
        else:
            hi, ghi = t, gt
            if side == -1:
                glo *= 0.5
            side = -1
    return hi


# ---------------------------------------------------------------------------------------------
# The cast: every block in parallel
# ---------------------------------------------------------------------------------------------


def scratch(pixels: int) -> tuple[F64, F32, U8, I64, U8, F32, npt.NDArray[np.int32], F32]:
    """Per-thread scratch of the kernel: ranges (previous, start), float32 models and Newton
    offsets, restart flags, start cells (this line's, predicted), and the first-root test's
    data for a group of lines: per ray flags and rates, per pixel tile ranges and limits."""
    t = numba.get_num_threads()
    return (np.empty((t, 2, pixels)), np.empty((t, 11, pixels), np.float32),
            np.empty((t, pixels), np.uint8), np.zeros((t, 2, pixels), np.int64),
            np.empty((t, GROUP_LINES, pixels), np.uint8),
            np.empty((t, GROUP_LINES, pixels), np.float32),
            np.empty((t, 4, pixels), np.int32), np.empty((t, pixels), np.float32))


@_jit(parallel=True)
def cast_blocks(dem: Any, dem_safe: Any, cols: int, table: Any, log2: Any, coef: Any,
                look9: Any, starts: Any, blk: Any, consts: Any, out_e: Any, out_n: Any,
                out_h: Any, out_hit: Any, line_flag: Any, counts: Any, s64: Any, lin: Any,
                redo: Any, cell: Any, st: Any, ratio: Any, tiles: Any, limit: Any) -> None:
    """Every block in parallel; within a block, lines in order (each ray starts from the
    previous line's range; a block's first line takes COLD_PASSES rounds), certified group by
    group.

    Vectorisation needs LLVM to know that no store of a vectorised loop touches the DEM it
    gathers from: numba marks a parallel region's array arguments noalias, so every scratch
    array is an argument (one slice per thread: s64, lin, redo, cell, st, ratio, tiles,
    limit), and
    `dem_safe`, the same array as `dem`, is what escapes into the (scalar) calls."""
    for b in numba.prange(starts.size - 1):
        tid = numba.get_thread_id()  # type: ignore[attr-defined]
        i0 = starts[b]
        for i in range(starts[b], starts[b + 1]):
            gl = i - i0
            rounds = COLD_PASSES if i == starts[b] else 1
            for r in range(rounds):
                _cast_line(i, gl, tid, 1 if rounds > 1 and r == 0 else 0,
                           dem, cols, coef, look9, blk, b, consts, s64, lin, redo, cell,
                           st, ratio, tiles, out_e, out_n, out_h, out_hit)
            if gl == GROUP_LINES - 1 or i == starts[b + 1] - 1:
                _certify_group(i0, gl + 1, tid, dem_safe, cols, table, log2, coef, look9,
                               blk, b, consts, st, ratio, tiles, limit, out_e, out_n, out_h,
                               out_hit, line_flag, counts)
                i0 = i + 1


@_jit(parallel=True)
def safe_pass(dem: Any, cols: int, coef: Any, look9: Any, starts: Any, blk: Any, consts: Any,
              out_e: Any, out_n: Any, out_h: Any, out_hit: Any, line_safe: Any,
              line_flag: Any, counts: Any) -> None:
    """After the C fast path (fastpath.py): its rays left uncertified (hit 2, in the lines
    line_safe flags) on the safe path, blocks in parallel."""
    for b in numba.prange(starts.size - 1):
        for i in range(starts[b], starts[b + 1]):
            if line_safe[i] == 0:
                continue
            for j in range(look9.shape[1]):
                if out_hit[i, j] == 2:
                    code = _safe_to_output(i, j, dem, cols, coef, look9, blk, b, consts,
                                           out_e, out_n, out_h, out_hit)
                    counts[b, 1 + code] += 1
                    if code == _EXACT:
                        line_flag[i] = 1
