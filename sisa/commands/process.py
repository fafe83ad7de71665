"""`sisa process RUN`: the post-processing of a simulated (or `sisa bench`) run, end to end —
sync, georeferencing and products as `sisa georef`, with the run's scenario as the sensor file,
plus an accuracy report against the run's truth.

RUN/process/ (or --out)
  ...                  everything `sisa georef` writes
  accuracy.json        every-pixel and check-point errors along/across/height, m and px
  report.html          the report: map, attitude, sync residuals, clock drift, errors, mosaic
  photos/              a run with a [camera]: the frame camera's products as `sisa georef
                       --camera` writes them, its photos rendered from the truth into
                       photos/images/ (or taken from RUN/photos/), timed by the sync
                       (sync/photo_times.csv; a log without the camera's records: by
                       truth/photos.csv, said)
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import shlex
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sisa.commands import (
    SubParsers,
    add_command,
    add_force_arg,
    check_inputs,
    finished_with_losses,
    flight_parts,
    say_warning,
)
from sisa.commands.georef import (
    PhotoInputs,
    add_georef_args,
    add_photo_cell_arg,
    check_photo_cell,
    headline,
    losses,
    options_from_args,
    photo_headline,
    photo_images,
    photo_losses,
    run_georef,
    run_photos,
    synced_photo_times,
)
from sisa.commands.progress import Progress, progress, split_lines
from sisa.core.errors import InputError
from sisa.core.outdir import name_taken, staged_output_dir

if TYPE_CHECKING:
    from emulators.scenario import Scenario
    from postproc.georef import GeorefOptions, Provenance, SensorModel
    from sisa.core.framecamera import FrameCamera
    from sisa.wiring.alongside import AccuracyAlongside


def register(sub: SubParsers[argparse.ArgumentParser]) -> None:
    parser = add_command(sub, "process", "sync, georeference and report on a simulated (or "
                         "bench) run, "
                         "with its accuracy against truth",
                         "sisa process runs/bench")
    parser.add_argument("run", type=Path, metavar="RUN",
                        help="a run folder of `sisa simulate` or `sisa bench`")
    parser.add_argument("--out", type=Path, default=None,
                        help="new output folder (default: RUN/process)")
    add_force_arg(parser)
    parser.add_argument("--nominal", action="store_true",
                        help="georeference with the nominal sensor (no boresight or "
                             "self-calibration), as an uncalibrated system would")
    add_georef_args(parser, "the run's scenario's sensor, as simulated (its scanner geometry, "
                    "boresight and mounting; with --nominal, without boresight and "
                    "self-calibration)")
    add_photo_cell_arg(parser)
    parser.set_defaults(handler=_run, dem=None)


def camera_of(scn: Scenario, *, nominal: bool = False) -> FrameCamera | None:
    """The frame camera a run's scenario implies (None without one): its true interior and
    mounting, or without the boresight."""
    from sisa.core.framecamera import FrameCamera, FrameMounting

    if scn.camera is None:
        return None
    mounting = (FrameMounting(lever_arm_m=scn.camera.mounting.lever_arm_m) if nominal else
                scn.camera.mounting)
    return FrameCamera(interior=scn.camera.model, mounting=mounting)


def _photo_inputs(args: argparse.Namespace, run: Path, scn: Scenario, out: Path,
                  bar: Progress, synced: Any) -> PhotoInputs | None:
    """A run with a camera: its photo times from the sync (`synced`: the sync result's photos,
    OUT/sync/photo_times.csv), or from the truth for a log without the camera's records (said),
    its photos from RUN/photos/ or rendered from the truth into OUT/photos/images/."""
    from postproc.georef import read_photo_times
    from sisa.wiring.photogcp import render_run_photos, too_many_to_render

    camera = camera_of(scn, nominal=args.nominal)
    if camera is None:
        return None
    path = run / "truth" / "photos.csv"
    if synced is not None:
        times = synced_photo_times(synced)
    elif not path.is_file():
        say_warning("process", f"{path}: no such file: no photo times, no photo products")
        return None
    else:
        times = read_photo_times(path)
        say_warning("process", f"photos timed by {path}, the run's truth (its flight log holds "
                    "no camera records for the sync to time them)")
    check_photo_cell(args.photo_cell)
    if (run / "photos").is_dir():
        return PhotoInputs(camera, times, photo_images(run / "photos", times), args.photo_cell)
    timed = times.timed()
    why = None if scn.camera is None else too_many_to_render(scn.camera,
                                                             int(timed.photo_number.size))
    if why is not None:  # the EO, exports and footprints are made all the same
        say_warning("process", f"photos: {why}: no photo orthos")
        return PhotoInputs(camera, times, None, args.photo_cell)
    bar.step("photos: rendering them from the truth")
    images = out / "photos" / "images"
    images.mkdir(parents=True)
    rendered = render_run_photos(scn, timed.photo_number, timed.t_mid_gps_ns, images)
    return PhotoInputs(camera, times, rendered, args.photo_cell)


def sensor_of(scn: Scenario, *, nominal: bool = False) -> SensorModel:
    """The sensor file a run's scenario implies (its true geometry and mounting, or the nominal
    ones)."""
    from postproc.georef import SensorModel
    from sisa.core.sensor import Mounting, ScannerGeometry

    geometry = ScannerGeometry(**{k: getattr(scn.scanner, k)
                                  for k in ScannerGeometry.model_fields})
    mounting = scn.mounting
    if nominal:
        geometry = geometry.model_copy(update={"delta_focal_mm": 0.0,
                                               "delta_principal_point_um": (0.0, 0.0)})
        mounting = Mounting(lever_arm_m=mounting.lever_arm_m,
                            antenna_offset_m=mounting.antenna_offset_m)
    name = f"{scn.block.name} scenario ({'nominal' if nominal else 'as simulated'})"
    return SensorModel(name=name, scanner=geometry, mounting=Mounting(**mounting.model_dump()))


def _headline(result: Any, acc: dict[str, Any] | None) -> list[tuple[str, str]]:
    rows = [("georeferencing", headline(result))]
    if acc is not None:
        p, c = acc["pixels"], acc["check_points"]
        rows.append(("every pixel vs truth, RMS along / across / height",
                     f"{p['along']['rms_px']:.4f} / {p['across']['rms_px']:.4f} / "
                     f"{p['height']['rms_px']:.4f} px ({p['pixels']} pixels)"))
        if c.get("points"):
            rows.append(("check points, RMS along / across / height",
                         f"{c['along']['rms_px']:.3f} / {c['across']['rms_px']:.3f} / "
                         f"{c['height']['rms_px']:.3f} px ({c['points']} observations, "
                         f"{c['distinct']} points"
                         + (f"; {c['not_georeferenced']} on lines not georeferenced, left out"
                            if c.get("not_georeferenced") else "") + ")"))
    return rows


def _say_what_is_not_judged(run: Path, acc: dict[str, Any] | None) -> None:
    """The accuracy the report cannot give, said rather than left out of the headline."""
    if acc is None:
        say_warning("process", f"{run / 'truth'}: no such folder: no accuracy against truth")
    elif not (run / "terrain" / "ground_points.csv").is_file():
        say_warning("process", f"{run / 'terrain' / 'ground_points.csv'}: no such file: no "
                    "check points")
    elif not acc["check_points"].get("points"):
        say_warning("process", "no check point lies on a georeferenced line: no check points")


def _alongside_line(judge: AccuracyAlongside, started_s: float) -> str:
    """The accuracy's own span: it ran beside the steps above (its CPU is counted in
    theirs), and its step above is only the wait for its end."""
    begin_s, end_s = (t - started_s for t in judge.span_s)
    return (f"  alongside, in a thread of its own: accuracy against truth from {begin_s:.1f} "
            f"to {end_s:.1f} s ({end_s - begin_s:.1f} s wall, {judge.cpu_s:.1f} s CPU, counted "
            f"in the steps it ran beside, {judge.ahead_lines} lines of truth cast while the "
            "log was read; its step above is the wait for its end)")


def _provenance(args: argparse.Namespace, run: Path, parts: list[Path],
                options: GeorefOptions) -> Provenance:
    """The archive record's command, inputs and sensor source (the report hashes the files)."""
    from postproc.georef import Provenance

    given = [options.trajectory, options.geoid if isinstance(options.geoid, Path) else None,
             args.sensor]
    inputs = [*parts, *sorted(p for p in (run / "scanner").iterdir() if p.is_file()),
              run / "terrain" / "dem.tif", run / "terrain" / "ground_points.csv",
              run / "scenario.toml", *(Path(p) for p in given if p is not None)]
    source = (f"--sensor {args.sensor}" if args.sensor is not None else
              "the run's scenario.toml" + (" (nominal: --nominal)" if args.nominal else ""))
    typed = getattr(args, "command_line", None)
    command = "sisa " + (shlex.join(typed) if typed is not None else f"process {run}")
    return Provenance(command, os.getcwd(), inputs, root=run, sensor_source=source)


