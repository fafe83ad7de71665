"""`sisa campaign process CAMPAIGN --out OUT`: every flight of a campaign synchronised,
georeferenced and orthorectified on Dask (a LocalCluster of worker processes, or an existing
cluster with --scheduler), the orthos and mosaics as Cloud-Optimized GeoTIFFs, a STAC catalog
over them (docs/campaign.md).

CAMPAIGN is a TOML file (postproc/campaign/config.py) or a folder of `sisa simulate` runs
(each run's scenario gives its sensor, as `sisa process` takes it).

OUT/flights/NAME/   each flight's products as `sisa georef` writes them (orthos as COGs)
OUT/mosaics/        one mosaic COG (and quicklook) per band set, CRS and cell
OUT/stac/           collection.json and an Item per segment

OUT is kept between runs: a rerun skips every task whose inputs and settings are unchanged.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import textwrap
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sisa.commands import (
    SubParsers,
    add_command,
    finished_with_losses,
    say_warning,
)
from sisa.commands.progress import clock, plain_period_s
from sisa.core.errors import InputError
from sisa.core.outdir import name_taken, write_whole

if TYPE_CHECKING:
    from distributed import Client

    from postproc.campaign import CampaignRun, CampaignSpec, FlightSpec, Stage

STOP_RULE = ("Ctrl-C (or SIGTERM) stops it: the tasks finished so far are kept, and a rerun "
             "resumes from them; no product is left half-written (each appears whole or not "
             "at all); exit 130 (143 for SIGTERM).")
MARKER = "campaign.json"  # names the campaign an output folder belongs to
STAGES = ("sync", "georef", "ortho", "flight", "mosaic")


def register(sub: SubParsers[argparse.ArgumentParser]) -> None:
    parser = add_command(sub, "campaign", "a whole campaign of flights on Dask: COGs and a "
                         "STAC catalog", "sisa campaign process season.toml --out season")
    inner = parser.add_subparsers(dest="campaign_command", metavar="ACTION")
    proc = inner.add_parser(
        "process", help="synchronise, georeference and orthorectify every flight; mosaics, "
        "COGs, STAC catalog; resumable", description="every flight synchronised once, every "
        "segment georeferenced and orthorectified as its own Dask task, one mosaic per band "
        "set; orthos and mosaics as Cloud-Optimized GeoTIFFs, a STAC catalog; a rerun skips "
        "what is done",
        epilog="example:\n  sisa campaign process season.toml --out season --workers 2\n"
               "  sisa campaign process runs/ --out camp --scheduler tcp://10.0.0.5:8786\n\n"
               + textwrap.fill(STOP_RULE, 79), formatter_class=argparse.RawDescriptionHelpFormatter)
    proc.add_argument("campaign", type=Path, metavar="CAMPAIGN",
                      help="campaign TOML file, or a folder of `sisa simulate` runs")
    proc.add_argument("--out", type=Path, required=True,
                      help="output folder (kept between runs: a rerun resumes it)")
    proc.add_argument("--scheduler", default=None, metavar="ADDRESS",
                      help="an existing Dask scheduler, e.g. tcp://HOST:8786 (its workers see "
                           "the same paths); default: a LocalCluster on this machine")
    proc.add_argument("--workers", type=int, default=None, metavar="N",
                      help="LocalCluster worker processes (default: the cores)")
    proc.add_argument("--force", action="store_true",
                      help="run every task again, whatever a previous run left in OUT (each "
                           "product replaced whole as its task ends); without it, a rerun "
                           "skips the tasks whose inputs and settings are unchanged")
    proc.add_argument("--cell", type=float, default=None, metavar="M",
                      help="one ortho cell for every flight, so that all share one mosaic "
                           "(default: the campaign file's cell_m, else each flight's pixel "
                           "spacing, as `sisa georef`)")
    proc.add_argument("--memory-limit", default="auto", metavar="BYTES",
                      help="per LocalCluster worker, e.g. 2GiB (default: the machine's memory "
                           "shared among the workers)")
    parser.set_defaults(handler=_run)


# --- the campaign from the command line ----------------------------------------------------

def runs_campaign(folder: Path) -> CampaignSpec:
    """A folder of `sisa simulate` runs as a campaign: every subfolder holding a flight.mcap,
    in name order, its scenario's sensor as simulated."""
    import dataclasses

    from emulators.scenario import load_scenario
    from postproc.campaign import CampaignSpec, FlightSpec, check_name, check_unique
    from postproc.georef import GeorefOptions
    from sisa.commands.process import sensor_of

    runs = sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith(".")
                  and (p / "flight.mcap").is_file())
    if not runs:
        raise InputError(f"{folder}: no run folder (a subfolder with flight.mcap) in it")
    flights: list[FlightSpec] = []
    for run in runs:
        name = check_name(run.name, str(run))
        for need in ("scanner", "terrain/dem.tif", "scenario.toml"):
            if not name_taken(run / need):
                raise InputError(f"{run}: no {need}: not a `sisa simulate` run with images")
        scn = load_scenario(run / "scenario.toml")
        options = GeorefOptions(sensor=sensor_of(scn), dem=run / "terrain" / "dem.tif")
        options = dataclasses.replace(options, leap_seconds_fallback=scn.block.leap_seconds)
        flights.append(FlightSpec(name, (run / "flight.mcap",), run / "scanner", options,
                                  f"{run / 'scenario.toml'} (as simulated)"))
    check_unique([f.name for f in flights], str(folder))
    name = check_name(folder.resolve().name, str(folder))
    return CampaignSpec(name, name, tuple(flights), folder)


