"""Fitted maps: a quadratic map from a local East-North-Up frame to (E, N, h) of the DEM's CRS
over a box, by least squares on pyproj at Chebyshev nodes, checked at other points; one per
block of lines (or one over the whole DEM)."""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import lru_cache
from typing import Final

import numpy as np
import numpy.typing as npt
from pyproj import Transformer

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
B1 = npt.NDArray[np.bool_]

BAND_PAD_M: Final = 10.0  # map box reaches this far above / below the DEM's heights


@lru_cache(maxsize=16)
def transformers(epsg: int) -> tuple[Transformer, Transformer, Transformer, Transformer]:
    """(ECEF → geodetic, geodetic → map, map → geodetic, geodetic → ECEF), built once."""
    return (Transformer.from_crs(4978, 4979, always_xy=True),
            Transformer.from_crs(4326, epsg, always_xy=True),
            Transformer.from_crs(epsg, 4326, always_xy=True),
            Transformer.from_crs(4979, 4978, always_xy=True))


def _enu_rotation(lat_rad: F64, lon_rad: F64) -> F64:
    """(..., 3, 3) rows east, north, up in ECEF."""
    sl, cl, so, co = np.sin(lat_rad), np.cos(lat_rad), np.sin(lon_rad), np.cos(lon_rad)
    z = np.zeros_like(sl)
    return np.stack([np.stack([-so, co, z], -1), np.stack([-sl * co, -sl * so, cl], -1),
                     np.stack([cl * co, cl * so, sl], -1)], -2)


_EXPONENTS: Final = np.array([e for e in itertools.product(range(3), repeat=3) if sum(e) <= 2])


def _monomials(u: F64) -> F64:
    return np.asarray(np.prod(u[..., None, :] ** _EXPONENTS, axis=-1))


def _chebyshev_nodes() -> F64:
    axes = [np.cos(np.pi * (np.arange(m) + 0.5) / m) for m in (4, 4, 3)]
    return np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=-1)


_NODES: Final = _chebyshev_nodes()
_FIT: Final = np.linalg.pinv(_monomials(_NODES))
_CHECKS: Final = np.concatenate([
    np.array(list(itertools.product((-1.0, 1.0), repeat=3))),
    np.random.default_rng(20_260_615).uniform(-1.0, 1.0, (8, 3))])
_CHECK_MONOMIALS: Final = _monomials(_CHECKS)


@dataclass(frozen=True)
class Maps:
    """Per block: line range, ENU origin and rotation, the quadratic map
    (E − E0, N − N0, h − h0) = a + g·p + ½ pᵀHp, and the DEM-grid box it is valid in."""

    starts: I64  # (blocks + 1,)
    origin_ecef_m: F64  # (b, 3)
    rot: F64  # (b, 3, 3) ENU rows
    a: F64  # (b, 3)
    g: F64  # (b, 3, 3) [component, axis]
    hess: F64  # (b, 3, 3, 3) [component, axis, axis]
    en0_m: F64  # (b, 2) E0, N0
    h0_m: F64  # (b,)
    box_en_m: F64  # (b, 4) west, south, east, north where the map is valid
    error_m: F64  # (b,) worst check-point error
    low_m: F64  # (b,) lowest and highest terrain the block's rays can meet (see
    high_m: F64  # fit_block_maps): the height band of the map and of the kernel's search


_PER_BLOCK: Final = ("origin_ecef_m", "rot", "a", "g", "hess", "en0_m", "h0_m", "box_en_m",
                      "error_m", "low_m", "high_m")  # Maps' fields after `starts`, in order


