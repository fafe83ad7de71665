"""`sisa georef` with a DEM whose window under one strip holds voids only (sea masked as nodata,
a hole in a mosaic): that segment is skipped, said once with its swath's bounds (stderr,
summary, reason "DEM voids"), nothing written for it, and the others are georeferenced; only
when every swath lies over voids (or off the DEM) does the job stop, in one line (exit 2).

Before, such a segment failed the whole job: "DEM.tif: the DEM has no valid height in the
window (415611.6, 4605459.6, 416484.8, 4606250.7) (+500 m)", naming no segment. A segment only
partly over voids (its window holds valid heights) is cast as before, its misses said.

On the seven-strip run of test_georef_dem_cover, with DEMs voided here from its own."""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
import rasterio
from rasterio.transform import Affine

from postproc.georef import Dem, GeorefJob, GeorefOptions, SegmentResult, SensorModel
from postproc.georef.demcover import SwathOnDem
from sisa.core.errors import InputError
from tests.exitcodes import INCOMPLETE, without_losses_line
from tests.postproc.test_georef_dem_cover import BOUNDS, georef, seven_run, warned

__all__ = ["seven_run"]  # the run's fixture, simulated once per session

# segment 6's swath ends near 416185 m east and its DEM window 800 m beyond (416985); segment
# 5's window reaches about 417190: voids west of here void the one window but not the other
VOID_WEST_OF_M = 417_080.0
VALID_EAST_OF_M = 419_000.0  # a DEM widened east, valid only here: every window is void
F64 = npt.NDArray[np.float64]


def voided_dem(run: Path, path: Path, valid: Callable[[F64], npt.NDArray[np.bool_]],
               widen_cells: int = 0) -> Path:
    """The run's DEM (widened east by `widen_cells` cells of 100 m) with every cell whose
    centre easting is not `valid` set to its nodata value."""
    with rasterio.open(run / "terrain" / "dem.tif") as ds:
        profile = ds.profile
        heights = ds.read(1)
        t: Affine = ds.transform
    nodata = profile["nodata"]
    assert nodata is not None
    heights = np.concatenate(
        [heights, np.full((heights.shape[0], widen_cells), 100.0, heights.dtype)], axis=1)
    east = t.c + (np.arange(heights.shape[1]) + 0.5) * t.a
    heights[:, ~valid(east)] = nodata
    profile.update(width=heights.shape[1])
    with rasterio.open(path, "w", **profile) as out:
        out.write(heights, 1)
    return path


