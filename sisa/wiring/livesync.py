"""The incremental sync: `postproc.sync` run again and again on a flight log while it is being
recorded, in a process of its own at the lowest priority, so the crew learns in the air whether
the flight will synchronise.

It is the post-processor's sync, not a second method: every few seconds the records written
since the last pass are read (`recorder.follow`, never the whole log again), added to the
columns `sisa sync` reads, and `synchronise` runs on all of them (at a lower priority than the
recorder: `_lower_priority`). Each pass prints one JSON
line on stdout: how far INS records and scan lines are timed, what the crew should act on
(`warnings`), and the ground footprint of the lines recorded so far as GeoJSON, coloured by
whether they are timed. The recorder's process serves it (`sisa.wiring.live`). When stdin
closes (the recording has ended) one last pass reads the finished file; with `--out`, its
tables are written in `sisa sync`'s format beside the time each row was first timed.

    python -m sisa.wiring.livesync --log flight.mcap --period 5 --half-swath-m 120 [--out DIR]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import select
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from acquisition.clocks import wall_clock_ns
from postproc.sync import (
    WANTED,
    SyncResult,
    TimeStatus,
    sync_input_from_columns,
    synchronise,
    write_time_tables,
)
from recorder.columns import GrowingColumns
from recorder.follow import LogFollower
from recorder.messages import Topic
from sisa.core.errors import SisaError

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]

# what the pass reads: the sync's columns, and where the antenna was (for the footprint)
LIVE_WANTED: Final = {**WANTED, Topic.GPS_FIX: ("t_host_ns", "t_gps_ns", "lat_deg", "lon_deg",
                                                "quality")}
EARTH_RADIUS_M: Final = 6_371_000.0  # the footprint is a sketch for the crew, not a product
STALE_S: Final = 45.0  # an INS record logged this long ago and still untimed is a warning
TAG_WINDOW_NS: Final = 30 * 10**9  # forwards to the receiver's event input without a TTT
TIMED_COLOUR: Final = "#2ca02c"
UNTIMED_COLOUR: Final = "#d62728"
PENDING_COLOUR: Final = "#ff7f0e"
FOOTPRINT_VERTICES: Final = 40  # per run of lines: enough for a strip on a map
MAX_CPU_SHARE: Final = 0.05  # of a core, for the passes of a long flight


@dataclass
class FirstTimed:
    """When each row was first timed (wall clock, Unix ns) and the time it got then."""

    wall_ns: I64 = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    t_gps_ns: I64 = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def update(self, t_gps_ns: I64, status: I64, now_ns: int) -> None:
        n = t_gps_ns.size
        if n > self.wall_ns.size:  # rows are the log's prefix: new ones come at the end
            grow = n - self.wall_ns.size
            self.wall_ns = np.concatenate([self.wall_ns, np.full(grow, -1, dtype=np.int64)])
            self.t_gps_ns = np.concatenate([self.t_gps_ns, np.full(grow, -1, dtype=np.int64)])
        new = (status[:n] == TimeStatus.OK) & (self.wall_ns[:n] < 0)
        self.wall_ns[:n][new] = now_ns
        self.t_gps_ns[:n][new] = t_gps_ns[new]


class LiveSync:
    """The passes over one growing log."""

    def __init__(self, log: Path, half_swath_m: float) -> None:
        self.log = log
        self._window: tuple[float, float] | None = None  # as the log records it
        self.follower = LogFollower(log)
        self.columns = GrowingColumns(LIVE_WANTED)
        self.half_swath_m = half_swath_m
        self.passes = 0
        self.ins_first = FirstTimed()
        self.line_first = FirstTimed()
        self.result: SyncResult | None = None
        self.cols: dict[str, dict[str, npt.NDArray[Any]]] = {}

    def header_window_ms(self) -> tuple[float, float]:
        """The header window as `sisa sync` will read it from the log (so the live and the
        offline sync refuse the same segments), once the recorder has written it."""
        from recorder.settings import header_window_of_log

        if self._window is None:
            window, source = header_window_of_log([self.log])
            if source is None:  # not written yet, or a log without it: the default for now
                return window
            self._window = window
        return self._window

    def run_pass(self) -> dict[str, Any]:
        """Read what is new, synchronise everything so far; the pass's summary."""
        t0 = time.perf_counter()
        for channels, chunk in self.follower.poll_batches():
            self.columns.add_chunk(channels, chunk)
        self.cols = cols = self.columns.columns()
        self.passes += 1
        now_ns = wall_clock_ns()
        out: dict[str, Any] = {"pass": self.passes, "t_wall_ns": now_ns,
                               "log_bytes_read": self.follower.stats.bytes_read}
        try:
            result = synchronise(sync_input_from_columns(cols, self.header_window_ms()))
        except (SisaError, ValueError, IndexError, np.linalg.LinAlgError) as exc:
            self.result = None  # early in a flight the log may not hold enough yet
            out["state"] = _empty_state(cols, f"not yet synchronised: {exc}")
            out["warnings"] = []
            out["footprint"] = _geojson([])
        else:
            self.result = result
            self.ins_first.update(result.ins.t_gps_ns, result.ins.status, now_ns)
            self.line_first.update(result.lines.t_gps_ns, result.lines.status, now_ns)
            out["state"] = _state(cols, result)
            out["warnings"] = crew_warnings(cols, result)
            out["footprint"] = _geojson(footprint(cols, result, self.half_swath_m))
        out["state"]["pass_s"] = round(time.perf_counter() - t0, 4)
        return out

    def write(self, folder: Path) -> None:
        """The last pass's tables in `sisa sync`'s format, and when each row was first timed."""
        folder.mkdir(parents=True, exist_ok=True)
        res = self.result
        if res is None:
            return
        write_time_tables(folder, res.ins, res.lines)
        ins_log = self.cols[Topic.INS_RECORD]["log_time_ns"]
        hdr_log = self.cols[Topic.SCANNER_HEADER]["log_time_ns"]
        np.savez(folder / "first_timed.npz",
                 ins_log_time_ns=ins_log, ins_wall_ns=self.ins_first.wall_ns[:ins_log.size],
                 ins_t_gps_ns=self.ins_first.t_gps_ns[:ins_log.size],
                 line_log_time_ns=hdr_log, line_wall_ns=self.line_first.wall_ns[:hdr_log.size],
                 line_t_gps_ns=self.line_first.t_gps_ns[:hdr_log.size])


