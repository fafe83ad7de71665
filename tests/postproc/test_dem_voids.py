"""Voids in the DEM, from the file to the ray caster: declared nodata, NaN whatever the tag,
void markers without a tag (-9999, -32768, 3.4e38), a DEM with no valid height at all; rays
that meet a void miss (NaN) and no other ray moves; every ray of the ray caster ends, also on a
surface it cannot fit a map to.

Small synthetic DEMs (5 m cells) and a few thousand rays: fast."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
import rasterio
from pyproj import Transformer
from rasterio.crs import CRS
from rasterio.transform import Affine

from postproc.georef import dem as dem_module
from postproc.georef.dem import Dem, DemVoidWarning, dem_extent, height_range
from postproc.georef.raycast import (
    CastStats,
    GroundPoints,
    blocks,
    intersect,
    reference,
    reference_intersect,
)
from sisa.cli import main
from sisa.core.errors import InputError
from sisa.core.frames import body_to_ned_matrix, ned_to_ecef_matrix
from sisa.core.sensor import R_NOMINAL_C_TO_B

F64 = npt.NDArray[np.float64]
UTM31N = 32631
CELL_M = 5.0
WEST_M, NORTH_M = 400_000.0, 4_601_000.0  # raster corner (cell edges)
VOID = (slice(95, 105), slice(70, 90))  # rows, cols: 50 m x 100 m in the middle


def hills(rows: int = 200, cols: int = 160) -> F64:
    """300 m +- 25 m of smooth hills and a gentle tilt, (rows, cols), float64."""
    e = CELL_M * np.arange(cols)[None, :]
    n = CELL_M * np.arange(rows)[:, None]
    return np.asarray(300.0 + 20.0 * np.sin(e / 70.0) * np.cos(n / 90.0) + 0.01 * e - 0.02 * n)


def dem_of(heights: npt.ArrayLike) -> Dem:
    return Dem(np.asarray(heights, np.float32), WEST_M + 0.5 * CELL_M, NORTH_M - 0.5 * CELL_M,
               CELL_M, CELL_M, UTM31N)


def write_tif(path: Path, data: npt.NDArray[np.generic], nodata: float | None) -> Path:
    with rasterio.open(path, "w", driver="GTiff", width=data.shape[1], height=data.shape[0],
                       count=1, dtype=data.dtype, crs=CRS.from_epsg(UTM31N),
                       transform=Affine(CELL_M, 0.0, WEST_M, 0.0, -CELL_M, NORTH_M),
                       nodata=nodata) as ds:
        ds.write(data, 1)
    return path


def strip(lines: int, pixels: int, north0_m: float, step_m: float, seed: int = 3
          ) -> tuple[F64, F64, F64]:
    """Lines flown north 320 m above the hills over the middle of the DEM, ±30° across track,
    pitch swinging ±12° so rays cross the void's edges from the north and the south."""
    rng = np.random.default_rng(seed)
    north = north0_m + step_m * np.arange(lines)
    east = np.full(lines, WEST_M + 80.0 * CELL_M)
    pitch = np.radians(12.0) * np.sin(np.arange(lines) / 3.0)
    roll = np.radians(2.0) * rng.standard_normal(lines)
    lon, lat = Transformer.from_crs(UTM31N, 4326, always_xy=True).transform(east, north)
    x, y, z = Transformer.from_crs(4979, 4978, always_xy=True).transform(
        lon, lat, np.full(lines, 620.0))
    rot = (ned_to_ecef_matrix(np.radians(lat), np.radians(lon))
           @ body_to_ned_matrix(roll, pitch, np.zeros(lines)) @ R_NOMINAL_C_TO_B)
    ang = np.radians(np.linspace(-30.0, 30.0, pixels))
    look = np.stack([np.zeros(pixels), np.tan(ang), -np.ones(pixels)])  # camera z: up
    return np.stack([x, y, z], axis=-1), rot, look


def centre_row_col(gp: GroundPoints) -> tuple[F64, F64]:
    """Fractional (row, col) of the points in the DEM's cell-centre grid."""
    col = (gp.easting_m - WEST_M) / CELL_M - 0.5
    row = (NORTH_M - gp.northing_m) / CELL_M - 0.5
    return row, col


