"""`sisa georef`: sync + direct georeferencing of a flight log onto a DEM, with the products.

OUT/
  sync/                      ins_times.csv, line_times.csv, sync_report.json (as `sisa sync`)
  segment_NNN_eo.csv         exterior orientation of every line (GPS ns, perspective centre,
                             attitude)
  segment_NNN_igm.bil/.hdr   ENVI IGM: easting, northing, ellipsoidal height of every pixel
                             centre (float64, NaN where the ray missed the DEM)
  segment_NNN_geoloc.vrt     the raw image with GDAL GEOLOCATION arrays (PIXEL_CENTER), for
                             `gdalwarp -geoloc`
  segment_NNN_glt.bil/.hdr   ENVI GLT: input sample/line of every output cell
  segment_NNN_ortho.tif      orthorectified segment (nearest neighbour, nodata outside)
  segment_NNN_quicklook.png
  mosaic.tif, mosaic_quicklook.png   all segments, each cell from the strip nearest nadir
  footprints.geojson         swath outline of every segment (WGS 84 lon/lat)
  georef_summary.json        CRS, cell size, per-segment counts and pixel spacing, the
                             trajectory's span, what was skipped and why
  photos/                    with --camera and --photo-times, the frame camera's: photo_eo.csv
                             (Metashape/Pix4D), geo.txt (OpenDroneMap), sidecars/, footprints,
                             and with --photos each photo's IGM, ortho and GLT, the photos'
                             mosaic; photo_summary.json (docs/frames.md)

A trajectory that covers only part of the flight georeferences the segments (and lines) it
covers, a DEM that covers only part of it the segments whose swath meets it; each segment or
stretch of lines skipped is one warning line on stderr.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sisa.commands import (
    FLIGHT_HELP,
    SubParsers,
    add_command,
    add_force_arg,
    check_inputs,
    finished_with_losses,
    flight_parts,
    say_warning,
)
from sisa.commands.progress import Progress, progress
from sisa.core.errors import InputError
from sisa.core.outdir import staged_output_dir

if TYPE_CHECKING:
    from postproc.georef import GeorefOptions, GeorefResult, OnCast, OnSynced, PhotoTimes
    from sisa.core.framecamera import FrameCamera

MAX_CELL_M = 10_000.0  # an ortho cell wider than any swath


def register(sub: SubParsers[argparse.ArgumentParser]) -> None:
    parser = add_command(sub, "georef", "put every scan line on GPS time and every pixel on the "
                         "DEM: IGM, geolocation VRT, GLT, ortho, mosaic, footprints",
                         "sisa georef runs/bench/flight.mcap --scanner runs/bench/scanner "
                         "--dem runs/bench/terrain/dem.tif --out runs/bench-georef")
    parser.add_argument("flight", nargs="+", type=Path, metavar="FLIGHT",
                        help=FLIGHT_HELP)
    parser.add_argument("--scanner", type=Path, required=True, metavar="DIR",
                        help="the scanner's recording folder (segment_NNN.bil/.hdr/.lines.csv)")
    parser.add_argument("--dem", type=Path, required=True, help="DEM GeoTIFF (projected CRS)")
    parser.add_argument("--out", type=Path, required=True, help="new output folder")
    add_force_arg(parser)
    add_georef_args(parser)
    parser.add_argument("--camera", type=Path, default=None, metavar="TOML",
                        help="the frame camera's file (interior orientation, mounting): with "
                             "--photo-times, its photos' EO, footprints and orthos in OUT/photos")
    parser.add_argument("--photo-times", type=Path, default=None, metavar="CSV",
                        help="photo times table: photo_number, t_mid_gps_ns (GPS ns); default: "
                             "the photos the sync of the flight log times")
    parser.add_argument("--photos", type=Path, default=None, metavar="DIR",
                        help="the camera's photos (photo_NNNNNN.bil/.hdr): their orthos and "
                             "mosaic")
    add_photo_cell_arg(parser)
    parser.set_defaults(handler=_run)


def add_photo_cell_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--photo-cell", type=float, default=None, metavar="M",
                        help="the photo orthos' cell in metres (default: the photos' pixel "
                             "spacing)")


@dataclass(frozen=True)
class PhotoInputs:
    """What the frame camera's products need besides the scanner's job."""

    camera: FrameCamera
    times: PhotoTimes | None  # None: the photos the sync of the log times (`synced_inputs`)
    images: dict[str, Path] | None
    cell_m: float | None
    images_dir: Path | None = None  # --photos, for photos timed by the sync


def photo_images(folder: Path, times: PhotoTimes) -> dict[str, Path]:
    """label → image file of every photo of the table found in `folder`."""
    return {label: folder / f"{label}.bil" for label in times.labels
            if (folder / f"{label}.bil").is_file()}


def check_photo_cell(cell_m: float | None) -> None:
    if cell_m is not None and not 0 < cell_m <= MAX_CELL_M:
        raise InputError(f"--photo-cell {cell_m:g}: must be a positive size in metres, at "
                         f"most {MAX_CELL_M:g}")


def photo_inputs_from_args(args: argparse.Namespace) -> PhotoInputs | None:
    """The camera, its photo times and images, checked before the job starts; None without
    --camera (then --photo-times and --photos are refused)."""
    from postproc.georef import load_camera, read_photo_times

    if args.camera is None:
        given = [n for n, v in (("--photo-times", args.photo_times), ("--photos", args.photos),
                                ("--photo-cell", args.photo_cell)) if v is not None]
        if given:
            raise InputError(f"{given[0]} needs --camera (the frame camera's file)")
        return None
    check_photo_cell(args.photo_cell)
    camera = load_camera(args.camera)
    if args.photo_times is None:  # timed by the sync, once the job has read the log
        return PhotoInputs(camera, None, None, args.photo_cell, args.photos)
    times = read_photo_times(args.photo_times)
    images = None if args.photos is None else photo_images(args.photos, times)
    return PhotoInputs(camera, times, images, args.photo_cell)


def synced_photo_times(photos: Any) -> PhotoTimes:
    """The sync's photos that have a number and a time (status ok or board_time) as the photo
    path's table (`postproc.georef.PhotoTimes`); a repeated number (the camera's counter
    wrapped) keeps its first photo."""
    import numpy as np

    from postproc.georef import PhotoTimes
    from postproc.sync import PhotoStatus

    keep = np.isin(photos.status, (PhotoStatus.OK, PhotoStatus.BOARD_TIME))
    numbers, times = photos.photo_number[keep], photos.t_gps_ns[keep]
    first = np.sort(np.unique(numbers, return_index=True)[1])
    return PhotoTimes(numbers[first], times[first])


def synced_inputs(photos: PhotoInputs, result: GeorefResult) -> PhotoInputs:
    """Photo inputs whose times are still to come (--camera without --photo-times) with the
    photos the sync of the log timed; InputError for a log without a frame camera's photos."""
    if photos.times is not None:
        return photos
    synced = getattr(result.sync, "photos", None)
    if synced is None:
        raise InputError("--camera: the flight log holds no photo of a frame camera (no "
                         "/camera/photo records): give --photo-times")
    times = synced_photo_times(synced)
    images = None if photos.images_dir is None else photo_images(photos.images_dir, times)
    return dataclasses.replace(photos, times=times, images=images)


