"""A segment's products from its IGM: the geolocation VRT and, when products are asked for,
its ortho, GLT and quicklook."""

from __future__ import annotations

import warnings
from pathlib import Path

from postproc.georef.jobrecords import SegmentResult
from postproc.georef.orthocell import swath_size_m
from postproc.products import (
    CutShortWarning,
    OrthoGrid,
    SwathIndex,
    orthorectify,
    write_geolocation_vrt,
    write_quicklook,
)


def segment_products(seg: SegmentResult, out: Path, epsg: int, cell_m: float, products: bool,
                     notes: list[str], *, workers: int | None = None) -> SwathIndex | None:
    """The segment's VRT and, with `products`, its ortho, GLT and quicklook (their names to
    `seg.files`; an ortho that holds no pixel said in `notes`); the index of its IGM they were
    made from (the mosaic's too); None without products, or when none of its pixels met the
    DEM (an IGM of NaN: nothing to map). `workers`: the ortho's windows made at once (default
    the ortho's own; a campaign's task takes one core: 1); the products do not depend on it."""
    stem = out / f"segment_{seg.segment:03d}"
    vrt = Path(f"{stem}_geoloc.vrt")
    write_geolocation_vrt(vrt, seg.image, seg.igm, epsg)
    seg.files["geolocation_vrt"] = vrt.name
    if not products or seg.rays_hit == 0:
        return None
    index = (SwathIndex.build(seg.igm) if workers is None else
             SwathIndex.build(seg.igm, workers=workers))
    grid = OrthoGrid.covering(index.bounds_m, cell_m, epsg)
    tif, glt = Path(f"{stem}_ortho.tif"), Path(f"{stem}_glt")
    with warnings.catch_warnings():  # a cut image: said once, by segment_raster's warning
        warnings.simplefilter("ignore", CutShortWarning)
        made = (orthorectify(index, seg.image, grid, tif, glt) if workers is None else
                orthorectify(index, seg.image, grid, tif, glt, workers=workers))
    if made.cells_filled == 0:
        width, length = swath_size_m(seg)
        notes.append(
            f"segment {seg.segment}: its ortho holds no pixel: no centre of its "
            f"{cell_m:g} m cells falls on the swath ({width:.0f} m wide, {length:.0f} m "
            "long); a smaller --cell")
    png = Path(f"{stem}_quicklook.png")
    write_quicklook(tif, png)
    seg.files.update(ortho=tif.name, glt=f"{glt.name}.bil", quicklook=png.name)
    return index
