"""Strip registration: a known sub-cell shift between two GeoTIFFs is measured back."""

import numpy as np
import pytest
import rasterio

from postproc.georef.registration import register_strips, tile_shift
from tests.postproc.test_dem import north_up


def _texture(shape, seed=3):
    rng = np.random.default_rng(seed)
    spec = np.fft.fft2(rng.normal(size=shape))
    fy = np.fft.fftfreq(shape[0])[:, None]
    fx = np.fft.fftfreq(shape[1])[None, :]
    spec /= np.maximum(np.hypot(fx, fy), 1.0 / max(shape)) ** 1.2
    return spec


def _shifted(spec, dx_cells, dy_cells):
    """The texture moved dx east, dy north (rows run south)."""
    fy = np.fft.fftfreq(spec.shape[0])[:, None]
    fx = np.fft.fftfreq(spec.shape[1])[None, :]
    phase = np.exp(-2j * np.pi * (fx * dx_cells + fy * (-dy_cells)))
    return np.real(np.fft.ifft2(spec * phase))


def _write(path, img, west, north, cell, nodata_cols=0):
    data = np.clip(1000 + 200 * img / img.std(), 1, 65535).astype(np.uint16)
    if nodata_cols:
        data[:, :nodata_cols] = 0
    with rasterio.open(path, "w", driver="GTiff", width=data.shape[1], height=data.shape[0],
                       count=1, dtype="uint16", crs="EPSG:32631", nodata=0,
                       transform=north_up(west, north, cell, cell)) as ds:
        ds.write(data, 1)


@pytest.mark.parametrize(("dx", "dy"), [(0.0, 0.0), (0.3, -0.2), (1.4, 0.7), (-2.25, 1.1)])
def test_tile_shift_recovers_known_shifts(dx, dy):
    spec = _texture((96, 96))
    a = _shifted(spec, 0.0, 0.0)
    b = _shifted(spec, dx, dy)
    got = tile_shift(a, b)
    assert got is not None
    assert got[0] == pytest.approx(dx, abs=0.05)
    assert got[1] == pytest.approx(dy, abs=0.05)


def test_register_strips_on_partly_overlapping_geotiffs(tmp_path):
    cell = 2.0
    spec = _texture((400, 700), seed=5)
    full_a = _shifted(spec, 0.0, 0.0)
    full_b = _shifted(spec, 0.6, -0.4)
    # a covers columns 0..499, b columns 200..699 of the same scene; b has a nodata edge
    _write(tmp_path / "a.tif", full_a[:, :500], 500_000.0, 4_600_000.0, cell)
    _write(tmp_path / "b.tif", full_b[:, 200:], 500_000.0 + 200 * cell, 4_600_000.0, cell,
           nodata_cols=20)
    reg = register_strips(tmp_path / "a.tif", tmp_path / "b.tif")
    assert reg is not None
    assert reg.tiles >= 4
    assert reg.dx_cells == pytest.approx(0.6, abs=0.05)
    assert reg.dy_cells == pytest.approx(-0.4, abs=0.05)


def test_no_overlap_gives_none(tmp_path):
    spec = _texture((200, 200))
    img = _shifted(spec, 0, 0)
    _write(tmp_path / "a.tif", img, 500_000.0, 4_600_000.0, 2.0)
    _write(tmp_path / "b.tif", img, 510_000.0, 4_600_000.0, 2.0)
    assert register_strips(tmp_path / "a.tif", tmp_path / "b.tif") is None
