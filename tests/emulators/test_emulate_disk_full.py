"""A disk that fills up under the emulators (issue 39, item 3): the scanner's own recording and
the truth tables on a real, small tmpfs, then `sisa emulate` on one.

The standard is `sisa record`'s (tests/recorder/test_disk_full.py): one line on stderr naming
the file and the cause, exit 2; the scanner's segment consistent (its BIL holds whole exactly
the lines its header and its lines file name) and readable; each truth table whole or absent;
no partial file left.
"""

from __future__ import annotations

import contextlib
import csv
import os
import subprocess
import sys
import warnings
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from emulators.scanner import BilSegmentWriter
from emulators.system import EmulatedSystem
from emulators.truth import TruthTable, read_truth_csv
from postproc.products import EnviRaster
from postproc.sync import read_scanner_lines
from recorder.columns import read_columns
from recorder.messages import Topic
from recorder.stats import DamagedLogWarning
from sisa.core.errors import RecorderError

ROOT = Path(__file__).resolve().parents[2]
PAGE = 4096
PIXELS, BANDS = 512, 4  # the bench preset's scanner: a line is one page
NO_SPACE = "No space left on device"


@contextlib.contextmanager
def tmpfs(folder: Path, size: str) -> Iterator[Path]:
    """A real tmpfs of `size` mounted on `folder` (made here), unmounted at the end: lazily if
    a file on it is still open (a test that failed before closing it), never left mounted."""
    folder.mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)],
                   check=True)
    try:
        yield folder
    finally:
        if subprocess.run(["umount", str(folder)], capture_output=True).returncode != 0:
            subprocess.run(["umount", "--lazy", str(folder)], check=True)


def fill(folder: Path, leave_bytes: int) -> None:
    """Fill the file system of `folder` but for about `leave_bytes`."""
    st = os.statvfs(folder)
    free = st.f_bavail * st.f_frsize
    with (folder / "filler").open("wb") as fh:
        fh.write(b"\0" * max(0, free - leave_bytes))


def partial_names(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if ".partial" in p.name]


def header_value(hdr: Path, key: str) -> str:
    for line in hdr.read_text(encoding="utf-8").splitlines():
        name, _, value = line.partition("=")
        if name.strip() == key:
            return value.strip()
    raise AssertionError(f"{hdr}: no {key}")


def check_segment(bil: Path) -> int:
    """The three files of a scanner segment agree; the number of lines they hold."""
    hdr, lines_csv = bil.with_suffix(".hdr"), bil.with_suffix(".lines.csv")
    samples, bands = int(header_value(hdr, "samples")), int(header_value(hdr, "bands"))
    assert header_value(hdr, "data type") == "12"  # uint16
    line_bytes = samples * bands * 2
    size = bil.stat().st_size
    assert size % line_bytes == 0, f"{bil}: {size} bytes, not whole lines of {line_bytes}"
    lines = size // line_bytes
    assert int(header_value(hdr, "lines")) == lines, f"{hdr} disagrees with {bil}"
    rows = [r for r in csv.reader(ln for ln in lines_csv.read_text(encoding="utf-8")
                                   .splitlines() if not ln.startswith("#"))]
    assert rows[0] == ["line_index", "frame_counter"]
    assert [int(r[0]) for r in rows[1:]] == list(range(lines)), f"{lines_csv} disagrees"
    raster = EnviRaster.open(bil)  # the project's own reader
    assert (raster.lines, raster.header_lines, raster.pixels, raster.bands) == \
        (lines, lines, samples, bands)
    if lines:
        assert raster.read_lines(0, lines).shape[0] == lines
    return lines


def check_truth(folder: Path, names: list[str]) -> list[str]:
    """Each truth table whole or absent: the names of those present."""
    present = []
    for name in names:
        path = folder / f"{name}.csv"
        if path.exists():
            read_truth_csv(path)  # refuses a table cut short (its header counts its rows)
            present.append(name)
    return present


