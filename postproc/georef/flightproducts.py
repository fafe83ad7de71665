"""The flight's products over its georeferenced segments: each segment's own
(`segmentproducts`), the footprints, the mosaic, the strip-to-strip registration and the
summary."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from postproc.georef.dem import union_bounds
from postproc.georef.handoff import Handoff
from postproc.georef.jobrecords import GeorefOptions, SegmentResult, SegmentSkip
from postproc.georef.registration import register_strips
from postproc.georef.segmentproducts import segment_products
from postproc.products import (
    OrthoGrid,
    SwathIndex,
    footprint_feature,
    mosaic,
    write_footprints_geojson,
    write_quicklook,
)
from postproc.sync import TimeStatus


def flight_products(done: list[SegmentResult], out: Path, epsg: int, cell_m: float,
                    products: bool, notes: list[str]) -> Path | None:
    """Every segment's products, the footprints of all, and with `products` the mosaic of
    their orthos and its quicklook; the mosaic's path (None when none is made)."""
    mapped: list[tuple[SwathIndex, Path]] = []
    for seg in done:
        if (index := segment_products(seg, out, epsg, cell_m, products, notes)) is not None:
            mapped.append((index, seg.image))
    write_footprints(done, out / "footprints.geojson", epsg)
    if not (products and mapped):
        return None
    mosaic_path = out / "mosaic.tif"
    mosaic(mapped, OrthoGrid.covering(union_bounds([ix.bounds_m for ix, _ in mapped]), cell_m,
                                      epsg), mosaic_path)
    write_quicklook(mosaic_path, out / "mosaic_quicklook.png")
    return mosaic_path


def write_footprints(done: list[SegmentResult], path: Path, epsg: int) -> None:
    """The swath outline of every segment `done`, with its lines and GPS time span."""
    features = [footprint_feature(seg.igm, epsg, properties={
        "segment": seg.segment, "lines": seg.lines,
        "t_first_gps_ns": seg.t_first_gps_ns, "t_last_gps_ns": seg.t_last_gps_ns})
        for seg in done]
    write_footprints_geojson(path, features)


def registrations(out: Path, done: list[SegmentResult]) -> list[dict[str, Any]]:
    """Shift between every pair of overlapping segment orthos (cells and metres)."""
    found = []
    orthos = [(d.segment, out / d.files["ortho"]) for d in done if "ortho" in d.files]
    for k, (sa, pa) in enumerate(orthos):
        for sb, pb in orthos[k + 1:]:
            reg = register_strips(pa, pb)
            if reg is None or reg.tiles == 0:
                continue
            found.append({"segments": [sa, sb], "dx_cells": reg.dx_cells,
                          "dy_cells": reg.dy_cells, "shift_cells": reg.shift_cells,
                          "tiles": reg.tiles, "spread_cells": reg.spread_cells})
    return found


def flight_summary(options: GeorefOptions, epsg: int, handoff: Handoff,
                   done: list[SegmentResult], cell_m: float, registered: list[dict[str, Any]],
                   skipped: list[SegmentSkip], notes: list[str]) -> dict[str, Any]:
    """The job's summary (georef_summary.json): the output CRS and datum, the cell, the
    sensor, every segment, the INS records timed, the strip registration, the trajectory,
    the skips, the warnings and the recorder's counts."""
    sensor = options.sensor
    ins = handoff.sync.ins
    return {
        "crs": f"EPSG:{epsg}", "vertical": "ellipsoidal (WGS 84)"
        if options.geoid is None else "ellipsoidal (DEM + geoid)",
        "cell_m": cell_m, "sensor": sensor.name,
        "time_delay_ms": sensor.time_delay_ms,
        "segments": [{
            "segment": d.segment, "lines": d.lines, "lines_timed": d.lines_timed,
            "lines_georeferenced": d.lines_georeferenced, "rays": d.rays,
            "rays_hit": d.rays_hit, "gsd_across_m": d.gsd_across_m,
            "gsd_along_m": d.gsd_along_m, "t_first_gps_ns": d.t_first_gps_ns,
            "t_last_gps_ns": d.t_last_gps_ns, "files": d.files} for d in done],
        "ins_records_timed": int((ins.status == TimeStatus.OK).sum()),
        "ins_records": int(ins.status.size),
        "strip_registration": registered,
        "trajectory": handoff.info,
        "skipped": [skip.as_dict() for skip in skipped],
        "warnings": list(notes),
        "recording_health": handoff.recording_health.as_dict(),
    }
