"""The DEM the post-processor casts rays onto: a north-up grid of ELLIPSOIDAL heights.

Conventions (docs/conventions.md):
- The grid is in a projected CRS in metres (the block's UTM zone); a geographic or rotated raster
  is refused rather than resampled, because resampling would change the surface rays are cast on.
- Each sample belongs to its cell CENTRE. rasterio's transform gives cell EDGES, so the first
  centre is half a cell in from the raster's corner.
- The surface is bilinear between centres and exists only inside the hull of the centres: the
  outer half cell and any cell touching a nodata sample carry no surface (NaN), nothing is
  extrapolated.
- Voids (no data): the band's declared nodata value, NaN (always, declared or not) and any value
  outside PLAUSIBLE_HEIGHTS_M, which no terrain has: the void markers of DEMs whose nodata
  value is not declared (-9999, -32768, ±3.4e38). Undeclared ones are read as voids with a
  DemVoidWarning naming how many; a DEM (or window) with no valid height is refused (a window
  of voids only is read as such when the caller asks: a job skips the segment over it).
- Heights are ellipsoidal. A DEM of orthometric heights H needs a geoid: h = H + N, with N a
  constant or a raster of undulations sampled bilinearly at every DEM cell centre. N is within
  GEOID_UNDULATION_M (Earth's geoid: -106..+85 m): a constant beyond is refused, raster values
  beyond are voids (a fill value, or heights in the wrong units) said like the DEM's.
- Only band 1 is read; `band_note` says so for a raster with more.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt
import rasterio
from pyproj import Transformer
from rasterio.errors import NotGeoreferencedWarning, RasterioError
from rasterio.windows import Window

from sisa.core.errors import InputError

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]

DEFAULT_MARGIN_M: Final = 500.0  # beyond bounds_m: room for oblique rays over relief
GEOID_COORD_STEP_CELLS: Final = 16  # geoid coordinates computed exactly every 16 DEM cells
# Heights (m) any terrain can have, orthometric or ellipsoidal (Dead Sea shore -430, Everest
# 8849, geoid -106..+85): a value outside is a void marker, declared or not.
PLAUSIBLE_HEIGHTS_M: Final = (-1000.0, 9000.0)
# The geoid undulations N (m) a geoid can have (Earth's: -106..+85 m): a constant beyond is
# refused, raster values beyond are voids; so h = H + N stays within SURFACE_HEIGHTS_M.
GEOID_UNDULATION_M: Final = (-110.0, 110.0)
# ...and the ellipsoidal heights a DEM read within them can have once a geoid (|N| < 110 m) is
# added: what the ray caster accepts.
SURFACE_HEIGHTS_M: Final = (PLAUSIBLE_HEIGHTS_M[0] - 200.0, PLAUSIBLE_HEIGHTS_M[1] + 200.0)
OVERVIEW_FACTOR: Final = 16  # `height_range` reads a 1/16 overview
# cells read at a time when a whole DEM (or its overview) is scanned: memory stays ~50 MB
# however wide the raster (1024 whole rows of a 200 000-column DEM took 3.2 GB)
SCAN_CELLS: Final = 1 << 22
SAMPLE_CELLS: Final = 64  # `dem_extent` samples 64 x 64 heights (a whole scan if none is valid)


class DemVoidWarning(UserWarning):
    """Cells were read as voids although the raster's nodata value does not declare them."""


