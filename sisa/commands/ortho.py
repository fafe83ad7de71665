"""`sisa ortho`: map an image onto a grid from its IGM, each cell from the nearest pixel centre
(or interpolated there: --resampling bilinear or cubic).

OUT.tif            every band of the image on the grid, its data type, nodata outside the swath
OUT_glt.bil/.hdr   ENVI GLT: for every cell the 1-based input sample and line (0: none);
                   not with --no-glt

The ortho step of `sisa georef` on its own, for an IGM it wrote (or any ENVI BIL IGM of
pixel-centre easting, northing, height): to map a segment again at another cell size, over
set bounds, or uncompressed. Both files appear only when complete. An existing one is refused;
with --force it is replaced by the new one once that is complete.
"""

from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path

from sisa.commands import SubParsers, add_command, add_force_arg
from sisa.commands.progress import progress
from sisa.core.errors import InputError
from sisa.core.outdir import refuse_existing

# postproc.products.ortho.TIFF_COMPRESSIONS, named here so `sisa --help` needs no GDAL
# (a test checks)
COMPRESSIONS = ("deflate", "zstd", "lzw", "none")
RESAMPLINGS = ("nearest", "bilinear", "cubic")  # postproc.products.resample.Resampling


def register(sub: SubParsers[argparse.ArgumentParser]) -> None:
    parser = add_command(sub, "ortho", "orthorectify an image from its IGM onto a map grid "
                         "(nearest pixel centre): GeoTIFF and GLT",
                         "sisa ortho runs/bench/process/segment_000_igm.bil "
                         "runs/bench/scanner/segment_000.bil --cell 2 --out seg0_2m.tif")
    parser.add_argument("igm", type=Path, metavar="IGM",
                        help="ENVI BIL IGM: easting, northing, height of every pixel centre")
    parser.add_argument("image", type=Path, metavar="IMAGE",
                        help="the ENVI image the IGM belongs to (same lines and pixels)")
    parser.add_argument("--out", type=Path, required=True, metavar="TIF",
                        help="the GeoTIFF to write; the GLT goes next to it as <stem>_glt.bil")
    parser.add_argument("--cell", type=float, default=None, metavar="M",
                        help="cell size in the CRS's units (default: the IGM's median pixel "
                             "spacing, two significant digits)")
    parser.add_argument("--bounds", type=float, nargs=4, default=None,
                        metavar=("WEST", "SOUTH", "EAST", "NORTH"),
                        help="area to map (default: the IGM's extent); the grid's edges are "
                             "snapped outwards to multiples of the cell size")
    parser.add_argument("--crs", type=int, default=None, metavar="EPSG",
                        help="the IGM's CRS, for an IGM whose header names none")
    parser.add_argument("--compress", choices=COMPRESSIONS, default="deflate",
                        help="GeoTIFF compression (default: deflate, level 1 with predictor)")
    parser.add_argument("--bands", default=None, metavar="LIST",
                        help="the image's bands to map, 1-based, in the GeoTIFF's order, e.g. "
                             "4,3,2 (default: every band)")
    parser.add_argument("--resampling", choices=RESAMPLINGS, default="nearest",
                        help="nearest: the nearest pixel's value (default, radiometry "
                             "untouched); bilinear (2x2 pixels) or cubic (4x4, cubic "
                             "convolution): the image interpolated at the cell centre's "
                             "position in it; the GLT stays the nearest pixel")
    parser.add_argument("--no-glt", action="store_true",
                        help="the GeoTIFF alone, without the GLT (a sparse file of 8 bytes a "
                             "cell: 0.7 GB for a 20 000-line strip at 1 m)")
    add_force_arg(parser, "GeoTIFF or GLT")
    parser.set_defaults(handler=_run)


def _run(args: argparse.Namespace) -> int:
    started = time.perf_counter()
    # one OpenBLAS thread, set before numpy loads it: the ortho does no linear algebra, and
    # the thread OpenBLAS starts otherwise spins ~0.05 s of the CPU both cores are busy with
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    from postproc.products import (
        EnviRaster,
        OrthoGrid,
        Resampling,
        SwathIndex,
        common_lines,
        igm_epsg,
        igm_pixel_spacing_m,
        nice_cell_m,
        orthorectify,
    )

    out = Path(args.out)
    bands = None if args.bands is None else _bands(args.bands)
    if out.suffix.lower() not in (".tif", ".tiff"):
        raise InputError(f"--out {out}: name the GeoTIFF (.tif)")
    if not out.parent.is_dir():
        raise InputError(f"--out {out}: folder {out.parent} does not exist")
    glt = None if args.no_glt else out.with_name(f"{out.stem}_glt")
    refuse_existing(out, "--out", force=args.force)
    for path in [] if glt is None else [glt.with_suffix(".bil"), glt.with_suffix(".hdr")]:
        refuse_existing(path, force=args.force)  # another output's GLT, perhaps
    epsg = igm_epsg(args.igm)
    if epsg is None:
        if args.crs is None:
            raise InputError(f"{args.igm}: the header names no coordinate system: give --crs")
        epsg = args.crs
    elif args.crs is not None and args.crs != epsg:
        raise InputError(f"--crs {args.crs}: the IGM is in EPSG:{epsg}")
    cell_m = args.cell if args.cell is not None else nice_cell_m(igm_pixel_spacing_m(args.igm))
    if not (math.isfinite(cell_m) and 0 < cell_m <= 10_000):
        raise InputError(f"cell size {cell_m}: give a positive --cell in metres"
                         if args.cell is not None else
                         f"{args.igm}: no two neighbouring pixels have positions: give --cell")
    t0 = time.perf_counter()
    # the extent of the lines to be mapped (both files', one perhaps cut short), then the
    # ortho's index
    index, image = common_lines(SwathIndex.build(args.igm), EnviRaster.open(args.image))
    if args.bounds is None and index.far is not None:
        # a grid over its extent would cover the far positions (one 5000 km off: 66 s, a
        # 21 GB sparse GLT, exit 0); on a grid given, they are mapped as none, with a warning
        raise InputError(f"{args.igm}: {index.far.text}: a damaged IGM? give --bounds to map "
                         "it anyway")
    if bands is not None and max(bands) >= image.bands:
        raise InputError(f"--bands {args.bands}: {args.image} has bands 1 to {image.bands}")
    grid = OrthoGrid.covering(args.bounds or index.bounds_m, cell_m, epsg)
    with progress("ortho", "ortho", unit="cells") as bar:
        res = orthorectify(index, image, grid, out, glt, compress=args.compress,
                           progress=bar.advance, on_total=bar.set_total, empty_ok=False,
                           bands=bands, resampling=Resampling(args.resampling))
    ortho_s = time.perf_counter() - t0
    print(f"{out}: {res.cells_filled} of {res.cells} cells filled ({grid.width} x "
          f"{grid.height} of {cell_m:g} m, EPSG:{epsg}), mean distance to the pixel centre "
          f"{res.mean_distance_m:.3f} m; {'no GLT' if glt is None else f'GLT {glt}.bil'}; "
          f"ortho {ortho_s:.2f} s, "
          f"{time.perf_counter() - started:.2f} s in all")
    return 0


def _bands(text: str) -> list[int]:
    """--bands 4,3,2 as 0-based band indices; one line for anything else."""
    try:
        numbers = [int(b) for b in text.split(",")]
    except ValueError:
        raise InputError(f"--bands {text}: give band numbers from 1, e.g. 4,3,2") from None
    if min(numbers) < 1 or len(set(numbers)) != len(numbers):
        raise InputError(f"--bands {text}: band numbers from 1, each once")
    return [b - 1 for b in numbers]
