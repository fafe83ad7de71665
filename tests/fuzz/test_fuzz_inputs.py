"""Fuzzing the other files post-processing reads: the scanner's lines files beside their ENVI
images, RTKLIB `.pos` solutions and Applanix SBET trajectories (issue 39: "a mutation fuzz of
the file readers").

Seeds are well-formed files of each kind, written here the way the scanner emulator, RTKLIB and
Applanix write them; hypothesis then damages them (bit flips, deletions, insertions of hostile
bytes and of integers longer than Python converts by default, cuts) or writes arbitrary bytes.
Every reader may only return a result or fail with one InputError line naming the file, within
the time limit and a bounded amount of memory for a small file.
"""

from __future__ import annotations

import shutil
import struct
import tempfile
import tracemalloc
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from hypothesis import strategies as st

from postproc.georef.trajfiles import read_rtklib_pos, read_sbet
from postproc.sync.files import read_scanner_lines
from sisa.core.errors import InputError
from sisa.core.timescale import NS_PER_S
from tests.fuzz import Fuzzer, ci_settings, run_fuzzer
from tests.fuzz.test_fuzz_files import damaged_text

# damaged inputs by design: the readers' warnings saying so are expected
pytestmark = [pytest.mark.filterwarnings("ignore::postproc.products.igm.HeaderBehindWarning"),
              pytest.mark.filterwarnings("ignore::postproc.georef.trajfiles.PartialRecordWarning")]

PEAK_BYTES_LIMIT = 48 * 2**20  # reading a file of a few kB may use a few MB, never hundreds
WEEK_2423_NS = 2423 * 7 * 86_400 * NS_PER_S
SBET_RECORD_BYTES = 17 * 8


@contextmanager
def _folder() -> Iterator[Path]:
    folder = Path(tempfile.mkdtemp(prefix="sisa-fuzz-inputs-"))
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _one_line_error_or_result(read: Callable[[], object], path: Path) -> int:
    """Run a reader: a result (0), or one InputError line naming the file (1); bounded memory."""
    tracemalloc.start()
    try:
        try:
            read()
            errors = 0
        except InputError as exc:
            text = str(exc)
            assert "\n" not in text, f"a multi-line error: {text!r}"
            assert path.name in text, f"the error does not name the file: {text!r}"
            errors = 1
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < PEAK_BYTES_LIMIT, f"reading {path.name} took {peak / 2**20:.0f} MiB"
    return errors


# --- the scanner's lines file beside its image --------------------------------------------------

SAMPLES, BANDS = 8, 2


def _lines_csv(lines: int, first_counter: int = 65_530) -> bytes:
    rows = [f"{i},{(first_counter + i) % 65_536}" for i in range(lines)]
    return ("# the frame counter of each image line\nline_index,frame_counter\n"
            + "\n".join(rows) + "\n").encode()


def _envi_header(lines: int) -> bytes:
    return (f"ENVI\nsamples = {SAMPLES}\nlines = {lines}\nbands = {BANDS}\nheader offset = 0\n"
            "file type = ENVI Standard\ndata type = 12\ninterleave = bil\nbyte order = 0\n"
            ).encode()


@st.composite
def scanner_folders(draw: st.DrawFn) -> tuple[bytes, bytes, int]:
    """(lines file, ENVI header, image lines): one of them damaged, or the image cut."""
    lines = draw(st.integers(0, 12))
    csv, header = _lines_csv(lines), _envi_header(lines)
    which = draw(st.sampled_from(("csv", "header", "image", "csv-bytes")))
    if which == "csv":
        csv = draw(damaged_text((csv,)))
    elif which == "header":
        header = draw(damaged_text((header,)))
    elif which == "csv-bytes":
        csv = draw(st.binary(max_size=300))
    image_lines = draw(st.integers(0, lines + 2)) if which == "image" else lines
    return csv, header, image_lines


def check_scanner_folder(case: tuple[bytes, bytes, int]) -> int:
    csv, header, image_lines = case
    with _folder() as folder:
        (folder / "segment_000.lines.csv").write_bytes(csv)
        (folder / "segment_000.hdr").write_bytes(header)
        (folder / "segment_000.bil").write_bytes(bytes(image_lines * SAMPLES * BANDS * 2))
        path = folder / "segment_000.lines.csv"
        table: list[object] = []
        errors = _one_line_error_or_result(lambda: table.append(read_scanner_lines(folder)),
                                           path)
        if table:  # read: never more lines than the image holds whole
            read = table[0]
            assert read.line.size <= max(image_lines, _header_lines(header)), read.line.size
            assert np.array_equal(read.line, np.arange(read.line.size))
        return errors