@dataclass(frozen=True, eq=False)
class Dem:
    """Heights on a north-up grid (row 0 = north) in a projected CRS, NaN = no data.

    `first_easting_m`/`first_northing_m` are the CENTRE of cell (row 0, col 0); `cell_e_m` and
    `cell_n_m` are the column and row spacings (both > 0; rows run south).
    """

    heights_m: F32
    first_easting_m: float
    first_northing_m: float
    cell_e_m: float
    cell_n_m: float
    epsg: int

    def __post_init__(self) -> None:
        h = self.heights_m
        if h.ndim != 2 or h.dtype != np.float32 or min(h.shape) < 2:
            raise ValueError(f"heights_m must be float32 (rows, cols) >= 2x2, got {h.dtype} "
                             f"{h.shape}")
        if not (self.cell_e_m > 0.0 and self.cell_n_m > 0.0):
            raise ValueError("cell sizes must be > 0")
        if np.isinf(h).any():
            raise ValueError("heights_m must be finite or NaN (no data), not infinite")

    @property
    def rows(self) -> int:
        return int(self.heights_m.shape[0])

    @property
    def cols(self) -> int:
        return int(self.heights_m.shape[1])

    @property
    def bounds_m(self) -> tuple[float, float, float, float]:
        """(west, south, east, north) of the surface: first to last cell CENTRE."""
        return (self.first_easting_m, self.first_northing_m - (self.rows - 1) * self.cell_n_m,
                self.first_easting_m + (self.cols - 1) * self.cell_e_m, self.first_northing_m)

    def height_at(self, easting_m: npt.ArrayLike, northing_m: npt.ArrayLike) -> F64:
        """Ellipsoidal height (m), bilinear between cell centres; NaN off the surface."""
        e, n = np.broadcast_arrays(np.asarray(easting_m, dtype=np.float64),
                                   np.asarray(northing_m, dtype=np.float64))
        x = (e - self.first_easting_m) / self.cell_e_m
        y = (self.first_northing_m - n) / self.cell_n_m
        return bilinear_centres(self.heights_m, x, y)

    @classmethod
    def read(cls, path: str | Path, *, bounds_m: tuple[float, float, float, float] | None = None,
             margin_m: float = DEFAULT_MARGIN_M, geoid: float | str | Path | None = None,
             voids_only_ok: bool = False) -> Dem:
        """Read a single-band GeoTIFF (or any GDAL raster), only the window that covers
        bounds_m = (west, south, east, north) in the DEM's CRS grown by margin_m, so a flight
        segment never loads a whole national DEM. Voids (module docstring) become NaN, the
        undeclared ones with a DemVoidWarning; InputError if the window has no valid height.
        `geoid` turns orthometric heights into ellipsoidal ones: a constant undulation N (m)
        or a raster of N in any CRS. `voids_only_ok`: a window of bounds_m with no valid height
        is returned as it is, all NaN and without the geoid, for the caller to skip (a segment
        over sea or a hole of a mosaic), not refused; the caller knows the DEM has a valid
        height elsewhere (`dem_extent`)."""
        path = Path(path)
        with _open(path, "DEM") as ds:
            epsg = _projected_epsg(ds, path)
            first_e, first_n, cell_e, cell_n = _grid_of(ds, path)
            win = _window(ds, path, first_e, first_n, cell_e, cell_n, bounds_m, margin_m)
            heights = _read_band(ds, win, path, "DEM")
            voids_only = not np.isfinite(heights).any()
            if voids_only and not (voids_only_ok and bounds_m is not None):
                if bounds_m is not None and _has_valid_height(ds):
                    raise InputError(f"{path}: the DEM has no valid height in the window "
                                     f"{bounds_text(bounds_m)} (+{margin_m:g} m)")
                raise _no_valid_height(path)
        dem = cls(heights, first_e + win.col_off * cell_e, first_n - win.row_off * cell_n,
                  cell_e, cell_n, epsg)
        if geoid is None or voids_only:
            return dem
        if isinstance(geoid, (int, float)):
            check_undulation_m(float(geoid), f"{path}: geoid undulation")
            return dem._with_heights(heights + np.float32(geoid))
        return dem._with_heights(heights + _undulation_at_centres(Path(geoid), dem))

    def _with_heights(self, heights_m: F32) -> Dem:
        return Dem(heights_m.astype(np.float32), self.first_easting_m, self.first_northing_m,
                   self.cell_e_m, self.cell_n_m, self.epsg)

    def centres_m(self) -> tuple[F64, F64]:
        """1-D eastings of the column centres and northings of the row centres."""
        cols = np.arange(self.cols, dtype=np.float64)
        rows = np.arange(self.rows, dtype=np.float64)
        return (np.asarray(self.first_easting_m + cols * self.cell_e_m),
                np.asarray(self.first_northing_m - rows * self.cell_n_m))


def bilinear_centres(grid: npt.NDArray[Any], x: F64, y: F64) -> F64:
    """Bilinear value of `grid` at fractional (col, row) positions of its samples; NaN outside
    [0, cols-1] x [0, rows-1] or next to a NaN sample."""
    rows, cols = grid.shape
    inside = (x >= 0.0) & (x <= cols - 1) & (y >= 0.0) & (y <= rows - 1)
    xs = np.where(inside, x, 0.0)
    ys = np.where(inside, y, 0.0)
    c0 = np.minimum(np.floor(xs), cols - 2).astype(np.intp)
    r0 = np.minimum(np.floor(ys), rows - 2).astype(np.intp)
    fx = xs - c0
    fy = ys - r0
    z00, z01, z10, z11 = (np.asarray(grid[r, c], dtype=np.float64)
                          for r, c in ((r0, c0), (r0, c0 + 1), (r0 + 1, c0), (r0 + 1, c0 + 1)))
    top = z00 * (1.0 - fx) + z01 * fx
    bottom = z10 * (1.0 - fx) + z11 * fx
    out = top * (1.0 - fy) + bottom * fy
    return np.asarray(np.where(inside, out, np.nan))


