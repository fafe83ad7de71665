"""Synthetic ground truth over the block: the DEM, the scene the scanner images, and the ground
control and check points.

Conventions (every product of this module):
- CRS: the block's UTM zone on WGS 84 (`LocalPlane.utm_epsg`). Heights are WGS 84 ELLIPSOIDAL
  metres (DEM and ground points); no geoid is involved.
- Rasters (DEM, scene) are north-up grids. `transform` is the rasterio affine of cell EDGES
  (GDAL AREA_OR_POINT=Area); each value belongs to its cell CENTRE. Sampling is bilinear between
  centres, constant over the outer half cell, and NaN outside the raster.
- Everything is seeded from `scn.seed` plus a per-product tag, so the DEM, the scene and the
  ground points are each reproducible on their own.
- Strips are assumed flown at mean_height_m + flying_height_agl_m (ellipsoidal): the flat-terrain
  height `block_figures` plans with. Ground points are kept inside the swath that height gives
  over the DEM, so every point is imaged.
"""

from __future__ import annotations

import math
import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path
from typing import Any, Final, TypeVar, cast

import numba
import numpy as np
import numpy.typing as npt
import rasterio
from rasterio.crs import CRS
from rasterio.transform import Affine
from rasterio.windows import Window
from scipy import fft as sfft

from emulators.block import block_extent_en_m, block_figures, strip_lines
from emulators.localplane import LocalPlane
from emulators.scenario import Scenario
from sisa.core.errors import ConfigError

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
U8 = npt.NDArray[np.uint8]
_Fn = TypeVar("_Fn", bound=Callable[..., Any])

# Seed tags: each product draws from its own stream, so changing one never shifts another.
_TAG_DEM: Final = 0x5D_E4
_TAG_SCENE: Final = 0x5C_E4
_TAG_POINTS: Final = 0x90_17

DEM_NODATA_M: Final = -9999.0
VERTICAL_DATUM: Final = "WGS 84 ellipsoid (ellipsoidal heights, as EPSG:4979)"
WAVELENGTH_RANGE_NM: Final = (430.0, 950.0)  # CASI-501 spectral range (seed 000)

# Seed 000 §6: 97 of Garrotxa's 111 ground points lie on the block borders (seen in one image),
# the rest inside the block (seen in two).
CONTROL_BORDER_FRACTION: Final = 97.0 / 111.0


def _jit(parallel: bool = False) -> Callable[[_Fn], _Fn]:
    """numba.njit with a typed signature (numba has no stubs), cached on disk, without the
    GIL (the scanner renders on a thread of its own, emulators.scanner)."""
    return cast(Callable[[_Fn], _Fn], numba.njit(cache=True, parallel=parallel, nogil=True))


# ---------------------------------------------------------------------------------------------
# Grids and interpolation
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Grid:
    """A north-up grid: west/north EDGES of the first cell, square cells."""

    west_m: float
    north_m: float
    cell_m: float
    rows: int
    cols: int

    @classmethod
    def covering(cls, bounds_m: tuple[float, float, float, float], cell_m: float) -> _Grid:
        """Smallest grid on multiples of cell_m that covers (west, south, east, north)."""
        west = math.floor(bounds_m[0] / cell_m) * cell_m
        north = math.ceil(bounds_m[3] / cell_m) * cell_m
        cols = max(2, math.ceil((bounds_m[2] - west) / cell_m))
        rows = max(2, math.ceil((north - bounds_m[1]) / cell_m))
        return cls(west, north, cell_m, rows, cols)

    @property
    def transform(self) -> Affine:
        return Affine(self.cell_m, 0.0, self.west_m, 0.0, -self.cell_m, self.north_m)

    def centres_m(self) -> tuple[F64, F64]:
        """1-D eastings of column centres and northings of row centres."""
        e = self.west_m + (np.arange(self.cols, dtype=np.float64) + 0.5) * self.cell_m
        n = self.north_m - (np.arange(self.rows, dtype=np.float64) + 0.5) * self.cell_m
        return e, n

    def centre_mesh_m(self) -> tuple[F64, F64]:
        e, n = self.centres_m()
        ee, nn = np.meshgrid(e, n)
        return ee, nn


@_jit()
def bilinear_at(grid: Any, west_m: float, north_m: float, cell_m: float,
                easting_m: float, northing_m: float) -> float:
    """Bilinear value of a north-up grid whose values sit at cell CENTRES (edges at west_m,
    north_m); constant over the outer half cell, NaN outside. Callable from other jitted code."""
    rows, cols = grid.shape
    x = (easting_m - west_m) / cell_m - 0.5
    y = (north_m - northing_m) / cell_m - 0.5
    if not (-0.5 <= x <= cols - 0.5 and -0.5 <= y <= rows - 0.5):
        return np.nan
    x = min(max(x, 0.0), cols - 1.0)
    y = min(max(y, 0.0), rows - 1.0)
    c0 = min(int(x), cols - 2)
    r0 = min(int(y), rows - 2)
    fx = x - c0
    fy = y - r0
    top = grid[r0, c0] * (1.0 - fx) + grid[r0, c0 + 1] * fx
    bottom = grid[r0 + 1, c0] * (1.0 - fx) + grid[r0 + 1, c0 + 1] * fx
    return float(top * (1.0 - fy) + bottom * fy)


@_jit(parallel=True)
def _bilinear_many(grid: Any, west_m: float, north_m: float, cell_m: float,
                   e: Any, n: Any, out: Any) -> None:
    for k in numba.prange(e.size):
        out[k] = bilinear_at(grid, west_m, north_m, cell_m, e[k], n[k])


def _spectral_noise(rng: np.random.Generator, shape: tuple[int, int], cell_m: float,
                    scale_m: float, beta: float) -> F64:
    """Zero-mean, unit-variance smooth random field with power spectrum ∝ (k² + 1/scale²)^(−β/2):
    fractal (fBm-like) below `scale_m`, flat above it. Synthesised on a padded grid so opposite
    edges are not forced to match."""
    padded = tuple(sfft.next_fast_len(int(s * 1.25) + 8) for s in shape)
    spec = sfft.rfft2(rng.standard_normal(padded), workers=-1)
    ky = sfft.fftfreq(padded[0], d=cell_m)[:, None]
    kx = sfft.rfftfreq(padded[1], d=cell_m)[None, :]
    spec *= (ky**2 + kx**2 + scale_m**-2) ** (-beta / 4.0)
    field = np.asarray(sfft.irfft2(spec, s=padded, workers=-1))[: shape[0], : shape[1]]
    field -= field.mean()
    std = float(field.std())
    return field / std if std > 0 else field