def fit_maps(boxes: F64, low_m: npt.ArrayLike, high_m: npt.ArrayLike, epsg: int) -> Maps:
    """Quadratic ENU → (E, N, h) maps over each EN box × [low, high] (padded; per box or one
    for all), by least squares on pyproj at Chebyshev nodes; error at independent check
    points."""
    to_geo, to_map, from_map, to_ecef = transformers(epsg)
    b = boxes.shape[0]
    low = np.broadcast_to(np.asarray(low_m, np.float64), (b,)).copy()
    high = np.broadcast_to(np.asarray(high_m, np.float64), (b,)).copy()
    en0 = np.round(0.5 * (boxes[:, :2] + boxes[:, 2:]))
    h0 = np.round(0.5 * (low + high))
    lon0, lat0 = from_map.transform(en0[:, 0], en0[:, 1])
    origin = np.stack(to_ecef.transform(lon0, lat0, h0), axis=-1)
    rot = _enu_rotation(np.radians(lat0), np.radians(lon0))
    # p-box: ENU bounding box of the EN box's corners, edge midpoints and centre at both heights
    t = np.array([0.0, 0.5, 1.0])
    fe, fn, fh = (g.ravel() for g in np.meshgrid(t, t, [0.0, 1.0], indexing="ij"))
    e = boxes[:, None, 0] + fe * (boxes[:, None, 2] - boxes[:, None, 0])
    n = boxes[:, None, 1] + fn * (boxes[:, None, 3] - boxes[:, None, 1])
    h = (low[:, None] - BAND_PAD_M) + fh * (high - low + 2.0 * BAND_PAD_M)[:, None] + 0.0 * e
    p = _map_to_enu(e, n, h, origin, rot, epsg)
    centre = 0.5 * (p.min(axis=1) + p.max(axis=1))
    half = 0.5 * (p.max(axis=1) - p.min(axis=1)) + 2.0

    def exact(u: F64) -> F64:
        q = centre[:, None] + u[None] * half[:, None]
        x = origin[:, None] + q @ rot
        lon, lat, hh = to_geo.transform(x[..., 0], x[..., 1], x[..., 2])
        ee, nn = to_map.transform(lon, lat)
        return np.stack([ee - en0[:, None, 0], nn - en0[:, None, 1], hh - h0[:, None]], -1)

    coef = _FIT @ exact(_NODES)  # (b, 10 terms, 3)
    err = np.abs(_CHECK_MONOMIALS @ coef - exact(_CHECKS))
    a, g, hess = _expand(coef, centre, half)
    return Maps(np.zeros(0, np.int64), origin, rot, a, g, hess, en0, h0, boxes.copy(),
                err.max(axis=(1, 2)), low, high)


def _map_to_enu(e: F64, n: F64, h: F64, origin: F64, rot: F64, epsg: int) -> F64:
    _, _, from_map, to_ecef = transformers(epsg)
    lon, lat = from_map.transform(e, n)
    x = np.stack(to_ecef.transform(lon, lat, h), axis=-1)
    return np.asarray((x - origin[:, None]) @ np.swapaxes(rot, 1, 2))


def _expand(coef: F64, centre: F64, half: F64) -> tuple[F64, F64, F64]:
    """Polynomial in u = (p − centre)/half → a + g·p + ½ pᵀHp (per block and component)."""
    b = coef.shape[0]
    lin = np.zeros((b, 3, 3))  # [b, k, axis] coefficient of u_axis
    quad = np.zeros((b, 3, 3, 3))  # [b, k, i, j] so that ½ uᵀ quad u is the quadratic part
    const = np.zeros((b, 3))
    for t, ex in enumerate(_EXPONENTS):
        idx = [i for i in range(3) for _ in range(ex[i])]
        if len(idx) == 0:
            const += coef[:, t]
        elif len(idx) == 1:
            lin[:, :, idx[0]] += coef[:, t]
        elif idx[0] == idx[1]:
            quad[:, :, idx[0], idx[0]] += 2.0 * coef[:, t]
        else:
            quad[:, :, idx[0], idx[1]] += coef[:, t]
            quad[:, :, idx[1], idx[0]] += coef[:, t]
    inv = 1.0 / half  # (b, 3)
    hess = quad * inv[:, None, :, None] * inv[:, None, None, :]
    g0 = lin * inv[:, None, :]
    g = g0 - np.einsum("bkij,bj->bki", hess, centre)
    a = (const - np.einsum("bki,bi->bk", g0, centre)
         + 0.5 * np.einsum("bi,bkij,bj->bk", centre, hess, centre))
    return a, g, hess


def take(maps: Maps, keep: B1) -> Maps:
    return Maps(maps.starts, *(getattr(maps, f)[keep] for f in _PER_BLOCK))


def concat(parts: list[Maps], order: I64) -> Maps:
    return Maps(np.zeros(0, np.int64),
                *(np.concatenate([getattr(p, f) for p in parts])[order] for f in _PER_BLOCK))


def with_starts(maps: Maps, starts: I64) -> Maps:
    return Maps(starts, *(getattr(maps, f) for f in _PER_BLOCK))
