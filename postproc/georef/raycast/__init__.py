"""Where each scanner ray first meets the DEM: the post-processor's ray casting.

Geometry. Rays are straight in ECEF; the DEM is a bilinear surface of ELLIPSOIDAL height over a
projected (UTM) grid, and (E, N, h) are not Cartesian (curvature drops a point 1 km from nadir
by ~8 cm; the UTM scale varies). Lines are grouped in blocks; for each block a local East-North-Up
frame is fitted with a QUADRATIC map p ↦ (E, N, h), least squares on pyproj at Chebyshev nodes
of a box holding every ray's path through the DEM's height range, and checked at other points
(< MAP_TOLERANCE_M, else the block is split). Along one ray E, N and h are then exact quadratics
in the range s, with per-line coefficients, so a ray costs a few multiply-adds to set up.

Fast path (numba, parallel over blocks, lines in order within a block). Each ray starts from the
range of the same pixel in the previous line (float64 set-up of float32 quadratic models of the
grid position and height in t = s − start, relative to the block) and takes two branch-free
float32 Newton steps on g = h − DEM(E, N), both on the bilinear patch of the cell under the
start (vectorised; its four corner heights are two 8-byte gathers, and the cells a few lines
ahead are prefetched); the few rays (~2 %) whose first step leaves that cell restart from there.
Inside one DEM cell g is a quadratic in t, so the last step bounds the remaining error: a ray is
accepted only if |g''|·step²/(2|g'|) < ROOT_TOLERANCE_M, that step stayed in the cell, and the
root is provably the FIRST one: g falls monotonically along the ray's whole path through the
DEM's height range when the steepest DEM slope under the paths of a group of rays (a sparse
table of per-tile slope maxima) times the ray's horizontal/vertical rate is below 1. Float32
positions relative to the block's grid origin and heights relative to the ray's start height
(itself rounded to a float32, like the DEM's samples: the steps subtract nearby float32s, which
loses nothing or next to nothing) leave < 0.1 mm; a product and a sum may fuse (of fastmath,
only `contract`); the output is evaluated in float64. Every other ray takes the safe path
(float64): a cell-by-cell walk along the ray from the top of the DEM's height range, solving
the (quadratic-in-s) gap exactly inside each cell, so a ray grazing a ridge or occluded by a
cliff finds its first crossing.

Misses (hit False, NaN): rays that never come down to the DEM's highest sample, that pass off
the DEM or over a nodata cell (one with ANY nodata corner) while within the DEM's height range
(nothing is invented about unknown terrain), and cameras below the surface. The few rays whose
path leaves the box a block's map was fitted to are solved by the reference method.

The DEM must hold terrain: NaN for no data, heights within SURFACE_HEIGHTS_M (InputError
otherwise: a void marker such as -9999 left in the heights would make a 10 km pit, which no
block map fits, and send every ray to the reference method). Every loop is bounded: the cell
walk to 10 million cells (then the reference method), root refinement to 100 steps, the
reference march to REFERENCE_MAX_STEPS per ray (a ray still marching then is a miss, counted
in CastStats.unresolved).

`reference_intersect` is the slow oracle sharing no code with the fast path: pyproj at every
point, DEM heights from `Dem.height_at`, steps no longer than gap / (1 + steepest slope within
reach) so no crossing can be skipped, then bisection to 1e-7 m.

Two kernels run the fast path. Where the CPU has AVX2 and FMA, `_castkernel.c` (built at
install, called through ctypes by `fastpath`, its own threads): 8 rays at once, models relative
to each ray's start cell (float32 rounds to 1e-7 cells there: 0.002 mm on the benchmark's
scene, 0.009 mm on the alpine ribs), a ray accepted on the previous line started from its end
point there moved by the change of the line's terms (float64 only on each group's first line
and where a ray was not accepted); the rays it does not certify go to the safe path in numba
(`kernel.safe_pass`). Elsewhere numba's `kernel.cast_blocks`, the same method in one loop (the
models relative to the block: 0.035 mm, 0.074 mm). Which one runs changes no hit and moves no
point by 0.1 mm (tests/postproc/test_raycast.py).

Inside, by job: `rays` (what a cast takes and gives), `maps` (the fitted local maps), `surface`
(the prepared DEM), `blocks` (the lines in blocks, each with its map), `tables` (what the
kernel reads of each line and block), `kernel` (every compiled loop, in one file for numba's
cache), `fastpath` (the C kernel), `reference` (the reference method) and `cast` (`intersect`:
one call, start to end).
"""

from postproc.georef.raycast.cast import intersect
from postproc.georef.raycast.rays import CastStats, GroundPoints
from postproc.georef.raycast.reference import reference_intersect

__all__ = ["CastStats", "GroundPoints", "intersect", "reference_intersect"]
