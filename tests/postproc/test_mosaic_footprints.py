"""Mosaic (nadir rule, IGM and GLT inputs), footprint GeoJSON and quicklook PNGs."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest
import rasterio
from pyproj import Geod, Transformer
from rasterio.errors import NotGeoreferencedWarning
from scipy.spatial import cKDTree

from postproc.products import (
    OrthoGrid,
    footprint_feature,
    igm_bounds,
    mosaic,
    orthorectify,
    write_footprints_geojson,
)
from postproc.products.quicklook import rgb_bands, write_quicklook
from sisa.core.errors import InputError
from tests.postproc.test_igm import EPSG, Strip, synthetic_strip, write_igm, write_raw

PIXELS = 64
pytestmark = pytest.mark.filterwarnings("ignore", category=NotGeoreferencedWarning)  # PNGs


def _strip_pair(folder: Path) -> list[tuple[Path, Path, Path, Strip]]:
    """Two parallel strips 40 m apart (64 m swaths: 24 m of overlap); band 3 marks the strip;
    each with its IGM, raw image and own ortho + GLT on grids aligned to 1 m."""
    out = []
    for k, east in enumerate((461_000.0, 461_040.0)):
        strip = synthetic_strip(220, PIXELS, heading_deg=4.0, turn_deg=0.0, jitter_m=0.2,
                                origin_m=(east, 4_661_000.0), miss=False, seed=10 + k)
        igm = write_igm(strip, folder / f"s{k}_igm")
        write_raw(folder / f"s{k}.bil", *strip.shape, marker=100 * (k + 1))
        grid = OrthoGrid.covering(igm_bounds(igm), 1.0, EPSG)
        orthorectify(igm, folder / f"s{k}.bil", grid, folder / f"s{k}.tif", folder / f"s{k}_glt")
        out.append((igm, folder / f"s{k}.bil", folder / f"s{k}_glt.bil", strip))
    return out


def test_mosaic_takes_the_pixel_nearest_nadir(tmp_path: Path) -> None:
    segs = _strip_pair(tmp_path)
    bounds = np.array([igm_bounds(s[0]) for s in segs])
    grid = OrthoGrid.covering((*bounds[:, :2].min(axis=0), *bounds[:, 2:].max(axis=0)), 1.0,
                              EPSG)
    res = mosaic([(igm, img) for igm, img, _, _ in segs], grid, tmp_path / "m_igm.tif",
                 tile_cells=50)
    mosaic([(glt, img) for _, img, glt, _ in segs], grid, tmp_path / "m_glt.tif", tile_cells=77)
    with rasterio.open(tmp_path / "m_igm.tif") as a, rasterio.open(tmp_path / "m_glt.tif") as b:
        m, m_glt = a.read(), b.read()
        assert a.transform == grid.transform
        assert a.nodata == 0
    np.testing.assert_array_equal(m, m_glt)  # GLT route = IGM route

    # independent oracle: each strip's nearest pixel by brute force, then the nadir rule
    rows, cols = np.mgrid[0:grid.height, 0:grid.width]
    centres = np.stack([grid.centre_x_m(cols.ravel()), grid.centre_y_m(rows.ravel())], axis=1)
    offs, covered = [], []
    for _, _, glt, strip in segs:
        with rasterio.open(glt) as g:
            r0, c0 = OrthoGrid(g.transform.c, g.transform.f, 1.0, g.width, g.height,
                               EPSG).offset_in(grid)
            own = np.zeros((grid.height, grid.width), dtype=bool)
            own[r0:r0 + g.height, c0:c0 + g.width] = g.read(1) != 0
        _, idx = cKDTree(np.stack([strip.easting_m.ravel(), strip.northing_m.ravel()],
                                  axis=1)).query(centres)
        offs.append(np.abs(idx % PIXELS - (PIXELS - 1) / 2).reshape(grid.height, grid.width))
        covered.append(own)
    both = covered[0] & covered[1]
    assert both.sum() > 2000
    expect = np.where(offs[1] < offs[0], 200, 100)
    assert (m[2][both] == expect[both]).mean() >= 0.99
    assert set(np.unique(m[2][both])) == {100, 200}  # the seam runs through the overlap
    assert (m[2][covered[0] & ~covered[1]] == 100).all()
    assert (m[2][covered[1] & ~covered[0]] == 200).all()
    assert (m[2][~covered[0] & ~covered[1]] == 0).all()
    assert res.cells_filled == int((m[2] > 0).sum())
    assert sum(res.cells_per_segment) == res.cells_filled


def test_mosaic_refuses_misaligned_glt(tmp_path: Path) -> None:
    segs = _strip_pair(tmp_path)
    grid = OrthoGrid.covering(igm_bounds(segs[0][0]), 1.0, EPSG)
    shifted = OrthoGrid(grid.west_m + 0.5, grid.north_m, 1.0, grid.width, grid.height, EPSG)
    with pytest.raises(InputError, match="not aligned"):
        mosaic([(segs[0][2], segs[0][1])], shifted, tmp_path / "m.tif")
    with pytest.raises(InputError, match="neither an IGM"):
        mosaic([(segs[0][1], segs[0][1])], grid, tmp_path / "m.tif")
    assert not (tmp_path / "m.tif").exists()


# -- footprints ------------------------------------------------------------------------------

def _inside(ring: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Even–odd rule, vectorised over points."""
    inside = np.zeros(len(pts), dtype=bool)
    x, y = pts[:, 0], pts[:, 1]
    for (x1, y1), (x2, y2) in itertools.pairwise(ring):
        crosses = (y1 > y) != (y2 > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
        inside ^= crosses & (x < xc)
    return inside


def _distance_to_ring(ring: np.ndarray, pts: np.ndarray) -> np.ndarray:
    a, b = ring[:-1][None], ring[1:][None]
    p = pts[:, None]
    ab = b - a
    t = np.clip(((p - a) * ab).sum(-1) / (ab * ab).sum(-1), 0, 1)
    return np.hypot(*(a + t[..., None] * ab - p).transpose(2, 0, 1)).min(axis=1)


def test_footprint_geojson(tmp_path: Path) -> None:
    strip = synthetic_strip(600, PIXELS, smooth_lines=25)  # attitude varies smoothly
    for a in (strip.easting_m, strip.northing_m, strip.height_m):
        a[:5] = np.nan  # the first lines missed the DEM
    igm = write_igm(strip, tmp_path / "seg_igm")
    feat = footprint_feature(igm, EPSG, properties={
        "segment": 3, "t_first_gps_ns": 1_000_000_000_000, "t_last_gps_ns": 1_030_500_000_000})
    write_footprints_geojson(tmp_path / "fp.geojson", [feat])
    doc = json.loads((tmp_path / "fp.geojson").read_text())
    assert doc["type"] == "FeatureCollection"
    assert "crs" not in doc
    (f,) = doc["features"]
    assert f["type"] == "Feature"
    assert f["geometry"]["type"] == "Polygon"
    ring = np.array(f["geometry"]["coordinates"][0])
    assert len(ring) >= 4
    assert (ring[0] == ring[-1]).all()
    lon, lat = ring[:, 0], ring[:, 1]
    assert 2.0 < lon.min() < lon.max() < 3.0  # UTM 31N near Garrotxa
    assert 42.0 < lat.min() < lat.max() < 42.2
    assert np.sum(lon[:-1] * lat[1:] - lon[1:] * lat[:-1]) > 0  # counter-clockwise
    assert len(ring) < 0.2 * 2 * 600  # subsampled

    utm = np.stack(Transformer.from_crs(4326, EPSG, always_xy=True).transform(lon, lat), axis=1)
    ok = np.isfinite(strip.easting_m)
    pts = np.stack([strip.easting_m[ok], strip.northing_m[ok]], axis=1)
    out = ~_inside(utm, pts)
    assert out.mean() < 0.05
    assert (_distance_to_ring(utm, pts[out]) <= 0.5 + 1e-3).all()  # the DP tolerance

    p = f["properties"]
    assert (p["segment"], p["lines"], p["first_line"], p["last_line"]) == (3, 600, 5, 599)
    assert p["duration_s"] == pytest.approx(30.5)
    full = np.concatenate([np.stack([strip.easting_m[5:, 0], strip.northing_m[5:, 0]], 1),
                           np.stack([strip.easting_m[-1], strip.northing_m[-1]], 1)[np.isfinite(
                               strip.easting_m[-1])],
                           np.stack([strip.easting_m[5:, -1], strip.northing_m[5:, -1]], 1)[::-1],
                           np.stack([strip.easting_m[5], strip.northing_m[5]], 1)[::-1]])
    full = full[np.isfinite(full).all(axis=1)]
    flon, flat = Transformer.from_crs(EPSG, 4326, always_xy=True).transform(full[:, 0],
                                                                             full[:, 1])
    area, _ = Geod(ellps="WGS84").polygon_area_perimeter(flon, flat)
    assert p["area_m2"] == pytest.approx(abs(area), rel=0.01)


def test_footprint_of_an_empty_igm_has_no_geometry(tmp_path: Path) -> None:
    strip = synthetic_strip(20, 8)
    strip.easting_m[:] = np.nan
    igm = write_igm(strip, tmp_path / "igm")
    feat = footprint_feature(igm, EPSG, properties={"segment": 0})
    assert feat["geometry"] is None
    assert feat["properties"]["first_line"] == -1
    write_footprints_geojson(tmp_path / "fp.geojson", [feat])
    assert json.loads((tmp_path / "fp.geojson").read_text())["features"][0]["geometry"] is None
    with pytest.raises(InputError, match="not a GeoJSON Feature"):
        write_footprints_geojson(tmp_path / "bad.geojson", [{"type": "Polygon"}])


# -- quicklooks ------------------------------------------------------------------------------

def test_rgb_bands_nearest_to_640_550_460() -> None:
    assert rgb_bands([460.0, 550.0, 640.0, 850.0]) == (3, 2, 1)
    assert rgb_bands([495.0, 625.0, 755.0, 885.0]) == (2, 1, 1)
    assert rgb_bands([None, None, None]) == (1, 2, 3)
    assert rgb_bands([None]) == (1, 1, 1)


def test_quicklooks_of_ortho_and_raw(tmp_path: Path) -> None:
    _, img, _, _ = _strip_pair(tmp_path)[0]
    tif = tmp_path / "s0.tif"
    shape = write_quicklook(tif, tmp_path / "o.png", max_size_px=100)
    with rasterio.open(tmp_path / "o.png") as png, rasterio.open(tif) as src:
        assert (png.driver, png.count, png.dtypes[0]) == ("PNG", 4, "uint8")
        assert (png.height, png.width) == shape
        assert max(shape) <= 100
        rgba = png.read()
        nodata = src.read(1, out_shape=shape) == 0
    np.testing.assert_array_equal(rgba[3] == 0, nodata)  # nodata transparent
    assert (rgba[3] == 255).sum() > 0.2 * rgba[3].size
    green = rgba[1][rgba[3] == 255]  # band 2 (550 nm): pixel number, stretched 2-98 %
    assert (green.min(), green.max()) == (0, 255)

    shape = write_quicklook(img, tmp_path / "raw.png", max_size_px=100)
    with rasterio.open(tmp_path / "raw.png") as png:
        assert (png.height, png.width) == shape == (100, 29)
        assert (png.read(4) == 255).all()
    assert sorted(p.name for p in tmp_path.glob("*.png")) == ["o.png", "raw.png"]
