"""Stage 2, direct georeferencing: the navigation solution on the synchronised times, each scan
line's exterior orientation, every pixel's ray cast onto the DEM, and the products written from
it (docs/georef.md).

Inside: `sensorfile` (the sensor model), `navigation` (GPS fixes and INS attitude into one
trajectory), `trajfiles` (external trajectories), `exterior` (a line's pose and boresight),
`dem` and `raycast` (the DEM and the ray–DEM intersection, a package of its own),
`registration` (strip-to-strip checks), the frame camera's photos (`photos`: each photo's
EO and map-frame ω φ κ; `photoexports`: Metashape/Pix4D CSV, OpenDroneMap geo.txt, JSON
sidecars; `photofootprints`: corners cast onto the DEM, GeoJSON; `photoortho`: every
pixel cast into an IGM, the ortho and the photos' mosaic), `report` (the HTML
processing report), and one flight's run: `job` (the steps in order) over `jobrecords`
(its options and results), `inputchecks` (what is refused or said before it starts),
`handoff` (the log read and synchronised, the trajectory), `segments` (each segment's lines,
times and poses), `demcover` (each swath against the DEM), `casting` (every ray into the
IGM), `orthocell` (the ortho cell), `segmentproducts` and `flightproducts`. The writers of
the products themselves are `postproc.products`. Other stages and the commands use only the
names below.
"""

from postproc.georef.dem import PLAUSIBLE_HEIGHTS_M, Dem, check_undulation_m
from postproc.georef.flightproducts import flight_summary, registrations, write_footprints
from postproc.georef.handoff import Handoff, load_handoff, merged_wanted, save_handoff
from postproc.georef.job import GeorefJob, OnCast, OnSynced, Skipped
from postproc.georef.jobrecords import GeorefOptions, GeorefResult, SegmentResult, SegmentSkip
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
from postproc.georef.orthocell import ortho_cell_m
from postproc.georef.photoexports import (
    CSV_GEODETIC_COLUMNS,
    CSV_MAP_COLUMNS,
    write_odm_geo,
    write_photo_csv,
    write_photo_sidecars,
)
from postproc.georef.photofootprints import PhotoCorners, photo_corners, write_photo_footprints
from postproc.georef.photoortho import PhotoGeo, PhotoOrthos, cast_photos, photo_orthos
from postproc.georef.photoproducts import load_camera, photo_products
from postproc.georef.photos import PhotoEo, PhotoSigma, photo_eo, project_to_photo
from postproc.georef.phototimes import PhotoTimes, photo_label, read_photo_times
from postproc.georef.raycast import CastStats, GroundPoints, intersect, reference_intersect
from postproc.georef.report import Provenance, write_report
from postproc.georef.segmentproducts import segment_products
from postproc.georef.segments import segment_image, segment_raster, segment_rasters
from postproc.georef.sensorfile import CALIBRATED_SUFFIX, SensorModel
from postproc.georef.trajfiles import LEAP_SECONDS_RANGE

__all__ = [
    "CALIBRATED_SUFFIX", "CSV_GEODETIC_COLUMNS", "CSV_MAP_COLUMNS", "LEAP_SECONDS_RANGE",
    "MAX_GAP_LIMIT_S", "NAV_WANTED", "PLAUSIBLE_HEIGHTS_M", "AntennaFixes", "CastStats", "Dem",
    "GeorefJob", "GeorefOptions", "GeorefResult", "GroundPoints", "Handoff", "InsSamples",
    "OnCast", "OnSynced", "PhotoCorners", "PhotoEo", "PhotoGeo", "PhotoOrthos", "PhotoSigma",
    "PhotoTimes", "Pose", "Provenance", "SegmentResult", "SegmentSkip", "SensorModel", "Skipped",
    "Trajectory", "cast_photos", "check_undulation_m", "ecef_to_geodetic", "fixes_from_columns",
    "flight_summary", "fuse_ins_gps", "geodetic_to_ecef", "intersect", "load_camera",
    "load_handoff", "merged_wanted", "nav_from_columns", "ortho_cell_m", "photo_corners",
    "photo_eo", "photo_label", "photo_orthos", "photo_products", "project_to_photo",
    "read_photo_times", "reference_intersect", "registrations", "save_handoff", "segment_image",
    "segment_products", "segment_raster", "segment_rasters", "write_footprints", "write_odm_geo",
    "write_photo_csv", "write_photo_footprints", "write_photo_sidecars", "write_report",
]
