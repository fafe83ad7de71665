"""`sisa calibrate` end to end on a short simulated run with an injected boresight and
self-calibration: measurements simulated from the truth, sync and navigation from the log, the
adjustment, and a calibration file that `sisa georef --sensor` can read; and two such runs
(another height and speed, later in the day) calibrated together as two flights."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest

from postproc.georef import SensorModel
from sisa.cli import main

SCENARIO = """base = "bench"
seed = 11
[block]
strip_length_m = 2500.0
[flight]
static_alignment_s = 40.0
[terrain]
control_points = 16
check_points = 10
[mounting]
boresight_arcsec = [900.0, -300.0, 200.0]
[scanner]
delta_focal_mm = 0.4
delta_principal_point_um = [0.0, 30.0]
"""


# Two strips and 16 control points cannot separate ω from δy0 to a pixel (σω ~500–800″, IFOV
# 318″; correlation −0.9998): `sisa calibrate` then writes no sensor file unless forced. The tests
# of the adjustment's mechanics force it; test_an_ill_conditioned_adjustment_writes_no_sensor
# checks the refusal itself.
WEAK_BLOCK = ["--force"]


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("calcli")
    (root / "scn.toml").write_text(SCENARIO)
    assert main(["simulate", "--scenario", str(root / "scn.toml"), "--out", str(root / "run"),
                 "--no-images"]) == 0
    return root / "run"


# the second flight: lower and faster (H/v 3.3 s against 10 s), two hours later, 8 km east (a
# simulated run has its own terrain: two over one area would have two DEMs of one place)
SECOND = SCENARIO.replace("[block]\n", """[block]
flying_height_agl_m = 300.0
ground_speed_kmh = 324.0
start_gps = "2026-06-15T11:00:00"
centre_lon_deg = 2.1
""")


@pytest.fixture(scope="module")
def second(run: Path) -> Path:
    root = run.parent
    (root / "scn2.toml").write_text(SECOND)
    assert main(["simulate", "--scenario", str(root / "scn2.toml"), "--out", str(root / "run2"),
                 "--no-images"]) == 0
    return root / "run2"


@pytest.fixture(scope="module")
def cal(run: Path) -> Path:
    out = run.parent / "cal"
    assert main(["calibrate", str(run), "--out", str(out), "--tie-points", "40",
                 "--blunders", "2", "--seed", "3", "--gcp-sigma-m", "0.05,0.05",
                 *WEAK_BLOCK]) == 0
    return out


def _param(report: dict[str, Any], name: str) -> tuple[float, float]:
    row = next(p for p in report["parameters"] if p["name"] == name)
    return row["estimate"], row["sigma"]


def test_calibration_recovers_the_injected_sensor(cal: Path) -> None:
    report = json.loads((cal / "calibration.json").read_text())
    truth = report["truth"]
    est, sig = _param(report, "delta_focal")
    assert abs(est - truth["delta_focal_mm"]) < 3 * sig
    assert sig < 0.05
    est, sig = _param(report, "kappa")
    assert abs(est - truth["boresight_with_ins_bias_arcsec"][2]) < 3 * sig
    look = report["look_offsets"]["across_um"]
    f_um = (9.33 + truth["delta_focal_mm"]) * 1e3
    want = (truth["delta_principal_point_um"][1]
            + f_um * math.radians(truth["boresight_with_ins_bias_arcsec"][0] / 3600))
    assert abs(look["value"] - want) < 3 * look["sigma"] + 0.5
    assert report["counts"]["tie_points"] >= 20
    assert "sync of the flight log" in report["line_times"]
    # the run's receiver states a phase solution: the navigation model takes its σ and τ
    assert report["navigation_accuracy"] == {"gps_sigma_m": [0.03, 0.05],
                                             "gps_correlation_s": 60.0}
    assert report["navigation_model"]["prior_sigma_enu_m"] == [[0.03, 0.03, 0.05]]


@pytest.mark.parametrize("flag", [["--nav-sigma-m=-1,2"], ["--nav-sigma-m", "1"],
                                  ["--nav-correlation-s", "0"]])
def test_a_bad_navigation_accuracy_is_one_line(run: Path, flag: list[str],
                                               capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["calibrate", str(run), "--out", str(run.parent / "never"), *flag]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_injected_blunders_are_rejected(cal: Path) -> None:
    report = json.loads((cal / "calibration.json").read_text())
    injected = {b["id"] for b in report["injected_blunders"]}
    # a blunder on one ray of a two-ray tie point cannot be told from its other ray: the
    # rejection names the point either way (and drops it)
    found = {b["id"] for b in report["blunders"] if b["kind"] == "image"}
    assert len(injected) == 2
    assert injected <= found
    assert len(found) <= 3
    assert 0.6 < report["sigma0"] < 1.5


def test_the_calibration_file_loads_as_a_sensor_file(cal: Path) -> None:
    sensor = SensorModel.load(cal / "sensor.toml")
    report = json.loads((cal / "calibration.json").read_text())
    assert sensor.mounting.boresight_arcsec[2] == pytest.approx(_param(report, "kappa")[0])
    assert sensor.scanner.delta_focal_mm == pytest.approx(_param(report, "delta_focal")[0])
    assert "(calibrated)" in sensor.name


def test_written_measurements_reproduce_the_adjustment(cal: Path, run: Path) -> None:
    out = run.parent / "again"
    assert main(["calibrate", str(run), "--out", str(out), "--obs",
                 str(cal / "observations.csv"), "--gcp", str(cal / "points.csv"),
                 "--gcp-sigma-m", "0.05,0.05", *WEAK_BLOCK]) == 0
    a = json.loads((cal / "calibration.json").read_text())
    b = json.loads((out / "calibration.json").read_text())
    assert _param(b, "delta_focal")[0] == pytest.approx(_param(a, "delta_focal")[0], abs=1e-3)
    assert len(b["blunders"]) == len(a["blunders"])


def test_bad_requests_are_one_line_errors(run: Path, capsys: pytest.CaptureFixture[str]
                                          ) -> None:
    out = run.parent / "bad"
    assert main(["calibrate", str(run), "--out", str(out), "--estimate", "boresite"]) == 2
    err = capsys.readouterr().err.strip()
    assert "unknown group 'boresite'" in err
    assert "\n" not in err
    assert main(["calibrate", str(run / "flight.mcap"), "--out", str(out)]) == 2
    assert "needs" in capsys.readouterr().err
    (run.parent / "obs.csv").write_text("id,segment,line,pixel\nC001,0,10.5,100.25\n")
    assert main(["calibrate", str(run), "--out", str(out), "--obs",
                 str(run.parent / "obs.csv")]) == 2
    assert "no column 'sigma_px'" in capsys.readouterr().err
    assert main(["calibrate", str(run), "--out", str(out), "--seed", "-3"]) == 2
    assert "--seed -3: use a whole number" in capsys.readouterr().err  # was numpy's traceback
    assert main(["calibrate", str(run), "--out", str(out), "--prior-attitude-arcsec", "-20"]) == 2
    assert "--prior-attitude-arcsec must be ≥ 0" in capsys.readouterr().err  # was: no prior
    # measurements of a segment the flight does not have: said only 'no control point'
    (run.parent / "obs7.csv").write_text("id,segment,line,pixel,sigma_px\nC001,7,10.5,100.25,0.3\n")
    assert main(["calibrate", str(run), "--out", str(out), "--obs",
                 str(run.parent / "obs7.csv")]) == 2
    assert "1 observations in a segment the recording does not have" in capsys.readouterr().err
    assert not out.exists()


def test_border_control_points_can_be_measured_in_one_image(run: Path) -> None:
    """seed 000: the ground points on the block borders have one observation, the others two."""
    import numpy as np

    from postproc.calibration import read_ground_points, read_observations
    from sisa.wiring.gcpsim import border_control

    pts = read_ground_points(run / "terrain" / "ground_points.csv")
    ctl = pts.kind == "control"
    near = border_control(pts, 6)
    assert len(near) == 6
    assert all(bool(ctl[k]) for k in near)
    out = run.parent / "one-view"
    assert main(["calibrate", str(run), "--out", str(out), "--single-view-control",
                 str(int(ctl.sum())), "--tie-points", "20", "--seed", "3",
                 "--gcp-sigma-m", "0.05,0.05", *WEAK_BLOCK]) == 0
    obs = read_observations(out / "observations.csv")
    ids, counts = np.unique(obs.point_id, return_counts=True)
    per = dict(zip(ids.tolist(), counts.tolist(), strict=True))
    assert {per[i] for i in pts.ids[ctl].tolist() if i in per} == {1}


DELAY = ["--estimate", "boresight,selfcal,delay", "--sim-delay-ms", "40", "--tie-points", "40",
         "--seed", "3", "--gcp-sigma-m", "0.05,0.05", *WEAK_BLOCK]


def test_two_flights_calibrate_together(run: Path, second: Path) -> None:
    """One delay, boresight and self-calibration for two flights of another H/v: the joint
    adjustment fixes the delay (and the shared groups) better than either flight alone."""
    root = run.parent
    for name, runs in (("alone1", [run]), ("alone2", [second]), ("joint", [run, second])):
        assert main(["calibrate", *map(str, runs), "--out", str(root / name), *DELAY]) == 0
    one, two, joint = (json.loads((root / n / "calibration.json").read_text())
                       for n in ("alone1", "alone2", "joint"))
    for name in ("time_delay", "phi", "delta_focal"):
        sig = _param(joint, name)[1]
        assert sig < _param(one, name)[1], name
        assert sig < _param(two, name)[1], name
    est, sig = _param(joint, "time_delay")
    assert abs(est - 40.0) < 4 * sig
    assert not joint["blunders"]
    assert joint["check_points"]["rms_across_px"] < 1.0
    assert [f["run"] for f in joint["flights"]] == [str(run), str(second)]
    assert all(f["truth"]["time_delay_ms"] == pytest.approx(40.0) for f in joint["flights"])
    assert joint["counts"]["strips"] == one["counts"]["strips"] + two["counts"]["strips"]
    res = joint["residuals"]
    assert {r["flight"] for r in res} == {0, 1}
    assert all(r["id"].startswith(f"{r['flight']}:") and r["segment"] // 1000 == r["flight"]
               for r in res)
    assert len(res) == len(one["residuals"]) + len(two["residuals"])
    assert {p["flight"] for p in joint["points"]} == {0, 1}
    sensor = SensorModel.load(root / "joint" / "sensor.toml")
    assert sensor.time_delay_ms == pytest.approx(est)
    obs = (root / "joint" / "observations.csv").read_text()
    assert "\n1:" in obs
    assert "\n0:" in obs


def test_several_runs_refuse_per_run_files(run: Path, second: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    out = run.parent / "bad-joint"
    for opt, value in (("--gcp", run / "terrain" / "ground_points.csv"),
                       ("--obs", run / "terrain" / "ground_points.csv"),  # any file there
                       ("--scanner", run / "terrain"), ("--dem", run / "terrain" / "dem.tif")):
        assert main(["calibrate", str(run), str(second), "--out", str(out), opt,
                     str(value)]) == 2
        err = capsys.readouterr().err.strip()
        assert opt in err
        assert "several runs" in err
        assert "\n" not in err
    assert main(["calibrate", str(run), str(second / "flight.mcap"), "--out", str(out)]) == 2
    assert "not both" in capsys.readouterr().err
    assert main(["calibrate", str(run), str(run), "--out", str(out), "--no-dem"]) == 2
    assert "overlap in GPS time" in capsys.readouterr().err
    assert not out.exists()


def test_several_runs_refuse_disagreeing_dems(run: Path, capsys: pytest.CaptureFixture[str]
                                              ) -> None:
    """The joined input takes a place's height from the first DEM that covers it: a second
    run whose DEM of the same place differs (as a simulated run over one area would) is
    refused."""
    import shutil

    import rasterio

    other = run.parent / "same-area"
    shutil.copytree(run, other)
    with rasterio.open(other / "terrain" / "dem.tif", "r+") as ds:
        ds.write(ds.read(1) + 20.0, 1)
    out = run.parent / "bad-dems"
    assert main(["calibrate", str(run), str(other), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "DEM differs" in err
    assert "--no-dem" in err
    assert not out.exists()


def test_a_dem_beside_the_flight_leaves_no_check_point_and_valid_json(
        run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """With a DEM that covers no check point the headline raised a TypeError (after the
    output folder was complete) and calibration.json held bare NaN, which JSON readers
    refuse."""
    import rasterio

    far = run.parent / "far-dem.tif"
    with rasterio.open(run / "terrain" / "dem.tif") as src:
        profile, heights = src.profile, src.read(1)
        t = src.transform
    profile["transform"] = rasterio.Affine(t.a, t.b, t.c + 200_000.0, t.d, t.e, t.f)
    with rasterio.open(far, "w", **profile) as dst:
        dst.write(heights, 1)
    out = run.parent / "cal-far-dem"
    assert main(["calibrate", str(run), "--out", str(out), "--dem", str(far),
                 *WEAK_BLOCK]) == 0
    assert "check points: none could be measured" in capsys.readouterr().out
    text = (out / "calibration.json").read_text()
    assert "NaN" not in text
    assert json.loads(text)["check_points"]["rms_along_m"] is None


def test_left_out_measurements_are_warnings_on_stderr(cal: Path, run: Path,
                                                      capsys: pytest.CaptureFixture[str]
                                                      ) -> None:
    """Rows off the image, on an untimed line or in a segment the log lacks were dropped with
    only a note in calibration.json: exit 0 and nothing said."""
    from postproc.calibration import read_observations

    obs = read_observations(cal / "observations.csv")
    taken = set(zip(obs.point_id.tolist(), obs.segment.tolist(), strict=True))
    segments = sorted(set(obs.segment.tolist()))
    ctl = sorted({i for i in obs.point_id.tolist() if i.startswith("C")})
    free = [(i, s) for i in ctl for s in segments if (i, s) not in taken]
    (i1, s1), (i2, s2) = free[:2]
    path = run.parent / "obs-off.csv"
    path.write_text((cal / "observations.csv").read_text()
                    + f"{i1},{s1},99999,100,0.3\n{i2},{s2},-5,100,0.3\n{ctl[0]},7,10,100,0.3\n")
    out = run.parent / "cal-off"
    assert main(["calibrate", str(run), "--out", str(out), "--obs", str(path), "--gcp",
                 str(cal / "points.csv"), "--gcp-sigma-m", "0.05,0.05", *WEAK_BLOCK]) == 0
    err = capsys.readouterr().err.splitlines()
    assert (f"sisa calibrate: warning: 2 observations on an untimed line or off the image: "
            f"left out ({i1} in segment {s1} at line 99999, {i2} in segment {s2} at line -5)"
            in err)
    assert (f"sisa calibrate: warning: 1 observations in a segment the recording does not have "
            f"({ctl[0]} in segment 7 at line 10)" in err)
    assert all(line.startswith("sisa calibrate: warning: ") for line in err)
    assert len(json.loads((out / "calibration.json").read_text())["notes"]) == len(err)


@pytest.mark.parametrize(("option", "expected"), [
    (["--noise-px", "1e300"], "--noise-px 1e+300: must be 0 to 1 (pixels: 3σ must stay within"),
    (["--noise-px", "-0.1"], "--noise-px -0.1: must be 0 to 1"),
    (["--gcp-sigma-m", "1e-300,0.5"], "--gcp-sigma-m 1e-300: must be 0.001 to 100"),
    (["--gcp-sigma-m", "0.5,1e300"], "--gcp-sigma-m 1e+300: must be 0.001 to 100"),
    (["--dem-sigma-m", "1e300"], "--dem-sigma-m 1e+300: must be 0.001 to 1000"),
    (["--prior-attitude-arcsec", "1e-300"], "--prior-attitude-arcsec 1e-300: must be 0 (no "
     "prior) or ≥ 0.001"),
    (["--sweep-delay-ms", "1e300"], "--sweep-delay-ms 1e+300: must be ±5 to ±1000"),
    (["--sweep-delay-ms", "0"], "--sweep-delay-ms 0: must be ±5 to ±1000"),
    (["--sim-delay-ms=-1e300"], "--sim-delay-ms -1e+300: must be within ±1000"),
    (["--sim-gcp-noise-m", "1e300,0"], "--sim-gcp-noise-m 1e+300: must be 0 to 100"),
])
def test_options_out_of_range_are_one_line_errors(run: Path, capsys: pytest.CaptureFixture[str],
                                                  option: list[str], expected: str) -> None:
    """Each was a traceback (sweep 1e300: numpy's array size; prior 1e-300: eigenvalues;
    sim delay 1e300: int overflow), numpy warnings, or an error blaming the sensor file in a
    300-digit pixel number (--noise-px 1e300)."""
    out = run.parent / "bad-option"
    assert main(["calibrate", str(run), "--out", str(out), *option]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert err.startswith(f"sisa calibrate: error: {expected}"), err
    assert "\n" not in err
    assert len(err) < 300
    assert not out.exists()


@pytest.mark.parametrize(("text", "expected"), [
    ("# EPSG:99999\nid,kind,easting_m,northing_m,height_m\nC001,control,416959.6,4605321.6,"
     "271.4\n", "g.csv: EPSG:99999 (from its # comment) is not a known CRS"),
    ("id,kind,lat_deg,lon_deg,height_m\nC001,control,41.6,2.0,271.4\nC002,check,41.6,2.0,"
     "1e300\n", "g.csv: column height_m, row 2: 1e+300 is outside -1000..9000"),
])
def test_bad_ground_points_are_one_line_errors(run: Path, capsys: pytest.CaptureFixture[str],
                                               text: str, expected: str) -> None:
    """An unknown EPSG was pyproj's CRSError traceback; a point at height 1e300 was left out
    with nothing said."""
    (run.parent / "g.csv").write_text(text)
    out = run.parent / "bad-gcp"
    assert main(["calibrate", str(run), "--out", str(out), "--gcp",
                 str(run.parent / "g.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"sisa calibrate: error: {run.parent / expected}"), err
    assert "\n" not in err
    assert not out.exists()


def test_an_ill_conditioned_adjustment_writes_no_sensor(
        run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 33, item 3: with the defaults, a short flight with control seen once gave ω ± σ
    hundreds of arcsec beyond the IFOV at correlation −1.000 with δy0, wrote it into sensor.toml
    and said nothing. Now: exit 3, no sensor.toml, the pair named with what would separate them,
    in calibration.json too; the boresight's truth labelled as what it is; --force writes it with
    the warning in the file; a prior on δy0 (the advice) makes a sensor file."""
    root = run.parent
    out = root / "cal-ill"
    assert main(["calibrate", str(run), "--out", str(out)]) == 3
    said = capsys.readouterr()
    assert not (out / "sensor.toml").exists()
    report = json.loads((out / "calibration.json").read_text())
    cond = report["conditioning"]
    assert cond["ill_conditioned"]
    labels = {u["label"] for u in cond["unresolved"]}
    assert "omega" in labels
    omega = next(u for u in cond["unresolved"] if u["label"] == "omega")
    assert omega["sigma"] > cond["pixel_worth"]["omega"]
    assert any(q["label"] == "delta_y0" and q["r"] < -0.99 for q in omega["partners"])
    note, = [n for n in report["notes"] if "cannot separate" in n]
    assert "omega, delta_y0" in note
    assert "--prior-y0-um" in note
    err = said.err.splitlines()
    assert f"sisa calibrate: warning: {note}" in err
    assert err[-1].startswith("sisa calibrate: warning: ill-conditioned adjustment: no ")
    assert "--force" in err[-1]
    assert "(truth* " in said.out
    assert "* truth of the boresight: the scenario's (900, -300, 200) arcsec composed with the " \
           "run's INS attitude bias" in said.out
    forced = root / "cal-ill-forced"
    assert main(["calibrate", str(run), "--out", str(forced), "--force"]) == 0
    assert "# WARNING, ill-conditioned: the observations cannot separate omega, delta_y0" in (
        forced / "sensor.toml").read_text()
    capsys.readouterr()
    prior = root / "cal-prior"
    assert main(["calibrate", str(run), "--out", str(prior), "--prior-y0-um", "20"]) == 0
    assert not json.loads((prior / "calibration.json").read_text())["conditioning"][
        "ill_conditioned"]
    SensorModel.load(prior / "sensor.toml")
