"""`sisa log`: look inside a flight log and repair one cut short.

  sisa log info FILE...       per-topic counts, rates, time span and gaps, the recorder's health;
                              works on truncated files; --json for scripts
  sisa log recover IN OUT     every readable message of IN into a new, complete MCAP file OUT
"""

from __future__ import annotations

import argparse
import json
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sisa.commands import FLIGHT_HELP, add_command, flight_parts, new_file_arg, say_warning
from sisa.core.errors import InputError, shown_text

if TYPE_CHECKING:
    from recorder.stats import FileStats, Gap, LogStats

# a topic, schema or stream name from the file, in a table: shown escaped (a crafted log's
# names held terminal escapes: a title set, a clear-screen, line breaks) and cut
NAME_CHARS = 60


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = add_command(sub, "log", "inspect and recover flight logs (MCAP)",
                         "sisa log info runs/bench-sim/flight.mcap")
    actions = parser.add_subparsers(dest="log_command", metavar="ACTION")
    info = add_command(actions, "info", "per-topic counts, rates, time span and gaps of a "
                       "flight log (also a truncated one), and the recorder's health over it",
                       "sisa log info runs/flight.mcap")
    info.add_argument("files", nargs="+", type=Path, metavar="FILE",
                      help=FLIGHT_HELP)
    info.add_argument("--gaps", type=int, default=10, metavar="N",
                      help="list at most N gaps, largest first (default: 10)")
    info.add_argument("--json", action="store_true",
                      help="the same as one JSON object on stdout (times in int64 ns), for "
                           "scripts: e.g. a post-flight check of health.problems")
    info.set_defaults(handler=_info)
    recover = add_command(actions, "recover", "copy every readable message of a truncated or "
                          "damaged flight log into a new, complete MCAP file",
                          "sisa log recover crashed.mcap recovered.mcap")
    recover.add_argument("input", type=Path, metavar="IN", help="the damaged MCAP file")
    recover.add_argument("output", type=new_file_arg, metavar="OUT",
                         help="new file (never overwritten)")
    recover.add_argument("--drop-undecodable", action="store_true",
                         help="leave out messages that do not decode (JSON nested too deep, "
                         "not an object, a damaged field: every reader skips them); without "
                         "it they are copied as they are, and counted")
    recover.set_defaults(handler=_recover)
    parser.set_defaults(handler=lambda _args: _usage(parser))


def _usage(parser: argparse.ArgumentParser) -> int:
    parser.print_help()
    return 2


def _info(args: argparse.Namespace) -> int:
    from recorder.reader import scan_log

    if args.gaps < 0:
        raise InputError(f"--gaps {args.gaps}: list at most N gaps, N 0 or more")
    stats = scan_log(flight_parts(args.files))
    for note in stats.part_notes:  # a part not given: said, and the rest is shown
        say_warning("log", note)
    if args.json:
        print(json.dumps(info_document(stats, args.gaps), indent=1))
        return 0
    for fs in stats.files:
        print(_file_line(fs))
    for line in _summary_lines(stats):
        print(line)
    for line in _topic_table(stats):
        print(line)
    for line in _health_lines(stats):
        print(line)
    for line in _gap_lines(stats, args.gaps):
        print(line)
    return 0


def info_document(stats: LogStats, gaps_shown: int) -> dict[str, Any]:
    """What `log info` prints, as plain JSON: every time int64 ns on the host clock, counts as
    integers; the largest `gaps_shown` gaps (all counted in each topic's `gaps`)."""
    from recorder.columns import topics_in

    largest = _largest_gaps(stats, gaps_shown)
    return {
        "files": [{"path": str(fs.path), "size_bytes": fs.size_bytes, "complete": fs.complete,
                   "has_summary": fs.has_summary, "chunks_read": fs.chunks_read,
                   "chunks_skipped": fs.chunks_skipped, "bytes_skipped": fs.bytes_skipped,
                   "bytes_unreadable": fs.bytes_unreadable, "problems": list(fs.problems),
                   "metadata": fs.metadata} for fs in stats.files],
        "part_notes": list(stats.part_notes),
        "time": "log time: the recording host's clock, int64 ns since 1970-01-01 UTC",
        "messages": stats.messages,
        "undecodable": stats.undecodable,
        "undecodable_first": [{"topic": b.topic, "log_time_ns": b.log_time_ns, "why": b.why}
                              for b in stats.bad],
        "start_ns": stats.start_ns,
        "end_ns": stats.end_ns,
        "topics": {topic: {"schema": t.schema_name, "count": t.count, "rate_hz": t.rate_hz,
                           "first_ns": t.first_ns, "last_ns": t.last_ns,
                           "usual_interval_ns": t.usual_interval_ns, "gaps": t.gap_count,
                           "lost_by_sequence": t.lost_by_sequence}
                   for topic in topics_in(stats) for t in [stats.topics[topic]]},
        "largest_gaps": [{"topic": g.topic, "start_ns": g.start_ns, "end_ns": g.end_ns,
                          "usual_interval_ns": g.usual_ns} for g in largest],
        "health": stats.health.as_dict(),
    }


