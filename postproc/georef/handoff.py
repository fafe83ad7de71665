"""The sync stage's hand-off to georeferencing: the flight log read once (sync and navigation
columns, and the recorder's own counts, in one pass), every INS record and scan line put on GPS
time, the trajectory the lines are looked up in (the log's navigation, or a trajectory file),
and the sync's files."""

from __future__ import annotations

import dataclasses
import io
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from postproc.georef.jobrecords import GeorefOptions
from postproc.georef.navigation import (
    NAV_WANTED,
    AntennaFixes,
    Columns,
    NavConfig,
    PiecewiseTrajectory,
    Trajectory,
    fixes_from_columns,
    nav_from_columns,
)
from postproc.georef.trajfiles import TRAJ_WANTED, read_trajectory_file
from postproc.sync import WANTED as SYNC_WANTED
from postproc.sync import (
    InsTimes,
    LineTimes,
    SyncResult,
    read_scanner_lines,
    sync_input_from_columns,
    synchronise,
    write_photo_times,
    write_report,
    write_time_tables,
)
from recorder.columns import read_topics
from recorder.framing import Paths, log_paths
from recorder.health import HEALTH_WANTED, HealthTotals, recording_note
from recorder.messages import Topic
from recorder.parts import recording_metadata
from recorder.settings import header_window_ms, recorded_camera_window_ms
from sisa.core.errors import InputError
from sisa.core.jsonio import finite_json
from sisa.core.outdir import write_whole
from sisa.core.timescale import gps_span_label


@dataclass(frozen=True)
class SyncTables:
    """What georeferencing takes of the sync: every INS record's and scan line's time, and
    the sync's report (a hand-off read back from its file holds these, not the whole
    SyncResult)."""

    ins: InsTimes
    lines: LineTimes
    report: dict[str, Any]


@dataclass
class Handoff:
    """The flight on GPS time, as georeferencing takes it."""

    sync: SyncResult | SyncTables
    trajectory: Trajectory
    trajectory_name: str  # for messages: "the trajectory FILE", "the flight log's navigation"
    info: dict[str, Any]  # the trajectory's source, span and gaps (the summary's "trajectory")
    log_fixes: AntennaFixes  # the log's own GPS fixes, for a judge of the run
    recording_health: HealthTotals  # the recorder's own counts, from the log
    nav: dict[str, Columns] = field(default_factory=dict)  # the log's NAV_WANTED columns

    def trajectory_span_label(self) -> str:
        traj = self.trajectory
        gaps = len(traj.gaps_ns()) if isinstance(traj, PiecewiseTrajectory) else 0
        return gps_span_label(*traj.span_ns) + (f", {gaps} gaps inside" if gaps else "")


def merged_wanted(*wanted: dict[str, tuple[str, ...]]) -> dict[str, tuple[str, ...]]:
    """One field list per topic for a single read_topics pass."""
    out: dict[str, tuple[str, ...]] = {}
    for w in wanted:
        for topic, fields in w.items():
            out[topic] = tuple(dict.fromkeys((*out.get(topic, ()), *fields)))
    return out


def read_and_sync(flight: Paths, scanner_dir: Path, opt: GeorefOptions, notes: list[str]
                  ) -> Handoff:
    """The log read once and synchronised with the scanner's lines files; what the reading
    and the trajectory have to say is added to `notes`."""
    lines = read_scanner_lines(scanner_dir)
    wanted = (SYNC_WANTED, NAV_WANTED) + ((TRAJ_WANTED,) if opt.trajectory else ())
    cols = read_topics(flight, {**merged_wanted(*wanted), **HEALTH_WANTED}, notes=notes)
    health = HealthTotals.from_columns(cols[Topic.HEALTH])
    recording = recording_note(health, log_paths(flight)[0])
    if recording is not None:  # the log may hold less than the devices sent
        notes.append(recording)
    meta = recording_metadata(log_paths(flight)[0])
    result = synchronise(sync_input_from_columns(cols, header_window_ms(meta)), lines,
                         camera_window_ms=recorded_camera_window_ms(meta))
    log_fixes = fixes_from_columns(cols)  # the log's own GPS, for a judge of the run
    info: dict[str, Any] = {}
    traj = _trajectory(cols, result, opt, info, notes)
    info["t_first_gps_ns"], info["t_last_gps_ns"] = (int(t) for t in traj.span_ns)
    info["gps_time"] = gps_span_label(*traj.span_ns)
    if isinstance(traj, PiecewiseTrajectory):
        info["gaps"] = [{"t_first_gps_ns": a, "t_last_gps_ns": b}
                        for a, b in traj.gaps_ns()]
    name = (f"the trajectory {opt.trajectory}" if opt.trajectory is not None else
            "the flight log's navigation")
    nav = {t: {f: cols[t][f] for f in fields if f in cols.get(t, {})}
           for t, fields in NAV_WANTED.items()}
    return Handoff(result, traj, name, info, log_fixes, health, nav)


