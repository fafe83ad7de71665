"""Ortho and GLT of a synthetic turning, turbulent strip, against independent oracles: a
brute-force nearest neighbour (scipy cKDTree), a separate point-in-triangle swath mask, and
GDAL reading every product."""

from __future__ import annotations

import os
import shutil
import threading
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rasterio
from scipy.spatial import cKDTree

import postproc.products.ortho as ortho
from postproc.products import (
    CutShortWarning,
    EnviRaster,
    OrthoGrid,
    SwathIndex,
    open_igm,
    orthorectify,
)
from sisa.core.errors import InputError
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


def test_glt_writer_refuses_windows_outside_and_reports_write_errors(tmp_path: Path) -> None:
    grid = OrthoGrid(500_000.0, 4_600_000.0, 1.0, 8, 6, 32631)
    glt = ortho.GltWriter(tmp_path / "g", grid, "seg.bil", "o.tif")
    values = np.zeros((3, 2, 4), np.int32)
    values[1, :, 1:3] = [[5, 6], [7, 8]]
    glt.write_window(2, 4, values)
    for row0, col0 in ((4, 0), (0, 5), (-1, 0)):
        with pytest.raises(ValueError, match="outside the 6 x 8 grid"):
            glt.write_window(row0, col0, values)
    glt.close()
    got = np.fromfile(tmp_path / "g.bil", "<i4").reshape(6, 2, 8)
    want = np.zeros((6, 2, 8), np.int32)
    want[3, :, 5:7] = [[5, 6], [7, 8]]
    np.testing.assert_array_equal(got, want)
    broken = ortho.GltWriter(tmp_path / "b", grid, "seg.bil", "o.tif")
    os.close(broken._fd or -1)  # the file gone from under it: the write fails, said as such
    with pytest.raises(OSError, match="Bad file descriptor"):
        broken.write_window(0, 0, values)
    broken._fd = None
    broken.abort()


def test_small_tiles_give_the_same_products(made: Made, tmp_path: Path) -> None:
    again = make(tmp_path, made.strip, tile_cells=37)
    a, ga = made.read()
    b, gb = again.read()
    np.testing.assert_array_equal(ga, gb)
    np.testing.assert_array_equal(a, b)


