"""`sisa ortho` as a user runs it: the products `orthorectify` makes, the grid it picks, one-line
errors with nothing written; and the console entry's exit."""

from __future__ import annotations

import gc
import signal
import subprocess
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rasterio
from rasterio.enums import ColorInterp

from postproc.products import open_igm
from postproc.products.ortho import TIFF_COMPRESSIONS, nice_cell_m
from sisa import cli
from sisa.commands.ortho import COMPRESSIONS
from tests.postproc.test_igm import synthetic_strip
from tests.postproc.test_ortho import Made, make, pair_cut_short


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> Made:
    return make(tmp_path_factory.mktemp("ortho_cli"), synthetic_strip(400, 48))


def sisa_ortho(*args: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "sisa.cli", "ortho", *map(str, args)],
                          capture_output=True, text=True, timeout=120, check=False)


def igm_without_crs(made: Made, folder: Path) -> Path:
    """The IGM again under a header that names no CRS (ENVI files from other tools)."""
    header = (made.folder / "seg_igm.hdr").read_text().splitlines()
    (folder / "nocrs_igm.hdr").write_text("\n".join(
        x for x in header if not x.startswith(("coordinate system", "map info"))))
    (folder / "nocrs_igm.bil").symlink_to(made.folder / "seg_igm.bil")
    return folder / "nocrs_igm.bil"


def test_same_products_as_orthorectify(made: Made, tmp_path: Path) -> None:
    g = made.grid
    out = tmp_path / "again.tif"
    proc = sisa_ortho(made.folder / "seg_igm.bil", made.folder / "seg.bil", "--out", out,
                      "--cell", g.cell_m, "--bounds", g.west_m, g.north_m - g.height * g.cell_m,
                      g.west_m + g.width * g.cell_m, g.north_m)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.count("\n") == 1
    assert f"{made.result.cells_filled} of {made.result.cells} cells filled" in proc.stdout
    with rasterio.open(out) as a, rasterio.open(made.tif) as b:
        assert a.transform == b.transform
        assert a.crs == b.crs
        np.testing.assert_array_equal(a.read(), b.read())
    assert (tmp_path / "again_glt.bil").read_bytes() == made.glt.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["again.tif", "again_glt.bil",
                                                          "again_glt.hdr"]



def test_no_glt_writes_the_same_geotiff_alone(made: Made, tmp_path: Path) -> None:
    g = made.grid
    out = tmp_path / "alone.tif"
    proc = sisa_ortho(made.folder / "seg_igm.bil", made.folder / "seg.bil", "--out", out,
                      "--cell", g.cell_m, "--bounds", g.west_m, g.north_m - g.height * g.cell_m,
                      g.west_m + g.width * g.cell_m, g.north_m, "--no-glt")
    assert proc.returncode == 0, proc.stderr
    assert "no GLT" in proc.stdout
    assert f"{made.result.cells_filled} of {made.result.cells} cells filled" in proc.stdout
    with rasterio.open(out) as a, rasterio.open(made.tif) as b:
        np.testing.assert_array_equal(a.read(), b.read())
    assert [p.name for p in tmp_path.iterdir()] == ["alone.tif"]

@pytest.mark.parametrize("existing", ["seg.tif", "seg_glt.bil", "seg_glt.hdr"])
def test_an_existing_output_is_refused_and_left_alone(made: Made, tmp_path: Path,
                                                      existing: str) -> None:
    """`sisa ortho --out EXISTING.tif` replaced it silently (exit 0) while every other command
    refused (issue 33, item 5): one policy, refuse unless --force."""
    (tmp_path / existing).write_bytes(b"an older product")
    proc = sisa_ortho(made.folder / "seg_igm.bil", made.folder / "seg.bil", "--out",
                      tmp_path / "seg.tif", "--compress", "none")
    assert proc.returncode == 2
    assert proc.stderr == (f"sisa ortho: error: {'--out ' if existing == 'seg.tif' else ''}"
                           f"{tmp_path / existing} already exists: choose a new name (outputs "
                           "are never overwritten; --force replaces it)\n")
    assert [p.name for p in tmp_path.iterdir()] == [existing]
    assert (tmp_path / existing).read_bytes() == b"an older product"


