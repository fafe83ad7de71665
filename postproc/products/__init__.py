"""The georeferencing products as files: ENVI rasters (the scanner's images, IGM, GLT), the
geolocation VRT, orthos and mosaics (GeoTIFF), footprints (GeoJSON) and quicklooks (PNG).

The ortho's inner loops are C (`_orthokernels.c`, called through ctypes); every other hot loop
in SISA is numba. Why two: docs/conventions.md, "Compiled loops". Other stages and the commands
use only the names below.
"""

from postproc.products.footprints import (
    footprint_feature,
    signed_area,
    write_footprints_geojson,
)
from postproc.products.igm import (
    CutShortWarning,
    EnviRaster,
    IgmWriter,
    igm_bounds,
    igm_epsg,
    igm_pixel_spacing_m,
    open_igm,
    replace_file,
    write_geolocation_vrt,
)
from postproc.products.mosaic import mosaic
from postproc.products.ortho import (
    TIFF_BLOCK,
    OrthoGrid,
    Progress,
    SwathIndex,
    common_lines,
    nice_cell_m,
    orthorectify,
)
from postproc.products.quicklook import RgbView, read_rgb, write_quicklook
from postproc.products.resample import Resampling

__all__ = [
    "TIFF_BLOCK", "CutShortWarning", "EnviRaster", "IgmWriter", "OrthoGrid", "Progress",
    "Resampling", "RgbView",
    "SwathIndex", "common_lines", "footprint_feature", "igm_bounds", "igm_epsg",
    "igm_pixel_spacing_m", "mosaic", "nice_cell_m", "open_igm", "orthorectify", "read_rgb",
    "replace_file", "signed_area", "write_footprints_geojson", "write_geolocation_vrt",
    "write_quicklook",
]
