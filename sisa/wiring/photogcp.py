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

from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt

from emulators.camera import PhotoRenderer, write_photo
from emulators.render import camera_pose_ecef
from emulators.scenario import CameraSettings
from emulators.terrain import Scene, Terrain
from emulators.trajectory import TruthTrajectory
from postproc.calibration import ImageObservations
from postproc.georef import Pose, geodetic_to_ecef, photo_label
from sisa.core.framecamera import camera_to_image
from sisa.core.frames import body_to_ned_matrix, ned_to_ecef_matrix

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


def photo_labels(numbers: I64) -> list[str]:
    return [photo_label(int(k)) for k in numbers.tolist()]
