"""`sisa georef` on inputs that give products, but not the ones asked for (found by a bad-input
sweep): a DEM that covers only part of the swaths, or none of one segment's; a DEM above the
aircraft; an ortho cell wider than the swath, or one a short segment's ortho holds no centre of.
Each is said: a warning per segment (exit 0, the products still usable) or one line (exit 2).

On the tiny two-strip run of test_trajectory_coverage (simulated once per session, shared), with
DEMs written here from its own."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import rasterio

from emulators.scenario import load_scenario
from emulators.trajectory import TruthTrajectory
from sisa.core.timescale import NS_PER_S
from tests.exitcodes import INCOMPLETE, without_losses_line
from tests.postproc.test_trajectory_coverage import georef, summary, write_truth_sbet
from tests.postproc.test_trajectory_coverage import (  # noqa: F401 (its fixture, by name)
    run as coverage_run,
)


@pytest.fixture
def run(request: pytest.FixtureRequest) -> Path:
    """The session's tiny run (test_trajectory_coverage's fixture, simulated once)."""
    path: Path = request.getfixturevalue("coverage_run")
    return path


# the tiny run's swaths (UTM 31N eastings): segment 0 416604-416826 m, segment 1 416505-416727 m
EAST_OF_BOTH_M = 416_700.0  # voided east of this: part of both swaths
WEST_OF_0_M = 416_740.0  # voided west of this: all of segment 1, part of segment 0


def dem_like(run: Path, path: Path, change: str, easting_m: float = 0.0) -> Path:
    """The run's DEM with "east"/"west" of `easting_m` nodata, or every height 9000 m."""
    with rasterio.open(run / "terrain" / "dem.tif") as ds:
        heights, profile = ds.read(1), ds.profile
        east = ds.xy(0, np.arange(ds.width))[0]
    cols = np.asarray(east) > easting_m
    if change == "east":
        heights[:, cols] = profile["nodata"]
    elif change == "west":
        heights[:, ~cols] = profile["nodata"]
    else:
        heights[:] = 9000.0
    with rasterio.open(path, "w", **profile) as out:
        out.write(heights, 1)
    return path


def warned(err: str) -> list[str]:
    return [line.removeprefix("sisa georef: warning: ") for line in err.splitlines()
            if line.startswith("sisa georef: warning: ")]


