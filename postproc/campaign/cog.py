"""Cloud-Optimized GeoTIFFs: a GeoTIFF rewritten with internal tiles, overviews and DEFLATE in
the COG layout (rio-cogeo), and checked by rio-cogeo's validator."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Final

from postproc.products import TIFF_BLOCK, replace_file
from sisa.core.errors import InputError
from sisa.core.outdir import private_partial

# nearest: the overviews keep the scanner's own values (no mixing of spectra), as the ortho does
OVERVIEW_RESAMPLING: Final = "nearest"


def write_cog(src: Path, dst: Path) -> None:
    """`src` as a COG at `dst` (whole or not at all), its pixels, CRS, transform and nodata
    unchanged; overviews down to one tile. The intermediate file is on disk, not in memory:
    memory stays bounded by GDAL's cache, whatever the raster's size."""
    import numpy as np
    import rasterio
    from rio_cogeo.cogeo import cog_translate
    from rio_cogeo.profiles import cog_profiles

    with rasterio.open(src) as ds:
        floats = np.dtype(ds.dtypes[0]).kind == "f"
    profile = dict(cog_profiles.get("deflate"))  # type: ignore[no-untyped-call]
    profile.update(blockxsize=TIFF_BLOCK, blockysize=TIFF_BLOCK, interleave="band",
                   predictor=3 if floats else 2)
    # made new in a hidden folder of ours and put in place by replace_file: over a placeholder
    # or over `src` ext4 would write the whole COG out to disk on our time (private_partial)
    folder, tmp = private_partial(dst)
    try:
        cog_translate(str(src), str(tmp), profile, overview_resampling=OVERVIEW_RESAMPLING,
                      in_memory=False, quiet=True, forward_band_tags=True,
                      forward_ns_tags=True)
        replace_file(tmp, dst)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def check_cog(path: Path) -> None:
    """InputError naming the first problem unless `path` is a valid COG (rio-cogeo's
    validator; warnings are not errors)."""
    from rio_cogeo.cogeo import cog_validate

    ok, errors, _ = cog_validate(str(path), quiet=True)
    if not ok:
        raise InputError(f"{path}: not a valid Cloud-Optimized GeoTIFF: "
                         f"{'; '.join(errors)[:300]}")
