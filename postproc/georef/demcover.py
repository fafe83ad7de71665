"""Where each segment's swath lies against the DEM: the DEM window read under it, and the skip,
warning or error when its rays cannot meet the DEM (the swath off the DEM, over its voids only,
or under its surface)."""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt
from pyproj import Transformer

from postproc.georef.dem import (
    DEFAULT_MARGIN_M,
    GEOID_UNDULATION_M,
    Dem,
    bounds_text,
    dem_extent,
    height_range,
    union_bounds,
)
from postproc.georef.exterior import LineEo
from postproc.georef.jobrecords import GeorefOptions, SegmentResult, SegmentSkip
from sisa.core.errors import InputError

I64 = npt.NDArray[np.int64]

FOOTPRINT_MARGIN_M: Final = 300.0  # DEM window beyond the estimated swath
# how far the DEM window reaches beyond the swath (Dem.read adds its margin to ours)
WINDOW_REACH_M: Final = FOOTPRINT_MARGIN_M + DEFAULT_MARGIN_M
# below this share of a segment's pixels (of its lines with a pose) on the DEM, a warning: the
# headline's percentage alone let a DEM covering half the flight pass unremarked
HIT_WARN_FRACTION: Final = 0.99


@dataclass(frozen=True)
class SwathOnDem:
    """Where a segment's swath lies against the DEM: what the messages need when its rays
    miss. Heights are ellipsoidal (m); `footprint_m` in the DEM's CRS, without margin."""

    footprint_m: tuple[float, float, float, float]
    camera_m: tuple[float, float]  # lowest, highest perspective centre (every 64th line)
    surface_m: tuple[float, float]  # lowest, highest valid height of the DEM window read
    on_dem: bool  # the footprint lies within the DEM's cell centres


