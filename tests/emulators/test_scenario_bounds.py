"""Scenario bounds: every value that would overflow a time, run a flight for days or allocate a
runaway array is refused at validation, one line naming the field and exit code 2, before any
port or folder exists; the values just inside each bound load."""

from __future__ import annotations

import math
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

import emulators.scenario as scenario_module
from emulators import trajectory
from emulators.localplane import LocalPlane
from emulators.scenario import (
    MAX_DEM_CELLS,
    MAX_FLIGHT_H,
    dem_extent_m,
    flight_duration_bound_s,
    load_scenario,
    scenario_from_table,
    turn_rate_deg_s,
)
from emulators.terrain import _dem_bounds_utm
from sisa.cli import main
from sisa.core.errors import ConfigError

# (TOML body after `base = "bench"`, text the one-line error must hold)
BAD = {
    "start-2300": ('[block]\nstart_gps = "2300-01-01T00:00:00"\n', "block.start_gps"),
    "start-1970": ('[block]\nstart_gps = "1970-01-01T00:00:00"\n', "block.start_gps"),
    "start-1980-01-01": ('[block]\nstart_gps = "1980-01-01T00:00:00"\n', "block.start_gps"),
    "start-before-epoch": ('[block]\nstart_gps = "1980-01-05T23:59:59"\n', "block.start_gps"),
    "start-last-day-2079": ('[block]\nstart_gps = "2079-12-31T00:00:00"\n', "block.start_gps"),
    "airfield-1e12": ("[flight]\nairfield_offset_m = [1e12, 1e12]\n",
                      "flight.airfield_offset_m"),
    "airfield-north": ("[flight]\nairfield_offset_m = [0.0, -200001.0]\n",
                       "flight.airfield_offset_m[1]"),
    "speed-0.001": ("[block]\nground_speed_kmh = 0.001\n", "block.ground_speed_kmh"),
    "speed-9.9": ("[block]\nground_speed_kmh = 9.9\n", "block.ground_speed_kmh"),
    "speed-1001": ("[block]\nground_speed_kmh = 1001\n", "block.ground_speed_kmh"),
    "dem-1e-9": ("[terrain]\ndem_spacing_m = 1e-9\n", "terrain.dem_spacing_m"),
    "dem-0.09": ("[terrain]\ndem_spacing_m = 0.09\n", "terrain.dem_spacing_m"),
    "dem-cells": ("[terrain]\ndem_spacing_m = 1.0\n", "terrain.dem_spacing_m"),
    "texture-1e-9": ("[terrain]\ntexture_cell_m = 1e-9\n", "terrain.texture_cell_m"),
    "scene-cells": ("[terrain]\ntexture_cell_m = 0.2\n", "terrain.texture_cell_m"),
    "takeoff-1e-9": ("[flight]\ntakeoff_acceleration_mps2 = 1e-9\n",
                     "flight.takeoff_acceleration_mps2"),
    "climb-1e-9": ("[flight]\nclimb_rate_mps = 1e-9\n", "flight.climb_rate_mps"),
    "turn-rate": ("[block]\nground_speed_kmh = 20\n", "flight.turn_bank_deg"),
    "flight-days": ("[block]\nstrips = 20\nstrip_length_m = 500000.0\n",
                    "block: the flight would last up to"),
    "slow-long-strips": ("[block]\nground_speed_kmh = 10\nstrip_length_m = 100000.0\n"
                         "[flight]\nturn_bank_deg = 5\n", "block.strip_length_m"),
    "dem-side": ("[block]\nstrip_length_m = 100000.0\nstrips = 7\nside_overlap_pct = 0\n"
                 "flying_height_agl_m = 20000\nground_speed_kmh = 900\n[scanner]\n"
                 "pixels = 4096\n[terrain]\ndem_spacing_m = 500\ntexture_cell_m = 500\n",
                 "km a side"),
    "line-samples": ("[scanner]\npixels = 65536\nbands = 288\n", "scanner: pixels × bands"),
    "control-points": ("[terrain]\ncontrol_points = 10001\n", "terrain.control_points"),
    # INS attitude errors: `simulate` failed on them with "roll_rad = -5.8e+302 rad is outside"
    "ins-bias-1e308": ("[ins]\nattitude_bias_arcsec = [1e308, 10, 30]\n",
                       "ins.attitude_bias_arcsec[0]"),
    "ins-bias-300-digits": ("[ins]\nattitude_bias_arcsec = [10, " + "9" * 300 + ", 30]\n",
                            "ins.attitude_bias_arcsec[1]"),
    "ins-bias-2-deg": ("[ins]\nattitude_bias_arcsec = [10, 10, 7200]\n",
                       "ins.attitude_bias_arcsec[2]"),
    "ins-noise-1e300": ("[ins]\nattitude_noise_arcsec = [2, 1e300, 3]\n",
                        "ins.attitude_noise_arcsec[1]"),
    "ins-noise-negative": ("[ins]\nattitude_noise_arcsec = [2, 2, -3]\n",
                           "ins.attitude_noise_arcsec[2]"),
    "ins-drift-1e308": ("[ins]\nattitude_drift_arcsec_per_h = [1e308, 5, 15]\n",
                        "ins.attitude_drift_arcsec_per_h[0]"),
    "ins-drift-negative": ("[ins]\nattitude_drift_arcsec_per_h = [5, -5, 15]\n",
                           "ins.attitude_drift_arcsec_per_h[1]"),
    # the mounting and the sensor geometry: they failed deep in navigation or georeferencing
    "antenna-1e308": ("[mounting]\nantenna_offset_m = [1e308, 0.0, -1.5]\n",
                      "mounting.antenna_offset_m[0]"),
    "lever-1e7": ("[mounting]\nlever_arm_m = [0.0, 0.0, 1e7]\n", "mounting.lever_arm_m[2]"),
    "boresight-1e300": ("[mounting]\nboresight_arcsec = [0.0, 1e300, 0.0]\n",
                        "mounting.boresight_arcsec[1]"),
    "effective-focal": ("[scanner]\nfocal_length_mm = 1.0\ndelta_focal_mm = -50\n",
                        "scanner: focal_length_mm + delta_focal_mm"),
    "focal-1e-300": ("[scanner]\nfocal_length_mm = 1e-300\n", "scanner.focal_length_mm"),
    "principal-point": ("[scanner]\nprincipal_point_um = [1e300, 0.0]\n",
                        "scanner.principal_point_um[0]"),
    # the block name becomes the simulated run's sensor name (sisa.commands.process.sensor_of)
    "block-name-newline": ('[block]\nname = "two\\nlines"\n', "block.name"),
}