# ---------------------------------------------------------------------------------------------
# The ray caster
# ---------------------------------------------------------------------------------------------


def test_rays_meeting_a_void_miss_and_no_other_ray_moves() -> None:
    """The cell walk tested only max() of a cell's corners for NaN, which drops a NaN in second
    place: a ray went on below the terrain through cells half in the void and was 'hit' where
    it came out, on the last valid row, metres below the surface. Now: every hit lies on the
    surface, equals the intact DEM's hit, agrees with the reference; rays away from the void
    are untouched."""
    full = hills()
    holed = full.copy()
    holed[VOID] = np.nan
    dem_full, dem_void = dem_of(full), dem_of(holed)
    centre, rot, look = strip(90, 48, NORTH_M - 130.0 * CELL_M, 3.0)
    stats = CastStats()
    got = intersect(dem_void, centre, rot, look, stats=stats)
    intact = intersect(dem_full, centre, rot, look)
    assert intact.hit.all()
    assert stats.safe_hit + stats.safe_miss > 0  # rays near the void take the cell walk
    lost = intact.hit & ~got.hit
    assert 200 < lost.sum() < 0.5 * got.hit.size

    # every hit is a point of the surface, never one in or under the void
    gap = got.height_m[got.hit] - dem_void.height_at(got.easting_m[got.hit],
                                                     got.northing_m[got.hit])
    assert np.isfinite(gap).all()
    assert np.abs(gap).max() < 1e-3
    # ... and is where the ray meets the intact DEM (same surface all along its path)
    for a, b in ((got.easting_m, intact.easting_m), (got.northing_m, intact.northing_m),
                 (got.height_m, intact.height_m)):
        assert np.abs(a[got.hit] - b[got.hit]).max() < 1e-4
        assert np.isnan(a[~got.hit]).all()

    # rays whose ground point is well away from the void (more than a path through the
    # relief: 40 m x tan 42° < 8 cells) still hit
    row, col = centre_row_col(intact)
    away = ((row < VOID[0].start - 10) | (row > VOID[0].stop + 9)
            | (col < VOID[1].start - 10) | (col > VOID[1].stop + 9))
    assert away.sum() > 1000
    assert got.hit[away].all()

    # the reference agrees ray for ray on the lines that lose rays
    lines = np.flatnonzero(lost.any(axis=1))[::4]
    ref = reference_intersect(dem_void, centre[lines], rot[lines], look)
    np.testing.assert_array_equal(ref.hit, got.hit[lines])


def test_void_markers_in_the_heights_are_refused_at_once() -> None:
    """-9999 left in the heights makes a 10 km pit: no block map fits such a height range and
    every ray went to the reference march, whose steps shrank with the pit's 2000:1 walls: it
    ran for hours. Now a one-line InputError, before any ray is cast."""
    heights = hills()
    heights[100:103, 80:83] = -9999.0
    centre, rot, look = strip(4, 8, NORTH_M - 100.0 * CELL_M, 3.0)
    with pytest.raises(InputError, match=r"heights from -9999 to .* outside any terrain"):
        intersect(dem_of(heights), centre, rot, look)
    heights[100:103, 80:83] = 3.4e38
    with pytest.raises(InputError, match="outside any terrain"):
        intersect(dem_of(heights), centre, rot, look)


def test_a_dem_with_no_valid_height_is_an_input_error() -> None:
    centre, rot, look = strip(4, 8, NORTH_M - 100.0 * CELL_M, 3.0)
    with pytest.raises(InputError, match="no valid height"):
        intersect(dem_of(np.full((20, 20), np.nan)), centre, rot, look)