class DemCover:
    """The job's DEM against its segments' swaths: its extent read once, each segment's swath
    placed on it (`swaths`, for the messages)."""

    def __init__(self, options: GeorefOptions) -> None:
        self.opt = options
        self.dem_epsg, self.dem_bounds = dem_extent(options.dem)
        self.swaths: dict[int, SwathOnDem] = {}

    @functools.cached_property
    def dem_height_range_m(self) -> tuple[float, float]:
        """Lowest and highest DEM heights (from a 1/16 overview, voids left out, ±50 m), read
        once per job."""
        found = height_range(self.opt.dem)
        return (0.0, 0.0) if found is None else (found[0] - 50.0, found[1] + 50.0)

    def swath_footprint(self, eo: LineEo, pick: I64, heights_m: tuple[float, float]
                        ) -> tuple[float, float, float, float]:
        """(west, south, east, north) in the DEM's CRS of where the edge and centre rays of the
        lines `pick` meet the heights `heights_m` (lowest, highest, ellipsoidal)."""
        look = self.opt.sensor.scanner.look_vectors_camera()
        to_geo = Transformer.from_crs(4978, 4979, always_xy=True)
        to_dem = Transformer.from_crs(4979, self.dem_epsg, always_xy=True)
        c = eo.centre_ecef_m[pick]
        lon, lat, h = to_geo.transform(c[:, 0], c[:, 1], c[:, 2])
        up = np.stack([np.cos(np.radians(lat)) * np.cos(np.radians(lon)),
                       np.cos(np.radians(lat)) * np.sin(np.radians(lon)),
                       np.sin(np.radians(lat))], axis=1)
        pts = []
        for j in (0, look.shape[1] // 2, look.shape[1] - 1):
            d = np.einsum("nij,j->ni", eo.r_ecef_from_camera[pick], look[:, j])
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            down = -np.einsum("ni,ni->n", d, up)
            for target in heights_m:
                s = np.where(down > 0.05, (h - target) / np.maximum(down, 0.05), 0.0)
                s = np.clip(s, 0.0, 50_000.0)
                p = c + s[:, None] * d
                plon, plat, _ = to_geo.transform(p[:, 0], p[:, 1], p[:, 2])
                pts.append(np.stack(to_dem.transform(plon, plat), axis=1))
        xy = np.concatenate(pts)
        return (float(xy[:, 0].min()), float(xy[:, 1].min()), float(xy[:, 0].max()),
                float(xy[:, 1].max()))

    def _camera_heights_m(self, eo: LineEo, pick: I64) -> tuple[float, float]:
        c = eo.centre_ecef_m[pick]
        _, _, h = Transformer.from_crs(4978, 4979, always_xy=True).transform(
            c[:, 0], c[:, 1], c[:, 2])
        return float(np.min(h)), float(np.max(h))

    def off_dem_skip(self, segment: int, eo: LineEo, t_gps_ns: I64) -> SegmentSkip | None:
        """The skip of a segment whose swath lies wholly off the DEM, where none of its rays
        can meet it; None when the swath touches the DEM. (Such a segment once failed the
        whole job when its DEM window was empty, or made an IGM of NaN.) The swath is placed
        as in `dem_window`, but through the last line too and over the heights a geoid can
        add, so that a segment with a ray on the DEM is never skipped."""
        valid = np.flatnonzero(eo.valid)
        pick = valid[::64]
        if valid.size and pick[-1] != valid[-1]:
            pick = np.append(pick, valid[-1])
        h_lo, h_hi = self.dem_height_range_m
        if isinstance(self.opt.geoid, Path):
            h_lo, h_hi = h_lo + GEOID_UNDULATION_M[0], h_hi + GEOID_UNDULATION_M[1]
        elif self.opt.geoid is not None:
            h_lo, h_hi = h_lo + float(self.opt.geoid), h_hi + float(self.opt.geoid)
        foot = self.swath_footprint(eo, pick, (h_lo, h_hi))
        w, s, e, n = self.dem_bounds
        if not (foot[2] < w or foot[0] > e or foot[3] < s or foot[1] > n):
            return None
        self.swaths[segment] = SwathOnDem(foot, self._camera_heights_m(eo, pick),
                                          (math.nan, math.nan), False)
        lines, timed = t_gps_ns.size, int((t_gps_ns >= 0).sum())
        return SegmentSkip(
            segment, lines, timed, lines, True, "off the DEM", (),
            f"segment {segment}: skipped, its swath {bounds_text(foot)} lies off the DEM "
            f"{self.opt.dem.name} {bounds_text(self.dem_bounds)}")

    def dem_window(self, segment: int, eo: LineEo) -> Dem | None:
        """The DEM under the segment's swath: edge and centre rays of every 64th line met with
        the DEM's lowest and highest heights, plus a margin (None when it holds voids only:
        `void_skip`); where the swath lies against the DEM goes to `swaths` (for the messages
        when rays miss)."""
        pick = np.flatnonzero(eo.valid)[::64]
        if pick.size == 0:  # the job skips such segments
            raise InputError("no line of the segment has a time and a pose: no DEM window")
        foot = self.swath_footprint(eo, pick, self.dem_height_range_m)
        m = FOOTPRINT_MARGIN_M
        dem = Dem.read(self.opt.dem, bounds_m=(foot[0] - m, foot[1] - m, foot[2] + m,
                                               foot[3] + m), geoid=self.opt.geoid,
                       voids_only_ok=True)
        valid = dem.heights_m[np.isfinite(dem.heights_m)]
        surface = ((float(valid.min()), float(valid.max())) if valid.size else
                   (math.nan, math.nan))
        inside = all(self.dem_bounds[k] <= foot[k] for k in (0, 1)) and all(
            foot[k] <= self.dem_bounds[k] for k in (2, 3))
        self.swaths[segment] = SwathOnDem(foot, self._camera_heights_m(eo, pick), surface,
                                          inside)
        return dem if valid.size else None

    def void_skip(self, segment: int, t_gps_ns: I64) -> SegmentSkip:
        """The skip of a segment whose DEM window holds voids only (no valid height within
        WINDOW_REACH_M of its swath: sea masked out, a hole in a mosaic), where none of its
        rays can meet the DEM. (Such a segment once failed the whole job, "the DEM has no
        valid height in the window".)"""
        foot = self.swaths[segment].footprint_m
        lines, timed = t_gps_ns.size, int((t_gps_ns >= 0).sum())
        return SegmentSkip(
            segment, lines, timed, lines, True, "DEM voids", (),
            f"segment {segment}: skipped, its swath {bounds_text(foot)} lies over DEM voids "
            f"only (nodata): the DEM {self.opt.dem.name} has no valid height within "
            f"{WINDOW_REACH_M:g} m of it")

    def partial_hit_note(self, segment: int, hits: int, posed: int) -> str | None:
        """The warning for a segment whose rays (`posed`, of its lines with a pose) miss the
        DEM in part, with the likeliest reason; None when at least HIT_WARN_FRACTION meet it."""
        if not posed or hits >= HIT_WARN_FRACTION * posed:
            return None
        swath = self.swaths[segment]
        if not swath.on_dem:
            why = "the DEM does not cover the whole swath?"
        elif swath.surface_m[1] >= swath.camera_m[0]:
            why = "terrain above the camera?"
        else:
            why = "voids in the DEM under the swath?"
        if hits == 0:
            return (f"segment {segment}: none of its pixels meet the DEM {self.opt.dem.name} "
                    f"({why}){': no ortho made for it' if self.opt.products else ''}")
        share = math.floor(1000 * hits / posed) / 10  # 98.96 % is not "99.0 %"
        return (f"segment {segment}: {share:.1f} % of its pixels meet the DEM "
                f"{self.opt.dem.name} ({why})")

    def no_hit_error(self, done: list[SegmentResult], off_dem: Sequence[int] = (),
                     voids: Sequence[int] = ()) -> InputError:
        """No ray of any segment met the DEM (`done`), or its swath lay off the DEM (`off_dem`,
        skipped) or over its voids only (`voids`, skipped): the one line that says why. It once
        always asked "does the DEM cover the flight?", also of a DEM that did, 8 km above the
        aircraft."""
        swaths = [self.swaths[s] for s in [d.segment for d in done] + list(off_dem) +
                  list(voids)]
        cam = min(sw.camera_m[0] for sw in swaths), max(sw.camera_m[1] for sw in swaths)
        under = [sw.surface_m for sw in swaths if not math.isnan(sw.surface_m[0])]
        surf = ((min(lo for lo, _ in under), max(hi for _, hi in under)) if under else
                (math.nan, math.nan))
        heights = (f"the DEM {_span_text(surf)} under the swaths"
                   f"{' (geoid added)' if self.opt.geoid is not None else ''}, the camera "
                   f"{_span_text(cam)}, both ellipsoidal")
        head = f"no pixel could be georeferenced on {self.opt.dem}"
        if under and surf[0] >= cam[1]:
            return InputError(f"{head}: its surface lies above the camera ({heights}): heights "
                              "in other units, or a wrong geoid?")
        if voids:
            return InputError(f"{head}: {self._voids_text(done, off_dem, voids)}")
        if not all(sw.on_dem for sw in swaths):
            foot = union_bounds([sw.footprint_m for sw in swaths])
            return InputError(f"{head}: the swaths {bounds_text(foot)} run off the DEM "
                              f"{bounds_text(self.dem_bounds)}")
        return InputError(f"{head}: the DEM covers the swaths, but no ray met its surface "
                          f"({heights})")

    def _voids_text(self, done: list[SegmentResult], off_dem: Sequence[int],
                    voids: Sequence[int]) -> str:
        """Why no pixel met the DEM when some swaths lie over its voids only."""
        foot = bounds_text(union_bounds([self.swaths[s].footprint_m for s in
                                         [d.segment for d in done] + [*off_dem, *voids]]))
        if not done and not off_dem:
            one = len(voids) == 1
            return (f"the swath{'' if one else 's'} {foot} lie{'s' if one else ''} over DEM "
                    f"voids only (nodata): no valid height within {WINDOW_REACH_M:g} m of "
                    f"{'it' if one else 'them'}")
        said = [f"{len(voids)} lie{'s' if len(voids) == 1 else ''} over DEM voids only (nodata)"]
        if off_dem:
            said.append(f"{len(off_dem)} off the DEM {bounds_text(self.dem_bounds)}")
        if done:
            said.append(f"no ray of the other {len(done)} met the DEM")
        return (f"of the {len(done) + len(off_dem) + len(voids)} swaths {foot}, "
                f"{', '.join(said[:-1])} and {said[-1]}")


def _span_text(span: tuple[float, float]) -> str:
    """Heights (m) for a message: "898 to 902 m", or "9000 m" when both round alike."""
    low, high = (f"{v:.0f}" for v in span)
    return f"{low} m" if low == high else f"{low} to {high} m"
