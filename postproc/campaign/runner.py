"""The campaign's graph on Dask: each flight synchronised once, each segment cast and mapped as
tasks of their own, each flight finished, then one mosaic per band set. The driver submits a
task as soon as what it needs is known (a flight's segments after its sync, its ortho cell
after all its segments are cast), so Dask's scheduler always has every task that can run.

A task whose key (its inputs' fingerprints and settings, and the keys it builds on) matches the
stamp it left in OUT is not run again: its recorded outcome is used. A run with nothing to do
never starts a cluster (`connect` is called at the first task to run).

OUT/flights/NAME/           the flight's products, as `sisa georef` names them
OUT/flights/NAME/.tasks/    one stamp per task: its key and outcome (JSON)
OUT/mosaics/                one mosaic COG per band set, CRS and cell
"""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import hashlib
import json
import os
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final, Protocol

from postproc.campaign.config import CampaignSpec, FlightSpec
from postproc.campaign.demvrt import write_dem_vrt
from postproc.campaign.fingerprint import file_fingerprint, files_fingerprint, task_key
from postproc.campaign.tasks import (
    Outcome,
    cast_task,
    flight_task,
    handoff_path,
    mosaic_task,
    ortho_task,
    segment_from_record,
    sync_task,
)
from postproc.georef import ortho_cell_m
from sisa.core.errors import InputError
from sisa.core.outdir import write_whole

if TYPE_CHECKING:
    from distributed import Client, Future

# bumped when a task's products change for the same inputs: every stamp is then stale
TASKS_VERSION: Final = "2"
RETRIES: Final = 1  # a task that raised (not a worker lost: Dask reschedules that itself)
STAMPS: Final = ".tasks"
DEM_VRT: Final = "dem_mosaic.vrt"  # in the flight's folder, when its DEM comes in tiles


class Stage(StrEnum):
    SYNC = "sync"
    GEOREF = "georef"
    ORTHO = "ortho"
    FLIGHT = "flight"
    MOSAIC = "mosaic"


class Events(Protocol):
    """What the driver tells its caller as it goes (progress bars, warnings)."""

    def planned(self, stage: Stage, tasks: int) -> None: ...

    def finished(self, stage: Stage, reused: bool) -> None: ...

    def warning(self, text: str) -> None: ...


@dataclass
class Step:
    """One task: its stage, flight and segment, its key and stamp, and what it needs."""

    stage: Stage
    flight: str
    segment: int
    key: str
    stamp: Path
    call: Callable[..., Outcome]
    args: tuple[Any, ...]
    name: str


@dataclass
class FlightRun:
    spec: FlightSpec
    out: Path
    sync_key: str = ""
    sync: Outcome | None = None
    cast_keys: dict[int, str] = field(default_factory=dict)
    casts: dict[int, Outcome] = field(default_factory=dict)
    ortho_keys: dict[int, str] = field(default_factory=dict)
    orthos: dict[int, Outcome] = field(default_factory=dict)
    cell_m: float | None = None
    finish: Outcome | None = None
    failure: str | None = None  # the flight as a whole: why it gave nothing

    @property
    def epsg(self) -> int:
        return int(self.sync.record["epsg"]) if self.sync is not None else 0

    @property
    def settled(self) -> bool:
        return self.failure is not None or self.finish is not None

    def warnings(self) -> list[str]:
        found = list(self.sync.warnings) if self.sync is not None else []
        for s in sorted(self.casts):
            found += self.casts[s].warnings
        for s in sorted(self.orthos):
            found += self.orthos[s].warnings
        return found


@dataclass
class MosaicRun:
    name: str
    epsg: int
    cell_m: float
    members: list[tuple[str, int]]  # (flight, segment)
    key: str = ""
    outcome: Outcome | None = None


@dataclass
class CampaignRun:
    spec: CampaignSpec
    out: Path
    flights: dict[str, FlightRun]
    mosaics: dict[str, MosaicRun] = field(default_factory=dict)
    ran: int = 0  # tasks run
    reused: int = 0  # tasks whose stamp matched
    # per stage run: (first task submitted, last one done), time.monotonic() seconds
    spans_s: dict[Stage, tuple[float, float]] = field(default_factory=dict)

    def failures(self) -> list[str]:
        """Every flight, segment or mosaic that gave nothing, with its reason."""
        said = []
        for name, fl in self.flights.items():
            if fl.failure is not None:
                said.append(f"flight {name}: {fl.failure}")
            for o in [*fl.casts.values(), *fl.orthos.values()]:
                if not o.ok and fl.failure is None:
                    said.append(f"flight {name}: {o.reason}")
        said += [f"{m.name}: {m.outcome.reason}" for m in self.mosaics.values()
                 if m.outcome is not None and not m.outcome.ok]
        return said


