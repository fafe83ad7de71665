"""The photo exports (postproc.georef.photoexports, photofootprints) read back by independent
readers: the csv module for the Metashape/Pix4D CSV, a reader of OpenDroneMap's documented
geo.txt rules written here, json for the sidecars and the GeoJSON footprints, whose corners are
projected back into the photo by the test's own collinearity; skips, refusals and failures
leave no file or a whole one."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pyproj import CRS, Transformer

from postproc.georef import (
    CSV_GEODETIC_COLUMNS,
    CSV_MAP_COLUMNS,
    Dem,
    PhotoEo,
    PhotoSigma,
    photo_eo,
    write_odm_geo,
    write_photo_csv,
    write_photo_footprints,
    write_photo_sidecars,
)
from sisa.core.errors import InputError
from sisa.core.framecamera import FrameCamera
from tests.postproc.test_photos import (
    CAMERA,
    EPSG,
    LABELS,
    MM,
    T0_NS,
    T_PHOTOS,
    Flight,
    ecef,
    project_truth,
    truth,
)

SIGMA = PhotoSigma(horizontal_m=0.03, vertical_m=0.06, attitude_deg=0.004)
OUTSIDE = T0_NS - 5_000_000_000  # before the trajectory: no pose, skipped
GROUND_H_M = 300.0
_UTM_TO_GEO = Transformer.from_crs(EPSG, 4326, always_xy=True)


@pytest.fixture(scope="module")
def eo() -> PhotoEo:
    """The photos of test_photos, plus one outside the trajectory."""
    return photo_eo(Flight(), [*LABELS, "LATE.tif"], np.append(T_PHOTOS, OUTSIDE),
                    CAMERA.mounting)


@pytest.fixture(scope="module")
def want() -> dict[str, np.ndarray]:
    return truth(T_PHOTOS)


def angle(eo: PhotoEo, name: str) -> np.ndarray:
    """ω, φ or κ (radians) of the photos with a pose."""
    return np.asarray(getattr(eo, f"{name}_rad")[eo.valid])


def read_csv(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with path.open(newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        return list(reader.fieldnames or []), list(reader)


def test_reference_csv_in_the_map_crs(tmp_path: Path, eo: PhotoEo,
                                      want: dict[str, np.ndarray]) -> None:
    path = tmp_path / "photos.csv"
    assert write_photo_csv(path, eo, SIGMA) == len(LABELS)
    columns, rows = read_csv(path)
    assert tuple(columns) == CSV_MAP_COLUMNS
    assert [r["label"] for r in rows] == LABELS  # the photo without a pose is left out
    col = {c: np.array([float(r[c]) for r in rows]) for c in columns[1:]}
    assert np.abs(col["easting_m"] - want["east"]).max() < 0.1 * MM
    assert np.abs(col["northing_m"] - want["north"]).max() < 0.1 * MM
    assert np.abs(col["height_m"] - want["h"]).max() < 0.1 * MM
    for name in ("omega", "phi", "kappa"):  # as the EO says, to the 1e-10° written
        assert np.abs(col[f"{name}_deg"] - np.degrees(angle(eo, name))).max() < 1e-9, name
    assert (col["accuracy_horizontal_m"] == 0.03).all()
    assert (col["accuracy_vertical_m"] == 0.06).all()
    assert (col["accuracy_attitude_deg"] == 0.004).all()


def test_reference_csv_in_geodetic_coordinates(tmp_path: Path, eo: PhotoEo,
                                               want: dict[str, np.ndarray]) -> None:
    path = tmp_path / "photos_wgs84.csv"
    write_photo_csv(path, eo, SIGMA, geodetic=True)
    columns, rows = read_csv(path)
    assert tuple(columns) == CSV_GEODETIC_COLUMNS
    lat = np.array([float(r["lat_deg"]) for r in rows])
    lon = np.array([float(r["lon_deg"]) for r in rows])
    assert np.abs(lat - want["lat"]).max() * 111_000 < 0.1 * MM
    assert np.abs(lon - want["lon"]).max() * 111_000 < 0.1 * MM


def read_odm_geo(path: Path) -> tuple[CRS, dict[str, list[float]]]:
    """OpenDroneMap's documented rules: line 1 the projection (PROJ string, EPSG code or
    'WGS84 UTM 31N'); then `image_name geo_x geo_y [geo_z] [3 angles] [horz vert] [extras]`
    separated by whitespace; empty lines and lines starting with # are skipped."""
    lines = path.read_text(encoding="utf-8").strip().split("\n")
    crs = CRS.from_user_input(lines[0].strip())
    entries = {}
    for line in lines[1:]:
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        entries[parts[0]] = [float(p) for p in parts[1:9]]
    return crs, entries