# ---------------------------------------------------------------------------------------------
# Meandering lines (river, roads)
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Meander:
    """A meandering line (river, road): a lateral offset f(s) from a straight axis through the
    origin, tabulated every step_m along the axis. The offset is a few random-phase sinusoids, so
    signed distances are cheap everywhere: (q − f(s)) / √(1 + f'(s)²), left of the axis > 0."""

    origin_e_m: float
    origin_n_m: float
    axis_e: float
    axis_n: float
    s0_m: float
    step_m: float
    half_width_m: float
    offset_m: F64
    offset_slope: F64

    @classmethod
    def random(cls, rng: np.random.Generator, origin_m: tuple[float, float], reach_m: float,
               wavelength_m: tuple[float, float], half_width_m: float) -> Meander:
        """Four sinusoids, wavelengths log-uniform in the range; amplitudes proportional to the
        wavelength and bounded so the line never turns back on itself."""
        theta = rng.uniform(0.0, 2.0 * np.pi)
        s = np.arange(-reach_m, reach_m + 4.0, 4.0)
        lam = np.exp(rng.uniform(math.log(wavelength_m[0]), math.log(wavelength_m[1]), size=4))
        amp = 0.025 * lam * rng.uniform(0.5, 1.0, size=4)
        phase = rng.uniform(0.0, 2.0 * np.pi, size=4)
        arg = 2.0 * np.pi * s[:, None] / lam + phase
        offset = (amp * np.sin(arg)).sum(axis=1)
        slope = (amp * 2.0 * np.pi / lam * np.cos(arg)).sum(axis=1)
        return cls(origin_m[0], origin_m[1], math.sin(theta), math.cos(theta), float(s[0]), 4.0,
                   half_width_m, offset, slope)

    def signed_distance_m(self, easting_m: npt.ArrayLike, northing_m: npt.ArrayLike) -> F64:
        de = np.asarray(easting_m, float) - self.origin_e_m
        dn = np.asarray(northing_m, float) - self.origin_n_m
        s = de * self.axis_e + dn * self.axis_n
        q = dn * self.axis_e - de * self.axis_n
        tab_s = self.s0_m + self.step_m * np.arange(self.offset_m.size)
        f = np.interp(s, tab_s, self.offset_m)
        fp = np.interp(s, tab_s, self.offset_slope)
        return np.asarray((q - f) / np.sqrt(1.0 + fp * fp))

    def packed(self) -> F64:
        """(origin e, origin n, axis e, axis n, s0, step, half width, max |offset|,
        max √(1 + slope²)) for the jitted kernels."""
        return np.array([self.origin_e_m, self.origin_n_m, self.axis_e, self.axis_n, self.s0_m,
                         self.step_m, self.half_width_m, float(np.abs(self.offset_m).max()),
                         float(np.sqrt(1.0 + self.offset_slope.max() ** 2))])


@_jit()
def _meander_near(geom: Any, offset: Any, slope: Any, k: int, e: float, n: float,
                  limit_m: float) -> float:
    """|distance| from (e, n) to meander k, or inf when it is surely beyond limit_m (a bound
    from the axis distance skips the table lookup for most of the scene)."""
    de = e - geom[k, 0]
    dn = n - geom[k, 1]
    q = dn * geom[k, 2] - de * geom[k, 3]
    if abs(q) - geom[k, 7] > limit_m * geom[k, 8]:
        return np.inf
    s = de * geom[k, 2] + dn * geom[k, 3]
    last = offset.shape[1] - 1
    x = min(max((s - geom[k, 4]) / geom[k, 5], 0.0), float(last))
    i = min(int(x), last - 1)
    fx = x - i
    f = offset[k, i] * (1.0 - fx) + offset[k, i + 1] * fx
    fp = slope[k, i] * (1.0 - fx) + slope[k, i + 1] * fx
    return float(abs(q - f) / math.sqrt(1.0 + fp * fp))


# ---------------------------------------------------------------------------------------------
# DEM
# ---------------------------------------------------------------------------------------------


def _dem_bounds_utm(scn: Scenario, plane: LocalPlane) -> tuple[float, float, float, float]:
    """UTM box around every strip's swath (the block extent traced along its edges, since the
    plane and UTM differ by a small rotation and scale), grown by terrain.margin_m."""
    e0, n0, e1, n1 = block_extent_en_m(scn)
    t = np.linspace(0.0, 1.0, 17)
    pe = np.concatenate([e0 + (e1 - e0) * t, np.full_like(t, e1), e1 - (e1 - e0) * t,
                         np.full_like(t, e0)])
    pn = np.concatenate([np.full_like(t, n0), n0 + (n1 - n0) * t, np.full_like(t, n1),
                         n1 - (n1 - n0) * t])
    x, y = plane.plane_to_utm(pe, pn)
    m = scn.terrain.margin_m
    return float(x.min() - m), float(y.min() - m), float(x.max() + m), float(y.max() + m)


def _random_river(rng: np.random.Generator, grid: _Grid) -> Meander:
    """A river crossing the DEM near its centre, meandering on 1–6 km wavelengths (scaled down
    for small DEMs)."""
    width = grid.cols * grid.cell_m
    height = grid.rows * grid.cell_m
    centre = (grid.west_m + width / 2.0 + rng.uniform(-0.15, 0.15) * width,
              grid.north_m - height / 2.0 + rng.uniform(-0.15, 0.15) * height)
    span = min(width, height)
    return Meander.random(rng, centre, reach_m=math.hypot(width, height),
                          wavelength_m=(0.15 * span, 0.6 * span), half_width_m=12.0)


def _relief_shape(rng: np.random.Generator, grid: _Grid, river: Meander) -> F64:
    """Unscaled terrain: fractal hills, a network of rounded ridges (crests along the zero lines
    of a second field), and a flat-floored valley along the river."""
    shape = (grid.rows, grid.cols)
    span = min(grid.rows, grid.cols) * grid.cell_m
    hills = _spectral_noise(rng, shape, grid.cell_m, scale_m=span / 2.0, beta=4.4)
    crest_src = _spectral_noise(rng, shape, grid.cell_m, scale_m=span / 4.0, beta=5.0)
    soft_abs = np.sqrt(crest_src**2 + 0.15**2)  # rounded crests along the zero lines
    ridges = (1.0 - np.minimum(soft_abs, 2.0) / 2.0) ** 2
    z = hills + 0.8 * (ridges - ridges.mean()) / max(float(ridges.std()), 1e-12)
    ee, nn = grid.centre_mesh_m()
    d = river.signed_distance_m(ee, nn)
    z -= 1.5 * np.exp(-((d / (0.12 * span)) ** 2))
    floor = float(np.percentile(z, 3.0))
    plain = np.exp(-((d / (0.025 * span + 40.0)) ** 4))
    return np.asarray(z * (1.0 - plain) + floor * plain)