# ---------------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------------


def check_undulation_m(value: float, name: str) -> None:
    """InputError `name value: ...` unless `value` is a geoid undulation Earth can have: a
    constant N of 1e6 m made every height implausible (an error blaming the DEM), 1e308 an
    overflow traceback, and -200 m passed silently, the surface 100 m off."""
    low, high = GEOID_UNDULATION_M
    if not (math.isfinite(value) and low <= value <= high):
        raise InputError(f"{name} {value:g}: must be {low:g} to {high:g} m (the geoid "
                         "undulation on Earth: -106 to +85 m)")


def bounds_text(bounds: tuple[float, ...]) -> str:
    """(west, south, east, north) to 0.1 m, for a message."""
    return "(" + ", ".join(f"{v:.1f}" for v in bounds) + ")"


def union_bounds(b: list[tuple[float, float, float, float]]
                 ) -> tuple[float, float, float, float]:
    """The (west, south, east, north) that holds every one of `b`."""
    return (min(x[0] for x in b), min(x[1] for x in b), max(x[2] for x in b),
            max(x[3] for x in b))


def band_note(path: str | Path, what: str = "DEM") -> str | None:
    """What to say of a raster with more than one band (None with one): only band 1 is read,
    which a 3-band file (an RGB relief rendering, a DEM with error bands) makes a guess."""
    path = Path(path)
    with _open(path, what) as ds:
        bands = int(ds.count)
    if bands == 1:
        return None
    return (f"{path}: the {what} raster has {bands} bands: band 1 is read as "
            f"{'heights' if what == 'DEM' else 'undulations'}, the others are ignored")


def dem_extent(path: str | Path) -> tuple[int, tuple[float, float, float, float]]:
    """(EPSG, bounds of the cell centres) of a DEM file, checked as `Dem.read` checks it but
    without reading its heights (a sparse sample of them, so that a DEM with no valid height
    is refused at once): what a job needs before it knows which window to read."""
    path = Path(path)
    with _open(path, "DEM") as ds:
        epsg = _projected_epsg(ds, path)
        first_e, first_n, cell_e, cell_n = _grid_of(ds, path)
        last_e = first_e + (ds.width - 1) * cell_e
        last_n = first_n - (ds.height - 1) * cell_n
        shape = (min(ds.height, SAMPLE_CELLS), min(ds.width, SAMPLE_CELLS))
        sample = _voids_to_nan(_read(ds, out_shape=shape))[0]
        if not np.isfinite(sample).any() and not _has_valid_height(ds):
            raise _no_valid_height(path)
    return epsg, (first_e, last_n, last_e, first_n)


def _open(path: Path, what: str) -> Any:
    if not path.is_file():
        raise InputError(f"{path}: {what} file not found")
    try:
        with warnings.catch_warnings():  # a raster without a CRS is refused below, in words
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            ds = rasterio.open(path)
    except RasterioError as exc:
        raise InputError(f"{path}: not a readable {what} raster ({_reason(exc)})") from None
    if ds.count < 1:
        ds.close()
        raise InputError(f"{path}: {what} raster has no band")
    if str(ds.dtypes[0]).startswith("complex"):
        ds.close()
        raise InputError(f"{path}: {what} band 1 holds {ds.dtypes[0]} values, not heights")
    return ds


def _projected_epsg(ds: Any, path: Path) -> int:
    crs = ds.crs
    if crs is None:
        raise InputError(f"{path}: DEM has no CRS")
    if not crs.is_projected:
        raise InputError(f"{path}: DEM is in a non-projected CRS ({crs}); reproject it to a "
                         "projected CRS in metres (the block's UTM zone) first")
    unit, factor = crs.linear_units_factor
    if factor != 1.0:
        raise InputError(f"{path}: DEM CRS units are {unit}, not metres")
    epsg = crs.to_epsg()
    if epsg is None:
        raise InputError(f"{path}: DEM CRS has no EPSG code ({crs.to_string()[:60]})")
    return int(epsg)


