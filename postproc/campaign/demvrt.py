"""Several DEM tiles of one flight as one DEM: a GDAL VRT mosaic of them (what `gdalbuildvrt`
makes), written beside the flight's products and read by the georeferencing like any DEM.

The tiles must share their CRS and cell and lie on one grid (tiles of one product do); where
they overlap, the first listed wins, and a tile's voids (its nodata) let the next show through.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Final
from xml.sax.saxutils import escape

from sisa.core.errors import InputError
from sisa.core.outdir import write_whole

GDAL_TYPES: Final = {"uint8": "Byte", "int16": "Int16", "uint16": "UInt16", "int32": "Int32",
                     "uint32": "UInt32", "float32": "Float32", "float64": "Float64"}
ALIGN_TOL: Final = 1e-6  # of a cell


def write_dem_vrt(dems: Sequence[Path], vrt: Path) -> None:
    """The VRT mosaic of `dems` (band 1 of each) at `vrt`, written only when its text changes
    (its fingerprint, hence every task key built on it, stays put on a rerun). InputError when
    the tiles do not share a CRS, a cell and a grid."""
    import rasterio

    tiles = []
    for path in dems:
        try:
            with rasterio.open(path) as ds:
                tiles.append((path, ds.crs, ds.transform, ds.width, ds.height, ds.nodata,
                              ds.dtypes[0]))
        except rasterio.errors.RasterioIOError as exc:
            raise InputError(f"{path}: not a DEM GDAL can read ({exc})") from None
    _, crs, t0, *_ = tiles[0]
    for path, c, t, *_ in tiles[1:]:
        if c != crs:
            raise InputError(f"{path}: CRS {c} differs from {tiles[0][0]}'s ({crs}): mosaic "
                             "DEM tiles of one CRS")
        if t.b or t.d or not (math.isclose(t.a, t0.a, rel_tol=1e-9)
                              and math.isclose(t.e, t0.e, rel_tol=1e-9)):
            raise InputError(f"{path}: cell {t.a:g} x {-t.e:g} differs from {tiles[0][0]}'s "
                             f"({t0.a:g} x {-t0.e:g}) or is not north-up")
        for off, cell in (((t.c - t0.c) / t0.a, "column"), ((t.f - t0.f) / t0.e, "row")):
            if abs(off - round(off)) > ALIGN_TOL:
                raise InputError(f"{path}: off {tiles[0][0]}'s grid by {off - round(off):.3f} "
                                 f"of a {cell}: mosaic DEM tiles on one grid")
    west = min(t.c for _, _, t, *_ in tiles)
    north = max(t.f for _, _, t, *_ in tiles)
    east = max(t.c + w * t.a for _, _, t, w, *_ in tiles)
    south = min(t.f + h * t.e for _, _, t, _, h, *_ in tiles)
    width, height = round((east - west) / t0.a), round((south - north) / t0.e)
    dtypes = {d for *_, d in tiles}
    dtype = dtypes.pop() if len(dtypes) == 1 else "float64"
    nodata = tiles[0][5]
    sources = []
    for path, _, t, w, h, nd, _ in reversed(tiles):  # drawn in order: the first listed last
        col, row = round((t.c - west) / t0.a), round((t.f - north) / t0.e)
        sources.append(
            "    <ComplexSource>\n"
            f'      <SourceFilename relativeToVRT="0">{escape(str(path.resolve()))}'
            "</SourceFilename>\n      <SourceBand>1</SourceBand>\n"
            f'      <SrcRect xOff="0" yOff="0" xSize="{w}" ySize="{h}"/>\n'
            f'      <DstRect xOff="{col}" yOff="{row}" xSize="{w}" ySize="{h}"/>\n'
            + (f"      <NODATA>{nd!r}</NODATA>\n" if nd is not None else "")
            + "    </ComplexSource>\n")
    text = (f'<VRTDataset rasterXSize="{width}" rasterYSize="{height}">\n'
            f"  <SRS>{escape(crs.to_wkt())}</SRS>\n"
            f"  <GeoTransform>{west!r}, {t0.a!r}, 0.0, {north!r}, 0.0, {t0.e!r}"
            "</GeoTransform>\n"
            f'  <VRTRasterBand dataType="{GDAL_TYPES.get(dtype, "Float64")}" band="1">\n'
            + (f"    <NoDataValue>{nodata!r}</NoDataValue>\n" if nodata is not None else "")
            + "".join(sources) + "  </VRTRasterBand>\n</VRTDataset>\n")
    try:
        if vrt.read_text(encoding="utf-8") == text:
            return
    except OSError:
        pass
    vrt.parent.mkdir(parents=True, exist_ok=True)
    write_whole(vrt, text)