def test_force_replaces_the_products_and_leaves_nothing_beside(made: Made,
                                                               tmp_path: Path) -> None:
    out = tmp_path / "seg.tif"
    for name in ("seg.tif", "seg_glt.bil", "seg_glt.hdr"):
        (tmp_path / name).write_bytes(b"an older product")
    proc = sisa_ortho(made.folder / "seg_igm.bil", made.folder / "seg.bil", "--out", out,
                      "--compress", "none", "--force")
    assert proc.returncode == 0, proc.stderr
    with rasterio.open(out) as o, rasterio.open(made.tif) as ref:
        assert o.count == ref.count
        assert o.read(1).any()
    assert (tmp_path / "seg_glt.bil").stat().st_size > len(b"an older product")
    assert "GLT" in (tmp_path / "seg_glt.hdr").read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seg.tif", "seg_glt.bil",
                                                          "seg_glt.hdr"]


def test_progress_bar_on_a_terminal_only(made: Made, tmp_path: Path) -> None:
    """stderr a terminal: a bar, drawn and cleared; stdout keeps its one summary line."""
    import os
    import pty

    master, slave = pty.openpty()
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "sisa.cli", "ortho", made.folder / "seg_igm.bil",
             made.folder / "seg.bil", "--out", tmp_path / "t.tif"],
            stdout=subprocess.PIPE, stderr=slave, text=True,
            env={**os.environ, "COLUMNS": "100", "TERM": "xterm"})
        os.close(slave)
        shown = b""
        while True:
            try:
                got = os.read(master, 65536)
            except OSError:  # EIO: the child closed the terminal
                break
            if not got:
                break
            shown += got
        out, _ = proc.communicate(timeout=120)
    finally:
        os.close(master)
    assert proc.returncode == 0
    assert out.count("\n") == 1
    assert "cells filled" in out
    assert b"ortho" in shown  # the bar's label
    assert sisa_ortho(made.folder / "seg_igm.bil", made.folder / "seg.bil", "--out",
                      tmp_path / "p.tif").stderr == ""  # not a terminal: nothing


def test_default_grid_is_the_pixel_spacing_over_the_extent(made: Made, tmp_path: Path) -> None:
    out = tmp_path / "auto.tif"
    proc = sisa_ortho(made.folder / "seg_igm.bil", made.folder / "seg.bil", "--out", out,
                      "--compress", "none")
    assert proc.returncode == 0, proc.stderr
    e, n = made.strip.easting_m, made.strip.northing_m
    step = np.hypot(np.diff(e, axis=1), np.diff(n, axis=1))
    cell = nice_cell_m(float(np.median(step[np.isfinite(step)])))
    assert cell != made.grid.cell_m  # the strip's pixels widen towards the edges
    with rasterio.open(out) as o:
        assert o.res == (cell, cell)
        assert o.compression is None
        west, north = o.transform.c, o.transform.f
        assert west <= np.nanmin(e) < west + cell
        assert north - cell < np.nanmax(n) <= north
        assert west / cell == pytest.approx(round(west / cell))