class Driver:
    """Runs a campaign's tasks on the client `connect` gives (called once, at the first task
    that must run)."""

    def __init__(self, spec: CampaignSpec, out: Path, connect: Callable[[], Client],
                 events: Events, *, force: bool = False) -> None:
        """`force`: every task runs, whatever its stamp says."""
        self.spec, self.out, self.events = spec, out, events
        self.force = force
        self._connect = connect
        self._client: Client | None = None
        self.run_state = CampaignRun(spec, out, {
            f.name: FlightRun(f, out / "flights" / f.name) for f in spec.flights})
        self._ready: deque[tuple[Step, Outcome, bool]] = deque()
        self._running: dict[Future[Outcome], Step] = {}

    # --- the loop --------------------------------------------------------------------------

    def run(self) -> CampaignRun:
        with _locked(self.out):
            _remove_partials(self.out)
            self.events.planned(Stage.SYNC, len(self.spec.flights))
            self.events.planned(Stage.FLIGHT, len(self.spec.flights))
            for fl in self.run_state.flights.values():
                try:
                    step = self._sync_step(fl)
                except InputError as exc:  # its DEM tiles do not make one DEM
                    fl.failure = str(exc)
                    self.events.finished(Stage.SYNC, False)
                    self.events.finished(Stage.FLIGHT, False)
                    self.events.warning(f"{fl.spec.name}: {exc}")
                    continue
                self._start(step)
            mosaics_started = False
            while self._ready or self._running:
                while self._ready:
                    self._on_done(*self._ready.popleft())
                if not mosaics_started and all(f.settled for f in
                                               self.run_state.flights.values()):
                    mosaics_started = True
                    self._start_mosaics()
                    continue
                if self._running:
                    self._wait_one()
            _remove_partials(self.out)  # a task that died with its worker ran again elsewhere
        return self.run_state

    def _wait_one(self) -> None:
        from distributed import wait

        done, _ = wait(list(self._running), return_when="FIRST_COMPLETED")  # type: ignore[no-untyped-call]
        for fut in done:
            step = self._running.pop(fut)
            first, _ = self.run_state.spans_s[step.stage]
            self.run_state.spans_s[step.stage] = (first, time.monotonic())
            try:
                outcome = fut.result()
            except Exception as exc:  # a bug, or a worker lost more often than Dask allows
                outcome = Outcome(False, reason=f"{type(exc).__name__}: {str(exc)[:300]}")
                self._ready.append((step, outcome, False))
                continue
            _write_stamp(step, outcome)  # a failure on the inputs too: it would fail again
            self._ready.append((step, outcome, False))

    def _start(self, step: Step) -> None:
        found = None if self.force else _read_stamp(step)
        if found is not None and self._outputs_exist(step, found):
            self.run_state.reused += 1
            self._ready.append((step, found, True))
            return
        if self._client is None:
            self._client = self._connect()
        self.run_state.ran += 1
        now = time.monotonic()
        first = self.run_state.spans_s.get(step.stage, (now, now))[0]
        self.run_state.spans_s[step.stage] = (first, now)
        fut = self._client.submit(step.call, *step.args, key=f"{step.name}-{step.key[:12]}-"
                                  f"{os.urandom(3).hex()}", retries=RETRIES, pure=False)
        self._running[fut] = step

    def _outputs_exist(self, step: Step, outcome: Outcome) -> bool:
        fl = self.run_state.flights.get(step.flight)
        rec = outcome.record
        if step.stage is Stage.SYNC:
            return not outcome.ok or (fl is not None and handoff_path(fl.out).is_file())
        if step.stage is Stage.GEOREF and outcome.ok and fl is not None:
            return _here(fl, rec["segment"])["igm"].is_file()
        if step.stage is Stage.ORTHO and outcome.ok and fl is not None:
            return all((fl.out / f).is_file() for f in rec["segment"]["files"].values())
        if step.stage is Stage.FLIGHT and outcome.ok and fl is not None:
            return (fl.out / str(rec["summary"])).is_file()
        if step.stage is Stage.MOSAIC and outcome.ok:
            return (self.out / "mosaics" / str(rec["mosaic"])).is_file()
        return True

    def _on_done(self, step: Step, outcome: Outcome, reused: bool) -> None:
        self.events.finished(step.stage, reused)
        if not reused:
            for w in outcome.warnings:
                self.events.warning(f"{step.flight}: {w}" if step.flight else w)
            if not outcome.ok:
                self.events.warning(f"{step.name}: {outcome.reason}")
        if step.stage is Stage.MOSAIC:
            self.run_state.mosaics[step.flight].outcome = outcome
            return
        fl = self.run_state.flights[step.flight]
        if step.stage is Stage.SYNC:
            self._synced(fl, outcome)
        elif step.stage is Stage.GEOREF:
            fl.casts[step.segment] = outcome
            self._maybe_orthos(fl)
        elif step.stage is Stage.ORTHO:
            fl.orthos[step.segment] = outcome
            self._maybe_finish(fl)
        else:
            fl.finish = outcome
            if not outcome.ok:
                fl.failure = outcome.reason

    # --- the steps of a flight ---------------------------------------------------------------

    def _sync_step(self, fl: FlightRun) -> Step:
        from recorder.parts import flight_parts

        if len(fl.spec.dems) > 1:  # tiles: their mosaic, as the flight's DEM
            vrt = fl.out / DEM_VRT
            write_dem_vrt(fl.spec.dems, vrt)
            fl.spec = dataclasses.replace(
                fl.spec, options=dataclasses.replace(fl.spec.options, dem=vrt))
        spec, opt = fl.spec, fl.spec.options
        try:
            parts = flight_parts(list(spec.log))
        except InputError:
            parts = list(spec.log)
        scanner = sorted(p for p in spec.scanner.iterdir() if p.is_file())
        fl.sync_key = task_key(
            "sync", TASKS_VERSION, files_fingerprint(parts), files_fingerprint(scanner),
            _dem_fingerprint(spec),
            files_fingerprint([opt.trajectory] if opt.trajectory else []),
            spec.sensor_text, opt.epsg, opt.leap_seconds, opt.leap_seconds_fallback,
            opt.max_gap_s)
        return self._step(Stage.SYNC, fl, -1, fl.sync_key, sync_task, (spec, fl.out))

    def _step(self, stage: Stage, fl: FlightRun, segment: int, key: str,
              call: Callable[..., Outcome], args: tuple[Any, ...]) -> Step:
        tag = stage.value if segment < 0 else f"{stage.value}_{segment:03d}"
        return Step(stage, fl.spec.name, segment, key, fl.out / STAMPS / f"{tag}.json", call,
                    args, f"{tag}-{fl.spec.name}")

    def _synced(self, fl: FlightRun, outcome: Outcome) -> None:
        fl.sync = outcome
        if not outcome.ok:
            fl.failure = outcome.reason
            self.events.finished(Stage.FLIGHT, True)
            return
        opt = fl.spec.options
        geoid = opt.geoid if not isinstance(opt.geoid, Path) else file_fingerprint(opt.geoid)
        segments = {int(s): v for s, v in outcome.record["segments"].items()}
        self.events.planned(Stage.GEOREF, len(segments))
        self.events.planned(Stage.ORTHO, len(segments))
        for s, info in sorted(segments.items()):
            key = task_key("cast", fl.sync_key, file_fingerprint(Path(info["image"])),
                           _dem_fingerprint(fl.spec), geoid, opt.block_lines)  # (not the
            # cell: the IGM does not depend on it; a cell too wide is refused before the orthos)
            fl.cast_keys[s] = key
            self._start(self._step(Stage.GEOREF, fl, s, key, cast_task, (fl.spec, fl.out, s)))

    def _maybe_orthos(self, fl: FlightRun) -> None:
        if len(fl.casts) < len(fl.cast_keys):
            return
        done = [segment_from_record(o.record["segment"]) for _, o in sorted(fl.casts.items())
                if o.ok]
        lost = len(fl.cast_keys) - len(done)
        for _ in range(lost):  # the orthos those segments will never have
            self.events.finished(Stage.ORTHO, True)
        if not done:
            fl.failure = "no segment could be georeferenced: " + "; ".join(
                o.reason for _, o in sorted(fl.casts.items()))[:500]
            self.events.finished(Stage.FLIGHT, True)
            return
        try:
            fl.cell_m = ortho_cell_m(fl.spec.options, done)
        except InputError as exc:
            fl.failure = str(exc)
            for _ in done:
                self.events.finished(Stage.ORTHO, True)
            self.events.finished(Stage.FLIGHT, True)
            return
        for s, o in sorted(fl.casts.items()):
            if o.ok:
                key = task_key("ortho", fl.cast_keys[s], fl.cell_m, fl.epsg)
                fl.ortho_keys[s] = key
                doc = {**o.record["segment"], "igm": str(_here(fl, o.record["segment"])["igm"])}
                self._start(self._step(Stage.ORTHO, fl, s, key, ortho_task,
                                       (fl.out, doc, fl.epsg, fl.cell_m)))

    def _maybe_finish(self, fl: FlightRun) -> None:
        if len(fl.orthos) < len(fl.ortho_keys):
            return
        docs = [{**o.record["segment"], "igm": str(_here(fl, o.record["segment"])["igm"])}
                for _, o in sorted(fl.orthos.items()) if o.ok]
        features = [o.record["footprint"] for _, o in sorted(fl.orthos.items()) if o.ok]
        skips = [sk for _, o in sorted(fl.casts.items()) for sk in o.record.get("skipped", [])]
        key = task_key("flight", sorted(fl.ortho_keys.values()), sorted(fl.cast_keys.values()))
        assert fl.cell_m is not None
        self._start(self._step(Stage.FLIGHT, fl, -1, key, flight_task,
                               (fl.spec, fl.out, docs, features, skips, fl.epsg, fl.cell_m,
                                fl.warnings(), fl.sync.record["recording_health"]
                                if fl.sync is not None else {})))

    # --- the mosaics -----------------------------------------------------------------------

    def _start_mosaics(self) -> None:
        groups: dict[tuple[Any, ...], MosaicRun] = {}
        bounds: dict[str, list[float]] = {}
        for fl in self.run_state.flights.values():
            for s, o in sorted(fl.orthos.items()):
                if not o.ok or "ortho" not in o.record or fl.cell_m is None:
                    continue
                orth = o.record["ortho"]
                band_set = (orth["bands"], orth["dtype"], tuple(orth["band_names"]))
                gkey = (band_set, fl.epsg, fl.cell_m)
                if gkey not in groups:
                    tag = hashlib.sha256(json.dumps(band_set).encode()).hexdigest()[:6]
                    name = (f"mosaic_{orth['bands']}b_{orth['dtype']}_{tag}_epsg{fl.epsg}_"
                            f"{fl.cell_m:g}m")
                    groups[gkey] = MosaicRun(name, fl.epsg, fl.cell_m, [])
                    bounds[name] = list(orth["bounds"])
                m = groups[gkey]
                m.members.append((fl.spec.name, s))
                b = bounds[m.name]
                w, so, e, n = orth["bounds"]
                bounds[m.name] = [min(b[0], w), min(b[1], so), max(b[2], e), max(b[3], n)]
        self.events.planned(Stage.MOSAIC, len(groups))
        (self.out / "mosaics").mkdir(parents=True, exist_ok=True)
        for m in groups.values():
            self.run_state.mosaics[m.name] = m
            pairs = []
            keys = []
            for flight, s in m.members:
                fl = self.run_state.flights[flight]
                rec = fl.orthos[s].record["segment"]
                pairs.append((str(fl.out / rec["files"]["glt"]), rec["image"]))
                keys.append(fl.ortho_keys[s])
            m.key = task_key("mosaic", keys, m.cell_m, m.epsg)
            step = Step(Stage.MOSAIC, m.name, -1, m.key,
                        self.out / "mosaics" / STAMPS / f"{m.name}.json", mosaic_task,
                        (pairs, bounds[m.name], m.cell_m, m.epsg,
                         self.out / "mosaics" / f"{m.name}.tif"), m.name)
            self._start(step)


