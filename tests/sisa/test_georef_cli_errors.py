"""`sisa georef` / `sisa process` options a user gets wrong, and options the messages point to:
an output CRS that is not metres or not an EPSG code is one line and nothing written (checked
before the log is read: the flight given here is not even a log); `--leap-seconds` and
`--max-gap-s` exist, as the trajectory messages say, and refuse bad values."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.transform import Affine

from postproc.georef import GeorefJob, GeorefOptions, SegmentResult, SensorModel
from postproc.georef.demcover import SwathOnDem
from sisa.cli import build_parser, main
from sisa.core.errors import InputError


@pytest.fixture
def inputs(tmp_path: Path) -> Path:
    """A small DEM in UTM 31N (metres); a flight 'log' and scanner folder never read."""
    with rasterio.open(tmp_path / "dem.tif", "w", driver="GTiff", width=20, height=20, count=1,
                       dtype="float32", crs="EPSG:32631",
                       transform=Affine(10.0, 0.0, 420_000.0, 0.0, -10.0, 4_610_000.0)) as ds:
        ds.write(np.full((1, 20, 20), 300.0, np.float32))
    (tmp_path / "flight.mcap").write_bytes(b"not read")
    (tmp_path / "scanner").mkdir()
    return tmp_path


def _georef(d: Path, capsys: pytest.CaptureFixture[str], *extra: str) -> tuple[int, str, str]:
    capsys.readouterr()
    rc = main(["georef", str(d / "flight.mcap"), "--scanner", str(d / "scanner"),
               "--dem", str(d / "dem.tif"), "--out", str(d / "out"), *extra])
    got = capsys.readouterr()
    return rc, got.out, got.err


@pytest.mark.parametrize(("crs", "says"), [
    ("2263", ("EPSG:2263", "US survey foot", "projected CRS in metres")),
    ("2229", ("EPSG:2229", "US survey foot", "metres")),
    ("27700x", ()),  # argparse: not an integer (exit 2 by argparse itself)
    ("0", ("--crs 0: not a valid EPSG code",)),
    ("-5", ("--crs -5: not a valid EPSG code",)),
    ("4326", ("EPSG:4326", "projected CRS")),
    ("99999", ("EPSG:99999", "unknown CRS")),
])
def test_output_crs_must_be_a_projected_epsg_in_metres(
        inputs: Path, capsys: pytest.CaptureFixture[str], crs: str, says: tuple[str, ...]
        ) -> None:
    if not says:
        with pytest.raises(SystemExit) as exc:
            _georef(inputs, capsys, "--crs", crs)
        assert exc.value.code == 2
        return
    rc, out, err = _georef(inputs, capsys, "--crs", crs)
    assert rc == 2
    assert out == ""
    line, = err.splitlines()
    assert line.startswith("sisa georef: error: ")
    for text in says:
        assert text in line
    assert not (inputs / "out").exists()
    assert sorted(p.name for p in inputs.iterdir()) == ["dem.tif", "flight.mcap", "scanner"]


@pytest.mark.parametrize("epsg", [32631, 25831, 2056, 3857, 32630])
def test_metre_crss_are_accepted(epsg: int) -> None:
    from postproc.georef.inputchecks import check_output_crs

    assert check_output_crs(epsg).to_epsg() == epsg


@pytest.mark.parametrize(("epsg", "says"), [(0, "not a valid EPSG code"), (-1, "not a valid"),
                                            (2263, "US survey foot"), (2240, "US survey foot")])
def test_the_job_itself_refuses_them(inputs: Path, epsg: int, says: str) -> None:
    options = GeorefOptions(sensor=SensorModel(), dem=inputs / "dem.tif", epsg=epsg)
    with pytest.raises(InputError, match=says):
        GeorefJob([inputs / "flight.mcap"], inputs / "scanner", inputs / "out", options)


def _check_note(inputs: Path, epsg: int, kind: str, says: str | None) -> None:
    """A georef job to `epsg` starts with one warning of `kind` that `says` (and names EPSG:epsg
    and the UTM zone of the DEM), or with none of that kind when `says` is None."""
    options = GeorefOptions(sensor=SensorModel(), dem=inputs / "dem.tif", epsg=epsg)
    job = GeorefJob([inputs / "flight.mcap"], inputs / "scanner", inputs / "out", options)
    said = [w for w in job.warnings if kind in w]
    if says is None:
        assert said == []
        return
    note, = said
    assert f"EPSG:{epsg}" in note
    assert says in note
    assert "--crs 32631" in note


@pytest.mark.parametrize(("epsg", "ground_m"), [(3857, "0.747 m"), (32631, None),
                                                (25831, None), (2056, None), (32630, None)])
def test_a_grid_whose_metres_are_not_ground_metres_is_said(
        inputs: Path, epsg: int, ground_m: str | None) -> None:
    """EPSG:3857 has metre axes but, at the DEM's 41.6°N, 0.747 ground metres per grid metre:
    accepted (products are right in its coordinates), with a warning that names the UTM zone;
    UTM, a neighbouring zone, ETRS89 and the Swiss grid stay within 1 % there and say nothing."""
    _check_note(inputs, epsg, "a metre of its grid",
                None if ground_m is None else f"a metre of its grid is {ground_m} on the ground")


@pytest.mark.parametrize(("epsg", "datum"), [(27700, "Ordnance Survey of Great Britain 1936"),
                                             (2056, "CH1903+"),
                                             (31468, "Deutsches Hauptdreiecksnetz"),
                                             (25831, None), (2154, None), (32631, None)])
def test_a_crs_whose_datum_proj_cannot_reach_there_is_said(
        inputs: Path, epsg: int, datum: str | None) -> None:
    """The British, Swiss and old German grids over the DEM's Catalonia: PROJ has no datum
    shift from WGS 84 there and takes the datums for one (metres to hundreds of metres off);
    said once, naming the UTM zone. ETRS89 and RGF93 have one, and WGS 84 needs none. (Found
    by a bad-input sweep: --crs 27700 for this flight was taken without a word.)"""
    _check_note(inputs, epsg, "PROJ knows no shift", None if datum is None else f"to {datum}")


@pytest.mark.parametrize("command", ["georef", "process"])
def test_the_options_the_trajectory_messages_name_exist(command: str) -> None:
    head = (["georef", "f.mcap", "--scanner", "s", "--dem", "d.tif", "--out", "o"]
            if command == "georef" else ["process", "run"])
    args = build_parser().parse_args([*head, "--leap-seconds", "18", "--max-gap-s", "1.5"])
    assert (args.leap_seconds, args.max_gap_s) == (18, 1.5)


@pytest.mark.parametrize(("option", "says"), [
    (("--leap-seconds", "-1"), "--leap-seconds -1: must be 0 to 60 (GPS - UTC: 18 since 2017)"),
    (("--leap-seconds", "99"), "--leap-seconds 99: must be 0 to 60 (GPS - UTC: 18 since 2017)"),
    (("--max-gap-s", "0"), "--max-gap-s 0.0: must be a positive number of seconds, at most "
                           "86400"),
    (("--max-gap-s", "-2"), "--max-gap-s -2.0: must be a positive number of seconds, at most "
                            "86400"),
    (("--max-gap-s", "nan"), "--max-gap-s nan: must be a finite number"),
    # an OverflowError traceback from the bridged gap in nanoseconds (found by a bad-input sweep)
    (("--max-gap-s", "1e300"), "--max-gap-s 1e+300: must be a positive number of seconds, at "
                               "most 86400"),
    (("--max-gap-s", "inf"), "--max-gap-s inf: must be a finite number"),
])
def test_bad_leap_seconds_and_max_gap_are_one_line(
        inputs: Path, capsys: pytest.CaptureFixture[str], option: tuple[str, str], says: str
        ) -> None:
    rc, out, err = _georef(inputs, capsys, *option)
    assert rc == 2
    assert out == ""
    assert err.splitlines() == [f"sisa georef: error: {says}"]
    assert not (inputs / "out").exists()


# --- found by a bad-input sweep of `sisa georef`: --geoid-m, --cell, --crs far away, a 3-band
# DEM, --leap-seconds without a trajectory --------------------------------------------------------

@pytest.mark.parametrize(("option", "says"), [
    # an overflow traceback (38 lines), an error blaming the DEM, and silence
    (("--geoid-m", "1e308"), "--geoid-m 1e+308: must be -110 to 110 m (the geoid undulation on "
                             "Earth: -106 to +85 m)"),
    (("--geoid-m", "3.5e38"), "--geoid-m 3.5e+38: must be -110 to 110 m"),
    (("--geoid-m", "1e6"), "--geoid-m 1e+06: must be -110 to 110 m"),
    (("--geoid-m", "-200"), "--geoid-m -200: must be -110 to 110 m"),
    (("--geoid-m", "110.5"), "--geoid-m 110.5: must be -110 to 110 m"),
    # "must be a positive size in metres" of a size over the limit
    (("--cell", "1e5"), "--cell 100000: must be at most 10000 m"),
    (("--cell", "10000.5"), "--cell 10000.5: must be at most 10000 m"),
    (("--cell", "0"), "--cell 0: must be a positive size in metres"),
])
def test_bad_geoid_undulation_and_cell_are_one_line(
        inputs: Path, capsys: pytest.CaptureFixture[str], option: tuple[str, str], says: str
        ) -> None:
    rc, out, err = _georef(inputs, capsys, *option)
    assert rc == 2
    assert out == ""
    line, = err.splitlines()
    assert line.startswith(f"sisa georef: error: {says}")
    assert not (inputs / "out").exists()


@pytest.mark.parametrize("undulation", ["-106", "85", "0", "49.5", "110", "-110"])
def test_geoid_undulations_earth_has_are_taken(undulation: str) -> None:
    from sisa.commands.georef import options_from_args

    args = build_parser().parse_args(["georef", "f.mcap", "--scanner", "s", "--dem", "d.tif",
                                      "--out", "o", "--geoid-m", undulation])
    assert options_from_args(args).geoid == float(undulation)


def test_the_job_itself_refuses_an_undulation_no_geoid_has(inputs: Path) -> None:
    """Before the log is read (it was a ValueError traceback from the first DEM window)."""
    options = GeorefOptions(sensor=SensorModel(), dem=inputs / "dem.tif", geoid=1e308)
    with pytest.raises(InputError, match=r"geoid undulation 1e\+308: must be -110 to 110 m"):
        GeorefJob([inputs / "flight.mcap"], inputs / "scanner", inputs / "out", options)


@pytest.mark.parametrize(("epsg", "says"), [
    (32601, "179° of longitude from its central meridian (-177°), on the far side of the "
            "projection: the products come out turned by 179° (northings of 15386 km)"),
    (32649, "109° of longitude from its central meridian (111°), on the far side"),
    (32633, "13° of longitude from its central meridian (15°), its grid north is 9° from true "
            "north there and a metre of its grid 0.986 m on the ground"),
    (32631, None), (32630, None), (25831, None), (2056, None), (3857, None)])
def test_a_transverse_mercator_far_from_its_central_meridian_is_said(
        inputs: Path, epsg: int, says: str | None) -> None:
    """UTM zone 1 over the DEM's 2°E: 179° from its central meridian the scale is 1 again,
    so the scale note said nothing, while the products came out upside down with northings of
    15 390 km. One note, in place of the scale note (zone 33); a zone away (32630) is fine."""
    _check_note(inputs, epsg, "central meridian", says)
    if says is not None:
        options = GeorefOptions(sensor=SensorModel(), dem=inputs / "dem.tif", epsg=epsg)
        job = GeorefJob([inputs / "flight.mcap"], inputs / "scanner", inputs / "out", options)
        assert len(job.warnings) == 1 + ("PROJ knows no shift" in " ".join(job.warnings))


def _job_warnings(inputs: Path, **kwargs: object) -> list[str]:
    options = GeorefOptions(sensor=SensorModel(), **kwargs)  # type: ignore[arg-type]
    return GeorefJob([inputs / "flight.mcap"], inputs / "scanner", inputs / "out",
                     options).warnings


def test_a_dem_of_several_bands_is_said(inputs: Path) -> None:
    """A 3-band raster given as the DEM (or the geoid) was read from band 1 without a word."""
    with rasterio.open(inputs / "rgb.tif", "w", driver="GTiff", width=20, height=20, count=3,
                       dtype="float32", crs="EPSG:32631",
                       transform=Affine(10.0, 0.0, 420_000.0, 0.0, -10.0, 4_610_000.0)) as ds:
        ds.write(np.full((3, 20, 20), 40.0, np.float32))
    assert _job_warnings(inputs, dem=inputs / "dem.tif") == []
    assert _job_warnings(inputs, dem=inputs / "rgb.tif") == [
        f"{inputs / 'rgb.tif'}: the DEM raster has 3 bands: band 1 is read as heights, the "
        "others are ignored"]
    assert _job_warnings(inputs, dem=inputs / "dem.tif", geoid=inputs / "rgb.tif") == [
        f"{inputs / 'rgb.tif'}: the geoid raster has 3 bands: band 1 is read as undulations, "
        "the others are ignored"]


def test_leap_seconds_without_a_trajectory_is_said(inputs: Path) -> None:
    """--leap-seconds only applies to a --trajectory .pos on UTC or JST; without one it changed
    nothing, silently (products byte-identical). A scenario's fallback (sisa process) says
    nothing."""
    assert _job_warnings(inputs, dem=inputs / "dem.tif", leap_seconds_fallback=18) == []
    assert _job_warnings(inputs, dem=inputs / "dem.tif", leap_seconds=18) == [
        "--leap-seconds 18: not used: it applies to a --trajectory .pos on UTC or JST, and the "
        "flight log's navigation is on GPS time"]


def _segment(segment: int, rays_hit: int) -> SegmentResult:
    return SegmentResult(segment=segment, lines=100, lines_timed=100, lines_georeferenced=100,
                         rays=51_200, rays_hit=rays_hit, gsd_across_m=0.4, gsd_along_m=1.0,
                         t_first_gps_ns=0, t_last_gps_ns=1, igm=Path("igm.bil"),
                         image=Path("image.bil"))


@pytest.mark.parametrize(("swath", "says"), [
    (SwathOnDem((420_050.0, 4_609_850.0, 420_150.0, 4_609_950.0), (898.2, 902.4),
                (9000.0, 9000.3), True),
     "its surface lies above the camera (the DEM 9000 m under the swaths, the camera 898 to "
     "902 m, both ellipsoidal): heights in other units, or a wrong geoid?"),
    (SwathOnDem((419_900.04, 4_609_850.0, 420_150.0, 4_609_950.0), (898.2, 902.4),
                (300.0, 300.0), False),
     "the swaths (419900.0, 4609850.0, 420150.0, 4609950.0) run off the DEM (420005.0, "
     "4609805.0, 420195.0, 4609995.0)"),
    (SwathOnDem((420_050.0, 4_609_850.0, 420_150.0, 4_609_950.0), (898.2, 902.4),
                (300.0, 300.0), True),
     "the DEM covers the swaths, but no ray met its surface (the DEM 300 m under the swaths, "
     "the camera 898 to 902 m, both ellipsoidal)")])
def test_no_pixel_on_the_dem_says_why(inputs: Path, swath: SwathOnDem, says: str) -> None:
    """It always asked "does the DEM cover the flight?", also of a DEM that did, above the
    aircraft: now the DEM's and the camera's heights, or the bounds that do not meet."""
    options = GeorefOptions(sensor=SensorModel(), dem=inputs / "dem.tif")
    job = GeorefJob([inputs / "flight.mcap"], inputs / "scanner", inputs / "out", options)
    job.cover.swaths[0] = swath
    assert str(job.cover.no_hit_error([_segment(0, 0)])) == (
        f"no pixel could be georeferenced on {inputs / 'dem.tif'}: {says}")


@pytest.mark.parametrize(("on_dem", "surface", "why"), [
    (False, (300.0, 310.0), "the DEM does not cover the whole swath?"),
    (True, (300.0, 310.0), "voids in the DEM under the swath?"),
    (True, (300.0, 1200.0), "terrain above the camera?")])
def test_a_segment_partly_off_the_dem_says_the_likeliest_why(
        inputs: Path, on_dem: bool, surface: tuple[float, float], why: str) -> None:
    options = GeorefOptions(sensor=SensorModel(), dem=inputs / "dem.tif")
    job = GeorefJob([inputs / "flight.mcap"], inputs / "scanner", inputs / "out", options)
    job.cover.swaths[3] = SwathOnDem((0.0, 0.0, 1.0, 1.0), (898.0, 902.0), surface, on_dem)
    assert job.cover.partial_hit_note(3, 25_474, 51_200) == (
        f"segment 3: 49.7 % of its pixels meet the DEM dem.tif ({why})")
    assert job.cover.partial_hit_note(3, 0, 51_200) == (
        f"segment 3: none of its pixels meet the DEM dem.tif ({why}): no ortho made for it")
    assert job.cover.partial_hit_note(3, 50_688, 51_200) is None  # 99 % meet it: nothing to say