def _header_lines(header: bytes) -> int:
    for row in header.decode("latin-1").splitlines():
        key, _, value = row.partition("=")
        if key.strip() == "lines" and value.strip().isdigit():
            return int(value.strip())
    return -1


# --- RTKLIB .pos --------------------------------------------------------------------------------


def _pos_text() -> bytes:
    head = ["% program   : RTKPOST ver.2.4.3 b34",
            "% pos mode  : kinematic",
            "% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,"
            "ns=# of satellites)",
            "%  GPST                  latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)"
            "   sde(m)   sdu(m)  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio"]
    rows = []
    for k in range(8):
        rows.append(f"2026/06/15 09:00:{1 + k:06.3f}   41.600{k:06d}    2.000{k:06d}   "
                    f"300.{k:04d}   1   9   0.0071   0.0052   0.0143  -0.0011   0.0023  -0.0031"
                    "   1.00   12.5")
    return ("\n".join(head + rows) + "\n").encode()


def check_pos_file(data: bytes) -> int:
    with _folder() as folder:
        path = folder / "rover.pos"
        path.write_bytes(data)
        return _one_line_error_or_result(lambda: read_rtklib_pos(path, leap_seconds=18), path)


# --- Applanix SBET ------------------------------------------------------------------------------


def _sbet_bytes(records: int = 6) -> bytes:
    out = bytearray()
    for k in range(records):
        tow_s = 2 * 86_400.0 + 32_400.0 + k * 0.005
        out += struct.pack("<17d", tow_s, 0.7261, 0.0349, 300.0 + k, 60.0, 5.0, -0.2, 0.01,
                           0.02, 1.2, 0.3, 0, 0, 0, 0, 0, 0)
    return bytes(out)


@st.composite
def sbet_files(draw: st.DrawFn) -> bytes:
    data = bytearray(_sbet_bytes(draw(st.integers(1, 8))))
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(("flip", "double", "cut", "append")))
        if op == "flip" and data:
            at = draw(st.integers(0, len(data) - 1))
            data[at] ^= 1 << draw(st.integers(0, 7))
        elif op == "double" and len(data) >= 8:  # a whole field set to a hostile value
            at = draw(st.integers(0, len(data) // 8 - 1)) * 8
            value = draw(st.sampled_from((float("nan"), float("inf"), -float("inf"), 1e308,
                                          -1e308, 0.0, 5e-324, 604_800.0, -1.0)))
            data[at:at + 8] = struct.pack("<d", value)
        elif op == "cut":
            del data[draw(st.integers(0, len(data))):]
        else:
            data += draw(st.binary(max_size=SBET_RECORD_BYTES + 8))
    return bytes(data)


def check_sbet_file(data: bytes) -> int:
    with _folder() as folder:
        path = folder / "sbet_001.out"
        path.write_bytes(data)
        sbet: list[object] = []
        errors = _one_line_error_or_result(
            lambda: sbet.append(read_sbet(path, WEEK_2423_NS)), path)
        return errors


FUZZERS = [
    Fuzzer("lines/folders", scanner_folders(), check_scanner_folder, examples=60),
    Fuzzer("pos/damaged", damaged_text((_pos_text(),)), check_pos_file, examples=60),
    Fuzzer("pos/random-bytes", st.binary(max_size=300), check_pos_file, examples=20),
    Fuzzer("sbet/damaged", sbet_files(), check_sbet_file, examples=60),
]


@pytest.mark.parametrize("fuzzer", FUZZERS, ids=[f.name for f in FUZZERS])
def test_fuzz_input_reader(fuzzer: Fuzzer) -> None:
    tally = run_fuzzer(fuzzer, ci_settings(fuzzer.examples))
    assert tally.examples >= 1
    assert tally.errors_counted >= 1  # the damage reaches the readers' checks (~half refused)


@pytest.mark.parametrize(("check", "seed"), [
    (check_scanner_folder, (_lines_csv(5), _envi_header(5), 5)),
    (check_pos_file, _pos_text()),
    (check_sbet_file, _sbet_bytes()),
], ids=["lines", "pos", "sbet"])
def test_the_seeds_read_whole(check: Callable[[object], int], seed: object) -> None:
    """Undamaged, each seed reads without an error: the fuzzers damage files that work."""
    assert check(seed) == 0
