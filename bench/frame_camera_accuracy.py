"""The frame camera's figures in docs/frames.md: what the tests bound, measured.

    PYTHONPATH=. .venv/bin/python bench/frame_camera_accuracy.py

Pixel → ray → pixel over the whole frame (257 × 257 points, corners in) of the two cameras in
tests/sisa/test_framecamera.py; the photo EO of tests/postproc/test_photos.py against its
pyproj + scipy truth (ECEF, UTM, ω φ κ with the grid axes found by finite differences); ground
points projected into each photo against the test's own collinearity; and the footprint
corners of tests/postproc/test_photo_exports.py projected back into their photos. A few
seconds (the ray caster's first call compiles, once).
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from postproc.georef import photo_eo, project_to_photo, write_photo_footprints
from sisa.core.framecamera import camera_to_image, image_to_camera
from tests.postproc import test_photo_exports as exports
from tests.postproc import test_photos as photos
from tests.sisa.test_framecamera import METRIC, STRONG, frame_grid

ARCSEC_PER_RAD = 180 * 3600 / np.pi


def main() -> None:
    for name, iop in (("strong distortion", STRONG), ("metric camera", METRIC)):
        col, row = frame_grid(iop)
        back = camera_to_image(image_to_camera(col, row, iop), iop)
        print(f"round trip, {name}: max {np.hypot(back[0] - col, back[1] - row).max():.1e} px")
    cam = photos.CAMERA
    eo = photo_eo(photos.Flight(), photos.LABELS, photos.T_PHOTOS, cam.mounting)
    want = photos.truth(photos.T_PHOTOS)
    pos_m = max(np.linalg.norm(eo.pose.centre_ecef_m - want["centre"], axis=1).max(),
                np.abs(eo.easting_m - want["east"]).max(),
                np.abs(eo.northing_m - want["north"]).max(),
                np.abs(eo.pose.height_m - want["h"]).max())
    print(f"photo EO position: max {pos_m * 1e3:.1e} mm (ECEF, E, N, h)")
    for a in ("omega", "phi", "kappa"):
        err = np.abs(np.angle(np.exp(1j * (getattr(eo, f"{a}_rad") - want[a])))).max()
        print(f"photo EO {a}: max {err * ARCSEC_PER_RAD:.1e} arcsec")
    rng = np.random.default_rng(11)
    worst = 0.0
    for i in range(photos.T_PHOTOS.size):
        east = want["east"][i] + rng.uniform(-700, 700, 400)
        north = want["north"][i] + rng.uniform(-500, 500, 400)
        lon, lat = photos._UTM_TO_GEO.transform(east, north)
        ground = photos.ecef(np.asarray(lat), np.asarray(lon), rng.uniform(150, 900, 400))
        got = project_to_photo(eo, i, ground, cam.interior)
        ref = photos.project_truth(ground, want["centre"][i], want["r_ek"][i], cam.interior)
        imaged = np.isfinite(got[0])  # (NaN outside the circle through the frame's corners)
        worst = max(worst, float(np.hypot(got[0] - ref[0], got[1] - ref[1])[imaged].max()))
    print(f"ground → photo against the collinearity: max {worst:.1e} px")
    iop = cam.interior
    corner_col = np.array([-0.5, iop.width_px - 0.5, iop.width_px - 0.5, -0.5])
    corner_row = np.array([-0.5, -0.5, iop.height_px - 0.5, iop.height_px - 0.5])
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "footprints.geojson"
        write_photo_footprints(path, exports.flat_dem(want["east"], want["north"]), eo, iop)
        features = json.loads(path.read_text(encoding="utf-8"))["features"]
    worst = 0.0
    for i, feature in enumerate(features):
        c = np.array(feature["properties"]["corners_lon_lat_h"])
        ground = photos.ecef(c[:, 1], c[:, 0], c[:, 2])
        col, row = photos.project_truth(ground, want["centre"][i], want["r_ek"][i], iop)
        worst = max(worst, float(np.hypot(col - corner_col, row - corner_row).max()))
    print(f"footprint corners back in their photos: max {worst:.1e} px")


if __name__ == "__main__":
    main()
