"""postproc.georef.dem: reading GeoTIFF DEMs, checked against rasterio/GDAL (cell centres, windows,
masks), pyproj (geoid sampling) and the emulator's own terrain sampler."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
from pyproj import Transformer
from rasterio.crs import CRS
from rasterio.transform import Affine
from rasterio.windows import from_bounds

from emulators.scenario import load_scenario
from emulators.terrain import Terrain
from postproc.georef.dem import Dem, DemVoidWarning, band_note
from sisa.core.errors import InputError

UTM31N = 32631


def north_up(west: float, north: float, xsize: float, ysize: float) -> Affine:
    """rasterio's from_origin without its deprecated `*` composition (a warning per call)."""
    return Affine(xsize, 0.0, west, 0.0, -ysize, north)


def write_tif(path: Path, data: np.ndarray, transform: Affine, crs: int | str = UTM31N,
              nodata: float | None = None) -> Path:
    with rasterio.open(path, "w", driver="GTiff", width=data.shape[1], height=data.shape[0],
                       count=1, dtype=data.dtype, crs=CRS.from_user_input(crs),
                       transform=transform, nodata=nodata) as ds:
        ds.write(data, 1)
    return path


@pytest.fixture
def small(tmp_path: Path) -> Path:
    """5 rows x 4 cols, value = 10·row + col, 2 m cells, corner (401000, 4600000)."""
    data = (10.0 * np.arange(5)[:, None] + np.arange(4)[None, :]).astype(np.float32)
    return write_tif(tmp_path / "small.tif", data, north_up(401_000.0, 4_600_000.0, 2.0, 2.0))


def test_samples_belong_to_cell_centres(small: Path) -> None:
    """GDAL's own cell centres (rasterio `xy`, offset 'center') carry exactly the cell's value;
    the raster's corner (half a cell out) is off the surface."""
    dem = Dem.read(small)
    with rasterio.open(small) as ds:
        values = ds.read(1)
        for row, col in [(0, 0), (2, 1), (4, 3), (3, 2)]:
            x, y = ds.xy(row, col)
            assert dem.height_at(x, y) == pytest.approx(values[row, col], abs=1e-9)
        corner_x, corner_y = ds.transform @ (0, 0)
    assert np.isnan(dem.height_at(corner_x, corner_y))
    assert dem.bounds_m == (401_001.0, 4_599_991.0, 401_007.0, 4_599_999.0)
    assert dem.epsg == UTM31N
    assert dem.heights_m.dtype == np.float32


def test_height_is_bilinear_between_centres(small: Path) -> None:
    dem = Dem.read(small)
    # value = 10·row + col is bilinear itself, so interpolation must reproduce it anywhere
    rng = np.random.default_rng(1)
    col = rng.uniform(0.0, 3.0, 50)
    row = rng.uniform(0.0, 4.0, 50)
    e = 401_001.0 + 2.0 * col
    n = 4_599_999.0 - 2.0 * row
    np.testing.assert_allclose(dem.height_at(e, n), 10.0 * row + col, atol=1e-9)
    midpoint = dem.height_at(401_002.0, 4_599_998.0)  # between cells (0,0),(0,1),(1,0),(1,1)
    assert midpoint == pytest.approx((0 + 1 + 10 + 11) / 4.0)


def test_window_covers_the_bounds_plus_margin_only(tmp_path: Path) -> None:
    data = np.random.default_rng(2).uniform(100, 900, (300, 400)).astype(np.float32)
    path = write_tif(tmp_path / "big.tif", data, north_up(500_000.0, 4_700_000.0, 5.0, 5.0))
    bounds = (500_600.0, 4_699_000.0, 500_900.0, 4_699_400.0)
    dem = Dem.read(path, bounds_m=bounds, margin_m=50.0)
    w, s, e, n = dem.bounds_m
    assert w <= bounds[0] - 50
    assert s <= bounds[1] - 50
    assert e >= bounds[2] + 50
    assert n >= bounds[3] + 50
    assert w > bounds[0] - 50 - 5.0
    assert e < bounds[2] + 50 + 5.0
    assert dem.rows * dem.cols < data.size / 10
    with rasterio.open(path) as ds:
        win = from_bounds(w - 2.5, s - 2.5, e + 2.5, n + 2.5, ds.transform)
        expected = ds.read(1, window=win.round_offsets().round_lengths())
    np.testing.assert_array_equal(dem.heights_m, expected)