def test_progress_counts_every_window_once(made: Made, tmp_path: Path) -> None:
    totals: list[int] = []
    steps: list[int] = []
    res = orthorectify(made.folder / "seg_igm.bil", made.folder / "seg.bil", made.grid,
                       tmp_path / "p.tif", tmp_path / "p_glt", tile_cells=37,
                       progress=steps.append, on_total=totals.append)
    assert len(totals) == 1
    assert len(steps) > 1  # small tiles: many windows
    assert sum(steps) == totals[0]
    assert res.cells_filled <= totals[0] < res.cells  # the windows the swath reaches, not all
    assert (tmp_path / "p_glt.bil").read_bytes() == made.glt.read_bytes()


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
    lock = threading.Lock()
    real = ortho.gather_pixels

    def failing(*args: object, **kw: object) -> np.ndarray:
        with lock:
            calls["n"] += 1
            n = calls["n"]
        if n == 3:
            raise OSError("disk full")
        return real(*args, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(ortho, "gather_pixels", failing)
    igm = made.folder / "seg_igm.bil"
    with pytest.raises(OSError, match="disk full"):
        orthorectify(igm, made.folder / "seg.bil", made.grid, tmp_path / "o.tif",
                     tmp_path / "g", tile_cells=64)
    # the work stops: at most the windows already being made when the failure came finish
    assert 3 <= calls["n"] <= 3 + ortho.WORKERS
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("tile_cells", [None, 64])
def test_workers_give_identical_products(made: Made, tmp_path: Path, tile_cells: int | None,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """Windows made on several threads at once: byte for byte the single-thread products,
    even with a GeoTIFF writer lagging behind (a window's arrays must not be reused before
    it is written)."""
    igm, image = made.folder / "seg_igm.bil", made.folder / "seg.bil"
    real = ortho.TiffWriter._write

    def lagging(self: ortho.TiffWriter, *args: Any) -> None:
        time.sleep(0.002)
        real(self, *args)

    monkeypatch.setattr(ortho.TiffWriter, "_write", lagging)
    runs = []
    for workers in (1, 2, 3):
        tif, glt = tmp_path / f"o{workers}.tif", tmp_path / f"g{workers}"
        res = orthorectify(igm, image, made.grid, tif, glt, tile_cells=tile_cells,
                           workers=workers)
        with rasterio.open(tif) as ds:
            runs.append((res, ds.read(), Path(f"{glt}.bil").read_bytes()))
    for res, data, glt_bytes in runs[1:]:
        assert res == runs[0][0]
        np.testing.assert_array_equal(data, runs[0][1])
        assert glt_bytes == runs[0][2]
    assert runs[0][0].cells_filled == made.result.cells_filled


def _choose(strip: Strip, grid: OrthoGrid, gap: str) -> tuple[np.ndarray, ...]:
    """The nearest-pixel kernel on a whole strip, with the descent gated by `_gaps` ("gaps"),
    always run ("always": gap 0) or never run ("never": gap inf)."""
    lines, pixels = strip.shape
    blk = np.stack([strip.easting_m, strip.northing_m, strip.height_m], axis=1)
    u, v, box = np.empty((lines, pixels)), np.empty((lines, pixels)), np.empty((lines, 4))
    x0, y0 = float(grid.centre_x_m(0)), float(grid.centre_y_m(0))
    ortho._to_cells(blk, x0, y0, grid.cell_m, u, v, box)
    gaps = np.empty_like(u)
    ortho._gaps(u, v, gaps)
    gaps = {"gaps": gaps, "always": np.zeros_like(u), "never": np.full_like(u, np.inf)}[gap]
    d2 = np.full((grid.height, grid.width), np.inf)
    line = np.full((grid.height, grid.width), -1, dtype=np.int32)
    pixel = np.full_like(line, -1)
    inside = np.zeros(line.shape, dtype=bool)
    ortho._rasterise(u, v, box, gaps, 0, lines - 1, 0, d2, line, pixel, inside)
    return line, pixel, d2, inside


def test_skipped_descents_change_nothing(made: Made) -> None:
    """The descent is skipped where `_gaps` proves no neighbour nearer: the choices are those
    of always descending, on a strip whose crossing lines need the descent."""
    gated = _choose(made.strip, made.grid, "gaps")
    always = _choose(made.strip, made.grid, "always")
    never = _choose(made.strip, made.grid, "never")
    for a, b in zip(gated, always, strict=True):
        np.testing.assert_array_equal(a, b)
    assert (never[0] != always[0]).sum() > 100  # the descent matters on this strip


def test_gaps_is_the_nearest_neighbour_of_the_descent() -> None:
    rng = np.random.default_rng(3)
    u, v = rng.normal(size=(9, 7)), rng.normal(size=(9, 7))
    u[4, 3] = np.nan
    v[0, 0] = np.nan
    got = np.empty_like(u)
    ortho._gaps(u, v, got)
    want = np.full_like(u, np.inf)
    for i, j in np.ndindex(u.shape):
        for a in range(max(i - ortho.DESCENT_LINES, 0), min(i + ortho.DESCENT_LINES + 1, 9)):
            for b in range(max(j - ortho.DESCENT_PIXELS, 0),
                           min(j + ortho.DESCENT_PIXELS + 1, 7)):
                d = (u[a, b] - u[i, j]) ** 2 + (v[a, b] - v[i, j]) ** 2
                if (a, b) != (i, j) and d < want[i, j]:
                    want[i, j] = d
    np.testing.assert_array_equal(got, want)
    assert np.isinf(got[4, 3])  # no position: no neighbour
    assert np.isinf(got[0, 0])
    assert np.isfinite(got[4, 2])


def test_line_extents_skip_pixels_without_a_position() -> None:
    rng = np.random.default_rng(5)
    blk = rng.normal(size=(6, 3, 8)) * 100
    blk[1, 0, 2] = np.nan  # easting only: the pixel has no position
    blk[2, 1, 5] = np.inf
    blk[3, :2] = np.nan  # a line without any position
    got = np.empty((6, 4))
    ortho._line_extents(blk, got)
    e, n = blk[:, 0].copy(), blk[:, 1].copy()
    bad = ~(np.isfinite(e) & np.isfinite(n))
    e[bad], n[bad] = np.nan, np.nan
    with np.errstate(invalid="ignore"), pytest.warns(RuntimeWarning):
        want = np.stack([np.nanmin(e, axis=1), np.nanmin(n, axis=1), np.nanmax(e, axis=1),
                         np.nanmax(n, axis=1)], axis=1)
    np.testing.assert_array_equal(got, want)
    assert np.isnan(got[3]).all()


def test_index_built_in_parts_is_the_whole_pass(made: Made,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """The IGM read by several workers, in reads of 7 lines (600 = 3 parts of 200): the
    same boxes as one worker reading it whole, and they hold every position."""
    igm = made.folder / "seg_igm.bil"
    whole = SwathIndex.build(igm, workers=1)
    monkeypatch.setattr(ortho, "MAX_READ_LINES", 7)
    for workers in (2, 3, 7):
        np.testing.assert_array_equal(SwathIndex.build(igm, workers=workers).boxes_m,
                                      whole.boxes_m)
    e, n = made.strip.easting_m, made.strip.northing_m
    assert whole.bounds_m == (np.nanmin(e), np.nanmin(n), np.nanmax(e), np.nanmax(n))


@pytest.mark.parametrize("dtype", ["u1", "<i2", "<f4", "<f8", ">u2"])
def test_gather_copies_every_band_of_any_type(dtype: str) -> None:
    """The C copy moves values of 1, 2, 4 or 8 bytes as they are, into bands kept apart as
    Scratch.planes keeps them; a big-endian block arrives in the machine's order."""
    rng = np.random.default_rng(11)
    block = (rng.random((40, 5, 30)) * 200).astype(dtype)
    line = rng.integers(-1, 40, size=(6, 7)).astype(np.int32)
    pixel = rng.integers(0, 30, size=(6, 7)).astype(np.int32)
    valid = line >= 10  # lines 0..9 are before the block: left as they were
    out = ortho.Scratch().planes("p", (5, 6, 7), block.dtype.newbyteorder("="), fill=7)
    flat = out.reshape(5, 42)
    assert not flat.flags.c_contiguous  # the bands lie apart
    ortho._copy_pixels(block[10:], 10, line.ravel(), pixel.ravel(), valid.ravel(), flat)
    want = np.full((5, 6, 7), 7, dtype=out.dtype)
    r, c = np.nonzero(valid)
    want[:, r, c] = block[line[r, c], :, pixel[r, c]].T
    np.testing.assert_array_equal(out, want)


def test_kernels_refuse_arrays_they_cannot_read() -> None:
    """The C kernels take raw pointers: a view with gaps, another type or a read-only output
    is refused before the call, not read as something else."""
    u = np.zeros((8, 6))
    gap = np.empty_like(u)
    with pytest.raises(ValueError, match="C-contiguous"):
        ortho._gaps(u[:, ::2], u[:, ::2], gap[:, :3])
    with pytest.raises(ValueError, match="C-contiguous"):
        ortho._gaps(u, u, gap.astype(np.float32))
    frozen = np.empty_like(u)
    frozen.flags.writeable = False
    with pytest.raises(ValueError, match="writable"):
        ortho._gaps(u, u, frozen)
    with pytest.raises(ValueError, match="writable"):
        ortho._line_extents(np.zeros((4, 3, 5)), np.empty((3, 4)))  # one line short
    with pytest.raises(ValueError, match="native"):
        ortho._copy_pixels(np.zeros((2, 1, 3)), 0, np.zeros(4, np.int32),
                           np.zeros(4, np.int32), np.ones(4, bool), np.zeros((1, 4), ">f8"))


def test_the_ortho_starts_without_numba() -> None:
    """`sisa ortho` runs as a process of its own; numba would cost it 1.5-2 s of start-up."""
    import subprocess
    import sys

    got = subprocess.run([sys.executable, "-c", "import sys, postproc.products.ortho; "
                          "print(sorted(m for m in sys.modules if m.split('.')[0] == 'numba'))"],
                         capture_output=True, text=True, check=True)
    assert got.stdout.strip() == "[]"


def test_mapped_reads_match_read_lines(tmp_path: Path) -> None:
    img = write_raw(tmp_path / "a.bil", 50, 9)
    raw = EnviRaster.open(tmp_path / "a.bil")
    sc = ortho.Scratch()
    first = sc.read_lines("raw", raw, 3, 20)
    np.testing.assert_array_equal(first, img[3:20])
    assert not first.flags.writeable  # a view of the file, not a copy
    again = sc.read_lines("raw", raw, 10, 12)
    np.testing.assert_array_equal(again, img[10:12])
    np.testing.assert_array_equal(first, img[3:20])  # an earlier read stays valid while held
    # a file cut after it was opened: said, not a crash on a page past its end
    with (tmp_path / "a.bil").open("r+b") as fh:
        fh.truncate(raw.header_offset + 30 * raw.line_bytes)
    np.testing.assert_array_equal(sc.read_lines("raw", raw, 0, 30), img[:30])
    with pytest.raises(InputError, match="truncated"):
        sc.read_lines("raw", raw, 20, 31)
    img = write_raw(tmp_path / "a.bil", 50, 9)
    # big-endian or band-sequential: raster.read_lines, which converts
    img.astype(">u2").transpose(1, 0, 2).tofile(tmp_path / "b.bil")
    hdr = (tmp_path / "a.hdr").read_text().replace("interleave = bil", "interleave = bsq")
    (tmp_path / "b.hdr").write_text(hdr.replace("byte order = 0", "byte order = 1"))
    other = EnviRaster.open(tmp_path / "b.bil")
    np.testing.assert_array_equal(sc.read_lines("raw", other, 5, 40), img[5:40])
    with pytest.raises(InputError, match="outside"):
        sc.read_lines("raw", raw, 40, 51)


def test_planes_keep_bands_off_4k_multiples() -> None:
    sc = ortho.Scratch()
    for shape, dtype in (((18, 512, 1024), np.uint16), ((3, 7, 5), np.float32)):
        arr = sc.planes("p", shape, dtype, fill=9)
        assert arr.shape == shape
        assert arr.dtype == dtype
        assert (arr == 9).all()
        assert arr.strides[0] % 4096 != 0
        assert arr.strides[0] % 4096 == ortho.PLANE_PAD_BYTES
        assert arr.strides[1:] == (shape[2] * arr.itemsize, arr.itemsize)


def test_chunked_reads_gather_every_line(made: Made, monkeypatch: pytest.MonkeyPatch) -> None:
    """The image read by chunks of 37 lines, some skipped: the same values."""
    monkeypatch.setattr(ortho, "RAW_CHUNK_LINES", 37)
    raw = EnviRaster.open(made.folder / "seg.bil")
    rng = np.random.default_rng(2)
    line = rng.integers(0, 600, size=(30, 40)).astype(np.int32)
    line[line // 37 % 3 == 1] = 0  # some chunks not needed at all
    pixel = rng.integers(0, 64, size=(30, 40)).astype(np.int32)
    valid = rng.random((30, 40)) < 0.8
    got = ortho.gather_pixels(raw, line, pixel, valid, 5)
    want = np.where(valid, made.raw[line, :, pixel].transpose(2, 0, 1), 5)
    np.testing.assert_array_equal(got, want)


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


def cut_copy(src: Path, dst: Path, lines: float) -> Path:
    """A copy of an ENVI raster cut after `lines` lines (a fraction: mid-line)."""
    raster = EnviRaster.open(src)
    dst.write_bytes(src.read_bytes()[:raster.header_offset
                                     + int(lines * raster.line_bytes)])
    shutil.copy(src.with_suffix(".hdr"), dst.with_suffix(".hdr"))
    return dst


def pair_cut_short(made: Made, folder: Path, cut: str, lines: float) -> tuple[Path, Path]:
    """`made`'s IGM and image, one of them (`cut`: "image" or "igm") a copy in `folder` cut
    after `lines` lines."""
    igm, image = made.folder / "seg_igm.bil", made.folder / "seg.bil"
    if cut == "image":
        return igm, cut_copy(image, folder / "cut.bil", lines)
    return cut_copy(igm, folder / "cut_igm.bil", lines), image


@pytest.mark.parametrize("cut", ["image", "igm"])
def test_a_file_cut_short_maps_the_lines_both_hold(made: Made, tmp_path: Path,
                                                   cut: str) -> None:
    """The image (or the IGM) cut mid-line 450: lines 0-449 mapped, a warning names the
    rest; every cell whose choice was a line before the cut keeps it."""
    igm, image = pair_cut_short(made, tmp_path, cut, 450.5)
    with pytest.warns(CutShortWarning, match=r"450 of its header's 600 lines .* lines "
                                             r"450-599 are not mapped"):
        orthorectify(igm, image, made.grid, tmp_path / "o.tif", tmp_path / "g")
    with rasterio.open(tmp_path / "o.tif") as o, rasterio.open(tmp_path / "g.bil") as g:
        tif, glt = o.read(), g.read()
    full_tif, full_glt = made.read()
    line = np.abs(glt[1]) - 1
    assert line.max() == 449
    before = (full_glt[1] != 0) & (np.abs(full_glt[1]) - 1 < 440)
    assert before.sum() > 1000
    np.testing.assert_array_equal(glt[:, before], full_glt[:, before])
    np.testing.assert_array_equal(tif[:, before], full_tif[:, before])


def test_a_header_declaring_lines_its_file_lacks_is_said(made: Made, tmp_path: Path) -> None:
    """The IGM's header says 10 000 lines, its file and the image hold 600: every line is
    mapped, and the IGM is said to be cut short (was silent; found by a bad-input sweep)."""
    igm = tmp_path / "long_igm.bil"
    shutil.copy(made.folder / "seg_igm.bil", igm)
    hdr = (made.folder / "seg_igm.hdr").read_text()
    assert "lines = 600" in hdr
    igm.with_suffix(".hdr").write_text(hdr.replace("lines = 600", "lines = 10000"))
    with pytest.warns(CutShortWarning, match=r"long_igm\.bil is cut short: 600 of its header's "
                                             r"10000 lines .* all of them are mapped"):
        orthorectify(igm, made.folder / "seg.bil", made.grid, tmp_path / "o.tif",
                     tmp_path / "g")
    with rasterio.open(tmp_path / "o.tif") as o:
        np.testing.assert_array_equal(o.read(), made.read()[0])


def test_a_shorter_header_is_still_refused(made: Made, tmp_path: Path) -> None:
    """Files whose headers disagree are a different image, not one cut short."""
    write_raw(tmp_path / "short.bil", 450, 64)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputError, match="IGM is 600 x 64"):
            orthorectify(made.folder / "seg_igm.bil", tmp_path / "short.bil", made.grid,
                         tmp_path / "o.tif", tmp_path / "g")


def test_zstd_product_holds_the_same_values(made: Made, tmp_path: Path) -> None:
    tif = tmp_path / "z.tif"
    orthorectify(made.folder / "seg_igm.bil", made.folder / "seg.bil", made.grid, tif,
                 tmp_path / "z_glt", compress="zstd")
    with rasterio.open(tif) as z, rasterio.open(made.tif) as d:
        assert z.compression.name == "zstd"
        assert z.nodata == d.nodata == 0
        np.testing.assert_array_equal(z.read(), d.read())


def damaged_igm(made: Made, folder: Path, name: str, damage: Any) -> Path:
    """`made`'s IGM written again with `damage(xyz)` done to its (lines, 3, pixels) values
    (IgmWriter would write a non-finite pixel all NaN)."""
    xyz = np.array(open_igm(made.folder / "seg_igm.bil"))
    damage(xyz)
    xyz.astype("<f8").tofile(folder / f"{name}.bil")
    shutil.copy(made.folder / "seg_igm.hdr", folder / f"{name}.hdr")
    return folder / f"{name}.bil"


def test_an_undamaged_igm_has_nothing_far(made: Made) -> None:
    """Turbulence white from line to line (lines cross), a DEM miss: nothing is far off."""
    assert SwathIndex.build(made.folder / "seg_igm.bil").far is None
    assert SwathIndex.build(made.folder / "seg_igm.bil", block_lines=7).far is None


def _far_pixel(xyz: np.ndarray) -> None:
    xyz[10, 1, 10] += 5e6  # northing 5000 km off


def _off_line(xyz: np.ndarray) -> None:
    xyz[300, 0] = 0.0  # a zeroed sector: one line's eastings


def _far_void(xyz: np.ndarray) -> None:
    xyz[10, :, 10] = np.nan


def _off_void(xyz: np.ndarray) -> None:
    xyz[300] = np.nan


@pytest.mark.parametrize(("damage", "void", "said", "count"), [
    (_far_pixel, _far_void, "IGM line 10, pixel 10 lies 5000 km from the rest of its line", 1),
    (_off_line, _off_void, "IGM line 300 lies 461 km from the lines around it", 64)])
def test_positions_far_from_the_rest_are_mapped_as_none(
        made: Made, tmp_path: Path, damage: Any, void: Any, said: str, count: int) -> None:
    """One northing 5000 km off stretched the default grid to 5000 km (`sisa ortho`: 66 s,
    a 21 GB sparse GLT); on a grid given, the quads reaching it filled a sliver of cells up
    to the grid's edge from the pixels beside it. Now the index leaves such positions out
    (its extent is the swath's), and the ortho maps them as NaN, with a warning."""
    far = damaged_igm(made, tmp_path, "far_igm", damage)
    index = SwathIndex.build(far)
    assert index.far is not None
    assert index.far.first == said
    assert len(index.far.pixels) == count
    np.testing.assert_array_equal(index.boxes_m,
                                  SwathIndex.build(made.folder / "seg_igm.bil").boxes_m
                                  if damage is _far_pixel else
                                  SwathIndex.build(damaged_igm(made, tmp_path, "v", void)).boxes_m)
    with pytest.warns(ortho.FarPositionWarning, match=rf"far_igm\.bil: {said}.*: mapped as no "
                                                      r"position \(a damaged IGM\?\)$"):
        orthorectify(far, made.folder / "seg.bil", made.grid, tmp_path / "o.tif",
                     tmp_path / "o_glt")
    nan = damaged_igm(made, tmp_path, "nan_igm", void)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        orthorectify(nan, made.folder / "seg.bil", made.grid, tmp_path / "n.tif",
                     tmp_path / "n_glt")
    assert (tmp_path / "o_glt.bil").read_bytes() == (tmp_path / "n_glt.bil").read_bytes()
    with rasterio.open(tmp_path / "o.tif") as o, rasterio.open(tmp_path / "n.tif") as n:
        np.testing.assert_array_equal(o.read(), n.read())


@pytest.mark.parametrize("value", [np.inf, -np.inf])
@pytest.mark.parametrize("band", [0, 1])
def test_an_infinite_position_is_refused(made: Made, tmp_path: Path, value: float,
                                         band: int) -> None:
    """The kernels took any value but NaN for a position: 44 cells of the bench run were
    filled from a wrong pixel. NaN is the IGM's 'no position'; an infinity is damage."""
    def damage(xyz: np.ndarray) -> None:
        xyz[200, band, 30] = value
        xyz[201:205, band, 3] = value

    igm = damaged_igm(made, tmp_path, "inf_igm", damage)
    name = ("easting", "northing")[band]
    with pytest.raises(InputError, match=rf"inf_igm\.bil: IGM line 200, pixel 30: {name} "
                                         rf"{value}: not a position \(NaN marks a pixel "
                                         r"without one\): a damaged IGM\?$"):
        orthorectify(igm, made.folder / "seg.bil", made.grid, tmp_path / "o.tif",
                     tmp_path / "o_glt")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["inf_igm.bil", "inf_igm.hdr"]


def test_a_grid_with_no_cell_filled_is_refused_when_asked(made: Made, tmp_path: Path) -> None:
    """An IGM whose lines are all one: `sisa ortho` wrote an ortho of nodata, '0 of 12168
    cells filled ... mean distance nan m', exit 0. With empty_ok=False (the command's), an
    error, nothing left; a grid missing the swath (its bounding box only) is said so."""
    def one_line(xyz: np.ndarray) -> None:
        xyz[:] = xyz[0]

    igm = damaged_igm(made, tmp_path, "same_igm", one_line)
    grid = OrthoGrid.covering(SwathIndex.build(igm).bounds_m, CELL_M, EPSG)
    assert orthorectify(igm, made.folder / "seg.bil", grid, tmp_path / "o.tif",
                        tmp_path / "o_glt").cells_filled == 0  # as before, by default
    for name in ("o.tif", "o_glt.bil", "o_glt.hdr"):
        (tmp_path / name).unlink()
    with pytest.raises(InputError, match=r"same_igm\.bil: no cell of the grid lies between "
                                         r"neighbouring pixels of the IGM: its lines do not "
                                         r"advance \(a damaged IGM\?\)$"):
        orthorectify(igm, made.folder / "seg.bil", grid, tmp_path / "o.tif",
                     tmp_path / "o_glt", empty_ok=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["same_igm.bil", "same_igm.hdr"]
    g = made.grid  # the strip turns: its bounding box's north-west corner holds no swath
    corner = OrthoGrid(g.west_m, g.north_m, g.cell_m, 20, 20, EPSG)
    with pytest.raises(InputError, match=r"^no cell of the grid \(\d+, \d+, \d+, \d+\) lies in "
                                         r"the image's swath: nothing to map$"):
        orthorectify(made.folder / "seg_igm.bil", made.folder / "seg.bil", corner,
                     tmp_path / "c.tif", None, empty_ok=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["same_igm.bil", "same_igm.hdr"]
