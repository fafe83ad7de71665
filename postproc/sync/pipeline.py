"""Time synchronisation: every INS record and every scan line in GPS time (seed §3.5, §5.3).

    inp = read_sync_input(paths)                  # one streaming pass over the flight log
    result = synchronise(inp, lines=read_scanner_lines(folder))
    result.ins.t_gps_ns, result.ins.status        # per INS record, in log order
    result.lines.t_gps_ns, result.lines.status    # per scan line
    result.report                                 # pulses, matches, margins, clock models

The pieces, each in its own module: `clockmap` (host clock and timing board → GPS), `pulses`
(GPS time of every forwarded pulse), `insclock` (INS counters, clock pieces, latches), `pattern`
(whole-second ambiguity), `insfit` (clock fits, record times), `insjumps` (fits carried
across a clock jump the records do not show), `lines` (scan lines).

Never a silent wrong time: an item whose time cannot be established has t_gps_ns = −1 and a
TimeStatus saying why. Post-processing reads only the flight log (and the scanner's own lines
files), never simulation truth.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import numpy.typing as npt

from postproc.sync import lines as ln
from postproc.sync.clockmap import ClockMap, board_map, host_map
from postproc.sync.coarse import coarse_latches
from postproc.sync.config import SyncConfig
from postproc.sync.flightlog import InsColumns, SyncInput, read_sync_input
from postproc.sync.hoststeps import find_steps, unstep_sync_input
from postproc.sync.insclock import TICK_NS, ins_timeline
from postproc.sync.insfit import fit_runs
from postproc.sync.insjumps import carry_runs
from postproc.sync.insrecords import latch_noise_s, tag_records
from postproc.sync.photos import DEFAULT_WINDOW_MS, photo_times, pulse_times
from postproc.sync.pulses import SisaPulses, sisa_pulses
from postproc.sync.report import ins_report, line_report, pulse_report
from postproc.sync.results import InsSolution, InsTimes, LineTimes, SyncResult
from recorder.framing import Paths
from sisa.core.errors import InputError
from sisa.core.timescale import NS_PER_S

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
WINDOW_OF_PERIOD = 0.45  # the coarse search stays inside half the LFSR period


def flight_epoch_ns(inp: SyncInput, host: ClockMap) -> int:
    """A whole GPS second at the start of the log: the origin of the float seconds inside."""
    firsts = [a[0] for a in (inp.ins.t_host_ns, inp.headers.t_host_ns, inp.gps.fix_t_host_ns,
                             inp.gps.tag_t_host_ns) if a.size]
    start = int(host.gps_ns(np.array([min(firsts)], dtype=np.int64))[0]) if firsts else 0
    return start // NS_PER_S * NS_PER_S


def _pattern_config(cfg: SyncConfig, lfsr_bits: I64) -> SyncConfig:
    if lfsr_bits.size == 0:
        return cfg
    period_s = float(2 ** int(lfsr_bits.min()) - 1)
    window = min(cfg.pattern.window_s, WINDOW_OF_PERIOD * period_s)
    return dataclasses.replace(cfg, pattern=dataclasses.replace(cfg.pattern, window_s=window))


def solve_ins(ins: InsColumns, pulses: SisaPulses, host: ClockMap, epoch_ns: int,
              cfg: SyncConfig) -> tuple[InsTimes, InsSolution]:
    """Clock pieces, pattern match, fits and record times."""
    res = cfg.ins_clock_resolution_ns
    tl = ins_timeline(ins, res // TICK_NS if res is not None else None)
    lat = coarse_latches(tl, ins.t_host_ns, host, epoch_ns)
    usable = np.flatnonzero(pulses.usable)
    order = usable[np.argsort(pulses.t_gps_ns[usable], kind="stable")]
    y_s = (pulses.t_gps_ns[order] - epoch_ns).astype(np.float64) / NS_PER_S
    noise = latch_noise_s(tl, cfg.tag_lsb_ns)
    resolution_s = tl.resolution_ticks * TICK_NS * 1e-9
    runs, blocks = fit_runs(lat, y_s, cfg, noise, resolution_s)
    runs = carry_runs(runs, lat, y_s, noise, cfg.assoc_tol_s + resolution_s,
                      tl.period_ticks * TICK_NS * 1e-9)
    t, status, run = tag_records(tl, lat, runs, epoch_ns, noise, cfg)
    times = InsTimes(tl.seq, ins.counter, t, status)
    x_rec = tl.seconds(tl.clock_ticks, tl.piece)
    sol = InsSolution(tl, lat.x_s, y_s, pulses.mode[order], runs, blocks, run, x_rec, noise)
    return times, sol


def solve_lines(inp: SyncInput, table: ln.LineTable | None, pulses: SisaPulses,
                host: ClockMap, epoch_ns: int, cfg: SyncConfig
                ) -> tuple[LineTimes, list[ln.SegmentFit], dict[str, Any]]:
    """Unwrap counters, place the timed frames, fit each segment, time every line."""
    hdr = inp.headers
    lines = table if table is not None else ln.lines_from_headers(hdr)
    modulus = ln.counter_modulus(hdr.frame_counter, lines.frame_counter, pulses.frame_counter)
    period_s = ln.measured_header_period_s(hdr, modulus)
    u_hdr = ln.unwrap_headers(hdr, modulus, 1.0 if period_s is None else period_s)
    hdr_gps_ns = ln.hdr_gps(hdr, host)
    fwd, seg_f, u_f = ln.place_forwards(pulses, hdr, u_hdr, hdr_gps_ns, modulus)
    groups = ln.by_segment(hdr.segment)
    segments = np.array([seg for seg, _ in groups], dtype=np.int64)
    refs = np.array([u_hdr[idx[0]] for _, idx in groups], dtype=np.int64)
    fits = ln.segment_fits(seg_f, u_f, pulses.t_gps_ns[fwd], segments, refs, epoch_ns)
    early = ln.suspect_segments(ln.early_headers(
        fits, hdr, u_hdr, hdr_gps_ns, epoch_ns,
        ln.EARLY_HEADER_FLOOR_S + ln.EARLY_HEADER_HOST_SIGMAS * host.line.sigma))
    neighbours = ln.suspect_segments(ln.neighbour_ties(
        fits, hdr, u_hdr, hdr_gps_ns, epoch_ns, inp.header_window_ms)
        if inp.header_window_ms is not None else {})
    fits = ln.refuse_segments(fits, early.keys() | neighbours.keys())
    u_line, linked = ln.align_lines(lines, hdr, u_hdr, modulus)
    t, status = ln.time_lines(lines.segment, u_line, linked, fits, epoch_ns, cfg)
    frame_pulse = pulses.mode == 2
    # dropped frames (exposed, not recorded) are known from the lines files only; missing from
    # the header stream are those and the headers lost on the serial link, apart only with them
    counts = {"frame_counter_modulus": modulus,
              "frames_dropped": ln.frame_drops(lines, modulus) if table is not None else None,
              "headers_lost": (ln.headers_lost(lines, hdr, u_line, linked, u_hdr)
                               if table is not None else None),
              "header_gaps": ln.frame_drops(ln.lines_from_headers(hdr), modulus),
              # without the lines files a line is numbered by header order: from the first gap
              # on, that number may not be the image's (report.header_order_note)
              "header_order_first_gap": ({str(s): n for s, n in
                                          ln.first_gap_lines(lines, modulus).items()}
                                         if table is None else None),
              # the sync filter names a forwarded frame by the header it tied to it on host
              # time; none named at all is the symptom syncreport.untied_frames_note explains
              "frame_pulses_forwarded": int(np.count_nonzero(frame_pulse)),
              "frame_pulses_with_counter": int(np.count_nonzero(
                  frame_pulse & (pulses.frame_counter >= 0))),
              "frame_pulses_placed": int(fwd.size),
              "header_line_period_ns": None if period_s is None else round(period_s * 1e9, 3),
              # segments refused: headers that would have reached the host before their own
              # frame's mid-exposure (lines.early_headers): [early, headers checked]
              "segments_early_headers": {str(seg): list(v) for seg, v in early.items()},
              # and those with headers in a neighbour frame's header window (lines.neighbour_ties)
              "segments_neighbour_ties": {str(seg): list(v) for seg, v in neighbours.items()}}
    return LineTimes(lines.segment, lines.line, lines.frame_counter, t, status), fits, counts


def synchronise(inp: SyncInput, lines: ln.LineTable | None = None,
                config: SyncConfig | None = None,
                camera_window_ms: tuple[float, float] | None = None) -> SyncResult:
    """GPS time of every INS record and every scan line of one flight log, and of every
    photo of a frame camera if it has one (`camera_window_ms`: when a photo message reaches
    the host after its pulse, as the log's metadata says; None: `photos.DEFAULT_WINDOW_MS`)."""
    if inp.ins.counter.size == 0 and inp.headers.segment.size == 0:
        raise InputError("the log has no INS records and no frame headers: nothing to time")
    cfg = _pattern_config(config or SyncConfig(), inp.sisa.session_lfsr_bits)
    real_pps = ~inp.sisa.pps_spurious
    # the board map takes no receive time: one fit serves the step finder and the pulses
    board = board_map(inp.sisa.pps_board_ns, inp.sisa.pps_gps_second_ns, inp.sisa.pps_spurious,
                      inp.gps.tag_t_gps_ns, inp.gps.tag_is_ptt)
    # a log recorded on a clock that stepped: the steps out of every receive time first
    host_steps = find_steps(inp.sisa.pps_t_host_ns[real_pps],
                            inp.sisa.pps_gps_second_ns[real_pps])
    inp = unstep_sync_input(inp, host_steps, None if board is None else board.gps_ns)
    g = inp.gps
    host = host_map(g.fix_t_host_ns, g.fix_t_gps_ns, g.tag_t_host_ns, g.tag_t_gps_ns,
                    inp.sisa.pps_t_host_ns[real_pps], inp.sisa.pps_gps_second_ns[real_pps])
    pulses, pstats = sisa_pulses(inp.sisa, g, board, host, ttt_window_ns=cfg.ttt_window_ns,
                                 max_board_gap_s=cfg.max_board_gap_s,
                                 agree_floor_ns=cfg.board_agree_floor_ns,
                                 tag_lsb_ns=cfg.tag_lsb_ns,
                                 host_tags=not inp.camera.pulse_to_gps_event.any())
    epoch = flight_epoch_ns(inp, host)
    ins_times, sol = solve_ins(inp.ins, pulses, host, epoch, cfg)
    line_times, fits, lcounts = solve_lines(inp, lines, pulses, host, epoch, cfg)
    report = {
        "flight_epoch_gps_ns": epoch,
        # the logging computer's clock set in flight (hoststeps): when, by how much
        "host_clock_steps": [{"gps_ns": h.gps_after_ns, "step_ms": round(h.step_ns / 1e6, 3)}
                             for h in host_steps],
        "config": dataclasses.asdict(cfg),
        "pulses": pulse_report(inp.sisa, pulses, pstats, sol, host, board),
        "ins": ins_report(ins_times, sol),
        "lines": line_report(line_times, fits, lcounts),
    }
    photos = None
    if not inp.camera.empty:
        cam_pulses = pulse_times(inp.camera, g.tag_t_gps_ns[~g.tag_is_ptt], pulses, board,
                                 ttt_window_ns=cfg.ttt_window_ns,
                                 max_board_gap_s=cfg.max_board_gap_s,
                                 agree_floor_ns=cfg.board_agree_floor_ns,
                                 tag_lsb_ns=cfg.tag_lsb_ns)
        photos, report["photos"] = photo_times(inp.camera, cam_pulses,
                                               camera_window_ms or DEFAULT_WINDOW_MS)
    return SyncResult(ins_times, line_times, report, sol, fits, photos)


def sync_log(paths: Paths, lines: ln.LineTable | None = None,
             config: SyncConfig | None = None) -> SyncResult:
    """`synchronise` on a flight log read from disk."""
    return synchronise(read_sync_input(paths), lines, config)
