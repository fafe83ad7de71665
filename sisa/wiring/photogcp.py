"""Simulated measurements of ground control in the frame camera's photos, from a simulated
run's TRUTH, as an operator makes them: the photos are RENDERED (emulators.camera.
PhotoRenderer: true pose → pixel ray → the emulator's ray caster → scene → DN) and each marker
is measured in the image, as the intensity centroid of its cross, from where the true
geometry says it is (the emulator's forward model and the true camera). What the adjustment
gets is the centroid, not the projection: the measurement carries the rendering's own errors
(pixel sampling, detector noise, the marker drawn on the scene's grid).

`TruthNavigation` puts the true trajectory behind post-processing's Trajectory protocol, for
tests and benchmarks that want the images' error alone.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from emulators.camera import PhotoRenderer, exposure_times, write_photo
from emulators.render import camera_pose_ecef
from emulators.scenario import CameraSettings, Scenario, scenario_from_table
from emulators.terrain import Scene, Terrain, ground_points
from emulators.trajectory import TruthTrajectory
from emulators.truth import read_truth_csv
from postproc.calibration import GroundPoints, ImageObservations
from postproc.georef import PhotoTimes, Pose, geodetic_to_ecef, photo_label
from sisa.core.errors import InputError
from sisa.core.framecamera import R_NOMINAL_K_TO_B, camera_to_image
from sisa.core.frames import body_to_ned_matrix, ned_to_ecef_matrix
from sisa.wiring.gcpsim import effective_boresight_arcsec, flight_truth

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

CENTROID_PASSES: Final = 5  # the window recentred on the centroid this many times
BACKGROUND_PERCENTILE: Final = 10.0  # the dark square's level, subtracted


@dataclass(frozen=True)
class TruthNavigation:
    """The true trajectory as a post-processing Trajectory (INS centre and R_b^e)."""

    traj: TruthTrajectory

    @property
    def span_ns(self) -> tuple[int, int]:
        return self.traj.t_start_ns, self.traj.t_end_ns

    def pose_at(self, t_gps_ns: npt.ArrayLike) -> Pose:
        t = np.asarray(t_gps_ns, np.int64)
        st = self.traj.state(t)
        r_be = ned_to_ecef_matrix(np.radians(st.lat_deg), np.radians(st.lon_deg)) @ \
            body_to_ned_matrix(st.roll_rad, st.pitch_rad, st.heading_rad)
        inside = (t >= self.traj.t_start_ns) & (t <= self.traj.t_end_ns)
        return Pose(t, np.asarray(st.ecef_m), np.asarray(r_be), inside)


def marker_centroid(image: F64, col: float, row: float, radius_px: float) -> tuple[float, float]:
    """The intensity centroid of a marker's bright cross inside its dark square (symmetric
    about the marker's centre), the window of `radius_px` recentred CENTROID_PASSES times
    from (col, row); NaN if the window holds no contrast."""
    rr, cc = np.mgrid[0:image.shape[0], 0:image.shape[1]]
    for _ in range(CENTROID_PASSES):
        inside = np.hypot(cc - col, rr - row) <= radius_px
        v = image[inside]
        if v.size == 0:
            return float("nan"), float("nan")
        w = np.clip(v - np.percentile(v, BACKGROUND_PERCENTILE), 0.0, None)
        if not w.sum() > 0:
            return float("nan"), float("nan")
        col = float((w * cc[inside]).sum() / w.sum())
        row = float((w * rr[inside]).sum() / w.sum())
    return col, row


@dataclass(frozen=True)
class PhotoMeasurements:
    obs: ImageObservations  # segment = photo number, line = row, pixel = col
    projected_px: F64  # (N, 2) where the true geometry puts each point (col, row)
    photos: dict[int, Path]  # the photos rendered, when written


def measure_control(camera: CameraSettings, traj: TruthTrajectory, terrain: Terrain,
                    scene: Scene, points: npt.NDArray[np.void], numbers: I64, t_ns: I64,
                    rng: np.random.Generator, *, radius_px: float, sigma_px: float,
                    folder: Path | None = None) -> PhotoMeasurements:
    """Render every photo (numbers, true mid-exposure times t_ns) that sees a ground point at
    least `radius_px` inside its frame, and measure each such point's marker there. `points`:
    emulators.terrain.ground_points rows. `folder`: where the rendered photos are written
    (photo_NNNNNN.bil), or None."""
    ground = geodetic_to_ecef(points["lat_deg"], points["lon_deg"], points["height_m"])
    centre, r_ke = camera_pose_ecef(traj.state(t_ns), camera.mounting)
    iop = camera.model
    renderer = PhotoRenderer(camera, terrain, scene, rng)
    ids: list[str] = []
    seg: list[int] = []
    col_m: list[float] = []
    row_m: list[float] = []
    projected: list[tuple[float, float]] = []
    written: dict[int, Path] = {}
    for i in range(t_ns.size):
        col, row = camera_to_image((ground - centre[i]) @ r_ke[i], iop)
        seen = np.flatnonzero((col > radius_px) & (col < iop.width_px - 1 - radius_px)
                              & (row > radius_px) & (row < iop.height_px - 1 - radius_px))
        if not seen.size:
            continue
        dn = renderer.render(traj.state(t_ns[i:i + 1]))
        if folder is not None:
            written[int(numbers[i])] = write_photo(folder, dn, int(numbers[i]), int(t_ns[i]))
        image = dn.astype(np.float64).sum(axis=1)  # every band: the marker is white in all
        for k in seen.tolist():
            c, r = marker_centroid(image, float(col[k]), float(row[k]), radius_px)
            if np.isfinite(c):
                ids.append(str(points["id"][k]))
                seg.append(int(numbers[i]))
                col_m.append(c)
                row_m.append(r)
                projected.append((float(col[k]), float(row[k])))
    n = len(ids)
    obs = ImageObservations(np.array(ids, np.str_), np.array(seg, np.int64),
                            np.array(row_m, np.float64), np.array(col_m, np.float64),
                            np.full(n, sigma_px))
    return PhotoMeasurements(obs, np.array(projected, np.float64).reshape(n, 2), written)


MARKER_RADIUS_PX: Final = 9.0  # the centroid window: inside a marker's dark square at ~1 m


def simulate_photo_control(run: Path, scn: Scenario, times: PhotoTimes, *, sigma_px: float,
                           seed: int) -> tuple[ImageObservations, dict[str, Any]]:
    """Markers measured in the photos of a simulated run (`measure_control` on the photos its
    truth times), and what the simulation knows: the boresight the data see (the scenario's,
    composed with the run's INS attitude error), the centroids' error against the true
    projections."""
    if scn.camera is None:
        raise InputError(f"{run / 'scenario.toml'}: no [camera]: no photos to calibrate")
    flight = flight_truth(run)
    terrain = Terrain.from_scenario(scn)
    pts = ground_points(scn, terrain)
    scene = Scene.from_scenario(scn, terrain, pts)
    timed = times.timed()
    meas = measure_control(scn.camera, flight.traj, terrain, scene, pts, timed.photo_number,
                           timed.t_mid_gps_ns, np.random.default_rng([seed, RENDER_STREAM]),
                           radius_px=MARKER_RADIUS_PX, sigma_px=sigma_px)
    off = np.hypot(meas.obs.pixel - meas.projected_px[:, 0],
                   meas.obs.line - meas.projected_px[:, 1])
    t_obs = times.time_of(meas.obs.segment)
    seen = effective_boresight_arcsec(flight, t_obs, scn.camera.mounting, R_NOMINAL_K_TO_B)
    truth = {"boresight_arcsec": list(seen),
             "scenario_boresight_arcsec": list(scn.camera.mounting.boresight_arcsec),
             "centroid_error_rms_px": float(np.sqrt(np.mean(off ** 2))) if off.size else None}
    return meas.obs, {"simulated": True, "truth": truth}


@dataclass(frozen=True)
class SimulatedBlock:
    """A simulated block's photos measured (`measure_control`), with what an adjustment of
    them takes and what the truth says of the measurements."""

    camera: CameraSettings
    traj: TruthTrajectory
    times: PhotoTimes
    points: GroundPoints  # control and check, at their true coordinates
    obs: ImageObservations
    centroid_error_rms_px: float  # the centroids against the true projections


def simulate_block(table: dict[str, Any], *, sigma_px: float, first_photo: int = 0
                   ) -> SimulatedBlock:
    """A scenario (`table`, as scenario_from_table takes it, with a [camera]) flown, every photo
    that sees a ground point rendered and its markers measured (seeded by the scenario)."""
    scn = scenario_from_table(table)
    if scn.camera is None:
        raise InputError("the scenario has no [camera]: no photos to measure")
    traj = TruthTrajectory.from_scenario(scn)
    terrain = Terrain.from_scenario(scn)
    pts = ground_points(scn, terrain)
    scene = Scene.from_scenario(scn, terrain, pts)
    t_ns, _ = exposure_times(scn.camera, traj)
    numbers = np.arange(first_photo, first_photo + t_ns.size, dtype=np.int64)
    meas = measure_control(scn.camera, traj, terrain, scene, pts, numbers, t_ns,
                           np.random.default_rng(scn.seed), radius_px=MARKER_RADIUS_PX,
                           sigma_px=sigma_px)
    off = np.hypot(meas.obs.pixel - meas.projected_px[:, 0],
                   meas.obs.line - meas.projected_px[:, 1])
    points = GroundPoints(pts["id"].astype(str), pts["kind"].astype(str),
                          geodetic_to_ecef(pts["lat_deg"], pts["lon_deg"], pts["height_m"]))
    return SimulatedBlock(scn.camera, traj, PhotoTimes(numbers, t_ns), points, meas.obs,
                          float(np.sqrt(np.mean(off ** 2))) if off.size else math.nan)


def photo_eo_accuracy(truth_csv: Path, sidecars: Path) -> dict[str, Any]:
    """Each photo's EO (its sidecar JSON) against the run's truth (truth/photos.csv): RMS of
    the perspective centre's error horizontally and vertically (local level at the centre) and
    of the body attitude's roll, pitch and heading (arcsec)."""
    truth = read_truth_csv(truth_csv)
    row = {int(k): i for i, k in enumerate(truth["photo_number"].tolist())}
    d_enu: list[F64] = []
    d_att: list[list[float]] = []
    for path in sorted(Path(sidecars).glob("photo_*.json")):
        doc = json.loads(path.read_text(encoding="utf-8"))
        i = row.get(int(doc["label"].split("_")[1]))
        if i is None:
            continue
        pc, att = doc["perspective_centre"], doc["attitude"]
        est = np.array([pc["x_ecef_m"], pc["y_ecef_m"], pc["z_ecef_m"]])
        true = np.array([truth[k][i] for k in ("x_ecef_m", "y_ecef_m", "z_ecef_m")])
        r_ne = ned_to_ecef_matrix(math.radians(pc["lat_deg"]), math.radians(pc["lon_deg"]))
        d_enu.append(np.asarray(r_ne.T @ (est - true)))
        d_att.append([3600.0 * (((att[f"{k}_deg"] - truth[f"{k}_deg"][i]) + 180.0) % 360.0
                                - 180.0) for k in ("roll", "pitch", "heading")])
    if not d_enu:
        return {"photos": 0}
    ned, a = np.array(d_enu), np.array(d_att)
    rms = np.sqrt(np.mean(a ** 2, axis=0))
    return {"photos": len(d_enu),
            "position_rms_m": {"horizontal": float(np.sqrt(np.mean(ned[:, 0] ** 2
                                                                    + ned[:, 1] ** 2))),
                               "vertical": float(np.sqrt(np.mean(ned[:, 2] ** 2)))},
            "attitude_rms_arcsec": {"roll": float(rms[0]), "pitch": float(rms[1]),
                                    "heading": float(rms[2])}}


MAX_RENDER_PIXELS: Final = 400_000_000  # a run's photos rendered by `sisa process`, at most
RENDER_STREAM: Final = 37  # the photos' detector noise: a random stream of their own


def too_many_to_render(camera: CameraSettings, photos: int) -> str | None:
    """Why `photos` photos of this camera are not rendered here (None: they are)."""
    pixels = camera.model.width_px * camera.model.height_px * photos
    if pixels <= MAX_RENDER_PIXELS:
        return None
    return (f"{photos} photos of {camera.model.width_px} x {camera.model.height_px} pixels are "
            f"too many to render here ({pixels / 1e6:.0f} Mpx, at most "
            f"{MAX_RENDER_PIXELS / 1e6:.0f}): give them in RUN/photos/")


def render_run_photos(scn: Scenario, numbers: I64, t_ns: I64, folder: Path
                      ) -> dict[str, Path]:
    """Every photo (numbers, TRUE mid-exposure times) of a simulated run rendered from its
    truth into `folder` (photo_NNNNNN.bil/.hdr): what the camera would have recorded.
    InputError when they hold more than MAX_RENDER_PIXELS pixels in all (a 100-megapixel
    camera: minutes a photo)."""
    camera = scn.camera
    if camera is None:
        raise InputError("the scenario has no [camera]: no photos to render")
    if (why := too_many_to_render(camera, int(t_ns.size))) is not None:
        raise InputError(why)
    traj = TruthTrajectory.from_scenario(scn)
    terrain = Terrain.from_scenario(scn)
    scene = Scene.from_scenario(scn, terrain, ground_points(scn, terrain))
    renderer = PhotoRenderer(camera, terrain, scene,
                             np.random.default_rng([scn.seed, RENDER_STREAM]))
    out: dict[str, Path] = {}
    for k, t in zip(numbers.tolist(), t_ns.tolist(), strict=True):
        dn = renderer.render(traj.state(np.array([t], np.int64)))
        out[photo_label(k)] = write_photo(folder, dn, k, t)
    return out
