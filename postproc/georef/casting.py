"""Every ray of one segment cast on its DEM window into the segment's IGM (and its EO file),
block of lines by block, with the segment's median pixel spacings; a --cell too wide for its
ortho is refused at the first block of rays."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
from pyproj import Transformer

from postproc.georef.dem import Dem
from postproc.georef.exterior import LineEo, write_eo_csv
from postproc.georef.jobrecords import GeorefOptions, SegmentResult
from postproc.georef.orthocell import EARLY_CELL_MARGIN, check_cell_against_swath
from postproc.georef.raycast import intersect
from postproc.georef.sensorfile import SensorModel
from postproc.products import EnviRaster, IgmWriter, Progress

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


@dataclass(frozen=True)
class IgmCaster:
    """What casting a segment needs of the job, set up once: where the files go, the sensor,
    the output CRS (and the transform to it from the DEM's, None when they are one), the lines
    per block, and the --cell to check at the first block (None: no ortho, or no --cell)."""

    out: Path
    sensor: SensorModel
    epsg: int
    to_out: Transformer | None
    block_lines: int
    cell_to_check: float | None

    @classmethod
    def for_job(cls, out: Path, options: GeorefOptions, dem_epsg: int, epsg: int
                ) -> IgmCaster:
        to_out = (None if epsg == dem_epsg else
                  Transformer.from_crs(dem_epsg, epsg, always_xy=True))
        # a --cell too wide for the orthos is refused at the segment's first block of rays,
        # not once the whole flight is cast (minutes on a long one); without products, no ortho
        return cls(out, options.sensor, epsg, to_out, options.block_lines,
                   options.cell_m if options.products else None)

    def cast(self, segment: int, eo: LineEo, t_gps_ns: I64, raw: EnviRaster, dem: Dem,
             progress: Progress | None) -> SegmentResult:
        """Every ray of the segment cast on `dem`, its window (`DemCover.dem_window`)."""
        image, n_lines, pixels = raw.path, raw.lines, raw.pixels
        self.sensor.check_pixels(pixels, str(image))
        look = self.sensor.scanner.look_vectors_camera()
        stem = self.out / f"segment_{segment:03d}"
        write_eo_csv(Path(f"{stem}_eo.csv"), segment, np.arange(n_lines), eo)
        hits = 0
        geo_lines = 0
        cell_to_check = self.cell_to_check
        across: list[F64] = []
        along: list[F64] = []
        with IgmWriter(Path(f"{stem}_igm"), n_lines, pixels, self.epsg) as igm:
            for lo in range(0, n_lines, self.block_lines):
                hi = min(lo + self.block_lines, n_lines)
                east, north, height = (np.full((hi - lo, pixels), np.nan) for _ in range(3))
                ok = np.flatnonzero(eo.valid[lo:hi])
                if ok.size:
                    gp = intersect(dem, eo.centre_ecef_m[lo:hi][ok],
                                   eo.r_ecef_from_camera[lo:hi][ok], look)
                    east[ok], north[ok], height[ok] = gp.easting_m, gp.northing_m, gp.height_m
                if self.to_out is not None:
                    east, north = self.to_out.transform(east, north)
                    east, north = np.asarray(east), np.asarray(north)
                igm.write_block(lo, east, north, height)
                good = np.isfinite(east)
                hits += int(good.sum())
                geo_lines += int(good.any(axis=1).sum())
                across.append(np.hypot(np.diff(east, axis=1), np.diff(north, axis=1))[::16]
                              .ravel())
                if cell_to_check is not None and math.isfinite(gsd := _median(across[-1:])):
                    check_cell_against_swath(cell_to_check, segment, gsd * max(pixels - 1, 0),
                                             gsd, margin=EARLY_CELL_MARGIN)
                    cell_to_check = None
                mid = pixels // 2
                along.append(np.hypot(np.diff(east[:, mid]), np.diff(north[:, mid])))
                if progress is not None:
                    progress(hi - lo)
        timed = t_gps_ns >= 0
        return SegmentResult(
            segment=segment, lines=n_lines, lines_timed=int(timed.sum()),
            lines_georeferenced=geo_lines, rays=n_lines * pixels, rays_hit=hits,
            gsd_across_m=_median(across), gsd_along_m=_median(along),
            t_first_gps_ns=int(t_gps_ns[timed].min()) if timed.any() else -1,
            t_last_gps_ns=int(t_gps_ns[timed].max()) if timed.any() else -1,
            igm=Path(f"{stem}_igm.bil"), image=image,
            files={"eo": f"{stem.name}_eo.csv", "igm": f"{stem.name}_igm.bil"})


def _median(parts: list[F64]) -> float:
    vals = np.concatenate(parts) if parts else np.zeros(0)
    vals = vals[np.isfinite(vals)]
    return float(np.median(vals)) if vals.size else math.nan