@pytest.mark.parametrize("cut", ["image", "igm"])
def test_a_file_cut_short_gets_the_grid_of_the_lines_mapped(made: Made, tmp_path: Path,
                                                            cut: str) -> None:
    """The default grid covers lines 0-199 of a pair cut mid-line 200, not the header's 400
    (the rest would be nodata); the warning is printed once."""
    igm, image = pair_cut_short(made, tmp_path, cut, 200.5)
    out = tmp_path / "o.tif"
    proc = sisa_ortho(igm, image, "--out", out, "--cell", made.grid.cell_m, "--no-glt")
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.count("\n") == 1
    assert proc.stderr.startswith("sisa ortho: warning:")
    assert "lines 200-399 are not mapped" in proc.stderr
    e = made.strip.easting_m[:200]
    n = made.strip.northing_m[:200]
    cell = made.grid.cell_m
    with rasterio.open(out) as o:
        west, north = o.transform.c, o.transform.f
        south = north - o.height * cell
        assert west <= np.nanmin(e) < west + cell
        assert north - cell < np.nanmax(n) <= north
        assert south <= np.nanmin(n) < south + cell
        assert np.nanmax(made.strip.northing_m) > north + cell  # where the lines left out go


def igm_of_infinities(made: Made, folder: Path) -> Path:
    """The IGM with every easting infinite (as a byte-swapped or foreign file can read)."""
    xyz = np.array(open_igm(made.folder / "seg_igm.bil"))
    xyz[:, 0] = np.inf
    xyz.tofile(folder / "inf_igm.bil")
    (folder / "inf_igm.hdr").write_text((made.folder / "seg_igm.hdr").read_text())
    return folder / "inf_igm.bil"