def test_a_dem_covering_part_of_the_swaths_is_said_per_segment(
        run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Only the headline's "NN% of pixels on the DEM" said it (exit 0); now one warning per
    segment under 99 %, in the summary too."""
    dem = dem_like(run, tmp_path / "half.tif", "east", EAST_OF_BOTH_M)
    rc, out, err = georef(run, tmp_path / "geo", capsys, "--dem", dem)
    assert rc == 0, err
    said = warned(err)
    assert len(said) == 2
    s = summary(tmp_path / "geo")
    assert s["warnings"] == said
    for note, seg in zip(said, s["segments"], strict=True):
        share = 100 * seg["rays_hit"] / seg["rays"]
        assert 1 < share < 99
        assert note == (f"segment {seg['segment']}: {np.floor(10 * share) / 10:.1f} % of its "
                        "pixels meet the DEM half.tif (voids in the DEM under the swath?)")
    assert "of pixels on the DEM" in out


def test_a_segment_with_no_pixel_on_the_dem_is_said_and_the_others_mapped(
        run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A DEM void under all of segment 1: the job failed with "<staging folder>/
    segment_001_igm.bil: no finite position in the IGM"; now segment 1 gets no ortho, said,
    and segment 0 and the mosaic are made."""
    dem = dem_like(run, tmp_path / "west.tif", "west", WEST_OF_0_M)
    out = tmp_path / "geo"
    capsys.readouterr()
    from sisa.cli import main

    rc = main(["georef", str(run / "flight.mcap"), "--scanner", str(run / "scanner"),
               "--dem", str(dem), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == INCOMPLETE, err  # lines promised, not all made
    err = without_losses_line(err)
    first, second = warned(err)
    assert first.startswith("segment 0: ")
    assert second == ("segment 1: none of its pixels meet the DEM west.tif (voids in the DEM "
                      "under the swath?): no ortho made for it")
    assert (out / "segment_000_ortho.tif").is_file()
    assert (out / "mosaic.tif").is_file()
    assert not (out / "segment_001_ortho.tif").exists()
    assert (out / "segment_001_geoloc.vrt").is_file()


def test_a_dem_above_the_aircraft_says_so(
        run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A DEM at 9000 m over the flight was asked "does the DEM cover the flight?": it does."""
    dem = dem_like(run, tmp_path / "high.tif", "high")
    rc, out, err = georef(run, tmp_path / "geo", capsys, "--dem", dem)
    assert rc == 2
    assert out == ""
    line, = err.splitlines()
    assert line.startswith(f"sisa georef: error: no pixel could be georeferenced on {dem}: its "
                           "surface lies above the camera (the DEM 9000 m under the swaths, the "
                           "camera ")
    assert line.endswith(" m, both ellipsoidal): heights in other units, or a wrong geoid?")
    assert not (tmp_path / "geo").exists()


@pytest.mark.parametrize("cell", ["150", "1000", "5000"])
def test_an_ortho_cell_wider_than_the_swath_is_refused(
        run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], cell: str) -> None:
    """--cell 1000 over a ~210 m swath made empty orthos and mosaic, exit 0; over half the
    swath's width is one line naming --cell and the width (no products, as --no-products
    needs no cell)."""
    capsys.readouterr()
    from sisa.cli import main

    rc = main(["georef", str(run / "flight.mcap"), "--scanner", str(run / "scanner"),
               "--dem", str(run / "terrain" / "dem.tif"), "--out", str(tmp_path / "geo"),
               "--cell", cell])
    got = capsys.readouterr()
    assert rc == 2
    assert got.out == ""
    line, = got.err.splitlines()
    assert line.startswith(f"sisa georef: error: --cell {cell}: wider than half the swath "
                           "(segment ")
    found = re.search(r"\(segment \d: (\d+) m wide, 0\.4\d m pixels\)", line)
    assert found is not None, line
    width = float(found.group(1))
    assert 200 < width < 230
    most = re.search(r"its ortho would hold a cell or two across, or none; use at most (\d+) m$",
                     line)
    assert most is not None, line
    assert width / 2 - 1.5 < int(most.group(1)) <= width / 2
    assert not (tmp_path / "geo").exists()
    rc, _, err = georef(run, tmp_path / "no-products", capsys, "--cell", cell)
    assert rc == 0, err


def test_an_ortho_holding_no_pixel_is_said(
        run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An SBET that ends 0.1 s into segment 1: its 5 m of swath hold no centre of 100 m cells
    (a cell the swath's width allows): an empty ortho, without a word; now said."""
    truth = TruthTrajectory.from_scenario(load_scenario(run / "scenario.toml"))
    sbet = tmp_path / "short.out"
    write_truth_sbet(sbet, truth, truth.t_start_ns + NS_PER_S,
                     truth.strips[1].t_start_ns + NS_PER_S // 10)
    capsys.readouterr()
    from sisa.cli import main

    rc = main(["georef", str(run / "flight.mcap"), "--scanner", str(run / "scanner"),
               "--dem", str(run / "terrain" / "dem.tif"), "--out", str(tmp_path / "geo"),
               "--cell", "100", "--trajectory", str(sbet)])
    err = capsys.readouterr().err
    assert rc == INCOMPLETE, err  # lines promised, not all made
    err = without_losses_line(err)
    no_pose, empty = warned(err)
    assert no_pose.startswith("segment 1: ")
    assert empty.startswith("segment 1: its ortho holds no pixel: no centre of its 100 m cells "
                            "falls on the swath (")
    assert empty.endswith(" m long); a smaller --cell")
    with rasterio.open(tmp_path / "geo" / "segment_001_ortho.tif") as ds:
        assert not ds.read_masks(1).any()
    with rasterio.open(tmp_path / "geo" / "segment_000_ortho.tif") as ds:
        assert ds.read_masks(1).any()
