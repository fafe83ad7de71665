"""A flight with a frame camera end to end (issue 37, part 3b): `sisa simulate` → `sisa process`
(the scanner's products and, in photos/, the camera's EO exports, footprints, orthos and
mosaic) → `sisa georef --camera` on the same inputs → `sisa calibrate --frame-camera`."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rasterio

from emulators.scenario import load_scenario
from emulators.terrain import Scene, Terrain, ground_points
from tests.postproc.test_photo_ortho import correlation_by_shift, peak_offset_cells

SHORT_WITH_CAMERA = """
base = "bench"
[block]
strip_length_m = 1200.0
[flight]
static_alignment_s = 40.0
[camera]
trigger_interval_s = 1.5
[camera.model]
width_px = 480
height_px = 360
pixel_pitch_um = 10.0
focal_length_mm = 6.0
k1 = -0.1
k2 = 0.02
p1 = 0.001
p2 = -0.0005
principal_point_px = [3.0, -2.0]
[camera.mounting]
lever_arm_m = [0.4, -0.2, 0.3]
boresight_arcsec = [300.0, -200.0, 600.0]
"""


def _sisa(*args: Any, check: bool = True) -> subprocess.CompletedProcess[str]:
    """A `sisa` command in a child process; 15 min (a camera flight renders its photos)."""
    proc = subprocess.run([sys.executable, "-m", "sisa.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=900)
    if check:
        assert proc.returncode == 0, proc.stderr
    return proc


@pytest.fixture(scope="module")
def processed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, str]:
    root = tmp_path_factory.mktemp("camera")
    scn = root / "camera.toml"
    scn.write_text(SHORT_WITH_CAMERA, encoding="utf-8")
    _sisa("simulate", "--scenario", scn, "--out", root / "run")
    proc = _sisa("process", root / "run")
    return root / "run", root / "run" / "process", proc.stdout + proc.stderr


def test_process_makes_the_cameras_products(processed: tuple[Path, Path, str]) -> None:
    _run, out, said = processed
    photos = out / "photos"
    summary = json.loads((photos / "photo_summary.json").read_text())
    n = summary["photos"]
    assert n >= 10
    assert summary["posed"] == summary["footprints"] == summary["orthos"] == n
    assert "truth/photos.csv" not in said  # the photos' times from the sync, not the truth
    assert (out / "sync" / "photo_times.csv").is_file()
    assert "frame camera:" in said
    crs = json.loads((out / "georef_summary.json").read_text())["crs"]
    with rasterio.open(photos / "photo_mosaic.tif") as ds:
        assert f"EPSG:{ds.crs.to_epsg()}" == crs == summary["crs"]
    for name in ("photo_eo.csv", "geo.txt", "footprints.geojson"):
        assert (photos / name).is_file()
    assert len(list((photos / "sidecars").glob("*.json"))) == n
    # the EO against the truth: phase GPS (cm) and the INS's ~10″
    acc = summary["accuracy"]
    assert acc["photos"] == n
    assert acc["position_rms_m"]["horizontal"] < 0.3
    assert max(acc["attitude_rms_arcsec"].values()) < 60.0
    report = (out / "report.html").read_text(encoding="utf-8")
    assert "<h2>Frame camera</h2>" in report
    assert 'alt="Photo mosaic on its map grid' in report
    assert "Map of the trajectory and the photos&#x27; footprints" in report


def test_the_photo_mosaic_aligns_with_the_scene(processed: tuple[Path, Path, str]) -> None:
    """With the navigation the post-processor fused from the log (phase GPS, INS errors):
    measured 2026-11-29 on a bench run, 0.997-0.998, the peak within 0.06 cell (1 m cells)."""
    run, out, _ = processed
    scn = load_scenario(run / "scenario.toml")
    terrain = Terrain.from_scenario(scn)
    scene = Scene.from_scenario(scn, terrain, ground_points(scn, terrain))
    corr = correlation_by_shift(out / "photos" / "photo_mosaic.tif", scene)
    assert (corr[(0, 0)] > 0.99).all()
    for band in range(scene.bands):
        assert max(corr, key=lambda k: float(corr[k][band])) == (0, 0)
    assert np.abs(peak_offset_cells(corr)).max() < 0.25


def test_georef_with_a_camera_file_writes_what_process_wrote(
        processed: tuple[Path, Path, str], tmp_path: Path) -> None:
    run, out, _ = processed
    scn = tomllib.loads((run / "scenario.toml").read_text())
    cam = tmp_path / "camera.toml"
    cam.write_text(json_to_toml({"interior": scn["camera"]["model"],
                                 "mounting": scn["camera"]["mounting"]}), encoding="utf-8")
    geo, synced = tmp_path / "geo", tmp_path / "synced"
    proc = _sisa("georef", run / "flight.mcap", "--scanner", run / "scanner", "--dem",
                 run / "terrain" / "dem.tif", "--out", geo, "--camera", cam, "--photo-times",
                 out / "sync" / "photo_times.csv", "--photos", out / "photos" / "images")
    assert f"{geo / 'photos'}: " in proc.stdout
    summary = json.loads((geo / "photos" / "photo_summary.json").read_text())
    assert summary["orthos"] == summary["photos"]
    # the same camera, times (the sync's table), images and navigation as `sisa process`:
    # the same EO file
    assert (geo / "photos" / "photo_eo.csv").read_bytes() == \
        (out / "photos" / "photo_eo.csv").read_bytes()
    with rasterio.open(geo / "photos" / "photo_mosaic.tif") as ds:
        assert ds.count == 4
    # without --photo-times: the photos the sync of the log times, the same EO again
    _sisa("georef", run / "flight.mcap", "--scanner", run / "scanner", "--dem",
          run / "terrain" / "dem.tif", "--out", synced, "--camera", cam)
    assert (synced / "photos" / "photo_eo.csv").read_bytes() == \
        (out / "photos" / "photo_eo.csv").read_bytes()


def json_to_toml(doc: dict[str, Any]) -> str:
    import tomli_w

    return tomli_w.dumps(doc)


@pytest.mark.parametrize(("args", "says"), [
    (("--photo-times", "x.csv"), "--photo-times needs --camera"),
    (("--photos", "."), "--photos needs --camera"),
])
def test_photo_options_alone_are_one_line(processed: tuple[Path, Path, str], tmp_path: Path,
                                          args: tuple[str, ...], says: str) -> None:
    run, _, _ = processed
    for name in ("x.csv", "cam.toml"):
        (tmp_path / name).write_text("", encoding="utf-8")
    proc = _sisa("georef", run / "flight.mcap", "--scanner", run / "scanner", "--dem",
                 run / "terrain" / "dem.tif", "--out", tmp_path / "out",
                 *(str(tmp_path / a) if a.endswith((".csv", ".toml")) else a for a in args),
                 check=False)
    assert proc.returncode == 2
    assert says in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_a_bad_photo_times_table_is_one_line(processed: tuple[Path, Path, str],
                                             tmp_path: Path) -> None:
    run, _out, _ = processed
    bad = tmp_path / "times.csv"
    bad.write_text("photo_number,t_mid_gps_ns\n1,1.5e18\n", encoding="utf-8")
    cam = tmp_path / "cam.toml"
    cam.write_text("[interior]\nwidth_px = 480\nheight_px = 360\n", encoding="utf-8")
    proc = _sisa("georef", run / "flight.mcap", "--scanner", run / "scanner", "--dem",
                 run / "terrain" / "dem.tif", "--out", tmp_path / "out", "--camera", cam,
                 "--photo-times", bad, check=False)
    assert proc.returncode == 2
    assert "not a whole number" in proc.stderr
    assert not (tmp_path / "out").exists()


def test_calibrate_finds_the_cameras_boresight(processed: tuple[Path, Path, str],
                                               tmp_path: Path) -> None:
    run, _, _ = processed
    cal = tmp_path / "cal"
    proc = _sisa("calibrate", run, "--frame-camera", "--estimate", "boresight",
                 "--gcp-sigma-m", "0.01,0.01", "--out", cal)
    doc = json.loads((cal / "calibration.json").read_text())
    truth = doc["truth"]["boresight_arcsec"]
    params = doc["camera_calibration"]["parameters"]
    z = [(p["estimate"] - t) / p["sigma"] for p, t in zip(params, truth, strict=True)]
    print(proc.stdout, "z", z)
    assert "truth/photos.csv" not in proc.stderr  # the photos timed by the sync of the log
    assert max(abs(v) for v in z) < 3.0
    camera = tomllib.loads((cal / "camera.toml").read_text())
    assert camera["mounting"]["boresight_arcsec"] == pytest.approx(
        [p["estimate"] for p in params])
