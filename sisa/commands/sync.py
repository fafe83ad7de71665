"""`sisa sync`: every INS record and every scan line of a flight log in GPS time.

OUT/
  ins_times.csv      seq, counter, t_gps_ns, status of every INS record (log order)
  line_times.csv     segment, line, frame_counter, t_gps_ns, status of every scan line
  sync_report.json   pulses found, matched and rejected; margin of every pattern block; clock
                     models and residuals; flagged counts
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from sisa.commands import FLIGHT_HELP, SubParsers, add_command, flight_parts, say_warning
from sisa.outdir import staged_output_dir


def register(sub: SubParsers[argparse.ArgumentParser]) -> None:
    parser = add_command(sub, "sync", "put every INS record and every scan line of a flight "
                         "log in GPS time (pulse pattern matching, clock fits)",
                         "sisa sync runs/bench/flight.mcap --scanner runs/bench/scanner "
                         "--out runs/bench-sync")
    parser.add_argument("flight", nargs="+", type=Path, metavar="FLIGHT",
                        help=FLIGHT_HELP)
    parser.add_argument("--scanner", type=Path, default=None, metavar="DIR",
                        help="the scanner's recording folder (segment_NNN.lines.csv); without "
                             "it, lines are the frame headers in the log")
    parser.add_argument("--out", type=Path, required=True, help="new output folder")
    parser.set_defaults(handler=_run)


def _run(args: argparse.Namespace) -> int:
    from postproc.sync import TimeStatus, synchronise
    from postproc.syncio import (
        read_scanner_lines,
        unlisted_line_notes,
        write_ins_times,
        write_line_times,
        write_report,
    )
    from postproc.synclog import WANTED as SYNC_WANTED
    from postproc.synclog import sync_input_from_columns
    from postproc.syncreport import no_ins_timed_note, untimed_lines_note
    from recorder.health import HEALTH_WANTED, HealthTotals, recording_note
    from recorder.messages import Topic
    from recorder.reader import read_topics

    started = time.perf_counter()
    with staged_output_dir(args.out) as out:
        lines = read_scanner_lines(args.scanner) if args.scanner is not None else None
        flight = flight_parts(args.flight)
        cols = read_topics(flight, {**SYNC_WANTED, **HEALTH_WANTED})
        recording = recording_note(HealthTotals.from_columns(cols[Topic.HEALTH]), flight[0])
        result = synchronise(sync_input_from_columns(cols), lines)
        result.report["inputs"] = {"flight": [str(p) for p in flight],
                                   "scanner": str(args.scanner) if args.scanner else None}
        ins, ln = result.ins, result.lines
        write_ins_times(out / "ins_times.csv", ins.seq, ins.counter, ins.t_gps_ns, ins.status)
        write_line_times(out / "line_times.csv", ln.segment, ln.line, ln.frame_counter,
                         ln.t_gps_ns, ln.status)
        notes = [] if recording is None else [recording]
        notes += [] if args.scanner is None else unlisted_line_notes(
            args.scanner, result.lines.segment, result.lines.line, "timed")
        ambiguous = no_ins_timed_note(ins.status, result.report)
        if ambiguous is not None:  # was said only as a count
            notes.append(ambiguous)
        untied = untimed_lines_note(result.report["lines"], flight)
        if untied is not None:  # was said only as a count
            notes.append(untied)
        result.report["notes"] = notes
        write_report(out / "sync_report.json", result.report)
    for note in notes:  # a segment left out by its lines file was gone without a word
        say_warning("sync", note)
    ok_ins = int((ins.status == TimeStatus.OK).sum())
    ok_lines = int((ln.status == TimeStatus.OK).sum())
    pulses = result.report["pulses"]
    print(f"{args.out}: INS records {ok_ins}/{ins.status.size} timed, scan lines "
          f"{ok_lines}/{ln.status.size} timed; latches matched "
          f"{pulses['ins_latches_matched']}/{pulses['ins_latches']}, pulses forwarded "
          f"{pulses['forwarded']} (rejected {pulses['rejected']}); "
          f"{time.perf_counter() - started:.1f} s")
    for kind, status in (("INS records", ins.status), ("scan lines", ln.status)):
        flagged = {s.name.lower(): int((status == s).sum()) for s in TimeStatus
                   if s is not TimeStatus.OK and (status == s).any()}
        if flagged:
            print(f"  {kind} flagged: " + ", ".join(f"{k} {v}" for k, v in flagged.items()))
    return 0
