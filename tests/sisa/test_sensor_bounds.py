"""Sensor-file values outside what an instrument can be are refused at load, one line naming the
file and the field as the TOML spells it, instead of failing later in navigation or being blamed
on the DEM; an empty file is refused, not read as the nominal sensor; the name prints on one
short line."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from emulators.scenario import PRESETS, load_scenario
from postproc.georef.sensorfile import MAX_NAME_CHARS, SensorModel
from sisa.cli import main
from sisa.commands.process import sensor_of
from sisa.core.errors import InputError
from sisa.core.sensor import Mounting, ScannerGeometry

# (sensor file text, the field the one-line error must name)
BAD = {
    "antenna-1e300": ("[mounting]\nantenna_offset_m = [1e300, 0.0, -1.5]\n",
                      "mounting.antenna_offset_m[0]"),
    "antenna-z-101": ("[mounting]\nantenna_offset_m = [0.0, 0.0, -101.0]\n",
                      "mounting.antenna_offset_m[2]"),
    "lever-1e300": ("[mounting]\nlever_arm_m = [1e300, 0.0, 0.3]\n", "mounting.lever_arm_m[0]"),
    "lever-1e7": ("[mounting]\nlever_arm_m = [0.0, 1e7, 0.3]\n", "mounting.lever_arm_m[1]"),
    "lever-300-digits": ("[mounting]\nlever_arm_m = [" + "9" * 300 + ", 0.0, 0.3]\n",
                         "mounting.lever_arm_m[0]"),
    "lever-nan": ("[mounting]\nlever_arm_m = [nan, 0.0, 0.3]\n",
                  "mounting.lever_arm_m[0]: must be a finite number"),
    "boresight-1e300": ("[mounting]\nboresight_arcsec = [1e300, 0.0, 0.0]\n",
                        "mounting.boresight_arcsec[0]"),
    "boresight-181-deg": ("[mounting]\nboresight_arcsec = [0.0, 0.0, -651600.0]\n",
                          "mounting.boresight_arcsec[2]"),
    "focal-1e-300": ("[scanner]\nfocal_length_mm = 1e-300\n", "scanner.focal_length_mm"),
    "pitch-1e-300": ("[scanner]\npixel_pitch_um = 1e-300\n", "scanner.pixel_pitch_um"),
    "effective-focal-negative": ("[scanner]\nfocal_length_mm = 1.0\ndelta_focal_mm = -50\n",
                                 "focal_length_mm + delta_focal_mm"),
    "effective-focal-zero": ("[scanner]\nfocal_length_mm = 50.0\ndelta_focal_mm = -50\n",
                             "focal_length_mm + delta_focal_mm"),
    "principal-point-1e300": ("[scanner]\nprincipal_point_um = [1e300, 0.0]\n",
                              "scanner.principal_point_um[0]"),
    "delta-principal-point-1e300": ("[scanner]\ndelta_principal_point_um = [0.0, -1e300]\n",
                                    "scanner.delta_principal_point_um[1]"),
    "empty": ("", "empty sensor file (no fields)"),
    "only-comments": ("# a sensor file\n\n   \n# nothing else\n", "empty sensor file (no fields)"),
    "only-empty-tables": ("[scanner]\n[mounting]\n", "empty sensor file (no fields)"),
    "name-newline": ('name = "CASI\\nsecond line"\n', "name: must be printable text on one line"),
    "name-escape": ('name = "CASI \\u001b[31m red"\n', "name: must be printable text"),
    "name-bidi": ('name = "CASI \\u202e"\n', "name: must be printable text"),
    "name-5000": ('name = "' + "x" * 5000 + '"\n', f"name: at most {MAX_NAME_CHARS} characters"),
}


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "sensor.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize(("text", "field"), list(BAD.values()), ids=list(BAD))
def test_bad_sensor_file_is_one_line_naming_the_field(tmp_path: Path, text: str,
                                                      field: str) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(InputError) as err:
        SensorModel.load(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: ")
    assert field in msg
    assert "\n" not in msg
    assert len(msg) < 250, msg
    assert not re.search(r"\d{20}", msg), msg  # no 300-digit numbers


@pytest.mark.parametrize("command", ["georef", "calibrate"])
@pytest.mark.parametrize("name", ["antenna-1e300", "effective-focal-negative", "empty"])
def test_the_cli_says_it_in_one_line_with_exit_2(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str],
                                                 command: str, name: str) -> None:
    text, field = BAD[name]
    path = _write(tmp_path, text)
    # inputs that exist (a missing one is said first); their contents are never read
    (tmp_path / "flight.mcap").write_bytes(b"")
    (tmp_path / "dem.tif").write_bytes(b"")
    (tmp_path / "scanner").mkdir()
    (tmp_path / "flight").mkdir()
    argv = (["georef", str(tmp_path / "flight.mcap"), "--scanner", str(tmp_path / "scanner"),
             "--dem", str(tmp_path / "dem.tif")] if command == "georef"
            else ["calibrate", str(tmp_path / "flight")])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no numpy RuntimeWarning on the way
        rc = main([*argv, "--out", str(tmp_path / "out"), "--sensor", str(path)])
    out, err = capsys.readouterr()
    assert rc == 2
    assert out == ""
    assert err.count("\n") == 1, err
    assert err.startswith(f"sisa {command}: error: {path}: ")
    assert field in err
    assert not (tmp_path / "out").exists()


# Values at the bounds load: they are what a real instrument may have
GOOD = {
    "offsets-100-m": "[mounting]\nlever_arm_m = [100.0, -100.0, 100]\n"
                     "antenna_offset_m = [-100.0, 100.0, -100.0]\n",
    "boresight-180-deg": "[mounting]\nboresight_arcsec = [648000.0, -648000.0, 0.0]\n",
    "interior-minimum": "[scanner]\nfocal_length_mm = 0.1\npixel_pitch_um = 0.1\n"
                        "principal_point_um = [100000.0, -100000.0]\n"
                        "delta_principal_point_um = [-100000.0, 100000.0]\n",
    "effective-focal-0.1": "[scanner]\nfocal_length_mm = 50.0\ndelta_focal_mm = -49.9\n",
    "name-200": 'name = "' + "é" * MAX_NAME_CHARS + '"\n',
    "name-only": 'name = "CASI-501 #2 on EC-FXX"\n',
}


@pytest.mark.parametrize("text", list(GOOD.values()), ids=list(GOOD))
def test_values_at_the_bounds_load(tmp_path: Path, text: str) -> None:
    SensorModel.load(_write(tmp_path, text))


def test_defaults_and_every_preset_validate(tmp_path: Path) -> None:
    model = SensorModel()
    assert SensorModel.load(_write(tmp_path, model.to_toml())) == model
    for preset in PRESETS:
        scn = load_scenario(preset)
        for nominal in (False, True):
            sensor = sensor_of(scn, nominal=nominal)
            assert SensorModel.load(_write(tmp_path, sensor.to_toml())) == sensor


def test_a_calibrated_name_at_the_limit_still_loads(tmp_path: Path) -> None:
    """`sisa calibrate` appends ' (calibrated)' to the name it was given: its output loads."""
    from postproc.calibration.adjust import calibrated_sensor
    from postproc.calibration.params import State

    given = SensorModel(name="n" * MAX_NAME_CHARS)
    zero = np.zeros(3)
    st = State(boresight_arcsec=zero, selfcal=zero, delay_ms=0.0, antenna_delta_m=zero,
               gps_block_enu_m=zero, gps_strip_enu_m=np.zeros((1, 3)),
               attitude_arcsec=np.zeros((1, 3)), drift_arcsec_per_s=np.zeros((1, 3)))
    out = calibrated_sensor(given, st)
    assert out.name == "n" * MAX_NAME_CHARS + " (calibrated)"
    assert SensorModel.load(_write(tmp_path, out.to_toml())) == out


def test_wrong_sensor_message_is_one_short_line() -> None:
    """Even a name that bypassed validation (model_copy does not validate) prints safely."""
    for name in ("line one\nline two", "x" * 5000):
        model = SensorModel().model_copy(update={"name": name})
        with pytest.raises(InputError, match="wrong sensor file") as err:
            model.check_pixels(256, "segment_000.bil")
        msg = str(err.value)
        assert "\n" not in msg
        assert len(msg) < 200, msg


def test_models_refuse_them_when_built_in_code_too() -> None:
    with pytest.raises(ValidationError):
        Mounting(antenna_offset_m=(1e300, 0.0, 0.0))
    with pytest.raises(ValidationError):
        ScannerGeometry(focal_length_mm=1.0, delta_focal_mm=-50.0)
    with pytest.raises(ValidationError):
        SensorModel(name="a\nb")
