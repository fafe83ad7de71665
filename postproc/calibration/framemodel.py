"""The frame camera's observation model in the calibration's adjustment (docs/calibration.md,
"The frame camera").

A photo sees a point at both image coordinates at one instant, its mid-exposure time t (plus
the delay τ): the pose, the perspective centre and every correction of the state are the line
scanner's (`model.PoseModel.camera_frame`, with the frame camera's nominal mounting
R_k^b = R_nom·Rx(ω)·Ry(φ)·Rz(κ), sisa.core.framecamera), then the collinearity and the Brown
distortion of `sisa.core.framecamera.camera_to_image`. An observation's two rows are
(row, col) in pixels, observed − modelled, so a frame camera needs no "rate": the scanner's
along-track line offset is its row, its across-track pixel its column.

Self-calibration keeps the scanner's parameters and units: δf (mm) changes the focal length,
δx0 and δy0 (µm on the focal plane) move the principal point by δx0/pitch columns right and
δy0/pitch rows down (Metashape's cx, cy, in µm). The distortion coefficients stay as given.
Unlike a line, a frame sees φ and δx0 apart (φ turns the rays, δx0 shifts the image), so no
prior is needed to part them.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from postproc.calibration.model import ObsGeometry, Pose, PoseModel
from postproc.calibration.params import State
from postproc.georef import Trajectory
from sisa.core.framecamera import (
    R_NOMINAL_K_TO_B,
    FrameCamera,
    FrameInterior,
    camera_to_image,
    image_to_camera,
)

F64 = npt.NDArray[np.float64]

POINT_STEP_M: Final = 0.1  # central differences by the point: the projection is smooth at m


class FrameCameraModel(PoseModel):
    """Projection of points into the observed photos, for a given parameter state; the
    observations' `line` is the row and `pixel` the column of the point in its photo, and
    `t_line_ns` the photo's mid-exposure time."""

    def __init__(self, traj: Trajectory, camera: FrameCamera, obs: ObsGeometry,
                 origin_ecef_m: F64, delay_grid_ms: float | None = None) -> None:
        super().__init__(traj, obs, origin_ecef_m, camera.mounting.lever_arm_m,
                         R_NOMINAL_K_TO_B, delay_grid_ms)
        self.camera = camera

    def interior(self, st: State) -> FrameInterior:
        """The camera's interior orientation with the state's self-calibration applied."""
        iop = self.camera.interior
        pitch = iop.pixel_pitch_um
        cx, cy = iop.principal_point_px
        return iop.model_copy(update={
            "focal_length_mm": iop.focal_length_mm + float(st.selfcal[0]),
            "principal_point_px": (cx + float(st.selfcal[1]) / pitch,
                                   cy + float(st.selfcal[2]) / pitch)})

    def image_points(self, st: State, x_m: F64, pose: Pose) -> tuple[F64, F64]:
        """(col, row) of the points x_m (N, 3, ECEF − origin) in their photos."""
        p, _, _ = self.camera_frame(st, x_m, pose)
        return camera_to_image(p, self.interior(st))

    def rates(self, st: State, x_m: F64) -> F64:
        """A photo's rows need no rate: ones."""
        return np.ones(self.obs.line.size)

    def residuals(self, st: State, x_m: F64, pose: Pose, rate: F64) -> tuple[F64, F64]:
        """(row, col) in pixels, observed − modelled."""
        col, row = self.image_points(st, x_m, pose)
        return self.obs.line - row, self.obs.pixel - col

    def point_jacobian(self, st: State, x_m: F64, pose: Pose, rate: F64) -> F64:
        """d(row, col residuals)/dX, shape (N, 2, 3), by central differences."""
        out = np.empty((x_m.shape[0], 2, 3))
        for k in range(3):
            step = np.zeros(3)
            step[k] = POINT_STEP_M
            plus = np.stack(self.residuals(st, x_m + step, pose, rate), axis=1)
            minus = np.stack(self.residuals(st, x_m - step, pose, rate), axis=1)
            out[:, :, k] = (plus - minus) / (2.0 * POINT_STEP_M)
        return out

    def ray(self, st: State, pose: Pose) -> tuple[F64, F64]:
        """Perspective centre (local) and unit ECEF direction of every observed (row, col)."""
        _, r_ce, centre = self.camera_frame(st, np.zeros((self.obs.line.size, 3)), pose)
        look = image_to_camera(self.obs.pixel, self.obs.line, self.interior(st))
        return centre, np.einsum("nij,nj->ni", r_ce, look)