def test_bad_input_is_one_line_and_writes_nothing(made: Made, tmp_path: Path) -> None:
    igm, image = made.folder / "seg_igm.bil", made.folder / "seg.bil"
    no_crs = igm_without_crs(made, tmp_path)
    inf_igm = igm_of_infinities(made, tmp_path)
    (tmp_path / "taken_glt.hdr").mkdir()
    (tmp_path / "dir.tif").mkdir()
    cases = [
        ((igm, tmp_path / "missing.bil", "--out", tmp_path / "o.tif"), "missing"),
        ((igm, image, "--out", tmp_path / "o.png"), "name the GeoTIFF"),
        ((igm, image, "--out", tmp_path / "no" / "o.tif"), "does not exist"),
        ((igm, image, "--out", tmp_path / "o.tif", "--cell", "-1"), "positive --cell"),
        ((igm, image, "--out", tmp_path / "o.tif", "--crs", "32630"), "EPSG:32631"),
        ((no_crs, image, "--out", tmp_path / "o.tif"), "give --crs"),
        ((image, image, "--out", tmp_path / "o.tif"), "not an IGM"),
        ((igm, image, "--out", tmp_path / "o.tif", "--cell", "1", "--bounds", "0", "0", "1e7",
          "1e7"), "10000000 x 10000000 cells of 1 m is too large"),
        # a sparse GLT of terabytes before anyone noticed; an empty GeoTIFF with exit 0
        ((igm, image, "--out", tmp_path / "o.tif", "--cell", "0.001"), "is too large"),
        # a 300-digit cell count printed in full; an OverflowError's traceback
        ((igm, image, "--out", tmp_path / "o.tif", "--cell", "1e-300"),
         "cells of 1e-300 m is too large"),
        ((igm, image, "--out", tmp_path / "o.tif", "--cell", "5e-324"), "is too large"),
        ((igm, image, "--out", tmp_path / "o.tif", "--bounds", "0", "0", "10", "10"),
         "does not overlap the image's ground"),
        # numpy's RuntimeWarnings on stderr before the error (found by a bad-input sweep)
        ((inf_igm, image, "--out", tmp_path / "o.tif"), "no two neighbouring pixels"),
        # a traceback after the GeoTIFF was in place, the GLT's parts left beside it
        ((igm, image, "--out", tmp_path / "taken.tif"), "taken_glt.hdr already exists"),
        ((igm, image, "--out", tmp_path / "dir.tif"), "dir.tif already exists"),
        # with --force, a folder in the way is still one line, nothing written
        ((igm, image, "--out", tmp_path / "taken.tif", "--force"), "taken_glt.hdr is a folder"),
        ((igm, image, "--out", tmp_path / "dir.tif", "--force"), "dir.tif is a folder"),
    ]
    before = sorted(p.name for p in tmp_path.iterdir())
    for args, says in cases:
        proc = sisa_ortho(*args)
        assert proc.returncode == 2, (args, proc.stderr)
        assert proc.stdout == ""
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1, proc.stderr
        assert lines[0].startswith("sisa ortho: error:"), proc.stderr
        assert says in lines[0], (says, lines[0])
        assert len(lines[0]) < 500, lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_a_one_cell_grid_is_mapped(made: Made, tmp_path: Path) -> None:
    """Was a traceback: numpy gives a one-cell window's cell axis any stride (found by a
    bad-input sweep)."""
    g = made.grid
    with rasterio.open(made.tif) as ds:
        band = ds.read(1)
    row, col = (int(v[len(v) // 2]) for v in np.nonzero(band != ds.nodata))
    west, north = g.west_m + col * g.cell_m, g.north_m - row * g.cell_m
    out = tmp_path / "one.tif"
    proc = sisa_ortho(made.folder / "seg_igm.bil", made.folder / "seg.bil", "--out", out,
                      "--cell", g.cell_m, "--bounds", west, north - g.cell_m, west + g.cell_m,
                      north)
    assert proc.returncode == 0, proc.stderr
    with rasterio.open(out) as one, rasterio.open(made.tif) as whole:
        assert (one.width, one.height) == (1, 1)
        np.testing.assert_array_equal(one.read()[:, 0, 0], whole.read()[:, row, col])


def test_the_igm_without_crs_maps_with_crs_given(made: Made, tmp_path: Path) -> None:
    proc = sisa_ortho(igm_without_crs(made, tmp_path), made.folder / "seg.bil", "--out",
                      tmp_path / "o.tif", "--crs", "32631", "--cell", "2")
    assert proc.returncode == 0, proc.stderr
    with rasterio.open(tmp_path / "o.tif") as o:
        assert o.crs.to_epsg() == 32631
        assert o.res == (2.0, 2.0)


def test_compressions_offered_are_the_writers() -> None:
    assert COMPRESSIONS == TIFF_COMPRESSIONS


def test_console_entry_exits_with_the_code_and_leaves_objects_to_the_process(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """...and ignores a late Ctrl-C or stop while the interpreter shuts down (which would kill
    the process by the signal: `sisa bench` saw its recorder end with -2)."""
    monkeypatch.setattr(sys, "argv", ["sisa", "scenario", "show", "no-such-preset"])
    monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)  # run() sets its own
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with pytest.raises(SystemExit) as done:
            cli.run()
        assert done.value.code == 2
        assert gc.get_freeze_count() > 0
        assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN
        assert signal.getsignal(signal.SIGTERM) == signal.SIG_IGN
    finally:
        gc.unfreeze()
        for s, h in handlers.items():
            signal.signal(s, h)


def test_a_four_band_byte_image_keeps_four_data_bands(made: Made, tmp_path: Path) -> None:
    """GDAL's default made band 4 of a 4-band uint8 GeoTIFF an alpha mask over the data (and
    rasterio then warned on every read of the products: found by a bad-input sweep)."""
    header = [x for x in (made.folder / "seg.hdr").read_text().splitlines()
              if not x.startswith(("wavelength", "band names", "data type", "bands"))]
    (tmp_path / "four.hdr").write_text("\n".join([*header, "data type = 1", "bands = 4"]) + "\n")
    (made.raw[:, :4] % 251).astype(np.uint8).tofile(tmp_path / "four.bil")
    g = made.grid
    proc = sisa_ortho(made.folder / "seg_igm.bil", tmp_path / "four.bil", "--out",
                      tmp_path / "four.tif", "--cell", g.cell_m, "--bounds", *g.bounds_m)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with rasterio.open(tmp_path / "four.tif") as r:
            assert r.count == 4
            assert ColorInterp.alpha not in r.colorinterp
            assert r.read(4, masked=True).count() > 0


def test_a_float_radiance_image_maps_like_its_dn(made: Made, tmp_path: Path) -> None:
    """A calibrated float32 image (no ignore value) with the DN image's IGM: the same choice
    of pixel in every cell, NaN outside the swath, the float predictor."""
    header = (made.folder / "seg.hdr").read_text()
    assert "data type = 12" in header
    (tmp_path / "rad.hdr").write_text("\n".join(
        "data type = 4" if x.startswith("data type") else x for x in header.splitlines()
        if not x.startswith("data ignore value")) + "\n")
    (made.raw.astype("<f4") * np.float32(0.01)).tofile(tmp_path / "rad.bil")
    g = made.grid
    proc = sisa_ortho(made.folder / "seg_igm.bil", tmp_path / "rad.bil", "--out",
                      tmp_path / "rad.tif", "--cell", g.cell_m, "--bounds", *g.bounds_m)
    assert proc.returncode == 0, proc.stderr
    with rasterio.open(tmp_path / "rad.tif") as r:
        assert r.dtypes[0] == "float32"
        assert np.isnan(r.nodata)
        assert r.tags(ns="IMAGE_STRUCTURE")["PREDICTOR"] == "3"
        rad = r.read()
    dn, _ = made.read()
    filled = dn[0] != 0
    np.testing.assert_array_equal(rad[:, filled], dn[:, filled].astype("f4") * np.float32(0.01))
    assert np.isnan(rad[:, ~filled]).all()


def damaged_copy(made: Made, folder: Path, name: str, damage: Any) -> Path:
    """`made`'s IGM with `damage(xyz)` done to its (lines, 3, pixels) values."""
    xyz = np.array(open_igm(made.folder / "seg_igm.bil"))
    damage(xyz)
    xyz.astype("<f8").tofile(folder / f"{name}.bil")
    (folder / f"{name}.hdr").write_text((made.folder / "seg_igm.hdr").read_text())
    return folder / f"{name}.bil"


def _far(xyz: np.ndarray) -> None:
    xyz[10, 1, 10] += 1e5


def _inf(xyz: np.ndarray) -> None:
    xyz[100, 0, 20] = -np.inf


def _one_line(xyz: np.ndarray) -> None:
    xyz[:] = xyz[0]


def test_damaged_inputs_are_one_line_and_write_nothing(made: Made, tmp_path: Path) -> None:
    """Found by a bad-input sweep, each exit 0 before: a far pixel stretched the default grid
    over it (5000 km: 66 s, a 21 GB sparse GLT); an infinite easting was taken for a position
    (cells filled from a wrong pixel); an IGM of one line repeated gave an ortho of nodata
    ('mean distance nan m'); an image header of 1 band for 4 read the file striped."""
    image = made.folder / "seg.bil"
    far = damaged_copy(made, tmp_path, "far_igm", _far)
    inf = damaged_copy(made, tmp_path, "inf_igm", _inf)
    same = damaged_copy(made, tmp_path, "same_igm", _one_line)
    (tmp_path / "one_band.bil").symlink_to(image)
    (tmp_path / "one_band.hdr").write_text(
        (made.folder / "seg.hdr").read_text().replace("bands = 4", "bands = 1"))
    cases = [
        ((far, image), "far_igm.bil: IGM line 10, pixel 10 lies 100 km from the rest of its "
                       "line: a damaged IGM? give --bounds to map it anyway"),
        ((inf, image), "inf_igm.bil: IGM line 100, pixel 20: easting -inf: not a position (NaN "
                       "marks a pixel without one): a damaged IGM?"),
        ((same, image), "same_igm.bil: no cell of the grid lies between neighbouring pixels "
                        "of the IGM: its lines do not advance (a damaged IGM?)"),
        ((made.folder / "seg_igm.bil", tmp_path / "one_band.bil"),
         f"one_band.bil holds {image.stat().st_size} bytes, its header describes "
         f"{image.stat().st_size // 4} (400 lines x 48 samples x 1 bands x 2 bytes + 0 "
         "offset): a header of another file or layout, or damaged?"),
    ]
    before = sorted(p.name for p in tmp_path.iterdir())
    for args, says in cases:
        proc = sisa_ortho(*args, "--out", tmp_path / "o.tif", "--cell", "1")
        assert proc.returncode == 2, (args, proc.stderr)
        assert proc.stdout == ""
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1, proc.stderr
        assert lines[0].startswith("sisa ortho: error:"), proc.stderr
        assert lines[0].endswith(says), (says, lines[0])
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_a_far_pixel_on_a_grid_given_is_mapped_as_none(made: Made, tmp_path: Path) -> None:
    """--bounds: the far pixel falls outside the grid; the cells beside the quads that reached
    it are not filled from its neighbours (a sliver to the grid's edge before); one warning."""
    far = damaged_copy(made, tmp_path, "far_igm", _far)
    g = made.grid
    proc = sisa_ortho(far, made.folder / "seg.bil", "--out", tmp_path / "o.tif", "--cell",
                      g.cell_m, "--bounds", *g.bounds_m, "--no-glt")
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ("sisa ortho: warning: " + str(far) + ": IGM line 10, pixel 10 lies "
                           "100 km from the rest of its line: mapped as no position (a damaged "
                           "IGM?)\n")

    def void(xyz: np.ndarray) -> None:
        xyz[10, :, 10] = np.nan

    nan = damaged_copy(made, tmp_path, "nan_igm", void)
    proc = sisa_ortho(nan, made.folder / "seg.bil", "--out", tmp_path / "n.tif", "--cell",
                      g.cell_m, "--bounds", *g.bounds_m, "--no-glt")
    assert proc.returncode == 0, proc.stderr
    with rasterio.open(tmp_path / "o.tif") as o, rasterio.open(tmp_path / "n.tif") as n:
        np.testing.assert_array_equal(o.read(), n.read())


def test_bands_maps_a_subset_in_the_order_given(made: Made, tmp_path: Path) -> None:
    """`sisa ortho --bands` (issue 33, item 11, as aplmap's band subsets): the GeoTIFF holds
    the bands named, in that order, each exactly as in the whole ortho, with its description."""
    g = made.grid
    bounds = (g.west_m, g.north_m - g.height * g.cell_m, g.west_m + g.width * g.cell_m,
              g.north_m)
    with rasterio.open(made.tif) as ref:
        full, names = ref.read(), ref.descriptions
    assert len(names) >= 2
    wanted = [len(names), 1]  # the last band, then the first
    out = tmp_path / "sub.tif"
    proc = sisa_ortho(made.folder / "seg_igm.bil", made.folder / "seg.bil", "--out", out,
                      "--cell", g.cell_m, "--bounds", *bounds, "--bands",
                      ",".join(map(str, wanted)), "--no-glt")
    assert proc.returncode == 0, proc.stderr
    with rasterio.open(out) as sub:
        assert sub.count == 2
        np.testing.assert_array_equal(sub.read(), full[[b - 1 for b in wanted]])
        assert sub.descriptions == tuple(names[b - 1] for b in wanted)
    for bad, says in ((f"{len(names) + 1}", f"has bands 1 to {len(names)}"),
                      ("0", "band numbers from 1, each once"), ("1,1", "each once"),
                      ("x", "give band numbers from 1")):
        proc = sisa_ortho(made.folder / "seg_igm.bil", made.folder / "seg.bil", "--out",
                          tmp_path / "bad.tif", "--bands", bad)
        assert proc.returncode == 2
        assert says in proc.stderr, proc.stderr
        assert not (tmp_path / "bad.tif").exists()
