"""Orthophotos of the frame camera through the scanner's ortho path.

    made = photo_orthos(out, dem, eo, interior, images, epsg=eo.epsg)

A photo is treated as the scanner treats a segment: every pixel centre's ray (from
`sisa.core.framecamera.image_to_camera`, distortion removed) is cast onto the DEM with
`raycast.intersect` into an IGM (one IGM line per image row, one sample per column, the
easting, northing and ellipsoidal height of the pixel centre), and `products.orthorectify`
maps the photo's ENVI image by nearest pixel centre onto a north-up grid (GeoTIFF + GLT).
The ray caster takes one pose per "line" and one set of look vectors for all of them: a photo
is one pose, so a chunk of its rows is one line of (rows × width) looks; the photos share
those looks (one camera), so each chunk is computed once and cast for several photos at once,
one line per photo (the caster's blocks then run in parallel). The
photos' mosaic is `products.mosaic` with `frames=True`: each cell from the photo whose chosen
pixel is nearest its image centre (the least oblique view, seams between photo centres).

The grid's cell is the photos' median pixel spacing rounded to two significant digits
(`nice_cell_m`), on multiples of the cell, so every photo ortho and the mosaic share it.
A photo without a pose, without an image, or whose rays all miss the DEM is skipped and
named in `notes`; an image whose size is not the camera's is refused (InputError).
"""

from __future__ import annotations

import contextlib
import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt

from postproc.georef.dem import Dem, union_bounds
from postproc.georef.navigation import transformer
from postproc.georef.photos import PhotoEo
from postproc.georef.raycast import intersect
from postproc.products import (
    CutShortWarning,
    EnviRaster,
    IgmWriter,
    OrthoGrid,
    SwathIndex,
    mosaic,
    nice_cell_m,
    orthorectify,
    write_quicklook,
)
from sisa.core.errors import InputError
from sisa.core.framecamera import FrameInterior, image_to_camera

F64 = npt.NDArray[np.float64]

RAYS_PER_CAST: Final = 1 << 22  # rays per ray-caster call (rows of several photos)
PHOTOS_PER_CAST: Final = 16  # photos cast together (each an open IGM)
MOSAIC_NAME: Final = "photo_mosaic.tif"


@dataclass(frozen=True)
class PhotoGeo:
    """One photo cast onto the DEM: its IGM, how many of its rays met the DEM, and the median
    distance between neighbouring pixel centres along its rows (m; NaN when unknown)."""

    label: str
    igm: Path
    rays: int
    rays_hit: int
    gsd_m: float


@dataclass
class PhotoOrthos:
    """What `photo_orthos` made: per photo its files (names in `out`), the cell, the mosaic."""

    cell_m: float
    files: dict[str, dict[str, str]] = field(default_factory=dict)  # label → kind → name
    geo: list[PhotoGeo] = field(default_factory=list)
    mosaic: Path | None = None
    notes: list[str] = field(default_factory=list)


def photo_looks(interior: FrameInterior, row0: int, row1: int) -> F64:
    """(3, rows × width) camera-frame unit rays of the pixel centres of rows [row0, row1),
    row-major (the IGM's order)."""
    cols, rows = np.meshgrid(np.arange(interior.width_px, dtype=np.float64),
                             np.arange(row0, row1, dtype=np.float64))
    return np.ascontiguousarray(image_to_camera(cols.ravel(), rows.ravel(), interior).T)


def cast_photos(dem: Dem, eo: PhotoEo, indices: Sequence[int], interior: FrameInterior,
                stems: Sequence[Path], epsg: int) -> list[PhotoGeo]:
    """Every pixel of the photos `indices` (each with a pose) cast onto `dem` into the IGMs
    `<stem>.bil` in `epsg` (pixel centres; NaN where a ray misses), each written whole. The
    photos share their camera's looks: each chunk of rows is computed once and cast for
    PHOTOS_PER_CAST photos at a time, one ray-caster "line" per photo."""
    geo: list[PhotoGeo] = []
    for k in range(0, len(indices), PHOTOS_PER_CAST):
        group = list(indices[k:k + PHOTOS_PER_CAST])
        geo += _cast_group(dem, eo, group, interior, list(stems[k:k + PHOTOS_PER_CAST]), epsg)
    return geo