@dataclass(frozen=True, eq=False)
class Terrain:
    """The synthetic DEM: ellipsoidal heights on a UTM grid (row 0 = north).

    `transform` maps cell EDGES (rasterio convention); `height_at` treats each value as the
    height at its cell CENTRE and interpolates bilinearly between centres.
    """

    epsg: int
    transform: Affine
    heights: F32
    spacing_m: float
    river: Meander

    @classmethod
    def from_scenario(cls, scn: Scenario) -> Terrain:
        """The DEM for the scenario: a function of the seed and of the grid, so a different
        block, margin or spacing gives a different (equally valid) landscape."""
        plane = LocalPlane.for_scenario(scn)
        ts = scn.terrain
        grid = _Grid.covering(_dem_bounds_utm(scn, plane), ts.dem_spacing_m)
        rng = np.random.default_rng([scn.seed, _TAG_DEM])
        river = _random_river(rng, grid)
        z = _relief_shape(rng, grid, river)
        ptp = float(z.max() - z.min())
        scale = ts.relief_m / ptp if ptp > 0 else 0.0
        heights = (ts.mean_height_m + (z - z.mean()) * scale).astype(np.float32)
        return cls(plane.utm_epsg, grid.transform, heights, ts.dem_spacing_m, river)

    @property
    def spacing(self) -> float:
        """Alias of spacing_m (metres)."""
        return self.spacing_m

    @property
    def grid(self) -> _Grid:
        rows, cols = self.heights.shape
        return _Grid(self.transform.c, self.transform.f, self.spacing_m, rows, cols)

    @property
    def bounds_m(self) -> tuple[float, float, float, float]:
        """(west, south, east, north) outer cell edges, UTM metres."""
        g = self.grid
        return (g.west_m, g.north_m - g.rows * g.cell_m, g.west_m + g.cols * g.cell_m, g.north_m)

    def height_at(self, easting_m: npt.ArrayLike, northing_m: npt.ArrayLike) -> F64:
        """Ellipsoidal height (m) at UTM points: bilinear between cell centres, NaN outside."""
        e, n = np.broadcast_arrays(np.asarray(easting_m, dtype=np.float64),
                                   np.asarray(northing_m, dtype=np.float64))
        out = np.empty(e.size)
        g = self.grid
        _bilinear_many(self.heights, g.west_m, g.north_m, g.cell_m, e.ravel(), n.ravel(), out)
        return out.reshape(e.shape)

    def write_dem(self, path: str | Path) -> None:
        """Float32 GeoTIFF, tiled + DEFLATE. GDAL's GeoTIFF writer cannot store a projected 3-D
        CRS in GeoKeys (it falls back to a .aux.xml sidecar that is easily lost), so the CRS is
        the 2-D UTM EPSG code and the vertical datum is declared in metadata (VERTICAL_DATUM,
        VERTICAL_UNITS, band unit and description)."""
        rows, cols = self.heights.shape
        profile = dict(driver="GTiff", width=cols, height=rows, count=1, dtype="float32",
                       crs=CRS.from_epsg(self.epsg), transform=self.transform,
                       nodata=DEM_NODATA_M, tiled=True, blockxsize=256, blockysize=256,
                       compress="deflate", predictor=3)
        with rasterio.open(Path(path), "w", **profile) as ds:
            ds.write(self.heights, 1)
            ds.update_tags(AREA_OR_POINT="Area", VERTICAL_DATUM=VERTICAL_DATUM,
                           VERTICAL_UNITS="metre", HEIGHT_TYPE="ellipsoidal",
                           SOURCE="SISA synthetic terrain (emulators.terrain)")
            ds.set_band_description(1, "height above the WGS 84 ellipsoid")
            ds.set_band_unit(1, "metre")


# ---------------------------------------------------------------------------------------------
# Scene: land cover, spectra and texture
# ---------------------------------------------------------------------------------------------


class LandCover(IntEnum):
    """Class ids in the scene's cover layer. Crops take CROP_VARIANTS consecutive ids, each a
    slightly different spectrum, so neighbouring fields of one crop still differ."""

    WATER = 0
    ROAD = 1
    TRACK = 2
    HEDGE = 3
    FOREST = 4
    BUILT = 5
    STUBBLE = 8
    MAIZE = 12
    ALFALFA = 16
    SOIL = 20
    FALLOW = 24


CROP_VARIANTS: Final = 4
# Plain ints for the jitted kernels.
_WATER, _ROAD, _TRACK, _HEDGE, _FOREST, _BUILT, _SOIL = (
    int(c) for c in (LandCover.WATER, LandCover.ROAD, LandCover.TRACK, LandCover.HEDGE,
                     LandCover.FOREST, LandCover.BUILT, LandCover.SOIL))
N_COVER_IDS: Final = int(LandCover.FALLOW) + CROP_VARIANTS
_CROPS: Final = (LandCover.STUBBLE, LandCover.MAIZE, LandCover.ALFALFA, LandCover.SOIL,
                 LandCover.FALLOW, LandCover.BUILT)
_CROP_WEIGHTS: Final = (0.30, 0.16, 0.16, 0.16, 0.205, 0.015)  # July in the Garrotxa lowlands
FOREST_FRACTION: Final = 0.4

# Layers of the scene raster (last axis).
L_COVER, L_DETAIL, L_WHITE, L_DARK = range(4)


def band_centres_nm(bands: int) -> F64:
    """Centres of `bands` equal-width bands spanning the CASI range."""
    lo, hi = WAVELENGTH_RANGE_NM
    return lo + (np.arange(bands) + 0.5) * (hi - lo) / bands


def _vegetation(lam: F64, green: float, red: float, nir: float, edge_nm: float = 715.0) -> F64:
    """Green leaves: chlorophyll dip in the red, green peak, red edge to a NIR plateau."""
    visible = red + (green - red) * np.exp(-(((lam - 550.0) / 35.0) ** 2))
    visible += 0.5 * red * np.exp(-(((lam - 440.0) / 30.0) ** 2))
    rise = 1.0 / (1.0 + np.exp(-(lam - edge_nm) / 12.0))
    return np.asarray(visible * (1.0 - rise) + nir * rise)


def _rising(lam: F64, r_blue: float, r_nir: float, power: float = 0.7) -> F64:
    """Soils, dry vegetation, asphalt: reflectance rising smoothly from blue to NIR."""
    x = (lam - WAVELENGTH_RANGE_NM[0]) / (WAVELENGTH_RANGE_NM[1] - WAVELENGTH_RANGE_NM[0])
    return np.asarray(r_blue + (r_nir - r_blue) * np.clip(x, 0.0, None) ** power)


def _cover_spectrum(cover: LandCover, variant: int, lam: F64) -> F64:
    v = 0.92 + 0.055 * variant  # crop variants: ±8 % in vigour / brightness
    table: dict[LandCover, Callable[[], F64]] = {
        LandCover.WATER: lambda: 0.07 * np.exp(-(lam - 430.0) / 120.0) + 0.005,
        LandCover.ROAD: lambda: _rising(lam, 0.07, 0.12, 1.0),
        LandCover.TRACK: lambda: _rising(lam, 0.18, 0.40),
        LandCover.HEDGE: lambda: _vegetation(lam, 0.07, 0.035, 0.30),
        LandCover.FOREST: lambda: _vegetation(lam, 0.06, 0.03, 0.28),
        LandCover.BUILT: lambda: 0.13 + 0.14 / (1.0 + np.exp(-(lam - 590.0) / 25.0)),
        LandCover.STUBBLE: lambda: _rising(lam, 0.14 * v, 0.42 * v, 0.6),
        LandCover.MAIZE: lambda: _vegetation(lam, 0.09, 0.04, 0.50 * v),
        LandCover.ALFALFA: lambda: _vegetation(lam, 0.11 * v, 0.05, 0.44, 712.0),
        LandCover.SOIL: lambda: _rising(lam, 0.07 * v, 0.26 * v, 0.9),
        LandCover.FALLOW: lambda: 0.55 * _rising(lam, 0.10, 0.36)
        + 0.45 * _vegetation(lam, 0.08, 0.06, 0.32 * v),
    }
    return np.asarray(table[cover]())


def cover_spectra(bands: int) -> F32:
    """Radiance factor (reflectance under unit illumination) of every cover id, shape
    (N_COVER_IDS, bands); ids that name no class stay 0."""
    lam = band_centres_nm(bands)
    spectra = np.zeros((N_COVER_IDS, bands), np.float32)
    for cover in LandCover:
        variants = CROP_VARIANTS if cover >= LandCover.STUBBLE else 1
        for k in range(variants):
            spectra[cover + k] = _cover_spectrum(cover, k, lam)
    return spectra


def paint_spectra(bands: int) -> F32:
    """Target paint: row 0 white, row 1 matt black (the GCP markers)."""
    lam = band_centres_nm(bands)
    return np.stack([0.80 + 0.05 * (lam > 500.0), np.full_like(lam, 0.035)]).astype(np.float32)


