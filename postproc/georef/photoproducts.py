"""A flight's frame-camera products, beside the scanner's: OUT/photos/.

    summary = photo_products(out / "photos", traj, dem_path, times, camera, images, epsg=...)

From the photo times table (`phototimes`) and the flight's trajectory: every timed photo's
EO (`photos.photo_eo`, in the products' CRS) written for the photogrammetry tools
(`photo_eo.csv` Metashape/Pix4D, `geo.txt` OpenDroneMap, `sidecars/<label>.json`), the
footprints (`footprints.geojson`) and, for the photos whose images are given, the photo orthos
and their mosaic (`photoortho`). `photo_summary.json` says what was made, skipped and why.
A camera file (TOML: `[interior]`, `[mounting]`, as sisa.core.framecamera's FrameCamera) is
read by `load_camera`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Final

import numpy as np
from pydantic import ValidationError

from postproc.georef.dem import Dem, dem_extent
from postproc.georef.navigation import Trajectory, transformer
from postproc.georef.photoexports import write_odm_geo, write_photo_csv, write_photo_sidecars
from postproc.georef.photofootprints import write_photo_footprints
from postproc.georef.photoortho import photo_orthos
from postproc.georef.photos import PhotoEo, PhotoSigma, photo_eo
from postproc.georef.phototimes import PhotoTimes
from sisa.core.bounded import read_settings_text, toml_loads
from sisa.core.errors import InputError
from sisa.core.framecamera import FrameCamera
from sisa.core.jsonio import write_json
from sisa.core.sensor import validation_text

LOWEST_GROUND_M: Final = -500.0  # ellipsoidal: below any land, for the DEM window's reach
DEM_MARGIN_M: Final = 200.0


def load_camera(path: Path) -> FrameCamera:
    """A camera file, or a one-line InputError naming it and its first bad field."""
    try:
        data = toml_loads(read_settings_text(Path(path)))
    except OSError as exc:
        raise InputError(f"{path}: cannot read the camera file: {exc.strerror}") from None
    except ValueError as exc:
        raise InputError(f"{path}: not a TOML camera file: {exc}") from None
    try:
        return FrameCamera.model_validate(data)
    except ValidationError as exc:
        raise InputError(f"{path}: {validation_text(exc)}") from None


def _dem_window(eo: PhotoEo, camera: FrameCamera, dem_epsg: int
                ) -> tuple[tuple[float, float, float, float], float]:
    """(bounds of the perspective centres in the DEM's CRS, how far beyond them a photo can
    see: its field's radius times its height above the lowest ground)."""
    ok = eo.valid
    east, north = transformer(4979, dem_epsg).transform(eo.pose.lon_deg[ok], eo.pose.lat_deg[ok])
    east, north = np.asarray(east), np.asarray(north)
    reach = camera.interior.field_radius() * (float(eo.pose.height_m[ok].max())
                                              - LOWEST_GROUND_M)
    return ((float(east.min()), float(north.min()), float(east.max()), float(north.max())),
            reach + DEM_MARGIN_M)


def photo_products(out: Path, traj: Trajectory, dem_path: Path, times: PhotoTimes,
                   camera: FrameCamera, images: Mapping[str, Path] | None, *, epsg: int,
                   geoid: float | Path | None = None, cell_m: float | None = None,
                   sigma: PhotoSigma | None = None) -> dict[str, Any]:
    """Everything of OUT/photos (module docstring) into the existing folder `out`; the
    summary (also written as photo_summary.json). InputError when no photo is timed or none
    has a pose."""
    out = Path(out)
    sigma = sigma or PhotoSigma()
    timed = times.timed()
    notes: list[str] = []
    untimed = times.photo_number.size - timed.photo_number.size
    if untimed:
        notes.append(f"{untimed} of {times.photo_number.size} photos have no time: left out")
    if timed.photo_number.size == 0:
        raise InputError(f"none of the {times.photo_number.size} photos has a time")
    eo = photo_eo(traj, timed.labels, timed.t_mid_gps_ns, camera.mounting, epsg=epsg)
    posed = int(eo.valid.sum())
    if posed < eo.valid.size:
        notes.append(f"{eo.valid.size - posed} timed photos have no navigation pose (outside "
                     "the trajectory or in its gaps): left out")
    write_photo_csv(out / "photo_eo.csv", eo, sigma)
    write_odm_geo(out / "geo.txt", eo, sigma)
    write_photo_sidecars(out / "sidecars", eo, sigma, camera)
    bounds, margin = _dem_window(eo, camera, dem_extent(dem_path)[0])
    dem = Dem.read(dem_path, bounds_m=bounds, margin_m=margin, geoid=geoid)
    written, skipped = write_photo_footprints(out / "footprints.geojson", dem, eo,
                                              camera.interior)
    if skipped:
        notes.append(f"{skipped} photos with a corner off the DEM: no footprint")
    summary: dict[str, Any] = {
        "crs": f"EPSG:{epsg}", "photos": int(times.photo_number.size),
        "timed": int(timed.photo_number.size), "posed": posed,
        "footprints": written, "camera": camera.model_dump(mode="json"),
        "sigma": sigma.model_dump(mode="json"),
        "files": {"eo_csv": "photo_eo.csv", "odm_geo": "geo.txt", "sidecars": "sidecars",
                  "footprints": "footprints.geojson"},
        "orthos": 0, "cell_m": None, "mosaic": None, "photo_files": {}}
    if images:
        made = photo_orthos(out, dem, eo, camera.interior, images, epsg=epsg, cell_m=cell_m)
        notes += made.notes
        summary.update(orthos=sum("ortho" in f for f in made.files.values()),
                       cell_m=made.cell_m if math.isfinite(made.cell_m) else None,
                       mosaic=None if made.mosaic is None else made.mosaic.name,
                       photo_files=made.files,
                       gsd_m={g.label: g.gsd_m for g in made.geo})
    else:
        notes.append("no photo images given: no photo orthos or mosaic")
    summary["warnings"] = notes
    write_json(out / "photo_summary.json", summary)
    return summary
