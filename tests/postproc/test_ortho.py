"""Ortho and GLT of a synthetic turning, turbulent strip, against independent oracles: a
brute-force nearest neighbour (scipy cKDTree), a separate point-in-triangle swath mask, and
GDAL reading every product."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import rasterio
from scipy.spatial import cKDTree

import postproc.ortho as ortho
from postproc.ortho import OrthoGrid, SwathIndex, orthorectify
from sisa.errors import InputError
from tests.postproc.test_igm import (
    EPSG,
    WAVELENGTHS_NM,
    Strip,
    gdal_ok,
    synthetic_strip,
    write_igm,
    write_raw,
)

CELL_M = 1.0


@dataclass(frozen=True)
class Made:
    folder: Path
    strip: Strip
    raw: np.ndarray  # (lines, bands, pixels)
    grid: OrthoGrid
    tif: Path
    glt: Path
    result: ortho.OrthoResult

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        with rasterio.open(self.tif) as o, rasterio.open(self.glt) as g:
            return o.read(), g.read()


def make(folder: Path, strip: Strip, *, tile_cells: int | None = None) -> Made:
    folder.mkdir(parents=True, exist_ok=True)
    igm = write_igm(strip, folder / "seg_igm")
    raw = write_raw(folder / "seg.bil", *strip.shape)
    grid = OrthoGrid.covering(SwathIndex.build(igm).bounds_m, CELL_M, EPSG)
    tif, glt = folder / "seg_ortho.tif", folder / "seg_glt"
    res = orthorectify(igm, folder / "seg.bil", grid, tif, glt, tile_cells=tile_cells)
    return Made(folder, strip, raw, grid, tif, Path(f"{glt}.bil"), res)


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> Made:
    return make(tmp_path_factory.mktemp("ortho"), synthetic_strip(600, 64))


def _chosen(glt: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    rows, cols = np.nonzero(glt[0] != 0)
    return rows, cols, np.abs(glt[1][rows, cols]) - 1, np.abs(glt[0][rows, cols]) - 1


def test_choice_is_the_nearest_pixel(made: Made) -> None:
    _, glt = made.read()
    rows, cols, line, pixel = _chosen(glt)
    e, n = made.strip.easting_m, made.strip.northing_m
    ok = np.isfinite(e)
    li, pj = np.nonzero(ok)
    centres = np.stack([made.grid.centre_x_m(cols), made.grid.centre_y_m(rows)], axis=1)
    d_nn, k = cKDTree(np.stack([e[ok], n[ok]], axis=1)).query(centres)
    same = (li[k] == line) & (pj[k] == pixel)
    assert same.mean() >= 0.99
    ours = np.hypot(e[line, pixel] - centres[:, 0], n[line, pixel] - centres[:, 1])
    assert ours.mean() <= 1.01 * d_nn.mean()
    assert made.result.mean_distance_m == pytest.approx(ours.mean(), rel=1e-9)


def _triangle_mask(x: np.ndarray, y: np.ndarray, tri: np.ndarray) -> np.ndarray:
    (ax, ay), (bx, by), (cx, cy) = tri
    area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    if area == 0:
        return np.zeros(x.shape, dtype=bool)
    w0 = ((bx - ax) * (y - ay) - (by - ay) * (x - ax)) / area
    w1 = ((cx - bx) * (y - by) - (cy - by) * (x - bx)) / area
    w2 = ((ax - cx) * (y - cy) - (ay - cy) * (x - cx)) / area
    mask: np.ndarray = (w0 >= 0) & (w1 >= 0) & (w2 >= 0)
    return mask


def swath_mask(strip: Strip, grid: OrthoGrid) -> np.ndarray:
    """Cells whose centre lies in a triangle of a quad of valid pixels (independent of the
    numba kernel: barycentric weights, one quad at a time)."""
    e, n = strip.easting_m, strip.northing_m
    inside = np.zeros((grid.height, grid.width), dtype=bool)
    corners = ((0, 0), (0, 1), (1, 1), (1, 0))
    for i in range(e.shape[0] - 1):
        for j in range(e.shape[1] - 1):
            q = np.array([(e[i + a, j + b], n[i + a, j + b]) for a, b in corners])
            good = np.isfinite(q).all(axis=1)
            if good.sum() < 3:
                continue
            c0, c1 = np.floor((q[good, 0].min() - grid.west_m) / grid.cell_m), \
                np.ceil((q[good, 0].max() - grid.west_m) / grid.cell_m)
            r0, r1 = np.floor((grid.north_m - q[good, 1].max()) / grid.cell_m), \
                np.ceil((grid.north_m - q[good, 1].min()) / grid.cell_m)
            rr, cc = np.mgrid[int(r0):int(r1) + 1, int(c0):int(c1) + 1]
            keep = (rr >= 0) & (rr < grid.height) & (cc >= 0) & (cc < grid.width)
            rr, cc = rr[keep], cc[keep]
            x, y = grid.centre_x_m(cc), grid.centre_y_m(rr)
            tris = [q[[0, 1, 2]], q[[0, 2, 3]]] if good.all() else [q[good]]
            hit = np.zeros(x.shape, dtype=bool)
            for t in tris:
                hit |= _triangle_mask(x, y, t)
            inside[rr[hit], cc[hit]] = True
    return inside


def test_no_holes_inside_the_swath_and_nodata_outside(made: Made) -> None:
    data, glt = made.read()
    inside = swath_mask(made.strip, made.grid)
    filled = glt[0] != 0
    assert inside.sum() > 30_000
    assert (inside & ~filled).sum() == 0  # no hole
    assert (filled & ~inside).sum() == 0  # nothing outside
    assert (data[:, ~filled] == 0).all()  # explicit nodata
    assert (data[0][filled] > 0).all()


def test_glt_and_ortho_agree_and_gdal_reads_them(made: Made) -> None:
    for path in (made.tif, made.glt, made.folder / "seg_igm.bil"):
        gdal_ok(path)
    data, glt = made.read()
    rows, cols, line, pixel = _chosen(glt)
    np.testing.assert_array_equal(data[:, rows, cols], made.raw[line, :, pixel].T)
    with rasterio.open(made.tif) as o, rasterio.open(made.glt) as g:
        assert g.transform == o.transform == made.grid.transform
        assert g.crs.to_epsg() == o.crs.to_epsg() == EPSG
        assert g.dtypes == ("int32", "int32")
        assert g.descriptions == ("GLT Sample Lookup", "GLT Line Lookup")
    header = made.glt.with_suffix(".hdr").read_text()
    assert "1-based sample (band 1) and line (band 2)" in header
    assert "0 = no input" in header


def test_geotiff_layout_and_cell_convention(made: Made) -> None:
    _, glt = made.read()
    with rasterio.open(made.tif) as ds:
        assert ds.dtypes == ("uint16",) * len(WAVELENGTHS_NM)
        assert ds.nodata == 0
        assert ds.profile["tiled"]
        assert ds.compression.name == "deflate"
        assert ds.tags()["AREA_OR_POINT"] == "Area"
        for b, wl in enumerate(WAVELENGTHS_NM, 1):
            assert f"{wl:.1f} nm" in ds.descriptions[b - 1]
            assert float(ds.tags(b)["wavelength"]) == wl
        # a positive GLT entry means the chosen pixel centre lies in the cell (GDAL's reading
        # of the GeoTIFF's grid); a negative one, that it lies outside
        rows, cols, line, pixel = _chosen(glt)
        x = made.strip.easting_m[line, pixel]
        y = made.strip.northing_m[line, pixel]
        r, c = rasterio.transform.rowcol(ds.transform, x, y)
        in_cell = (np.asarray(r) == rows) & (np.asarray(c) == cols)
        np.testing.assert_array_equal(in_cell, glt[0][rows, cols] > 0)
        assert in_cell.mean() > 0.5


def test_small_tiles_give_the_same_products(made: Made, tmp_path: Path) -> None:
    again = make(tmp_path, made.strip, tile_cells=37)
    a, ga = made.read()
    b, gb = again.read()
    np.testing.assert_array_equal(ga, gb)
    np.testing.assert_array_equal(a, b)


def test_grid_snaps_to_cell_multiples() -> None:
    g = OrthoGrid.covering((461_000.3, 4_661_000.7, 461_010.1, 4_661_020.2), 1.5, EPSG)
    assert (g.west_m, g.north_m) == (460_999.5, 4_661_020.5)
    w, s, e, n = g.bounds_m
    assert 0 <= 461_000.3 - w < 1.5
    assert 0 <= 4_661_000.7 - s < 1.5
    assert 0 <= e - 461_010.1 < 1.5
    assert 0 <= n - 4_661_020.2 < 1.5
    inner = OrthoGrid.covering((461_003.0, 4_661_003.0, 461_006.0, 4_661_006.0), 1.5, EPSG)
    assert inner.offset_in(g) == (round((g.north_m - inner.north_m) / 1.5),
                                  round((inner.west_m - g.west_m) / 1.5))
    shifted = OrthoGrid(inner.west_m + 0.5, inner.north_m, 1.5, 2, 2, EPSG)
    with pytest.raises(InputError, match="not aligned"):
        shifted.offset_in(g)
    with pytest.raises(InputError, match="positive"):
        OrthoGrid.covering((0, 0, 1, 1), 0.0, EPSG)


def test_failure_leaves_no_product(made: Made, tmp_path: Path,
                                   monkeypatch: pytest.MonkeyPatch) -> None:
    calls = {"n": 0}
    real = ortho.gather_pixels

    def failing(*args: object, **kw: object) -> np.ndarray:
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError("disk full")
        return real(*args, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(ortho, "gather_pixels", failing)
    igm = made.folder / "seg_igm.bil"
    with pytest.raises(OSError, match="disk full"):
        orthorectify(igm, made.folder / "seg.bil", made.grid, tmp_path / "o.tif",
                     tmp_path / "g", tile_cells=64)
    assert calls["n"] == 3
    assert list(tmp_path.iterdir()) == []


def test_image_must_match_the_igm(made: Made, tmp_path: Path) -> None:
    write_raw(tmp_path / "short.bil", 599, 64)
    with pytest.raises(InputError, match="IGM is 600 x 64"):
        orthorectify(made.folder / "seg_igm.bil", tmp_path / "short.bil", made.grid,
                     tmp_path / "o.tif", tmp_path / "g")
    other = OrthoGrid(made.grid.west_m, made.grid.north_m, 1.0, 10, 10, 32630)
    with pytest.raises(InputError, match="EPSG:32631"):
        orthorectify(made.folder / "seg_igm.bil", made.folder / "seg.bil", other,
                     tmp_path / "o.tif", tmp_path / "g")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["short.bil", "short.hdr"]


def test_zstd_product_holds_the_same_values(made: Made, tmp_path: Path) -> None:
    tif = tmp_path / "z.tif"
    orthorectify(made.folder / "seg_igm.bil", made.folder / "seg.bil", made.grid, tif,
                 tmp_path / "z_glt", compress="zstd")
    with rasterio.open(tif) as z, rasterio.open(made.tif) as d:
        assert z.compression.name == "zstd"
        assert z.nodata == d.nodata == 0
        np.testing.assert_array_equal(z.read(), d.read())
