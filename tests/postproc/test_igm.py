"""IGM files: round trip through GDAL, all-or-nothing writes, and `gdalwarp -geoloc` on the
geolocation VRT landing every cell on a pixel centred near it (no half-pixel shift)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import rasterio
from pyproj import CRS
from rasterio.errors import NotGeoreferencedWarning

from postproc.products import OrthoGrid
from postproc.products.igm import (
    IGM_BAND_NAMES,
    EnviRaster,
    IgmWriter,
    igm_epsg,
    open_igm,
    replace_file,
    write_geolocation_vrt,
)
from sisa.core.errors import InputError

EPSG = 32631  # UTM 31N (Garrotxa, Bellmunt)
GDALWARP = shutil.which("gdalwarp")
GDALINFO = shutil.which("gdalinfo")
pytestmark = pytest.mark.filterwarnings("ignore", category=NotGeoreferencedWarning)


@dataclass(frozen=True)
class Strip:
    """A synthetic segment: pixel-centre positions (lines, pixels) and its raw image."""

    easting_m: np.ndarray
    northing_m: np.ndarray
    height_m: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return self.easting_m.shape


def synthetic_strip(lines: int, pixels: int, *, spacing_m: float = 1.0, along_m: float = 1.0,
                    heading_deg: float = 30.0, turn_deg: float = 12.0, jitter_m: float = 0.35,
                    yaw_deg: float = 1.5, surge_m: float = 0.2, smooth_lines: int = 1,
                    origin_m: tuple[float, float] = (461_000.0, 4_661_000.0),
                    miss: bool = True, seed: int = 1) -> Strip:
    """A gently turning strip flown at `heading_deg` (clockwise from grid north), with
    turbulence (sideways, yaw and along-track jitter; yaw and surge low-passed over
    `smooth_lines`: with 1 they are white from line to line, harsher than any aircraft, so
    lines cross), wider pixels towards the edges, and a DEM miss (NaN) at one edge for a run
    of lines. Pixel 0 is on the right of the flight direction."""
    rng = np.random.default_rng(seed)
    s = np.arange(lines) * along_m
    heading = np.radians(heading_deg + turn_deg * s / max(s[-1], 1.0))
    east_c = origin_m[0] + np.cumsum(np.sin(heading)) * along_m
    north_c = origin_m[1] + np.cumsum(np.cos(heading)) * along_m
    lateral = jitter_m * _noise(rng, lines, 9)
    yaw = heading + np.radians(yaw_deg) * _noise(rng, lines, smooth_lines)
    surge = surge_m * _noise(rng, lines, smooth_lines)
    c = (pixels - 1) / 2
    q = (c - np.arange(pixels)) / max(c, 1.0)
    across = (c - np.arange(pixels)) * spacing_m * (1 + 0.1 * q**2)  # metres to the right
    right_e, right_n = np.cos(yaw)[:, None], -np.sin(yaw)[:, None]
    fwd_e, fwd_n = np.sin(heading)[:, None], np.cos(heading)[:, None]
    off = across[None, :] + lateral[:, None]
    east = east_c[:, None] + off * right_e + surge[:, None] * fwd_e
    north = north_c[:, None] + off * right_n + surge[:, None] * fwd_n
    height = 120.0 + 5.0 * np.sin(east / 50.0) + 3.0 * np.cos(north / 40.0)
    if miss:
        lo = lines // 3
        east[lo:lo + 12, -4:] = np.nan
        north[lo:lo + 12, -4:] = np.nan
        height[lo:lo + 12, -4:] = np.nan
    return Strip(east, north, height)


def _noise(rng: np.random.Generator, n: int, smooth: int) -> np.ndarray:
    """Unit-variance noise, low-passed over `smooth` samples."""
    x = np.convolve(rng.normal(size=n + smooth - 1), np.ones(smooth), mode="valid")
    return x / x.std()


def write_igm(strip: Strip, stem: Path, epsg: int = EPSG, block: int = 97) -> Path:
    lines, pixels = strip.shape
    with IgmWriter(stem, lines, pixels, epsg) as w:
        for lo in range(0, lines, block):
            w.write_block(lo, strip.easting_m[lo:lo + block], strip.northing_m[lo:lo + block],
                          strip.height_m[lo:lo + block])
    return Path(f"{stem}.bil")


WAVELENGTHS_NM = (460.0, 550.0, 640.0, 850.0)


def write_raw(path: Path, lines: int, pixels: int, *, marker: int = 7,
              wavelengths_nm: tuple[float, ...] = WAVELENGTHS_NM,
              names_with_nm: bool = True) -> np.ndarray:
    """An ENVI BIL uint16 image as the scanner writes it; band 1 = line + 1, band 2 =
    pixel + 1 (so any resampler's choice can be decoded), band 3 = `marker`, others texture."""
    bands = len(wavelengths_nm)
    i, j = np.mgrid[0:lines, 0:pixels]
    img = np.empty((lines, bands, pixels), dtype=np.uint16)
    img[:, 0], img[:, 1] = i + 1, j + 1
    if bands > 2:
        img[:, 2] = marker
    for b in range(3, bands):
        img[:, b] = 1000 + (37 * i + 11 * j * b) % 900
    img.astype("<u2").tofile(path)
    names = ", ".join(f"band {b + 1} ({w:.1f} nm)" if names_with_nm else f"band {b + 1}"
                      for b, w in enumerate(wavelengths_nm))
    path.with_suffix(".hdr").write_text(
        "ENVI\ndescription = {synthetic segment}\n"
        f"samples = {pixels}\nlines = {lines}\nbands = {bands}\nheader offset = 0\n"
        "file type = ENVI Standard\ndata type = 12\ninterleave = bil\nbyte order = 0\n"
        "data ignore value = 0\nwavelength units = Nanometers\n"
        "wavelength = {" + ", ".join(f"{w:.2f}" for w in wavelengths_nm) + "}\n"
        "band names = {" + names + "}\n", encoding="ascii")
    return img


def gdal_ok(path: Path) -> None:
    assert GDALINFO is not None, "gdalinfo (GDAL command-line tools) is needed"
    proc = subprocess.run([GDALINFO, str(path)], capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stderr


# -- round trip --------------------------------------------------------------------------------

def test_igm_round_trip_through_gdal(tmp_path: Path) -> None:
    strip = synthetic_strip(250, 40)
    path = write_igm(strip, tmp_path / "seg_igm")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seg_igm.bil", "seg_igm.hdr"]
    gdal_ok(path)
    with rasterio.open(path) as ds:
        assert (ds.count, ds.height, ds.width) == (3, 250, 40)
        assert ds.dtypes == ("float64",) * 3
        assert ds.descriptions == IGM_BAND_NAMES
        assert all(np.isnan(v) for v in ds.nodatavals)
        for band, want in enumerate((strip.easting_m, strip.northing_m, strip.height_m), 1):
            np.testing.assert_array_equal(ds.read(band), want)
        envi = ds.tags(ns="ENVI")
        assert CRS.from_wkt(envi["coordinate_system_string"].strip("{}")).to_epsg() == EPSG
        assert "CENTRE" in envi["description"]
        assert "ellipsoidal" in envi["description"]
    assert igm_epsg(path) == EPSG
    mm = open_igm(path)
    assert mm.shape == (250, 3, 40)
    np.testing.assert_array_equal(mm[:, 1], strip.northing_m)


@pytest.mark.parametrize("epsg", [EPSG, 25831, 2154])
def test_gdal_reads_the_crs_of_the_igm(tmp_path: Path, epsg: int) -> None:
    """Issue 33, item 10: the IGM header had no `map info`, and GDAL reads an ENVI header's
    `coordinate system string` only with one: gdalinfo showed no CRS. An "Arbitrary" map info
    (the raster is the image's grid) gives GDAL the CRS of the coordinates in the bands."""
    strip = synthetic_strip(20, 8)
    path = write_igm(strip, tmp_path / "seg_igm", epsg=epsg)
    assert "map info = {Arbitrary, " in path.with_suffix(".hdr").read_text()
    with rasterio.open(path) as ds:
        assert ds.crs is not None
        assert ds.crs.to_epsg() == epsg
    proc = subprocess.run([GDALINFO, str(path)], capture_output=True, text=True, check=True)
    assert "Coordinate System is:\n" in proc.stdout
    assert f'ID["EPSG",{epsg}]]' in proc.stdout


def test_pixel_with_any_bad_coordinate_is_all_nan(tmp_path: Path) -> None:
    e = np.full((2, 3), 450_000.0)
    n = np.full((2, 3), 4_650_000.0)
    h = np.full((2, 3), 100.0)
    h[1, 2] = np.inf
    with IgmWriter(tmp_path / "x", 2, 3, EPSG) as w:
        w.write_block(0, e, n, h)
    igm = open_igm(tmp_path / "x.bil")
    assert np.isnan(igm[1, :, 2]).all()
    assert np.isfinite(igm[0]).all()
    assert np.isfinite(igm[1, :, :2]).all()


def test_failed_or_short_write_leaves_nothing(tmp_path: Path) -> None:
    e = np.zeros((5, 4)) + 450_000.0
    def fail_midway() -> None:
        with IgmWriter(tmp_path / "a", 10, 4, EPSG) as w:
            w.write_block(0, e, e, e)
            raise RuntimeError("disk on fire")

    with pytest.raises(RuntimeError):
        fail_midway()
    with pytest.raises(InputError, match="only 5 of 10 lines"), \
            IgmWriter(tmp_path / "b", 10, 4, EPSG) as w:
        w.write_block(0, e, e, e)
    assert list(tmp_path.iterdir()) == []


def test_replace_file_sets_the_old_file_aside_and_restores_it_on_failure(
        tmp_path: Path) -> None:
    final, tmp = tmp_path / "p.bil", tmp_path / ".p.bil.partial"
    final.write_bytes(b"old")
    tmp.write_bytes(b"new")
    replace_file(tmp, final)
    assert final.read_bytes() == b"new"
    assert [p.name for p in tmp_path.iterdir()] == ["p.bil"]
    with pytest.raises(FileNotFoundError):  # nothing to move in: the old file stays
        replace_file(tmp, final)
    assert final.read_bytes() == b"new"
    assert [p.name for p in tmp_path.iterdir()] == ["p.bil"]
    replace_file(final, tmp_path / "q.bil")  # nothing in the way
    assert (tmp_path / "q.bil").read_bytes() == b"new"
    folder = tmp_path / "d.bil"
    (folder / "inside").mkdir(parents=True)
    with pytest.raises(IsADirectoryError):  # a folder in the way is an error, and left alone
        replace_file(tmp_path / "q.bil", folder)
    assert (folder / "inside").is_dir()
    assert (tmp_path / "q.bil").read_bytes() == b"new"


def test_blocks_must_follow_each_other(tmp_path: Path) -> None:
    e = np.zeros((5, 4)) + 450_000.0
    w = IgmWriter(tmp_path / "a", 10, 4, EPSG)
    w.write_block(0, e, e, e)
    with pytest.raises(InputError, match="expected 5"):
        w.write_block(6, e, e, e)
    with pytest.raises(InputError, match="expected"):
        w.write_block(5, e[:, :3], e[:, :3], e[:, :3])
    w.abort()
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(InputError, match="not a projected CRS"):
        IgmWriter(tmp_path / "c", 1, 1, 4326)


# -- gdalwarp -geoloc on the VRT ---------------------------------------------------------------

def _warp_offsets(vrt: Path, strip: Strip, grid: OrthoGrid, cwd: Path) -> np.ndarray:
    """(cells, 2) east/north offset: ground position of the pixel gdalwarp chose − centre."""
    assert GDALWARP is not None, "gdalwarp (GDAL command-line tools) is needed"
    out = cwd / f"warp_{vrt.stem}.tif"
    w, s, e, n = grid.bounds_m
    proc = subprocess.run(
        [GDALWARP, "-q", "-overwrite", "-geoloc", "-r", "near", "-t_srs", f"EPSG:{grid.epsg}",
         "-te", repr(w), repr(s), repr(e), repr(n), "-tr", repr(grid.cell_m), repr(grid.cell_m),
         str(vrt), str(out)], cwd=cwd, capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stderr
    with rasterio.open(out) as ds:
        assert ds.transform == grid.transform
        line1, pix1 = ds.read(1).astype(np.int64), ds.read(2).astype(np.int64)
    rows, cols = np.nonzero((line1 > 0) & (pix1 > 0))
    li, pj = line1[rows, cols] - 1, pix1[rows, cols] - 1
    de = strip.easting_m[li, pj] - grid.centre_x_m(cols)
    dn = strip.northing_m[li, pj] - grid.centre_y_m(rows)
    return np.stack([de, dn], axis=1)


def test_gdalwarp_geoloc_lands_on_pixel_centres(tmp_path: Path) -> None:
    # GDAL inverts the geolocation arrays approximately: strong line-to-line jitter makes its
    # nearest pixel wander (up to 1.9 cells here with yaw 1.5°); keep the turbulence mild.
    strip = synthetic_strip(300, 48, miss=False, yaw_deg=0.3, surge_m=0.05)
    work = tmp_path / "made_here"
    work.mkdir()
    igm = write_igm(strip, work / "seg_igm")
    write_raw(work / "seg.bil", *strip.shape)
    write_geolocation_vrt(work / "seg_geoloc.vrt", work / "seg.bil", igm, EPSG)
    moved = tmp_path / "moved" / "elsewhere"
    shutil.move(work, moved)  # relative paths: the folder can move
    elsewhere = tmp_path / "cwd"
    elsewhere.mkdir()
    grid = OrthoGrid.covering((np.nanmin(strip.easting_m), np.nanmin(strip.northing_m),
                               np.nanmax(strip.easting_m), np.nanmax(strip.northing_m)), 1.0,
                              EPSG)
    off = _warp_offsets(moved / "seg_geoloc.vrt", strip, grid, elsewhere)
    assert off.shape[0] > 0.8 * 300 * 48  # the swath is covered
    assert np.abs(off).max() <= 1.0  # within one cell of the centre, east and north
    assert np.hypot(*off.mean(axis=0)) < 0.05  # and no systematic (half-pixel) shift

    # The same warp with the pixel-corner convention is shifted by about half a pixel in
    # both directions: the test above would catch a convention error.
    text = (moved / "seg_geoloc.vrt").read_text()
    assert "PIXEL_CENTER" in text
    corner = moved / "corner.vrt"
    corner.write_text(text.replace("PIXEL_CENTER", "TOP_LEFT_CORNER"))
    off_c = _warp_offsets(corner, strip, grid, elsewhere)
    assert np.hypot(*off_c.mean(axis=0)) > 0.4


@pytest.mark.parametrize("names_with_nm", [True, False])
def test_vrt_band_descriptions_say_the_wavelength_once(tmp_path: Path,
                                                       names_with_nm: bool) -> None:
    """Issue 33, item 10: the VRT took GDAL's description of an ENVI band, which appends the
    wavelength to the header's band name: "band 1 (495.0 nm) (495.00 Nanometers)". It now
    says it once, as the ortho GeoTIFF does, whether the header's names hold it or not."""
    igm = write_igm(synthetic_strip(30, 8), tmp_path / "igm")
    write_raw(tmp_path / "img.bil", 30, 8, names_with_nm=names_with_nm)
    write_geolocation_vrt(tmp_path / "v.vrt", tmp_path / "img.bil", igm, EPSG)
    want = tuple(f"band {b + 1} ({w:.1f} nm)" for b, w in enumerate(WAVELENGTHS_NM))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(tmp_path / "v.vrt") as ds:
            assert ds.descriptions == want


def test_vrt_refuses_mismatched_igm(tmp_path: Path) -> None:
    strip = synthetic_strip(30, 8)
    igm = write_igm(strip, tmp_path / "igm")
    write_raw(tmp_path / "img.bil", 31, 8)
    with pytest.raises(InputError, match="IGM is 30 x 8"):
        write_geolocation_vrt(tmp_path / "v.vrt", tmp_path / "img.bil", igm, EPSG)
    assert not (tmp_path / "v.vrt").exists()


@pytest.mark.parametrize("interleave", ["bil", "bip"])
def test_a_raster_cut_mid_line_keeps_its_whole_lines(tmp_path: Path, interleave: str) -> None:
    """A line-interleaved file shorter than its header: the lines before the cut are read
    as written, the header's count is kept apart (callers say what is missing)."""
    img = write_raw(tmp_path / "a.bil", 40, 9)
    if interleave == "bip":
        img.transpose(0, 2, 1).astype("<u2").tofile(tmp_path / "a.bil")
        hdr = tmp_path / "a.hdr"
        hdr.write_text(hdr.read_text().replace("interleave = bil", "interleave = bip"))
    line_bytes = img.shape[1] * img.shape[2] * 2
    os.truncate(tmp_path / "a.bil", 17 * line_bytes + 5)
    raw = EnviRaster.open(tmp_path / "a.bil")
    assert (raw.lines, raw.header_lines, raw.cut_short) == (17, 40, True)
    np.testing.assert_array_equal(raw.read_lines(0, 17), img[:17])
    with pytest.raises(InputError, match=r"lines \[0, 18\) outside 0\.\.17"):
        raw.read_lines(0, 18)
    write_raw(tmp_path / "whole.bil", 40, 9)
    whole = EnviRaster.open(tmp_path / "whole.bil")
    assert (whole.lines, whole.header_lines, whole.cut_short) == (40, 40, False)


@pytest.mark.parametrize(("interleave", "size"), [("bsq", 17 * 9 * 2 * 5), ("bil", 10)])
def test_a_cut_raster_without_a_whole_line_or_in_bands_is_refused(
        tmp_path: Path, interleave: str, size: int) -> None:
    """BSQ cut short has every band incomplete; a BIL shorter than one line has nothing."""
    write_raw(tmp_path / "a.bil", 40, 9)
    hdr = tmp_path / "a.hdr"
    hdr.write_text(hdr.read_text().replace("interleave = bil", f"interleave = {interleave}"))
    os.truncate(tmp_path / "a.bil", size)
    with pytest.raises(InputError, match=r"a\.bil: truncated: \d+ bytes, the header needs"):
        EnviRaster.open(tmp_path / "a.bil")


@pytest.mark.parametrize("offset", ["abc", "nan", "1.5", "1e400"])
def test_a_header_offset_that_is_not_a_whole_number_of_bytes_is_named(
        tmp_path: Path, offset: str) -> None:
    """Were tracebacks (float('abc'), int(nan)), or a guess (1.5 read as 1): found by a
    bad-input sweep of `sisa ortho`."""
    write_raw(tmp_path / "a.bil", 40, 9)
    hdr = tmp_path / "a.hdr"
    hdr.write_text(hdr.read_text().replace("header offset = 0", f"header offset = {offset}"))
    with pytest.raises(InputError, match=rf"a\.bil: ENVI header offset '{re.escape(offset)}' "
                                         "is not a whole number of bytes"):
        EnviRaster.open(tmp_path / "a.bil")


def test_a_header_without_a_data_type_is_refused(tmp_path: Path) -> None:
    """GDAL reads such a file as bytes: a uint16 image was mapped as two bytes a pixel (found
    by a bad-input sweep of `sisa ortho`)."""
    write_raw(tmp_path / "a.bil", 40, 9)
    hdr = tmp_path / "a.hdr"
    text = hdr.read_text()
    assert "data type = " in text
    hdr.write_text("\n".join(line for line in text.splitlines()
                             if not line.startswith("data type")) + "\n")
    with pytest.raises(InputError, match=r"a\.bil: the ENVI header gives no data type"):
        EnviRaster.open(tmp_path / "a.bil")
