"""The ortho cell: one sized by the segments' median across-track pixel spacing, or the --cell
given, refused when wider than half a swath (its orthos would hold a cell or two across)."""

from __future__ import annotations

import math
from typing import Final

import numpy as np

from postproc.georef.jobrecords import GeorefOptions, SegmentResult
from postproc.products import nice_cell_m
from sisa.core.errors import InputError

# the --cell check at a segment's first block of rays refuses only a cell this much wider than
# allowed: that block's pixel spacing is not the whole segment's (198 against 211 m of swath on
# a test run), and a cell the check after the whole flight takes must not be refused early
EARLY_CELL_MARGIN: Final = 1.25


def ortho_cell_m(options: GeorefOptions, done: list[SegmentResult]) -> float:
    """The --cell, checked against the swaths when orthos are made; without one, a nice
    round size near the median across-track pixel spacing of the segments `done`."""
    cell_m = options.cell_m or nice_cell_m(
        float(np.median([d.gsd_across_m for d in done if math.isfinite(d.gsd_across_m)]
                        or [math.nan])))
    if not math.isfinite(cell_m) or cell_m <= 0:
        hits, rays = sum(d.rays_hit for d in done), sum(d.rays for d in done)
        raise InputError(f"only {hits} of {rays} pixels met the DEM, too few neighbours to "
                         "measure the pixel spacing the ortho cell is sized by: give --cell M")
    if options.products and options.cell_m is not None:
        check_cell_against_swaths(cell_m, done)
    return cell_m


def swath_size_m(seg: SegmentResult) -> tuple[float, float]:
    """(across-track width, along-track length) of a segment's georeferenced swath, from its
    median pixel spacings (NaN when unknown)."""
    pixels = seg.rays // seg.lines if seg.lines else 0
    return (seg.gsd_across_m * max(pixels - 1, 0),
            seg.gsd_along_m * max(seg.lines_georeferenced - 1, 0))


def check_cell_against_swaths(cell_m: float, done: list[SegmentResult]) -> None:
    """InputError when the ortho cell is wider than half the narrowest swath: its orthos
    would hold a cell or two across at best, none at worst (--cell 5000 over a 500 m swath
    gave empty orthos and mosaic, exit 0)."""
    widths = [(swath_size_m(d)[0], d) for d in done]
    widths = [(w, d) for w, d in widths if math.isfinite(w) and w > 0]
    if not widths:
        return
    width, seg = min(widths, key=lambda wd: wd[0])
    check_cell_against_swath(cell_m, seg.segment, width, seg.gsd_across_m)


def check_cell_against_swath(cell_m: float, segment: int, width_m: float, gsd_m: float,
                             margin: float = 1.0) -> None:
    """InputError when the ortho cell is wider than half of one segment's swath (`width_m`
    across, of `gsd_m` pixels) times `margin`; nothing when the width is unknown."""
    if math.isfinite(width_m) and width_m > 0 and cell_m > margin * width_m / 2:
        raise InputError(f"--cell {cell_m:g}: wider than half the swath (segment {segment}: "
                         f"{width_m:.0f} m wide, {gsd_m:.2g} m pixels): its ortho would hold a "
                         f"cell or two across, or none; use at most {math.floor(width_m / 2)} m")