def _trajectory(cols: dict[str, Columns], result: SyncResult | SyncTables, opt: GeorefOptions,
                info: dict[str, Any], notes: list[str]) -> Trajectory:
    """The trajectory file's, or the log's navigation on the synchronised INS times; its
    source (and a trajectory file's format and time scale) into `info`."""
    antenna_offset_m = opt.sensor.mounting.antenna_offset_m
    if opt.trajectory is None:
        info["source"] = "flight log"
        config = None if opt.max_gap_s is None else NavConfig(max_gps_gap_s=opt.max_gap_s)
        return nav_from_columns(cols, result.ins, antenna_offset_m=antenna_offset_m,
                                config=config)
    info["source"] = str(opt.trajectory)
    traj = read_trajectory_file(opt.trajectory, cols, result.ins,
                                antenna_offset_m=antenna_offset_m,
                                leap_seconds=opt.leap_seconds,
                                fallback_leap_seconds=opt.leap_seconds_fallback,
                                max_gap_s=opt.max_gap_s, report=info)
    notes += info.pop("warnings", [])
    if opt.leap_seconds is not None and info.get("time_scale") not in ("UTC", "JST"):
        kind = "an SBET" if info.get("format") == "Applanix SBET" else "a .pos"
        notes.append(f"--leap-seconds {opt.leap_seconds}: not used: {opt.trajectory} is "
                     f"{kind} on GPS time (the option is for a .pos on UTC or JST)")
    return traj


def write_sync(out_dir: Path, result: SyncResult | SyncTables) -> None:
    """The sync's files: INS record and line times, and its report, in out_dir/sync."""
    sync_dir = out_dir / "sync"
    sync_dir.mkdir(parents=True, exist_ok=True)
    write_time_tables(sync_dir, result.ins, result.lines)
    photos = getattr(result, "photos", None)
    if photos is not None:
        write_photo_times(sync_dir, photos)
    write_report(sync_dir / "sync_report.json", result.report)


def save_handoff(path: Path, handoff: Handoff) -> None:
    """The flight on GPS time, kept for the tasks that georeference its segments one by one
    (a campaign), as plain arrays (a NumPy .npz, no pickle: nothing in it can run code): the
    INS records' and lines' times, the log's navigation columns the trajectory is built from,
    and what is said of them (JSON). Tens of bytes per INS record; never image data."""
    arrays: dict[str, Any] = {}
    for topic, fields in handoff.nav.items():
        for name, values in fields.items():
            arrays[f"nav|{topic}|{name}"] = np.asarray(values)
    for prefix, table in (("ins", handoff.sync.ins), ("lines", handoff.sync.lines)):
        for name in table.__dataclass_fields__:
            arrays[f"{prefix}|{name}"] = np.asarray(getattr(table, name))
    meta = {"info": finite_json(handoff.info), "trajectory_name": handoff.trajectory_name,
            "report": finite_json(handoff.sync.report)}
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    write_whole(path, buf.getvalue())


def load_handoff(path: Path, opt: GeorefOptions) -> Handoff:
    """A hand-off `save_handoff` wrote, its trajectory built again from the navigation
    columns (or `opt.trajectory`'s file) as `read_and_sync` built it: the same poses. The
    recorder's counts and the log's own fixes are not in it (the sync task reports them)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        meta = json.loads(arrays.pop("meta").tobytes().decode())
        nav: dict[str, Columns] = {}
        tables: dict[str, dict[str, Any]] = {"ins": {}, "lines": {}}
        for key, values in arrays.items():
            kind, *rest = key.split("|")
            if kind == "nav":
                nav.setdefault(rest[0], {})[rest[1]] = values
            else:
                tables[kind][rest[0]] = values
        sync = SyncTables(InsTimes(**tables["ins"]), LineTimes(**tables["lines"]),
                          meta["report"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{path}: unreadable sync hand-off ({str(exc)[:200]}): synchronise "
                         "the flight again") from None
    info: dict[str, Any] = dict(meta["info"])
    rebuilt: dict[str, Any] = {}
    if opt.trajectory is not None and info.get("leap_seconds") is not None:
        opt = dataclasses.replace(opt, leap_seconds=int(info["leap_seconds"]))
    traj = _trajectory(nav, sync, opt, rebuilt, [])
    fixes = AntennaFixes(np.zeros(0, np.int64), np.zeros((0, 3)))
    return Handoff(sync, traj, str(meta["trajectory_name"]), info, fixes, HealthTotals(), nav)
