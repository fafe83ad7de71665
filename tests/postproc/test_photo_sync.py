"""Issue 37: a frame camera and the scanner through one sync unit, simulated end to end: every
photo and every scan line on GPS time, 0 wrong tags under the camera's faults, and the scanner's
timing as good with the camera as without it (same seed).

The flight is the short bench of test_sync_faults (~230 s, two 600 m strips) with the
bench_camera preset's camera and receiver, a photo every 31.25 m (0.52 s, near the camera's
0.5 s cycle) so a short flight holds ~40 photos."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from emulators.scenario import Scenario, scenario_from_table
from emulators.truth import read_truth_csv
from postproc.sync import (
    PhotoStatus,
    SyncResult,
    TimeStatus,
    read_sync_input,
    synchronise,
)
from recorder.columns import read_columns
from recorder.messages import Topic
from recorder.parts import recording_metadata
from recorder.settings import recorded_camera_window_ms
from sisa.wiring.simulation import simulate
from tests.postproc.test_sync import (
    all_timed_between_latches,
    ins_truth_ns,
    line_truth_ns,
    ok_errors_ns,
)
from tests.postproc.test_sync_faults import SHORT, _merge

PHOTO_WRONG_NS = 5_000  # a photo time off by more than this while timed is a wrong tag
CAMERA = {"trigger_distance_m": 31.25}
PROFILES: dict[str, dict[str, Any]] = {
    "no_fault": {},
    "lost_pulses_20pct": {"lost_pulse_fraction": 0.2},
    "lost_photo_numbers_20pct": {"lost_photo_number_fraction": 0.2},
    "spurious_pulses_1hz": {"spurious_pulse_rate_hz": 1.0},
    "pulses_on_frame_pulses_50pct": {"on_frame_fraction": 0.5},
    "all_at_once": {"lost_pulse_fraction": 0.1, "lost_photo_number_fraction": 0.1,
                    "spurious_pulse_rate_hz": 0.5, "on_frame_fraction": 0.3},
}


def scenario(seed: int, camera_faults: dict[str, Any] | None) -> Scenario:
    """The short two-sensor flight; the same without its camera when `camera_faults` is None."""
    scn = scenario_from_table(_merge({"base": "bench_camera", "seed": seed, **SHORT},
                                     {"camera": {**CAMERA, "faults": camera_faults or {}}}))
    return scn.model_copy(update={"camera": None}) if camera_faults is None else scn


def fly(scn: Scenario, run: Path) -> SyncResult:
    simulate(scn, run, images=False)
    window = recorded_camera_window_ms(recording_metadata(run / "flight.mcap"))
    return synchronise(read_sync_input(run / "flight.mcap"), camera_window_ms=window)


def photo_truth(run: Path) -> dict[str, np.ndarray]:
    return read_truth_csv(run / "truth" / "photos.csv")


def photo_errors_ns(res: SyncResult, run: Path) -> np.ndarray:
    """Error of every photo timed with its number."""
    assert res.photos is not None
    truth = photo_truth(run)
    t_of = dict(zip(truth["photo_number"].tolist(), truth["t_mid_gps_ns"].tolist(), strict=True))
    p = res.photos
    named = np.flatnonzero((p.t_gps_ns >= 0) & (p.photo_number >= 0))
    return np.array([p.t_gps_ns[i] - t_of[int(p.photo_number[i])] for i in named], np.int64)


def check_scanner_side(res: SyncResult, run: Path) -> tuple[np.ndarray, np.ndarray]:
    inp = read_sync_input(run / "flight.mcap")
    e_ins = ok_errors_ns(res.ins.t_gps_ns, res.ins.status, ins_truth_ns(run, inp))
    e_line = ok_errors_ns(res.lines.t_gps_ns, res.lines.status, line_truth_ns(run, res))
    all_timed_between_latches(res, max_beyond=5 * 64)
    assert (res.lines.status == TimeStatus.OK).all()
    assert np.abs(e_ins).max() < PHOTO_WRONG_NS
    assert np.abs(e_line).max() < PHOTO_WRONG_NS
    assert np.sqrt(np.mean(e_ins.astype(float) ** 2)) < 1_000
    assert np.sqrt(np.mean(e_line.astype(float) ** 2)) < 1_000
    return e_ins, e_line


@pytest.mark.parametrize("profile", list(PROFILES))
def test_every_photo_timed_or_flagged_never_wrong(profile: str, tmp_path: Path) -> None:
    res = fly(scenario(1, PROFILES[profile]), tmp_path)
    check_scanner_side(res, tmp_path)
    assert res.photos is not None
    err = photo_errors_ns(res, tmp_path)
    assert err.size > 20
    assert np.abs(err).max() < PHOTO_WRONG_NS  # 0 wrong tags
    assert np.sqrt(np.mean(err.astype(float) ** 2)) < 1_000
    truth, p = photo_truth(tmp_path), res.photos
    status_of = {int(n): int(s) for n, s in zip(p.photo_number, p.status, strict=True)
                 if n >= 0}
    both = (truth["pulse_sent"] == 1) & (truth["message_sent"] == 1)
    unresolved = [n for n in truth["photo_number"][both]
                  if status_of[int(n)] not in (PhotoStatus.OK, PhotoStatus.BOARD_TIME)]
    spurious = int((read_truth_csv(tmp_path / "truth" / "faults.csv")["target"]
                    == "CAMERA").sum())
    assert len(unresolved) <= spurious  # only a spurious pulse in its window leaves one
    assert all(status_of[int(n)] == PhotoStatus.AMBIGUOUS for n in unresolved)
    no_pulse = truth["photo_number"][(truth["pulse_sent"] == 0) & (truth["message_sent"] == 1)]
    assert all(status_of[int(n)] in (PhotoStatus.NO_PULSE, PhotoStatus.AMBIGUOUS)
               for n in no_pulse)
    # a pulse whose number was lost keeps its time, with photo number -1
    lost_number = truth["t_mid_gps_ns"][(truth["pulse_sent"] == 1) & (truth["message_sent"] == 0)]
    loose = p.t_gps_ns[(p.status == PhotoStatus.NO_PHOTO_NUMBER) & (p.t_gps_ns >= 0)]
    for t in lost_number:
        assert np.abs(loose - t).min() < PHOTO_WRONG_NS
    targets = read_truth_csv(tmp_path / "truth" / "faults.csv")["target"]
    assert np.isin(targets, ("camera", "CAMERA")).any() == (profile != "no_fault")


def test_pulses_on_frame_pulses_share_the_event_input(tmp_path: Path) -> None:
    """Half the exposures on a scanner frame's mid-exposure: the event input takes one of the
    two pulses, the other is timed by the board, and both sensors stay timed."""
    res = fly(scenario(2, PROFILES["pulses_on_frame_pulses_50pct"]), tmp_path)
    check_scanner_side(res, tmp_path)
    faults = read_truth_csv(tmp_path / "truth" / "faults.csv")
    assert (faults["kind"] == "camera_on_frame").sum() > 10
    rep = res.report["photos"]
    assert rep["camera_pulses_board_timed"] > 0
    assert rep["camera_pulses_tagged"] > 0
    fwd = read_columns(tmp_path / "flight.mcap", Topic.SYNC_FORWARD)
    assert ((fwd["mode"] == 2) & ~fwd["to_gps_event"]).any()  # a frame pulse gave way
    assert np.abs(photo_errors_ns(res, tmp_path)).max() < PHOTO_WRONG_NS


def test_the_scanner_is_timed_as_well_with_the_camera_as_without(tmp_path: Path) -> None:
    """Same seed, with and without the camera: the INS gets the same pulses, every record and
    line is timed in both, and no time moves by more than the tag rounding (a frame pulse the
    camera took the event input from is timed by the board instead of its TTT)."""
    without = fly(scenario(3, None), tmp_path / "without")
    with_camera = fly(scenario(3, {}), tmp_path / "with")
    assert without.photos is None
    assert with_camera.photos is not None
    fwd = [read_columns(tmp_path / name / "flight.mcap", Topic.SYNC_FORWARD)
           for name in ("without", "with")]
    for field in ("board_ns", "source", "mode", "frame_counter"):
        assert (fwd[0][field] == fwd[1][field]).all()
    assert (fwd[0]["to_gps_event"] & ~fwd[1]["to_gps_event"]).any()
    assert (without.ins.status == with_camera.ins.status).all()
    assert (without.lines.status == with_camera.lines.status).all()
    assert np.abs(without.ins.t_gps_ns - with_camera.ins.t_gps_ns).max() < 100
    assert np.abs(without.lines.t_gps_ns - with_camera.lines.t_gps_ns).max() < 100
    rms = [[np.sqrt(np.mean(e.astype(float) ** 2)) for e in check_scanner_side(r, tmp_path / n)]
           for r, n in ((without, "without"), (with_camera, "with"))]
    assert rms[1][0] < 1.2 * rms[0][0] + 5
    assert rms[1][1] < 1.2 * rms[0][1] + 5


def test_sisa_sync_writes_the_photo_table(tmp_path: Path) -> None:
    from postproc.georef import read_photo_times
    from sisa.cli import main

    simulate(scenario(4, {"lost_pulse_fraction": 0.2}), tmp_path / "run", images=False)
    code = main(["sync", str(tmp_path / "run" / "flight.mcap"), "--out",
                 str(tmp_path / "sync")])
    assert code == 3  # the photos whose pulse was lost are not timed: said, exit 3
    table = read_truth_csv(tmp_path / "sync" / "photo_times.csv")  # (a commented CSV too)
    assert (table["status"] == "no_pulse").sum() > 0
    # the photo path's reader (sisa georef --photo-times) takes the table as it is
    photos = read_photo_times(tmp_path / "sync" / "photo_times.csv")
    assert (photos.photo_number == table["photo_number"]).all()
    timed = photos.timed()
    truth = photo_truth(tmp_path / "run")
    assert timed.photo_number.size == int((table["status"] == "ok").sum()
                                          + (table["status"] == "board_time").sum()) > 10
    t_of = dict(zip(truth["photo_number"].tolist(), truth["t_mid_gps_ns"].tolist(),
                    strict=True))
    err = timed.t_mid_gps_ns - np.array([t_of[int(k)] for k in timed.photo_number])
    assert np.abs(err).max() < PHOTO_WRONG_NS


def test_the_photo_times_give_each_photo_its_true_pose(tmp_path: Path) -> None:
    """The sync's photo times into the photo EO path (postproc.georef.photo_eo, through the
    table sisa process hands it: sisa.commands.process.synced_photo_times), on an error-free
    flight: each perspective centre within 1 cm of the truth's, so the time found is the
    photo's (a photo 1 ms off is 6 cm off)."""
    from pyproj import Transformer

    from postproc.georef import NAV_WANTED, merged_wanted, nav_from_columns, photo_eo
    from postproc.sync import WANTED, sync_input_from_columns
    from recorder.columns import read_topics
    from sisa.commands.process import synced_photo_times
    from sisa.commands.simulate import error_free

    scn = error_free(scenario(6, {"lost_photo_number_fraction": 0.2}))
    assert scn.camera is not None
    run = tmp_path / "run"
    simulate(scn, run, images=False)
    cols = read_topics(run / "flight.mcap", merged_wanted(WANTED, NAV_WANTED))
    res = synchronise(sync_input_from_columns(cols), camera_window_ms=recorded_camera_window_ms(
        recording_metadata(run / "flight.mcap")))
    assert res.photos is not None
    traj = nav_from_columns(cols, res.ins, antenna_offset_m=scn.mounting.antenna_offset_m)
    times = synced_photo_times(res.photos)
    eo = photo_eo(traj, times.labels, times.t_mid_gps_ns, scn.camera.mounting, epsg=32631)
    truth = photo_truth(run)
    row_of = {int(n): i for i, n in enumerate(truth["photo_number"])}
    rows = [row_of[int(k)] for k in times.photo_number]
    assert len(rows) == int((truth["message_sent"] == 1).sum())  # the lost numbers: not here
    assert eo.valid.all()
    east, north = Transformer.from_crs(4979, 32631, always_xy=True).transform(
        truth["lon_deg"][rows], truth["lat_deg"][rows])
    off = np.hypot(eo.easting_m - east, eo.northing_m - north)
    assert off.max() < 0.01
    assert np.abs(eo.pose.height_m - truth["height_m"][rows]).max() < 0.01


def test_sisa_sync_says_when_the_camera_pulse_line_is_dead(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]
                                                            ) -> None:
    from sisa.cli import main

    simulate(scenario(5, {"lost_pulse_fraction": 1.0}), tmp_path / "run", images=False)
    code = main(["sync", str(tmp_path / "run" / "flight.mcap"), "--out",
                 str(tmp_path / "sync")])
    assert code == 3
    err = capsys.readouterr().err
    assert "not one camera pulse" in err
    assert "of 40 photos not timed" in err