def run_photos(out: Path, result: GeorefResult, options: GeorefOptions, photos: PhotoInputs,
               bar: Progress, command: str = "georef") -> dict[str, Any]:
    """The frame camera's products into OUT/photos (postproc.georef.photo_products), its
    warnings one line each on stderr."""
    from postproc.georef import photo_products

    bar.step("photos: EO, footprints, orthos, mosaic")
    assert photos.times is not None, "synced_inputs first"
    folder = out / "photos"
    folder.mkdir(exist_ok=True)  # `sisa process` may have rendered the photos into it
    summary = photo_products(folder, result.trajectory, options.dem, photos.times,
                             photos.camera, photos.images, epsg=result.epsg,
                             geoid=options.geoid, cell_m=photos.cell_m)
    for warning in summary["warnings"]:
        say_warning(command, f"photos: {warning}")
    return summary


def photo_headline(summary: dict[str, Any]) -> str:
    return (f"{summary['posed']}/{summary['photos']} photos with a pose, "
            f"{summary['footprints']} footprints, {summary['orthos']} orthos"
            + (f" (cell {summary['cell_m']:g} m)" if summary["cell_m"] else ""))


def photo_losses(summary: dict[str, Any], images_given: bool) -> str | None:
    """Photos the inputs promised and the products lack: a pose for every photo, and with
    images an ortho for every one."""
    want = summary["photos"]
    made = summary["orthos"] if images_given else summary["posed"]
    return None if made >= want else f"{want - made} of {want} photos without " + (
        "an ortho" if images_given else "a pose")