def _cast_group(dem: Dem, eo: PhotoEo, group: list[int], interior: FrameInterior,
                stems: list[Path], epsg: int) -> list[PhotoGeo]:
    if not eo.valid[group].all():
        raise InputError("a photo without a pose cannot be cast")
    width, height = interior.width_px, interior.height_px
    rows_per_cast = max(RAYS_PER_CAST // (width * len(group)), 1)
    to_out = None if epsg == dem.epsg else transformer(dem.epsg, epsg)
    centre, rot = eo.pose.centre_ecef_m[group], eo.pose.r_ecef_from_camera[group]
    hits = np.zeros(len(group), np.int64)
    steps: list[list[F64]] = [[] for _ in group]
    with contextlib.ExitStack() as stack:
        igms = [stack.enter_context(IgmWriter(stem, height, width, epsg,
                                              source=f"photo {eo.labels[i]}"))
                for i, stem in zip(group, stems, strict=True)]
        for row0 in range(0, height, rows_per_cast):
            row1 = min(row0 + rows_per_cast, height)
            got = intersect(dem, centre, rot, photo_looks(interior, row0, row1))
            shape = (len(group), row1 - row0, width)
            east, north, h = (a.reshape(shape)
                              for a in (got.easting_m, got.northing_m, got.height_m))
            if to_out is not None:
                east, north = (np.asarray(a) for a in to_out.transform(east, north))
            hits += got.hit.sum(axis=1)
            for m, igm in enumerate(igms):
                igm.write_block(row0, east[m], north[m], h[m])
                steps[m].append(np.hypot(np.diff(east[m], axis=1),
                                         np.diff(north[m], axis=1))[::8].ravel())
    return [PhotoGeo(eo.labels[i], igm.path, width * height, int(hits[m]), _median(steps[m]))
            for m, (i, igm) in enumerate(zip(group, igms, strict=True))]


def _median(parts: list[F64]) -> float:
    step = np.concatenate(parts)
    step = step[np.isfinite(step)]
    return float(np.median(step)) if step.size else math.nan


def _checked_image(path: Path, label: str, interior: FrameInterior) -> EnviRaster:
    raw = EnviRaster.open(Path(path))
    if (raw.pixels, raw.lines) != (interior.width_px, interior.height_px):
        raise InputError(f"{path}: photo {label} is {raw.pixels} x {raw.lines} pixels, the "
                         f"camera's {interior.width_px} x {interior.height_px}")
    return raw


def photo_orthos(out: Path, dem: Dem, eo: PhotoEo, interior: FrameInterior,
                 images: Mapping[str, Path], *, epsg: int, cell_m: float | None = None
                 ) -> PhotoOrthos:
    """For every photo with a pose and an image (`images`: label → ENVI image, row 0 at the
    top), its IGM, ortho GeoTIFF and GLT in `out` (`<label>_igm.bil`, `<label>_ortho.tif`,
    `<label>_glt.bil`), then the mosaic of them all (`photo_mosaic.tif` and its quicklook).
    `cell_m`: the grid's cell (default: the photos' median pixel spacing, rounded)."""
    out = Path(out)
    raws = {label: _checked_image(images[label], label, interior)
            for label in eo.labels if label in images}
    made = PhotoOrthos(cell_m=math.nan)
    cast: list[int] = []
    for i, label in enumerate(eo.labels):
        if label not in raws:
            made.notes.append(f"photo {label}: no image: no ortho")
        elif not eo.valid[i]:
            made.notes.append(f"photo {label}: no navigation pose at its time: no ortho")
        else:
            cast.append(i)
    stems = [out / f"{eo.labels[i]}_igm" for i in cast]
    for geo in cast_photos(dem, eo, cast, interior, stems, epsg):
        made.files[geo.label] = {"igm": geo.igm.name}
        if geo.rays_hit == 0:
            made.notes.append(f"photo {geo.label}: none of its rays met the DEM: no ortho")
        else:
            made.geo.append(geo)
    if not made.geo:
        return made
    made.cell_m = cell_m or nice_cell_m(float(np.nanmedian([g.gsd_m for g in made.geo])))
    if not (math.isfinite(made.cell_m) and made.cell_m > 0):
        raise InputError("the photos' pixel spacing could not be measured (too few rays met "
                         "the DEM): give the photo ortho cell")
    mapped: list[tuple[SwathIndex, Path]] = []
    for geo in made.geo:
        index = SwathIndex.build(geo.igm)
        grid = OrthoGrid.covering(index.bounds_m, made.cell_m, epsg)
        tif, glt = out / f"{geo.label}_ortho.tif", out / f"{geo.label}_glt"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CutShortWarning)
            orthorectify(index, raws[geo.label], grid, tif, glt)
        made.files[geo.label].update(ortho=tif.name, glt=f"{glt.name}.bil")
        mapped.append((index, raws[geo.label].path))
    made.mosaic = out / MOSAIC_NAME
    grid = OrthoGrid.covering(union_bounds([ix.bounds_m for ix, _ in mapped]), made.cell_m,
                              epsg)
    mosaic(mapped, grid, made.mosaic, frames=True)
    write_quicklook(made.mosaic, out / "photo_mosaic_quicklook.png")
    return made
