"""The lines in blocks, each with its map fitted over the box its rays' paths can cover through
its height band, split until the map fits."""

from __future__ import annotations

import math
from typing import Final

import numpy as np
import numpy.typing as npt

from postproc.georef.raycast.kernel import footprint_kernel
from postproc.georef.raycast.maps import Maps, concat, fit_maps, take, with_starts
from postproc.georef.raycast.surface import Surface
from postproc.georef.raycast.tables import line_coefficients, look_products

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
B1 = npt.NDArray[np.bool_]

BLOCK_LINES: Final = 512  # lines sharing one fitted map (and one parallel work item)
BALANCE_BLOCKS: Final = 8  # the block count is a multiple of this (not of the threads)
MAP_TOLERANCE_M: Final = 3e-5  # fitted map vs pyproj at check points
BOX_MARGIN_M: Final = 60.0  # map box beyond the sampled footprints...
BOX_MARGIN_FRACTION: Final = 0.1  # ...plus this fraction of its size
FOOTPRINT_LEVELS: Final = 17  # heights spanning the DEM's range; a block's band is widened
# to the nearest of them (its map box is sized by footprints there)


def fit_block_maps(surf: Surface, centre: F64, rot: F64, unit: F64) -> Maps:
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

    # equal blocks, as many as a multiple of BALANCE_BLOCKS: the kernel's static schedule is
    # balanced on 1, 2, 4 or 8 threads, and the blocks (hence every map and every ray's start)
    # do not depend on the threads a process has: a campaign's one-thread task gives the IGM
    # `sisa georef` gives on all the cores, bit for bit
    count = min(n, math.ceil(math.ceil(n / BLOCK_LINES) / BALANCE_BLOCKS) * BALANCE_BLOCKS)
    bounds = (np.arange(count + 1, dtype=np.int64) * n) // count
    start, stop = bounds[:-1], bounds[1:]
    banded = np.zeros(start.size, np.bool_)  # blocks given their own height band
    parts: list[tuple[I64, Maps]] = []
    for _ in range(64):
        k_lo, k_hi = np.zeros_like(start), np.full_like(start, FOOTPRINT_LEVELS - 1)
        low, high = np.full(start.size, surf.low_m), np.full(start.size, surf.high_m)
        if banded.any():
            reach = _block_boxes(footprints(k_lo, k_hi), lines, start[banded], stop[banded],
                                 hull, k_lo[banded], k_hi[banded])
            low[banded], high[banded] = _box_heights(surf, reach)
            k_lo[banded], k_hi[banded] = _level_span(levels, low[banded], high[banded])
        boxes = _block_boxes(footprints(k_lo, k_hi), lines, start, stop, hull, k_lo, k_hi)
        maps = fit_maps(boxes, low, high, dem.epsg)
        keep = (maps.error_m <= MAP_TOLERANCE_M) | (banded & (stop - start == 1))
        parts.append((start[keep], take(maps, keep)))
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
    maps = concat([p[1] for p in parts], order)
    bad = maps.error_m > MAP_TOLERANCE_M
    maps.box_en_m[bad] = [np.inf, np.inf, -np.inf, -np.inf]
    return with_starts(maps, np.append(starts[order], n).astype(np.int64))


def _box_heights(surf: Surface, boxes: F64) -> tuple[F64, F64]:
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


def _footprints(coarse: Maps, centre: F64, rot: F64, unit: F64, levels: F64, hull: F64
                ) -> F64:
    """Per line and height level (lines, levels, 4): approximate EN box (west, south, east,
    north) of where its rays cross that height (the camera itself when below), clipped to the
    DEM; the camera's own position when no ray comes down."""
    coarse = with_starts(coarse, np.array([0, centre.shape[0]], np.int64))
    coef = line_coefficients(coarse, centre, rot)
    out = np.empty((centre.shape[0], levels.size, 4))
    footprint_kernel(coef, look_products(unit), levels - coarse.h0_m[0], coarse.en0_m[0],
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