SENSOR_DEFAULT = "a nominal CASI-501 with zero offsets"


def add_georef_args(parser: argparse.ArgumentParser, sensor_default: str = SENSOR_DEFAULT
                    ) -> None:
    parser.add_argument("--sensor", type=Path, default=None, metavar="TOML",
                        help="sensor/calibration file (scanner geometry, mounting, time delay); "
                             f"default: {sensor_default}")
    parser.add_argument("--crs", type=int, default=None, metavar="EPSG",
                        help="output CRS, projected in metres (default: the DEM's)")
    parser.add_argument("--cell", type=float, default=None, metavar="M",
                        help="ortho cell size in metres (default: the pixel spacing)")
    parser.add_argument("--trajectory", type=Path, default=None, metavar="FILE",
                        help="RTKLIB .pos or Applanix SBET instead of the log's GPS fixes")
    parser.add_argument("--leap-seconds", type=int, default=None, metavar="N",
                        help="GPS - UTC in seconds for a --trajectory .pos on UTC or JST "
                             "(default: as the flight log's receiver messages state it)")
    parser.add_argument("--max-gap-s", type=float, default=None, metavar="S",
                        help="longest gap the navigation bridges: between SBET records "
                             "(default 0.25), between GPS fixes or .pos solutions, by the INS "
                             "(default 30)")
    geoid = parser.add_mutually_exclusive_group()
    geoid.add_argument("--geoid", type=Path, default=None, metavar="TIF",
                       help="geoid undulation raster: the DEM holds orthometric heights")
    geoid.add_argument("--geoid-m", type=float, default=None, metavar="N",
                       help="constant geoid undulation for an orthometric DEM (-110 to "
                            "110 m)")
    parser.add_argument("--no-products", action="store_true",
                        help="only EO, IGM and the geolocation VRT (no ortho, GLT, mosaic)")


def options_from_args(args: argparse.Namespace, sensor_default: object = None
                      ) -> GeorefOptions:
    from postproc.georef import (
        LEAP_SECONDS_RANGE,
        MAX_GAP_LIMIT_S,
        GeorefOptions,
        SensorModel,
        check_undulation_m,
    )

    if args.sensor is not None:
        sensor = SensorModel.load(args.sensor)
    elif isinstance(sensor_default, SensorModel):
        sensor = sensor_default
    else:
        sensor = SensorModel()
    if args.cell is not None and not args.cell > 0:
        raise InputError(f"--cell {args.cell:g}: must be a positive size in metres")
    if args.cell is not None and args.cell > MAX_CELL_M:
        raise InputError(f"--cell {args.cell:g}: must be at most {MAX_CELL_M:g} m")
    if args.crs is not None and args.crs <= 0:
        raise InputError(f"--crs {args.crs}: not a valid EPSG code (a positive integer)")
    lo, hi = LEAP_SECONDS_RANGE
    if args.leap_seconds is not None and not lo <= args.leap_seconds <= hi:
        raise InputError(f"--leap-seconds {args.leap_seconds}: must be {lo} to {hi} (GPS - UTC: "
                         "18 since 2017)")
    if args.max_gap_s is not None and not 0 < args.max_gap_s <= MAX_GAP_LIMIT_S:
        raise InputError(f"--max-gap-s {args.max_gap_s}: must be a positive number of seconds, "
                         f"at most {MAX_GAP_LIMIT_S}")
    if args.geoid_m is not None:  # up front: 1e308 was an overflow traceback
        check_undulation_m(args.geoid_m, "--geoid-m")
    geoid = args.geoid if args.geoid is not None else args.geoid_m
    return GeorefOptions(sensor=sensor, dem=args.dem, geoid=geoid, epsg=args.crs,
                         cell_m=args.cell, trajectory=args.trajectory,
                         products=not args.no_products, leap_seconds=args.leap_seconds,
                         max_gap_s=args.max_gap_s)