def test_odm_geo_txt(tmp_path: Path, eo: PhotoEo, want: dict[str, np.ndarray]) -> None:
    path = tmp_path / "geo.txt"
    assert write_odm_geo(path, eo, SIGMA) == len(LABELS)
    assert path.read_text(encoding="utf-8").splitlines()[0] == f"EPSG:{EPSG}"
    crs, entries = read_odm_geo(path)
    assert crs.to_epsg() == EPSG
    assert list(entries) == LABELS
    got = np.array(list(entries.values()))
    assert got.shape == (len(LABELS), 8)  # x y z, three angles, two accuracies
    assert np.abs(got[:, 0] - want["east"]).max() < 0.1 * MM
    assert np.abs(got[:, 1] - want["north"]).max() < 0.1 * MM
    assert np.abs(got[:, 2] - want["h"]).max() < 0.1 * MM
    for k, name in enumerate(("omega", "phi", "kappa")):
        assert np.abs(got[:, 3 + k] - np.degrees(angle(eo, name))).max() < 1e-9, name
    assert (got[:, 6] == 0.03).all()
    assert (got[:, 7] == 0.06).all()


def test_json_sidecars(tmp_path: Path, eo: PhotoEo, want: dict[str, np.ndarray]) -> None:
    folder = tmp_path / "sidecars"
    assert write_photo_sidecars(folder, eo, SIGMA, CAMERA) == len(LABELS)
    assert sorted(p.name for p in folder.iterdir()) == sorted(f"{lb}.json" for lb in LABELS)
    for i, label in enumerate(LABELS):
        doc = json.loads((folder / f"{label}.json").read_text(encoding="utf-8"))
        assert doc["label"] == label
        assert doc["t_gps_ns"] == int(T_PHOTOS[i])  # exact: an int, never through a float
        assert doc["crs"]["map"] == f"EPSG:{EPSG}"
        pc = doc["perspective_centre"]
        centre = np.array([pc["x_ecef_m"], pc["y_ecef_m"], pc["z_ecef_m"]])
        assert np.linalg.norm(centre - want["centre"][i]) < 1 * MM
        assert abs(pc["easting_m"] - want["east"][i]) < 1 * MM
        assert abs(pc["height_m"] - want["h"][i]) < 1 * MM
        att = doc["attitude"]
        for name in ("omega", "phi", "kappa"):
            assert att[f"{name}_deg"] == math.degrees(angle(eo, name)[i])  # full precision
            assert abs(att[f"{name}_deg"] - math.degrees(want[name][i])) < 0.01 / 3600
        np.testing.assert_allclose(att["r_ecef_from_camera"], want["r_ek"][i], atol=1e-13)
        assert PhotoSigma.model_validate(doc["sigma"]) == SIGMA
        assert FrameCamera.model_validate(doc["camera"]) == CAMERA


def flat_dem(east: np.ndarray, north: np.ndarray, half_m: float = 3000.0) -> Dem:
    cell = 25.0
    n = int(2 * half_m / cell) + 1
    heights = np.full((n, n), GROUND_H_M, np.float32)
    return Dem(heights, float(east.mean() - half_m), float(north.mean() + half_m), cell, cell,
               EPSG)