# --- the scanner's recording ------------------------------------------------------------------

BLOCK = 5  # lines per append: 5 pages of BIL, a row of the lines file each


@pytest.mark.parametrize("leave_pages", [0, 1, 2, 3, 6, 7, 11, 12, 13, 40])
def test_the_scanner_segment_stays_consistent_whatever_step_fills_the_disk(
        leave_pages: int, tmp_path: Path) -> None:
    """The disk fills in the BIL, the lines file or the header's rewrite, or as the segment
    starts: one RecorderError naming the file; the three files agree (or none is left)."""
    with tmpfs(tmp_path / "disk", "1m") as disk:
        fill(disk, leave_pages * PAGE)
        writer: list[BilSegmentWriter] = []
        with pytest.raises(RecorderError) as failed:
            _record_until_full(disk, writer)
        text = str(failed.value)
        assert "\n" not in text
        assert NO_SPACE in text
        assert f"cannot write {disk}/segment_000." in text
        assert not partial_names(disk)
        bil = disk / "segment_000.bil"
        if writer:
            with pytest.raises(RecorderError) as again:  # every later call: the same error
                writer[0].append(np.zeros((1, BANDS, PIXELS), np.uint16), [0])
            assert again.value is failed.value
            writer[0].close()
        if not writer or writer[0].lines == 0:  # no line written: nothing of it is left
            assert "is removed (no line of it was written)" in text
            assert not list(disk.glob("segment_000*"))
            return
        lines = check_segment(bil)
        assert lines == writer[0].lines
        assert f"kept up to its last whole block ({lines} lines:" in text
        assert lines % BLOCK == 0
        if lines:
            data = EnviRaster.open(bil).read_lines(0, lines)
            assert (data[::BLOCK, 0, 0] == np.arange(1, lines // BLOCK + 1)).all()
            assert read_scanner_lines(disk).line.size == lines


def _record_until_full(disk: Path, made: list[BilSegmentWriter]) -> None:
    """Blocks of BLOCK lines (line k of a block: DN k + 1) until the disk is full."""
    writer = BilSegmentWriter(disk, 0, PIXELS, BANDS, 16)
    made.append(writer)
    for k in range(1000):
        writer.append(np.full((BLOCK, BANDS, PIXELS), k + 1, np.uint16),
                      np.arange(BLOCK) + BLOCK * k)


# --- the truth tables -------------------------------------------------------------------------

def _tables() -> list[TruthTable]:
    small = TruthTable("small", {"i": "index"}, "a small table")
    small.extend(i=range(10))
    big = TruthTable("big", {"i": "index", "x": "a float"}, "a big table", spill_rows=1000)
    big.extend(i=range(40_000), x=np.linspace(0, 1, 40_000).tolist())
    tiny = TruthTable("tiny", {"i": "index"}, "a tiny table")
    tiny.append(i=1)
    return [small, big, tiny]


@pytest.mark.parametrize("leave_pages", [0, 1, 3, 50])
def test_truth_tables_are_whole_or_absent(leave_pages: int, tmp_path: Path) -> None:
    with tmpfs(tmp_path / "disk", "1m") as disk:
        fill(disk, leave_pages * PAGE)
        tables = _tables()
        system = SimpleNamespace(truth_tables=lambda: tables)
        with pytest.raises(RecorderError) as failed:
            EmulatedSystem.write_truth(system, disk / "truth")  # type: ignore[arg-type]
        text = str(failed.value)
        assert "\n" not in text
        assert NO_SPACE in text
        assert str(disk / "truth") in text
        assert not partial_names(disk)
        if (disk / "truth").exists():
            present = check_truth(disk / "truth", ["small", "big", "tiny"])
            assert "big" not in present  # 1.2 MB: never on this disk
            absent = [n for n in ("small", "big", "tiny") if n not in present]
            assert f"not written ({', '.join(absent)})" in text
        # a table written after a failed write goes on at its end, spilled rows and all
        tables[1].append(i=40_000, x=1.0)
        assert tables[1].column("i").tolist() == list(range(40_001))


# --- sisa emulate -----------------------------------------------------------------------------

# 21 s of flight before strip 0 (no warning: `sisa sync` has its scanner-off pulses), then the
# strip at 4x: a line a page, 250 pages a second, fill a 3 MB disk within seconds
FILLING_RUN = ["--preset", "bench", "--start", "325", "--duration", "60", "--speed", "4"]


def check_run_after_disk_full(out: Path, err: str) -> str:
    """One error line naming a file of the run and the cause; the scanner's segments
    consistent and readable; each truth table whole or absent; no partial file. The line."""
    lines = err.splitlines()
    assert len(lines) == 1, err
    line = lines[0]
    assert f"cannot write {out}/" in line
    assert NO_SPACE in line
    assert not partial_names(out.parent), partial_names(out.parent)
    recorded = 0
    for bil in sorted((out / "scanner").glob("segment_*.bil")):
        recorded += check_segment(bil)
    if recorded:
        assert read_scanner_lines(out / "scanner").line.size == recorded
    for table in sorted((out / "truth").glob("*.csv")):
        columns = read_truth_csv(table)  # whole: its header counts its rows
        if table.stem == "frames":  # the truth of what the scanner recorded, no more
            assert int((columns["line_index"] >= 0).sum()) == recorded
    return line


def test_sisa_emulate_on_a_full_disk_exits_with_one_line(tmp_path: Path) -> None:
    """The scanner's BIL fills a 3 MB tmpfs: were three chained ENOSPC tracebacks, a header,
    BIL and lines file that disagreed (764 / 765 / 765 lines) and a 0-byte truth table."""
    with tmpfs(tmp_path / "disk", "3m") as disk:
        out = disk / "run"
        done = subprocess.run([sys.executable, "-m", "sisa.cli", "emulate", *FILLING_RUN,
                               "--out", str(out), "--quiet"],
                              capture_output=True, text=True, timeout=300, cwd=ROOT)
        assert done.returncode == 2, done.stderr
        line = check_run_after_disk_full(out, done.stderr)
        assert line.startswith(f"sisa emulate: error: cannot write {out}/scanner/segment_000."), \
            line
        assert check_segment(out / "scanner" / "segment_000.bil") > 100  # seconds of it kept
        assert "; truth: cannot write " in line or "the truth tables are whole in " in line
        assert " outputs in " not in done.stdout  # no summary: it failed


# --- sisa bench -------------------------------------------------------------------------------

def test_sisa_bench_on_a_full_disk_exits_with_one_line(tmp_path: Path) -> None:
    """The emulator's scanner fills the disk the recorder writes to as well: each child's
    error was its own line, the emulator's three tracebacks, then the bench's `sisa emulate
    exited 1, sisa record exited 2`. Now one line, the children's words in it; the run so far
    kept (the recorder had begun its flight log), every file in it whole or consistent."""
    with tmpfs(tmp_path / "disk", "3m") as disk:
        out = disk / "run"
        done = subprocess.run([sys.executable, "-m", "sisa.cli", "bench", *FILLING_RUN,
                               "--out", str(out)],
                              capture_output=True, text=True, timeout=300, cwd=ROOT)
        assert done.returncode == 2, done.stderr
        line = check_run_after_disk_full(out, done.stderr)
        assert line.startswith("sisa bench: error: sisa "), line
        assert line.endswith(f"; the run so far is in {out}"), line
        assert "exited" not in line  # each child said why, in its own words
        assert ".partial" not in line  # the files named where they are kept
        assert sorted(p.name for p in disk.iterdir()) == ["run"]
        assert not (out / "emulator").exists()
        assert (out / "flight.mcap").is_file()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DamagedLogWarning)  # cut by the full disk
            assert len(read_columns(out / "flight.mcap", Topic.INS_RECORD)["counter"]) > 100