# Just inside each bound: (overrides of bench, the bound it sits at)
GOOD: dict[str, dict[str, Any]] = {
    "start-gps-epoch": {"block": {"start_gps": "1980-01-06T00:00:00"}},
    "start-last-second": {"block": {"start_gps": "2079-12-30T23:59:59"}},
    "airfield-200-km": {"flight": {"airfield_offset_m": [200_000.0, -200_000.0]}},
    "speed-10": {"block": {"ground_speed_kmh": 10.0}, "flight": {"turn_bank_deg": 8.0}},
    "speed-1000": {"block": {"ground_speed_kmh": 1000.0}},
    # 0.1 m DEM and 1 cm texture over a small block
    "dem-0.1": {"block": {"strips": 1, "strip_length_m": 200.0, "flying_height_agl_m": 50.0},
                "terrain": {"dem_spacing_m": 0.1, "margin_m": 50.0, "texture_cell_m": 0.1}},
    "texture-0.01": {"block": {"strips": 1, "strip_length_m": 100.0, "flying_height_agl_m": 20.0},
                     "terrain": {"margin_m": 0.0, "texture_cell_m": 0.01}},
    "dem-cells": {"terrain": {"dem_spacing_m": 1.6}},
    "scene-cells": {"terrain": {"texture_cell_m": 0.32}},
    "takeoff-0.5": {"flight": {"takeoff_acceleration_mps2": 0.5}},
    "climb-0.5": {"flight": {"climb_rate_mps": 0.5}},
    "turn-rate": {"block": {"ground_speed_kmh": 36.0}, "flight": {"turn_bank_deg": 28.0}},
    "line-samples": {"scanner": {"pixels": 2048, "bands": 256}},
    "points": {"terrain": {"control_points": 10_000, "check_points": 10_000}},
    "ins-errors": {"ins": {"attitude_bias_arcsec": [3600.0, 0.0, 3600.0],
                           "attitude_noise_arcsec": [0.0, 3600.0, 3600.0],
                           "attitude_drift_arcsec_per_h": [150.0, 150.0, 0.0]}},
    "mounting": {"mounting": {"lever_arm_m": [100.0, -100.0, 100.0],
                              "antenna_offset_m": [-100.0, 100.0, -100.0],
                              "boresight_arcsec": [648_000.0, -648_000.0, 0.0]}},
    "effective-focal": {"scanner": {"focal_length_mm": 50.0, "delta_focal_mm": -49.9}},
}