def _run(args: argparse.Namespace) -> int:
    started, cpu_started = time.perf_counter(), time.process_time()
    run: Path = args.run
    if not name_taken(run) or not run.exists():
        raise InputError(f"{run}: no such folder")
    if not run.is_dir():  # `sisa process runs/bench-demo/flight.mcap` said "no flight.mcap"
        hint = (f" (the run folder is {run.parent})" if (run.parent / "flight.mcap").is_file()
                and (run.parent / "scenario.toml").is_file() else "")
        raise InputError(f"{run}: a file, not a run folder: give the folder `sisa simulate` or "
                         f"`sisa bench` made{hint}")
    check_inputs(("--sensor", args.sensor, "file"),
                 ("--trajectory", args.trajectory, "file"), ("--geoid", args.geoid, "file"))
    if not (run / "flight.mcap").is_file():
        raise InputError(f"{run}: not a run folder of `sisa simulate` or `sisa bench` (no "
                         "flight.mcap)")
    if not (run / "scanner").is_dir():
        raise InputError(f"{run}: no scanner/ folder, so no image to georeference (a run of "
                         "`sisa simulate --no-images`? `sisa sync` times its lines without "
                         "images)")
    if not any((run / "scanner").glob("segment_*.lines.csv")):
        raise InputError(f"{run}: the scanner recorded no image (no segment in "
                         f"{run / 'scanner'}): the run held no strip (`sisa bench --strip N` "
                         "records one; `sisa sync` times a run without images)")
    from emulators.scenario import load_scenario
    from postproc.georef import write_report
    from sisa.core.jsonio import write_json
    from sisa.wiring.alongside import AccuracyAlongside

    scn = load_scenario(run / "scenario.toml")
    args.dem = run / "terrain" / "dem.tif"
    options = dataclasses.replace(options_from_args(args, sensor_of(scn, nominal=args.nominal)),
                                  leap_seconds_fallback=scn.block.leap_seconds)
    out = args.out if args.out is not None else run / "process"
    parts = flight_parts([run / "flight.mcap"])
    judge = AccuracyAlongside(scn, run) if (run / "truth").is_dir() else None
    with (staged_output_dir(out, force=args.force) as tmp, progress("process") as bar,
          judge if judge is not None else contextlib.nullcontext()):
        result = run_georef(parts, run / "scanner", tmp, options, bar, command="process",
                            on_synced=None if judge is None else judge.start,
                            on_cast=None if judge is None else judge.add)
        photos = _photo_inputs(args, run, scn, tmp, bar, getattr(result.sync, "photos", None))
        summary = (None if photos is None else
                   run_photos(tmp, result, options, photos, bar, command="process"))
        if summary is not None and (run / "truth" / "photos.csv").is_file():
            from sisa.wiring.photogcp import photo_eo_accuracy

            summary["accuracy"] = photo_eo_accuracy(run / "truth" / "photos.csv",
                                                    tmp / "photos" / "sidecars")
            write_json(tmp / "photos" / "photo_summary.json", summary)
        bar.step("accuracy against truth")
        acc = None if judge is None else judge.result()
        _say_what_is_not_judged(run, acc)
        if acc is not None:
            public = {k: v for k, v in acc.items() if not k.startswith("_")}
            write_json(tmp / "accuracy.json", public)
        rows = _headline(result, acc)
        if summary is not None:
            rows.append(("frame camera", photo_headline(summary)))
        bar.step("report")
        write_report(tmp / "report.html", result, tmp, options.sensor.mounting,
                     title=f"SISA processing report — {scn.block.name}", accuracy=acc,
                     headline=rows, provenance=_provenance(args, run, parts, options),
                     sensor_toml=options.sensor.to_toml(), sensor_name=options.sensor.name,
                     photos=summary)
    print(f"report: {out / 'report.html'}")
    for name, value in rows:
        print(f"  {name}: {value}")
    for line in split_lines(bar, time.perf_counter() - started,
                            time.process_time() - cpu_started):
        print(line)
    if judge is not None:
        print(_alongside_line(judge, started))
    lost = [text for text in (losses(result), None if summary is None or photos is None else
                              photo_losses(summary, photos.images is not None)) if text]
    return 0 if not lost else finished_with_losses("process", "; ".join(lost))
