"""The fast path in C (`_castkernel.c`: AVX2 and FMA, 8 rays at once, its own threads), built
at install and called through ctypes; None where it is not built or this CPU lacks AVX2 or
FMA, and then `cast.py` takes numba's kernel (kernel.py), the same method. Its rays left
uncertified go to kernel.py's safe path after it (`safe_pass`)."""

from __future__ import annotations

import ctypes
import importlib
from typing import Final

import numba
import numpy as np
import numpy.typing as npt

from postproc.georef.raycast import kernel

F64 = npt.NDArray[np.float64]
U8 = npt.NDArray[np.uint8]
I64 = npt.NDArray[np.int64]
PREFETCH_STRIDE: Final = 4  # of every 8 rays, the cells of lanes 0 and 4 are prefetched
MAX_CELLS: Final = 2**31 - 2**20  # int32 DEM indices (a bigger DEM takes numba's kernel)


def _load() -> ctypes.CDLL | None:
    try:
        module = importlib.import_module("postproc.georef.raycast._castkernel")
    except ImportError:
        return None
    lib = ctypes.CDLL(module.__file__)
    lib.castkernel_usable.argtypes, lib.castkernel_usable.restype = [], ctypes.c_int
    if not lib.castkernel_usable():
        return None
    p, i = ctypes.c_void_p, ctypes.c_int64
    lib.cast_fast.argtypes = [p, i, i, p, i, i, p, p, p, i, p, i, p, p, p, p, p, p, p, p, p, i]
    lib.cast_fast.restype = ctypes.c_int
    return lib


LIB: ctypes.CDLL | None = _load()
_PARAMS: Final = np.array([kernel.GROUP_LINES, kernel.CHUNK_PIXELS, kernel.TILE_CELLS,
                           kernel.COLD_PASSES, kernel.ROOT_TOLERANCE_M,
                           kernel.MAX_NEWTON_STEP_M, kernel.SLOPE_MARGIN,
                           kernel.PREFETCH_LINES, PREFETCH_STRIDE], dtype=np.float64)


def usable(cells: int) -> bool:
    return LIB is not None and cells <= MAX_CELLS


def cast_fast(flat: npt.NDArray[np.float32], rows: int, cols: int,
              slope_table: npt.NDArray[np.float32], log2: I64, coef: F64, look9: F64,
              starts: I64, blk: F64, consts: F64, out_e: F64, out_n: F64, out_h: F64,
              out_hit: U8, line_safe: U8, counts: I64) -> None:
    """kernel.cast_blocks' fast path and certification (hit 1: certified; 2: left to the safe
    path, its line flagged in line_safe), blocks on numba's thread count of threads."""
    assert LIB is not None
    f4, f8, i8, u1 = np.float32, np.float64, np.int64, np.uint8
    typed = ((flat, f4), (slope_table, f4), (log2, i8), (coef, f8), (look9, f8), (starts, i8),
             (blk, f8), (consts, f8), (out_e, f8), (out_n, f8), (out_h, f8), (out_hit, u1),
             (line_safe, u1), (counts, i8), (_PARAMS, f8))
    if not (all(a.flags.c_contiguous and a.dtype == t for a, t in typed)
            and out_e.size == out_n.size == out_h.size == out_hit.size
            == coef.shape[0] * look9.shape[1] and line_safe.size == coef.shape[0]
            and counts.shape == (starts.size - 1, 4) and flat.size == rows * cols
            and slope_table.ndim == 3 and blk.shape[0] == starts.size - 1):
        raise ValueError("cast_fast: arrays of the wrong type, layout or size")
    arrays = [a for a, _ in typed]
    ptr = [a.ctypes.data for a in arrays]
    got = LIB.cast_fast(ptr[0], rows, cols, ptr[1], slope_table.shape[1],
                        slope_table.shape[2], ptr[2], ptr[3], ptr[4], look9.shape[1], ptr[5],
                        starts.size - 1, ptr[6], ptr[7], ptr[8], ptr[9], ptr[10], ptr[11],
                        ptr[12], ptr[13], ptr[14], numba.get_num_threads())
    if got != 0:
        raise MemoryError("the ray caster's C kernel could not get memory for its scratch")