def _grid_of(ds: Any, path: Path) -> tuple[float, float, float, float]:
    """(first centre easting, first centre northing, cell east, cell north) of a north-up
    raster; rasterio's transform is for cell EDGES, so the first centre is half a cell in."""
    t = ds.transform
    if t.b != 0.0 or t.d != 0.0:
        raise InputError(f"{path}: DEM grid is rotated or skewed ({tuple(t)[:6]}); "
                         "warp it to a north-up grid first")
    if not (t.a > 0.0 and t.e < 0.0):
        raise InputError(f"{path}: DEM grid is not north-up (pixel size {t.a}, {t.e})")
    if ds.width < 2 or ds.height < 2:
        raise InputError(f"{path}: DEM has fewer than 2x2 cells")
    return float(t.c + 0.5 * t.a), float(t.f + 0.5 * t.e), float(t.a), float(-t.e)


def height_range(path: str | Path, overview: int = OVERVIEW_FACTOR) -> tuple[float, float] | None:
    """(lowest, highest) valid height of a DEM file from a 1/`overview` overview (voids as in
    `Dem.read`, without the warning); None if no overview sample is valid. What a job needs to
    place a swath on the DEM before it reads a window."""
    path = Path(path)
    low, high = math.inf, -math.inf
    with _open(path, "DEM") as ds:
        for win, shape in _scan_windows(ds, overview):
            data = _voids_to_nan(_read(ds, window=win, out_shape=shape))[0]
            if np.isfinite(data).any():
                low, high = min(low, float(np.nanmin(data))), max(high, float(np.nanmax(data)))
    return None if low > high else (low, high)