def _empty_state(cols: dict[str, dict[str, npt.NDArray[Any]]], note: str) -> dict[str, Any]:
    ins_n = int(cols[Topic.INS_RECORD]["counter"].size)
    lines_n = int(cols[Topic.SCANNER_HEADER]["segment"].size)
    return {"ins_records": ins_n, "ins_timed": 0, "ins_timed_pct": 0.0,
            "ins_timed_until_gps_ns": -1, "lines": lines_n, "lines_timed": 0,
            "lines_timed_until_gps_ns": -1, "segment": -1, "segment_lines": 0,
            "segment_lines_timed_pct": 0.0, "note": note}


def _state(cols: dict[str, dict[str, npt.NDArray[Any]]], res: SyncResult) -> dict[str, Any]:
    ins_ok = res.ins.status == TimeStatus.OK
    ln_ok = res.lines.status == TimeStatus.OK
    seg = res.lines.segment
    last_seg = int(seg[-1]) if seg.size else -1
    in_seg = seg == last_seg
    seg_n = int(np.count_nonzero(in_seg))
    seg_ok = int(np.count_nonzero(ln_ok & in_seg))
    return {
        "ins_records": int(ins_ok.size), "ins_timed": int(np.count_nonzero(ins_ok)),
        "ins_timed_pct": _pct(int(np.count_nonzero(ins_ok)), ins_ok.size),
        "ins_timed_until_gps_ns": int(res.ins.t_gps_ns[ins_ok].max()) if ins_ok.any() else -1,
        "lines": int(ln_ok.size), "lines_timed": int(np.count_nonzero(ln_ok)),
        "lines_timed_until_gps_ns": (int(res.lines.t_gps_ns[ln_ok].max()) if ln_ok.any()
                                     else -1),
        "segment": last_seg, "segment_lines": seg_n,
        "segment_lines_timed_pct": _pct(seg_ok, seg_n),
        "note": "",
    }


def _pct(part: int, whole: int) -> float:
    return round(100.0 * part / whole, 2) if whole else 0.0


