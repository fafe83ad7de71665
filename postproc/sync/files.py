"""Files of time synchronisation: the scanner's lines files in, the time tables and report out.

Outputs are CSV with a commented header naming every column and its unit, and one JSON report.
The tables are written with numpy in blocks, so a million lines never become Python rows.
"""

from __future__ import annotations

import codecs
import io
import re
from pathlib import Path
from typing import Any, Final, TextIO

import numpy as np
import numpy.typing as npt

from postproc.sync.config import TimeStatus
from postproc.sync.lines import LineTable
from postproc.sync.photos import PhotoStatus, PhotoTimes, PhotoTimeSource
from postproc.sync.results import InsTimes, LineTimes
from sisa.core.errors import InputError
from sisa.core.jsonio import write_json

I64 = npt.NDArray[np.int64]

LINES_GLOB: Final = "segment_*.lines.csv"
IMAGES_GLOB: Final = "segment_*.bil"
_SEGMENT_RE: Final = re.compile(r"segment_(\d+)\.lines\.csv$")
_IMAGE_RE: Final = re.compile(r"segment_(\d+)\.bil$")
# what a frame header can carry (acquisition/scanner_header.py: frame_counter u32, segment u16;
# postproc reads files, not the codecs: tests/postproc/test_sync.py checks they agree)
FRAME_COUNTER_MAX: Final = 2**32 - 1
SEGMENT_MAX: Final = 2**16 - 1
WRITE_BLOCK: Final = 100_000

STATUS_DOC: Final = ("status: " + " | ".join(s.name.lower() for s in TimeStatus)
                     + " (only ok rows carry a time; see docs/sync.md)")

INS_HEADER: Final = (
    "# SISA time synchronisation: the GPS time of every INS record of the flight log, in log\n"
    "# order (sisa sync; docs/sync.md).\n"
    "# seq: record index from 0, the record counter unwrapped (a gap = records missing from the\n"
    "#   log); after an INS reboot it continues from the last record before it\n"
    "# counter: the record counter as logged (wraps)\n"
    "# t_gps_ns: GPS time of the record's measurement epoch, int64 ns since\n"
    "#   1980-01-06T00:00:00 on the GPS scale (no leap seconds); -1 unless status is ok\n"
    f"# {STATUS_DOC}\n"
    "seq,counter,t_gps_ns,status\n")

LINE_HEADER: Final = (
    "# SISA time synchronisation: the GPS time of every scan line (sisa sync; docs/sync.md).\n"
    "# segment: recording segment (segment_NNN files of the scanner)\n"
    "# line: 0-based line of the segment's BIL file (without the scanner's lines files: the\n"
    "#   order of the frame headers of the segment in the log)\n"
    "# frame_counter: the scanner's frame counter of the line, as recorded (wraps)\n"
    "# t_gps_ns: GPS time of the line's mid-exposure, int64 ns since 1980-01-06T00:00:00 on\n"
    "#   the GPS scale (no leap seconds); -1 unless status is ok\n"
    f"# {STATUS_DOC}\n"
    "segment,line,frame_counter,t_gps_ns,status\n")


def _read_lines_csv(path: Path, segment: int) -> LineTable:
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: unreadable: {exc}") from None
    if raw.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        raise InputError(f"{path}: UTF-16 text (a Windows 'Unicode' save): save it as UTF-8 or "
                         "plain ASCII text")
    try:  # utf-8-sig: the byte-order mark Excel and Windows tools write is read past (it was
        # taken as part of the first line: "expected the header line", beside that very line)
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: unreadable: {exc}") from None
    body = [(number, row) for number, row in enumerate(text.splitlines(), start=1)
            if row.strip() and not row.startswith("#")]  # numbered as an editor counts lines
    if not body or body[0][1].strip() != "line_index,frame_counter":
        raise InputError(f"{path}: expected the header line 'line_index,frame_counter'")
    rows = [row for _, row in body[1:]]
    try:
        data = np.loadtxt(io.StringIO("\n".join(rows)), delimiter=",", dtype=np.int64,
                          ndmin=2) if rows else np.zeros((0, 2), dtype=np.int64)
        if data.shape[1] != 2:
            raise ValueError("not two columns")
    except ValueError:
        raise InputError(f"{path}: {_first_bad_row(body[1:])}: expected two integers, "
                         "line_index,frame_counter") from None
    line, counter = data[:, 0], data[:, 1]
    if not np.array_equal(line, np.arange(line.size)):
        raise InputError(f"{path}: line_index must run 0, 1, 2, ... in file order")
    bad = np.flatnonzero((counter < 0) | (counter > FRAME_COUNTER_MAX))
    if bad.size:  # beyond the header's field: damage (2^63 overflowed the unwrapping)
        number, row = body[1 + int(bad[0])]
        raise InputError(f"{path}: row {number} ({row.strip()!r}): frame_counter outside "
                         f"0..{FRAME_COUNTER_MAX}, what a frame header holds")
    return LineTable(np.full(line.size, segment, dtype=np.int64), line, counter)


