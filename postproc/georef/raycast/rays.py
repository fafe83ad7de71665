"""What a cast takes and gives: the rays checked (shapes, finite non-zero look vectors, rotation
matrices, the lines with a pose), the ground points, and how the rays were resolved."""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np
import numpy.typing as npt

from postproc.georef.raycast.kernel import pose_check

F64 = npt.NDArray[np.float64]
B1 = npt.NDArray[np.bool_]


@dataclass
class GroundPoints:
    """First intersection of every ray with the DEM, in the DEM's CRS: easting, northing and
    ellipsoidal height (lines, pixels), NaN where the ray misses (hit False)."""

    easting_m: F64
    northing_m: F64
    height_m: F64
    hit: B1

    @classmethod
    def empty(cls, lines: int, pixels: int) -> GroundPoints:
        """Uninitialised buffers: allocate once, pass as `out=` for every chunk of lines."""
        shape = (lines, pixels)
        return cls(np.empty(shape), np.empty(shape), np.empty(shape), np.empty(shape, np.bool_))

    @property
    def shape(self) -> tuple[int, int]:
        return cast(tuple[int, int], self.easting_m.shape)


@dataclass
class CastStats:
    """How the rays of one `intersect` call were resolved (for benchmarks and reports)."""

    fast: int = 0  # accepted from the Newton path
    safe_hit: int = 0  # cell walk, hit
    safe_miss: int = 0  # cell walk, miss
    exact: int = 0  # outside the fitted maps: reference method
    unresolved: int = 0  # of those, still marching after REFERENCE_MAX_STEPS steps: missed
    blocks: int = 0
    map_error_m: float = 0.0  # worst fitted-map error at the check points


def checked_rays(centre: F64, rot: F64, look: F64) -> tuple[F64, F64, F64, B1]:
    """Contiguous float64 inputs and the lines with a pose (finite centre and rotation)."""
    c = np.ascontiguousarray(centre, dtype=np.float64)
    r = np.ascontiguousarray(rot, dtype=np.float64)
    lk = np.ascontiguousarray(look, dtype=np.float64)
    n = c.shape[0] if c.ndim == 2 else -1
    if c.shape != (n, 3) or r.shape != (n, 3, 3) or lk.ndim != 2 or lk.shape[0] != 3:
        raise ValueError(f"expected centre (n, 3), rotation (n, 3, 3), look (3, p); got "
                         f"{c.shape}, {r.shape}, {lk.shape}")
    if not np.isfinite(lk).all() or (lk.shape[1] and not (np.linalg.norm(lk, axis=0) > 0.0).all()):
        raise ValueError("look vectors must be finite and non-zero")
    ok = np.empty(n, np.bool_)
    if pose_check(c, r, ok.view(np.uint8)) > 1e-6:
        raise ValueError("r_ecef_from_camera must be rotation matrices")
    return c, r, lk, ok


def output_buffers(out: GroundPoints | None, n: int, p: int) -> GroundPoints:
    if out is None:
        return GroundPoints.empty(n, p)
    arrays = (out.easting_m, out.northing_m, out.height_m)
    if (any(a.shape != (n, p) or a.dtype != np.float64 or not a.flags.c_contiguous
            for a in arrays) or out.hit.shape != (n, p) or out.hit.dtype != np.bool_
            or not out.hit.flags.c_contiguous):
        raise ValueError(f"out buffers must be C-contiguous float64/bool of shape {(n, p)}")
    return out
