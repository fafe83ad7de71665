"""Bad calibration inputs (postproc.calibration.data, calib_setup): every one a one-line InputError
naming the file, the row and the field, numbers short (:g), and no numpy warning on the way."""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from postproc.calibration import ImageObservations, read_ground_points, read_observations
from postproc.calibration.setup import Notes, check_sensor_fits
from postproc.georef import SensorModel
from sisa.core.errors import InputError

POINTS = "id,kind,lat_deg,lon_deg,height_m\nA,control,41.6,2.0,300.0\n"
OBS = "id,segment,line,pixel,sigma_px\nA,0,10.5,100.25,0.3\n"


@pytest.fixture(autouse=True)
def no_warnings() -> Iterator[None]:
    """A numpy RuntimeWarning on the way to the error is a failure too."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        yield


def _refused(path: Path, text: str, reader: object, *expected: str) -> str:
    path.write_text(text, encoding="utf-8")
    with pytest.raises(InputError) as info:
        reader(path)  # type: ignore[operator]
    message = str(info.value)
    assert "\n" not in message
    assert len(message) < 300, message
    for part in (str(path), *expected):
        assert part in message, message
    return message


# --- ground points ----------------------------------------------------------------------------

@pytest.mark.parametrize(("comment", "expected"), [
    ("# EPSG:99999", "EPSG:99999 (from its # comment) is not a known CRS"),
    ("# EPSG:" + "9" * 5000, "is not a known CRS"),  # int() of 5000 digits raises ValueError
    ("# EPSG:4326", "EPSG:4326 (from its # comment) is WGS 84, not a projected CRS"),
    ("# EPSG:2263", "has axes in US survey foot"),  # feet read as metres: 3.3× off
])
def test_the_crs_of_easting_northing_must_be_projected_metres(tmp_path: Path, comment: str,
                                                              expected: str) -> None:
    """An unknown EPSG was a pyproj CRSError traceback; a geographic or foot one a wrong
    place."""
    _refused(tmp_path / "g.csv", f"{comment}\nid,kind,easting_m,northing_m,height_m\n"
             "A,control,416959.6,4605321.6,271.4\n", read_ground_points, expected)


def test_an_easting_no_projection_can_invert_names_its_row(tmp_path: Path) -> None:
    _refused(tmp_path / "g.csv", "# EPSG:32631\nid,kind,easting_m,northing_m,height_m\n"
             "A,control,416959.6,4605321.6,271.4\nB,control,1e30,4605321.6,271.4\n",
             read_ground_points, "easting_m, northing_m, row 2", "EPSG:32631")


@pytest.mark.parametrize(("row", "expected"), [
    ("B,check,41.6,2.0,1e300", "column height_m, row 2: 1e+300 is outside -1000..9000"),
    ("B,check,41.6,1e6,300", "column lon_deg, row 2: 1e+06 is outside -180..180"),
    ("B,control,-91,2.0,300", "column lat_deg, row 2: -91 is outside -90..90"),
    ("B,control,41.6,x,300", "column lon_deg, row 2: 'x' is not a number"),
    (",control,41.6,2.0,300", "column id, row 2: empty"),
    ("B\x01,control,41.6,2.0,300", r"column id, row 2: 'B\x01' must be printable text on one line"),
    ("A,check,41.6,2.0,300", "column id, rows 1 and 2: point 'A' appears twice"),
    ("B,survey,41.6,2.0,300", "column kind, row 2: kind 'survey' is not one of"),
])
def test_ground_point_values_are_refused_with_their_row(tmp_path: Path, row: str,
                                                        expected: str) -> None:
    """A point at height 1e300 or longitude 1e6 was never measured and only a note said so;
    an empty id or one with a control character was taken."""
    _refused(tmp_path / "g.csv", POINTS + row + "\n", read_ground_points, expected)


def test_a_tie_points_ignored_coordinates_are_not_checked(tmp_path: Path) -> None:
    path = tmp_path / "g.csv"
    path.write_text(POINTS + "T,tie,nan,1e6,1e300\n", encoding="utf-8")
    pts = read_ground_points(path)
    assert np.isnan(pts.ecef_m[1]).all()
    assert np.isfinite(pts.ecef_m[0]).all()


# --- observations -----------------------------------------------------------------------------

@pytest.mark.parametrize(("row", "expected"), [
    ("B,1e30,10,10,0.3", "column segment, row 2: 1e+30 is not a whole number in 0..65535"),
    ("B,65536,10,10,0.3", "column segment, row 2: 65536 is not a whole number in 0..65535"),
    ("B,1.5,10,10,0.3", "column segment, row 2: 1.5 is not a whole number"),
    ("B,-1,10,10,0.3", "column segment, row 2: -1 is not a whole number"),
    ("B,0,10,10,1e-300", "column sigma_px, row 2: 1e-300 is outside 0.001..100"),
    ("B,0,10,10,0", "column sigma_px, row 2: 0 is outside 0.001..100"),
    ("B,0,10,10,1e300", "column sigma_px, row 2: 1e+300 is outside 0.001..100"),
    ("B,0,10,1e300,0.3", "column pixel, row 2: 1e+300 is outside -100000..100000"),
    ("B,0,-1e300,10,0.3", "column line, row 2: -1e+300 is outside"),
    ("B,0,10,nan,0.3", "column pixel, row 2: not a finite number"),
    (",0,10,10,0.3", "column id, row 2: empty"),
    ("B\x7f,0,10,10,0.3", r"column id, row 2: 'B\x7f' must be printable text on one line"),
])
def test_observation_values_are_refused_with_their_row(tmp_path: Path, row: str,
                                                       expected: str) -> None:
    """segment 1e30 was cast with a RuntimeWarning and its row silently dropped; sigma_px
    1e-300 flooded numpy warnings and ended in a wrong 'not determined'; pixel 1e300 was
    printed in 300 digits."""
    _refused(tmp_path / "o.csv", OBS + row + "\n", read_observations, expected)


def test_a_point_measured_twice_in_one_segment_is_refused(tmp_path: Path) -> None:
    """Two rows of one point in one image counted as two independent measurements: twice the
    weight, silently. Another segment is another image, and fine."""
    path = tmp_path / "o.csv"
    path.write_text(OBS + "A,1,10.5,100.25,0.3\n", encoding="utf-8")
    assert len(read_observations(path)) == 2
    _refused(path, OBS + "A,1,10.5,100.25,0.3\nA,0,11.0,101.0,0.3\n", read_observations,
             "rows 1 and 3 both measure point 'A' in segment 0")


def test_a_line_off_the_image_is_read_and_left_to_the_notes(tmp_path: Path) -> None:
    path = tmp_path / "o.csv"
    path.write_text(OBS + "B,0,99999,10,0.3\nC,0,-5,10,0.3\n", encoding="utf-8")
    assert read_observations(path).line.tolist() == [10.5, 99999.0, -5.0]


# --- set-up -----------------------------------------------------------------------------------

def test_a_pixel_beyond_the_sensor_is_said_in_short() -> None:
    obs = ImageObservations(np.array(["C001"]), np.array([0]), np.array([1.0]),
                            np.array([-8.857e300]), np.array([0.3]))
    with pytest.raises(InputError, match=r"at pixel -8\.857e\+300, but the sensor") as info:
        check_sensor_fits(SensorModel(), obs)
    assert len(str(info.value)) < 200


def test_notes_name_their_first_items() -> None:
    notes = Notes()
    notes.add(0, "nothing", ["X"])
    notes.add(2, "few: left out", ["a", "b"])
    notes.add(5, "many: left out", ["a", "b", "c", "d", "e"])
    notes.add(1, "plain")
    assert notes.lines == ["2 few: left out (a, b)", "5 many: left out (a, b, c, and 2 more)",
                           "1 plain"]


def test_an_adjustment_gone_astray_is_no_sensor_file() -> None:
    """The calibrated sensor file is checked as one is read: a boresight beyond 180° or a
    focal length gone below zero was written (or a pydantic traceback) for `sisa georef` to
    refuse later."""
    from postproc.calibration.adjust import calibrated_sensor
    from postproc.calibration.params import base_state
    from postproc.georef import SensorModel

    sensor = SensorModel(name="CASI")
    st = base_state(sensor, 1)
    st.boresight_arcsec[:] = (12.0, -30.0, 45.0)
    st.antenna_delta_m[:] = (0.1, 0.0, 0.0)
    good = calibrated_sensor(sensor, st)
    assert good.name == "CASI (calibrated)"
    assert good.mounting.boresight_arcsec == (12.0, -30.0, 45.0)
    assert good.mounting.antenna_offset_m == (0.1, 0.0, -1.5)
    assert calibrated_sensor(good, st).name == "CASI (calibrated)"
    st.boresight_arcsec[0] = 7e6
    with pytest.raises(InputError, match=r"^the adjustment's sensor is no sensor: "
                                         r"mounting\.boresight_arcsec\[0\]: .*\(got 7000000\)"
                                         r": it did not converge"):
        calibrated_sensor(sensor, st)
    st.boresight_arcsec[0] = 0.0
    st.selfcal[0] = -9.5  # f = 9.33 mm: the effective focal length below zero
    with pytest.raises(InputError, match=r"focal_length_mm \+ delta_focal_mm"):
        calibrated_sensor(sensor, st)
