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

from postproc.georef import GeorefJob, GeorefOptions
from postproc.sensorfile import SensorModel
from sisa.cli import build_parser, main
from sisa.errors import InputError


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
    from postproc.georef import check_output_crs

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
