"""The campaign's tasks, as a worker runs them: each takes file paths and small settings, writes
its products into the flight's folder (every file whole: the products' own writers), and gives
back a small JSON-able `Outcome`; large arrays never leave the worker. Each task takes one
core (one ortho window at a time, the ray caster on one thread): the campaign's parallelism is
its tasks.

    sync_task     a flight's log read and synchronised once; the hand-off kept for its segments
    cast_task     one segment's rays cast into its EO and IGM
    ortho_task    one segment's VRT, ortho (as a COG), GLT and quicklook
    flight_task   the flight's footprints, strip registration and summary
    mosaic_task   a mosaic of segments (one band set, one CRS and cell) from their GLTs, a COG

A task that fails on its input (a SisaError: a damaged log, a segment off its DEM) gives a
failed Outcome with the one-line reason, so that the rest of the campaign goes on; anything
else is raised, for Dask to report (or retry, for a worker lost).
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from postproc.campaign.cog import check_cog, write_cog
from postproc.campaign.config import FlightSpec
from postproc.georef import (
    GeorefJob,
    SegmentResult,
    Skipped,
    flight_summary,
    load_handoff,
    registrations,
    save_handoff,
    segment_image,
    segment_products,
    segment_raster,
    segment_rasters,
)
from postproc.products import (
    OrthoGrid,
    footprint_feature,
    mosaic,
    write_footprints_geojson,
    write_quicklook,
)
from sisa.core.errors import SisaError
from sisa.core.jsonio import finite_json
from sisa.core.outdir import partial_path, write_whole

HANDOFF_NAME: Final = "handoff.npz"  # in the flight's sync/ folder
TASK_CORES: Final = 1


@dataclass(frozen=True)
class Outcome:
    """What a task made (`record`, JSON-able) or why it could not (`reason`, one line), and
    its warnings. `failed_on_input`: the failure comes from the inputs, so a rerun with the
    same inputs would fail again (kept, not retried)."""

    ok: bool
    record: dict[str, Any] = field(default_factory=dict)
    reason: str = ""
    warnings: tuple[str, ...] = ()

    def as_dict(self) -> dict[str, Any]:
        return {"ok": self.ok, "record": self.record, "reason": self.reason,
                "warnings": list(self.warnings)}

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> Outcome:
        return cls(bool(doc["ok"]), dict(doc["record"]), str(doc["reason"]),
                   tuple(doc["warnings"]))


def _one_core() -> None:
    """The ray caster's numba loops on this thread only (the worker runs as many tasks at once
    as it has threads)."""
    import numba

    numba.set_num_threads(TASK_CORES)


def _io_bytes() -> tuple[int, int]:
    """(bytes read, bytes written) by this process so far through read/write calls, page
    cache or not (/proc/self/io rchar, wchar: what a network file system would carry); zeros
    where the kernel does not say."""
    try:
        fields = dict(line.split(": ") for line in
                      Path("/proc/self/io").read_text().splitlines())
        return int(fields["rchar"]), int(fields["wchar"])
    except (OSError, KeyError, ValueError):
        return 0, 0


def guarded(work: Callable[[], Outcome]) -> Outcome:
    """`work()`, or a failed Outcome with its one-line reason when the inputs make it fail;
    either with what the task cost (`cost` in its record: wall and CPU seconds, bytes read
    and written, the worker's peak RSS so far; measured per process, so exact with one
    thread per worker)."""
    import resource
    import time

    wall0, cpu0, (read0, written0) = time.perf_counter(), time.process_time(), _io_bytes()
    try:
        _one_core()
        outcome = work()
    except SisaError as exc:
        outcome = Outcome(False, reason=str(exc).splitlines()[0][:500] if str(exc) else
                          type(exc).__name__)
    read1, written1 = _io_bytes()
    outcome.record["cost"] = {
        "wall_s": round(time.perf_counter() - wall0, 3),
        "cpu_s": round(time.process_time() - cpu0, 3),
        "read_bytes": read1 - read0, "written_bytes": written1 - written0,
        "peak_rss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024}
    return outcome


def handoff_path(out: Path) -> Path:
    return out / "sync" / HANDOFF_NAME


def _job(flight: FlightSpec, out: Path) -> GeorefJob:
    from recorder.parts import flight_parts

    return GeorefJob(flight_parts(list(flight.log)), flight.scanner, out, flight.options)


# --- sync ----------------------------------------------------------------------------------

def sync_task(flight: FlightSpec, out: Path) -> Outcome:
    """Read and synchronise the flight once; its segments (lines each image holds and each
    lines file lists) for the segment tasks."""
    def work() -> Outcome:
        import numpy as np

        out.mkdir(parents=True, exist_ok=True)
        job = _job(flight, out)
        handoff = job.synchronise()
        rasters = segment_rasters(job.scanner_dir, handoff.sync, job.warnings)
        save_handoff(handoff_path(out), handoff)
        segs, counts = np.unique(handoff.sync.lines.segment, return_counts=True)
        listed = {int(s): int(n) for s, n in zip(segs, counts, strict=True)}
        segments = {str(s): {"lines": raw.lines, "header_lines": raw.header_lines,
                             "listed": listed.get(s, 0), "image": str(raw.path)}
                    for s, raw in rasters.items()}
        return Outcome(True, {"segments": segments, "epsg": job.epsg,
                              "recording_health": handoff.recording_health.as_dict()},
                       warnings=tuple(job.warnings))
    return guarded(work)


# --- one segment ---------------------------------------------------------------------------

def segment_record(seg: SegmentResult) -> dict[str, Any]:
    doc = dataclasses.asdict(seg)
    doc["igm"], doc["image"] = str(seg.igm), str(seg.image)
    return finite_json(doc)  # type: ignore[no-any-return]


def segment_from_record(doc: dict[str, Any]) -> SegmentResult:
    fields = dict(doc)
    fields["igm"], fields["image"] = Path(doc["igm"]), Path(doc["image"])
    for k in ("gsd_across_m", "gsd_along_m"):
        fields[k] = math.nan if doc[k] is None else float(doc[k])
    fields["files"] = dict(doc.get("files", {}))
    return SegmentResult(**fields)


def cast_task(flight: FlightSpec, out: Path, segment: int) -> Outcome:
    """Cast every ray of one segment (its EO and IGM files); the record holds its result, or
    the skip that left it out (a segment off the DEM, over voids, without times or poses)."""
    def work() -> Outcome:
        job = _job(flight, out)
        before = len(job.warnings)
        handoff = load_handoff(handoff_path(out), flight.options)
        raw, _ = segment_raster(segment_image(job.scanner_dir, segment), segment)
        skipped = Skipped()
        seg = job.segment(handoff, segment, raw, skipped, None)
        notes = tuple(job.warnings[before:])
        skips = [s.as_dict() for s in skipped.skips]
        if seg is None:
            why = skips[-1]["message"] if skips else f"segment {segment}: skipped"
            return Outcome(False, {"skipped": skips}, reason=why, warnings=notes)
        return Outcome(True, {"segment": segment_record(seg), "skipped": skips},
                       warnings=notes)
    return guarded(work)


def segment_footprint(seg: SegmentResult, epsg: int) -> dict[str, Any]:
    """The segment's swath outline as `sisa georef`'s footprints.geojson holds it."""
    return finite_json(footprint_feature(seg.igm, epsg, properties={  # type: ignore[no-any-return]
        "segment": seg.segment, "lines": seg.lines,
        "t_first_gps_ns": seg.t_first_gps_ns, "t_last_gps_ns": seg.t_last_gps_ns}))


def ortho_task(out: Path, seg_doc: dict[str, Any], epsg: int, cell_m: float) -> Outcome:
    """A segment's VRT, ortho, GLT and quicklook, as `sisa georef` writes them, then the
    ortho rewritten as a COG (the same pixels, grid and nodata) and validated."""
    def work() -> Outcome:
        import rasterio

        seg = segment_from_record(seg_doc)
        notes: list[str] = []
        segment_products(seg, out, epsg, cell_m, True, notes, workers=TASK_CORES)
        record: dict[str, Any] = {"segment": segment_record(seg),
                                  "footprint": segment_footprint(seg, epsg)}
        if "ortho" in seg.files:
            tif = out / seg.files["ortho"]
            write_cog(tif, tif)
            check_cog(tif)
            with rasterio.open(tif) as ds:
                record["ortho"] = {
                    "shape": [ds.height, ds.width], "transform": list(ds.transform)[:6],
                    "bounds": list(ds.bounds), "bands": ds.count, "dtype": ds.dtypes[0],
                    "band_names": [d or "" for d in ds.descriptions]}
        return Outcome(True, record, warnings=tuple(notes))
    return guarded(work)


# --- the flight, the campaign --------------------------------------------------------------

def flight_task(flight: FlightSpec, out: Path, seg_docs: Sequence[dict[str, Any]],
                features: Sequence[dict[str, Any]], skips: Sequence[dict[str, Any]], epsg: int,
                cell_m: float, notes: Sequence[str], health: dict[str, Any]) -> Outcome:
    """The flight's footprints, strip-to-strip registration and georef_summary.json, as
    `sisa georef` writes them, over the segments made."""
    def work() -> Outcome:
        done = [segment_from_record(d) for d in seg_docs]
        write_footprints_geojson(out / "footprints.geojson", list(features))
        handoff = load_handoff(handoff_path(out), flight.options)
        summary = flight_summary(flight.options, epsg, handoff, done, cell_m,
                                 registrations(out, done), [], list(notes))
        summary["skipped"] = list(skips)
        summary["recording_health"] = health  # the sync task's, from the log
        write_whole(out / "georef_summary.json",
                    json.dumps(finite_json(summary), indent=1, allow_nan=False) + "\n")
        return Outcome(True, {"summary": "georef_summary.json",
                              "footprints": "footprints.geojson",
                              "strip_registration": summary["strip_registration"]})
    return guarded(work)


def mosaic_task(members: Sequence[tuple[str, str]], bounds_m: Sequence[float], cell_m: float,
                epsg: int, out_tif: Path) -> Outcome:
    """The mosaic of segments [(GLT, raw image), ...] on the grid of `cell_m` over `bounds_m`
    (every cell from the segment whose pixel is nearest nadir), as a validated COG with its
    quicklook."""
    def work() -> Outcome:
        grid = OrthoGrid.covering(bounds_m, cell_m, epsg)
        plain = partial_path(out_tif, ".plain.tif")
        try:
            made = mosaic([(Path(g), Path(i)) for g, i in members], grid, plain)
            write_cog(plain, out_tif)
        finally:
            plain.unlink(missing_ok=True)
        check_cog(out_tif)
        png = out_tif.with_name(out_tif.stem + "_quicklook.png")
        write_quicklook(out_tif, png)
        return Outcome(True, {"mosaic": out_tif.name, "quicklook": png.name,
                              "cells": made.cells, "cells_filled": made.cells_filled,
                              "shape": [grid.height, grid.width],
                              "transform": list(grid.transform)[:6]})
    return guarded(work)
