"""Each segment's scan lines as georeferencing takes them: its image (whole, or the lines before
a cut), every line's GPS time and exterior orientation, and the skip of the lines that have no
time or no pose, or the job's one error when no line of any segment has both."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt

from postproc.georef.exterior import LineEo, exterior_orientation
from postproc.georef.handoff import Handoff, SyncTables
from postproc.georef.jobrecords import LineSpan, SegmentSkip
from postproc.georef.sensorfile import SensorModel
from postproc.products import EnviRaster
from postproc.sync import SyncResult, TimeStatus, unlisted_line_notes, untimed_lines_note
from recorder.framing import Paths, log_paths
from sisa.core.errors import InputError
from sisa.core.timescale import NS_PER_DAY, NS_PER_S, gps_span_label

I64 = npt.NDArray[np.int64]

SPANS_IN_MESSAGE: Final = 3  # stretches of lines a warning names (the summary has them all)


def segment_image(scanner_dir: Path, segment: int) -> Path:
    path = scanner_dir / f"segment_{segment:03d}.bil"
    if not path.is_file():
        what = ("a link to nothing" if path.is_symlink() and not path.exists() else
                "not a file" if path.exists() or path.is_symlink() else "missing")
        raise InputError(f"{path}: {what}, but the lines file lists segment {segment}")
    return path


def segment_raster(path: Path, segment: int) -> tuple[EnviRaster, str | None]:
    """The segment's raw image, and what to say when its file is cut short (None if whole):
    the lines before the cut are georeferenced, the rest named as missing."""
    raw = EnviRaster.open(path)
    if not raw.cut_short:
        return raw, None
    return raw, (f"segment {segment}: {raw.cut_short_text(path.name)}: lines {raw.lines}-"
                 f"{raw.header_lines - 1} are not georeferenced")


def segment_rasters(scanner_dir: Path, result: SyncResult | SyncTables, notes: list[str]
                    ) -> dict[int, EnviRaster]:
    """The raw image of every segment the lines files list, in segment order (InputError when
    one is missing); images cut short, and lines the lines files leave out, said in `notes`."""
    segments = sorted({int(s) for s in result.lines.segment})
    images = {s: segment_image(scanner_dir, s) for s in segments}
    rasters = {}
    for s in segments:
        rasters[s], cut = segment_raster(images[s], s)
        if cut is not None:
            notes.append(cut)
    notes += unlisted_line_notes(scanner_dir, result.lines.segment, result.lines.line,
                                 "georeferenced")
    return rasters


def segment_eo(handoff: Handoff, sensor: SensorModel, scanner_dir: Path, segment: int,
               n_lines: int, header_lines: int | None = None) -> tuple[LineEo, I64]:
    """EO of every line of the segment's image (invalid where the line has no time).
    `header_lines`: what the image's header declares when its file holds only `n_lines`
    (cut short): the lines file may list those, which are left out."""
    traj, ln = handoff.trajectory, handoff.sync.lines
    sel = ln.segment == segment
    t = np.full(n_lines, -1, dtype=np.int64)
    rows = ln.line[sel]
    declared = n_lines if header_lines is None else max(header_lines, n_lines)
    if rows.size and (rows.min() < 0 or rows.max() >= declared):
        raise InputError(f"{scanner_dir / f'segment_{segment:03d}.lines.csv'} lists "
                         f"line {rows.max()} but its image only {declared} lines")
    ok = (ln.status[sel] == TimeStatus.OK) & (rows < n_lines)
    t[rows[ok]] = ln.t_gps_ns[sel][ok]
    timed = t >= 0
    eo = exterior_orientation(traj, np.where(timed, t, traj.span_ns[0]), sensor.mounting,
                              time_delay_ns=sensor.time_delay_ns)
    eo.valid[:] &= timed
    return eo, t


def coverage(handoff: Handoff, segment: int, eo: LineEo, t_gps_ns: I64) -> SegmentSkip | None:
    """What of the segment cannot be georeferenced for want of a time or a pose; None if
    every timed line has a pose (lines without a time alone are as before: NaN)."""
    n = t_gps_ns.size
    timed = t_gps_ns >= 0
    if not timed.any():
        result = handoff.sync
        sel = result.lines.segment == segment
        why = Counter(TimeStatus(int(v)).name.lower().replace("_", " ")
                      for v in result.lines.status[sel] if v != TimeStatus.OK)
        if n > int(sel.sum()):
            why["not in the lines file"] += n - int(sel.sum())
        said = ", ".join(f"{k} {v}" for v, k in why.most_common())
        return SegmentSkip(segment, n, 0, n, True, "no line time", (),
                           f"segment {segment}: skipped, none of its {n} lines has a GPS "
                           f"time (sync: {said or 'no line'})")
    rows = np.flatnonzero(timed)
    missing = ~eo.valid[rows]
    if not missing.any():
        return None
    edges = np.flatnonzero(np.diff(np.concatenate([[0], missing.view(np.int8), [0]])))
    spans = tuple(LineSpan(int(rows[a]), int(rows[b - 1]), int(t_gps_ns[rows[a]]),
                           int(t_gps_ns[rows[b - 1]]))
                  for a, b in zip(edges[::2], edges[1::2], strict=True))
    said = "; ".join(f"lines {sp.first_line}-{sp.last_line}, "
                     f"{gps_span_label(sp.t_first_gps_ns, sp.t_last_gps_ns)}"
                     for sp in spans[:SPANS_IN_MESSAGE])
    if len(spans) > SPANS_IN_MESSAGE:
        said += f"; and {len(spans) - SPANS_IN_MESSAGE} more stretches"
    whole = not eo.valid.any()
    k = int(missing.sum())
    head = (f"segment {segment}: skipped, none of its {k} timed lines has a pose" if whole
            else f"segment {segment}: {k} of {n} lines not georeferenced, no pose")
    return SegmentSkip(
        segment, n, int(timed.sum()), n if whole else k, whole, "no pose", spans,
        f"{head} ({said}): outside {handoff.trajectory_name} "
        f"({handoff.trajectory_span_label()})")


def no_overlap_error(handoff: Handoff, flight: Paths) -> InputError:
    """No segment has a line with a time and a pose: the one line that says why."""
    ln, traj = handoff.sync.lines, handoff.trajectory
    name, span = handoff.trajectory_name, handoff.trajectory_span_label()
    t = ln.t_gps_ns[(ln.status == TimeStatus.OK) & (ln.t_gps_ns >= 0)]
    if t.size == 0:
        untied = untimed_lines_note(handoff.sync.report["lines"], log_paths(flight))
        if untied is not None:  # the count alone did not say why
            return InputError(f"nothing to georeference: {untied}")
        why = Counter(TimeStatus(int(v)).name.lower().replace("_", " ") for v in ln.status)
        said = ", ".join(f"{k} {v}" for v, k in why.most_common())
        return InputError(f"no scan line could be put on GPS time (sync: "
                          f"{said or 'no line in the lines files'}), against {name} ({span}): "
                          "nothing to georeference")
    (a0, a1), b0, b1 = traj.span_ns, int(t.min()), int(t.max())
    if a1 < b0:
        where = f"it ends {_duration_label(b0 - a1)} before the first line"
    elif a0 > b1:
        where = f"it starts {_duration_label(a0 - b1)} after the last line"
    else:
        where = "no line falls inside its valid stretches"
    days = round((a0 - b0) / NS_PER_DAY)
    if days and abs(a0 - b0 - days * NS_PER_DAY) < 2 * 3600 * NS_PER_S:
        where += f"; {abs(days)} days apart: a file of another day?"
    return InputError(f"{name} ({span}) does not cover the scan lines "
                      f"({gps_span_label(b0, b1)}): {where}")


def _duration_label(ns: int) -> str:
    s = abs(ns) / NS_PER_S
    if s >= 86_400:
        return f"{s / 86_400:.2f} days"
    return f"{s / 3600:.2f} h" if s >= 3600 else f"{s:.1f} s"
