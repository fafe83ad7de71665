"""Photo footprints: the four outer corners of every photo cast onto the DEM, as GeoJSON.

The corner rays come from the camera model (`sisa.core.framecamera.image_to_camera`, distortion
removed) and are cast with the scanner's ray caster (`raycast.intersect`: the first crossing
with the DEM, < 1 mm of range). The ground between the corners is not followed: a footprint is
the quadrilateral of its corners, what a photo index needs (the sides of a photo over rough
terrain bend; the ortho, a later part, will use every pixel). One Feature per photo (RFC 7946:
WGS 84 lon/lat, exterior ring counter-clockwise), properties `label`, `t_gps_ns` and
`corners_lon_lat_h` (image order: top-left, top-right, bottom-right, bottom-left; heights
ellipsoidal). A photo without a pose, or with a corner that misses the DEM (off its edge, over
no data, above the horizon), is skipped, and counted.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from postproc.georef.dem import Dem
from postproc.georef.navigation import transformer
from postproc.georef.photos import PhotoEo
from postproc.georef.raycast import intersect
from postproc.products import signed_area, write_footprints_geojson
from sisa.core.errors import InputError
from sisa.core.framecamera import FrameInterior, image_to_camera
from sisa.core.outdir import refuse_existing

F64 = npt.NDArray[np.float64]


class PhotoCorners(NamedTuple):
    """Ground of the four image corners of N photos in the DEM's CRS (NaN: no pose, or miss)."""

    easting_m: F64  # (N, 4) top-left, top-right, bottom-right, bottom-left
    northing_m: F64
    height_m: F64  # ellipsoidal
    complete: npt.NDArray[np.bool_]  # (N,) all four corners on the DEM


def photo_corners(dem: Dem, eo: PhotoEo, interior: FrameInterior) -> PhotoCorners:
    """The four corner rays of every photo cast onto `dem`."""
    look = image_to_camera(*interior.corners_px(), interior).T  # (3, 4)
    n = eo.valid.size
    east, north, height = (np.full((n, 4), np.nan) for _ in range(3))
    hit = np.zeros((n, 4), np.bool_)
    ok = np.flatnonzero(eo.valid)
    if ok.size:
        got = intersect(dem, eo.pose.centre_ecef_m[ok], eo.pose.r_ecef_from_camera[ok], look)
        east[ok], north[ok], height[ok], hit[ok] = (got.easting_m, got.northing_m,
                                                    got.height_m, got.hit)
    return PhotoCorners(east, north, height, np.asarray(hit.all(axis=1)))


def _feature(label: str, t_gps_ns: int, lon: F64, lat: F64, h: F64) -> dict[str, Any]:
    ring = np.stack([lon, lat], axis=1)
    if signed_area(np.vstack([ring, ring[:1]])) < 0:  # RFC 7946: counter-clockwise
        ring = ring[::-1]
    coords = [[float(a), float(b)] for a, b in ring]
    return {"type": "Feature",
            "geometry": {"type": "Polygon", "coordinates": [[*coords, coords[0]]]},
            "properties": {"label": label, "t_gps_ns": t_gps_ns, "corners_lon_lat_h": [
                [float(a), float(b), float(c)] for a, b, c in zip(lon, lat, h, strict=True)]}}


def write_photo_footprints(path: Path, dem: Dem, eo: PhotoEo, interior: FrameInterior, *,
                           force: bool = False) -> tuple[int, int]:
    """The footprints as a GeoJSON FeatureCollection, written whole; (written, skipped).
    InputError, nothing written, if no photo has all four corners on the DEM."""
    path = Path(path)
    refuse_existing(path, force=force)
    corners = photo_corners(dem, eo, interior)
    rows = np.flatnonzero(corners.complete)
    if rows.size == 0:
        raise InputError(f"{path}: no photo has all four corners on the DEM (or a pose); "
                         "nothing written")
    lon, lat = transformer(dem.epsg, 4326).transform(corners.easting_m[rows],
                                                     corners.northing_m[rows])
    lon, lat = np.asarray(lon), np.asarray(lat)
    features = [_feature(eo.labels[i], int(eo.pose.t_gps_ns[i]), lon[k], lat[k],
                         corners.height_m[i]) for k, i in enumerate(rows.tolist())]
    write_footprints_geojson(path, features)
    return int(rows.size), int(eo.valid.size - rows.size)