def _recover(args: argparse.Namespace) -> int:
    from recorder.recover import recover
    from recorder.writer import part_path

    _refuse_part_name(args.input, args.output)
    report = recover(args.input, args.output, drop_undecodable=args.drop_undecodable)
    print(report.summary())
    if not report.messages:  # a complete file all the same: said, not hidden in the summary
        why = f" ({report.problems[0]})" if report.problems else ""
        say_warning("log", f"no readable messages in {args.input}{why}: {args.output} holds "
                    "none")
    further = _further_parts(args.input)
    if further:
        names = ", ".join(p.name for p in further)
        verb = "is a further part" if len(further) == 1 else "are further parts"
        say_warning("log", f"{names} beside {args.input} {verb} of the same recording, not in "
                    f"{args.output}: recover each to {args.output.name}'s numbered names (`sisa "
                    f"log recover {further[0]} {part_path(args.output, 1)}`, ...), and readers "
                    f"given {args.output} take them together")
    return 0


def _refuse_part_name(src: Path, out: Path) -> None:
    """OUT named as a further part of a log beside it (flight_001.mcap beside flight.mcap)
    would be read with that log as a part of it: refused, unless IN is a further part itself
    (recovering each part to the numbered names, as the warning below says)."""
    from recorder.parts import part_label
    from recorder.writer import named_as_part

    part = named_as_part(out)
    if part is None or not part[0].is_file():
        return
    base, index = part
    label = part_label(src) if src.is_file() else None
    if label is not None and label.index > 0:
        return
    raise InputError(f"{out} would be read as part {index} of {base} (readers "
                     f"take the numbered files beside a log as its parts): choose another name")


def _further_parts(path: Path) -> list[Path]:
    """The parts after `path` found beside it when it is part 0 of a split recording: `log
    recover` copies one file, and without a word its output would pass for the whole flight."""
    from recorder.parts import part_label
    from recorder.writer import split_parts

    first = part_label(path)
    if first is None or first.index != 0:
        return []
    labels = (part_label(p) for p in split_parts(path)[1:])
    return [label.path for label in labels
            if label is not None and label.index > 0 and label.same_recording(first)]


def _file_line(fs: FileStats) -> str:
    size = f"{fs.size_bytes / 1e6:.1f} MB" if fs.size_bytes >= 100_000 else f"{fs.size_bytes} B"
    if fs.complete:
        state = "complete (summary present)" if fs.has_summary else "complete (no summary)"
    else:
        state = f"truncated (no summary): read {fs.chunks_read} complete chunks"
        if fs.bytes_unreadable:
            state += f", last {fs.bytes_unreadable} bytes unreadable"
    if fs.chunks_skipped:
        state += f"; {fs.chunks_skipped} damaged chunks skipped"
    if fs.bytes_skipped:
        state += f" ({fs.bytes_skipped} damaged bytes passed over)"
    meta = fs.metadata.get("sisa.recording", {})
    extra = ", ".join(f"{shown_text(k)}={shown_text(v)}" for k, v in meta.items()
                      if k not in ("first_part",))
    lines = [f"{fs.path}: {size}, {state}"] + ([f"  {extra}"] if extra else [])
    lines += [f"  problem: {p}" for p in fs.problems]
    return "\n".join(lines)


