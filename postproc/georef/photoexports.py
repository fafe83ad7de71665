"""The photos' EO in the files photogrammetry tools import (docs/frames.md, "Exports"):

- `write_photo_csv`: Metashape / Pix4D reference CSV, one header line of named columns then one
  row per photo: label, easting/northing/height (map CRS) or lat/lon/height (WGS 84), ω φ κ in
  degrees (Pix4D's convention, `photos`), accuracies in metres and degrees.
- `write_odm_geo`: OpenDroneMap's geo.txt, first line the projection (`EPSG:32631`), then
  `label x y z omega phi kappa horz_accuracy vert_accuracy`, space-separated.
- `write_photo_sidecars`: one JSON per photo (time, EO in every frame, σ, camera), in a folder.

Heights are ellipsoidal (WGS 84) everywhere. Only valid photos are written (`photos`: one
outside the trajectory has no pose); each writer returns how many it wrote, and writes nothing,
raising InputError, if no photo is valid. Every file (and the sidecars' folder) appears whole or
not at all, and an existing one is refused unless `force`.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any, Final

import numpy as np

from postproc.georef.photos import PhotoEo, PhotoSigma
from sisa.core.errors import InputError
from sisa.core.framecamera import FrameCamera
from sisa.core.outdir import refuse_existing, staged_output_dir, write_whole

CSV_MAP_COLUMNS: Final = ("label", "easting_m", "northing_m", "height_m", "omega_deg",
                          "phi_deg", "kappa_deg", "accuracy_horizontal_m",
                          "accuracy_vertical_m", "accuracy_attitude_deg")
CSV_GEODETIC_COLUMNS: Final = ("label", "lat_deg", "lon_deg", *CSV_MAP_COLUMNS[3:])
METRE_FMT: Final = "{:.4f}"  # 0.1 mm
DEGREE_FMT: Final = "{:.10f}"  # lat/lon: 0.01 mm; angles: 0.00004″


def _valid_rows(eo: PhotoEo, what: str) -> list[int]:
    rows = np.flatnonzero(eo.valid).tolist()
    if not rows:
        raise InputError(f"{what}: no photo has a navigation pose; nothing written")
    return rows


def _angles_deg(eo: PhotoEo, i: int) -> list[str]:
    return [DEGREE_FMT.format(float(np.degrees(a[i])))
            for a in (eo.omega_rad, eo.phi_rad, eo.kappa_rad)]


def _write_table(path: Path, eo: PhotoEo, first_line: str, separator: str,
                 row: Callable[[int], list[str]], force: bool) -> int:
    """`first_line`, then `row(i)` of every valid photo joined by `separator`, written whole;
    returns the photos written."""
    path = Path(path)
    refuse_existing(path, force=force)
    rows = _valid_rows(eo, str(path))
    write_whole(path, "\n".join([first_line, *(separator.join(row(i)) for i in rows)]) + "\n")
    return len(rows)


def write_photo_csv(path: Path, eo: PhotoEo, sigma: PhotoSigma, *, geodetic: bool = False,
                    force: bool = False) -> int:
    """The reference CSV (columns CSV_MAP_COLUMNS, or CSV_GEODETIC_COLUMNS if `geodetic`);
    returns the photos written."""
    acc = [METRE_FMT.format(sigma.horizontal_m), METRE_FMT.format(sigma.vertical_m),
           DEGREE_FMT.format(sigma.attitude_deg)]

    def row(i: int) -> list[str]:
        if geodetic:
            xy = [DEGREE_FMT.format(eo.pose.lat_deg[i]), DEGREE_FMT.format(eo.pose.lon_deg[i])]
        else:
            xy = [METRE_FMT.format(eo.easting_m[i]), METRE_FMT.format(eo.northing_m[i])]
        return [eo.labels[i], *xy, METRE_FMT.format(eo.pose.height_m[i]), *_angles_deg(eo, i),
                *acc]

    head = ",".join(CSV_GEODETIC_COLUMNS if geodetic else CSV_MAP_COLUMNS)
    return _write_table(path, eo, head, ",", row, force)


def write_odm_geo(path: Path, eo: PhotoEo, sigma: PhotoSigma, *, force: bool = False) -> int:
    """OpenDroneMap's geo.txt in the map CRS; returns the photos written."""

    def row(i: int) -> list[str]:
        return [eo.labels[i], METRE_FMT.format(eo.easting_m[i]),
                METRE_FMT.format(eo.northing_m[i]), METRE_FMT.format(eo.pose.height_m[i]),
                *_angles_deg(eo, i), METRE_FMT.format(sigma.horizontal_m),
                METRE_FMT.format(sigma.vertical_m)]

    return _write_table(path, eo, f"EPSG:{eo.epsg}", " ", row, force)


def sidecar(eo: PhotoEo, i: int, sigma: PhotoSigma, camera: FrameCamera) -> dict[str, Any]:
    """One photo's sidecar document (floats at full precision; conventions named inside)."""
    p = eo.pose

    def deg(a: np.ndarray) -> float:
        return float(np.degrees(a[i]))

    return {
        "label": eo.labels[i],
        "t_gps_ns": int(p.t_gps_ns[i]),
        "time_scale": "GPS ns since 1980-01-06T00:00:00, no leap seconds; mid-exposure "
                      "plus the time delay",
        "crs": {"map": f"EPSG:{eo.epsg}", "geodetic": "EPSG:4979", "ecef": "EPSG:4978",
                "heights": "WGS 84 ellipsoidal"},
        "perspective_centre": {
            "x_ecef_m": float(p.centre_ecef_m[i, 0]), "y_ecef_m": float(p.centre_ecef_m[i, 1]),
            "z_ecef_m": float(p.centre_ecef_m[i, 2]), "lat_deg": float(p.lat_deg[i]),
            "lon_deg": float(p.lon_deg[i]), "height_m": float(p.height_m[i]),
            "easting_m": float(eo.easting_m[i]), "northing_m": float(eo.northing_m[i])},
        "attitude": {
            "roll_deg": deg(p.roll_rad), "pitch_deg": deg(p.pitch_rad),
            "heading_deg": deg(p.heading_rad),
            "omega_deg": deg(eo.omega_rad), "phi_deg": deg(eo.phi_rad),
            "kappa_deg": deg(eo.kappa_rad), "grid_convergence_deg": deg(eo.convergence_rad),
            "r_map_from_camera": eo.r_map_from_camera[i].tolist(),
            "r_ecef_from_camera": p.r_ecef_from_camera[i].tolist(),
            "conventions": "body x forward y right z down, R_b^n = Rz(heading) Ry(pitch) "
                           "Rx(roll), true heading; camera x right y up z back; "
                           "R_map_from_camera = Rx(omega) Ry(phi) Rz(kappa), map frame grid "
                           "east, grid north, ellipsoidal up at the perspective centre"},
        "sigma": sigma.model_dump(),
        "camera": camera.model_dump(mode="json"),
    }


def write_photo_sidecars(folder: Path, eo: PhotoEo, sigma: PhotoSigma, camera: FrameCamera,
                         *, force: bool = False) -> int:
    """`folder`/<label>.json for every valid photo; the folder appears whole. Returns the
    photos written."""
    folder = Path(folder)
    rows = _valid_rows(eo, str(folder))
    with staged_output_dir(folder, force=force) as scratch:
        for i in rows:
            doc = sidecar(eo, i, sigma, camera)
            (scratch / f"{eo.labels[i]}.json").write_text(
                json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    return len(rows)