def with_cell(spec: CampaignSpec, cell_m: float) -> CampaignSpec:
    """Every flight mapped on cells of `cell_m` (--cell)."""
    import dataclasses

    if not 0 < cell_m <= 10_000:
        raise InputError(f"--cell {cell_m:g}: a size in metres, above 0, at most 10000")
    flights = tuple(dataclasses.replace(f, options=dataclasses.replace(f.options, cell_m=cell_m))
                    for f in spec.flights)
    return dataclasses.replace(spec, flights=flights)


def _claim_out(out: Path, spec: CampaignSpec) -> None:
    """OUT is new, or a folder this campaign wrote before (resumed); anything else is
    refused rather than written into."""
    marker = out / MARKER
    if name_taken(out):
        if not out.is_dir() or out.is_symlink():
            raise InputError(f"{out} exists and is not a folder")
        if marker.is_file():
            try:
                doc = json.loads(marker.read_text(encoding="utf-8"))
            except (OSError, ValueError):
                doc = {}
            if doc.get("campaign") != spec.name:
                shown = str(doc.get("campaign"))[:64]
                raise InputError(f"{out} holds campaign {shown!r}, not {spec.name!r}: choose "
                                 "a new output folder")
            return
        if any(out.iterdir()):
            raise InputError(f"{out} exists and is not a campaign's output folder: choose a "
                             "new one (outputs are never overwritten)")
    out.mkdir(parents=True, exist_ok=True)
    write_whole(marker, json.dumps({"campaign": spec.name, "source": str(spec.source)}) + "\n")


# --- the cluster -------------------------------------------------------------------------------

def _connector(args: argparse.Namespace, held: list[Any]) -> Any:
    """A function that starts (or joins) the cluster when the first task must run, says where
    its dashboard is, and keeps what it made in `held` to close at the end."""
    def connect() -> Client:
        from distributed import Client, LocalCluster

        dashboard = _has_bokeh()
        if args.scheduler is not None:
            try:
                client = Client(args.scheduler, timeout="20s")  # type: ignore[no-untyped-call]
            except (OSError, TimeoutError, ValueError) as exc:
                raise InputError(f"--scheduler {args.scheduler}: cannot connect ({exc})") \
                    from None
            workers = len(client.scheduler_info().get("workers", {}))
            print(f"cluster: {args.scheduler}, {workers} workers", file=sys.stderr)
        else:
            n = args.workers or os.cpu_count() or 1
            cluster = LocalCluster(  # type: ignore[no-untyped-call]
                n_workers=n, threads_per_worker=1, processes=True,
                memory_limit=args.memory_limit, dashboard_address="127.0.0.1:0",
                host="127.0.0.1")
            held.append(cluster)
            client = Client(cluster)  # type: ignore[no-untyped-call]
            info: dict[str, Any] = client.scheduler_info()["workers"]
            first: dict[str, Any] = next(iter(info.values()), {})
            limit = float(first.get("memory_limit") or 0)
            print(f"cluster: LocalCluster, {n} worker processes, 1 thread each, "
                  f"{limit / 2**30:.1f} GiB memory limit per worker", file=sys.stderr)
        held.append(client)
        if dashboard and client.dashboard_link:
            print(f"dashboard: {client.dashboard_link}", file=sys.stderr)
        else:
            print("dashboard: unavailable (bokeh is not installed)" if not dashboard else
                  "dashboard: none (the scheduler serves none)", file=sys.stderr)
        return client
    return connect


def _check_installed() -> None:
    """The campaign's own dependencies (the `campaign` extra), said missing in one line."""
    import importlib.util

    missing = [m for m in ("distributed", "pystac", "rio_cogeo", "jsonschema")
               if importlib.util.find_spec(m) is None]
    if missing:
        raise InputError(f"campaign: {', '.join(missing)} not installed: "
                         "pip install 'sisa[campaign]'")


def _check_address(address: str) -> None:
    """--scheduler as Dask takes it (PROTOCOL://HOST:PORT), checked before anything is
    written."""
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        parse_host_port(parse_address(address)[1])
    except ValueError as exc:
        raise InputError(f"--scheduler {address[:100]!r}: not a scheduler address such as "
                         f"tcp://HOST:8786 ({exc})") from None


