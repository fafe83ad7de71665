"""PNG quicklooks of an ortho GeoTIFF or a raw ENVI segment.

True colour from the bands nearest 640/550/460 nm (wavelengths from the bands' `wavelength`
metadata, which GDAL reads from the ENVI header and SISA writes into its GeoTIFFs, else from
"(… nm)" in the band descriptions), a 2–98 % stretch per band over valid pixels, nodata
transparent. The raster is read decimated (GDAL reads only the lines and blocks it needs), so
a quicklook of a 10 GB segment stays small in memory.
"""

from __future__ import annotations

import os
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt
import rasterio
from rasterio.enums import Resampling
from rasterio.errors import NotGeoreferencedWarning, RasterioIOError
from rasterio.windows import from_bounds

from sisa.core.errors import InputError
from sisa.core.outdir import create_partial

U8 = npt.NDArray[np.uint8]

RGB_NM: Final = (640.0, 550.0, 460.0)
STRETCH_PCT: Final = (2.0, 98.0)
MAX_SIZE_PX: Final = 1024
_NM_IN_TEXT: Final = re.compile(r"([0-9]+(?:\.[0-9]*)?)\s*(nm|nanometers)\b", re.IGNORECASE)


def band_wavelengths_nm(ds: Any) -> list[float | None]:
    """Per band: `wavelength` metadata (nm, or µm if the units say so), else "(x nm)" in the
    description, else None."""
    out: list[float | None] = []
    for b in range(1, ds.count + 1):
        tags = ds.tags(b)
        units = tags.get("wavelength_units", ds.tags().get("wavelength_units", "nm")).lower()
        try:
            wl: float | None = float(tags["wavelength"]) * (1e3 if units.startswith("micro")
                                                            else 1.0)
        except (KeyError, ValueError):
            m = _NM_IN_TEXT.search(ds.descriptions[b - 1] or "")
            wl = float(m.group(1)) if m else None
        out.append(wl)
    return out


def rgb_bands(wavelengths_nm: Sequence[float | None]) -> tuple[int, int, int]:
    """1-based bands nearest 640, 550, 460 nm; without wavelengths bands 1, 2, 3 (or the one
    band three times)."""
    n = len(wavelengths_nm)
    known = [(b + 1, w) for b, w in enumerate(wavelengths_nm) if w is not None]
    if known and n >= 3:

        def nearest(target_nm: float) -> int:
            return min(known, key=lambda bw: abs(bw[1] - target_nm))[0]

        return nearest(RGB_NM[0]), nearest(RGB_NM[1]), nearest(RGB_NM[2])
    return (1, 2, 3) if n >= 3 else (1, 1, 1)


def stretch(values: npt.NDArray[Any], valid: npt.NDArray[np.bool_]) -> U8:
    """2–98 % of the valid values onto 0–255."""
    if not valid.any():
        return np.zeros(values.shape, dtype=np.uint8)
    lo, hi = np.percentile(values[valid].astype(np.float64), STRETCH_PCT)
    hi = hi if hi > lo else lo + 1.0
    scaled = (values.astype(np.float64) - lo) * (255.0 / (hi - lo))
    out: U8 = np.clip(np.rint(scaled), 0, 255).astype(np.uint8)
    return out


@dataclass(frozen=True)
class RgbView:
    """A raster's true-colour view as the quicklook draws it, and what it shows."""

    rgba: U8  # (4, rows, cols), alpha 0 on nodata
    bands: tuple[int, int, int]  # 1-based bands shown as red, green, blue
    wavelengths_nm: tuple[float | None, float | None, float | None]  # of those bands
    descriptions: tuple[str, str, str]  # of those bands
    bounds: tuple[float, float, float, float] | None  # west, south, east, north (None: no map)
    epsg: int | None


def read_rgb(src: Path, *, max_size_px: int = MAX_SIZE_PX,
             bounds: tuple[float, float, float, float] | None = None) -> RgbView:
    """The true-colour view of a raster, longest side ≤ max_size_px (read decimated); of the
    map window `bounds` (west, south, east, north, outside the raster: nodata) if given."""
    src = Path(src)
    if max_size_px < 1:
        raise InputError(f"quicklook size must be at least 1 pixel, got {max_size_px}")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(src) as ds:  # no GDAL_CACHEMAX Env: it made this read 300x slower
                wavelengths = band_wavelengths_nm(ds)
                bands = rgb_bands(wavelengths)
                win = None if bounds is None else from_bounds(
                    *bounds, transform=ds.transform).round_offsets().round_lengths()
                height, width = (ds.height, ds.width) if win is None else (
                    int(win.height), int(win.width))
                scale = max(height, width) / max_size_px
                shape = (max(1, round(height / max(scale, 1.0))),
                         max(1, round(width / max(scale, 1.0))))
                data = ds.read(list(bands), out_shape=(3, *shape), window=win,
                               boundless=win is not None, resampling=Resampling.nearest,
                               masked=True)
                mapped = ds.crs is not None and not ds.transform.is_identity
                if mapped:
                    bounds = tuple(ds.bounds if win is None else ds.window_bounds(win))
                epsg = ds.crs.to_epsg() if mapped else None
                descriptions = tuple(ds.descriptions[b - 1] or f"band {b}" for b in bands)
    except RasterioIOError as exc:
        raise InputError(f"{src}: unreadable raster: {exc}") from None
    mask = np.asarray(np.ma.getmaskarray(data).any(axis=0), dtype=np.bool_)
    if np.issubdtype(data.dtype, np.floating):
        mask |= ~np.isfinite(np.ma.getdata(data)).all(axis=0)
    valid = ~mask
    rgba = np.empty((4, *shape), dtype=np.uint8)
    for k in range(3):
        rgba[k] = stretch(np.ma.getdata(data[k]), valid)
    rgba[3] = np.where(valid, 255, 0)
    r, g, b = (wavelengths[i - 1] for i in bands)
    d0, d1, d2 = descriptions
    return RgbView(rgba, bands, (r, g, b), (d0, d1, d2),
                   (bounds[0], bounds[1], bounds[2], bounds[3]) if mapped and bounds else None,
                   None if epsg is None else int(epsg))


def write_quicklook(src: Path, png: Path, *, max_size_px: int = MAX_SIZE_PX) -> tuple[int, int]:
    """Write an RGBA PNG, longest side ≤ max_size_px; returns its (height, width)."""
    view = read_rgb(src, max_size_px=max_size_px)
    _write_png(Path(png), view.rgba)
    return int(view.rgba.shape[1]), int(view.rgba.shape[2])


def _write_png(png: Path, rgba: U8) -> None:
    tmp, fd = create_partial(png)  # its name taken (GDAL then writes it by its path)
    os.close(fd)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.Env(GDAL_PAM_ENABLED="NO"), rasterio.open(
                tmp, "w", driver="PNG", width=rgba.shape[2], height=rgba.shape[1], count=4,
                dtype="uint8") as out:
            out.write(rgba)
    os.replace(tmp, png)
