"""The sync report: what was found, matched and rejected, and how good each fit is.

Every figure is plain JSON (ints, floats, strings), so `sync_report.json` can be read anywhere.
Predicted errors come from the noise model through the fit: one latch ↔ pulse pair has
`noise_s` (latch truncation and tag rounding, uniform); a record's time error from its clock fit
is noise·√leverage, its RMS over the records of a fit is noise·√(mean leverage).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from postproc.sync.clockmap import ClockMap
from postproc.sync.config import TimeStatus
from postproc.sync.flightlog import SisaColumns
from postproc.sync.pulses import PulseSource, SisaPulses

if TYPE_CHECKING:
    from postproc.sync.lines import SegmentFit
    from postproc.sync.results import InsSolution, InsTimes, LineTimes

I64 = npt.NDArray[np.int64]
NS = 1e9
# the sync filter ties a header on time alone only in a window narrower than its shortest line
# period: the period less the 5 % grid tolerance (acquisition.syncfilter, interval_tolerance)
NARROW_OF_PERIOD = 0.95


def status_counts(status: I64) -> dict[str, int]:
    return {s.name.lower(): int(np.count_nonzero(status == s)) for s in TimeStatus
            if np.any(status == s)}


def _map_summary(m: ClockMap | None) -> dict[str, Any] | None:
    if m is None:
        return None
    return {"pairs": m.line.n, "residual_rms_ns": round(m.residual_rms_ns, 3),
            "rate_ppm": round(m.drift_ppm, 6), "span_s": round(m.line.x_max - m.line.x_min, 3),
            **({"from": m.source} if m.source else {})}


def pulse_report(sisa: SisaColumns, pulses: SisaPulses, stats: dict[str, int],
                 sol: InsSolution, host: ClockMap, board: ClockMap | None) -> dict[str, Any]:
    empty = np.zeros(0, dtype=np.int64)
    claimed = np.concatenate([empty, *(r.latches for r in sol.runs)])
    pulses_hit = np.unique(np.concatenate([empty, *(r.pulses for r in sol.runs)]))
    usable = int(np.count_nonzero(pulses.usable))
    latches = sol.timeline.latch_record.size
    return {
        "sync_sessions": int(sisa.session_lfsr_bits.size),
        "lfsr_bits": int(sisa.session_lfsr_bits.min()) if sisa.session_lfsr_bits.size else None,
        "pps_seen": int(sisa.pps_board_ns.size),
        "pps_rejected_as_spurious": int(np.count_nonzero(sisa.pps_spurious)),
        "forwarded": int(pulses.t_gps_ns.size),
        "forwarded_mode1": int(np.count_nonzero(pulses.mode == 1)),
        "forwarded_mode2": int(np.count_nonzero(pulses.mode == 2)),
        "timed_by": {s.name.lower(): int(np.count_nonzero(pulses.source == s))
                     for s in PulseSource},
        "usable": usable,
        "rejected": int(pulses.t_gps_ns.size - usable),
        **stats,
        "ins_latches": latches,
        "ins_latches_matched": int(claimed.size),
        "ins_latches_unmatched": int(latches - claimed.size),
        "forwarded_without_latch": int(usable - len(pulses_hit)),
        "host_map": _map_summary(host),
        "board_map": _map_summary(board),
    }


def _block(b: Any, sol: InsSolution) -> dict[str, Any]:
    s = b.score
    return {"piece": b.piece, "latches": b.stop - b.first, "best": s.best, "second": s.second,
            "margin": s.margin, "resolved": b.resolved,
            "shift_s": None if np.isnan(s.shift_s) else round(s.shift_s, 6),
            # the probability bound that decided it (postproc.sync.pattern; docs/sync.md)
            "false_match_bound": float(f"{s.false_match:.3g}"),
            "contradiction_bound": float(f"{s.contradiction:.3g}"),
            "chance_agreement": None if np.isnan(s.chance) else round(s.chance, 6),
            "shifts_compared": s.cells}


def _run(i: int, sol: InsSolution) -> dict[str, Any]:
    r = sol.runs[i]
    recs = sol.record_x_s[sol.run_of_record == i]
    lev = float(np.mean(r.line.leverage(recs))) if recs.size else float("nan")
    return {
        "piece": r.piece, "latches": int(r.latches.size), "records": int(recs.size),
        "ins_clock_span_s": [round(r.line.x_min, 6), round(r.line.x_max, 6)],
        "ins_clock_fast_ppm": round((1.0 / r.line.slope - 1.0) * 1e6, 6),
        "residual_rms_ns": round(r.line.sigma * NS, 3),
        "noise_model_latch_rms_ns": round(sol.noise_s * NS, 3),
        "predicted_record_rms_ns": None if np.isnan(lev) else round(
            float(max(r.line.sigma, sol.noise_s) * np.sqrt(lev)) * NS, 3),
    }


def ins_report(times: InsTimes, sol: InsSolution) -> dict[str, Any]:
    tl = sol.timeline
    return {
        **tl.counts,
        "counter_modulus": tl.counter_modulus,
        "clock_resolution_ns": tl.resolution_ticks * 100,
        "record_period_ns": round(tl.period_ticks * 100, 3),
        "clock_pieces": int(tl.piece_first.size),
        "status": status_counts(times.status),
        "blocks_resolved": sum(b.resolved for b in sol.blocks),
        "blocks": [_block(b, sol) for b in sol.blocks],
        "clock_models": [_run(i, sol) for i in range(len(sol.runs))],
    }


def _segment(f: SegmentFit, times: LineTimes) -> dict[str, Any]:
    sel = times.segment == f.segment
    out: dict[str, Any] = {"segment": f.segment, "lines": int(np.count_nonzero(sel)),
                           "frames_timed": f.frames_timed, "frames_rejected": f.frames_rejected,
                           "status": status_counts(times.status[sel])}
    if f.line is not None:
        out |= {"line_period_ns": round(f.line.slope * NS, 3),
                "period_borrowed": f.borrowed_period,
                "residual_rms_ns": round(f.line.sigma * NS, 3)}
    return out


def line_report(times: LineTimes, fits: list[SegmentFit], counts: dict[str, Any]
                ) -> dict[str, Any]:
    return {"lines": int(times.t_gps_ns.size), **counts, "status": status_counts(times.status),
            "segments": [_segment(f, times) for f in fits]}


def frames_untied(lines: dict[str, Any]) -> bool:
    """Frame pulses were forwarded, not one names its frame, and lines went untimed for it:
    the sync filter tied no frame header to its pulse (`lines`: the report's "lines")."""
    return bool(lines.get("frame_pulses_forwarded", 0) > 0
                and lines.get("frame_pulses_with_counter", 0) == 0
                and lines["status"].get("no_pulses", 0) > 0)


# why INS records stay ambiguous when a log has no mode-1 pattern to speak of (the recorder
# started with the scanner already recording): 6 s of it left all ambiguous in a real-time
# bench, 15 s timed every record
AMBIGUOUS_HINT = ("no pulse was singled out as its GPS second; the mode-1 pattern does that, "
                  "mode-2 trains alone do not: record a register period (15 s with 4 bits) with "
                  "the scanner off (docs/sync.md, 'The whole-second ambiguity'); if the log has "
                  "one, the coarse time from the host clock failed (see the host map in `sisa "
                  "sync`'s report)")


def _pattern_was_there(pulses: dict[str, Any]) -> bool:
    """The log holds at least a register period's one-bits of mode-1 pulses."""
    bits = pulses.get("lfsr_bits")
    return bits is not None and pulses.get("forwarded_mode1", 0) >= 2 ** (bits - 1)


def no_ins_timed_note(ins_status: npt.ArrayLike, report: dict[str, Any] | None = None
                      ) -> str | None:
    """The warning when sync timed no INS record and left every one ambiguous; else None.
    With the report: the advice that fits the log. "Record a register period with the scanner
    off" was printed for a log with 346 s of it, whose host → GPS map had gone wrong."""
    status = np.asarray(ins_status)
    if status.size == 0 or not (status == TimeStatus.AMBIGUOUS).all():
        return None
    head = f"no INS record timed, all {status.size} ambiguous"
    if report is None or not _pattern_was_there(report["pulses"]):
        return f"{head}: {AMBIGUOUS_HINT}"
    pulses = report["pulses"]
    host = pulses.get("host_map") or {}
    residual_ms = host.get("residual_rms_ns", float("nan")) / 1e6
    return (f"{head}, though the log has {pulses['forwarded_mode1']} mode-1 pulses (the PPS "
            f"pattern): no block of latches matched them, so the coarse time of the INS "
            f"records (host receive times through the host → GPS map: from "
            f"{host.get('from', '?')}, residual {residual_ms:.3g} ms, rate "
            f"{host.get('rate_ppm', float('nan')):.4g} ppm; a few ms and ppm on a sound log) is "
            "off by more than the 3 ms the match allows: check the host clock and the receive "
            "times in the log (docs/sync.md, 'Clocks the log holds')")


def host_steps_note(report: dict[str, Any]) -> str | None:
    """The warning when the log's receive times step (a logger stamping the system clock):
    when and by how much, taken out before anything was timed (hoststeps). None when none."""
    steps = report.get("host_clock_steps") or []
    if not steps:
        return None
    epoch = int(report["flight_epoch_gps_ns"])
    each = "; ".join(f"{s['step_ms'] / 1e3:+.3f} s at {(s['gps_ns'] - epoch) / 1e9:.0f} s"
                     for s in steps)
    return (f"the log's receive times step {len(steps)} time(s) ({each} into the log): it was "
            "recorded on a clock that was set in flight (chrony's makestep, a leap second, by "
            "hand; `sisa record` stamps a clock that never steps). Each step was taken out of "
            "every receive time before timing (docs/sync.md, 'Host clock steps')")


def header_order_note(lines: dict[str, Any], what: str = "line_times.csv") -> str | None:
    """The warning when lines were numbered by frame-header order and the frame counter skips:
    from the first skip of a segment on, the number may not be the image's line (a dropped
    frame and a lost header look alike without the scanner's lines files), so a time put on an
    image line by that number could be a line period off, silently. None when no skip."""
    first = lines.get("header_order_first_gap") or {}
    if not first:
        return None
    where = ", ".join(f"segment {s} from line {n}" for s, n in sorted(
        first.items(), key=lambda kv: int(kv[0])))
    return (f"lines numbered by frame-header order, and the frame counter skips "
            f"({lines.get('header_gaps', '?')} frames missing from the headers; {where}): a "
            f"frame the scanner dropped and a header lost on the link look alike there, so "
            f"from those lines on the numbers in {what} may not be the image's lines (each "
            "time belongs to its frame_counter): give the scanner's folder (--scanner) to "
            "number lines by its lines files")


def untimed_lines_note(lines: dict[str, Any], flight: Sequence[Path]) -> str | None:
    """`untied_frames_note` with the header window `flight` was recorded with (or the
    default), when `frames_untied`; else None. For every command that syncs a log: `georef`
    and `calibrate` failed with a bare count of no_pulses lines. Segments refused for their
    headers (`refused_segments_note`) are said first."""
    early = refused_segments_note(lines)
    if early is not None or not frames_untied(lines):
        return early
    from recorder.settings import header_window_of_log

    return untied_frames_note(lines, *header_window_of_log(flight))


def refused_segments_note(lines: dict[str, Any]) -> str | None:
    """Why the lines of some segments are no_pulses although their frames were tied: the fit
    put headers before their own frames (lines.early_headers), or in a neighbouring frame's
    header window (lines.neighbour_ties): the marks of a header window that does not fit the
    scanner's latency. None when no segment was refused."""
    early = lines.get("segments_early_headers") or {}
    neighbours = lines.get("segments_neighbour_ties") or {}
    if not early and not neighbours:
        return None

    def each(counts: dict[str, list[int]]) -> str:
        return ", ".join(f"segment {s}: {n} of {k}" for s, (n, k) in sorted(
            counts.items(), key=lambda kv: int(kv[0])))

    why = []
    if early:
        why.append(f"headers would have reached the recorder before the middle of their "
                   f"frames' exposure ({each(early)})")
    if neighbours:
        why.append(f"headers fall in another frame's header window ({each(neighbours)})")
    return (f"scan lines of {len({*early, *neighbours})} segment(s) not timed (no_pulses): with "
            f"the frame counters the sync filter gave, {' and '.join(why)}, so the sync filter "
            "may have tied headers to other frames' pulses, and every time would then be a "
            "line period wrong: the header window (sisa.header_window_ms) does not fit the "
            "scanner's header latency; measure it and record with a window that covers it "
            "(docs/sync.md, Limits)")


def untied_frames_note(lines: dict[str, Any], window_ms: tuple[float, float],
                       window_from: str | None) -> str:
    """Why every line is no_pulses when `frames_untied`: the filter ties a header to its pulse
    on host time alone only in a header window narrower than a line period (docs/sync.md,
    Limits). The period is the headers' own (host times); the window `sisa.header_window_ms`
    as the log's recording settings give it (`window_from` says so), or (None) the default."""
    head = (f"{lines['status']['no_pulses']} scan lines not timed (no_pulses): none of the "
            f"{lines['frame_pulses_forwarded']} forwarded frame pulses carries its frame counter")
    period_ns = lines.get("header_line_period_ns")
    lo, hi = window_ms
    width = hi - lo
    if period_ns is None or width < NARROW_OF_PERIOD * period_ns * 1e-6:
        return f"{head} (no frame header was tied to its pulse; docs/sync.md, Limits)"
    period = f"{period_ns * 1e-6:.3g} ms"
    fix = ("set sisa.header_window_ms (and sisa.read_interval_ms) narrower than a line period "
           "(docs/sync.md, Limits)")
    if window_from is None:
        return (f"{head}: the frame headers show a line period of {period}; a header window "
                f"not narrower (sisa.header_window_ms; the default [{lo:g}, {hi:g}] is "
                f"{width:g} ms wide) ties no frame header to its pulse on host time: {fix}")
    return (f"{head}: the header window (sisa.header_window_ms [{lo:g}, {hi:g}] "
            f"{window_from}: {width:g} ms wide) is not narrower than the scanner's line period "
            f"({period}, from the frame headers), so frame headers cannot be tied to pulses on "
            f"host time: {fix}")
