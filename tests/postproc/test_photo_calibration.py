"""The frame camera's calibration (postproc.calibration.photos and framemodel).

The frame model's projection is checked against the photo EO's own (postproc.georef.photos.
project_to_photo: another implementation of the collinearity, through photo_eo's pose); the
boresight is recovered from markers measured in photos the emulator rendered (sisa.wiring.
photogcp: rendered by the forward model, measured as centroids, never projected for the
adjustment), starting from zero.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from emulators.scenario import CameraSettings
from postproc.calibration import (
    CalibrationOptions,
    Group,
    PhotoCalibrationInput,
    PriorSigmas,
    calibrate_photos,
    photo_report_json,
)
from postproc.calibration.framemodel import FrameCameraModel
from postproc.calibration.model import ObsGeometry
from postproc.calibration.params import build_layout
from postproc.calibration.photos import start_state
from postproc.georef import PhotoTimes, photo_eo, project_to_photo
from sisa.core.errors import InputError
from sisa.core.framecamera import FrameCamera, FrameMounting
from sisa.wiring.photogcp import SimulatedBlock, TruthNavigation, simulate_block

TRUE_BORESIGHT = (300.0, -200.0, 600.0)
CAMERA: dict[str, Any] = {
    "trigger_interval_s": 2.0,
    "model": {"width_px": 480, "height_px": 360, "pixel_pitch_um": 10.0,
              "focal_length_mm": 6.0, "k1": -0.1, "k2": 0.02, "p1": 0.001, "p2": -0.0005,
              "principal_point_px": [3.0, -2.0]},
    "mounting": {"lever_arm_m": [0.4, -0.2, 0.3], "boresight_arcsec": list(TRUE_BORESIGHT)}}


@pytest.fixture(scope="module")
def block() -> SimulatedBlock:
    return simulate_block({"base": "bench", "seed": 2, "camera": CAMERA}, sigma_px=0.04,
                          first_photo=100)


def _nominal(camera: CameraSettings) -> FrameCamera:
    return FrameCamera(interior=camera.model,
                       mounting=FrameMounting(lever_arm_m=camera.mounting.lever_arm_m))


def test_the_frame_model_projects_as_the_photo_eo_does(block: SimulatedBlock) -> None:
    """Every control point in every photo: the adjustment's projection at the true boresight
    against project_to_photo on photo_eo's pose (two implementations), < 1e-6 px."""
    cam = FrameCamera(interior=block.camera.model, mounting=block.camera.mounting)
    nav = TruthNavigation(block.traj)
    eo = photo_eo(nav, block.times.labels, block.times.t_mid_gps_ns, cam.mounting)
    n_photo, n_point = block.times.photo_number.size, len(block.points)
    photo = np.repeat(np.arange(n_photo), n_point)
    point = np.tile(np.arange(n_point), n_photo)
    origin = block.points.ecef_m.mean(axis=0)
    n = photo.size
    geom = ObsGeometry(point, np.zeros(n, np.int64), block.times.t_mid_gps_ns[photo],
                       np.zeros(n), np.ones(n), np.zeros(n), np.zeros(n), np.ones(n))
    model = FrameCameraModel(nav, cam, geom, origin)
    layout = build_layout((Group.BORESIGHT,), [0], start_state(cam, 0.0, 1))
    col, row = model.image_points(layout.base, block.points.ecef_m[point] - origin,
                                  model.pose_at_delay(0.0))
    want_col = np.empty(n)
    want_row = np.empty(n)
    for i in range(n_photo):
        sel = photo == i
        want_col[sel], want_row[sel] = project_to_photo(eo, i, block.points.ecef_m,
                                                        cam.interior)
    inside = np.isfinite(want_col)
    assert inside.sum() > 20
    assert np.array_equal(np.isfinite(col), inside)
    assert np.abs(col[inside] - want_col[inside]).max() < 1e-6
    assert np.abs(row[inside] - want_row[inside]).max() < 1e-6


def test_the_boresight_is_recovered_from_measured_markers(block: SimulatedBlock) -> None:
    """Started from zero; within 3σ of the truth (measured 2026-11-29, seed 2: see
    docs/calibration.md, "The frame camera", for the bench over seeds)."""
    inp = PhotoCalibrationInput(TruthNavigation(block.traj), block.times, block.points,
                                block.obs, _nominal(block.camera))
    res = calibrate_photos(inp, CalibrationOptions(
        groups=(Group.BORESIGHT,), gcp_sigma_m=(0.01, 0.01),
        priors=PriorSigmas(principal_point_x_um=None)))
    assert block.centroid_error_rms_px < 0.1
    assert res.counts["observations_used"] >= 20
    z = (res.theta - np.array(TRUE_BORESIGHT)) / res.sigma
    print("boresight", res.theta.round(2), "±", res.sigma.round(2), "z", z.round(2))
    assert np.abs(z).max() < 3.0
    assert (res.sigma < 10.0).all()  # arcsec: a real determination, not a prior
    assert res.camera.mounting.boresight_arcsec == pytest.approx(res.theta.tolist())
    doc = photo_report_json(res)
    assert [p["name"] for p in doc["parameters"]] == ["omega", "phi", "kappa"]
    assert FrameCamera.model_validate(doc["camera"]) == res.camera


def test_a_photo_without_a_time_is_left_out_and_said(block: SimulatedBlock) -> None:
    times = PhotoTimes(block.times.photo_number,
                       np.where(np.arange(block.times.photo_number.size) % 2 == 0,
                                block.times.t_mid_gps_ns, -1))
    inp = PhotoCalibrationInput(TruthNavigation(block.traj), times, block.points, block.obs,
                                _nominal(block.camera))
    res = calibrate_photos(inp, CalibrationOptions(groups=(Group.BORESIGHT,),
                                                   gcp_sigma_m=(0.01, 0.01)))
    assert any("without a time" in note for note in res.notes)
    assert res.counts["observations"] == len(block.obs)


def test_no_control_in_any_photo_is_one_error(block: SimulatedBlock) -> None:
    keep = block.points.kind != "control"
    obs = block.obs.select(np.isin(block.obs.point_id, block.points.ids[keep]))
    inp = PhotoCalibrationInput(TruthNavigation(block.traj), block.times, block.points, obs,
                                _nominal(block.camera))
    with pytest.raises(InputError, match="no control point is observed"):
        calibrate_photos(inp)