def test_nodata_becomes_nan_and_no_surface_next_to_it(tmp_path: Path) -> None:
    data = np.full((6, 6), 250.0, np.float32)
    data[2, 3] = -9999.0
    path = write_tif(tmp_path / "hole.tif", data, north_up(400_000.0, 4_600_000.0, 1.0, 1.0),
                     nodata=-9999.0)
    dem = Dem.read(path)
    assert np.isnan(dem.heights_m[2, 3])
    assert np.isfinite(dem.heights_m).sum() == 35
    with rasterio.open(path) as ds:
        x, y = ds.xy(2, 3)
        far_x, far_y = ds.xy(5, 0)
    assert np.isnan(dem.height_at(x - 0.4, y + 0.3))  # in a cell touching the hole
    assert dem.height_at(far_x, far_y) == 250.0


def test_constant_geoid_adds_the_undulation(small: Path) -> None:
    plain = Dem.read(small)
    shifted = Dem.read(small, geoid=49.5)
    np.testing.assert_allclose(shifted.heights_m, plain.heights_m + np.float32(49.5))


def test_geoid_raster_in_another_crs_is_sampled_at_the_centres(tmp_path: Path,
                                                                small: Path) -> None:
    """A geographic grid of N = 40 + 3·lon − 0.5·lat (bilinear interpolation reproduces a
    linear function exactly): the DEM gains N at every cell centre, as pyproj says."""
    lon0, lat0, step = 1.5, 42.0, 0.01  # covers UTM 31N near 401 km E, 4600 km N
    lon_c = lon0 + step * (np.arange(60) + 0.5)
    lat_c = lat0 - step * (np.arange(60) + 0.5)
    grid = (40.0 + 3.0 * lon_c[None, :] - 0.5 * lat_c[:, None]).astype(np.float32)
    geoid = write_tif(tmp_path / "geoid.tif", grid, north_up(lon0, lat0, step, step), 4326)
    dem = Dem.read(small, geoid=geoid)
    plain = Dem.read(small)
    e, n = np.meshgrid(*plain.centres_m())
    lon, lat = Transformer.from_crs(UTM31N, 4326, always_xy=True).transform(e, n)
    expected = plain.heights_m + (40.0 + 3.0 * lon - 0.5 * lat)
    np.testing.assert_allclose(dem.heights_m, expected, atol=2e-4)


def test_geoid_that_does_not_cover_the_dem_is_refused(tmp_path: Path, small: Path) -> None:
    grid = np.zeros((10, 10), np.float32)
    geoid = write_tif(tmp_path / "far.tif", grid, north_up(20.0, 10.0, 0.1, 0.1), 4326)
    with pytest.raises(InputError, match=r"far\.tif"):
        Dem.read(small, geoid=geoid)


def damaged_tif(path: Path) -> Path:
    """A DEFLATE GeoTIFF whose first block's bytes are overwritten: its header still opens."""
    data = np.arange(64 * 64, dtype=np.float32).reshape(64, 64)
    with rasterio.open(path, "w", driver="GTiff", width=64, height=64, count=1,
                       dtype="float32", crs=CRS.from_epsg(UTM31N), compress="deflate",
                       transform=north_up(401_000.0, 4_600_000.0, 2.0, 2.0)) as ds:
        ds.write(data, 1)
    with rasterio.open(path) as ds:
        at = int(ds.get_tag_item("BLOCK_OFFSET_0_0", "TIFF", bidx=1))
        size = int(ds.get_tag_item("BLOCK_SIZE_0_0", "TIFF", bidx=1))
    with path.open("r+b") as fh:
        fh.seek(at)
        fh.write(b"\xa5" * size)
    return path