def test_footprint_corners_are_the_image_corners_on_the_ground(
        tmp_path: Path, eo: PhotoEo, want: dict[str, np.ndarray]) -> None:
    path = tmp_path / "photos.geojson"
    written, skipped = write_photo_footprints(path, flat_dem(want["east"], want["north"]), eo,
                                              CAMERA.interior)
    assert (written, skipped) == (len(LABELS), 1)
    doc = json.loads(path.read_text(encoding="utf-8"))
    assert doc["type"] == "FeatureCollection"
    iop = CAMERA.interior
    corner_col = [-0.5, iop.width_px - 0.5, iop.width_px - 0.5, -0.5]
    corner_row = [-0.5, -0.5, iop.height_px - 0.5, iop.height_px - 0.5]
    worst = 0.0
    for i, feature in enumerate(doc["features"]):
        assert feature["properties"]["label"] == LABELS[i]
        assert feature["properties"]["t_gps_ns"] == int(T_PHOTOS[i])
        ring = np.array(feature["geometry"]["coordinates"][0])
        assert ring.shape == (5, 2)
        assert (ring[0] == ring[-1]).all()
        x, y = ring[:-1, 0], ring[:-1, 1]
        assert np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0  # counter-clockwise
        corners = np.array(feature["properties"]["corners_lon_lat_h"])
        assert np.abs(corners[:, 2] - GROUND_H_M).max() < 1 * MM
        assert {tuple(c) for c in corners[:, :2]} == {tuple(c) for c in ring[:-1]}
        ground = ecef(corners[:, 1], corners[:, 0], corners[:, 2])
        col, row = project_truth(ground, want["centre"][i], want["r_ek"][i], iop)
        worst = max(worst, float(np.hypot(col - corner_col, row - corner_row).max()))
    assert worst < 0.01


def test_a_photo_with_a_corner_off_the_dem_is_skipped(tmp_path: Path, eo: PhotoEo,
                                                      want: dict[str, np.ndarray]) -> None:
    dem = flat_dem(want["east"][:2], want["north"][:2], half_m=1200.0)  # the first photos only
    path = tmp_path / "some.geojson"
    written, skipped = write_photo_footprints(path, dem, eo, CAMERA.interior)
    assert 0 < written < len(LABELS)
    assert written + skipped == len(LABELS) + 1
    labels = [f["properties"]["label"] for f in
              json.loads(path.read_text(encoding="utf-8"))["features"]]
    assert labels == LABELS[:written]


# --- refusals and failures: nothing written, or the old file untouched ------------------------

def no_pose(eo: PhotoEo) -> PhotoEo:
    return eo._replace(pose=eo.pose._replace(valid=np.zeros(eo.valid.size, np.bool_)))


@pytest.mark.parametrize("writer", ["csv", "geo", "sidecars", "footprints"])
def test_no_photo_with_a_pose_writes_nothing(tmp_path: Path, eo: PhotoEo,
                                             want: dict[str, np.ndarray], writer: str) -> None:
    out = tmp_path / "out"
    with pytest.raises(InputError, match="nothing written"):
        write(writer, out, no_pose(eo), want)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("writer", ["csv", "geo", "sidecars", "footprints"])
def test_an_existing_output_is_refused_and_kept(tmp_path: Path, eo: PhotoEo,
                                                want: dict[str, np.ndarray], writer: str
                                                ) -> None:
    out = tmp_path / "out"
    if writer == "sidecars":
        out.mkdir()
        (out / "keep").write_text("old")
    else:
        out.write_text("old")
    with pytest.raises(InputError, match="already exists"):
        write(writer, out, eo, want)
    assert (out / "keep" if writer == "sidecars" else out).read_text() == "old"
    write(writer, out, eo, want, force=True)  # --force replaces it whole
    assert not (out / "keep").exists() if writer == "sidecars" else out.read_text() != "old"


def test_a_failure_half_way_through_the_sidecars_leaves_nothing(
        tmp_path: Path, eo: PhotoEo, monkeypatch: pytest.MonkeyPatch) -> None:
    calls = {"n": 0}
    real = json.dumps

    def failing(doc: Any, **kwargs: Any) -> str:
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError(28, "No space left on device")
        return real(doc, **kwargs)

    monkeypatch.setattr("postproc.georef.photoexports.json.dumps", failing)
    with pytest.raises(OSError, match="No space"):
        write_photo_sidecars(tmp_path / "sidecars", eo, SIGMA, CAMERA)
    assert list(tmp_path.iterdir()) == []


def write(writer: str, out: Path, eo: PhotoEo, want: dict[str, np.ndarray], *,
          force: bool = False) -> None:
    if writer == "csv":
        write_photo_csv(out, eo, SIGMA, force=force)
    elif writer == "geo":
        write_odm_geo(out, eo, SIGMA, force=force)
    elif writer == "sidecars":
        write_photo_sidecars(out, eo, SIGMA, CAMERA, force=force)
    else:
        write_photo_footprints(out, flat_dem(want["east"], want["north"]), eo,
                               CAMERA.interior, force=force)