def _write(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "s.toml"
    path.write_text('base = "bench"\n' + body, encoding="utf-8")
    return path


@pytest.mark.parametrize(("body", "field"), list(BAD.values()), ids=list(BAD))
def test_bad_value_is_one_line_naming_the_field_and_exit_2(tmp_path, capsys, body, field):
    path = _write(tmp_path, body)
    assert main(["scenario", "show", str(path)]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.count("\n") == 1, err
    assert "Traceback" not in err
    assert str(path) in err
    assert field in err
    assert not re.search(r"\d{20}", err), err  # no 300-digit numbers


@pytest.mark.parametrize("table", list(GOOD.values()), ids=list(GOOD))
def test_values_just_inside_the_bounds_load(table):
    scenario_from_table({"base": "bench", **table})


def test_boundary_values_show(tmp_path, capsys):
    """The CLI too: the GPS epoch, the slowest speed and the finest DEM show their figures."""
    for name in ("start-gps-epoch", "speed-10", "dem-0.1"):
        body = "".join(f"[{t}]\n" + "".join(f"{k} = {v!r}\n".replace("'", '"')
                                             for k, v in fields.items())
                       for t, fields in GOOD[name].items())
        assert main(["scenario", "show", str(_write(tmp_path, body))]) == 0, name
        assert "flight_duration_s" in capsys.readouterr().out


@pytest.mark.parametrize("name", ["start-2300", "start-1970", "airfield-1e12", "speed-0.001",
                                  "dem-1e-9", "ins-bias-1e308"])
def test_emulate_refuses_before_any_port_or_folder(tmp_path, name):
    body, field = BAD[name]
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "sisa.cli", "emulate", "--scenario",
                           str(_write(tmp_path, body)), "--out", str(out), "--duration", "1"],
                          capture_output=True, text=True, check=False, timeout=120)
    assert proc.returncode == 2
    assert proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert field in lines[0]
    assert not out.exists()


def test_suggested_dem_spacing_and_texture_cell_are_accepted():
    for field, tiny in (("dem_spacing_m", 0.5), ("texture_cell_m", 0.05)):
        with pytest.raises(ConfigError) as err:
            scenario_from_table({"base": "garrotxa", "terrain": {field: tiny}})
        found = re.search(r"at least ([0-9.]+) m", str(err.value))
        assert found, str(err.value)
        scenario_from_table({"base": "garrotxa", "terrain": {field: float(found[1])}})


def test_turn_rate_bound_is_g_tan_bank_over_speed():
    max_bank = math.degrees(math.atan(math.radians(30.0) * 10.0 / 9.80665))  # 28.1° at 10 m/s
    ok = scenario_from_table({"block": {"ground_speed_kmh": 36.0},
                              "flight": {"turn_bank_deg": max_bank - 0.01}})
    assert turn_rate_deg_s(ok) == pytest.approx(30.0, abs=0.02)
    with pytest.raises(ConfigError, match=rf"bank at most {max_bank:.2f}°"):
        scenario_from_table({"block": {"ground_speed_kmh": 36.0},
                             "flight": {"turn_bank_deg": max_bank + 0.01}})