@pytest.mark.parametrize("case", ["missing", "text", "geographic", "rotated", "outside",
                                  "complex", "damaged", "damaged geoid"])
def test_bad_inputs_raise_one_line_input_errors(tmp_path: Path, small: Path, case: str) -> None:
    """"complex" and "damaged" were a traceback or numpy's warnings and heights from the real
    part (found by a bad-input sweep of `sisa georef`)."""
    data = np.zeros((4, 4), np.float32)
    kwargs: dict[str, object] = {}
    if case == "complex":
        path = write_tif(tmp_path / "c.tif", data.astype(np.complex64),
                         north_up(401_000.0, 4_600_000.0, 2.0, 2.0))
    elif case == "damaged":
        path = damaged_tif(tmp_path / "damaged.tif")
    elif case == "damaged geoid":
        path = small
        kwargs["geoid"] = damaged_tif(tmp_path / "geoid.tif")
    elif case == "missing":
        path = tmp_path / "nope.tif"
    elif case == "text":
        path = tmp_path / "dem.tif"
        path.write_text("not a raster\n")
    elif case == "geographic":
        path = write_tif(tmp_path / "geo.tif", data, north_up(2.0, 41.0, 1e-4, 1e-4), 4326)
    elif case == "rotated":
        path = write_tif(tmp_path / "rot.tif", data,
                         Affine(2.0, 0.5, 400_000.0, 0.5, -2.0, 4_600_000.0))
    else:
        path = small
        kwargs["bounds_m"] = (0.0, 0.0, 10.0, 10.0)
    with pytest.raises(InputError) as err:
        Dem.read(path, **kwargs)  # type: ignore[arg-type]
    message = str(err.value)
    assert str(kwargs.get("geoid", path)) in message
    assert "\n" not in message
    if case.startswith("damaged"):
        assert "cannot read band 1" in message


def test_reads_the_emulator_dem_as_the_emulator_samples_it(tmp_path: Path) -> None:
    """The bench terrain written by the emulator: same heights at interior points."""
    terrain = Terrain.from_scenario(load_scenario("bench"))
    path = tmp_path / "bench.tif"
    terrain.write_dem(path)
    dem = Dem.read(path)
    w, s, e, n = dem.bounds_m
    rng = np.random.default_rng(5)
    pe, pn = rng.uniform(w, e, 500), rng.uniform(s, n, 500)
    np.testing.assert_allclose(dem.height_at(pe, pn), terrain.height_at(pe, pn), atol=1e-4)


# --- found by a bad-input sweep of `sisa georef`: geoids no geoid is, bounds to 13 digits --------

def _geoid_tif(path: Path, grid: np.ndarray, nodata: float | None = None) -> Path:
    """A geographic geoid grid of 0.01° cells over the `small` DEM (41.5°N, 1.7°E; 60 x 60)."""
    return write_tif(path, grid.astype(np.float32), north_up(1.5, 42.0, 0.01, 0.01), 4326,
                     nodata=nodata)


@pytest.mark.parametrize("undulation", [1e308, 3.5e38, 1e6, -200.0, 110.5, float("nan")])
def test_constant_geoid_no_geoid_has_is_refused(small: Path, undulation: float) -> None:
    """1e308 was a ValueError traceback (float32 overflow), 1e6 an error blaming the DEM's
    heights, -200 accepted; Earth's geoid is -106..+85 m."""
    with pytest.raises(InputError) as err:
        Dem.read(small, geoid=undulation)
    assert str(err.value) == (f"{small}: geoid undulation {undulation:g}: must be -110 to "
                              "110 m (the geoid undulation on Earth: -106 to +85 m)")


