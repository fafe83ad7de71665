"""Bilinear and cubic resampling for the ortho, from the nearest pixel the ortho finds.

The ortho maps each output cell to the input pixel whose ground position (IGM) is nearest to
the cell centre. Interpolating needs the cell's *fractional* image position: the IGM is locally
linear over a pixel, so with G(l, s) the ground position of line l, sample s, and J its
derivatives at the nearest pixel (central differences of the IGM, one-sided at an edge),

    (ds, dl) = J⁻¹ · (cell − G(l₀, s₀)),

one Newton step from the nearest pixel (exact where the IGM is affine; the nearest pixel is
within half a pixel, where the IGM's curvature is negligible). The image is then interpolated
at (l₀ + dl, s₀ + ds) with separable weights: bilinear (2 × 2 pixels) or cubic convolution
(Keys, a = −0.5, 4 × 4 pixels: reproduces quadratics, the kernel of GDAL's `cubic`).

A cell keeps its nearest pixel's value where interpolation would invent or mix what is not data:
a neighbour outside the image, an input pixel equal to the image's ignore value, an IGM without
positions around it (void, NaN), or a fractional position more than a pixel from the nearest one
(sheared lines). Integer images get the interpolated value rounded and clipped to their type
(cubic overshoots at edges). The GLT stays the nearest-pixel lookup: it is a table of pixels.
"""

from __future__ import annotations

from collections.abc import Callable
from enum import StrEnum
from typing import Any, Final

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
B = npt.NDArray[np.bool_]

KEYS_A: Final = -0.5
MAX_OFFSET_PX: Final = 1.0  # farther from the nearest pixel: the IGM is not linear there

# (band values of the cells, as (bands, cells)) from the image at (line, sample) per cell
Gather = Callable[[npt.NDArray[np.int64], npt.NDArray[np.int64]], npt.NDArray[Any]]


class Resampling(StrEnum):
    NEAREST = "nearest"
    BILINEAR = "bilinear"
    CUBIC = "cubic"


def fractional_offsets(centre: F64, ds_plus: F64, ds_minus: F64, dl_plus: F64, dl_minus: F64,
                       s_step: F64, l_step: F64, cell: F64) -> tuple[F64, F64, B]:
    """(ds, dl, usable) of each cell: its position in pixels from the nearest pixel, from the
    ground positions (2, n) of that pixel and of its neighbours ±1 sample and ±1 line (equal to
    the centre's at an edge), the index steps between those neighbours (2 in the middle, 1 at
    an edge, 0 for an image one pixel wide) and the cell centres (2, n)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        ja = (ds_plus - ds_minus) / s_step  # ∂G/∂s
        jb = (dl_plus - dl_minus) / l_step  # ∂G/∂l
        det = ja[0] * jb[1] - ja[1] * jb[0]
        rx, ry = cell[0] - centre[0], cell[1] - centre[1]
        ds = (jb[1] * rx - jb[0] * ry) / det
        dl = (ja[0] * ry - ja[1] * rx) / det
    usable = (np.isfinite(ds) & np.isfinite(dl) & (np.abs(ds) <= MAX_OFFSET_PX)
              & (np.abs(dl) <= MAX_OFFSET_PX))
    return np.where(usable, ds, 0.0), np.where(usable, dl, 0.0), usable


def taps(method: Resampling, position: F64) -> tuple[I64, list[F64]]:
    """The first pixel index and the weights of each tap along one axis for positions given
    in pixels (integer = a pixel centre): 2 taps bilinear, 4 cubic."""
    base = np.floor(position)
    t = position - base
    if method is Resampling.BILINEAR:
        return base.astype(np.int64), [1.0 - t, t]
    if method is Resampling.CUBIC:
        return base.astype(np.int64) - 1, [_keys(1.0 + t), _keys(t), _keys(1.0 - t),
                                           _keys(2.0 - t)]
    raise ValueError(f"no taps for {method}")


def _keys(x: F64) -> F64:
    """Keys' cubic convolution kernel at |x| ≤ 2."""
    x = np.abs(x)
    a = KEYS_A
    near = ((a + 2) * x - (a + 3)) * x * x + 1
    far = ((a * x - 5 * a) * x + 8 * a) * x - 4 * a
    return np.where(x <= 1, near, np.where(x < 2, far, 0.0))


def interpolate(method: Resampling, line: F64, sample: F64, lines: int, samples: int,
                gather: Gather, ignore: float | None, dtype: np.dtype[Any]
                ) -> tuple[npt.NDArray[Any], B]:
    """(values (bands, n) in `dtype`, interpolated) at fractional (line, sample) per cell;
    `interpolated` is False where a tap falls outside the image or on an ignored value (the
    caller keeps the nearest pixel's value there)."""
    l0, wl = taps(method, line)
    s0, ws = taps(method, sample)
    ok = (l0 >= 0) & (l0 + len(wl) <= lines) & (s0 >= 0) & (s0 + len(ws) <= samples)
    lc, sc = np.where(ok, l0, 0), np.where(ok, s0, 0)
    total: F64 | None = None
    for i, w_line in enumerate(wl):
        for j, w_sample in enumerate(ws):
            values = gather(np.minimum(lc + i, lines - 1), np.minimum(sc + j, samples - 1))
            v = values.astype(np.float64)
            if ignore is not None:
                ok &= ~(v == ignore).any(axis=0)
            ok &= np.isfinite(v).all(axis=0)
            term = v * (w_line * w_sample)
            total = term if total is None else total + term
    assert total is not None
    if np.issubdtype(dtype, np.integer):
        info = np.iinfo(dtype)
        total = np.clip(np.rint(np.nan_to_num(total)), info.min, info.max)
    return total.astype(dtype), ok