def _scan_windows(ds: Any, overview: int = 1) -> Iterator[tuple[Window, tuple[int, int]]]:
    """The whole raster in windows of whole blocks of the file, each with the shape of its
    1/`overview` overview: about SCAN_CELLS overview cells a window, so a scan of any DEM runs
    in bounded memory and reads no block twice."""
    block_rows, block_cols = ds.block_shapes[0]
    side = math.isqrt(SCAN_CELLS) * overview
    cols = min(ds.width, max(1, side // block_cols) * block_cols)
    rows = max(1, SCAN_CELLS * overview * overview // cols // block_rows) * block_rows
    for r0 in range(0, ds.height, rows):
        for c0 in range(0, ds.width, cols):
            win = Window(c0, r0, min(cols, ds.width - c0), min(rows, ds.height - r0))
            yield win, (max(win.height // overview, 1), max(win.width // overview, 1))


def _window(ds: Any, path: Path, first_e: float, first_n: float, cell_e: float, cell_n: float,
            bounds_m: tuple[float, float, float, float] | None, margin_m: float) -> Window:
    """Cells whose centres' hull covers bounds_m + margin (clipped to the raster)."""
    if bounds_m is None:
        return Window(0, 0, ds.width, ds.height)
    if not all(math.isfinite(v) for v in bounds_m):
        if not _has_valid_height(ds):
            raise _no_valid_height(path)
        raise InputError(f"{path}: DEM window bounds {bounds_m} are not finite (derived from "
                         "NaN heights?)")
    west, south, east, north = bounds_m
    if not (west <= east and south <= north) or margin_m < 0.0:
        raise InputError(f"{path}: bad bounds {bounds_m} / margin {margin_m}")
    c0 = max(math.floor((west - margin_m - first_e) / cell_e), 0)
    c1 = min(math.ceil((east + margin_m - first_e) / cell_e), ds.width - 1)
    r0 = max(math.floor((first_n - north - margin_m) / cell_n), 0)
    r1 = min(math.ceil((first_n - south + margin_m) / cell_n), ds.height - 1)
    if c1 - c0 < 1 or r1 - r0 < 1:
        extent = (first_e, first_n - (ds.height - 1) * cell_n,
                  first_e + (ds.width - 1) * cell_e, first_n)
        raise InputError(f"{path}: bounds {bounds_text(bounds_m)} (+{margin_m:g} m) do not "
                         f"overlap the DEM {bounds_text(extent)}")
    return Window(c0, r0, c1 - c0 + 1, r1 - r0 + 1)


def _read_band(ds: Any, win: Window, path: Path, what: str) -> F32:
    """Band 1 in the window as float32, voids NaN: masked (declared nodata) cells, NaN and
    values outside PLAUSIBLE_HEIGHTS_M. Undeclared voids other than NaN get a
    DemVoidWarning."""
    out, marked = _voids_to_nan(_read(ds, window=win))
    if marked.size:
        warnings.warn(_void_note(path, marked, what, PLAUSIBLE_HEIGHTS_M, "no surface there"),
                      DemVoidWarning, stacklevel=3)
    return out


def _void_note(path: Path, marked: F64, what: str, plausible: tuple[float, float],
               meaning: str) -> str:
    """The warning for cells read as voids that no nodata value declares: how many, their
    commonest values, the range they are outside of."""
    one = marked.size == 1
    return (f"{path}: {marked.size} {what} cell{'' if one else 's'} hold{'s' if one else ''} "
            f"{_values_text(marked)}, outside {_range_text(plausible)}, and no nodata value "
            f"declares {'it' if one else 'them'}: read as void{'' if one else 's'} ({meaning})")


def _values_text(values: F64) -> str:
    """The three commonest of `values`, for a message ("-9999, -32768 ...")."""
    unique, counts = np.unique(values, return_counts=True)
    top = unique[np.argsort(counts)[::-1][:3]]
    return f"{', '.join(f'{v:g}' for v in top)}{' ...' if unique.size > 3 else ''}"


def _read(ds: Any, **kwargs: Any) -> np.ma.MaskedArray[Any, Any]:
    """Band 1 as a masked array (rasterio's `read` arguments), or an InputError naming the file
    when GDAL cannot read it (damaged tiles, a file cut short, a size it cannot allocate)."""
    try:
        band: np.ma.MaskedArray[Any, Any] = ds.read(1, masked=True, **kwargs)
    except (RasterioError, MemoryError) as exc:
        # rasterio's "Read failed" names GDAL's own error as its cause
        raise InputError(f"{ds.name}: cannot read band 1 ({_reason(exc.__cause__ or exc)}): "
                         "a damaged or incomplete file?") from None
    return band


def _reason(exc: BaseException) -> str:
    """An error's first line (its type when it says nothing), for a one-line message."""
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


def _voids_to_nan(data: np.ma.MaskedArray[Any, Any],
                  plausible: tuple[float, float] = PLAUSIBLE_HEIGHTS_M) -> tuple[F32, F64]:
    """float32 copy of a masked band with every void NaN, and the values of the implausible
    cells (outside `plausible`) its mask (the raster's nodata value) leaves in (float64, for
    the note)."""
    mask = np.ma.getmaskarray(data)
    raw = np.ma.getdata(data)
    with np.errstate(over="ignore"):  # float64 beyond float32's range: inf, implausible
        out = np.ascontiguousarray(raw, dtype=np.float32)
    low, high = plausible
    implausible = ~mask & ((out < low) | (out > high))  # NaN compares False: a void anyway
    marked = np.asarray(raw[implausible], dtype=np.float64)
    out[mask | implausible] = np.nan
    return out, marked


def _has_valid_height(ds: Any) -> bool:
    """Whether any cell of the whole raster is a valid height (read in windows of about
    SCAN_CELLS cells: only on the way to an error, or for a DEM whose sample found none)."""
    return any(np.isfinite(_voids_to_nan(_read(ds, window=win))[0]).any()
               for win, _ in _scan_windows(ds))


def _range_text(limits: tuple[float, float]) -> str:
    low, high = limits
    return f"{low:g}..{high:g} m"


def _plausible_text() -> str:
    return _range_text(PLAUSIBLE_HEIGHTS_M)


def _no_valid_height(path: Path) -> InputError:
    return InputError(f"{path}: the DEM has no valid height (every cell is nodata, NaN or "
                      f"outside {_plausible_text()})")


# ---------------------------------------------------------------------------------------------
# Geoid
# ---------------------------------------------------------------------------------------------


def _undulation_at_centres(path: Path, dem: Dem) -> F32:
    """Geoid undulation N (m) at every DEM cell centre, bilinear between the geoid raster's own
    centres. The DEM → geoid-CRS transform is done by pyproj every GEOID_COORD_STEP_CELLS cells
    and interpolated in between (it is smooth: far below a micro-degree), while the geoid grid
    itself is sampled bilinearly at each centre. Values outside GEOID_UNDULATION_M are voids
    (a DemVoidWarning naming the geoid's range); a DEM cell whose N is a void, or off the
    geoid's grid, is an InputError saying which (a geoid of 3000 m was a 'no pixel could be
    georeferenced: does the DEM cover the flight?' much later)."""
    with _open(path, "geoid") as ds:
        if ds.crs is None:
            raise InputError(f"{path}: geoid raster has no CRS")
        col, row = _geoid_pixel_coords(ds, dem)
        ok = np.isfinite(col) & np.isfinite(row)
        if not ok.any():
            raise InputError(f"{path}: geoid coordinates undefined over the DEM")
        c0 = max(math.floor(float(col[ok].min())) - 1, 0)
        r0 = max(math.floor(float(row[ok].min())) - 1, 0)
        c1 = min(math.ceil(float(col[ok].max())) + 2, ds.width - 1)
        r1 = min(math.ceil(float(row[ok].max())) + 2, ds.height - 1)
        if c1 - c0 < 1 or r1 - r0 < 1:
            raise InputError(f"{path}: geoid raster does not cover the DEM")
        win = Window(c0, r0, c1 - c0 + 1, r1 - r0 + 1)
        grid, marked = _voids_to_nan(_read(ds, window=win), GEOID_UNDULATION_M)
        on_grid = (col >= 0.0) & (col <= ds.width - 1) & (row >= 0.0) & (row <= ds.height - 1)
    voids = f"nodata, NaN or outside {_range_text(GEOID_UNDULATION_M)}, the geoid's range"
    if not np.isfinite(grid).any():
        held = f"; {marked.size} hold {_values_text(marked)}" if marked.size else ""
        raise InputError(f"{path}: the geoid raster has no valid undulation over the DEM "
                         f"(every cell there is {voids}{held})")
    n = bilinear_centres(grid, col - c0, row - r0)
    missing = np.isnan(n) & np.isfinite(dem.heights_m)
    if (off := int((missing & ~on_grid).sum())) > 0:
        raise InputError(f"{path}: geoid raster does not cover {off} DEM cells")
    if (void := int(missing.sum())) > 0:
        raise InputError(f"{path}: the geoid raster has no valid undulation at {void} DEM "
                         f"cells ({voids})")
    if marked.size:
        warnings.warn(_void_note(path, marked, "geoid", GEOID_UNDULATION_M,
                                 "no undulation there"), DemVoidWarning, stacklevel=3)
    return n.astype(np.float32)


def _geoid_pixel_coords(ds: Any, dem: Dem) -> tuple[F64, F64]:
    """Fractional (col, row) of every DEM centre in the geoid raster, relative to the geoid's
    own cell centres."""
    step = GEOID_COORD_STEP_CELLS
    rs = np.unique(np.append(np.arange(0, dem.rows, step), dem.rows - 1))
    cs = np.unique(np.append(np.arange(0, dem.cols, step), dem.cols - 1))
    e_1d, n_1d = dem.centres_m()
    ee, nn = np.meshgrid(e_1d[cs], n_1d[rs])
    to_geoid = Transformer.from_crs(dem.epsg, ds.crs.to_wkt(), always_xy=True)
    gx, gy = (np.asarray(v, dtype=np.float64) for v in to_geoid.transform(ee, nn))
    inv = ~ds.transform
    if ds.crs.is_geographic:
        gx = _wrap_longitude(gx, ds)
    col = inv.a * gx + inv.b * gy + inv.c - 0.5
    row = inv.d * gx + inv.e * gy + inv.f - 0.5
    return _interp_coarse(col, rs, cs, dem), _interp_coarse(row, rs, cs, dem)


def _wrap_longitude(lon: F64, ds: Any) -> F64:
    """Shift longitudes by ±360° into a geographic geoid grid's span (0–360° grids)."""
    west = ds.bounds.left
    east = ds.bounds.right
    lon = np.where(lon < west, lon + 360.0, lon)
    return np.asarray(np.where(lon > east, lon - 360.0, lon))


def _interp_coarse(values: F64, rs: npt.NDArray[np.intp], cs: npt.NDArray[np.intp],
                   dem: Dem) -> F64:
    """Bilinear interpolation of values known at rows rs x cols cs to every DEM cell."""
    rows = np.arange(dem.rows, dtype=np.float64)
    cols = np.arange(dem.cols, dtype=np.float64)
    x = np.interp(cols, cs, np.arange(cs.size, dtype=np.float64))
    y = np.interp(rows, rs, np.arange(rs.size, dtype=np.float64))
    xx, yy = np.meshgrid(x, y)
    return bilinear_centres(values, xx, yy)