@pytest.mark.parametrize(("fill", "nodata", "held"), [
    (np.nan, None, ""), (-32768.0, -32768.0, ""), (3000.0, None, "; 25 hold 3000"),
    (1e30, None, "; 25 hold 1e+30")])
def test_geoid_raster_without_a_valid_undulation_says_so(
        tmp_path: Path, small: Path, fill: float, nodata: float | None, held: str) -> None:
    """All NaN or nodata was "does not cover the DEM" (it does); 3000 m was taken, leaving
    every ray under the surface ("no pixel could be georeferenced: does the DEM cover the
    flight?"); 1e30 a warning with the DEM's plausible range."""
    geoid = _geoid_tif(tmp_path / "geoid.tif", np.full((60, 60), fill), nodata)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputError) as err:
            Dem.read(small, geoid=geoid)
    assert str(err.value) == (f"{geoid}: the geoid raster has no valid undulation over the "
                              "DEM (every cell there is nodata, NaN or outside -110..110 m, the "
                              f"geoid's range{held})")


def test_geoid_raster_voids_are_said_against_the_geoids_range(tmp_path: Path,
                                                              small: Path) -> None:
    """A 1e30 beside the cells the DEM needs: a void, said with the geoid's range (it was the
    DEM's, -1000..9000 m); under a DEM cell: an error naming the cells."""
    grid = np.full((60, 60), 49.5)
    with rasterio.open(small) as ds:
        lon, lat = Transformer.from_crs(UTM31N, 4326, always_xy=True).transform(*ds.xy(2, 1))
    row, col = int((42.0 - lat) / 0.01), int((lon - 1.5) / 0.01)
    grid[row - 2, col] = 1e30  # read (the window has a cell of margin) but not needed
    geoid = _geoid_tif(tmp_path / "geoid.tif", grid)
    with pytest.warns(DemVoidWarning) as said:
        dem = Dem.read(small, geoid=geoid)
    note, = (str(w.message) for w in said)
    assert note == (f"{geoid}: 1 geoid cell holds 1e+30, outside -110..110 m, and no nodata "
                    "value declares it: read as void (no undulation there)")
    np.testing.assert_allclose(dem.heights_m, Dem.read(small).heights_m + np.float32(49.5))
    grid[row, col] = 1e30
    _geoid_tif(geoid, grid)
    with pytest.raises(InputError, match=r"no valid undulation at 20 DEM cells \(nodata, NaN or "
                                         r"outside -110\.\.110 m"):
        Dem.read(small, geoid=geoid)


def test_bounds_off_the_dem_are_said_to_a_decimetre(small: Path) -> None:
    """They were 416188.9330400008 and (+500.0 m)."""
    far = (416_188.93304000085, 4_604_056.222936864, 417_390.30419914704, 4_607_628.619075728)
    with pytest.raises(InputError) as err:
        Dem.read(small, bounds_m=far)
    assert str(err.value) == (f"{small}: bounds (416188.9, 4604056.2, 417390.3, 4607628.6) "
                              "(+500 m) do not overlap the DEM (401001.0, 4599991.0, 401007.0, "
                              "4599999.0)")


def test_a_raster_of_several_bands_is_said(tmp_path: Path, small: Path) -> None:
    path = tmp_path / "rgb.tif"
    with rasterio.open(path, "w", driver="GTiff", width=4, height=5, count=3, dtype="float32",
                       crs=CRS.from_epsg(UTM31N),
                       transform=north_up(401_000.0, 4_600_000.0, 2.0, 2.0)) as ds:
        ds.write(np.ones((3, 5, 4), np.float32))
    assert band_note(small) is None
    assert band_note(path) == (f"{path}: the DEM raster has 3 bands: band 1 is read as heights, "
                               "the others are ignored")
