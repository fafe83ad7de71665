"""Stage 2, direct georeferencing: the navigation solution on the synchronised times, each scan
line's exterior orientation, every pixel's ray cast onto the DEM, and the products written from
it (docs/georef.md).

Inside: `sensorfile` (the sensor model), `navigation` (GPS fixes and INS attitude into one
trajectory), `trajfiles` (external trajectories), `exterior` (a line's pose and boresight),
`dem` and `raycast` (the DEM and the ray–DEM intersection, a package of its own),
`registration` (strip-to-strip checks), `report` (the HTML processing report), and one
flight's run: `job` (the steps in order) over `jobrecords` (its options and results),
`inputchecks` (what is refused or said before it starts), `handoff` (the log read and
synchronised, the trajectory), `segments` (each segment's lines, times and poses), `demcover`
(each swath against the DEM), `casting` (every ray into the IGM), `orthocell` (the ortho
cell), `segmentproducts` and `flightproducts`. The writers of the products themselves are
`postproc.products`. Other stages and the commands use only the names below.
"""

from postproc.georef.dem import PLAUSIBLE_HEIGHTS_M, Dem, check_undulation_m
from postproc.georef.handoff import merged_wanted
from postproc.georef.job import GeorefJob
from postproc.georef.jobrecords import GeorefOptions, GeorefResult, SegmentResult
from postproc.georef.navigation import (
    MAX_GAP_LIMIT_S,
    NAV_WANTED,
    AntennaFixes,
    InsSamples,
    Pose,
    Trajectory,
    ecef_to_geodetic,
    fixes_from_columns,
    fuse_ins_gps,
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
    "GeorefResult", "GroundPoints", "InsSamples", "Pose", "Provenance", "SegmentResult",
    "SensorModel", "Trajectory", "check_undulation_m", "ecef_to_geodetic", "fixes_from_columns",
    "fuse_ins_gps", "geodetic_to_ecef",
    "intersect", "merged_wanted", "nav_from_columns", "reference_intersect", "write_report",
]