# --- stamps and the output folder ------------------------------------------------------------

def _dem_fingerprint(spec: FlightSpec) -> dict[str, str]:
    """The DEM's, and each tile's when it is their VRT mosaic (the VRT is rewritten only when
    its text changes: a tile changed in place leaves it as it was)."""
    return files_fingerprint([spec.options.dem, *spec.dems])


def _here(fl: FlightRun, seg: dict[str, Any]) -> dict[str, Path]:
    """A segment record's products where the flight's folder is now (an output folder may
    have been moved since the record was made): they are named inside it."""
    return {"igm": fl.out / Path(seg["igm"]).name}


def _read_stamp(step: Step) -> Outcome | None:
    try:
        doc = json.loads(step.stamp.read_text(encoding="utf-8"))
        if doc.get("key") != step.key:
            return None
        return Outcome.from_dict(doc["outcome"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _write_stamp(step: Step, outcome: Outcome) -> None:
    step.stamp.parent.mkdir(parents=True, exist_ok=True)
    write_whole(step.stamp, json.dumps({"key": step.key, "task": step.name,
                                        "outcome": outcome.as_dict()}, indent=1) + "\n")


@contextlib.contextmanager
def _locked(out: Path) -> Iterator[None]:
    """One run at a time on an output folder: a second is refused, not interleaved."""
    out.mkdir(parents=True, exist_ok=True)
    with (out / ".campaign.lock").open("a") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError(f"{out}: another `sisa campaign process` is running on it") \
                from None
        yield


def _remove_partials(out: Path) -> None:
    """Files a task was writing when its worker died: never renamed into place, removed."""
    for path in out.rglob(".*.partial-*"):
        with contextlib.suppress(OSError):
            if path.is_file() or path.is_symlink():
                path.unlink()