def test_flight_duration_limit_is_sharp():
    def table(length_m: float) -> dict[str, Any]:
        return {"base": "bench", "block": {"strips": 12, "strip_length_m": length_m},
                "terrain": {"dem_spacing_m": 1000.0, "texture_cell_m": 1000.0}}

    lo, hi = 3000.0, 500_000.0  # bisect the strip length where the bound reaches the limit
    for _ in range(40):
        mid = (lo + hi) / 2
        try:
            scenario_from_table(table(mid))
            lo = mid
        except ConfigError:
            hi = mid
    bound_h = sum(flight_duration_bound_s(scenario_from_table(table(lo))).values()) / 3600
    assert bound_h == pytest.approx(MAX_FLIGHT_H, rel=1e-6)
    with pytest.raises(ConfigError, match="the flight would last up to 24"):
        scenario_from_table(table(hi))


def _planned_end_s(scn: scenario_module.Scenario) -> float:
    return trajectory._plan(scn, LocalPlane.for_scenario(scn)).t_end_s


def test_plan_constants_match_the_trajectory():
    assert scenario_module._PLAN_SMOOTHING_SIGMA_S == trajectory.SMOOTHING_SIGMA_S
    assert scenario_module._PLAN_KERNEL_HALF_WIDTH_S == trajectory.KERNEL_HALF_WIDTH_S
    assert scenario_module._PLAN_CLIMB_OUT_MIN_S == trajectory.CLIMB_OUT_MIN_S
    assert scenario_module._PLAN_CLIMB_ACCELERATION_MPS2 == trajectory.CLIMB_ACCELERATION_MPS2
    assert scenario_module._PLAN_CLIMB_RAMP_S == trajectory.CLIMB_RAMP_S


VARIED: list[dict[str, Any]] = [
    {"base": "bench"}, {"base": "garrotxa"}, {"base": "bellmunt"},
    # slow UAV at the turn-rate limit, holding circles to finish a long climb
    {"base": "bench", "block": {"ground_speed_kmh": 36.0, "flying_height_agl_m": 3000.0},
     "flight": {"turn_bank_deg": 28.0, "climb_rate_mps": 0.5}},
    # fast, shallow turns, strips not alternating, transversal strips, far airfield
    {"base": "bench", "block": {"ground_speed_kmh": 900.0, "strips": 5, "transversal_strips": 2,
                                "alternate_directions": False, "first_strip_heading_deg": 37.0},
     "flight": {"turn_bank_deg": 5.0, "airfield_offset_m": [150_000.0, 90_000.0],
                "figure_eights": 3}},
    # close strips, a wide turn, a slow take-off
    {"base": "bench", "block": {"strips": 9, "side_overlap_pct": 90.0},
     "flight": {"turn_bank_deg": 10.0, "takeoff_acceleration_mps2": 0.5,
                "rotation_speed_kmh": 400.0}},
]


@pytest.mark.parametrize("table", VARIED)
def test_duration_bound_holds_the_planned_flight(table):
    scn = scenario_from_table(table)
    bound_s = sum(flight_duration_bound_s(scn).values())
    planned_s = _planned_end_s(scn)
    assert planned_s <= bound_s <= 2.5 * planned_s


@pytest.mark.parametrize("table", VARIED)
def test_dem_extent_is_the_terrain_grid_to_a_per_cent(table):
    scn = scenario_from_table(table)
    west, south, east, north = _dem_bounds_utm(scn, LocalPlane.for_scenario(scn))
    width_m, height_m = dem_extent_m(scn)
    assert 1.0 <= width_m / (east - west) <= 1.02
    assert 1.0 <= height_m / (north - south) <= 1.02


@pytest.mark.parametrize("name", ["bench", "garrotxa", "bellmunt"])
def test_presets_are_well_inside_every_limit(name):
    scn = load_scenario(name)
    width_m, height_m = dem_extent_m(scn)
    assert width_m * height_m / scn.terrain.dem_spacing_m**2 < MAX_DEM_CELLS / 2
    assert sum(flight_duration_bound_s(scn).values()) / 3600 < MAX_FLIGHT_H / 4
    assert turn_rate_deg_s(scn) < 20.0