def _has_bokeh() -> bool:
    import importlib.util

    return importlib.util.find_spec("bokeh") is not None


# --- progress ----------------------------------------------------------------------------------

class StageBars:
    """A bar per stage on a terminal (rich); otherwise a plain line of every stage's count on
    stderr every few seconds. Warnings go out one line each."""

    def __init__(self) -> None:
        self.total = dict.fromkeys(STAGES, 0)
        self.done = dict.fromkeys(STAGES, 0)
        self.reused = 0
        self.started = time.monotonic()
        self._bar: Any = None
        self._tasks: dict[str, Any] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if sys.stderr.isatty():
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
            )

            self._bar = Progress(TextColumn("{task.description:>7}"), BarColumn(),
                                 MofNCompleteColumn(), TimeElapsedColumn(), transient=True)
            self._bar.start()
            self._tasks = {s: self._bar.add_task(s, total=0) for s in STAGES}
        elif (period := plain_period_s()) is not None:
            self._thread = threading.Thread(target=self._lines, args=(period,), daemon=True)
            self._thread.start()

    def planned(self, stage: Stage, tasks: int) -> None:
        self.total[stage.value] += tasks
        if self._bar is not None:
            self._bar.update(self._tasks[stage.value], total=self.total[stage.value])

    def finished(self, stage: Stage, reused: bool) -> None:
        self.done[stage.value] += 1
        self.reused += reused
        if self._bar is not None:
            self._bar.update(self._tasks[stage.value], completed=self.done[stage.value])

    def warning(self, text: str) -> None:
        if self._bar is not None:
            self._bar.console.print(f"sisa campaign: warning: {text}", markup=False,
                                    highlight=False)
        else:
            say_warning("campaign", text)

    def line(self) -> str:
        counts = ", ".join(f"{s} {self.done[s]}/{self.total[s]}" for s in STAGES)
        return f"sisa campaign: {counts} ({clock(time.monotonic() - self.started)})"

    def _lines(self, period: float) -> None:
        while not self._stop.wait(period):
            print(f"{time.strftime('%H:%M:%S')} {self.line()}", file=sys.stderr, flush=True)

    def close(self) -> None:
        self._stop.set()
        if self._bar is not None:
            self._bar.stop()


# --- the command -------------------------------------------------------------------------------

def _lines_lost(run: CampaignRun) -> tuple[int, int]:
    """(scan lines georeferenced, lines the inputs promised) over the flights that synced;
    a flight that failed whole counts its lines (unknown before sync) as none."""
    geo = promised = 0
    for fl in run.flights.values():
        if fl.sync is None or not fl.sync.ok:
            continue
        for s, info in fl.sync.record["segments"].items():
            promised += max(int(info["listed"]), int(info["lines"]))
            cast = fl.casts.get(int(s))
            if cast is not None and cast.ok:
                geo += int(cast.record["segment"]["lines_georeferenced"])
    return geo, promised


def _run(args: argparse.Namespace) -> int:
    if getattr(args, "campaign_command", None) != "process":
        raise InputError("campaign: give an action: `sisa campaign process CAMPAIGN --out OUT`")
    started = time.perf_counter()
    if args.workers is not None and not 1 <= args.workers <= 1024:
        raise InputError(f"--workers {args.workers}: 1 to 1024")
    src: Path = args.campaign
    if not name_taken(src):
        raise InputError(f"{src}: no such file or folder")
    _check_installed()
    if args.scheduler is not None:
        _check_address(args.scheduler)
    from postproc.campaign import Driver, load_campaign, write_catalog

    spec = runs_campaign(src) if src.is_dir() else load_campaign(src)
    if args.cell is not None:
        spec = with_cell(spec, args.cell)
    _claim_out(args.out, spec)
    held: list[Any] = []
    bars = StageBars()
    try:
        run = Driver(spec, args.out, _connector(args, held), bars, force=args.force).run()
    finally:
        bars.close()
        for thing in reversed(held):
            thing.close()
    catalog = args.out / "stac" / "collection.json"
    if run.ran or not catalog.is_file():
        catalog = write_catalog(run)
    failures = run.failures()
    geo, promised = _lines_lost(run)
    segments = sum(1 for fl in run.flights.values() for o in fl.orthos.values() if o.ok)
    mosaics = sum(1 for m in run.mosaics.values() if m.outcome is not None and m.outcome.ok)
    print(f"{args.out}: {len(spec.flights)} flights, {segments} segments mapped, "
          f"{geo}/{promised} scan lines georeferenced, {mosaics} mosaics; {run.ran} tasks run, "
          f"{run.reused} reused; catalog {catalog}; {time.perf_counter() - started:.1f} s")
    if failures or geo < promised:
        for line in failures:
            say_warning("campaign", f"not made: {line}")
        what = (f"{len(failures)} flights, segments or mosaics not made" if failures else
                f"{promised - geo} of {promised} scan lines not georeferenced")
        return finished_with_losses("campaign", what)
    return 0