def crew_warnings(cols: dict[str, dict[str, npt.NDArray[Any]]], res: SyncResult,
                  stale_s: float = STALE_S) -> list[str]:
    """What the crew can act on while airborne, in words; [] when all is well. An INS record
    still untimed `stale_s` after it was logged is one to warn of."""
    out: list[str] = []
    fwd, tags = cols[Topic.SYNC_FORWARD], cols[Topic.GPS_TIME_TAG]
    ins = cols[Topic.INS_RECORD]
    newest = max((int(c["log_time_ns"][-1]) for c in cols.values() if c["log_time_ns"].size),
                 default=0)
    since = newest - TAG_WINDOW_NS
    to_event = int(np.count_nonzero(fwd["to_gps_event"] & (fwd["log_time_ns"] >= since)))
    ttt = int(np.count_nonzero((tags["kind"] == "TTT") & (tags["log_time_ns"] >= since)))
    if to_event >= 3 and ttt == 0:
        out.append(f"tags not arriving: {to_event} pulses sent to the GPS event input in the "
                   "last 30 s and no TTT time tag back: check the receiver's event input and "
                   "its TTT output")
    stale = ins["log_time_ns"] < newest - int(stale_s * 1e9)
    untimed = stale & (res.ins.status != TimeStatus.OK)
    tl = res.ins_solution.timeline
    if tl.latch_record.size:  # outside the latched pulses: never timed
        beyond = tl.outside_latch_span()
        after_last = untimed & beyond  # before the first latch the sync had not begun: no warning
        after_last[:int(tl.latch_record.min())] = False
        untimed &= ~beyond
        if np.any(after_last):
            out.append(f"no pulse latched: {int(np.count_nonzero(after_last))} INS records "
                       f"logged over {stale_s:g} s ago, after the last pulse the INS latched, "
                       "not timed (a record is timed only between two latched pulses): check "
                       "the PPS and the sync cable to the INS")
    if np.any(untimed):
        latches = int(np.count_nonzero(ins["sync_flag"]))
        kinds = {TimeStatus(int(s)).name.lower(): int(n) for s, n in
                 zip(*np.unique(res.ins.status[untimed], return_counts=True), strict=True)}
        what = ", ".join(f"{n} {k}" for k, n in kinds.items())
        if latches == 0:
            out.append(f"INS records not timed ({what}): the INS latched no sync pulse: check "
                       "the sync cable to the INS")
        else:
            out.append(f"pattern not matching: INS records logged over {stale_s:g} s ago not "
                       f"timed ({what}), with {latches} latched pulses: the INS's pulses do "
                       "not match the sync unit's pattern yet")
    jumps = int(np.count_nonzero(res.ins.status == TimeStatus.CLOCK_JUMP))
    if jumps:
        out.append(f"INS clock jump: {jumps} records between two fits flagged clock_jump "
                   "(the INS clock jumped; records on either side are timed separately)")
    hdr = cols[Topic.SCANNER_HEADER]
    lines = res.report.get("lines", {})
    if hdr["segment"].size and int(lines.get("frame_pulses_with_counter", 0)) == 0:
        out.append(f"scanner headers without pulses: {hdr['segment'].size} frame headers and "
                   f"{int(lines.get('frame_pulses_forwarded', 0))} frame pulses tied to a "
                   "frame: check the scanner's frame-pulse line and the header window")
    return out


def footprint(cols: dict[str, dict[str, npt.NDArray[Any]]], res: SyncResult,
              half_swath_m: float) -> list[dict[str, Any]]:
    """GeoJSON features: per strip (scanner segment), each run of lines timed or not as a
    swath polygon along the antenna track, coloured by its sync state. Where the antenna was
    comes from the fixes by host time, so untimed lines are placed too."""
    hdr, fix = cols[Topic.SCANNER_HEADER], cols[Topic.GPS_FIX]
    good = fix["quality"] > 0
    f_t = fix["t_host_ns"][good]
    if f_t.size < 2 or hdr["segment"].size == 0 or half_swath_m <= 0:
        return []
    order = np.argsort(f_t, kind="stable")
    f_t, lat, lon = f_t[order], fix["lat_deg"][good][order], fix["lon_deg"][good][order]
    n = min(hdr["segment"].size, res.lines.status.size)  # without lines files: one row a header
    seg, t_hdr = hdr["segment"][:n], hdr["t_host_ns"][:n]
    ok = res.lines.status[:n] == TimeStatus.OK
    newest = int(t_hdr.max())
    features = []
    for s in np.unique(seg).tolist():
        idx = np.flatnonzero(seg == s)
        cut = np.flatnonzero(np.diff(ok[idx].astype(np.int8))) + 1
        for run in np.split(idx, cut):
            timed = bool(ok[run[0]])
            recent = newest - int(t_hdr[run[-1]]) < STALE_S * 1e9
            colour = TIMED_COLOUR if timed else PENDING_COLOUR if recent else UNTIMED_COLOUR
            ring = _swath(t_hdr[run], f_t, lat, lon, half_swath_m)
            if ring is None:
                continue
            features.append({
                "type": "Feature",
                "geometry": {"type": "Polygon", "coordinates": [ring]},
                "properties": {"name": f"strip {s}: {run.size} lines "
                                       f"{'timed' if timed else 'not timed yet'}",
                               "segment": s, "lines": int(run.size), "timed": timed,
                               "style": {"color": colour, "fillColor": colour,
                                         "weight": 1, "opacity": 0.9, "fillOpacity": 0.35}},
            })
    return features


