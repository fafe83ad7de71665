"""`sisa calibrate`: boresight, self-calibration, time delay, antenna offset (and GPS shifts,
per-strip attitude) from ground control, tie points and the DEM (docs/calibration.md).

RUN_OR_FLIGHT is a run folder of `sisa simulate` or a flight log (MCAP, all parts in order).
For a run folder the image measurements are simulated from its truth (sisa.wiring.gcpsim) unless
--obs gives them; the ground points, DEM and starting sensor come from the run. For a flight log,
--obs and --gcp are needed. The adjustment itself (postproc.calibration.adjust) never reads truth.

Several run folders are several flights sharing the sensor (postproc.calibration.flights): each
run's input is built as for one run (its simulated measurements, points, DEM, sync and navigation),
all from one starting sensor (--sensor, or the runs' common nominal one), and the adjustment is
of the joined input: segment s of flight k is k·1000 + s, point ids are "k:id" (k from 0, in
the order given), and calibration.json gives each residual, point and blunder its "flight".
Options naming one run's files (--gcp, --obs, --scanner, --dem) are refused with several runs.

An ill-conditioned adjustment (a parameter of the sensor file that the data do not determine to
a pixel, coupled to another they cannot separate it from: postproc.calibration.conditioning)
writes no sensor.toml unless --force: everything else is written, the parameters and what would
separate them are said on stderr and in calibration.json ("conditioning", "notes"), and the exit
code is 3 (finished, but not everything asked for was produced).

OUT/
  sensor.toml         the calibrated sensor file (`sisa georef --sensor OUT/sensor.toml`), with
                      the estimates ± σ and the strongest correlations as comments
  calibration.json    estimates, σ, correlation matrix, residuals of every observation (px, m),
                      adjusted points, check points (RMS and prediction), blunders, notes
                      (+ the simulation's truth and settings for a run folder)
  observations.csv    the image measurements used (id, segment, line, pixel, sigma_px)
  points.csv          the ground points as given to the adjustment (tie points: nan)

With --frame-camera the frame camera is calibrated instead, in the same adjustment with its
collinearity (postproc.calibration.photos): OUT/camera.toml (the calibrated camera file,
`sisa georef --camera`), calibration.json ("camera_calibration": estimates, σ, correlations,
residual RMS, blunders, notes; a run's truth), observations.csv (segment = photo number,
line = row, pixel = column) and points.csv.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

from sisa.commands import (
    SubParsers,
    add_command,
    check_inputs,
    check_seed,
    flight_parts,
    say_warning,
)
from sisa.commands.progress import progress
from sisa.core.errors import InputError
from sisa.core.outdir import staged_output_dir

if TYPE_CHECKING:
    from postproc.calibration import (
        CalibrationInput,
        CalibrationOptions,
        CalibrationResult,
        GroundPoints,
        ImageObservations,
        NavigationAccuracy,
        PhotoCalibrationInput,
    )
    from postproc.georef import SensorModel, Trajectory
    from postproc.sync import SyncResult


# What the numeric options may be; outside, a one-line error says why.
GCP_SIGMA_M_RANGE: Final = (1e-3, 100.0)  # < 1 mm overflows the weights; > 100 m is no control
DEM_SIGMA_M_RANGE: Final = (1e-3, 1000.0)  # likewise for a DEM height
PRIOR_MIN: Final = 1e-3  # µm or arcsec: a tighter prior holds the value; leave its group out
SWEEP_SPAN_MS: Final = (5.0, 1000.0)  # ≥ 3 trial delays (5 ms steps); each is one adjustment
SIM_DELAY_MS_MAX: Final = 1000.0  # a scanner's delay is milliseconds; 1 s is ~70 m of flight
SIM_GCP_NOISE_M_MAX: Final = 100.0  # a survey error beyond 100 m makes the points other places
# Tie points the adjustment can use: each adds one redundancy to tens of parameters, whose σ
# falls only as 1/√n; docs/calibration.md's best case uses 1000. The simulation costs ~1.3 ms
# and ~110 kB per tie point on the test run (10 000: 14 s, 1.4 GB; 40 000: 49 s, 4.8 GB, and
# the adjustment then refused φ and δx0 as inseparable); 10^9 was numpy's MemoryError traceback
# (6·N candidates drawn at once), and 10^6 would exhaust the memory.
TIE_POINTS_MAX: Final = 10_000
EXIT_INCOMPLETE: Final = 3  # finished, but not all it promised (DESIGN.md): here no sensor file


def register(sub: SubParsers[argparse.ArgumentParser]) -> None:
    parser = add_command(sub, "calibrate", "calibrate boresight, self-calibration, time delay "
                         "and offsets from ground control (least squares, blunder detection)",
                         "sisa calibrate runs/garrotxa --out runs/garrotxa-cal "
                         "--estimate boresight,selfcal --tie-points 300\n  "
                         "sisa calibrate runs/high runs/low --out runs/cal "
                         "--estimate boresight,selfcal,delay   # two flights, one sensor")
    parser.add_argument("flight", nargs="+", type=Path, metavar="RUN_OR_FLIGHT",
                        help="a run folder of `sisa simulate`, or the flight log (MCAP; its "
                             "numbered parts are found beside it); "
                             "several run folders: flights sharing the sensor, adjusted together")
    parser.add_argument("--out", type=Path, required=True, help="new output folder")
    parser.add_argument("--force", action="store_true",
                        help="replace an existing output folder (the new one is made beside it "
                             "and takes its place only once complete), and write sensor.toml "
                             "even from an ill-conditioned adjustment (by default it is not "
                             "written, and the exit code is 3)")
    parser.add_argument("--gcp", type=Path, default=None, metavar="CSV",
                        help="ground points (id, kind, lat_deg, lon_deg, height_m); default "
                             "RUN/terrain/ground_points.csv")
    parser.add_argument("--obs", type=Path, default=None, metavar="CSV",
                        help="image measurements (id, segment, line, pixel, sigma_px); a run "
                             "folder without it gets simulated ones")
    parser.add_argument("--scanner", type=Path, default=None, metavar="DIR",
                        help="the scanner's recording (lines files); default RUN/scanner if "
                             "there, else lines are numbered in frame-header order")
    parser.add_argument("--sensor", type=Path, default=None, metavar="TOML",
                        help="starting sensor file; default: the run's nominal sensor "
                             "(no boresight, no self-calibration) or a nominal CASI-501")
    parser.add_argument("--dem", type=Path, default=None, metavar="TIF",
                        help="DEM (ellipsoidal) for surface control and check points; default "
                             "RUN/terrain/dem.tif")
    parser.add_argument("--no-dem", action="store_true", help="no DEM at all")
    parser.add_argument("--estimate", default="boresight,selfcal", metavar="GROUPS",
                        help="comma list of boresight, selfcal, delay, antenna, gps_block, "
                             "gps_strip, attitude, drift (default: boresight,selfcal)")
    _add_weights(parser)
    _add_simulation(parser)
    _add_frame_camera(parser)
    parser.set_defaults(handler=_run)


def _add_frame_camera(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("the frame camera (instead of the scanner)")
    g.add_argument("--frame-camera", action="store_true",
                   help="calibrate the frame camera: --obs holds its measurements (segment = "
                        "photo number, line = row, pixel = column); a run folder without "
                        "--obs gets markers measured in its rendered photos. Writes "
                        "OUT/camera.toml")
    g.add_argument("--camera", type=Path, default=None, metavar="TOML",
                   help="starting camera file; default: the run's camera without boresight")
    g.add_argument("--photo-times", type=Path, default=None, metavar="CSV",
                   help="photo_number, t_mid_gps_ns; default: the photos the sync of the "
                        "flight log times")
    g.add_argument("--photo-sigma-px", type=float, default=0.05, metavar="PX",
                   help="stated precision of the simulated marker centroids (default 0.05)")


def _add_weights(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("weights and priors")
    g.add_argument("--gcp-sigma-m", default="0.5,0.5", metavar="H,V",
                   help="σ of the surveyed coordinates, horizontal and vertical (default 0.5,0.5)")
    g.add_argument("--dem-sigma-m", type=float, default=2.0, metavar="M",
                   help="σ of a DEM height (default 2)")
    g.add_argument("--snooping-k", type=float, default=4.0, metavar="K",
                   help="reject observations whose standardised residual exceeds K (default 4)")
    g.add_argument("--prior-x0-um", type=float, default=20.0, metavar="UM",
                   help="prior σ of δx0 (default 20; 0 = none: φ and δx0 are then inseparable)")
    g.add_argument("--prior-y0-um", type=float, default=0.0, metavar="UM",
                   help="prior σ of δy0 (default 0 = none)")
    g.add_argument("--prior-attitude-arcsec", type=float, default=20.0, metavar="AS",
                   help="prior σ of per-strip attitude offsets (default 20)")
    g.add_argument("--nav-sigma-m", default=None, metavar="H,V",
                   help="the trajectory's stated accuracy: σ of its GPS positions, horizontal "
                        "and vertical (default for a run: its scenario's receiver; for a "
                        "flight log none, and σ then leave the navigation's error out; 0,0: "
                        "none)")
    g.add_argument("--nav-correlation-s", type=float, default=None, metavar="S",
                   help="correlation time of that error (Gauss–Markov; default for a run: its "
                        "scenario's, else 60)")
    g.add_argument("--check-heights", action="store_true",
                   help="check points enter the adjustment with only their height observed "
                        "(seed 000's procedure); their horizontal position stays a check")
    g.add_argument("--sweep-delay-ms", type=float, default=None, metavar="MS",
                   help="also run the seed's delay sweep over ±MS (5 ms steps) for comparison")


def _add_simulation(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("simulated measurements (run folder, no --obs)")
    g.add_argument("--noise-px", type=float, default=0.3,
                   help="σ of the measurements, pixels (0.3; at most 1)")
    g.add_argument("--tie-points", type=int, default=0, metavar="N",
                   help=f"tie points in strip overlaps (default 0; at most {TIE_POINTS_MAX})")
    g.add_argument("--max-views", type=int, default=2, help="segments a point is measured in")
    g.add_argument("--single-view-control", type=int, default=0, metavar="N",
                   help="the N control points nearest the block border are measured in one "
                        "image only (seed 000's Garrotxa: 97 of 111; default 0)")
    g.add_argument("--sim-delay-ms", type=float, default=0.0, metavar="MS",
                   help="inject a scanner delay: a line tagged t was exposed at t + MS")
    g.add_argument("--sim-gcp-noise-m", default="0,0", metavar="H,V",
                   help="survey error added to control/check coordinates (default 0,0)")
    g.add_argument("--blunders", type=int, default=0, help="gross errors to inject (default 0)")
    g.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")


def _within(flag: str, value: float, limits: tuple[float, float], why: str,
            either_sign: bool = False) -> None:
    """InputError unless lo ≤ value ≤ hi (|value|, either_sign)."""
    lo, hi = limits
    if not lo <= (abs(value) if either_sign else value) <= hi:
        span = f"±{lo:g} to ±{hi:g}" if either_sign and lo > 0 else (
            f"within ±{hi:g}" if either_sign else f"{lo:g} to {hi:g}")
        shown = str(value) if isinstance(value, int) else f"{value:g}"  # a count, as typed
        raise InputError(f"{flag} {shown}: must be {span} ({why})")


def _pair(text: str, what: str) -> tuple[float, float]:
    try:
        a, b = (float(x) for x in text.split(","))
    except ValueError:
        raise InputError(f"{what} {text!r}: give two numbers, e.g. 2.5,2.0") from None
    if not (math.isfinite(a) and math.isfinite(b) and a >= 0 and b >= 0):
        raise InputError(f"{what} {text!r}: values must be finite and ≥ 0")
    return a, b


def _is_run(paths: list[Path]) -> bool:
    return len(paths) == 1 and paths[0].is_dir()


PER_RUN_OPTIONS = (("gcp", "--gcp"), ("obs", "--obs"), ("scanner", "--scanner"), ("dem", "--dem"))


def _several_runs(args: argparse.Namespace) -> list[Path] | None:
    """The run folders when several are given (None: one run or one flight log's parts)."""
    paths: list[Path] = list(args.flight)
    dirs = [p.is_dir() for p in paths]
    if len(paths) < 2 or not any(dirs):
        return None
    if not all(dirs):
        raise InputError("give several run folders or the parts of one flight log, not both")
    given = [flag for name, flag in PER_RUN_OPTIONS if getattr(args, name) is not None]
    if given:
        raise InputError(f"{', '.join(given)} name one run's files: with several runs each "
                         "run's own are used (give one run to override them)")
    return paths


def _flight_paths(args: argparse.Namespace) -> list[Path]:
    if _is_run(args.flight):
        log = args.flight[0] / "flight.mcap"
        if not log.is_file():
            raise InputError(f"{args.flight[0]}: no flight.mcap: not a run folder")
        return flight_parts([log])
    for p in args.flight:
        if not p.is_file():
            raise InputError(f"{p}: no such flight log")
    return flight_parts(args.flight)


def _sensor(args: argparse.Namespace) -> SensorModel:
    from postproc.georef import SensorModel

    if args.sensor is not None:
        return SensorModel.load(args.sensor)
    scn_path = args.flight[0] / "scenario.toml" if _is_run(args.flight) else None
    if scn_path is not None and scn_path.is_file():
        from emulators.scenario import load_scenario
        from sisa.commands.process import sensor_of

        return sensor_of(load_scenario(scn_path), nominal=True)
    return SensorModel()


def _default(args: argparse.Namespace, given: Path | None, rel: str, what: str) -> Path:
    if given is not None:
        return Path(given)
    if _is_run(args.flight):
        return Path(args.flight[0]) / rel
    raise InputError(f"a flight log needs {what}")


def _options(args: argparse.Namespace) -> CalibrationOptions:
    from postproc.calibration import CalibrationOptions, PriorSigmas, parse_groups

    for flag in ("--prior-x0-um", "--prior-y0-um", "--prior-attitude-arcsec"):
        value = getattr(args, flag[2:].replace("-", "_"))
        if value < 0:  # it meant "none", silently
            raise InputError(f"{flag} must be ≥ 0 (0: no prior)")
        if 0 < value < PRIOR_MIN:  # the eigen-solver failed on 1e-300
            raise InputError(f"{flag} {value:g}: must be 0 (no prior) or ≥ {PRIOR_MIN:g} (a "
                             "tighter prior holds the value: leave its group out of --estimate)")
    _navigation(args)  # its options checked before any work
    gcp_sigma_m = _pair(args.gcp_sigma_m, "--gcp-sigma-m")
    for v in gcp_sigma_m:
        _within("--gcp-sigma-m", v, GCP_SIGMA_M_RANGE, "metres: below 1 mm the weights "
                "overflow, above 100 m a point is no control")
    _within("--dem-sigma-m", args.dem_sigma_m, DEM_SIGMA_M_RANGE, "metres")
    if args.sweep_delay_ms is not None:
        _within("--sweep-delay-ms", args.sweep_delay_ms, SWEEP_SPAN_MS, "ms either side: the "
                "sweep needs three 5 ms steps, and each is an adjustment", either_sign=True)

    def prior(v: float) -> float | None:
        return v if v > 0 else None

    return CalibrationOptions(
        groups=parse_groups(args.estimate), gcp_sigma_m=gcp_sigma_m,
        dem_sigma_m=args.dem_sigma_m, snooping_k=args.snooping_k,
        check_heights=args.check_heights,
        priors=PriorSigmas(principal_point_x_um=prior(args.prior_x0_um),
                           principal_point_y_um=prior(args.prior_y0_um),
                           attitude_arcsec=prior(args.prior_attitude_arcsec)))


def _check_simulation(args: argparse.Namespace) -> None:
    """The simulation options, checked with the others (before any work). --noise-px at most
    a third of the margin past the detector's ends that calibration allows (3σ stays inside):
    1e300 was blamed on the sensor file in a 300-digit pixel number."""
    from postproc.calibration import SENSOR_FIT_MARGIN_PX

    check_seed(args.seed)
    if (args.tie_points < 0 or args.blunders < 0 or args.max_views < 1
            or args.single_view_control < 0):
        raise InputError("--tie-points, --blunders and --single-view-control must be ≥ 0, "
                         "--max-views ≥ 1")
    _within("--tie-points", args.tie_points, (0, TIE_POINTS_MAX), "tie points beyond it add "
            "little to the adjustment; each costs ~110 kB and ~1.3 ms to simulate")
    _within("--noise-px", args.noise_px, (0.0, SENSOR_FIT_MARGIN_PX / 3.0),
            f"pixels: 3σ must stay within the {SENSOR_FIT_MARGIN_PX:g} px past the detector's "
            "ends that the sensor check allows")
    _within("--sim-delay-ms", args.sim_delay_ms, (0.0, SIM_DELAY_MS_MAX),
            "a scanner's delay is milliseconds", either_sign=True)
    for v in _pair(args.sim_gcp_noise_m, "--sim-gcp-noise-m"):
        _within("--sim-gcp-noise-m", v, (0.0, SIM_GCP_NOISE_M_MAX), "metres")


def _observations(args: argparse.Namespace, points: GroundPoints
                  ) -> tuple[ImageObservations, GroundPoints, dict[str, Any]]:
    """(measurements, points as the adjustment sees them, simulation info)."""
    from postproc.calibration import read_observations

    if args.obs is not None:
        return read_observations(args.obs), points, {}
    if not _is_run(args.flight):
        raise InputError("a flight log needs --obs (image measurements of the ground points)")
    from sisa.wiring.gcpsim import SimSettings, simulate_observations

    settings = SimSettings(noise_px=args.noise_px, max_views=args.max_views,
                           single_view_control=args.single_view_control,
                           tie_points=args.tie_points, delay_ms=args.sim_delay_ms,
                           gcp_noise_m=_pair(args.sim_gcp_noise_m, "--sim-gcp-noise-m"),
                           blunders=args.blunders, seed=args.seed)
    sim = simulate_observations(args.flight[0], points, settings)
    info = {"simulated": True, "truth": sim.truth,
            "injected_blunders": [{"id": str(sim.obs.point_id[k]),
                                   "segment": int(sim.obs.segment[k])}
                                  for k in sim.blunder_rows.tolist()]}
    return sim.obs, sim.points, info


def log_navigation(args: argparse.Namespace, paths: list[Path], scanner: Path | None,
                   sensor: SensorModel) -> tuple[Trajectory, SyncResult]:
    """The flight log read once: the sync (lines from the scanner's lines files, else in
    frame-header order) and the navigation with the sensor file's antenna offset; what the
    recording and the sync could not vouch for said on stderr."""
    from postproc.georef import NAV_WANTED, merged_wanted, nav_from_columns
    from postproc.sync import WANTED as SYNC_WANTED
    from postproc.sync import (
        header_order_note,
        read_scanner_lines,
        sync_input_from_columns,
        synchronise,
        untimed_lines_note,
    )
    from recorder.columns import read_topics
    from recorder.health import HEALTH_WANTED, HealthTotals, recording_note
    from recorder.messages import Topic
    from recorder.parts import recording_metadata
    from recorder.settings import header_window_ms, recorded_camera_window_ms

    cols = read_topics(paths, {**merged_wanted(SYNC_WANTED, NAV_WANTED), **HEALTH_WANTED})
    recording = recording_note(HealthTotals.from_columns(cols[Topic.HEALTH]), paths[0])
    if recording is not None:
        say_warning(args.command, recording)
    meta = recording_metadata(paths[0])
    sync = synchronise(sync_input_from_columns(cols, header_window_ms(meta)),
                       read_scanner_lines(scanner) if scanner is not None else None,
                       camera_window_ms=recorded_camera_window_ms(meta))
    unsure = header_order_note(sync.report["lines"], "the image measurements' lines")
    if unsure is not None:  # a measurement's line may be timed a line period off
        say_warning(args.command, unsure)
    untied = untimed_lines_note(sync.report["lines"], paths)
    if untied is not None:  # observations on untimed lines are left out, and this is why
        say_warning(args.command, untied)
    traj = nav_from_columns(cols, sync.ins, antenna_offset_m=sensor.mounting.antenna_offset_m)
    return traj, sync


def build_input(args: argparse.Namespace, sensor: SensorModel | None = None
                ) -> tuple[CalibrationInput, dict[str, Any]]:
    """Sync and navigation from the log, points, measurements, DEM and starting sensor (the
    given one, else --sensor or the run's nominal one)."""
    from postproc.calibration import CalibrationInput, SegmentClock, read_ground_points
    from postproc.georef import Dem

    sensor = _sensor(args) if sensor is None else sensor
    paths = _flight_paths(args)
    points = read_ground_points(_default(args, args.gcp, "terrain/ground_points.csv", "--gcp"))
    obs, points, info = _observations(args, points)
    scanner = args.scanner
    if scanner is None and _is_run(args.flight) and (args.flight[0] / "scanner").is_dir():
        scanner = args.flight[0] / "scanner"
    traj, sync = log_navigation(args, paths, scanner, sensor)
    navigation = _navigation(args)
    dem = None
    if not args.no_dem and (args.dem is not None or _is_run(args.flight)):
        dem_path = _default(args, args.dem, "terrain/dem.tif", "--dem")
        dem = Dem.read(dem_path) if dem_path.is_file() or args.dem else None
    info["line_times"] = ("sync of the flight log, lines from "
                          + ("the scanner's lines files" if scanner else "frame-header order"))
    if navigation is not None:
        info["navigation_accuracy"] = {"gps_sigma_m": list(navigation.gps_sigma_m),
                                       "gps_correlation_s": navigation.gps_correlation_s}
    return CalibrationInput(traj, SegmentClock.from_line_times(sync.lines), points, obs,
                            sensor, dem, navigation), info


NAV_CORRELATION_S_RANGE: Final = (1.0, 86_400.0)  # a second (the fix rate) to a day


def _navigation(args: argparse.Namespace) -> NavigationAccuracy | None:
    """The trajectory's stated accuracy: --nav-sigma-m / --nav-correlation-s, else a run's
    scenario's GPS receiver (σ and correlation time it states; not its truth), else none."""
    from postproc.calibration import NavigationAccuracy

    tau = args.nav_correlation_s
    if tau is not None:
        _within("--nav-correlation-s", tau, NAV_CORRELATION_S_RANGE, "seconds")
    scn_path = args.flight[0] / "scenario.toml" if _is_run(args.flight) else None
    stated = None
    if scn_path is not None and scn_path.is_file():
        from emulators.scenario import load_scenario

        gps = load_scenario(scn_path).gps
        stated = ((gps.horizontal_sigma_m, gps.vertical_sigma_m), gps.noise_correlation_s)
    if args.nav_sigma_m is not None:
        sigma = _pair(args.nav_sigma_m, "--nav-sigma-m")
        for v in sigma:
            _within("--nav-sigma-m", v, (0.0, GCP_SIGMA_M_RANGE[1]), "metres")
    elif stated is not None:
        sigma = stated[0]
    else:
        return None
    if max(sigma) == 0.0:
        return None
    return NavigationAccuracy(sigma, tau if tau is not None else
                              stated[1] if stated is not None else 60.0)


def _shared_sensor(args: argparse.Namespace, runs: list[Path]) -> SensorModel:
    """--sensor, else the runs' nominal sensor, which must be the same for all (names aside)."""
    if args.sensor is not None:
        return _sensor(args)
    first = _sensor(argparse.Namespace(**{**vars(args), "flight": runs[:1]}))
    for run in runs[1:]:
        other = _sensor(argparse.Namespace(**{**vars(args), "flight": [run]}))
        if other.model_copy(update={"name": first.name}) != first:
            raise InputError(f"{run}: its nominal sensor differs from {runs[0]}'s: give the "
                             "flights' common starting sensor with --sensor")
    return first


def build_joint_input(args: argparse.Namespace, runs: list[Path]
                      ) -> tuple[CalibrationInput, dict[str, Any]]:
    """Each run's input as for one run, from one starting sensor, joined (calib_flights)."""
    from postproc.calibration import (
        SEGMENT_STRIDE,
        flight_point_id,
        flight_segment,
        join_flights,
    )

    sensor = _shared_sensor(args, runs)
    inputs: list[CalibrationInput] = []
    flights: list[dict[str, Any]] = []
    injected: list[dict[str, Any]] = []
    for k, run in enumerate(runs):
        inp, info = build_input(argparse.Namespace(**{**vars(args), "flight": [run]}), sensor)
        inputs.append(inp)
        injected += [{"id": flight_point_id(k, b["id"]), "segment": flight_segment(k, b["segment"]),
                      "flight": k} for b in info.pop("injected_blunders", [])]
        flights.append({"flight": k, "run": str(run), "first_segment": flight_segment(k, 0),
                        "dem": inp.dem is not None, **info})
    _check_dems(inputs, runs, args.dem_sigma_m)
    return join_flights(inputs), {"segment_stride": SEGMENT_STRIDE, "flights": flights,
                                  "injected_blunders": injected}


def _check_dems(inputs: list[CalibrationInput], runs: list[Path], sigma_m: float) -> None:
    """The joined input takes a height from the first flight's DEM that covers the place
    (calib_flights.FlightsSurface): refuse DEMs that disagree where they overlap, as two
    simulated runs over one area do (each run has its own synthetic terrain)."""
    import numpy as np
    from pyproj import Transformer

    from postproc.georef import Dem

    dems = [(k, i.dem) for k, i in enumerate(inputs) if isinstance(i.dem, Dem)]
    for a, (ka, da) in enumerate(dems):
        w, s, e, n = da.bounds_m
        ge, gn = np.meshgrid(np.linspace(w, e, 40), np.linspace(s, n, 40))
        ea, na = ge.ravel(), gn.ravel()
        for kb, db in dems[a + 1:]:
            eb, nb = (ea, na) if db.epsg == da.epsg else Transformer.from_crs(
                da.epsg, db.epsg, always_xy=True).transform(ea, na)
            d = da.height_at(ea, na) - db.height_at(eb, nb)
            d = d[np.isfinite(d)]
            rms = float(np.sqrt(np.mean(d * d))) if d.size else 0.0
            if rms > sigma_m:
                raise InputError(f"{runs[kb]}: its DEM differs from {runs[ka]}'s by {rms:.1f} m "
                                 "RMS where they overlap (simulated runs over one area each "
                                 "have their own terrain): use runs over separate areas, or "
                                 "--no-dem")


def _mark_flights(report: dict[str, Any]) -> None:
    """Each residual, point, blunder and check measurement gets its flight ("k:id" → k)."""
    for key in ("residuals", "points", "blunders", "check_list"):
        for row in report.get(key) or []:
            if isinstance(row, dict) and ":" in str(row.get("id", "")):
                row["flight"] = int(str(row["id"]).split(":", 1)[0])


def headline(res: CalibrationResult, truth: dict[str, Any] | None) -> list[str]:
    from postproc.calibration import high_correlations, look_angles, parameter_rows

    out = [f"σ0 {res.sigma0:.3f} ({res.dof} dof), {res.counts['observations_used']} "
           f"measurements of {res.counts['control_points']} control and "
           f"{res.counts['tie_points']} tie points in {res.counts['strips']} strips, "
           f"{len(res.blunders)} blunders rejected"]
    tv = _truth_values(truth) if truth else {}
    biased = truth is not None and _boresight_differs(truth)
    for p in parameter_rows(res):
        if p["segment"] is None:
            mark = "*" if biased and p["name"] in BORESIGHT_NAMES else ""
            t = f"   (truth{mark} {tv[p['name']]:.4g})" if p["name"] in tv else ""
            t += "   set by its prior" if p["set_by_prior"] else ""
            out.append(f"  {p['name']:<12} {p['estimate']:12.4f} ± {p['sigma']:<10.4f} "
                       f"{p['unit']}{t}")
    if biased and truth is not None and any(
            p["name"] in BORESIGHT_NAMES for p in parameter_rows(res)):
        scn = ", ".join(f"{v:g}" for v in truth["boresight_arcsec"])
        out.append(f"  * truth of the boresight: the scenario's ({scn}) arcsec composed with "
                   "the run's INS attitude bias and mean drift, which the images cannot tell "
                   "from a boresight")
    for h in high_correlations(res)[:4]:
        out.append(f"  correlation {h['a']} ↔ {h['b']} {h['r']:+.3f}")
    look = look_angles(res)
    out.append(f"  look offsets (what the images fix): along δx0 − f'φ "
               f"{look['along_um']['value']:.2f} ± {look['along_um']['sigma']:.2f} µm, across "
               f"δy0 + f'ω {look['across_um']['value']:.2f} ± {look['across_um']['sigma']:.2f} µm")
    if res.check and not res.check["observations"]:
        out.append("  check points: none could be measured (none on a georeferenced line and "
                   "the DEM)")
    elif res.check:
        c = res.check
        out.append(f"  check points: {c['observations']} measurements of {c['points']} points, "
                   f"RMS along {c['rms_along_m']:.2f} m ({c['rms_along_px']:.2f} px), across "
                   f"{c['rms_across_m']:.2f} m ({c['rms_across_px']:.2f} px); predicted "
                   f"{c['predicted_rms_along_m']:.2f} / {c['predicted_rms_across_m']:.2f} m")
    return out


BORESIGHT_NAMES: Final = ("omega", "phi", "kappa")


def _boresight_differs(truth: dict[str, Any]) -> bool:
    """The boresight the images see (with the INS bias) is not the scenario's own."""
    return any(abs(a - b) >= 0.05 for a, b in zip(
        truth["boresight_with_ins_bias_arcsec"], truth["boresight_arcsec"], strict=True))


def _truth_values(truth: dict[str, Any]) -> dict[str, float]:
    b = truth["boresight_with_ins_bias_arcsec"]
    return {"omega": b[0], "phi": b[1], "kappa": b[2], "delta_focal": truth["delta_focal_mm"],
            "delta_x0": truth["delta_principal_point_um"][0],
            "delta_y0": truth["delta_principal_point_um"][1],
            "time_delay": truth["time_delay_ms"]}


def _run(args: argparse.Namespace) -> int:
    check_inputs(("", args.flight, "any"), ("--gcp", args.gcp, "file"),
                 ("--obs", args.obs, "file"), ("--scanner", args.scanner, "folder"),
                 ("--sensor", args.sensor, "file"), ("--dem", args.dem, "file"),
                 ("--camera", args.camera, "file"), ("--photo-times", args.photo_times, "file"))
    if args.frame_camera:
        return _run_frame_camera(args)
    given = [f for f, v in (("--camera", args.camera), ("--photo-times", args.photo_times))
             if v is not None]
    if given:
        raise InputError(f"{given[0]} is for the frame camera: add --frame-camera")
    import numpy as np

    from postproc.calibration import (
        calibrate,
        load_check,
        report_json,
        sensor_toml,
        sweep_delay,
        write_ground_points,
        write_observations,
    )
    from sisa.core.jsonio import write_json

    started = time.perf_counter()
    opt = _options(args)
    _check_simulation(args)
    runs = _several_runs(args)
    with staged_output_dir(args.out, force=args.force) as out, progress("calibrate") as bar:
        bar.step("sync, navigation and measurements")
        inp, info = build_input(args) if runs is None else build_joint_input(args, runs)
        bar.step("adjustment")
        res = calibrate(inp, opt)
        for note in res.notes:  # in calibration.json alone, a dropped row went unnoticed
            say_warning(args.command, note)
        if args.sweep_delay_ms is not None:
            bar.step("delay sweep")
            span = abs(args.sweep_delay_ms)
            info["delay_sweep"] = sweep_delay(inp, opt, np.arange(-span, span + 1e-9, 5.0))
        refused = res.conditioning.get("ill_conditioned", False) and not args.force
        if not refused:
            text = sensor_toml(res)
            load_check(text)
            (out / "sensor.toml").write_text(text, encoding="utf-8")
        report = report_json(res, {"settings": {"estimate": args.estimate,
                                                "gcp_sigma_m": list(opt.gcp_sigma_m),
                                                "dem_sigma_m": opt.dem_sigma_m,
                                                "dem": inp.dem is not None}, **info})
        if runs is not None:
            _mark_flights(report)
        write_json(out / "calibration.json", report)
        write_observations(out / "observations.csv", inp.obs)
        write_ground_points(out / "points.csv", inp.points)
    print(f"{args.out}: calibrated in {time.perf_counter() - started:.1f} s"
          + (f", {len(runs)} flights (segments k·1000 + s, points k:id)" if runs else ""))
    for line in headline(res, info.get("truth")):
        print(line)
    if "delay_sweep" in info:
        print(f"  delay sweep (seed method): minimum RMS at {info['delay_sweep']['best_ms']:.1f} "
              "ms")
    if refused:
        say_warning(args.command, f"ill-conditioned adjustment: no {args.out / 'sensor.toml'} "
                    "written (its values would be noise along what the data cannot separate; "
                    "--force writes it anyway); exit code 3")
        return EXIT_INCOMPLETE
    return 0


def _camera_input(args: argparse.Namespace) -> tuple[PhotoCalibrationInput, dict[str, Any]]:
    """The frame camera's calibration input: the log's navigation (sync without the scanner's
    images needed), the photo times, the points, the measurements and the starting camera."""
    from postproc.calibration import PhotoCalibrationInput, read_ground_points, read_observations
    from postproc.georef import Dem, load_camera, read_photo_times

    run = args.flight[0] if _is_run(args.flight) else None
    scn = None
    if run is not None and (run / "scenario.toml").is_file():
        from emulators.scenario import load_scenario

        scn = load_scenario(run / "scenario.toml")
    from sisa.commands.georef import synced_photo_times
    from sisa.commands.process import camera_of

    nominal = None if scn is None else camera_of(scn, nominal=True)
    if args.camera is not None:
        camera = load_camera(args.camera)
    elif nominal is not None:
        camera = nominal
    else:
        raise InputError("--frame-camera needs --camera (or a run folder whose scenario has a "
                         "[camera])")
    sensor = _sensor(args)
    traj, sync = log_navigation(args, _flight_paths(args), None, sensor)
    if args.photo_times is not None:
        times = read_photo_times(args.photo_times)
    elif sync.photos is not None:  # the photos the sync timed (status ok or board_time)
        times = synced_photo_times(sync.photos)
    else:
        raise InputError("--frame-camera: the flight log holds no photo of a frame camera: "
                         "give --photo-times (photo_number, t_mid_gps_ns)")
    points = read_ground_points(_default(args, args.gcp, "terrain/ground_points.csv", "--gcp"))
    info: dict[str, Any] = {}
    if args.obs is not None:
        obs = read_observations(args.obs)
    elif run is not None and scn is not None:
        from sisa.wiring.photogcp import simulate_photo_control

        _within("--photo-sigma-px", args.photo_sigma_px, (1e-3, 100.0), "pixels")
        obs, info = simulate_photo_control(run, scn, times, sigma_px=args.photo_sigma_px,
                                           seed=args.seed)
    else:
        raise InputError("a flight log needs --obs (the photos' measurements of the points)")
    dem = None
    if not args.no_dem and (args.dem is not None or run is not None):
        dem_path = _default(args, args.dem, "terrain/dem.tif", "--dem")
        dem = Dem.read(dem_path) if dem_path.is_file() or args.dem else None
    navigation = _navigation(args)
    if navigation is not None:
        info["navigation_accuracy"] = {"gps_sigma_m": list(navigation.gps_sigma_m),
                                       "gps_correlation_s": navigation.gps_correlation_s}
    return PhotoCalibrationInput(traj, times, points, obs, camera, dem,
                                 sensor.time_delay_ms, navigation), info


def _run_frame_camera(args: argparse.Namespace) -> int:
    """`sisa calibrate --frame-camera`: OUT/camera.toml, calibration.json, observations.csv."""
    import tomli_w

    from postproc.calibration import (
        calibrate_photos,
        photo_report_json,
        write_ground_points,
        write_observations,
    )
    from sisa.core.jsonio import write_json

    started = time.perf_counter()
    opt = _options(args)
    check_seed(args.seed)
    if _several_runs(args) is not None:
        raise InputError("--frame-camera takes one run or one flight log")
    with staged_output_dir(args.out, force=args.force) as out, progress("calibrate") as bar:
        bar.step("navigation, photo times and measurements")
        inp, info = _camera_input(args)
        bar.step("adjustment")
        res = calibrate_photos(inp, opt)
        for note in res.notes:
            say_warning(args.command, note)
        (out / "camera.toml").write_text(tomli_w.dumps(res.camera.model_dump(mode="json")),
                                         encoding="utf-8")
        report = {"camera_calibration": photo_report_json(res),
                  "settings": {"estimate": args.estimate, "gcp_sigma_m": list(opt.gcp_sigma_m),
                               "dem": inp.dem is not None}, **info}
        write_json(out / "calibration.json", report)
        write_observations(out / "observations.csv", inp.obs)
        write_ground_points(out / "points.csv", inp.points)
    print(f"{args.out}: frame camera calibrated in {time.perf_counter() - started:.1f} s, "
          f"{res.counts['observations_used']} measurements in {res.counts['photos']} photos, "
          f"sigma0 {res.sigma0:.2f}")
    truth = info.get("truth", {}).get("boresight_arcsec")
    for k, p in enumerate(res.layout.params):
        line = f"  {p.label}: {res.theta[k]:.3f} ± {res.sigma[k]:.3f} {p.unit}"
        if truth is not None and p.group.value == "boresight":
            want = truth[p.component]
            line += f" (truth {want:.3f}, z {(res.theta[k] - want) / res.sigma[k]:+.2f})"
        print(line)
    return 0
