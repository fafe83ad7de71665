"""`sisa ortho --resampling`: bilinear and cubic interpolation at each cell centre's position in
the image (issue 33, item 11), checked against the exact position on an IGM that is an affine
map of (line, sample), where the answer is known in closed form."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio

from postproc.products import OrthoGrid, Resampling, SwathIndex, orthorectify
from postproc.products.resample import taps
from sisa.cli import main
from tests.postproc.test_igm import EPSG, Strip, write_igm

LINES, PIXELS = 120, 48
ORIGIN_M = (461_000.0, 4_661_000.0)
HEADING_RAD = np.radians(30.0)
ALONG_M, ACROSS_M = 1.3, 1.0  # line and pixel spacing on the ground
CELL_M = 0.7


def _affine_strip() -> Strip:
    """Pixel-centre ground positions: an affine map of (line, sample), rotated 30°."""
    line, sample = np.mgrid[0:LINES, 0:PIXELS].astype(np.float64)
    fwd = np.array([np.sin(HEADING_RAD), np.cos(HEADING_RAD)])
    right = np.array([np.cos(HEADING_RAD), -np.sin(HEADING_RAD)])
    east = ORIGIN_M[0] + line * ALONG_M * fwd[0] + sample * ACROSS_M * right[0]
    north = ORIGIN_M[1] + line * ALONG_M * fwd[1] + sample * ACROSS_M * right[1]
    return Strip(east, north, np.full(east.shape, 120.0))


def _image_position(east: np.ndarray, north: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(line, sample) of ground points: the affine map above, inverted."""
    de, dn = east - ORIGIN_M[0], north - ORIGIN_M[1]
    line = (de * np.sin(HEADING_RAD) + dn * np.cos(HEADING_RAD)) / ALONG_M
    sample = (de * np.cos(HEADING_RAD) - dn * np.sin(HEADING_RAD)) / ACROSS_M
    return line, sample


def _field(line: np.ndarray, sample: np.ndarray) -> np.ndarray:
    """A smooth image: linear plus a gentle quadratic (cubic convolution reproduces both)."""
    return 100.0 + 2.0 * line + 3.0 * sample + 0.01 * (line - 60.0) ** 2


def _write_float_image(path: Path) -> None:
    line, sample = np.mgrid[0:LINES, 0:PIXELS].astype(np.float64)
    img = np.stack([_field(line, sample), 500.0 - sample], axis=1).astype("<f4")  # (l, b, s)
    img.tofile(path)
    path.with_suffix(".hdr").write_text(
        f"ENVI\nsamples = {PIXELS}\nlines = {LINES}\nbands = 2\nheader offset = 0\n"
        "file type = ENVI Standard\ndata type = 4\ninterleave = bil\nbyte order = 0\n",
        encoding="ascii")


@pytest.fixture(scope="module")
def pair(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, OrthoGrid]:
    folder = tmp_path_factory.mktemp("resampling")
    igm = write_igm(_affine_strip(), folder / "seg_igm")
    image = folder / "seg.bil"
    _write_float_image(image)
    grid = OrthoGrid.covering(SwathIndex.build(igm).bounds_m, CELL_M, EPSG)
    return igm, image, grid