def test_reference_march_steps_by_local_slopes_and_every_ray_ends(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A 2000 m mast on one cell far from the strip: the reference march used the DEM's
    steepest slope (~280) for every step of every ray; with the slopes within reach it needs
    a few hundred steps. A ray still marching after REFERENCE_MAX_STEPS is a miss, counted:
    every call ends with a defined result for every ray."""
    heights = hills()
    heights[5, 5] = 2300.0
    dem = dem_of(heights)
    centre, rot, look = strip(3, 12, NORTH_M - 100.0 * CELL_M, 3.0)
    fast = intersect(dem, centre, rot, look)
    assert fast.hit.all()

    monkeypatch.setattr(reference, "REFERENCE_MAX_STEPS", 400)
    ref = reference_intersect(dem, centre, rot, look)
    assert ref.hit.all()
    for a, b in ((ref.easting_m, fast.easting_m), (ref.northing_m, fast.northing_m),
                 (ref.height_m, fast.height_m)):
        assert np.abs(a - b).max() < 1e-3

    # no block map fits (tolerance 0): every ray goes to the reference march, which may take
    # 2 steps: all end unresolved, missed, counted
    monkeypatch.setattr(blocks, "MAP_TOLERANCE_M", 0.0)
    monkeypatch.setattr(reference, "REFERENCE_MAX_STEPS", 2)
    stats = CastStats()
    none = intersect(dem, centre, rot, look, stats=stats)
    assert stats.exact == stats.unresolved == none.hit.size
    assert not none.hit.any()
    assert np.isnan(none.easting_m).all()


# ---------------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------------


def test_void_markers_without_a_nodata_tag_are_read_as_voids(tmp_path: Path) -> None:
    data = hills(40, 30).astype(np.float32)
    data[10:13, 5:8] = -9999.0
    data[20, 20] = -32768.0
    data[30, 3] = 3.4028235e38
    data[0, 0] = -500.0  # low, but terrain can be: kept
    data[1, 1] = 0.0
    markers = np.zeros(data.shape, bool)
    markers[10:13, 5:8] = markers[20, 20] = markers[30, 3] = True
    path = write_tif(tmp_path / "untagged.tif", data, nodata=None)
    with pytest.warns(DemVoidWarning, match=r"11 DEM cells hold -9999, .*no nodata value"):
        dem = Dem.read(path)
    assert np.isnan(dem.heights_m[markers]).all()
    np.testing.assert_array_equal(dem.heights_m[~markers], data[~markers])
    assert height_range(path, overview=1) == (-500.0, float(data[~markers].max()))

    # an int16 DEM (SRTM style) whose -32768 is not declared
    ints = np.round(hills(40, 30)).astype(np.int16)
    ints[3:5, 3:5] = -32768
    with pytest.warns(DemVoidWarning, match="4 DEM cells hold -32768"):
        dem = Dem.read(write_tif(tmp_path / "int16.tif", ints, nodata=None))
    assert np.isnan(dem.heights_m).sum() == 4

    # declared: the same cells, no warning
    data[20, 20] = data[30, 3] = -9999.0
    with warnings.catch_warnings():
        warnings.simplefilter("error", DemVoidWarning)
        dem = Dem.read(write_tif(tmp_path / "tagged.tif", data, nodata=-9999.0))
    assert np.isnan(dem.heights_m[markers]).all()


@pytest.mark.parametrize("nodata", [None, -9999.0, math.nan])
def test_nan_heights_are_voids_whatever_the_nodata_tag(tmp_path: Path,
                                                       nodata: float | None) -> None:
    data = hills(40, 30).astype(np.float32)
    data[10:20, 10:20] = np.nan
    path = write_tif(tmp_path / "nan.tif", data, nodata=nodata)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DemVoidWarning)  # NaN needs no note
        dem = Dem.read(path)
    assert np.isnan(dem.heights_m).sum() == 100
    low, high = height_range(path, overview=1) or (math.nan, math.nan)
    assert (low, high) == (float(np.nanmin(data)), float(np.nanmax(data)))
    assert dem_extent(path)[0] == UTM31N
    # bounds made from a NaN height range: a clear error, not "bad bounds (nan, ...)"
    with pytest.raises(InputError, match="are not finite"):
        Dem.read(path, bounds_m=(math.nan,) * 4)


@pytest.mark.parametrize(("fill", "nodata"), [(math.nan, None), (math.nan, -9999.0),
                                          (-9999.0, -9999.0), (-9999.0, None)])
def test_a_dem_file_with_no_valid_height_is_refused(tmp_path: Path, fill: float,
                                                    nodata: float | None) -> None:
    path = write_tif(tmp_path / "void.tif", np.full((30, 20), fill, np.float32), nodata)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DemVoidWarning)
        for read in (lambda: Dem.read(path), lambda: dem_extent(path),
                     lambda: Dem.read(path, bounds_m=(math.nan,) * 4)):
            with pytest.raises(InputError, match="the DEM has no valid height"):
                read()
    assert height_range(path) is None


def test_valid_dem_but_a_void_window_names_the_window(tmp_path: Path) -> None:
    data = hills(40, 30).astype(np.float32)
    data[:20] = np.nan
    path = write_tif(tmp_path / "north_void.tif", data, nodata=None)
    inside = (WEST_M + 40.0, NORTH_M - 40.0, WEST_M + 60.0, NORTH_M - 20.0)
    with pytest.raises(InputError, match="no valid height in the window"):
        Dem.read(path, bounds_m=inside, margin_m=0.0)


@pytest.mark.parametrize(("fill", "nodata"), [(-9999.0, -9999.0), (math.nan, None)])
def test_georef_on_a_dem_with_no_valid_height_stops_at_once_with_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], fill: float,
        nodata: float | None) -> None:
    """Refused before the flight is read (exit 2, one line): it was a traceback from the ray
    caster (ValueError, exit 1), or 'bad bounds (nan, nan, nan, nan)' after the sync."""
    dem = write_tif(tmp_path / "void.tif", np.full((30, 20), fill, np.float32), nodata)
    (tmp_path / "flight.mcap").write_bytes(b"")
    (tmp_path / "scanner").mkdir()
    code = main(["georef", str(tmp_path / "flight.mcap"), "--scanner", str(tmp_path / "scanner"),
                 "--dem", str(dem), "--out", str(tmp_path / "geo"), "--no-products"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1
    assert f"{dem}: the DEM has no valid height" in err
    assert not (tmp_path / "geo").exists()


@pytest.mark.parametrize("overview", [1, 4])
def test_a_whole_dem_is_scanned_in_bounded_windows_of_whole_blocks(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, overview: int) -> None:
    """A scan of the whole raster (for a valid height, or its overview's height range) reads
    windows of whole blocks of about SCAN_CELLS overview cells: every cell once, in memory that
    does not grow with the raster (1024 whole rows of a 200 000-column DEM once took 3.2 GB)."""
    monkeypatch.setattr(dem_module, "SCAN_CELLS", 1024)
    rows, cols = 300, 500
    data = np.full((rows, cols), np.nan, np.float32)
    data[251:253, 433:435] = [[200.0, 210.0], [220.0, 299.0]]
    path = tmp_path / "tiled.tif"
    with rasterio.open(path, "w", driver="GTiff", width=cols, height=rows, count=1,
                       dtype="float32", crs=CRS.from_epsg(UTM31N), tiled=True, blockxsize=64,
                       blockysize=32, transform=Affine(CELL_M, 0.0, WEST_M, 0.0, -CELL_M,
                                                       NORTH_M)) as ds:
        ds.write(data, 1)
    seen = np.zeros((rows, cols), np.int64)
    with rasterio.open(path) as ds:
        windows = list(dem_module._scan_windows(ds, overview))
        # the valid patch lies outside dem_extent's 64 x 64 sample: only the scan finds it
        assert np.isnan(ds.read(1, out_shape=(64, 64))).all()
    for win, (out_rows, out_cols) in windows:
        seen[win.row_off:win.row_off + win.height, win.col_off:win.col_off + win.width] += 1
        assert win.row_off % 32 == 0
        assert win.col_off % 64 == 0
        assert out_rows * out_cols <= 4 * 1024
    assert len(windows) > 4
    assert (seen == 1).all()
    assert dem_extent(path)[0] == UTM31N
    assert height_range(path, overview=1) == (200.0, 299.0)


def test_a_void_window_is_named_to_a_decimetre(tmp_path: Path) -> None:
    """The window was printed as computed (400040.00000000006, ... (+0.0 m)): to 0.1 m now."""
    data = hills(40, 30).astype(np.float32)
    data[:20] = np.nan
    path = write_tif(tmp_path / "north_void.tif", data, nodata=None)
    inside = (WEST_M + 40.00000000006, NORTH_M - 40.04, WEST_M + 60.0, NORTH_M - 20.0)
    with pytest.raises(InputError) as err:
        Dem.read(path, bounds_m=inside, margin_m=0.0)
    assert str(err.value) == (f"{path}: the DEM has no valid height in the window (400040.0, "
                              "4600960.0, 400060.0, 4600980.0) (+0 m)")
