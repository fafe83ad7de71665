"""Stage 3, system calibration: boresight, self-calibration, lever arm, antenna offset and time
delay from ground control, tie points and the DEM, one flight or several adjusted together
(docs/calibration.md).

Inside: `data` (observations and ground points as files), `flights` (several flights joined),
`params` (parameter groups and priors), `model` (the collinearity model of a line, on a pose
model shared with `framemodel`, the frame camera's), `photos` (the frame camera's
calibration in the same adjustment), `surface`
(the DEM as a height constraint), `navigation` (the trajectory's stated accuracy as a
stochastic model), `problem` and `setup` (the least-squares problem), `solve`
(Gauss–Newton with blunder rejection), `check` (check points), `adjust` (one adjustment),
`report` (what it found, as JSON and a sensor file) and `pipeline` (inputs to result). The
commands use only the names below.
"""

from postproc.calibration.adjust import (
    CalibrationInput,
    CalibrationOptions,
    CalibrationResult,
    sweep_delay,
)
from postproc.calibration.data import (
    GroundPoints,
    ImageObservations,
    SegmentClock,
    read_ground_points,
    read_observations,
    write_ground_points,
    write_observations,
)
from postproc.calibration.flights import (
    SEGMENT_STRIDE,
    flight_point_id,
    flight_segment,
    join_flights,
)
from postproc.calibration.navigation import NavigationAccuracy
from postproc.calibration.params import Group, PriorSigmas, parse_groups
from postproc.calibration.photos import (
    PhotoCalibrationInput,
    PhotoCalibrationResult,
    calibrate_photos,
    photo_report_json,
)
from postproc.calibration.pipeline import calibrate
from postproc.calibration.report import (
    high_correlations,
    load_check,
    look_angles,
    parameter_rows,
    report_json,
    sensor_toml,
)
from postproc.calibration.setup import SENSOR_FIT_MARGIN_PX

__all__ = [
    "SEGMENT_STRIDE", "SENSOR_FIT_MARGIN_PX", "CalibrationInput", "CalibrationOptions",
    "CalibrationResult", "GroundPoints", "Group", "ImageObservations", "NavigationAccuracy",
    "PhotoCalibrationInput", "PhotoCalibrationResult", "PriorSigmas", "SegmentClock", "calibrate",
    "calibrate_photos", "flight_point_id", "flight_segment", "high_correlations", "join_flights",
    "load_check", "look_angles", "parameter_rows", "parse_groups", "photo_report_json",
    "read_ground_points", "read_observations", "report_json", "sensor_toml", "sweep_delay",
    "write_ground_points", "write_observations",
]