def _ortho(pair: tuple[Path, Path, OrthoGrid], method: Resampling, out: Path
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    igm, image, grid = pair
    orthorectify(igm, image, grid, out, out.with_name(out.stem + "_glt"), resampling=method)
    with rasterio.open(out) as ds:
        values = ds.read(1).astype(np.float64)
        filled = ds.read_masks(1) > 0
        t = ds.transform
        rows, cols = np.mgrid[0:ds.height, 0:ds.width] + 0.5  # cell centres
    line, sample = _image_position(t.c + cols * t.a, t.f + rows * t.e)
    return values, line, sample, filled


@pytest.mark.parametrize(("method", "tolerance"), [(Resampling.BILINEAR, 0.01),
                                                   (Resampling.CUBIC, 2e-4)])
def test_interpolation_lands_on_the_cell_centres_image_position(
        pair: tuple[Path, Path, OrthoGrid], tmp_path: Path, method: Resampling,
        tolerance: float) -> None:
    values, line, sample, filled = _ortho(pair, method, tmp_path / f"{method}.tif")
    inner = filled & (line > 2) & (line < LINES - 3) & (sample > 2) & (sample < PIXELS - 3)
    assert inner.sum() > 5000
    # bilinear is exact for the linear part; its error on the quadratic is ≤ 0.01·(1/4)²·... ≈ 0.003
    error = np.abs(values[inner] - _field(line[inner], sample[inner]))
    assert error.max() < tolerance, error.max()


def test_nearest_is_off_by_up_to_half_a_pixel_and_unchanged(
        pair: tuple[Path, Path, OrthoGrid], tmp_path: Path) -> None:
    """The default keeps each cell's nearest pixel (radiometry untouched): off the exact
    position by up to half a pixel, which interpolation removes."""
    values, line, sample, filled = _ortho(pair, Resampling.NEAREST, tmp_path / "n.tif")
    inner = filled & (line > 2) & (line < LINES - 3) & (sample > 2) & (sample < PIXELS - 3)
    nearest = _field(np.rint(line[inner]), np.rint(sample[inner]))
    assert np.abs(values[inner] - nearest).max() < 1e-3  # the nearest pixel's own value
    assert np.abs(values[inner] - _field(line[inner], sample[inner])).max() > 0.5


def test_glt_is_the_same_for_every_method(pair: tuple[Path, Path, OrthoGrid],
                                          tmp_path: Path) -> None:
    gl = {}
    for method in Resampling:
        out = tmp_path / f"{method}.tif"
        _ortho(pair, method, out)
        with rasterio.open(tmp_path / f"{method}_glt.bil") as ds:
            gl[method] = ds.read()
    assert np.array_equal(gl[Resampling.NEAREST], gl[Resampling.BILINEAR])
    assert np.array_equal(gl[Resampling.NEAREST], gl[Resampling.CUBIC])


@pytest.mark.parametrize("method", [Resampling.BILINEAR, Resampling.CUBIC])
def test_weights_sum_to_one_and_reproduce_a_ramp(method: Resampling) -> None:
    position = np.linspace(3.0, 4.0, 101)
    base, weights = taps(method, position)
    assert np.allclose(sum(weights), 1.0)
    ramp = sum(w * (base + k) for k, w in enumerate(weights))
    assert np.allclose(ramp, position)


def test_cli_resampling_and_refusal(pair: tuple[Path, Path, OrthoGrid], tmp_path: Path,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    igm, image, _ = pair
    out = tmp_path / "c.tif"
    assert main(["ortho", str(igm), str(image), "--cell", "1", "--resampling", "cubic",
                 "--out", str(out)]) == 0
    with rasterio.open(out) as ds:
        assert "interpolated (cubic)" in ds.tags()["TIFFTAG_IMAGEDESCRIPTION"]
    with pytest.raises(SystemExit) as bad:
        main(["ortho", str(igm), str(image), "--resampling", "lanczos", "--out",
              str(tmp_path / "x.tif")])
    assert bad.value.code == 2
    assert "--resampling: invalid choice: 'lanczos'" in capsys.readouterr().err
    assert not (tmp_path / "x.tif").exists()


@pytest.mark.parametrize("method", [Resampling.BILINEAR, Resampling.CUBIC])
def test_a_turbulent_strip_with_voids_mixes_in_no_nodata(tmp_path: Path,
                                                         method: Resampling) -> None:
    """Crossing lines, a DEM miss (no positions) and the scanner's ignore value 0: a constant
    band stays that constant in every filled cell (nothing mixed in from outside the image or
    from ignored pixels), integer values stay integers of the image's type."""
    from tests.postproc.test_igm import synthetic_strip, write_raw

    strip = synthetic_strip(300, 40)
    igm = write_igm(strip, tmp_path / "t_igm")
    raw = write_raw(tmp_path / "t.bil", *strip.shape, marker=7)
    raw_path = tmp_path / "t.bil"
    # a run of ignored pixels (0) inside the image
    img = np.fromfile(raw_path, "<u2").reshape(raw.shape)
    img[150:153, 2, 10:20] = 0
    img.tofile(raw_path)
    grid = OrthoGrid.covering(SwathIndex.build(igm).bounds_m, 1.0, EPSG)
    out = tmp_path / "t.tif"
    orthorectify(igm, raw_path, grid, out, None, resampling=method)
    with rasterio.open(out) as ds:
        assert ds.dtypes[0] == "uint16"
        marker, filled = ds.read(3), ds.read_masks(1) > 0
    assert filled.sum() > 8000
    assert set(np.unique(marker[filled]).tolist()) <= {0, 7}  # 0 only where the pixel was 0
    assert (marker[filled] == 0).sum() <= 3 * 10 * 2  # the ignored pixels' own cells
