"""One call of the ray caster: the rays of a run of lines cast on the DEM (the block maps, the
kernel, the reference method for the rays it leaves, the statistics)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from postproc.georef.dem import Dem
from postproc.georef.raycast import fastpath
from postproc.georef.raycast.blocks import fit_block_maps
from postproc.georef.raycast.kernel import cast_blocks, safe_pass, scratch
from postproc.georef.raycast.rays import CastStats, GroundPoints, checked_rays, output_buffers
from postproc.georef.raycast.reference import resolve_exact
from postproc.georef.raycast.surface import surface_of
from postproc.georef.raycast.tables import kernel_tables, line_coefficients, look_products

F64 = npt.NDArray[np.float64]


def intersect(dem: Dem, centre_ecef_m: F64, r_ecef_from_camera: F64, look_camera: F64, *,
              out: GroundPoints | None = None, stats: CastStats | None = None) -> GroundPoints:
    """Ground point of every pixel of every line: ray i, j is
    centre_ecef_m[i] + s · r_ecef_from_camera[i] @ look_camera[:, j], s ≥ 0.

    centre_ecef_m (n, 3), r_ecef_from_camera (n, 3, 3) rotations, look_camera (3, p)
    unnormalised camera-frame look vectors. Coordinates in the DEM's CRS, accurate to
    < 1 mm of range. A line whose pose is NaN (no time) gives NaN, hit False. `out` buffers
    are reused when given (shape (n, p)); `stats`, when given, is filled in."""
    centre, rot, look, posed = checked_rays(centre_ecef_m, r_ecef_from_camera, look_camera)
    n, p = centre.shape[0], look.shape[1]
    out = output_buffers(out, n, p)
    if n == 0 or p == 0:
        return out
    if not posed.all():  # lines without a pose: NaN, the others as usual
        sub = intersect(dem, centre[posed], rot[posed], look, stats=stats)
        for full, part in ((out.easting_m, sub.easting_m), (out.northing_m, sub.northing_m),
                           (out.height_m, sub.height_m)):
            full[posed], full[~posed] = part, np.nan
        out.hit[posed], out.hit[~posed] = sub.hit, False
        return out
    surf = surface_of(dem)
    unit = look / np.linalg.norm(look, axis=0)
    maps = fit_block_maps(surf, centre, rot, unit)
    coef = line_coefficients(maps, centre, rot)
    blk, consts = kernel_tables(surf, maps)
    line_flag = np.zeros(n, np.uint8)
    counts = np.zeros((maps.starts.size - 1, 4), np.int64)
    look9 = look_products(unit)
    hit = out.hit.view(np.uint8)
    if fastpath.usable(surf.flat.size):  # AVX2 + FMA: C, then the safe path for its leftovers
        line_safe = np.zeros(n, np.uint8)
        fastpath.cast_fast(surf.flat, surf.rows, surf.cols, surf.slope_table, surf.log2, coef,
                           look9, maps.starts, blk, consts, out.easting_m, out.northing_m,
                           out.height_m, hit, line_safe, counts)
        if line_safe.any():  # (a parallel region costs ~1 ms of waking threads)
            safe_pass(surf.flat, surf.cols, coef, look9, maps.starts, blk, consts,
                      out.easting_m, out.northing_m, out.height_m, hit, line_safe, line_flag,
                      counts)
    else:
        cast_blocks(surf.flat, surf.flat, surf.cols, surf.slope_table, surf.log2, coef, look9,
                    maps.starts, blk, consts, out.easting_m, out.northing_m, out.height_m, hit,
                    line_flag, counts, *scratch(p))
    exact, unresolved = resolve_exact(dem, out, line_flag, centre, rot, unit)
    if stats is not None:
        total = counts.sum(axis=0)
        stats.fast, stats.safe_hit, stats.safe_miss = int(total[0]), int(total[1]), int(total[2])
        stats.exact, stats.unresolved = exact, unresolved
        stats.blocks = int(maps.starts.size - 1)
        stats.map_error_m = float(maps.error_m.max())
    return out