def _utc(t_ns: int) -> str:
    return datetime.fromtimestamp(t_ns / 1e9, UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"


def _summary_lines(stats: LogStats) -> list[str]:
    if not stats.messages:
        return ["no readable messages"]
    span_s = (stats.end_ns - stats.start_ns) / 1e9
    lines = [f"{stats.messages} messages on {len(stats.topics)} topics, log time "
             f"{_utc(stats.start_ns)} .. {_utc(stats.end_ns)} ({span_s:.3f} s, host clock)"]
    if stats.undecodable:
        n = stats.undecodable
        lines.append(f"{n} message{'s' if n != 1 else ''} could not be decoded (every reader "
                     "skips them; `sisa log recover --drop-undecodable` makes a copy without them)"
                     + (f"; the first {len(stats.bad)}:" if stats.undecodable > len(stats.bad)
                        else ":"))
        lines += [f"  {shown_text(b.topic)} at +{(b.log_time_ns - stats.start_ns) / 1e9:.3f} s "
                  f"(log time {b.log_time_ns}): {b.why}" for b in stats.bad]
    return lines


def _topic_table(stats: LogStats) -> list[str]:
    from recorder.columns import topics_in

    if not stats.topics:
        return []
    head = (f"{'topic':<20} {'schema':<22} {'count':>9} {'rate_hz':>9} {'first_s':>9} "
            f"{'last_s':>9} {'usual_ms':>9} {'gaps':>5} {'lost':>5}")
    lines = [head]
    for topic in topics_in(stats):
        t = stats.topics[topic]
        first_s, last_s = ((t.first_ns - stats.start_ns) / 1e9, (t.last_ns - stats.start_ns) / 1e9)
        lines.append(
            f"{shown_text(topic, NAME_CHARS):<20} {shown_text(t.schema_name, NAME_CHARS):<22} "
            f"{t.count:>9} {t.rate_hz:>9.2f} {first_s:>9.3f} "
            f"{last_s:>9.3f} {t.usual_interval_ns / 1e6:>9.3f} {_count(t.gap_count):>5} "
            f"{t.lost_by_sequence:>5}")
    return lines


def _health_lines(stats: LogStats) -> list[str]:
    """The recorder's own counters over the recording (`/sisa/health`), a verdict first: what
    an operator checks after landing, and did not see without opening the log in a viewer."""
    from recorder.health import COUNTERS, HEADINGS

    health = stats.health
    streams = health.ordered()
    if not streams and not health.unreadable:
        return []  # a log from before health reports, or another recorder's
    lines = [f"recorder health (its own counters, totals over the recording): "
             f"{health.verdict()}"]
    if health.unreadable:
        lines[0] += f" ({health.unreadable} reports unreadable)"
    if streams:
        widths = [max(8, len(h)) for h in HEADINGS]
        lines.append(f"  {'stream':<8} {'messages':>9} "
                     + " ".join(f"{h:>{w}}" for h, w in zip(HEADINGS, widths, strict=True)))
        lines += [f"  {shown_text(t.stream, NAME_CHARS):<8} {t.messages:>9} "
                  + " ".join(f"{t.counts[c]:>{w}}" for c, w in zip(COUNTERS, widths, strict=True))
                  for t in streams]
        lines += [f"  {t.stream} refused by reason: "
                  + ", ".join(f"{shown_text(r, 40)} {n}" for r, n in t.refused.items())
                  for t in streams if t.refused]
    return lines


def _largest_gaps(stats: LogStats, limit: int) -> list[Gap]:
    return sorted(stats.gaps, key=lambda g: -g.duration_ns)[:max(0, limit)]


def _count(n: int | None) -> str:
    return "-" if n is None else str(n)


def _gap_lines(stats: LogStats, limit: int) -> list[str]:
    total = sum(t.gap_count or 0 for t in stats.topics.values())
    if not total or limit <= 0:
        return []
    gaps = _largest_gaps(stats, limit)
    lines = [f"gaps longer than 2x the topic's usual interval around them: {total} "
             f"(largest {len(gaps)}; none counted on the sync unit's forwarded pulses, silent "
             "by design)"]
    for g in gaps:
        at_s = (g.start_ns - stats.start_ns) / 1e9
        lines.append(f"  {shown_text(g.topic, NAME_CHARS):<20} at +{at_s:.3f} s: "
                     f"{g.duration_ns / 1e9:.3f} s (usual {g.usual_ns / 1e9:.4f} s)")
    return lines
