"""The prepared DEM: what the kernel needs of a DEM (flat float32 heights, their range, a sparse
table of per-tile slope maxima, a coarse map over it), built once per DEM."""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from postproc.georef.dem import SURFACE_HEIGHTS_M, Dem
from postproc.georef.raycast.kernel import TILE_CELLS
from postproc.georef.raycast.maps import Maps, fit_maps
from sisa.core.errors import InputError

F32 = npt.NDArray[np.float32]
I64 = npt.NDArray[np.int64]


@dataclass(frozen=True, eq=False)
class Surface:
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
    coarse_map: Maps  # over the whole DEM: only to size the blocks' boxes

    @classmethod
    def build(cls, dem: Dem) -> Surface:
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
        coarse = fit_maps(np.array([dem.bounds_m], dtype=np.float64), low, high, dem.epsg)
        return cls(dem, np.ascontiguousarray(h).ravel(), dem.rows, dem.cols, low, high, table,
                   log2, coarse)


_SURFACES: weakref.WeakKeyDictionary[Dem, Surface] = weakref.WeakKeyDictionary()


def surface_of(dem: Dem) -> Surface:
    surf = _SURFACES.get(dem)
    if surf is None:
        surf = _SURFACES[dem] = Surface.build(dem)
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