def test_a_segment_over_dem_voids_only_is_skipped_and_the_others_mapped(
        seven_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    dem = voided_dem(seven_run, tmp_path / "west_void.tif", lambda e: e >= VOID_WEST_OF_M)
    out = tmp_path / "geo"
    rc, stdout, err = georef(seven_run, dem, out, capsys)
    assert rc == INCOMPLETE, err  # lines promised, not all made
    err = without_losses_line(err)
    assert stdout.startswith(f"{out}: 6 of 7 segments (1 skipped), ")
    *partial, void = warned(err)
    # segments 1-5, partly or wholly over voids but with valid heights in their window: cast
    # as before, their misses said
    assert [note.split(":")[0] for note in partial] == [f"segment {s}" for s in range(1, 6)]
    assert all("(voids in the DEM under the swath?)" in note for note in partial)
    found = re.fullmatch(rf"segment 6: skipped, its swath {BOUNDS} lies over DEM voids only "
                         r"\(nodata\): the DEM west_void\.tif has no valid height within 800 m "
                         "of it", void)
    assert found is not None, void
    west, south, east, north = (float(v) for v in found.groups())
    assert west < east < VOID_WEST_OF_M - 800.0
    assert south < north

    # the segments cast: their files; segment 6: nothing at all
    for segment in range(6):
        for suffix in ("eo.csv", "igm.bil", "geoloc.vrt"):
            assert (out / f"segment_{segment:03d}_{suffix}").is_file()
    for suffix in ("glt.bil", "ortho.tif", "quicklook.png"):
        assert (out / f"segment_000_{suffix}").is_file()
    assert not [p.name for p in out.glob("segment_006_*")]
    assert (out / "mosaic.tif").is_file()

    summary: dict[str, Any] = json.loads((out / "georef_summary.json").read_text())
    assert [s["segment"] for s in summary["segments"]] == list(range(6))
    assert summary["segments"][0]["rays_hit"] == summary["segments"][0]["rays"] > 0
    assert summary["warnings"] == [*partial, void]
    skip, = summary["skipped"]
    assert skip["segment"] == 6
    assert skip["reason"] == "DEM voids"
    assert skip["whole_segment"] is True
    assert skip["lines_skipped"] == skip["lines"] == skip["lines_timed"] > 0
    assert skip["message"] == void


def test_every_swath_over_dem_voids_is_one_line(
        seven_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A DEM with valid heights, but none near any swath: the one line that says why (it was
    the window error of the first segment), nothing written."""
    dem = voided_dem(seven_run, tmp_path / "sea.tif", lambda e: e >= VALID_EAST_OF_M,
                     widen_cells=300)
    rc, stdout, err = georef(seven_run, dem, tmp_path / "geo", capsys)
    assert rc == 2
    assert stdout == ""
    line, = err.splitlines()
    found = re.fullmatch(rf"sisa georef: error: no pixel could be georeferenced on "
                         rf"{re.escape(str(dem))}: the swaths {BOUNDS} lie over DEM voids only "
                         r"\(nodata\): no valid height within 800 m of them", line)
    assert found is not None, line
    west, _, east, _ = (float(v) for v in found.groups())
    assert west < 416_000
    assert 417_390 < east < VALID_EAST_OF_M - 800.0
    assert not (tmp_path / "geo").exists()


# -- the messages, and the window read, without a flight ----------------------------------------


@pytest.fixture
def job(tmp_path: Path) -> GeorefJob:
    """A job on a small DEM in UTM 31N (cell centres 420005-420195 E, 4609805-4609995 N): its
    flight and scanner folder are never read."""
    with rasterio.open(tmp_path / "dem.tif", "w", driver="GTiff", width=20, height=20, count=1,
                       dtype="float32", crs="EPSG:32631", nodata=-9999.0,
                       transform=Affine(10.0, 0.0, 420_000.0, 0.0, -10.0, 4_610_000.0)) as ds:
        heights = np.full((20, 20), 40.0, np.float32)
        heights[:, :10] = -9999.0  # the west half: voids
        ds.write(heights, 1)
    options = GeorefOptions(sensor=SensorModel(), dem=tmp_path / "dem.tif")
    return GeorefJob([tmp_path / "flight.mcap"], tmp_path / "scanner", tmp_path / "out",
                     options)


def _segment(segment: int) -> SegmentResult:
    return SegmentResult(segment=segment, lines=100, lines_timed=100, lines_georeferenced=0,
                         rays=51_200, rays_hit=0, gsd_across_m=math.nan, gsd_along_m=math.nan,
                         t_first_gps_ns=0, t_last_gps_ns=1, igm=Path("igm.bil"),
                         image=Path("image.bil"))


VOID = SwathOnDem((420_010.0, 4_609_850.0, 420_050.0, 4_609_950.0), (898.2, 902.4),
                  (math.nan, math.nan), True)
OFF = SwathOnDem((419_000.0, 4_609_850.0, 419_100.0, 4_609_950.0), (898.2, 902.4),
                 (math.nan, math.nan), False)
MISSED = SwathOnDem((420_150.0, 4_609_850.0, 420_190.0, 4_609_950.0), (898.2, 902.4),
                    (40.0, 40.0), True)


def test_no_pixel_with_swaths_over_voids_says_so(job: GeorefJob) -> None:
    head = f"no pixel could be georeferenced on {job.opt.dem}: "
    job.cover.swaths.update({0: VOID, 1: OFF, 2: MISSED, 3: VOID})
    assert str(job.cover.no_hit_error([], voids=[0])) == head + (
        "the swath (420010.0, 4609850.0, 420050.0, 4609950.0) lies over DEM voids only "
        "(nodata): no valid height within 800 m of it")
    assert str(job.cover.no_hit_error([], voids=[0, 3])) == head + (
        "the swaths (420010.0, 4609850.0, 420050.0, 4609950.0) lie over DEM voids only "
        "(nodata): no valid height within 800 m of them")
    assert str(job.cover.no_hit_error([], off_dem=[1], voids=[0])) == head + (
        "of the 2 swaths (419000.0, 4609850.0, 420050.0, 4609950.0), 1 lies over DEM voids only "
        "(nodata) and 1 off the DEM (420005.0, 4609805.0, 420195.0, 4609995.0)")
    assert str(job.cover.no_hit_error([_segment(2)], off_dem=[1], voids=[0, 3])) == head + (
        "of the 4 swaths (419000.0, 4609850.0, 420190.0, 4609950.0), 2 lie over DEM voids only "
        "(nodata), 1 off the DEM (420005.0, 4609805.0, 420195.0, 4609995.0) and no ray of the "
        "other 1 met the DEM")


def test_the_skip_of_a_segment_over_voids(job: GeorefJob) -> None:
    job.cover.swaths[4] = VOID
    skip = job.cover.void_skip(4, np.array([-1, 5, 6, 7], np.int64))
    assert (skip.segment, skip.lines, skip.lines_timed, skip.lines_skipped, skip.whole_segment,
            skip.reason) == (4, 4, 3, 4, True, "DEM voids")
    assert skip.message == (
        "segment 4: skipped, its swath (420010.0, 4609850.0, 420050.0, 4609950.0) lies over "
        "DEM voids only (nodata): the DEM dem.tif has no valid height within 800 m of it")


def test_a_window_of_voids_only_is_read_when_asked(job: GeorefJob) -> None:
    """Refused as before unless the caller asks for it; then all NaN, for it to skip."""
    west_half = (420_010.0, 4_609_850.0, 420_050.0, 4_609_950.0)
    with pytest.raises(InputError, match="no valid height in the window"):
        Dem.read(job.opt.dem, bounds_m=west_half, margin_m=0.0)
    dem = Dem.read(job.opt.dem, bounds_m=west_half, margin_m=0.0, voids_only_ok=True,
                   geoid=10.0)
    assert dem.heights_m.size > 0
    assert np.isnan(dem.heights_m).all()
    assert dem.first_easting_m == 420_005.0
    # a window with a valid height: as before, the geoid added
    dem = Dem.read(job.opt.dem, bounds_m=(420_010.0, 4_609_850.0, 420_150.0, 4_609_950.0),
                   margin_m=0.0, voids_only_ok=True, geoid=10.0)
    assert np.nanmax(dem.heights_m) == 50.0
