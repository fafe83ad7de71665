"""`sisa georef` with a DEM that covers only some of the flight's strips: a segment whose swath
lies wholly off the DEM is skipped, said once with its swath's and the DEM's bounds (stderr,
summary), and the others are georeferenced with their products, mosaic and footprints; only a
DEM that no swath meets stops the job (one line, exit 2).

Before, a swath more than the DEM window's margin (800 m) off the DEM failed the whole job
("DEM.tif: bounds (...) (+500 m) do not overlap the DEM (...)", naming no segment) after the
segments before it had been cast; a swath nearer the DEM gave an IGM of NaN and a warning
that asked whether the DEM covered the swath.

On a run of seven short N-S strips without side overlap (simulated once per session, ~7 s),
with DEMs cropped here from its own."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest
import rasterio
from rasterio.transform import Affine
from rasterio.windows import Window

from sisa.cli import main
from tests.exitcodes import INCOMPLETE, without_losses_line
from tests.postproc import simulated_once

SEVEN = """base = "bench"
seed = 5
[block]
strips = 7
side_overlap_pct = 0.0
strip_length_m = 200.0
flying_height_agl_m = 250.0
[flight]
static_alignment_s = 15.0
figure_eights = 0
climb_rate_mps = 20.0
turn_bank_deg = 45.0
run_in_s = 3.0
takeoff_acceleration_mps2 = 5.0
airfield_offset_m = [-300.0, -1200.0]
[terrain]
margin_m = 400.0
control_points = 0
check_points = 0
"""
# the run's swaths (UTM 31N eastings), strip k ~205 m west of strip k-1: segment 0
# 417167-417394 m, 1 416964-417192 m, 2 416758-416983 m, ... 6 415943-416156 m (1 km off
# segment 0, beyond the 800 m the DEM window reaches out)
WEST_EDGE_M = 417_160.0  # a DEM starting here covers segment 0, a sliver of 1, none of 2-6
EAST_OF_ALL_M = 417_500.0  # a DEM starting here meets no swath


@pytest.fixture(scope="session")
def seven_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The seven-strip run, simulated once per session."""
    return simulated_once(tmp_path_factory, "dem-cover-run", SEVEN)


def dem_east_of(run: Path, path: Path, west_edge_m: float) -> Path:
    """The run's DEM cropped to its cells east of `west_edge_m` (a smaller raster, not
    voids)."""
    with rasterio.open(run / "terrain" / "dem.tif") as ds:
        c0 = round((west_edge_m - ds.bounds.left) / ds.res[0])
        win = Window(c0, 0, ds.width - c0, ds.height)
        t = ds.transform
        profile = ds.profile
        profile.update(width=win.width, height=win.height,
                       transform=Affine(t.a, t.b, t.c + c0 * t.a, t.d, t.e, t.f))
        heights = ds.read(1, window=win)
    with rasterio.open(path, "w", **profile) as out:
        out.write(heights, 1)
    return path


def dem_centres_text(path: Path) -> str:
    """The DEM's cell-centre bounds as the messages give them."""
    with rasterio.open(path) as ds:
        half = ds.res[0] / 2
        b = ds.bounds
        return (f"({b.left + half:.1f}, {b.bottom + half:.1f}, {b.right - half:.1f}, "
                f"{b.top - half:.1f})")


def georef(run: Path, dem: Path, out: Path, capsys: pytest.CaptureFixture[str]
           ) -> tuple[int, str, str]:
    capsys.readouterr()
    rc = main(["georef", str(run / "flight.mcap"), "--scanner", str(run / "scanner"),
               "--dem", str(dem), "--out", str(out)])
    got = capsys.readouterr()
    return rc, got.out, got.err


def warned(err: str) -> list[str]:
    return [line.removeprefix("sisa georef: warning: ") for line in err.splitlines()
            if line.startswith("sisa georef: warning: ")]


BOUNDS = r"\((\d+\.\d), (\d+\.\d), (\d+\.\d), (\d+\.\d)\)"


def test_segments_off_the_dem_are_skipped_and_the_others_mapped(
        seven_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    dem = dem_east_of(seven_run, tmp_path / "east.tif", WEST_EDGE_M)
    out = tmp_path / "geo"
    rc, stdout, err = georef(seven_run, dem, out, capsys)
    assert rc == INCOMPLETE, err  # lines promised, not all made
    err = without_losses_line(err)
    assert stdout.startswith(f"{out}: 2 of 7 segments (5 skipped), ")
    partial, *off = warned(err)
    assert partial.startswith("segment 1: ")
    assert partial.endswith("% of its pixels meet the DEM east.tif (the DEM does not cover the "
                            "whole swath?)")
    assert len(off) == 5
    dem_text = dem_centres_text(dem)
    for segment, note in zip(range(2, 7), off, strict=True):
        found = re.fullmatch(rf"segment {segment}: skipped, its swath {BOUNDS} lies off the DEM "
                             rf"east\.tif {re.escape(dem_text)}", note)
        assert found is not None, note
        west, south, east, north = (float(v) for v in found.groups())
        assert west < east < WEST_EDGE_M
        assert south < north

    # the segments on the DEM: every product; the others: nothing at all
    for segment in (0, 1):
        for suffix in ("eo.csv", "igm.bil", "geoloc.vrt", "glt.bil", "ortho.tif",
                       "quicklook.png"):
            assert (out / f"segment_{segment:03d}_{suffix}").is_file()
    assert not [p.name for p in out.glob("segment_00[2-6]_*")]
    assert (out / "mosaic.tif").is_file()
    assert (out / "mosaic_quicklook.png").is_file()
    features = json.loads((out / "footprints.geojson").read_text())["features"]
    assert [f["properties"]["segment"] for f in features] == [0, 1]
    assert all(f["geometry"] is not None for f in features)

    summary: dict[str, Any] = json.loads((out / "georef_summary.json").read_text())
    assert [s["segment"] for s in summary["segments"]] == [0, 1]
    assert summary["warnings"] == [partial, *off]
    skips = summary["skipped"]
    assert [s["segment"] for s in skips] == [2, 3, 4, 5, 6]
    for skip, note in zip(skips, off, strict=True):
        assert skip["reason"] == "off the DEM"
        assert skip["whole_segment"] is True
        assert skip["lines_skipped"] == skip["lines"] == skip["lines_timed"] > 0
        assert skip["message"] == note
    with rasterio.open(out / "segment_000_ortho.tif") as ds:
        assert ds.read_masks(1).mean() > 100  # most of the swath's cells are filled


def test_a_dem_no_swath_meets_is_one_line(
        seven_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Every segment off the DEM: the one line that says why, nothing written."""
    dem = dem_east_of(seven_run, tmp_path / "far.tif", EAST_OF_ALL_M)
    rc, stdout, err = georef(seven_run, dem, tmp_path / "geo", capsys)
    assert rc == 2
    assert stdout == ""
    line, = err.splitlines()
    found = re.fullmatch(rf"sisa georef: error: no pixel could be georeferenced on "
                         rf"{re.escape(str(dem))}: the swaths {BOUNDS} run off the DEM "
                         rf"{re.escape(dem_centres_text(dem))}", line)
    assert found is not None, line
    west, _, east, _ = (float(v) for v in found.groups())
    assert west < 416_000
    assert 417_390 < east < EAST_OF_ALL_M
    assert not (tmp_path / "geo").exists()