def _first_bad_row(rows: list[tuple[int, str]]) -> str:
    """Where the data rows stop being line_index,frame_counter: 'row N ('...')'."""
    for number, row in rows:
        fields = row.split(",")
        if len(fields) != 2 or not all(_is_int64(f) for f in fields):
            return f"row {number} ({row[:40]!r})"
    return "a row"


def _is_int64(text: str) -> bool:
    try:
        value = int(text)
    except ValueError:
        return False
    return -2**63 <= value < 2**63


def read_scanner_lines(folder: Path) -> LineTable:
    """Every `segment_NNN.lines.csv` of a scanner recording folder, in segment order."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: no such scanner folder")
    files = sorted(folder.glob(LINES_GLOB))
    if not files:
        raise InputError(f"{folder}: no {LINES_GLOB} files (the scanner's line → frame "
                         "counter records)")
    for image in scanner_images(folder):
        lines_csv = image.with_suffix(".lines.csv")
        if not lines_csv.is_file():
            raise InputError(f"{image}: no {lines_csv.name} beside it (the scanner's line → "
                             "frame counter record): its lines could not be timed")
    tables = []
    for path in files:
        m = _SEGMENT_RE.search(path.name)
        if m is None:
            raise InputError(f"{path}: cannot read the segment number from the name")
        segment = int(m.group(1))
        if not 0 <= segment <= SEGMENT_MAX:
            raise InputError(f"{path}: segment {segment} outside 0..{SEGMENT_MAX}, what a frame "
                             "header holds")
        table = _read_lines_csv(path, segment)
        _check_against_image(path, path.with_name(f"{m.group(0)[:-len('.lines.csv')]}.bil"),
                             table.line.size)
        tables.append(table)
    return LineTable(*(np.concatenate([getattr(t, f) for t in tables])
                       for f in ("segment", "line", "frame_counter")))


def _check_against_image(lines_csv: Path, image: Path, rows: int) -> None:
    """A lines file that lists more lines than its image holds (its header's count, or the
    whole lines of a file longer than its header says) does not belong to it: InputError (it
    was timed, and every line past the image flagged). One that lists fewer, as after a
    recording cut short, is said by `unlisted_line_notes`; an image whose header cannot be read
    is named there too, and not judged here."""
    from postproc.products.igm import EnviRaster

    if not image.is_file():
        return
    try:
        raster = EnviRaster.open(image)
    except InputError:
        return
    holds = max(raster.lines, raster.header_lines)
    if rows > holds:
        raise InputError(f"{lines_csv}: lists {rows} lines, but its image {image.name} holds "
                         f"{holds}: a lines file that does not match its image (of another "
                         "segment or recording?)")


def scanner_images(folder: Path) -> list[Path]:
    """Every `segment_NNN.bil` image of a scanner recording folder, in segment order."""
    return sorted(Path(folder).glob(IMAGES_GLOB))


def unlisted_line_notes(folder: Path, segment: npt.NDArray[np.integer[Any]],
                        line: npt.NDArray[np.integer[Any]], what: str) -> list[str]:
    """What to say of the scanner folder's images whose lines files list none or only some of
    their lines (a lines file cut short, or holding its header only): those lines have no
    frame counter, so no time, and are not `what` ("timed", "georeferenced"). An image whose
    header cannot be read is named, and not judged. `segment`, `line`: the lines listed."""
    from postproc.products import EnviRaster

    notes = []
    for image in scanner_images(folder):
        try:
            n_lines = EnviRaster.open(image).lines
        except InputError as exc:
            notes.append(f"{exc}: its lines are not checked against it")
            continue
        m = _IMAGE_RE.search(image.name)
        s = int(m.group(1)) if m is not None else -1
        listed = np.unique(line[(segment == s) & (line >= 0) & (line < n_lines)]).size
        if listed == 0:
            notes.append(f"{image}: its lines file lists no line: not {what}")
        elif listed < n_lines:
            notes.append(f"{image}: its lines file lists {listed} of its {n_lines} lines: the "
                         f"other {n_lines - listed} have no frame counter: not {what}")
    return notes


def _status_names(status: I64) -> npt.NDArray[np.str_]:
    names = np.array([s.name.lower() for s in TimeStatus])
    return np.asarray(names[status], dtype=np.str_)


def _write_table(fh: TextIO, columns: list[npt.NDArray[Any]]) -> None:
    n = columns[0].size
    for lo in range(0, n, WRITE_BLOCK):
        block = [c[lo:lo + WRITE_BLOCK].astype(str) for c in columns]
        rows = block[0]
        for col in block[1:]:
            rows = np.char.add(np.char.add(rows, ","), col)
        fh.write("\n".join(rows.tolist()))
        fh.write("\n")


def write_ins_times(path: Path, seq: I64, counter: I64, t_gps_ns: I64, status: I64) -> None:
    with Path(path).open("w", encoding="utf-8", newline="") as fh:
        fh.write(INS_HEADER)
        _write_table(fh, [seq, counter, t_gps_ns, _status_names(status)])


def write_line_times(path: Path, segment: I64, line: I64, frame_counter: I64, t_gps_ns: I64,
                     status: I64) -> None:
    with Path(path).open("w", encoding="utf-8", newline="") as fh:
        fh.write(LINE_HEADER)
        _write_table(fh, [segment, line, frame_counter, t_gps_ns, _status_names(status)])


def write_time_tables(folder: Path, ins: InsTimes, lines: LineTimes) -> None:
    """`folder`/ins_times.csv and `folder`/line_times.csv, as `sisa sync` writes them."""
    write_ins_times(folder / "ins_times.csv", ins.seq, ins.counter, ins.t_gps_ns, ins.status)
    write_line_times(folder / "line_times.csv", lines.segment, lines.line, lines.frame_counter,
                     lines.t_gps_ns, lines.status)


PHOTO_HEADER: Final = (
    "# SISA time synchronisation: the GPS time of every photo the frame camera named (sisa\n"
    "# sync; docs/sync.md, \"Photos\"), one row per photo message, in the order they reached\n"
    "# the recorder; the photo times table `sisa georef --photo-times` reads.\n"
    "# photo_number: the camera's photo number, as sent (wraps)\n"
    "# t_mid_gps_ns: GPS time of the photo's mid-exposure, int64 ns since 1980-01-06T00:00:00\n"
    "#   on the GPS scale (no leap seconds); -1 unless status is ok or board_time\n"
    "# sigma_ns: the time's predicted error (1 sigma), empty without a time\n"
    "# source: event_tag (the receiver tagged its pulse) | board (the sync unit's timing board,\n"
    "#   through the PPS) | none\n"
    "# status: " + " | ".join(s.name.lower() for s in PhotoStatus
                              if s is not PhotoStatus.NO_PHOTO_NUMBER) + "\n"
    "photo_number,t_mid_gps_ns,sigma_ns,source,status\n")
UNNAMED_HEADER: Final = (
    "# SISA time synchronisation: the frame camera's pulses no photo message named (sisa sync;\n"
    "# docs/sync.md, \"Photos\"): a photo whose message was lost, or a pulse the camera never\n"
    "# made; each with its time, as the photos'.\n"
    "# t_gps_ns: GPS time of the pulse (a mid-exposure), int64 ns; -1 without a time\n"
    "# sigma_ns, source: as in photo_times.csv\n"
    "t_gps_ns,sigma_ns,source\n")


def write_photo_times(folder: Path, photos: PhotoTimes) -> None:
    """`folder`/photo_times.csv (the named photos) and `folder`/camera_pulses_unnamed.csv."""
    sources = np.array([s.name.lower() for s in PhotoTimeSource])
    names = np.array([s.name.lower() for s in PhotoStatus])
    sigma = np.array(["" if not np.isfinite(v) else f"{v:.1f}" for v in photos.sigma_ns],
                     dtype=np.str_)
    named = photos.photo_number >= 0
    for name, head, pick, columns in (
            ("photo_times.csv", PHOTO_HEADER, named,
             [photos.photo_number, photos.t_gps_ns, sigma, sources[photos.source],
              names[photos.status]]),
            ("camera_pulses_unnamed.csv", UNNAMED_HEADER, ~named,
             [photos.t_gps_ns, sigma, sources[photos.source]])):
        with (Path(folder) / name).open("w", encoding="utf-8", newline="") as fh:
            fh.write(head)
            if pick.any():
                _write_table(fh, [c[pick] for c in columns])


def write_report(path: Path, report: dict[str, Any]) -> None:
    write_json(path, report)
