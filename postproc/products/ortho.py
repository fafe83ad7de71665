"""Orthorectification by nearest pixel centre: the ortho GeoTIFF and its GLT (ENVI). On request
the GeoTIFF holds the image interpolated (bilinear, cubic) at each cell centre's position in it
instead, from the same nearest pixel (postproc.products.resample); the GLT does not change.

For every cell of a north-up grid, the input pixel whose ground position (IGM, pixel centre) is
nearest to the cell centre. Every quad of 2×2 neighbouring pixels is rasterised onto the grid as
two triangles, so each cell centre inside the swath is reached (no holes from resampling); the
nearest corner of the quad is then refined by a descent over neighbouring pixels, which finds
the exact nearest pixel even where turbulence shears the lines. Cells whose centre no quad
covers are nodata. Work goes by output windows (full-width strips of rows, or square tiles on
wide grids) sized by WINDOW_BYTES, each reading only the IGM and image lines that reach it, so
memory does not grow with the length of the flight. Windows are made WORKERS at a time on
threads (the C kernels, postproc/products/_orthokernels.c, run without the GIL) while a background
thread compresses the GeoTIFF of the previous one; the products do not depend on the number
of threads.
"""

from __future__ import annotations

import contextlib
import ctypes
import dataclasses
import importlib
import itertools
import math
import mmap
import os
import shutil
import warnings
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from queue import SimpleQueue
from typing import Any, Final

import numpy as np
import numpy.typing as npt
import rasterio
from affine import Affine
from rasterio.errors import RasterioIOError
from rasterio.windows import Window

from postproc.products.igm import (
    CutShortWarning,
    EnviRaster,
    band_labels,
    commit_envi,
    coordinate_system_string,
    crs_name,
    envi_header_text,
    envi_list,
    igm_epsg,
    igm_raster,
    projected_crs,
    replace_file,
)
from postproc.products.resample import Resampling, fractional_offsets, interpolate
from sisa.core.errors import InputError
from sisa.core.interrupt import raise_if_stopped
from sisa.core.outdir import create_partial, private_partial

F64 = npt.NDArray[np.float64]
I32 = npt.NDArray[np.int32]
I64 = npt.NDArray[np.int64]
B = npt.NDArray[np.bool_]

TIFF_BLOCK: Final = 256  # GeoTIFF tile side, cells (see docs/georef.md: 512 wrote a third more)
WINDOW_BYTES: Final = 160_000_000  # output values (all bands) held per work window
STRIP_MAX_COLS: Final = 8192  # grids up to this wide go by full-width strips of rows
INDEX_BLOCK_LINES: Final = 128  # lines per bounding box of the swath index
MAX_READ_LINES: Final = 2048  # IGM lines per read
RAW_CHUNK_LINES: Final = 1024  # image lines per read
DESCENT_LINES: Final = 2  # neighbourhood searched by the descent to the nearest pixel
DESCENT_PIXELS: Final = 1
GAP_FACTOR: Final = 4.0 * (1 + 1e-6)  # 4: see _gaps; 1e-6: room for rounding
DESCENT_MARGIN_LINES: Final = 4  # lines read beyond a run of quads for the descent
PLANE_PAD_BYTES: Final = 64  # see Scratch.planes
WORKERS: Final = 2  # windows made at once (each holds its arrays: memory)
GDAL_CACHE_MB: Final = 128
TIFF_ZLEVEL: Final = 1
TIFF_ZSTD_LEVEL: Final = 1  # GDAL's default (9) is several times slower for ~10 % smaller files
TIFF_COMPRESSIONS: Final = ("deflate", "zstd", "lzw", "none")
GLT_BAND_NAMES: Final = ("GLT Sample Lookup", "GLT Line Lookup")
MAX_GRID_CELLS: Final = 2**32  # 65 536² cells: a 32 GB GLT; a finer grid or a wider one is
# a mistyped --cell or --bounds (0.001 m cells made a 13 TB sparse GLT before anyone noticed)
FAR_WIDTHS: Final = 50.0  # a position this many line widths from the rest is damage: see _far_lines


# -- the C kernels ---------------------------------------------------------------------------

def _load_kernels() -> ctypes.CDLL:
    """postproc/products/_orthokernels.c, built when SISA is installed. Called through ctypes, which
    releases the GIL for the call (why C: see the file's head)."""
    try:
        kernels = importlib.import_module("postproc.products._orthokernels")
    except ImportError as exc:
        raise ImportError("postproc.products._orthokernels (the ortho's C kernels) is not built: "
                          "install SISA with `pip install -e .` (`make setup`)") from exc
    lib = ctypes.CDLL(kernels.__file__)
    p, i, d = ctypes.c_void_p, ctypes.c_int64, ctypes.c_double
    signatures = {
        "line_extents": [p, i, i, i, p],
        "to_cells": [p, i, i, i, d, d, d, p, p, p],
        "gaps": [p, p, i, i, i, i, p],
        "rasterise": [p, p, p, p, i, i, i, i, i, i, i, i, i, d, p, p, p, p],
        "line_range": [p, p, i, p, p],
        "chunk_spans": [p, p, i, i, i, p],
        "copy_pixels": [p, i, i, i, i, i, p, p, p, i, p, i],
        "glt_values": [p, p, p, p, i, i, p, p],
    }
    for name, args in signatures.items():
        fn = getattr(lib, name)
        fn.argtypes, fn.restype = args, None
    lib.write_glt_rows.argtypes = [ctypes.c_int, p, i, i, i, i, i]
    lib.write_glt_rows.restype = ctypes.c_int  # 0 or an errno
    return lib


_C = _load_kernels()


def _check_in(*arrays: npt.NDArray[Any], dtype: npt.DTypeLike) -> None:
    """The kernels read C-contiguous arrays of one type, of one shape when given together."""
    for a in arrays:
        if a.dtype != np.dtype(dtype) or not a.flags.c_contiguous or a.shape != arrays[0].shape:
            raise ValueError(f"kernel input: need C-contiguous {np.dtype(dtype)} arrays of one "
                             f"shape, got {a.dtype} {a.shape}")


def _check_out(a: npt.NDArray[Any], dtype: npt.DTypeLike, shape: tuple[int, ...]) -> None:
    _check_in(a, dtype=dtype)
    if a.shape != shape or not a.flags.writeable:
        raise ValueError(f"kernel output: need a writable {shape} array, got {a.shape}")


# -- the output grid -------------------------------------------------------------------------

