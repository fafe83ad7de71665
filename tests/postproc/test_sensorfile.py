"""The sensor file: round trip, one-line errors, and the wrong-sensor guard."""

import pytest

from postproc.georef import SensorModel
from sisa.core.errors import InputError
from sisa.core.sensor import Mounting, ScannerGeometry


def test_round_trip_keeps_every_value(tmp_path):
    model = SensorModel(name="CASI #2", time_delay_ms=85.0,
                        scanner=ScannerGeometry(delta_focal_mm=0.65,
                                                delta_principal_point_um=(12.7, 64.5)),
                        mounting=Mounting(lever_arm_m=(0.1, -0.2, 0.3),
                                          boresight_arcsec=(1742.0, -2.0, -74.0)))
    path = tmp_path / "sensor.toml"
    path.write_text(model.to_toml(), encoding="utf-8")
    back = SensorModel.load(path)
    assert back == model
    assert back.time_delay_ns == 85_000_000


@pytest.mark.parametrize(("text", "words"), [
    ("[scanner]\npixles = 512\n", "scanner.pixles"),
    ("time_delay_ms = 'soon'\n", "time_delay_ms"),
    ("[mounting]\nlever_arm_m = [1, 2]\n", "mounting.lever_arm_m"),
    ("this is = not toml = at all\n", "not a TOML sensor file"),
])
def test_bad_files_give_one_line_naming_the_field(tmp_path, text, words):
    path = tmp_path / "bad.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(InputError) as err:
        SensorModel.load(path)
    msg = str(err.value)
    assert words in msg
    assert str(path) in msg
    assert "\n" not in msg


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="cannot read"):
        SensorModel.load(tmp_path / "nope.toml")


def test_sensor_for_another_instrument_is_refused():
    model = SensorModel(scanner=ScannerGeometry(pixels=1024))
    model.check_pixels(1024, "x.bil")
    with pytest.raises(InputError, match="wrong sensor file"):
        model.check_pixels(512, "segment_000.bil")