def run_georef(flight: list[Path], scanner: Path, out: Path, options: GeorefOptions,
               bar: Progress, command: str = "georef", *, on_synced: OnSynced | None = None,
               on_cast: OnCast | None = None) -> GeorefResult:
    """The job, its steps shown on `bar` (reading and sync, then the scan lines, then the
    products); its warnings (segments or lines skipped, and why) one line each on stderr;
    `on_synced` and `on_cast` as `GeorefJob.run`'s."""
    from postproc.georef import GeorefJob

    job = GeorefJob(flight, scanner, out, options)
    bar.step("reading the flight log and synchronising")

    def on_total(lines: int) -> None:
        bar.step("georeferencing", lines, "lines")

    def advance(lines: int) -> None:
        bar.advance(lines)
        if bar.total is not None and bar.completed >= bar.total:
            bar.step("ortho, mosaic, footprints" if options.products else "footprints")

    result = job.run(progress=advance, on_total=on_total, on_synced=on_synced, on_cast=on_cast)
    for warning in result.warnings:
        say_warning(command, warning)
    return result


def lines_promised(result: GeorefResult) -> int:
    """The scan lines the inputs promised: per segment, the lines its image holds or its lines
    file lists, whichever are more (an image cut short holds fewer; a lines file cut short
    lists fewer)."""
    import numpy as np

    segs, counts = np.unique(result.sync.lines.segment, return_counts=True)
    per = {int(s): int(n) for s, n in zip(segs, counts, strict=True)}
    made = [(d.segment, d.lines) for d in result.segments]
    skipped = [(s.segment, s.lines) for s in result.skipped if s.whole_segment]
    for segment, lines in made + skipped:
        per[segment] = max(per.get(segment, 0), lines)
    return sum(per.values())


def lines_georeferenced(result: GeorefResult) -> tuple[int, int]:
    """(lines georeferenced, lines promised)."""
    return sum(s.lines_georeferenced for s in result.segments), lines_promised(result)


def losses(result: GeorefResult) -> str | None:
    """What the headline lacks against the inputs' promise, said as the exit 3 line."""
    geo, lines = lines_georeferenced(result)
    return None if geo >= lines else f"{lines - geo} of {lines} scan lines not georeferenced"


def headline(result: GeorefResult) -> str:
    whole = [s for s in result.skipped if s.whole_segment]
    geo, lines = lines_georeferenced(result)
    rays = sum(s.rays for s in result.segments)
    hit = sum(s.rays_hit for s in result.segments)
    segments = (f"{len(result.segments)} segments" if not whole else
                f"{len(result.segments)} of {len(result.segments) + len(whole)} segments "
                f"({len(whole)} skipped)")
    return (f"{segments}, {geo}/{lines} lines georeferenced, "
            f"{hit / max(rays, 1):.2%} of pixels on the DEM, EPSG:{result.epsg}, "
            f"cell {result.cell_m:g} m")


def _run(args: argparse.Namespace) -> int:
    started = time.perf_counter()
    check_inputs(("", args.flight, "file"), ("--scanner", args.scanner, "folder"),
                 ("--dem", args.dem, "file"), ("--sensor", args.sensor, "file"),
                 ("--trajectory", args.trajectory, "file"), ("--geoid", args.geoid, "file"),
                 ("--camera", args.camera, "file"), ("--photo-times", args.photo_times, "file"),
                 ("--photos", args.photos, "folder"))
    options = options_from_args(args)
    photos = photo_inputs_from_args(args)
    summary = None
    with staged_output_dir(args.out, force=args.force) as out, progress("georef") as bar:
        result = run_georef(flight_parts(args.flight), args.scanner, out, options, bar)
        if photos is not None:
            photos = synced_inputs(photos, result)
            summary = run_photos(out, result, options, photos, bar)
    print(f"{args.out}: {headline(result)}; {time.perf_counter() - started:.1f} s")
    if summary is not None:
        print(f"{args.out / 'photos'}: {photo_headline(summary)}")
    lost = [text for text in (losses(result), None if summary is None or photos is None else
                              photo_losses(summary, photos.images is not None)) if text]
    return 0 if not lost else finished_with_losses("georef", "; ".join(lost))
