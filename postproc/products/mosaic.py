"""Mosaic of segments on one grid, streamed by output tiles.

Each segment contributes, for every cell, its own nearest pixel (from its IGM, as the ortho
does, or from its GLT). Where strips overlap the cell takes the segment whose chosen pixel is
nearest to nadir, |pixel − (pixels − 1)/2|: the nadir of one strip and the edge of its
neighbour, so seams fall mid-overlap and every cell shows the least oblique view. Photos of a
frame camera (`frames=True`) look down from their image centre, not from a line's middle: the
cell takes the photo whose chosen pixel is nearest its image centre, in both directions.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt
import rasterio
from rasterio.errors import RasterioIOError

from postproc.products.igm import EnviRaster
from postproc.products.ortho import (
    GDAL_CACHE_MB,
    OrthoGrid,
    SwathIndex,
    TiffWriter,
    check_pair,
    gather_pixels,
    nearest_pixels,
    output_nodata,
    window_cells,
)
from sisa.core.errors import InputError

I32 = npt.NDArray[np.int32]
B = npt.NDArray[np.bool_]
Choice = tuple[I32, I32, B]  # line, pixel (0-based), valid

GLT_BANDS: Final = 2


@dataclass(frozen=True)
class _Segment:
    """One strip: its image and where its pixels go (an IGM index or a GLT on an aligned
    grid)."""

    raw: EnviRaster
    bounds_m: tuple[float, float, float, float]
    index: SwathIndex | None = None
    glt: EnviRaster | None = None
    glt_offset: tuple[int, int] = (0, 0)  # (row, col) of the GLT's first cell in the mosaic

    def choose(self, grid: OrthoGrid, row0: int, col0: int, rows: int, cols: int
               ) -> Choice | None:
        w, s, e, n = self.bounds_m
        x0, y0 = float(grid.centre_x_m(col0)), float(grid.centre_y_m(row0))
        if e < x0 or w > x0 + (cols - 1) * grid.cell_m or n < y0 - (rows - 1) * grid.cell_m \
                or s > y0:
            return None
        if self.index is not None:
            ch = nearest_pixels(self.index, grid, row0, col0, rows, cols)
            return ch.line, ch.pixel, ch.valid
        return None if self.glt is None else self._from_glt(self.glt, row0, col0, rows, cols)

    def _from_glt(self, glt: EnviRaster, row0: int, col0: int, rows: int, cols: int
                  ) -> Choice:
        line = np.full((rows, cols), -1, dtype=np.int32)
        pixel = np.full((rows, cols), -1, dtype=np.int32)
        r0, c0 = row0 - self.glt_offset[0], col0 - self.glt_offset[1]
        ra, rb = max(r0, 0), min(r0 + rows, glt.lines)
        ca, cb = max(c0, 0), min(c0 + cols, glt.pixels)
        if ra < rb and ca < cb:
            blk = np.abs(glt.read_lines(ra, rb)[:, :, ca:cb].astype(np.int64))
            if blk[:, 0].max(initial=0) > self.raw.pixels or \
                    blk[:, 1].max(initial=0) > self.raw.lines:
                raise InputError(f"{glt.path}: points beyond the image {self.raw.path}")
            ok = (blk[:, 0] > 0) & (blk[:, 1] > 0)
            win = (slice(ra - r0, rb - r0), slice(ca - c0, cb - c0))
            pixel[win] = np.where(ok, blk[:, 0] - 1, -1)
            line[win] = np.where(ok, blk[:, 1] - 1, -1)
        return line, pixel, line >= 0


def _glt_grid(path: Path) -> OrthoGrid:
    try:
        with rasterio.open(path) as ds:
            t, crs, width, height = ds.transform, ds.crs, ds.width, ds.height
    except RasterioIOError as exc:
        raise InputError(f"{path}: unreadable GLT: {exc}") from None
    epsg = crs.to_epsg() if crs is not None else None
    if epsg is None or t.b != 0 or t.d != 0 or not math.isclose(t.a, -t.e, rel_tol=1e-9):
        raise InputError(f"{path}: GLT without a north-up map info and an EPSG coordinate "
                         "system")
    return OrthoGrid(t.c, t.f, t.a, width, height, int(epsg))


def _open_segment(geometry: Path | SwathIndex, image: Path, grid: OrthoGrid) -> _Segment:
    raw = EnviRaster.open(Path(image))
    if isinstance(geometry, SwathIndex):  # an IGM its caller has indexed already
        index = geometry
    else:
        geo = EnviRaster.open(Path(geometry))
        if geo.bands == GLT_BANDS and geo.dtype.kind == "i" and geo.dtype.itemsize == 4:
            glt_grid = _glt_grid(geo.path)
            return _Segment(raw, glt_grid.bounds_m, glt=geo,
                            glt_offset=glt_grid.offset_in(grid))
        if not (geo.bands == 3 and geo.dtype.kind == "f" and geo.dtype.itemsize == 8):
            raise InputError(f"{geometry}: neither an IGM (3 float64 bands) nor a GLT (2 int32 "
                             "bands)")
        index = SwathIndex.build(geo.path)
    check_pair(index, raw, grid.epsg)
    return _Segment(raw, index.bounds_m, index=index)


@dataclass(frozen=True)
class MosaicResult:
    cells: int
    cells_filled: int
    cells_per_segment: tuple[int, ...]


def mosaic(segments: Sequence[tuple[Path | SwathIndex, Path]], grid: OrthoGrid, out_tif: Path,
           *, tile_cells: int | None = None, compress: str = "deflate",
           frames: bool = False) -> MosaicResult:
    """Mosaic [(IGM or GLT, raw image), ...] onto `grid` as one GeoTIFF (written whole or not
    at all); an IGM may come as the SwathIndex its caller built (no second pass over it). All
    images must have the same bands and data type. `frames`: the images are photos (the
    nearest to its image centre wins, not the nearest to its line's middle)."""
    if not segments:
        raise InputError("mosaic: no segment given")
    segs = [_open_segment(g, i, grid) for g, i in segments]
    first = segs[0].raw
    for s in segs[1:]:
        if (s.raw.bands, s.raw.dtype.name) != (first.bands, first.dtype.name):
            raise InputError(f"{s.raw.path}: {s.raw.bands} bands of {s.raw.dtype.name}, but "
                             f"{first.path} has {first.bands} of {first.dtype.name}")
    nodata = output_nodata(first)
    counts = [0] * len(segs)
    desc = (f"SISA mosaic of {len(segs)} segments: each cell from the segment whose nearest "
            "pixel is closest to nadir, |pixel - (pixels - 1)/2|; within a segment the pixel "
            "whose pixel-centre ground position is nearest to the cell centre")
    if frames:
        desc = (f"SISA mosaic of {len(segs)} photos: each cell from the photo whose nearest "
                "pixel is closest to its image centre; within a photo the pixel whose "
                "pixel-centre ground position is nearest to the cell centre")
    with rasterio.Env(GDAL_CACHEMAX=GDAL_CACHE_MB):
        tif = TiffWriter(Path(out_tif), grid, first, nodata, desc, compress)
        try:
            for row0, col0, rows, cols in grid.windows(window_cells(first), tile_cells):
                got = _mosaic_tile(segs, grid, row0, col0, rows, cols, nodata, counts, frames)
                if got is not None:
                    tif.write(got[0], row0, col0, got[1])
        except BaseException:
            tif.abort()
            raise
        tif.close()
    return MosaicResult(grid.width * grid.height, sum(counts), tuple(counts))


def _mosaic_tile(segs: list[_Segment], grid: OrthoGrid, row0: int, col0: int, rows: int,
                 cols: int, nodata: float, counts: list[int], frames: bool = False
                 ) -> tuple[npt.NDArray[np.generic], B] | None:
    best_off = np.full((rows, cols), np.inf)
    best_seg = np.full((rows, cols), -1, dtype=np.int32)
    line = np.full((rows, cols), -1, dtype=np.int32)
    pixel = np.full((rows, cols), -1, dtype=np.int32)
    for k, seg in enumerate(segs):
        got = seg.choose(grid, row0, col0, rows, cols)
        if got is None:
            continue
        ln, px, ok = got
        off = np.abs(px - (seg.raw.pixels - 1) / 2.0)
        if frames:  # a photo's nadir is its centre: the distance there, in pixels
            off = np.hypot(off, ln - (seg.raw.lines - 1) / 2.0)
        take = ok & (off < best_off)
        best_off[take], best_seg[take], line[take], pixel[take] = off[take], k, ln[take], px[take]
    if (best_seg < 0).all():
        return None
    data = np.full((segs[0].raw.bands, rows, cols), nodata,
                   dtype=segs[0].raw.dtype.newbyteorder("="))
    for k in np.unique(best_seg[best_seg >= 0]):
        sel = best_seg == k
        gather_pixels(segs[k].raw, line, pixel, sel, nodata, into=data)
        counts[k] += int(sel.sum())
    return data, best_seg >= 0
