"""What the kernel reads of each line and block: a line's ray coefficients in its block's
frame, the products of the look vectors, and the block's grid tables."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from postproc.georef.raycast.kernel import coefficients_kernel
from postproc.georef.raycast.maps import Maps
from postproc.georef.raycast.surface import Surface

F64 = npt.NDArray[np.float64]


def line_coefficients(maps: Maps, centre: F64, rot: F64) -> F64:
    """Per line i, in its block's frame: E, N, h (relative to the block origin) along ray j are
    A + B·s + C·s² with B = u·l_j and C = l_jᵀQl_j. Packed (n, 30): A (3), u (3 × 3),
    ½Q as (q00, q11, q22, q01, q02, q12) × 3, matching `look_products`."""
    blk = np.repeat(np.arange(maps.starts.size - 1), np.diff(maps.starts))
    out = np.empty((centre.shape[0], 30))
    coefficients_kernel(blk, maps.origin_ecef_m, maps.rot, maps.a, maps.g, maps.hess, centre,
                        rot, out)
    return out


def look_products(unit: F64) -> F64:
    """(9, p): l0, l1, l2, l0², l1², l2², 2·l0·l1, 2·l0·l2, 2·l1·l2 of unit look vectors."""
    l0, l1, l2 = unit
    return np.ascontiguousarray(np.stack([l0, l1, l2, l0 * l0, l1 * l1, l2 * l2,
                                          2 * l0 * l1, 2 * l0 * l2, 2 * l1 * l2]))


def ray_terms(coef: F64, look9: F64) -> tuple[F64, F64]:
    """B and C (lines, pixels, 3) of every ray (numpy; the kernel inlines the same sums)."""
    u = coef[:, 3:12].reshape(-1, 3, 3)
    q = coef[:, 12:30].reshape(-1, 3, 6)
    return (np.einsum("nki,ip->npk", u, look9[:3]), np.einsum("nkm,mp->npk", q, look9[3:]))


def kernel_tables(surf: Surface, maps: Maps) -> tuple[F64, F64]:
    """Per block (b, 14): fractional grid offset of the block origin (x, y), its integer grid
    origin (x, y), the valid box in local grid coordinates (x0, x1, y0, y1), E0, N0, h0, (unused),
    the lowest and highest terrain its rays can meet. Constants: 1/cell_e, 1/cell_n."""
    dem = surf.dem
    gx = (maps.en0_m[:, 0] - dem.first_easting_m) / dem.cell_e_m
    gy = (dem.first_northing_m - maps.en0_m[:, 1]) / dem.cell_n_m
    ox, oy = np.round(gx), np.round(gy)
    box = maps.box_en_m
    with np.errstate(invalid="ignore"):
        vx0 = np.clip((box[:, 0] - dem.first_easting_m) / dem.cell_e_m, 0, dem.cols - 1)
        vx1 = np.clip((box[:, 2] - dem.first_easting_m) / dem.cell_e_m, 0, dem.cols - 1)
        vy0 = np.clip((dem.first_northing_m - box[:, 3]) / dem.cell_n_m, 0, dem.rows - 1)
        vy1 = np.clip((dem.first_northing_m - box[:, 1]) / dem.cell_n_m, 0, dem.rows - 1)
    empty = ~np.isfinite(box).all(axis=1)
    vx0[empty], vx1[empty] = 1.0, 0.0
    blk = np.stack([gx - ox, gy - oy, ox, oy, vx0 - ox, vx1 - ox, vy0 - oy, vy1 - oy,
                    maps.en0_m[:, 0], maps.en0_m[:, 1], maps.h0_m, np.zeros_like(ox),
                    maps.low_m, maps.high_m], axis=1)
    consts = np.array([1.0 / dem.cell_e_m, 1.0 / dem.cell_n_m])
    return np.ascontiguousarray(blk), consts