@_jit()
def _hash01(i: int, j: int, salt: int) -> float:
    """Deterministic uniform number in [0, 1) from two lattice indices and a salt."""
    h = np.uint64(i) * np.uint64(0x9E3779B97F4A7C15)
    h ^= np.uint64(j) * np.uint64(0xC2B2AE3D27D4EB4F)
    h ^= np.uint64(salt) * np.uint64(0x165667B19E3779F9)
    h ^= h >> np.uint64(31)
    h *= np.uint64(0xBF58476D1CE4E5B9)
    h ^= h >> np.uint64(29)
    h *= np.uint64(0x94D049BB133111EB)
    h ^= h >> np.uint64(32)
    return float(h >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@_jit()
def _seed_xy(i: int, j: int, sx: float, sy: float, salt: int) -> tuple[float, float]:
    """Seed of lattice cell (i, j), jittered over its middle half: polygons stay fairly regular
    (like parcels) and the 3 × 3 search below finds the true nearest seeds."""
    return ((i + 0.25 + 0.5 * _hash01(i, j, salt)) * sx,
            (j + 0.25 + 0.5 * _hash01(i, j, salt + 1)) * sy)


@_jit()
def _voronoi(x: float, y: float, sx: float, sy: float, salt: int, cache: Any, row: int
             ) -> tuple[int, int, float, float, float, int, int]:
    """Cell of a jittered-lattice Voronoi diagram (sx × sy lattice) holding (x, y): its lattice
    index, its seed, the distance to the cell's edge and the neighbour across that edge.
    `cache[row]` (31 floats) keeps the 3 × 3 seeds around the last lattice cell, which
    neighbouring scene cells nearly always share, and the inverse seed distances from the last
    nearest seed."""
    ci = math.floor(x / sx)
    cj = math.floor(y / sy)
    if cache[row, 0] != ci or cache[row, 1] != cj or cache[row, 2] != salt:
        cache[row, 0], cache[row, 1], cache[row, 2], cache[row, 21] = ci, cj, salt, -1.0
        for k in range(9):
            sx_k, sy_k = _seed_xy(ci + k // 3 - 1, cj + k % 3 - 1, sx, sy, salt)
            cache[row, 3 + 2 * k], cache[row, 4 + 2 * k] = sx_k, sy_k
    best, kb = np.inf, 0
    for k in range(9):
        d2 = (x - cache[row, 3 + 2 * k]) ** 2 + (y - cache[row, 4 + 2 * k]) ** 2
        if d2 < best:
            best, kb = d2, k
    bx, by = cache[row, 3 + 2 * kb], cache[row, 4 + 2 * kb]
    if cache[row, 21] != kb:
        cache[row, 21] = kb
        for k in range(9):
            dx, dy = cache[row, 3 + 2 * k] - bx, cache[row, 4 + 2 * k] - by
            cache[row, 22 + k] = 1.0 / math.sqrt(dx * dx + dy * dy) if k != kb else 0.0
    edge, kn = np.inf, kb
    for k in range(9):
        if k == kb:
            continue
        dx, dy = cache[row, 3 + 2 * k] - bx, cache[row, 4 + 2 * k] - by
        dist = ((bx + dx / 2.0 - x) * dx + (by + dy / 2.0 - y) * dy) * cache[row, 22 + k]
        if dist < edge:
            edge, kn = dist, k
    return (ci + kb // 3 - 1, cj + kb % 3 - 1, bx, by, edge, ci + kn // 3 - 1, cj + kn % 3 - 1)


@_jit()
def _pick_crop(u: float, crops: Any, weights: Any) -> int:
    """The crop whose cumulative weight first exceeds u."""
    acc = 0.0
    for k in range(crops.size):
        acc += weights[k]
        if u < acc:
            return int(crops[k])
    return int(crops[crops.size - 1])


@_jit()
def _encode_detail(factor: float) -> int:
    """Brightness factor 0.5–1.5 → byte."""
    return int(min(max((factor - 0.5) * 255.0 + 0.5, 0.0), 255.0))


@_jit()
def _field_cover(e: float, n: float, score: Any, score_geo: Any, land: Any, salt: int,
                 crops: Any, weights: Any, caches: Any) -> tuple[int, float]:
    """Cover and brightness factor from the district/field Voronoi layout. Districts (km
    scale) carry their own field orientation and are bounded by minor roads; fields inside are
    elongated Voronoi cells bounded by tracks or hedges; a field becomes forest where the
    forest score at its seed passes the threshold, so woods follow field boundaries.
    `caches` rows: district lattice, field lattice, district parameters, field attributes."""
    di, dj, _, _, d_edge, _, _ = _voronoi(e, n, land[0], land[0], salt, caches, 0)
    if d_edge < land[4]:
        return _ROAD, 1.0
    if caches[2, 0] != di or caches[2, 1] != dj:
        theta = np.pi * _hash01(di, dj, salt + 3)
        caches[2, 0], caches[2, 1] = di, dj
        caches[2, 2] = salt + 17 + int(1e4 * _hash01(di, dj, salt + 2))
        caches[2, 3], caches[2, 4] = math.cos(theta), math.sin(theta)
    dsalt, ct, st = int(caches[2, 2]), caches[2, 3], caches[2, 4]
    a = e * ct + n * st
    b = n * ct - e * st
    fi, fj, fa, fb, f_edge, ni, nj = _voronoi(a, b, land[1], land[2], dsalt, caches, 1)
    if f_edge < land[3] and not _inside_woods(fa, fb, ni, nj, ct, st, land, dsalt, score,
                                               score_geo, _hash01(fi + ni, fj + nj, dsalt + 6)):
        hedge = _hash01(fi + ni, fj + nj, dsalt + 5) < 0.4
        return (_HEDGE if hedge else _TRACK), 1.0
    field = caches[3]
    if field[0] != fi or field[1] != fj or field[2] != dsalt:
        field[0], field[1], field[2] = fi, fj, dsalt
        _field_attributes(fa * ct - fb * st, fa * st + fb * ct, fi, fj, dsalt, score,
                          score_geo, land[6], crops, weights, field)
    cover = int(field[3])
    if cover == _FOREST:
        return cover, 1.0
    if cover == _BUILT:
        roof = _hash01(math.floor(a / 14.0), math.floor(b / 10.0), dsalt + 9)
        return cover, 0.6 + 0.8 * roof
    phase = (b if field[5] > 0.5 else a) / land[7]
    tramlines = 1.0 - 4.0 * abs(phase - math.floor(phase) - 0.5)  # triangle wave, ±1
    return cover, field[4] * (1.0 + field[6] * tramlines)


@_jit()
def _inside_woods(fa: float, fb: float, ni: int, nj: int, ct: float, st: float, land: Any,
                  dsalt: int, score: Any, score_geo: Any, u: float) -> bool:
    """True for an edge between two forest fields (no track there, except one in five)."""
    na, nb = _seed_xy(ni, nj, land[1], land[2], dsalt)
    thr = land[6]
    own = bilinear_at(score, score_geo[0], score_geo[1], score_geo[2],
                      fa * ct - fb * st, fa * st + fb * ct)
    other = bilinear_at(score, score_geo[0], score_geo[1], score_geo[2],
                        na * ct - nb * st, na * st + nb * ct)
    return own > thr and other > thr and u > 0.2


@_jit()
def _field_attributes(seed_e: float, seed_n: float, fi: int, fj: int, dsalt: int, score: Any,
                      score_geo: Any, forest_threshold: float, crops: Any, weights: Any,
                      out: Any) -> None:
    """Per-field constants into out[3:7]: cover id, brightness, tramline direction, tramline
    contrast. Woods take the field when the forest score at its seed passes the threshold."""
    forest = bilinear_at(score, score_geo[0], score_geo[1], score_geo[2], seed_e, seed_n)
    cover = _pick_crop(_hash01(fi, fj, dsalt + 7), crops, weights)
    if forest > forest_threshold:
        cover = _FOREST
    elif cover != _BUILT:
        cover += int(CROP_VARIANTS * _hash01(fi, fj, dsalt + 10))
    out[3] = cover
    out[4] = 0.85 + 0.3 * _hash01(fi, fj, dsalt + 8)
    out[5] = _hash01(fi, fj, dsalt + 11)
    out[6] = 0.12 if _SOIL <= cover < _SOIL + CROP_VARIANTS else 0.06


@_jit(parallel=True)
def _paint_cover(layers: Any, grid_geo: Any, score: Any, score_geo: Any, curve_geom: Any,
                 curve_offset: Any, curve_slope: Any, land: Any, salt: int, crops: Any,
                 weights: Any) -> None:
    """Cover id and detail byte of every scene cell (curve 0 is the river, the others roads)."""
    rows, cols = layers.shape[0], layers.shape[1]
    for r in numba.prange(rows):
        n = grid_geo[1] - (r + 0.5) * grid_geo[2]
        caches = np.full((4, 31), np.nan)
        for c in range(cols):
            e = grid_geo[0] + (c + 0.5) * grid_geo[2]
            noise = _hash01(r, c, salt + 99)
            cover, factor = -1, 1.0
            for k in range(1, curve_geom.shape[0]):
                road_hw = curve_geom[k, 6]
                if _meander_near(curve_geom, curve_offset, curve_slope, k, e, n,
                                 road_hw) < road_hw:
                    cover = _ROAD
            if cover < 0:
                d_river = _meander_near(curve_geom, curve_offset, curve_slope, 0, e, n,
                                        curve_geom[0, 6] + land[5])
                if d_river < curve_geom[0, 6]:
                    cover = _WATER
                elif d_river < curve_geom[0, 6] + land[5]:
                    cover = _FOREST  # riparian gallery
            if cover < 0:
                cover, factor = _field_cover(e, n, score, score_geo, land, salt, crops, weights,
                                             caches)
            if cover == _FOREST:
                factor *= 0.65 + 0.7 * noise  # crowns and shadows
            elif cover == _HEDGE:
                factor *= 0.7 + 0.6 * noise
            else:
                factor *= 0.94 + 0.12 * noise
            layers[r, c, 0] = cover
            layers[r, c, 1] = _encode_detail(factor)


@_jit()
def _cell_terms(layers: Any, r: int, c: int, weight: float) -> tuple[int, float, float, float]:
    """(cover id, weight of its spectrum, weight of white paint, weight of black paint) of one
    cell entering a sample with the given interpolation weight."""
    white = layers[r, c, L_WHITE] / 255.0
    dark = layers[r, c, L_DARK] / 255.0
    factor = 0.5 + layers[r, c, L_DETAIL] / 255.0
    return (int(layers[r, c, L_COVER]), weight * factor * (1.0 - white - dark), weight * white,
            weight * dark)


@_jit(parallel=True)
def _sample_scene(layers: Any, spectra: Any, paint: Any, west_m: float, north_m: float,
                  cell_m: float, e: Any, n: Any, nearest: bool, out: Any) -> None:
    """Gathers the (up to) four cells of each sample first, then writes every band once."""
    rows, cols = layers.shape[0], layers.shape[1]
    for k in numba.prange(e.size):
        x = (e[k] - west_m) / cell_m - 0.5
        y = (north_m - n[k]) / cell_m - 0.5
        if not (-0.5 <= x <= cols - 0.5 and -0.5 <= y <= rows - 0.5):
            for b in range(out.shape[0]):
                out[b, k] = np.nan
            continue
        x = min(max(x, 0.0), cols - 1.0)
        y = min(max(y, 0.0), rows - 1.0)
        if nearest:
            ca, sa, wa, da = _cell_terms(layers, int(y + 0.5), int(x + 0.5), 1.0)
            for b in range(out.shape[0]):
                out[b, k] = sa * spectra[ca, b] + wa * paint[0, b] + da * paint[1, b]
            continue
        c0 = min(int(x), cols - 2)
        r0 = min(int(y), rows - 2)
        r1, c1 = r0 + 1, c0 + 1
        fx, fy = x - c0, y - r0
        ca, sa, wa, da = _cell_terms(layers, r0, c0, (1.0 - fx) * (1.0 - fy))
        cb, sb, wb, db = _cell_terms(layers, r0, c1, fx * (1.0 - fy))
        cc, sc, wc, dc = _cell_terms(layers, r1, c0, (1.0 - fx) * fy)
        cd, sd, wd, dd = _cell_terms(layers, r1, c1, fx * fy)
        white, dark = wa + wb + wc + wd, da + db + dc + dd
        for b in range(out.shape[0]):
            out[b, k] = (sa * spectra[ca, b] + sb * spectra[cb, b] + sc * spectra[cc, b]
                         + sd * spectra[cd, b] + white * paint[0, b] + dark * paint[1, b])


def _forest_score(rng: np.random.Generator, terrain: Terrain) -> tuple[F32, float]:
    """Where woods grow: steep and high ground plus km-scale randomness; returns the score on
    the DEM grid and the threshold that makes FOREST_FRACTION of it forest."""
    h = terrain.heights.astype(np.float64)
    gy, gx = np.gradient(h, terrain.spacing_m)
    slope = np.hypot(gx, gy)

    def z(a: F64) -> F64:
        std = float(a.std())
        return (a - a.mean()) / std if std > 0 else np.zeros_like(a)

    noise = _spectral_noise(rng, h.shape, terrain.spacing_m, scale_m=2500.0, beta=4.0)
    score = (0.5 * z(h) + 0.4 * z(slope) + 0.8 * noise).astype(np.float32)
    return score, float(np.quantile(score, 1.0 - FOREST_FRACTION))


def _random_roads(rng: np.random.Generator, grid: _Grid, cell_m: float) -> list[Meander]:
    """Main roads: gently winding lines through random points, about one per 100 km²."""
    width, height = grid.cols * grid.cell_m, grid.rows * grid.cell_m
    count = 2 + int(width * height / 100e6)
    reach = math.hypot(width, height)
    span = min(width, height)
    return [Meander.random(rng, (grid.west_m + rng.uniform(0.2, 0.8) * width,
                                 grid.north_m - rng.uniform(0.2, 0.8) * height), reach,
                           (0.3 * span, 1.0 * span), max(4.0, 0.75 * cell_m))
            for _ in range(count)]


# GCP target, in units of _marker_unit_m: white cross arms (half-width, half-length) on a black
# square (half-size). Arms two units wide always fill at least one texture cell and one pixel.
TARGET_ARM_HALF_WIDTH: Final = 1.0
TARGET_ARM_HALF_LENGTH: Final = 3.5
TARGET_SQUARE_HALF: Final = 5.5


def _marker_unit_m(scn: Scenario) -> float:
    """Stroke width of a GCP target: one nadir pixel or one texture cell, whichever is larger."""
    return max(block_figures(scn).gsd_across_nadir_m, scn.terrain.texture_cell_m)


def _overlap_1d(lo: F64, hi: F64, half: float) -> F64:
    """Length of each interval [lo, hi] inside [−half, half]."""
    return np.asarray(np.clip(np.minimum(hi, half) - np.maximum(lo, -half), 0.0, None))


def _paint_marker(layers: U8, grid: _Grid, e_m: float, n_m: float, unit_m: float) -> None:
    """A white cross on a black square centred exactly on the point (TARGET_* sizes). Coverage
    is exact per cell (products of 1-D overlaps of axis-aligned rectangles), so the target is
    rendered without any bias of its own."""
    arm = TARGET_ARM_HALF_WIDTH * unit_m
    length = TARGET_ARM_HALF_LENGTH * unit_m
    square = TARGET_SQUARE_HALF * unit_m
    c0 = max(0, math.floor((e_m - square - grid.west_m) / grid.cell_m))
    c1 = min(grid.cols, math.ceil((e_m + square - grid.west_m) / grid.cell_m))
    r0 = max(0, math.floor((grid.north_m - n_m - square) / grid.cell_m))
    r1 = min(grid.rows, math.ceil((grid.north_m - n_m + square) / grid.cell_m))
    if c0 >= c1 or r0 >= r1:
        return
    x_lo = grid.west_m + np.arange(c0, c1, dtype=np.float64) * grid.cell_m - e_m
    y_lo = n_m - grid.north_m + np.arange(r0, r1, dtype=np.float64) * grid.cell_m  # southwards
    x_hi, y_hi = x_lo + grid.cell_m, y_lo + grid.cell_m
    ox = {h: _overlap_1d(x_lo, x_hi, h) for h in (arm, length, square)}
    oy = {h: _overlap_1d(y_lo, y_hi, h) for h in (arm, length, square)}
    white = (np.outer(oy[length], ox[arm]) + np.outer(oy[arm], ox[length])
             - np.outer(oy[arm], ox[arm])) / grid.cell_m**2
    dark = np.outer(oy[square], ox[square]) / grid.cell_m**2 - white
    layers[r0:r1, c0:c1, L_WHITE] = np.rint(np.clip(white, 0, 1) * 255).astype(np.uint8)
    layers[r0:r1, c0:c1, L_DARK] = np.rint(np.clip(dark, 0, 1) * 255).astype(np.uint8)


def _land_params(rng: np.random.Generator, cell_m: float, forest_threshold: float) -> F64:
    """[district size, field length, field width, track half-width, minor road half-width,
    riparian width, forest threshold, tramline period] in metres (threshold unitless)."""
    field_len = rng.uniform(200.0, 260.0)
    return np.array([rng.uniform(2500.0, 3500.0), field_len, field_len * rng.uniform(0.55, 0.7),
                     max(1.5, 0.75 * cell_m), max(3.0, 0.75 * cell_m), 25.0, forest_threshold,
                     max(12.0, 3.0 * cell_m)])


def _scene_grid(terrain: Terrain, cell_m: float) -> _Grid:
    """The scene raster: the DEM's extent at the texture cell."""
    w, s, e, n = terrain.bounds_m
    return _Grid(w, n, cell_m, max(2, math.ceil((n - s) / cell_m)),
                 max(2, math.ceil((e - w) / cell_m)))


@dataclass(frozen=True, eq=False)
class Scene:
    """What the scanner sees: a raster (same UTM grid family as the DEM, at texture_cell_m) of
    uint8 layers [cover id, brightness detail, white paint, black paint] and per-cover spectra.
    Radiance is a radiance factor (reflectance under unit illumination, 0–1); the scanner model
    applies illumination, gain and noise."""

    epsg: int
    transform: Affine
    cell_m: float
    layers: U8
    spectra: F32
    paint: F32

    @classmethod
    def from_scenario(cls, scn: Scenario, terrain: Terrain,
                      points: npt.NDArray[np.void] | None = None) -> Scene:
        """Builds the scene over the DEM; GCP targets are painted at `points` (default: the
        scenario's ground points)."""
        rng = np.random.default_rng([scn.seed, _TAG_SCENE])
        cell = scn.terrain.texture_cell_m
        dem = terrain.grid
        grid = _scene_grid(terrain, cell)
        score, threshold = _forest_score(rng, terrain)
        curves = [terrain.river, *_random_roads(rng, dem, cell)]
        layers = np.zeros((grid.rows, grid.cols, 4), np.uint8)
        _paint_cover(layers, np.array([grid.west_m, grid.north_m, cell]), score,
                     np.array([dem.west_m, dem.north_m, dem.cell_m]),
                     np.stack([c.packed() for c in curves]),
                     np.stack([c.offset_m for c in curves]),
                     np.stack([c.offset_slope for c in curves]),
                     _land_params(rng, cell, threshold), int(rng.integers(1, 2**31)),
                     np.array([int(c) for c in _CROPS]), np.array(_CROP_WEIGHTS))
        if points is None:
            points = ground_points(scn, terrain)
        unit = _marker_unit_m(scn)
        for pe, pn in zip(points["easting_m"], points["northing_m"], strict=True):
            _paint_marker(layers, grid, float(pe), float(pn), unit)
        bands = scn.scanner.bands
        return cls(terrain.epsg, grid.transform, cell, layers, cover_spectra(bands),
                   paint_spectra(bands))

    @staticmethod
    def raster_bytes(scn: Scenario, terrain: Terrain) -> int:
        """Memory the scene's layers will take, without building them."""
        g = _scene_grid(terrain, scn.terrain.texture_cell_m)
        return g.rows * g.cols * 4

    @property
    def bands(self) -> int:
        return int(self.spectra.shape[1])

    @property
    def band_centres_nm(self) -> F64:
        return band_centres_nm(self.bands)

    @property
    def grid(self) -> _Grid:
        return _Grid(self.transform.c, self.transform.f, self.cell_m, self.layers.shape[0],
                     self.layers.shape[1])

    def radiance(self, easting_m: npt.ArrayLike, northing_m: npt.ArrayLike, *,
                 nearest: bool = False, out: F32 | None = None) -> F32:
        """Radiance factor at UTM points, shape (bands, N) float32: bilinear between cell
        centres (mixed pixels), or the nearest cell; NaN outside the scene. `out` may be a
        preallocated (bands, N) float32 array."""
        e = np.ascontiguousarray(easting_m, dtype=np.float64).ravel()
        n = np.ascontiguousarray(northing_m, dtype=np.float64).ravel()
        if e.shape != n.shape:
            raise ValueError(f"easting and northing differ in size: {e.size} vs {n.size}")
        if out is None:
            out = np.empty((self.bands, e.size), np.float32)
        elif out.shape != (self.bands, e.size) or out.dtype != np.float32:
            raise ValueError(f"out must be float32 of shape {(self.bands, e.size)}")
        g = self.grid
        _sample_scene(self.layers, self.spectra, self.paint, g.west_m, g.north_m, g.cell_m, e, n,
                      nearest, out)
        return out

    def _cell_rows(self, r0: int, r1: int, spectra: F32, paint: F32) -> F32:
        """Radiance of every cell in rows r0:r1 for the given spectra, shape (b, rows, cols)."""
        lay = self.layers[r0:r1]
        factor = 0.5 + lay[..., L_DETAIL] / np.float32(255.0)
        white = lay[..., L_WHITE] / np.float32(255.0)
        dark = lay[..., L_DARK] / np.float32(255.0)
        base = spectra[lay[..., L_COVER]] * (factor * (1 - white - dark))[..., None]
        painted = white[..., None] * paint[0] + dark[..., None] * paint[1]
        return np.asarray(np.moveaxis(base + painted, -1, 0), dtype=np.float32)

    def write_scene_geotiff(self, path: str | Path) -> None:
        """Band-mean radiance factor at the texture cell, float32 GeoTIFF (tiled, DEFLATE)."""
        mean_spec = self.spectra.mean(axis=1, keepdims=True)
        mean_paint = self.paint.mean(axis=1, keepdims=True)
        rows, cols = self.layers.shape[:2]
        profile = dict(driver="GTiff", width=cols, height=rows, count=1, dtype="float32",
                       crs=CRS.from_epsg(self.epsg), transform=self.transform, nodata=np.nan,
                       tiled=True, blockxsize=256, blockysize=256, compress="deflate",
                       predictor=3, zlevel=1)
        with rasterio.Env(GDAL_CACHEMAX=64), rasterio.open(Path(path), "w", **profile) as ds:
            step = 256  # whole rows of tiles: each tile is compressed once
            for r0 in range(0, rows, step):
                r1 = min(rows, r0 + step)
                ds.write(self._cell_rows(r0, r1, mean_spec, mean_paint)[0], 1,
                         window=Window(0, r0, cols, r1 - r0))
            ds.update_tags(AREA_OR_POINT="Area", QUANTITY="band-mean radiance factor",
                           BANDS_NM=" ".join(f"{c:.1f}" for c in self.band_centres_nm))

    def quicklook_rgb(self, max_size_px: int = 2048) -> U8:
        """True-colour (≈640/550/470 nm) block-averaged image, 2–98 % stretch, (h, w, 3)."""
        pick = [int(np.abs(self.band_centres_nm - nm).argmin()) for nm in (640.0, 550.0, 470.0)]
        rows, cols = self.layers.shape[:2]
        k = max(1, math.ceil(max(rows, cols) / max_size_px))
        h, w = rows // k, cols // k
        rgb = np.empty((3, h, w), np.float32)
        step = _chunk_rows(cols, k)
        for r0 in range(0, h * k, step):
            r1 = min(h * k, r0 + step)
            cells = self._cell_rows(r0, r1, self.spectra[:, pick], self.paint[:, pick])
            blocks = cells[:, :, : w * k].reshape(3, (r1 - r0) // k, k, w, k)
            rgb[:, r0 // k : r1 // k] = blocks.mean(axis=(2, 4))
        lo, hi = (float(v) for v in np.percentile(rgb[:, ::4, ::4], [2.0, 98.0]))
        rgb -= lo
        rgb *= 1.0 / max(hi - lo, 1e-6)
        np.clip(rgb, 0.0, 1.0, out=rgb)
        rgb **= 1 / 1.6  # brighten the shadows a little
        rgb *= 255.0
        return np.moveaxis(np.rint(rgb, out=rgb).astype(np.uint8), 0, -1)

    def write_scene_quicklook(self, path: str | Path, max_size_px: int = 2048) -> None:
        """PNG quicklook of the scene (true colour), at most max_size_px on its longer side."""
        _write_png_rgb(Path(path), self.quicklook_rgb(max_size_px))


def _chunk_rows(cols: int, multiple: int) -> int:
    """Rows per chunk (a multiple of `multiple`) keeping per-chunk temporaries near 50 MB."""
    return max(1, 500_000 // (cols * multiple)) * multiple


def _write_png_rgb(path: Path, rgb: U8) -> None:
    """Minimal 8-bit RGB PNG: one IDAT, filter 0 on every row."""
    h, w, _ = rgb.shape
    raw = np.hstack([np.zeros((h, 1), np.uint8), rgb.reshape(h, w * 3)]).tobytes()

    def chunk(tag: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + tag + data
                + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF))

    header = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
                     + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))


# ---------------------------------------------------------------------------------------------
# Ground control and check points
# ---------------------------------------------------------------------------------------------

GROUND_POINT_DTYPE: Final = np.dtype([
    ("id", "U8"), ("kind", "U8"), ("easting_m", "f8"), ("northing_m", "f8"),
    ("height_m", "f8"), ("lat_deg", "f8"), ("lon_deg", "f8"),
])


@dataclass(frozen=True, eq=False)
class _StripCover:
    """Which strips image a ground point: nadir swaths of every strip, narrowed over high ground
    (the swath scales with the height of the aircraft above the terrain)."""

    start_m: F64  # (k, 2) plane east, north
    unit: F64  # (k, 2) along-strip unit vectors
    length_m: F64
    half_swath_m: float
    flight_height_m: float
    agl_m: float

    @classmethod
    def from_scenario(cls, scn: Scenario) -> _StripCover:
        lines = strip_lines(scn)
        start = np.array([s.start_en_m for s in lines])
        delta = np.array([s.end_en_m for s in lines]) - start
        length = np.hypot(delta[:, 0], delta[:, 1])
        agl = scn.block.flying_height_agl_m
        return cls(start, delta / length[:, None], length,
                   block_figures(scn).swath_width_m / 2.0,
                   scn.terrain.mean_height_m + agl, agl)

    def count(self, east_m: F64, north_m: F64, height_m: F64, inset_m: float) -> npt.NDArray[
            np.int64]:
        """Strips whose swath holds each point at least inset_m from its edges and ends."""
        rel_e = east_m[:, None] - self.start_m[None, :, 0]
        rel_n = north_m[:, None] - self.start_m[None, :, 1]
        along = rel_e * self.unit[:, 0] + rel_n * self.unit[:, 1]
        across = np.abs(rel_n * self.unit[:, 0] - rel_e * self.unit[:, 1])
        half = self.half_swath_m * (self.flight_height_m - height_m) / self.agl_m
        inside = ((along >= inset_m) & (along <= self.length_m - inset_m)
                  & (across <= half[:, None] - inset_m))
        return np.asarray(inside.sum(axis=1), dtype=np.int64)


class _Spacing:
    """Grid hash refusing points closer than min_m to any accepted one (targets never touch)."""

    def __init__(self, min_m: float) -> None:
        self.min_m = min_m
        self.cells: dict[tuple[int, int], list[tuple[float, float]]] = {}

    def try_add(self, e: float, n: float) -> bool:
        ci, cj = math.floor(e / self.min_m), math.floor(n / self.min_m)
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                for pe, pn in self.cells.get((ci + di, cj + dj), ()):
                    if math.hypot(pe - e, pn - n) < self.min_m:
                        return False
        self.cells.setdefault((ci, cj), []).append((e, n))
        return True


_Sampler = Callable[[int], tuple[F64, F64]]


def _target_reach_m(scn: Scenario) -> float:
    """From a ground point to its target's farthest corner."""
    return TARGET_SQUARE_HALF * _marker_unit_m(scn) * math.sqrt(2.0)


def _point_inset_m(scn: Scenario) -> float:
    """How far inside the block's edge a ground point must lie: its target, and a margin from
    the swath's edge."""
    return 0.05 * block_figures(scn).swath_width_m + _target_reach_m(scn)


def ground_point_room_problem(scn: Scenario) -> str | None:
    """Why the block has no room for the scenario's ground points (None: it has, or it asks
    for none)."""
    if scn.terrain.control_points + scn.terrain.check_points == 0:
        return None
    fig = block_figures(scn)
    inset_m = _point_inset_m(scn)
    if fig.block_length_m > 2.0 * inset_m and fig.block_width_m > 2.0 * inset_m:
        return None
    return (f"terrain: ground points need {2 * inset_m:.0f} m of margin (their targets and the "
            f"swath's edge) but the block is {fig.block_length_m:.0f} x "
            f"{fig.block_width_m:.0f} m: use a finer terrain.texture_cell_m, a larger block, or "
            "no control and check points")


class _Placer:
    """Draws candidate points in the block frame (u along the first strip heading, v to its
    right, origin at the block centre) and keeps those imaged often enough and far enough
    apart."""

    MAX_ROUNDS: Final = 60
    MAX_STALE_ROUNDS: Final = 4
    RESCUE_BATCH: Final = 256

    def __init__(self, scn: Scenario, terrain: Terrain, rng: np.random.Generator) -> None:
        fig = block_figures(scn)
        h = math.radians(scn.block.first_strip_heading_deg)
        self.along = np.array([math.sin(h), math.cos(h)])
        self.right = np.array([math.cos(h), -math.sin(h)])
        self.plane = LocalPlane.for_scenario(scn)
        self.terrain = terrain
        self.rng = rng
        self.cover = _StripCover.from_scenario(scn)
        self.inset_m = _point_inset_m(scn)
        self.band_m = 0.3 * fig.swath_width_m
        self.half_u = fig.block_length_m / 2.0 - self.inset_m
        self.half_v = fig.block_width_m / 2.0 - self.inset_m
        if (problem := ground_point_room_problem(scn)) is not None:
            raise ConfigError(problem)
        self.spacing = _Spacing(3.0 * _target_reach_m(scn))
        self.overlap = 2 if len(strip_lines(scn)) > 1 else 1

    def ring(self, m: int) -> tuple[F64, F64]:
        """Stratified along the block's perimeter, up to band_m inside it."""
        hu, hv = self.half_u, self.half_v
        perimeter = 4.0 * (hu + hv)
        s = ((np.arange(m) + self.rng.uniform(size=m)) / m + self.rng.uniform()) % 1.0
        s *= perimeter
        depth = self.rng.uniform(0.0, min(self.band_m, hu, hv), size=m)
        u = np.empty(m)
        v = np.empty(m)
        side = np.searchsorted(np.cumsum([2 * hu, 2 * hv, 2 * hu, 2 * hv]), s, side="right")
        offs = s - np.concatenate([[0.0], np.cumsum([2 * hu, 2 * hv, 2 * hu])])[np.minimum(side, 3)]
        for k, (uu, vv) in enumerate([(-hu + offs, -hv + depth), (hu - depth, -hv + offs),
                                      (hu - offs, hv - depth), (-hu + depth, hv - offs)]):
            sel = side == k
            u[sel], v[sel] = uu[sel], vv[sel]
        return u, v

    def inner(self, m: int) -> tuple[F64, F64]:
        """Uniform inside the ring band."""
        hu = max(self.half_u - self.band_m, 0.0)
        hv = max(self.half_v - self.band_m, 0.0)
        return self.rng.uniform(-hu, hu, m), self.rng.uniform(-hv, hv, m)

    def stratified(self, m: int) -> tuple[F64, F64]:
        """Jittered grid over the whole block: uniform coverage without clumps."""
        hu, hv = self.half_u, self.half_v
        nu = max(1, round(math.sqrt(m * hu / hv)))
        nv = math.ceil(m / nu)
        cells = self.rng.permutation(nu * nv)[:m]
        iu, iv = cells // nv, cells % nv
        u = -hu + (iu + self.rng.uniform(size=m)) * (2 * hu / nu)
        v = -hv + (iv + self.rng.uniform(size=m)) * (2 * hv / nv)
        return u, v

    def place(self, count: int, sampler: _Sampler, min_strips: int, what: str) -> tuple[F64, F64]:
        """UTM (easting, northing) of `count` accepted points. Each round draws as many
        candidates as are missing; after MAX_STALE_ROUNDS rounds without a point it goes on
        with RESCUE_BATCH candidates a round (one missing point drawn four times failed on
        ~1 % of seeds, e.g. an inner control point needing two strips' overlap; a placement
        that succeeds in the first phase is unchanged by the second)."""
        got_e: list[float] = []
        got_n: list[float] = []
        for batch in (None, self.RESCUE_BATCH):
            stale = 0
            for _ in range(self.MAX_ROUNDS):
                if len(got_e) == count or stale == self.MAX_STALE_ROUNDS:
                    break
                before = len(got_e)
                u, v = sampler(count - len(got_e) if batch is None else batch)
                self._accept(u, v, min_strips, count, got_e, got_n)
                stale = stale + 1 if len(got_e) == before else 0
        if len(got_e) < count:
            raise ConfigError(f"terrain: could place only {len(got_e)} of {count} {what} points "
                              "inside the block; ask for fewer points or a larger block")
        return np.array(got_e), np.array(got_n)

    def _accept(self, u: F64, v: F64, min_strips: int, count: int, got_e: list[float],
                got_n: list[float]) -> None:
        """Append the candidates (block u, v) that lie on the DEM, in `min_strips` swaths and
        clear of every accepted point, in order, up to `count`."""
        pe = u * self.along[0] + v * self.right[0]
        pn = u * self.along[1] + v * self.right[1]
        x, y = self.plane.plane_to_utm(pe, pn)
        h = self.terrain.height_at(x, y)
        ok = np.isfinite(h) & (self.cover.count(pe, pn, h, self.inset_m) >= min_strips)
        for i in np.flatnonzero(ok):
            if len(got_e) < count and self.spacing.try_add(float(x[i]), float(y[i])):
                got_e.append(float(x[i]))
                got_n.append(float(y[i]))


def ground_points(scn: Scenario, terrain: Terrain) -> npt.NDArray[np.void]:
    """Control points ('C001'…) mostly along the block borders, the rest inside it where strips
    overlap, and check points ('K001'…) spread uniformly over the block (seed 000 §6). Every
    point lies inside at least one strip's swath and carries its DEM height (ellipsoidal)."""
    n_ctrl, n_chk = scn.terrain.control_points, scn.terrain.check_points
    if n_ctrl + n_chk == 0:  # a block too small for points can still be flown without them
        return np.zeros(0, GROUND_POINT_DTYPE)
    rng = np.random.default_rng([scn.seed, _TAG_POINTS])
    placer = _Placer(scn, terrain, rng)
    n_border = round(n_ctrl * CONTROL_BORDER_FRACTION)
    parts = [placer.place(n_border, placer.ring, 1, "border control"),
             placer.place(n_ctrl - n_border, placer.inner, placer.overlap, "inner control"),
             placer.place(n_chk, placer.stratified, 1, "check")]
    e = np.concatenate([p[0] for p in parts])
    n = np.concatenate([p[1] for p in parts])
    table = np.zeros(e.size, GROUND_POINT_DTYPE)
    digits = max(3, len(str(max(n_ctrl, n_chk))))
    table["id"] = [f"C{i + 1:0{digits}d}" for i in range(n_ctrl)] + [
        f"K{i + 1:0{digits}d}" for i in range(n_chk)]
    table["kind"] = ["control"] * n_ctrl + ["check"] * n_chk
    table["easting_m"], table["northing_m"] = e, n
    table["height_m"] = terrain.height_at(e, n)
    table["lat_deg"], table["lon_deg"] = LocalPlane.for_scenario(scn).utm_to_geodetic(e, n)
    return table


def write_ground_points_csv(path: str | Path, points: npt.NDArray[np.void], *,
                            utm_epsg: int) -> None:
    """CSV with a '#' header naming columns, units and CRS; mm in UTM, 1e-9° in lat/lon."""
    name = CRS.from_epsg(utm_epsg).to_wkt().split('"')[1]
    lines = [
        f"# SISA ground points. easting_m, northing_m: {name} (EPSG:{utm_epsg}), metres. "
        "height_m: WGS 84 ellipsoidal height, metres (no geoid). "
        "lat_deg, lon_deg: WGS 84 geodetic, degrees. kind: control | check.",
        ",".join(GROUND_POINT_DTYPE.names or ()),
    ]
    lines += [f"{p['id']},{p['kind']},{p['easting_m']:.3f},{p['northing_m']:.3f},"
              f"{p['height_m']:.3f},{p['lat_deg']:.9f},{p['lon_deg']:.9f}" for p in points]
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")
