"""Direct georeferencing of a whole flight: sync → navigation → per-line exterior orientation →
ray–DEM intersection of every pixel → products (seed 003, eq. 1; docs/georef.md).

    job = GeorefJob(flight_paths, scanner_dir, out_dir, options)
    result = job.run(progress)        # streams segment by segment, block of lines by block

The log is read once (sync and navigation columns in one pass). Each segment is processed in
blocks of `block_lines` lines, and each product is written block by block or tile by tile, so
memory is bounded by the navigation arrays and one block, not by the length of the flight.
Nothing here reads simulation truth.

A trajectory that covers only part of the flight (an external file, a log cut short) georeferences
what it covers: lines without a pose are NaN like lines without a time, a segment with no pose
at all is skipped, each said in `result.warnings` and the summary's `skipped`; only when no
segment has a pose does the job fail, naming the trajectory's and the lines' time spans. A DEM
that covers only part of the flight likewise: a segment whose swath lies wholly off the DEM is
skipped (its swath's and the DEM's bounds said), as is one whose DEM window holds voids only
(nodata: sea masked out, a hole in a mosaic), and only when no segment is left does the job
fail, saying why no pixel met the DEM.

Inputs that still give products but not the ones asked for are said in `result.warnings` too:
a segment whose rays miss the DEM in part (demcover.HIT_WARN_FRACTION), an ortho that holds no
pixel, a DEM of several bands, --leap-seconds where no time is on UTC, an output CRS whose grid
is not ground metres or north there. No pixel on the DEM at all is an InputError saying why (the
surface above the camera, the swath off the DEM or over its voids only), as is an ortho cell
wider than half the swath (refused at a segment's first block of rays, not after the whole
flight is cast).

The job runs the steps in order, each in a module of its own: `inputchecks` (before it
starts), `handoff` (the log read and synchronised, the trajectory), `segments` (each segment's
image and every line's time and pose), `demcover` (each swath against the DEM), `casting`
(every ray into the IGM), `orthocell` (the ortho cell), `segmentproducts` and
`flightproducts` (VRT, ortho, GLT, quicklooks, footprints, mosaic, registration, summary); its
records are `jobrecords`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from postproc.georef.casting import IgmCaster
from postproc.georef.dem import Dem
from postproc.georef.demcover import DemCover
from postproc.georef.flightproducts import flight_products, flight_summary, registrations
from postproc.georef.handoff import Handoff, read_and_sync, write_sync
from postproc.georef.inputchecks import check_output_crs, crs_notes, input_notes
from postproc.georef.jobrecords import GeorefOptions, GeorefResult, SegmentResult, SegmentSkip
from postproc.georef.orthocell import ortho_cell_m
from postproc.georef.segments import coverage, no_overlap_error, segment_eo, segment_rasters
from postproc.products import EnviRaster, Progress
from postproc.sync import SyncResult
from recorder.framing import Paths
from sisa.core.jsonio import write_json

OnSynced = Callable[[Handoff, int], None]  # the hand-off, the output EPSG
OnCast = Callable[[SegmentResult], None]


@dataclass
class Skipped:
    """The segments and lines a run skipped, and why."""

    skips: list[SegmentSkip] = field(default_factory=list)
    off_dem: list[int] = field(default_factory=list)  # swath off the DEM: skipped
    voids: list[int] = field(default_factory=list)  # DEM window of voids only: skipped


class GeorefJob:
    """One flight's georeferencing: its inputs checked when it is made, before the log is
    read; `run` once."""

    def __init__(self, flight: Paths, scanner_dir: Path, out_dir: Path,
                 options: GeorefOptions) -> None:
        self.flight = flight
        self.scanner_dir = Path(scanner_dir)
        self.out = Path(out_dir)
        self.opt = options
        self.cover = DemCover(options)
        self.epsg = self.cover.dem_epsg if options.epsg is None else options.epsg
        crs = check_output_crs(self.epsg)
        self.caster = IgmCaster.for_job(self.out, options, self.cover.dem_epsg, self.epsg)
        self.warnings: list[str] = crs_notes(crs, self.cover.dem_epsg, self.cover.dem_bounds)
        self.warnings += input_notes(options)

    def run(self, progress: Progress | None = None, on_total: Progress | None = None, *,
            on_synced: OnSynced | None = None, on_cast: OnCast | None = None
            ) -> GeorefResult:
        """Sync, then every segment; `on_total` is told the scan lines to georeference,
        `progress` each block of lines done; `on_synced` the hand-off and the output EPSG
        once the log is synchronised, `on_cast` each segment once its IGM is whole (for work
        alongside the products: `sisa process`'s accuracy)."""
        handoff = self.synchronise()
        if on_synced is not None:
            on_synced(handoff, self.epsg)
        rasters = segment_rasters(self.scanner_dir, handoff.sync, self.warnings)
        if on_total is not None:
            on_total(sum(raw.lines for raw in rasters.values()))
        done: list[SegmentResult] = []
        skipped = Skipped()
        for s, raw in rasters.items():
            if (seg := self.segment(handoff, s, raw, skipped, progress)) is not None:
                done.append(seg)
                if on_cast is not None:
                    on_cast(seg)
        self.check_any_done(handoff, done, skipped)
        cell_m = ortho_cell_m(self.opt, done)
        mosaic_path = flight_products(done, self.out, self.epsg, cell_m, self.opt.products,
                                      self.warnings)
        summary = flight_summary(self.opt, self.epsg, handoff, done, cell_m,
                                 registrations(self.out, done), skipped.skips, self.warnings)
        write_json(self.out / "georef_summary.json", summary)
        if not isinstance(handoff.sync, SyncResult):  # read_and_sync's is always whole
            raise TypeError("a hand-off read back from its file cannot make a GeorefResult")
        return GeorefResult(handoff.sync, handoff.trajectory, self.epsg, cell_m, done,
                            mosaic_path, summary, skipped.skips, list(self.warnings),
                            log_fixes=handoff.log_fixes, recording_health=handoff.recording_health)

    def synchronise(self) -> Handoff:
        """The log read once and synchronised, the trajectory built, the sync's files written
        in OUT/sync: the first step, done once per flight (a campaign hands the result to each
        segment's task through `save_handoff`)."""
        self.out.mkdir(parents=True, exist_ok=True)
        handoff = read_and_sync(self.flight, self.scanner_dir, self.opt, self.warnings)
        write_sync(self.out, handoff.sync)
        return handoff

    def check_any_done(self, handoff: Handoff, done: list[SegmentResult], skipped: Skipped
                       ) -> None:
        """The job's one error when no segment could be georeferenced, saying why."""
        if not done and not skipped.off_dem and not skipped.voids:
            raise no_overlap_error(handoff, self.flight)
        if not any(d.rays_hit for d in done):
            raise self.cover.no_hit_error(done, skipped.off_dem, skipped.voids)

    def segment(self, handoff: Handoff, s: int, raw: EnviRaster, skipped: Skipped,
                progress: Progress | None = None) -> SegmentResult | None:
        """One segment: its lines' times and poses, its swath against the DEM, its rays cast;
        None when it is skipped whole (said in `skipped` and the warnings)."""
        eo, t = segment_eo(handoff, self.opt.sensor, self.scanner_dir, s, raw.lines,
                           raw.header_lines)
        if (skip := coverage(handoff, s, eo, t)) is not None:
            self._skip(skipped, skip)
        dem: Dem | None = None
        if eo.valid.any():
            if (off := self.cover.off_dem_skip(s, eo, t)) is not None:
                skipped.off_dem.append(s)
            elif (dem := self.cover.dem_window(s, eo)) is None:
                off = self.cover.void_skip(s, t)
                skipped.voids.append(s)
            if off is not None:
                self._skip(skipped, off)
        if dem is None:
            if progress is not None:
                progress(raw.lines)
            return None
        seg = self.caster.cast(s, eo, t, raw, dem, progress)
        posed = int(eo.valid.sum()) * raw.pixels
        if (note := self.cover.partial_hit_note(s, seg.rays_hit, posed)) is not None:
            self.warnings.append(note)
        return seg

    def _skip(self, skipped: Skipped, skip: SegmentSkip) -> None:
        skipped.skips.append(skip)
        self.warnings.append(skip.message)
