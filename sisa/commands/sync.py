"""`sisa sync`: every INS record and every scan line of a flight log in GPS time.

OUT/
  ins_times.csv      seq, counter, t_gps_ns, status of every INS record (log order)
  line_times.csv     segment, line, frame_counter, t_gps_ns, status of every scan line
  photo_times.csv    photo_number, t_mid_gps_ns, sigma_ns, source, status of every photo the
                     frame camera named (a flight with a camera only)
  camera_pulses_unnamed.csv   t_gps_ns, sigma_ns, source of its pulses no photo named
  sync_report.json   pulses found, matched and rejected; margin of every pattern block; clock
                     models and residuals; flagged counts
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sisa.commands import (
    FLIGHT_HELP,
    SubParsers,
    add_command,
    add_force_arg,
    finished_with_losses,
    flight_parts,
    say_warning,
)
from sisa.commands.progress import progress
from sisa.core.errors import InputError
from sisa.core.outdir import staged_output_dir

if TYPE_CHECKING:
    import numpy.typing as npt


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
    add_force_arg(parser)
    parser.set_defaults(handler=_run)


def _run(args: argparse.Namespace) -> int:
    from postproc.sync import WANTED as SYNC_WANTED
    from postproc.sync import (
        TimeStatus,
        header_order_note,
        host_steps_note,
        no_ins_timed_note,
        read_scanner_lines,
        sync_input_from_columns,
        synchronise,
        unlisted_line_notes,
        untimed_lines_note,
        write_photo_times,
        write_report,
        write_time_tables,
    )
    from recorder.columns import read_topics
    from recorder.health import HEALTH_WANTED, HealthTotals, recording_note
    from recorder.messages import Topic
    from recorder.parts import recording_metadata
    from recorder.settings import header_window_ms, recorded_camera_window_ms

    started = time.perf_counter()
    with staged_output_dir(args.out, force=args.force) as out, progress("sync") as bar:
        bar.step("reading the scanner's lines and the flight log")
        lines = read_scanner_lines(args.scanner) if args.scanner is not None else None
        flight = flight_parts(args.flight)
        cols = read_topics(flight, {**SYNC_WANTED, **HEALTH_WANTED})
        recording = recording_note(HealthTotals.from_columns(cols[Topic.HEALTH]), flight[0])
        bar.step("synchronising")
        try:
            meta = recording_metadata(flight[0])
            result = synchronise(sync_input_from_columns(cols, header_window_ms(meta)), lines,
                                 camera_window_ms=recorded_camera_window_ms(meta))
        except InputError as exc:  # what the log lacks: named by the log
            raise InputError(f"{flight[0]}: {exc}") from None
        bar.step("writing the tables")
        result.report["inputs"] = {"flight": [str(p) for p in flight],
                                   "scanner": str(args.scanner) if args.scanner else None}
        ins, ln = result.ins, result.lines
        write_time_tables(out, ins, ln)
        if result.photos is not None:
            write_photo_times(out, result.photos)
        notes = [] if recording is None else [recording]
        stepped = host_steps_note(result.report)
        if stepped is not None:  # the times are sound, the recorder was not
            notes.append(stepped)
        notes += [] if args.scanner is None else unlisted_line_notes(
            args.scanner, result.lines.segment, result.lines.line, "timed")
        ambiguous = no_ins_timed_note(ins.status, result.report)
        if ambiguous is not None:  # was said only as a count
            notes.append(ambiguous)
        if args.scanner is None:
            unsure = header_order_note(result.report["lines"])
            if unsure is not None:  # the numbers were wrong after a lost header, silently
                notes.append(unsure)
        untied = untimed_lines_note(result.report["lines"], flight)
        if untied is not None:  # was said only as a count
            notes.append(untied)
        photos = result.report.get("photos")
        if photos is not None and photos["photo_messages"] and not photos["camera_pulses"]:
            notes.append(f"the log has {photos['photo_messages']} photo messages from the "
                         "frame camera and not one camera pulse: no photo is timed (is its "
                         "pulse line connected to the sync unit?)")
        result.report["notes"] = notes
        write_report(out / "sync_report.json", result.report)
    for note in notes:  # a segment left out by its lines file was gone without a word
        say_warning("sync", note)
    ok_ins = int((ins.status == TimeStatus.OK).sum())
    ok_lines = int((ln.status == TimeStatus.OK).sum())
    # what the inputs promised: the INS records from the first latched pulse to the last (none
    # is timed outside them: the flight's first and last seconds; docs/sync.md, Limits); per
    # segment, the lines of the scanner's files or the log's frame headers, whichever says
    # more (a log cut short holds fewer headers; a lines file cut short, fewer lines)
    beyond = result.ins_solution.timeline.outside_latch_span()
    promised, unlisted = promised_lines(ln.segment, cols[Topic.SCANNER_HEADER]["segment"])
    pulses = result.report["pulses"]
    print(f"{args.out}: INS records {ok_ins}/{ins.status.size} timed, scan lines "
          f"{ok_lines}/{promised} timed; latches matched "
          f"{pulses['ins_latches_matched']}/{pulses['ins_latches']}, pulses forwarded "
          f"{pulses['forwarded']} (rejected {pulses['rejected']}); "
          f"{time.perf_counter() - started:.1f} s")
    for kind, status in (("INS records", ins.status), ("scan lines", ln.status)):
        flagged = {s.name.lower(): int((status == s).sum()) for s in TimeStatus
                   if s is not TimeStatus.OK and (status == s).any()}
        if flagged:
            print(f"  {kind} flagged: " + ", ".join(f"{k} {v}" for k, v in flagged.items()))
    if unlisted:
        print(f"  scan lines not in the scanner's files: {unlisted} (frame headers in the log)")
    if beyond.any():
        print(f"  INS records before the first pulse the INS latched or after its last: "
              f"{int(beyond.sum())} (never timed: no pulse shows the INS clock there)")
    ok_spanned = int((ins.status[~beyond] == TimeStatus.OK).sum())
    counts = [("INS records", ok_spanned, int((~beyond).sum())),
              ("scan lines", ok_lines, promised)]
    if result.photos is not None:
        counts.append(("photos", *_photo_headline(result.report["photos"])))
    lost = [f"{n - ok} of {n} {what}" for what, ok, n in counts if ok < n]
    if lost:
        return finished_with_losses("sync", f"{' and '.join(lost)} not timed")
    return 0


def _photo_headline(report: dict[str, Any]) -> tuple[int, int]:
    """Print the photos' line; (photos timed with their number, photos the camera named)."""
    status: dict[str, int] = report["status"]
    timed = status["ok"] + status["board_time"]
    flagged = ", ".join(f"{k} {v}" for k, v in status.items() if v and k != "ok")
    print(f"  photos {timed}/{report['photo_messages']} timed ({status['ok']} by their event "
          "tag)" + (f"; {flagged}" if flagged else ""))
    return timed, int(report["photo_messages"])


def promised_lines(listed_segments: npt.ArrayLike, header_segments: npt.ArrayLike
                   ) -> tuple[int, int]:
    """(lines the inputs promised, how many of them only the log's frame headers promised):
    per segment, the lines listed (by the scanner's files, or the headers themselves) or the
    headers in the log, whichever are more."""
    import numpy as np

    listed = dict(zip(*np.unique(np.asarray(listed_segments), return_counts=True),
                      strict=True))
    headers = dict(zip(*np.unique(np.asarray(header_segments), return_counts=True),
                       strict=True))
    more = {s: max(int(headers.get(s, 0)) - int(listed.get(s, 0)), 0) for s in headers}
    unlisted = sum(more.values())
    return int(sum(listed.values())) + unlisted, unlisted