@dataclass(frozen=True)
class OrthoGrid:
    """A north-up grid in a projected CRS. Cell (row, col) is the square
    [west + col·cell, west + (col+1)·cell] × [north − (row+1)·cell, north − row·cell]
    (GeoTIFF AREA_OR_POINT=Area); its centre is the point a pixel is chosen for."""

    west_m: float
    north_m: float
    cell_m: float
    width: int
    height: int
    epsg: int

    def __post_init__(self) -> None:
        if not (math.isfinite(self.cell_m) and self.cell_m > 0):
            raise InputError(f"grid cell must be a positive number of metres, got {self.cell_m}")
        if self.width <= 0 or self.height <= 0:
            raise InputError(f"grid must have cells, got {self.width} x {self.height}")
        if self.width * self.height > MAX_GRID_CELLS:
            raise _too_large(self.width, self.height, self.cell_m)
        projected_crs(self.epsg)

    @classmethod
    def covering(cls, bounds_m: Sequence[float], cell_m: float, epsg: int) -> OrthoGrid:
        """The smallest grid with edges on multiples of `cell_m` that holds (west, south,
        east, north); grids of one cell size built this way are aligned with each other."""
        west, south, east, north = (float(b) for b in bounds_m)
        if not all(map(math.isfinite, (west, south, east, north))) or west > east or \
                south > north:
            raise InputError(f"grid bounds {tuple(bounds_m)} are not (west, south, east, north)")
        if not (math.isfinite(cell_m) and cell_m > 0):
            raise InputError(f"grid cell must be a positive number of metres, got {cell_m}")
        cols_f, rows_f = (east - west) / cell_m, (north - south) / cell_m  # may overflow to inf
        if cols_f * rows_f > MAX_GRID_CELLS:
            raise _too_large(cols_f, rows_f, cell_m)
        c0, c1 = math.floor(west / cell_m), math.ceil(east / cell_m)
        r0, r1 = math.floor(south / cell_m), math.ceil(north / cell_m)
        return cls(c0 * cell_m, r1 * cell_m, float(cell_m), max(c1 - c0, 1), max(r1 - r0, 1),
                   int(epsg))

    @property
    def transform(self) -> Affine:
        return Affine(self.cell_m, 0.0, self.west_m, 0.0, -self.cell_m, self.north_m)

    @property
    def bounds_m(self) -> tuple[float, float, float, float]:
        return (self.west_m, self.north_m - self.height * self.cell_m,
                self.west_m + self.width * self.cell_m, self.north_m)

    def centre_x_m(self, col: npt.ArrayLike) -> F64:
        return self.west_m + (np.asarray(col, dtype=np.float64) + 0.5) * self.cell_m

    def centre_y_m(self, row: npt.ArrayLike) -> F64:
        return self.north_m - (np.asarray(row, dtype=np.float64) + 0.5) * self.cell_m

    def windows(self, max_cells: int, tile_cells: int | None = None
                ) -> Iterator[tuple[int, int, int, int]]:
        """(row0, col0, rows, cols) of work windows of at most ~max_cells, row by row, on
        GeoTIFF block boundaries: full-width strips when the grid is narrow enough (one GLT
        write per strip), else square tiles; `tile_cells` forces square tiles of that side."""
        if tile_cells is not None:
            rows = cols = max(int(tile_cells), 1)
        elif self.width <= STRIP_MAX_COLS and self.width * TIFF_BLOCK <= max_cells:
            rows, cols = max_cells // self.width // TIFF_BLOCK * TIFF_BLOCK, self.width
        else:
            rows = cols = max(math.isqrt(max_cells) // TIFF_BLOCK, 1) * TIFF_BLOCK
        for r in range(0, self.height, rows):
            for c in range(0, self.width, cols):
                yield r, c, min(rows, self.height - r), min(cols, self.width - c)

    def offset_in(self, outer: OrthoGrid) -> tuple[int, int]:
        """(row, col) of this grid's first cell in `outer`; the grids must be aligned."""
        if self.epsg != outer.epsg or not math.isclose(self.cell_m, outer.cell_m,
                                                       rel_tol=1e-9):
            raise InputError(f"grids differ: EPSG:{self.epsg} cell {self.cell_m} m against "
                             f"EPSG:{outer.epsg} cell {outer.cell_m} m")
        col = (self.west_m - outer.west_m) / outer.cell_m
        row = (outer.north_m - self.north_m) / outer.cell_m
        if abs(col - round(col)) > 1e-6 or abs(row - round(row)) > 1e-6:
            raise InputError("grids are not aligned (edges are not on common multiples of the "
                             "cell size)")
        return round(row), round(col)


def _too_large(cols: float, rows: float, cell_m: float) -> InputError:
    def count(n: float) -> str:
        return f"{n:.3g}" if n >= 1e9 else f"{math.ceil(n)}"
    return InputError(f"a grid of {count(cols)} x {count(rows)} cells of {cell_m:g} m is too "
                      f"large (more than {MAX_GRID_CELLS:,} cells): check the cell size and the "
                      "bounds")


def nice_cell_m(gsd_m: float) -> float:
    """The pixel spacing rounded to two significant digits: 0.964 → 0.96, 3.47 → 3.5."""
    if not math.isfinite(gsd_m) or gsd_m <= 0:
        return math.nan
    digits = 1 - math.floor(math.log10(gsd_m))
    return round(gsd_m, digits)


# -- where each block of lines lies on the ground --------------------------------------------

class FarPositionWarning(UserWarning):
    """An IGM holds positions far from the rest (damage): they are mapped as no position."""


@dataclass(frozen=True)
class FarPositions:
    """Positions of an IGM far from the rest of it (see _far_lines), which the index and the
    ortho take for no position (NaN): a damaged value 5000 km off otherwise stretches the
    grid over 5000 km, or, on a grid given, fills a sliver of cells from the pixels beside it."""

    pixels: I64  # (n, 2): line, pixel of every such position, in the order of lines
    first: str  # e.g. "IGM line 10, pixel 10 lies 5000 km from the rest of its line"

    @property
    def text(self) -> str:
        more = len(self.pixels) - 1
        return self.first + (f" (and {more} more positions far off)" if more else "")

    def void(self, blk: npt.NDArray[Any], line0: int) -> None:
        """Set these positions NaN in blk (lines, 3, pixels), IGM lines from line0 on."""
        a, b = np.searchsorted(self.pixels[:, 0], [line0, line0 + blk.shape[0]])
        if b > a:
            blk[self.pixels[a:b, 0] - line0, :, self.pixels[a:b, 1]] = np.nan


@dataclass(frozen=True)
class SwathIndex:
    """Bounding box of every block of quads of an IGM, so a tile reads only the lines that
    reach it. Block k holds the quads whose first line is in [k·block_lines, (k+1)·block_lines)
    (they reach one line further). Positions far from the rest (`far`) are left out."""

    raster: EnviRaster
    block_lines: int
    boxes_m: F64  # (blocks, 4): west, south, east, north; NaN where a block has no position
    far: FarPositions | None = None  # usually None

    @classmethod
    def build(cls, igm: Path, block_lines: int = INDEX_BLOCK_LINES,
              workers: int = WORKERS, lines: int | None = None) -> SwathIndex:
        """The index of the IGM's lines, or of its first `lines`."""
        raster = igm_raster(Path(igm))
        if lines is not None and lines < raster.lines:
            raster = dataclasses.replace(raster, lines=lines)
        per_line = np.empty((raster.lines, 4))
        # the reads and the kernel release the GIL: `workers` parts of the file at once
        parts = np.linspace(0, raster.lines, max(int(workers), 1) + 1).astype(int).tolist()

        def extents(first: int, end: int) -> None:
            sc = Scratch()
            for lo in range(first, end, MAX_READ_LINES):
                hi = min(lo + MAX_READ_LINES, end)
                _line_extents(sc.read_lines("igm", raster, lo, hi), per_line[lo:hi])

        with ThreadPoolExecutor(len(parts) - 1, thread_name_prefix="sisa-index") as pool:
            for done in [pool.submit(extents, a, b) for a, b in itertools.pairwise(parts)]:
                done.result()
        far = _far_positions(raster, per_line, block_lines)
        starts = np.arange(0, max(raster.lines - 1, 1), block_lines)
        boxes = np.empty((starts.size, 4))
        boxes[:, :2] = np.fmin.reduceat(per_line[:, :2], starts, axis=0)
        boxes[:, 2:] = np.fmax.reduceat(per_line[:, 2:], starts, axis=0)
        nxt = np.minimum(starts + block_lines, raster.lines - 1)  # last line of each block
        boxes[:, :2] = np.fmin(boxes[:, :2], per_line[nxt, :2])
        boxes[:, 2:] = np.fmax(boxes[:, 2:], per_line[nxt, 2:])
        return cls(raster, block_lines, boxes, far)

    @property
    def bounds_m(self) -> tuple[float, float, float, float]:
        b = self.boxes_m
        if not np.isfinite(b).any():
            raise InputError(f"{self.raster.path}: no finite position in the IGM")
        return (float(np.nanmin(b[:, 0])), float(np.nanmin(b[:, 1])),
                float(np.nanmax(b[:, 2])), float(np.nanmax(b[:, 3])))

    def _hits(self, west: float, south: float, east: float, north: float) -> B:
        b = self.boxes_m
        with np.errstate(invalid="ignore"):
            hit: B = ((b[:, 2] >= west) & (b[:, 0] <= east) & (b[:, 3] >= south)
                      & (b[:, 1] <= north))
        return hit

    def cell_extent(self, grid: OrthoGrid, row0: int, col0: int, rows: int, cols: int,
                    snap: int = 1) -> tuple[int, int, int, int] | None:
        """The part (row0, col0, rows, cols) of a window that the swath can reach, its start
        snapped down and its end up to multiples of `snap` within the window; None if none."""
        x0, y0 = float(grid.centre_x_m(col0)), float(grid.centre_y_m(row0))
        b = self.boxes_m[self._hits(x0, y0 - (rows - 1) * grid.cell_m,
                                    x0 + (cols - 1) * grid.cell_m, y0)]
        if b.shape[0] == 0:
            return None
        c_lo = math.floor((float(b[:, 0].min()) - grid.west_m) / grid.cell_m - 0.5)
        c_hi = math.ceil((float(b[:, 2].max()) - grid.west_m) / grid.cell_m - 0.5) + 1
        r_lo = math.floor((grid.north_m - float(b[:, 3].max())) / grid.cell_m - 0.5)
        r_hi = math.ceil((grid.north_m - float(b[:, 1].min())) / grid.cell_m - 0.5) + 1
        r_lo, c_lo = max(r_lo // snap * snap, row0), max(c_lo // snap * snap, col0)
        r_hi = min(-(-r_hi // snap) * snap, row0 + rows)
        c_hi = min(-(-c_hi // snap) * snap, col0 + cols)
        if r_lo >= r_hi or c_lo >= c_hi:
            return None
        return r_lo, c_lo, r_hi - r_lo, c_hi - c_lo

    def quad_runs(self, west: float, south: float, east: float, north: float
                  ) -> list[tuple[int, int]]:
        """[first, end) ranges of quad lines whose blocks' boxes meet the given extent."""
        blocks = np.flatnonzero(self._hits(west, south, east, north))
        if blocks.size == 0:
            return []
        breaks = np.flatnonzero(np.diff(blocks) > 1)
        firsts = np.concatenate([blocks[:1], blocks[breaks + 1]])
        lasts = np.concatenate([blocks[breaks], blocks[-1:]])
        end_line = self.raster.lines - 1
        runs = []
        for f, la in zip(firsts, lasts, strict=True):
            q0, q1 = int(f) * self.block_lines, min((int(la) + 1) * self.block_lines, end_line)
            runs += [(a, min(a + MAX_READ_LINES, q1)) for a in range(q0, q1, MAX_READ_LINES)]
        return runs


def _far_lines(per_line: F64, block_lines: int) -> tuple[I64, B, F64, float]:
    """Lines holding a position far from the rest, from the lines' extents (west, south, east,
    north; O(lines), no pass over the pixels): a line wider than FAR_WIDTHS line widths (the
    median of the lines' extents) holds a pixel that far from the rest of it; a line whose
    centre lies that far from the median of the centres of its block of lines and the blocks
    either side is off as a whole (a zeroed sector: easting 0). A flight's lines follow each
    other, so neither happens to an IGM undamaged. Returns the lines, whether each is wide
    (else off as a whole), their distances and the limit (metres); none where the lines have
    no extent (one pixel each, all at one place)."""
    w, s, e, n = per_line.T
    lines = per_line.shape[0]
    size = np.fmax(e - w, n - s)
    centre = np.stack([(w + e) / 2, (s + n) / 2], axis=1)
    step = np.hypot(*np.diff(centre, axis=0).T)
    width, advance = (float(np.median(v[np.isfinite(v)])) if np.isfinite(v).any() else 0.0
                      for v in (size, step))
    # one-pixel lines have no width: the way along three blocks then sets the scale
    limit = FAR_WIDTHS * max(width, 3 * block_lines * advance)
    if not (math.isfinite(limit) and limit > 0):
        return np.empty(0, np.int64), np.empty(0, np.bool_), np.empty(0), 0.0
    blocks = -(-lines // block_lines)
    c = np.full((blocks + 2, block_lines, 2), np.nan)
    c.reshape(-1, 2)[block_lines:block_lines + lines] = centre
    around = np.concatenate([c[:-2], c[1:-1], c[2:]], axis=1)  # (blocks, 3 blocks, 2)
    ranked = np.sort(around, axis=1)  # NaN last
    k = np.isfinite(around).sum(axis=1, keepdims=True)
    mid = (np.take_along_axis(ranked, np.maximum((k - 1) // 2, 0), axis=1)
           + np.take_along_axis(ranked, k // 2, axis=1))[:, 0] / 2  # k = 0: NaN, as no line
    ref = np.repeat(mid, block_lines, axis=0)[:lines]
    off = np.hypot(*(centre - ref).T)
    with np.errstate(invalid="ignore"):
        wide, away = size > limit, off > limit
    found = np.flatnonzero(wide | away)
    return found, wide[found], np.where(wide, size, off)[found], limit


def _far_positions(raster: EnviRaster, per_line: F64, block_lines: int
                   ) -> FarPositions | None:
    """The positions far from the rest of the IGM (see _far_lines), None if none; the extents
    of their lines (per_line) are made again without them."""
    found, wide, dist, limit = _far_lines(per_line, block_lines)
    if found.size == 0:
        return None
    hits, first = [], ""
    for line, is_wide, d in zip(found.tolist(), wide.tolist(), dist.tolist(), strict=True):
        blk = np.array(raster.read_lines(line, line + 1), dtype=np.float64)
        x, y = blk[0, 0], blk[0, 1]
        ok = np.isfinite(x) & np.isfinite(y)
        if is_wide:  # a pixel more than half the limit from the line's median: see _far_lines
            with np.errstate(invalid="ignore"):
                gone = np.hypot(x - np.median(x[ok]), y - np.median(y[ok]))
                pixels = np.flatnonzero(ok & (gone > limit / 2))  # an infinity: refused later
            worst = int(pixels[np.argmax(gone[pixels])])
            said = (f"IGM line {line}, pixel {worst} lies {_distance(float(gone[worst]))} from "
                    "the rest of its line")
        else:
            pixels = np.flatnonzero(ok)
            said = f"IGM line {line} lies {_distance(d)} from the lines around it"
        first = first or said
        hits.append(np.stack([np.full(pixels.size, line), pixels], axis=1))
        blk[0, :, pixels] = np.nan
        _line_extents(blk, per_line[line:line + 1])
    return FarPositions(np.concatenate(hits).astype(np.int64), first)


def _distance(m: float) -> str:
    return f"{m / 1000:.0f} km" if m >= 10_000 else f"{m:.0f} m"


def _line_extents(blk: npt.NDArray[Any], out: F64) -> None:
    """out (lines, 4): west, south, east, north of each line of an IGM block (lines, 3,
    pixels) over its pixels with a finite position (NaN where none), in one pass."""
    b = np.ascontiguousarray(blk, np.float64)
    _check_out(out, np.float64, (b.shape[0], 4))
    _C.line_extents(b.ctypes.data, *b.shape, out.ctypes.data)


# -- the nearest pixel of every cell of a tile -----------------------------------------------

class Scratch:
    """Arrays reused from window to window: a fresh large array costs a page fault per 4 KB
    touched, more than the work done in it."""

    def __init__(self) -> None:
        self._bufs: dict[str, npt.NDArray[Any]] = {}
        self._maps: dict[str, mmap.mmap | None] = {}

    def get(self, name: str, shape: tuple[int, ...], dtype: npt.DTypeLike,
            fill: float | None = None) -> npt.NDArray[Any]:
        size = math.prod(shape)
        buf = self._bufs.get(name)
        if buf is None or buf.size < size or buf.dtype != np.dtype(dtype):
            buf = self._bufs[name] = np.empty(size, dtype=dtype)
        arr = buf[:size].reshape(shape)
        if fill is not None:
            arr.fill(fill)
        return arr

    def planes(self, name: str, shape: tuple[int, int, int], dtype: npt.DTypeLike,
               fill: float | None = None) -> npt.NDArray[Any]:
        """A (bands, rows, cols) array whose bands lie PLANE_PAD_BYTES more than a multiple
        of 4 KB apart: writing a cell's value into every band otherwise hits one cache set
        per band at once (windows are multiples of TIFF_BLOCK cells), several times slower."""
        bands, rows, cols = shape
        item = np.dtype(dtype).itemsize
        plane = rows * cols + (-rows * cols * item % 4096 + PLANE_PAD_BYTES) // item
        arr = self.get(name, (bands, plane), dtype)[:, :rows * cols].reshape(shape)
        if fill is not None:
            arr.fill(fill)
        return arr

    def read_lines(self, name: str, raster: EnviRaster, line0: int, line1: int
                   ) -> npt.NDArray[Any]:
        """raster.read_lines(line0, line1), read-only, as a view of the file mapped into memory
        when the file is BIL in native byte order: no copy of the page cache into a buffer
        (an IGM's heights, a third of it, are then never touched), valid until the next read
        of this name; anything else, and errors, are read_lines' own."""
        if raster.interleave != "bil" or not raster.dtype.isnative or \
                not 0 <= line0 < line1 <= raster.lines:
            return raster.read_lines(line0, line1)
        start = raster.header_offset + line0 * raster.line_bytes
        length = (line1 - line0) * raster.line_bytes
        skip = start % mmap.ALLOCATIONGRANULARITY
        with raster.path.open("rb", buffering=0) as fh:
            if os.fstat(fh.fileno()).st_size < start + length:  # cut since it was opened
                raise InputError(f"{raster.path}: truncated while reading")
            self._maps[name] = None  # the last mapping of this name goes with its arrays
            mapped = mmap.mmap(fh.fileno(), skip + length, offset=start - skip,
                               access=mmap.ACCESS_READ)
        self._maps[name] = mapped
        out = np.frombuffer(mapped, raster.dtype, (line1 - line0) * raster.bands
                            * raster.pixels, skip)
        return out.reshape(line1 - line0, raster.bands, raster.pixels)


@dataclass(frozen=True)
class TileChoice:
    """For each cell of a tile: the chosen input pixel (-1 where none), its squared distance
    to the cell centre in cell units², and whether it lies inside the cell."""

    line: I32
    pixel: I32
    d2_cells: F64
    inside: B

    @property
    def valid(self) -> B:
        return self.line >= 0


def nearest_pixels(index: SwathIndex, grid: OrthoGrid, row0: int, col0: int, rows: int,
                   cols: int, scratch: Scratch | None = None) -> TileChoice:
    """The nearest input pixel of every cell of the window (rows × cols at row0, col0); with
    `scratch`, the arrays are overwritten by the next call."""
    sc = scratch or Scratch()
    d2 = sc.get("d2", (rows, cols), np.float64, np.inf)
    line = sc.get("line", (rows, cols), np.int32, -1)
    pixel = sc.get("pixel", (rows, cols), np.int32, -1)
    inside = sc.get("inside", (rows, cols), np.bool_, False)
    x0, y0 = float(grid.centre_x_m(col0)), float(grid.centre_y_m(row0))
    x1, y1 = x0 + (cols - 1) * grid.cell_m, y0 - (rows - 1) * grid.cell_m
    for q0, q1 in index.quad_runs(x0, y1, x1, y0):
        lo = max(q0 - DESCENT_MARGIN_LINES, 0)
        hi = min(q1 + 1 + DESCENT_MARGIN_LINES, index.raster.lines)
        blk = sc.read_lines("igm", index.raster, lo, hi)
        if index.far is not None:
            blk = np.array(blk)  # the file's view is read-only
            index.far.void(blk, lo)
        u = sc.get("u", (hi - lo, blk.shape[2]), np.float64)
        v = sc.get("v", (hi - lo, blk.shape[2]), np.float64)
        box = sc.get("box", (hi - lo, 4), np.float64)
        gap = sc.get("gap", (hi - lo, blk.shape[2]), np.float64)
        _to_cells(blk, x0, y0, float(grid.cell_m), u, v, box)
        # an infinity (the kernels take any value but NaN for a position) shows in the lines'
        # extents: umin or vmin -inf, umax or vmax +inf; no pass over the pixels
        if np.isneginf(box[:, 0::2]).any() or np.isposinf(box[:, 1::2]).any():
            raise _infinite(index.raster, blk, lo)
        _gaps(u, v, gap)
        _rasterise(u, v, box, gap, q0 - lo, q1 - lo, lo, d2, line, pixel, inside)
    return TileChoice(line, pixel, d2, inside)


def _infinite(raster: EnviRaster, blk: npt.NDArray[Any], line0: int) -> InputError:
    """The error for an IGM holding an infinity (blk: its lines from line0 on): damage, or a
    foreign file; NaN is an IGM's 'no position', an infinity no position at all."""
    line, band, pixel = (int(i) for i in np.argwhere(np.isinf(blk[:, :2]))[0])
    return InputError(f"{raster.path}: IGM line {line0 + line}, pixel {pixel}: "
                      f"{('easting', 'northing')[band]} {blk[line, band, pixel]}: not a position "
                      "(NaN marks a pixel without one): a damaged IGM?")


def _to_cells(blk: npt.NDArray[Any], x0: float, y0: float, cell: float, u: F64, v: F64,
              box: F64) -> None:
    """u, v (lines, pixels): positions of the IGM block (lines, 3, pixels) in cell units
    (column and row of the window's cell centres: (x - x0) / cell, (y0 - y) / cell), in one
    pass without temporaries; box: each line's umin, umax, vmin, vmax over its non-NaN values
    (+inf, -inf where it has none)."""
    b = np.ascontiguousarray(blk, np.float64)
    lines, _, pixels = b.shape
    for a in (u, v):
        _check_out(a, np.float64, (lines, pixels))
    _check_out(box, np.float64, (lines, 4))
    _C.to_cells(b.ctypes.data, *b.shape, x0, y0, cell, u.ctypes.data, v.ctypes.data,
                box.ctypes.data)


def _gaps(u: F64, v: F64, gap: F64) -> None:
    """gap[i, j]: squared distance from pixel (i, j) to the nearest other pixel of its descent
    neighbourhood (±DESCENT_LINES, ±DESCENT_PIXELS); inf where there is none. By the triangle
    inequality, no neighbour is nearer than pixel (i, j) to a point within sqrt(gap) / 2 of
    it: the descent from there can be skipped (one pass, each pair once, instead of a search
    per cell)."""
    _check_in(u, v, dtype=np.float64)
    _check_out(gap, np.float64, u.shape)
    _C.gaps(u.ctypes.data, v.ctypes.data, *u.shape, DESCENT_LINES, DESCENT_PIXELS,
            gap.ctypes.data)


def _rasterise(u: F64, v: F64, box: F64, gap: F64, q0: int, q1: int, line_base: int,
               d2: F64, line: I32, pixel: I32, inside: B) -> None:
    """Rasterise quads with first line q0..q1-1 of the block (u, v: positions in cell units,
    column and row of the window's cell centres; box: each line's u/v extent) and keep each
    cell's nearest pixel. Corners in ring order a (i, j), b (i, j+1), c (i+1, j+1),
    d (i+1, j): all valid, triangles abc + acd; one missing, the triangle of the other three.
    A cell centre on a shared edge (within 1e-9 of the doubled area) is in both triangles, so
    there are no cracks. The cell takes the nearest of the quad's corners (squared distance,
    NaN as inf); where a neighbour could be nearer (gap <= GAP_FACTOR · d²), a descent moves
    to the nearest pixel within ±DESCENT_LINES lines and ±DESCENT_PIXELS pixels while that
    gets closer (turbulence can make lines cross, so it looks beyond the next one; at most
    64 steps). A cell keeps the first strictly nearest pixel found, `inside` when its centre
    is within half a cell of the pixel in u and v."""
    _check_in(u, v, gap, dtype=np.float64)
    _check_in(box, dtype=np.float64)
    if box.shape != (u.shape[0], 4) or gap.shape != u.shape:
        raise ValueError("box (lines, 4) and gap (lines, pixels) must match u")
    _check_out(d2, np.float64, d2.shape)
    _check_out(line, np.int32, d2.shape)
    _check_out(pixel, np.int32, d2.shape)
    _check_out(inside, np.bool_, d2.shape)
    _C.rasterise(u.ctypes.data, v.ctypes.data, box.ctypes.data, gap.ctypes.data, *u.shape,
                 q0, q1, line_base, *d2.shape, DESCENT_LINES, DESCENT_PIXELS, GAP_FACTOR,
                 d2.ctypes.data, line.ctypes.data, pixel.ctypes.data, inside.ctypes.data)


# -- reading the chosen pixels of the image --------------------------------------------------

def _chunk_spans(line: npt.NDArray[np.integer[Any]], valid: B, chunk_lines: int) -> I64:
    """(chunks, 2): the first and last line needed by the valid cells in each chunk of
    `chunk_lines` image lines, from the chunk of the first such line to that of the last
    (first > last where a chunk has none); (0, 2) without a valid cell."""
    lines = np.ascontiguousarray(line, np.int32)
    ok = np.ascontiguousarray(valid, np.bool_)
    if ok.shape != lines.shape:
        raise ValueError("line and valid must have one shape")
    first, last = ctypes.c_int64(), ctypes.c_int64()
    _C.line_range(lines.ctypes.data, ok.ctypes.data, lines.size, ctypes.byref(first),
                  ctypes.byref(last))
    if last.value < 0:
        return np.empty((0, 2), np.int64)
    k0 = first.value // chunk_lines
    spans = np.empty((last.value // chunk_lines - k0 + 1, 2), np.int64)
    spans[:, 0], spans[:, 1] = last.value + 1, -1
    _C.chunk_spans(lines.ctypes.data, ok.ctypes.data, lines.size, chunk_lines, k0,
                   spans.ctypes.data)
    return spans


def _copy_pixels(block: npt.NDArray[Any], lo: int, line: npt.NDArray[np.integer[Any]],
                 pixel: npt.NDArray[np.integer[Any]], valid: B, out: npt.NDArray[Any]) -> None:
    """out[b, c] = block[line[c] - lo, b, pixel[c]] for the valid cells c whose line is in the
    block (lines, bands, pixels), cell by cell, every band; out (bands, cells) may have its
    bands apart (see Scratch.planes: they should not lie a multiple of 4 KB apart)."""
    item = out.dtype.itemsize
    # numpy may give an axis of length 1 any stride (a one-cell window): only longer ones count
    if (out.ndim != 2 or not out.flags.writeable or (out.shape[1] > 1 and out.strides[1] != item)
            or (out.shape[0] > 1 and out.strides[0] % item) or not out.dtype.isnative):
        raise ValueError("out must be a writable (bands, cells) array of native values, "
                         "cells contiguous")
    src = np.ascontiguousarray(block, out.dtype)  # the image's byte order to the machine's
    lines, bands, pixels = src.shape
    cell_line, cell_pixel = (np.ascontiguousarray(a, np.int32) for a in (line, pixel))
    ok = np.ascontiguousarray(valid, np.bool_)
    if bands != out.shape[0] or not cell_line.size == cell_pixel.size == ok.size \
            == out.shape[1]:
        raise ValueError("block, cells and out do not match")
    _C.copy_pixels(src.ctypes.data, lo, lines, bands, pixels, item, cell_line.ctypes.data,
                   cell_pixel.ctypes.data, ok.ctypes.data, ok.size, out.ctypes.data,
                   out.strides[0] // item)


def gather_pixels(raw: EnviRaster, line: npt.NDArray[np.integer[Any]],
                  pixel: npt.NDArray[np.integer[Any]], valid: B, fill: float,
                  scratch: Scratch | None = None, into: npt.NDArray[Any] | None = None
                  ) -> npt.NDArray[Any]:
    """(bands, rows, cols): the image's value at (line, pixel) where valid, else `fill` (or,
    with `into`, what `into` held); the image is read by chunks of lines, only where some
    cell needs them."""
    rows, cols = line.shape
    sc = scratch or Scratch()
    if into is None:
        into = sc.planes("pixels", (raw.bands, rows, cols), raw.dtype.newbyteorder("="), fill)
    out = np.reshape(into, (raw.bands, rows * cols), copy=False)
    cell_line, cell_pixel, cell_ok = line.ravel(), pixel.ravel(), valid.ravel()
    for lo, last in _chunk_spans(cell_line, cell_ok, RAW_CHUNK_LINES).tolist():
        if last >= lo:
            _copy_pixels(sc.read_lines("raw", raw, lo, last + 1), lo, cell_line, cell_pixel,
                         cell_ok, out)
    return out.reshape(raw.bands, rows, cols)


def output_nodata(raw: EnviRaster) -> float:
    """The image's own ignore value when it has one (SISA's scanner: 0), else 0 or NaN. A
    float image declaring 0 keeps 0: its zeros are not data by its own header."""
    if raw.nodata is not None:
        return raw.nodata
    return math.nan if raw.dtype.kind == "f" else 0.0


# -- the output files ------------------------------------------------------------------------

class TiffWriter:
    """A tiled, DEFLATE-compressed GeoTIFF written window by window under a temporary name,
    renamed into place by `close()`. Blocks without data are not written: GDAL fills them
    with nodata when it closes the file.

    Writing (compression) runs in a background thread while the next window is computed:
    `write()` first waits for the previous write, so a caller may reuse the arrays it passed
    once the following `write()` has returned.

    Band-interleaved, horizontal predictor, DEFLATE level 1: on imagery with sensor noise
    the higher levels shrink the file by a few per cent at several times the time.
    `compress` "none" is for timing the resampling alone: blocks left unwritten stay empty in
    the file (SPARSE_OK; GDAL reads them as nodata) instead of being written as zeros."""

    def __init__(self, path: Path, grid: OrthoGrid, raw: EnviRaster, nodata: float,
                 description: str, compress: str = "deflate",
                 bands: Sequence[int] | None = None) -> None:
        """`bands`: the image's bands (0-based) to write, in this order (default: all)."""
        self._bands = None if bands is None else list(bands)
        if compress not in TIFF_COMPRESSIONS:
            raise InputError(f"GeoTIFF compression {compress!r}: use one of "
                             f"{', '.join(TIFF_COMPRESSIONS)}")
        self.path = Path(path)
        # GDAL creates the file new, in a hidden folder of ours (see private_partial: a 600 MB
        # GeoTIFF opened over a placeholder was written out to disk in its close, 0.06 s)
        self._dir, self._tmp = private_partial(self.path)
        kind = np.dtype(raw.dtype.name).kind
        packing: dict[str, Any] = {"compress": compress}
        if compress != "none":
            packing["predictor"] = 3 if kind == "f" else 2
        if compress == "deflate":
            packing["zlevel"] = TIFF_ZLEVEL
        if compress == "zstd":
            packing["zstd_level"] = TIFF_ZSTD_LEVEL
        if compress == "none":
            packing["sparse_ok"] = True
        try:
            self._ds = rasterio.open(
                self._tmp, "w", driver="GTiff", width=grid.width, height=grid.height,
                count=raw.bands if self._bands is None else len(self._bands),
                dtype=raw.dtype.name, crs=f"EPSG:{grid.epsg}",
                transform=grid.transform, nodata=nodata, tiled=True, blockxsize=TIFF_BLOCK,
                blockysize=TIFF_BLOCK, interleave="band", bigtiff="IF_SAFER",
                # spectral bands, not colours: GDAL makes 3 or 4 bytes bands RGB(A) by default,
                # the 4th then an alpha mask over the data (found by a bad-input sweep)
                photometric="MINISBLACK", num_threads="ALL_CPUS", **packing)
        except RasterioIOError as exc:  # a grid GDAL cannot hold, a folder it cannot write
            shutil.rmtree(self._dir, ignore_errors=True)
            raise InputError(f"{self.path}: GDAL cannot create a {grid.width} x {grid.height} "
                             f"GeoTIFF of {raw.bands} bands: "
                             f"{str(exc).replace(str(self._tmp), str(self.path))}") from None
        self._ds.update_tags(AREA_OR_POINT="Area", TIFFTAG_IMAGEDESCRIPTION=description)
        labels = band_labels(raw)
        for k, b in enumerate(range(raw.bands) if self._bands is None else self._bands):
            self._ds.set_band_description(k + 1, labels[b])
            wl = raw.wavelengths_nm[b]
            if wl is not None:
                self._ds.update_tags(k + 1, wavelength=f"{wl:g}", wavelength_units="Nanometers")
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sisa-tiff")
        self._pending: Future[None] | None = None

    def write(self, data: npt.NDArray[Any], row0: int, col0: int, valid: B) -> None:
        """Queue the window's blocks that hold data (`valid`: the window's cells)."""
        self._wait()
        self._pending = self._pool.submit(self._write, data, row0, col0, valid)

    def _wait(self) -> None:
        if self._pending is not None:
            pending, self._pending = self._pending, None
            pending.result()

    def _write(self, data: npt.NDArray[Any], row0: int, col0: int, valid: B) -> None:
        rows, cols = valid.shape
        if self._bands is not None:
            data = data[self._bands]
        if row0 % TIFF_BLOCK or col0 % TIFF_BLOCK:
            self._ds.write(data, window=Window(col0, row0, cols, rows))
            return
        for r in range(0, rows, TIFF_BLOCK):
            for c in range(0, cols, TIFF_BLOCK):
                if valid[r:r + TIFF_BLOCK, c:c + TIFF_BLOCK].any():
                    blk = data[:, r:r + TIFF_BLOCK, c:c + TIFF_BLOCK]
                    self._ds.write(blk, window=Window(col0 + c, row0 + r, blk.shape[2],
                                                      blk.shape[1]))

    def close(self) -> None:
        """Finish the last write, close and rename into place (or drop it all on error)."""
        try:
            self._wait()
            self._pool.shutdown()
            self._ds.close()
            raise_if_stopped()  # never put in place after a stop, even one C code lost
        except BaseException:
            self.abort()
            raise
        try:
            replace_file(self._tmp, self.path)
        finally:
            shutil.rmtree(self._dir, ignore_errors=True)

    def abort(self) -> None:
        try:
            with contextlib.suppress(Exception):  # the error being handled is the caller's
                self._wait()
        finally:
            self._pool.shutdown()
            self._ds.close()
            shutil.rmtree(self._dir, ignore_errors=True)


class GltWriter:
    """The GLT as ENVI BIL int32 (band 1 sample, band 2 line, 1-based), written tile by tile
    into a zero-filled file (0 = no input pixel) and renamed into place by `close()`."""

    def __init__(self, stem: Path, grid: OrthoGrid, image_name: str, ortho_name: str) -> None:
        self.path, self.grid = Path(f"{stem}.bil"), grid
        self.image_name, self.ortho_name = image_name, ortho_name
        self._tmp, fd = create_partial(self.path)
        self._fd: int | None = fd
        try:
            os.ftruncate(self._fd, grid.height * 2 * grid.width * 4)
        except OSError as exc:  # EFBIG: a grid beyond what the file system holds
            self.abort()
            raise InputError(f"{self.path}: a GLT of {grid.width} x {grid.height} cells "
                             f"cannot be created: {exc.strerror or exc}") from None

    def write_window(self, row0: int, col0: int, values: I32) -> None:
        """values (rows, 2, cols): sample and line of the window, as the GLT holds them."""
        if self._fd is None:
            raise InputError(f"{self.path}: GLT writer already closed")
        data = np.ascontiguousarray(values, dtype="<i4")  # the file's order, whatever the host's
        rows, bands, cols = data.shape
        g = self.grid
        if bands != 2 or not (0 <= row0 <= g.height - rows and 0 <= col0 <= g.width - cols):
            raise ValueError(f"GLT window {data.shape} at ({row0}, {col0}) outside the "
                             f"{g.height} x {g.width} grid")
        # the row loop and its writes in C: two small writes a row, ~40 000 for a 20 000-line
        # strip, cost a Python loop ~0.1 s and held the GIL the other window needs
        err = _C.write_glt_rows(self._fd, data.ctypes.data, rows, cols, g.width, row0, col0)
        if err:
            raise OSError(err, os.strerror(err), str(self._tmp))

    def close(self) -> None:
        if self._fd is None:
            return
        os.close(self._fd)
        self._fd = None
        commit_envi(self._tmp, self.path, self.header_text())

    def abort(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
        self._tmp.unlink(missing_ok=True)

    def header_text(self) -> str:
        g = self.grid
        desc = (f"SISA GLT (geographic lookup table) of {self.image_name} for "
                f"{self.ortho_name}: for every output cell, the 1-based sample (band 1) and "
                "line (band 2) of the input pixel whose pixel-centre ground position is "
                "nearest to the cell centre. 0 = no input pixel (the cell centre is outside "
                "the swath). Negative = that nearest pixel lies outside the cell, which is "
                "filled from it (ENVI's infill convention): use the absolute value.")
        return envi_header_text(
            description=desc, samples=g.width, lines=g.height, bands=2, dtype=np.int32,
            fields=[("band names", envi_list(GLT_BAND_NAMES)),
                    ("map info", envi_map_info(g)),
                    ("coordinate system string", coordinate_system_string(
                        projected_crs(g.epsg))),
                    ("data ignore value", "0")])


def envi_map_info(grid: OrthoGrid) -> str:
    """ENVI `map info`: pixel (1, 1) is the upper-left corner of the upper-left cell."""
    crs = projected_crs(grid.epsg)
    head = f"1, 1, {grid.west_m!r}, {grid.north_m!r}, {grid.cell_m!r}, {grid.cell_m!r}"
    if 32601 <= grid.epsg <= 32660 or 32701 <= grid.epsg <= 32760:
        hemi = "North" if grid.epsg < 32700 else "South"
        return f"{{UTM, {head}, {grid.epsg % 100}, {hemi}, WGS-84, units=Meters}}"
    return f"{{{crs_name(crs).replace(',', ' ')}, {head}, units=Meters}}"


# -- orthorectify one segment ----------------------------------------------------------------

@dataclass(frozen=True)
class OrthoResult:
    cells: int
    cells_filled: int
    cells_infill: int  # filled from a pixel outside the cell (negative in the GLT)
    mean_distance_m: float  # cell centre → ground position of the chosen pixel
    max_distance_m: float


def common_lines(index: SwathIndex, raw: EnviRaster) -> tuple[SwathIndex, EnviRaster]:
    """The IGM and the image over the lines both files hold, when their headers agree and one
    (or both) is cut short (a copy or a recording interrupted): the lines past the cut are
    left out with a warning naming them; both holding as many lines, a header that declares
    more is said cut short too. Otherwise the pair as given (check_pair judges it)."""
    g = index.raster
    if g.lines == raw.lines and g.pixels == raw.pixels:  # nothing to leave out; one header
        for cut, other in ((g, raw), (raw, g)):  # may still declare lines neither file holds
            if cut.cut_short and cut.header_lines != other.header_lines:
                warnings.warn(CutShortWarning(
                    f"{cut.cut_short_text(cut.path)}; {other.path} holds as many, and all of "
                    "them are mapped"), stacklevel=3)
        return index, raw
    if g.pixels != raw.pixels or g.header_lines != raw.header_lines:
        return index, raw
    lines = min(g.lines, raw.lines)
    for cut in (g, raw):
        if cut.cut_short:
            warnings.warn(CutShortWarning(
                f"{cut.cut_short_text(cut.path)}: lines {lines}-{cut.header_lines - 1} are not "
                "mapped"), stacklevel=3)
    if g.lines > lines:
        index = SwathIndex.build(g.path, index.block_lines, lines=lines)
    return index, dataclasses.replace(raw, lines=lines)


def check_pair(index: SwathIndex, raw: EnviRaster, epsg: int) -> None:
    g = index.raster
    if (g.lines, g.pixels) != (raw.lines, raw.pixels):
        raise InputError(f"{g.path}: IGM is {g.lines} x {g.pixels}, the image {raw.path} "
                         f"{raw.lines} x {raw.pixels}")
    code = igm_epsg(g.path)
    if code is not None and code != epsg:
        raise InputError(f"{g.path}: IGM is in EPSG:{code}, the grid in EPSG:{epsg}")


def window_cells(raw: EnviRaster) -> int:
    """Cells per work window so that its values and buffers stay near WINDOW_BYTES."""
    per_cell = raw.bands * raw.dtype.itemsize + 32  # + choice buffers and the GLT
    return max(WINDOW_BYTES // per_cell, TIFF_BLOCK * TIFF_BLOCK)


def _glt_values(line: I32, pixel: I32, inside: B, d2: F64, out: I32
                ) -> tuple[int, int, float, float]:
    """Fill out (rows, 2, cols) with the signed 1-based GLT; return (filled, infill,
    sum of distances, max distance) in cell units."""
    _check_in(line, pixel, dtype=np.int32)
    _check_in(inside, dtype=np.bool_)
    _check_in(d2, dtype=np.float64)
    rows, cols = line.shape
    _check_out(out, np.int32, (rows, 2, cols))
    figures = np.empty(4)
    _C.glt_values(line.ctypes.data, pixel.ctypes.data, inside.ctypes.data, d2.ctypes.data,
                  rows, cols, out.ctypes.data, figures.ctypes.data)
    return int(figures[0]), int(figures[1]), float(figures[2]), float(figures[3])


Progress = Callable[[int], None]  # told a count of work just done (lines, grid cells)


def orthorectify(igm: Path | SwathIndex, image: Path | EnviRaster, grid: OrthoGrid,
                 out_tif: Path, glt_stem: Path | None, *, tile_cells: int | None = None,
                 compress: str = "deflate", workers: int = WORKERS,
                 progress: Progress | None = None, on_total: Progress | None = None,
                 empty_ok: bool = True, bands: Sequence[int] | None = None,
                 resampling: Resampling = Resampling.NEAREST) -> OrthoResult:
    """Write `out_tif` (every band of `image`, its data type, nodata outside the swath) and,
    unless `glt_stem` is None, `<glt_stem>.bil/.hdr`; each appears only when complete. `igm`:
    the IGM file, or its SwathIndex when the caller built one for the grid's bounds (one pass
    over the IGM, not two); `image`: the image file, or the EnviRaster its caller opened (and
    perhaps cut to the IGM's lines with common_lines). `tile_cells` forces square work tiles
    of that side (default: windows sized by WINDOW_BYTES); `workers`: windows computed at once
    (the products do not depend on it). `on_total` is told how many cells the swath can reach
    (the windows to map), `progress` how many of them each finished window held. Without
    `empty_ok`, a grid on which no cell is filled is an InputError, nothing written. Positions
    far from the rest of the IGM (SwathIndex.far) are mapped as none, with a warning.
    `bands`: the image's bands (0-based) the GeoTIFF holds, in this order (default: all).
    `resampling`: the nearest pixel (default), or the image interpolated bilinearly or by
    cubic convolution at the cell centre's fractional image position (the GLT stays the
    nearest pixel's; postproc.products.resample)."""
    out_tif = Path(out_tif)
    glt_files = () if glt_stem is None else (Path(f"{glt_stem}.bil"), Path(f"{glt_stem}.hdr"))
    for path in (out_tif, *glt_files):  # found at the end: a traceback beside finished products
        if path.is_dir():
            raise InputError(f"{path} is a folder, in the way of a product")
    index = igm if isinstance(igm, SwathIndex) else SwathIndex.build(Path(igm))
    raw = image if isinstance(image, EnviRaster) else EnviRaster.open(Path(image))
    index, raw = common_lines(index, raw)
    check_pair(index, raw, grid.epsg)
    if index.far is not None:
        warnings.warn(FarPositionWarning(f"{index.raster.path}: {index.far.text}: mapped as no "
                                         "position (a damaged IGM?)"), stacklevel=2)
    w, s, e, n = index.bounds_m
    gw, gs, ge, gn = grid.bounds_m
    if not (w < ge and gw < e and s < gn and gs < n):
        raise InputError(f"the grid ({gw:.0f}, {gs:.0f}, {ge:.0f}, {gn:.0f}) does not overlap "
                         f"the image's ground ({w:.0f}, {s:.0f}, {e:.0f}, {n:.0f}): nothing "
                         "to map")
    nodata = output_nodata(raw)
    desc = (f"SISA ortho of {raw.path.name}: each cell holds the input pixel whose "
            "pixel-centre ground position (IGM) is nearest to the cell centre")
    if resampling is not Resampling.NEAREST:
        desc = (f"SISA ortho of {raw.path.name}: each cell holds the image interpolated "
                f"({resampling.value}) at the cell centre's position in the image, from the "
                "IGM's pixel-centre ground positions")
    with rasterio.Env(GDAL_CACHEMAX=GDAL_CACHE_MB):
        if bands is not None and not all(0 <= b < raw.bands for b in bands):
            raise InputError(f"{raw.path}: bands {', '.join(str(b + 1) for b in bands)}: the "
                             f"image has bands 1 to {raw.bands}")
        tif = TiffWriter(out_tif, grid, raw, nodata, desc, compress, bands)
        glt: GltWriter | None = None
        try:
            if glt_stem is not None:
                glt = GltWriter(Path(glt_stem), grid, raw.path.name, out_tif.name)
            filled, infill, dist_sum, dist_max = _ortho_windows(
                index, raw, grid, nodata, tif, glt, tile_cells, max(int(workers), 1),
                progress, on_total, resampling)
            if filled == 0 and not empty_ok:
                raise _nothing_filled(index, grid)
            tif.close()
        except BaseException:
            tif.abort()
            if glt is not None:
                glt.abort()
            raise
        if glt is not None:
            glt.close()
    return OrthoResult(grid.width * grid.height, filled, infill,
                       dist_sum / filled if filled else math.nan, dist_max)


def _nothing_filled(index: SwathIndex, grid: OrthoGrid) -> InputError:
    """The error for a grid on which no cell is filled: on a grid holding the IGM's whole
    extent, no cell centre lies in any quad of neighbouring pixels (an IGM whose lines are all
    one: an ortho of nodata and 'mean distance nan m' before); else the grid misses the
    swath, its bounding box only."""
    w, s, e, n = index.bounds_m
    gw, gs, ge, gn = grid.bounds_m
    if gw <= w and gs <= s and e <= ge and n <= gn:
        return InputError(f"{index.raster.path}: no cell of the grid lies between neighbouring "
                          "pixels of the IGM: its lines do not advance (a damaged IGM?)")
    return InputError(f"no cell of the grid ({gw:.0f}, {gs:.0f}, {ge:.0f}, {gn:.0f}) lies in "
                      "the image's swath: nothing to map")


def _window_arrays(out: Scratch, raw: EnviRaster, rows: int, cols: int
                   ) -> tuple[B, npt.NDArray[Any], I32]:
    """A window's products in `out`: its filled cells, values (bands, rows, cols) and GLT
    (rows, 2, cols)."""
    return (out.get("ok", (rows, cols), np.bool_),
            out.planes("pixels", (raw.bands, rows, cols), raw.dtype.newbyteorder("=")),
            out.get("glt", (rows, 2, cols), np.int32))


def _make_window(index: SwathIndex, raw: EnviRaster, grid: OrthoGrid, nodata: float,
                 part: tuple[int, int, int, int], work: SimpleQueue[Scratch], out: Scratch,
                 resampling: Resampling = Resampling.NEAREST
                 ) -> tuple[npt.NDArray[Any], B, I32, tuple[int, int, float, float]] | None:
    """A window's values for the GeoTIFF, its filled cells, its GLT and GLT figures (see
    _glt_values), in `out`'s arrays; None if no cell is filled. The arrays it works in are
    one of `work`'s, needed only while a window is made (less memory to hold and touch)."""
    row0, col0, rows, cols = part
    sc = work.get()
    try:
        ch = nearest_pixels(index, grid, row0, col0, rows, cols, sc)
        ok, data, values = _window_arrays(out, raw, rows, cols)
        np.greater_equal(ch.line, 0, out=ok)
        if not ok.any():
            return None
        data.fill(nodata)
        gather_pixels(raw, ch.line, ch.pixel, ok, nodata, sc, into=data)
        if resampling is not Resampling.NEAREST:
            _resample_window(index, raw, grid, row0, col0, ch, ok, data, resampling)
        figures = _glt_values(ch.line, ch.pixel, ch.inside, ch.d2_cells, values)
    finally:
        work.put(sc)
    return data, ok, values, figures


def _cells_of(raster: EnviRaster, line: I64, pixel: I64, scratch: Scratch) -> npt.NDArray[Any]:
    """(bands, n): the raster's values at (line, pixel), every cell inside it."""
    out = np.empty((raster.bands, 1, line.size), raster.dtype.newbyteorder("="))
    return gather_pixels(raster, line[None, :], pixel[None, :], np.ones((1, line.size), bool),
                         0.0, scratch, into=out)[:, 0, :]


def _resample_window(index: SwathIndex, raw: EnviRaster, grid: OrthoGrid, row0: int,
                     col0: int, ch: TileChoice, ok: B, data: npt.NDArray[Any],
                     method: Resampling) -> None:
    """Replace the nearest pixel's value of the filled cells by the image interpolated at the
    cell centre's fractional image position, where that can be done (postproc.products.resample);
    the GLT keeps the nearest pixel."""
    rows, cols = ok.shape
    cells = np.flatnonzero(ok.ravel())
    line0 = ch.line.ravel()[cells].astype(np.int64)
    pix0 = ch.pixel.ravel()[cells].astype(np.int64)
    n_lines, n_pixels = index.raster.lines, index.raster.pixels
    igm_scratch, raw_scratch = Scratch(), Scratch()

    def ground(line: I64, pixel: I64) -> F64:
        return _cells_of(index.raster, line, pixel, igm_scratch)[:2].astype(np.float64)

    s_plus, s_minus = np.minimum(pix0 + 1, n_pixels - 1), np.maximum(pix0 - 1, 0)
    l_plus, l_minus = np.minimum(line0 + 1, n_lines - 1), np.maximum(line0 - 1, 0)
    row, col = np.divmod(cells, cols)
    centre_xy = np.stack([grid.centre_x_m(col0 + col), grid.centre_y_m(row0 + row)])
    ds, dl, usable = fractional_offsets(
        ground(line0, pix0), ground(line0, s_plus), ground(line0, s_minus),
        ground(l_plus, pix0), ground(l_minus, pix0), (s_plus - s_minus).astype(np.float64),
        (l_plus - l_minus).astype(np.float64), centre_xy)
    values, interpolated = interpolate(
        method, line0 + dl, pix0 + ds, raw.lines, raw.pixels,
        lambda line, pixel: _cells_of(raw, line, pixel, raw_scratch), raw.nodata, data.dtype)
    take = usable & interpolated
    flat = np.reshape(data, (data.shape[0], rows * cols), copy=False)
    flat[:, cells[take]] = values[:, take]


def _ortho_windows(index: SwathIndex, raw: EnviRaster, grid: OrthoGrid, nodata: float,
                   tif: TiffWriter, glt: GltWriter | None, tile_cells: int | None,
                   workers: int, progress: Progress | None, on_total: Progress | None,
                   resampling: Resampling = Resampling.NEAREST
                   ) -> tuple[int, int, float, float]:
    """Every window, `workers` at a time (the kernels release the GIL), handed to the
    GeoTIFF writer in order; (filled, infill, sum and max of the distances in metres)."""
    filled = infill = 0
    dist_sum = dist_max = 0.0
    # only where the swath can be: less to fill
    parts = [p for w in grid.windows(window_cells(raw), tile_cells)
             if (p := index.cell_extent(grid, *w, snap=TIFF_BLOCK)) is not None]
    if on_total is not None:
        on_total(sum(p[2] * p[3] for p in parts))
    if not parts:
        return filled, infill, dist_sum, dist_max
    work: SimpleQueue[Scratch] = SimpleQueue()
    for _ in range(workers):
        work.put(Scratch())
    # a window's products are in use until the GeoTIFF writer is done with them: `workers`
    # windows being made, one made and waiting for the writer, one being written
    free = [Scratch() for _ in range(workers + 2)]
    _, _, rows, cols = max(parts, key=lambda p: p[2] * p[3])
    for sc in free:  # sized once for the largest window: growing means fresh pages again
        _window_arrays(sc, raw, rows, cols)
    todo = iter(parts)
    writing: Scratch | None = None
    running: deque[tuple[tuple[int, int, int, int], Scratch, Future[Any]]] = deque()
    with ThreadPoolExecutor(workers, thread_name_prefix="sisa-ortho") as pool:

        def start() -> None:
            part = next(todo, None)
            if part is not None:
                sc = free.pop()
                running.append((part, sc, pool.submit(
                    _make_window, index, raw, grid, nodata, part, work, sc, resampling)))

        for _ in range(workers):
            start()
        while running:
            (row0, col0, n_rows, n_cols), scratch, future = running.popleft()
            made = future.result()
            start()
            if progress is not None:
                progress(n_rows * n_cols)
            if made is None:
                free.append(scratch)
                continue
            data, ok, values, (n, n_in, d_sum, d_top) = made
            if glt is not None:  # one thread: writers of a file contend
                glt.write_window(row0, col0, values)
            tif.write(data, row0, col0, ok)  # returns once the previous write is done
            if writing is not None:
                free.append(writing)
            writing = scratch
            filled, infill = filled + n, infill + n_in
            dist_sum += d_sum * grid.cell_m
            dist_max = max(dist_max, d_top * grid.cell_m)
    return filled, infill, dist_sum, dist_max
