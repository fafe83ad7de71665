"""Stage 2, direct georeferencing: the navigation solution on the synchronised times, each scan
line's exterior orientation, every pixel's ray cast onto the DEM, and the products written from
it (docs/georef.md).

Inside: `sensorfile` (the sensor model), `navigation` (GPS fixes and INS attitude into one
trajectory), `trajfiles` (external trajectories), `exterior` (a line's pose and boresight),
`dem` and `raycast` (the DEM and the ray–DEM intersection), `registration` (strip-to-strip
checks), `job` (one flight's run: segments, products, registration) and `report` (the HTML
processing report). The writers of the products themselves are `postproc.products`. Other
stages and the commands use only the names below.
"""

from postproc.georef.dem import PLAUSIBLE_HEIGHTS_M, Dem, check_undulation_m
from postproc.georef.job import GeorefJob, GeorefOptions, GeorefResult, SegmentResult, merged_wanted
from postproc.georef.navigation import (
    MAX_GAP_LIMIT_S,
    NAV_WANTED,
    AntennaFixes,
    Pose,
    Trajectory,
    ecef_to_geodetic,
    fixes_from_columns,
    geodetic_to_ecef,
    nav_from_columns,
)
from postproc.georef.raycast import CastStats, GroundPoints, intersect, reference_intersect
from postproc.georef.report import Provenance, write_report
from postproc.georef.sensorfile import CALIBRATED_SUFFIX, SensorModel
from postproc.georef.trajfiles import LEAP_SECONDS_RANGE

__all__ = [
    "CALIBRATED_SUFFIX", "LEAP_SECONDS_RANGE", "MAX_GAP_LIMIT_S", "NAV_WANTED",
    "PLAUSIBLE_HEIGHTS_M", "AntennaFixes", "CastStats", "Dem", "GeorefJob", "GeorefOptions",
    "GeorefResult", "GroundPoints", "Pose", "Provenance", "SegmentResult", "SensorModel",
    "Trajectory",
    "check_undulation_m", "ecef_to_geodetic", "fixes_from_columns", "geodetic_to_ecef",
    "intersect", "merged_wanted", "nav_from_columns", "reference_intersect", "write_report",
]