def _swath(t_ns: I64, f_t: I64, lat: F64, lon: F64, half_m: float) -> list[list[float]] | None:
    """A polygon ring [lon, lat] half_m either side of the antenna's path over t_ns."""
    pick = np.unique(np.linspace(0, t_ns.size - 1, min(t_ns.size, FOOTPRINT_VERTICES))
                     .astype(np.int64))
    t = (t_ns[pick] - f_t[0]).astype(np.float64)
    x = (f_t - f_t[0]).astype(np.float64)
    la, lo = np.interp(t, x, lat), np.interp(t, x, lon)
    if la.size < 2:  # one line: its heading from the track around it
        la = np.interp([t[0] - 5e8, t[0] + 5e8], x, lat)
        lo = np.interp([t[0] - 5e8, t[0] + 5e8], x, lon)
    k = np.cos(np.radians(la))
    north = np.gradient(la) * math.pi / 180 * EARTH_RADIUS_M
    east = np.gradient(lo) * math.pi / 180 * EARTH_RADIUS_M * k
    norm = np.hypot(north, east)
    if not np.all(norm > 0):
        return None
    # to the right of the track: (east, north) turned clockwise = (−north... ) as (dE, dN)
    r_e, r_n = north / norm, -east / norm
    d_lat = np.degrees(r_n * half_m / EARTH_RADIUS_M)
    d_lon = np.degrees(r_e * half_m / (EARTH_RADIUS_M * k))
    right = np.column_stack([lo + d_lon, la + d_lat])
    left = np.column_stack([lo - d_lon, la - d_lat])[::-1]
    ring = np.vstack([right, left, right[:1]])
    return [[round(float(a), 7), round(float(b), 7)] for a, b in ring]


def _geojson(features: list[dict[str, Any]]) -> str:
    return json.dumps({"type": "FeatureCollection", "features": features},
                      separators=(",", ":"))


NICENESS: Final = 10  # below the recorder; not SCHED_IDLE, which other work could starve


def _lower_priority() -> None:
    """Give way to the recorder: its duties come first. Not SCHED_IDLE: any other busy process
    on the machine could then starve the passes, and the crew's view would stop; at nice 10 a
    pass still gets its share, and the recorder, waking every few ms, preempts it."""
    with contextlib.suppress(OSError):
        os.nice(NICENESS)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sisa.wiring.livesync",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--log", type=Path, required=True, help="the recording (first part)")
    parser.add_argument("--period", type=float, default=5.0, help="seconds between passes")
    parser.add_argument("--half-swath-m", type=float, default=0.0)
    parser.add_argument("--out", type=Path, default=None,
                        help="write the last pass's tables here when stdin closes")
    args = parser.parse_args(argv)
    _lower_priority()
    live = LiveSync(args.log, args.half_swath_m)
    ending = False
    wait_s = args.period
    while True:
        ready, _, _ = select.select([sys.stdin], [], [], wait_s)
        if ready and not os.read(sys.stdin.fileno(), 4096):  # closed: the recording has ended
            ending = True
        cpu0 = time.process_time()
        try:
            line = json.dumps(live.run_pass(), separators=(",", ":"))
        except Exception as exc:  # a pass that fails says so and the next runs
            line = json.dumps({"pass": live.passes, "t_wall_ns": wall_clock_ns(),
                               "error": f"{type(exc).__name__}: {exc}"[:300]})
        with contextlib.suppress(BrokenPipeError):
            print(line, flush=True)
        # a long flight's pass takes longer (1 s at 5 hours): the passes then space out so
        # that they never take more than MAX_CPU_SHARE of a core
        wait_s = max(args.period, (time.process_time() - cpu0) / MAX_CPU_SHARE)
        if ending:
            if args.out is not None:
                live.write(args.out)
            return 0


if __name__ == "__main__":
    sys.exit(main())
