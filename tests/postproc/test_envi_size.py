"""An ENVI header against the file it describes: more bytes than it describes, or a byte order
ENVI has not, is refused by name; a file cut short still reads as cut short; SISA's own writers
(scanner BIL, IGM, GLT) describe their files exactly. Found by a bad-input sweep: `bands = 1`
for 4 (or `data type = 1` for 12) made `sisa georef` exit 0 with a striped image."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pytest

from emulators.scanner import BilSegmentWriter
from postproc.products.igm import EnviRaster, HeaderBehindWarning
from postproc.products.ortho import GltWriter, OrthoGrid
from sisa.core.errors import InputError
from tests.postproc.test_igm import EPSG, synthetic_strip, write_igm, write_raw

LINES, PIXELS, BANDS = 40, 9, 4  # write_raw's uint16 image: 72 bytes a line


def edit_header(bil: Path, old: str, new: str) -> None:
    hdr = bil.with_suffix(".hdr")
    text = hdr.read_text()
    assert old in text
    hdr.write_text(text.replace(old, new))


@pytest.mark.parametrize(("old", "new", "need", "describes"), [
    ("bands = 4", "bands = 1", 720, "40 lines x 9 samples x 1 bands x 2 bytes + 0 offset"),
    ("data type = 12", "data type = 1", 1440,
     "40 lines x 9 samples x 4 bands x 1 bytes + 0 offset"),
])
def test_a_header_describing_less_than_its_file_is_refused(
        tmp_path: Path, old: str, new: str, need: int, describes: str) -> None:
    bil = tmp_path / "a.bil"
    write_raw(bil, LINES, PIXELS)
    edit_header(bil, old, new)
    have = LINES * PIXELS * BANDS * 2
    with pytest.raises(InputError, match=rf"^{bil} holds {have} bytes, its header describes "
                                         rf"{need} \({re.escape(describes)}\): a header of "
                                         r"another file or layout, or damaged\?$"):
        EnviRaster.open(bil)


@pytest.mark.parametrize("extra", [1, 71, 73])
def test_bytes_past_the_last_line_are_refused(tmp_path: Path, extra: int) -> None:
    """Part of a line too: no writer we know leaves bytes over."""
    bil = tmp_path / "a.bil"
    write_raw(bil, LINES, PIXELS)
    with bil.open("ab") as fh:
        fh.write(b"\0" * extra)
    with pytest.raises(InputError, match=rf"holds {LINES * 72 + extra} bytes, its header "
                                         rf"describes {LINES * 72} "):
        EnviRaster.open(bil)


@pytest.mark.parametrize(("header_lines", "extra_lines"), [(39, 0), (40, 1), (20, 3)])
def test_whole_lines_past_the_header_are_read_and_said(tmp_path: Path, header_lines: int,
                                                        extra_lines: int) -> None:
    """A recording stopped between writing a block and rewriting its header (the scanner
    writes the header after each block) holds whole lines past the header's count: every one is
    read, with a warning, none lost (an exact multiple of the data is another layout: above)."""
    bil = tmp_path / "a.bil"
    write_raw(bil, LINES, PIXELS)
    edit_header(bil, f"lines = {LINES}", f"lines = {header_lines}")
    with bil.open("ab") as fh:
        fh.write(b"\0" * 72 * extra_lines)
    held = LINES + extra_lines
    with pytest.warns(HeaderBehindWarning, match=rf"a\.bil holds {held} lines, "
                      rf"{held - header_lines} more than its header's {header_lines} \(a "
                      r"recording stopped before its header was rewritten\?\): all"):
        raw = EnviRaster.open(bil)
    assert (raw.lines, raw.header_lines, raw.cut_short) == (held, held, False)
    whole = np.fromfile(bil, "<u2").reshape(held, BANDS, PIXELS)
    np.testing.assert_array_equal(raw.read_lines(0, held), whole)


@pytest.mark.parametrize(("old", "new", "part"), [
    ("bands = 4", "bands = 8", "1/2"), ("bands = 4", "bands = 5", "4/5"),
    ("data type = 12", "data type = 5", "1/4")])
def test_a_file_an_exact_part_of_its_header_may_be_another_layout(
        tmp_path: Path, old: str, new: str, part: str) -> None:
    """A header of more bands (or wider numbers) than the file holds reads as cut short, as
    before ("a copy or a recording interrupted?" alone misled), now with a second guess."""
    bil = tmp_path / "a.bil"
    write_raw(bil, LINES, PIXELS)
    edit_header(bil, old, new)
    raw = EnviRaster.open(bil)
    assert raw.cut_short
    assert raw.cut_short_text("a.bil").endswith(
        "(a copy or a recording interrupted? or a header of another layout: the file holds "
        f"exactly {part} of the data it describes)")


def test_a_file_cut_mid_line_says_no_other_layout(tmp_path: Path) -> None:
    bil = tmp_path / "a.bil"
    write_raw(bil, LINES, PIXELS)
    os.truncate(bil, 20 * 72 + 5)  # mid-line 20, of 40: not half of the bytes
    raw = EnviRaster.open(bil)
    assert (raw.lines, raw.header_lines) == (20, 40)
    assert raw.cut_short_text("a.bil") == ("a.bil is cut short: 20 of its header's 40 lines "
                                           "are in the file (a copy or a recording "
                                           "interrupted?)")


def test_a_bsq_file_half_its_header_says_so(tmp_path: Path) -> None:
    bil = tmp_path / "a.bil"
    write_raw(bil, LINES, PIXELS)
    edit_header(bil, "interleave = bil", "interleave = bsq")
    edit_header(bil, "bands = 4", "bands = 8")
    with pytest.raises(InputError, match=r"truncated: 2880 bytes, the header needs 5760 \(a "
                                         r"header of another layout: the file holds exactly "
                                         r"1/2 of the data it describes\)$"):
        EnviRaster.open(bil)


@pytest.mark.parametrize("order", ["7", "2", "-1", "big", "0.5"])
def test_a_byte_order_neither_0_nor_1_is_refused(tmp_path: Path, order: str) -> None:
    """GDAL read any value but 1 as little-endian, silently."""
    bil = tmp_path / "a.bil"
    write_raw(bil, LINES, PIXELS)
    edit_header(bil, "byte order = 0", f"byte order = {order}")
    with pytest.raises(InputError, match=rf"a\.bil: ENVI byte order '{order}' is neither 0 "
                                         r"\(little-endian\) nor 1 \(big-endian\)$"):
        EnviRaster.open(bil)


def test_byte_order_1_reads_big_endian(tmp_path: Path) -> None:
    bil = tmp_path / "a.bil"
    img = write_raw(bil, LINES, PIXELS)
    img.astype(">u2").tofile(bil)
    edit_header(bil, "byte order = 0", "byte order = 1")
    raw = EnviRaster.open(bil)
    assert raw.dtype == np.dtype(">u2")
    np.testing.assert_array_equal(raw.read_lines(0, LINES), img)


def test_sisas_writers_describe_their_files_exactly(tmp_path: Path) -> None:
    """The scanner's BIL after every block (its header rewritten after each: a recording read
    while it goes on), the IGM and the GLT: each opens whole."""
    seg = BilSegmentWriter(tmp_path, 0, PIXELS, BANDS, 16)
    for k in range(3):
        seg.append(np.full((5, BANDS, PIXELS), k + 1, np.uint16), np.arange(5) + 5 * k)
        raw = EnviRaster.open(seg.bil_path)
        assert (raw.lines, raw.header_lines) == (5 * (k + 1), 5 * (k + 1))
    seg.close()
    igm = EnviRaster.open(write_igm(synthetic_strip(30, 8), tmp_path / "igm"))
    assert (igm.lines, igm.bands, igm.pixels) == (30, 3, 8)
    grid = OrthoGrid(461_000.0, 4_661_000.0, 1.0, 7, 5, EPSG)
    glt = GltWriter(tmp_path / "glt", grid, "a.bil", "a.tif")
    glt.write_window(0, 0, np.ones((5, 2, 7), np.int32))
    glt.close()
    assert (EnviRaster.open(tmp_path / "glt.bil").lines, grid.height) == (5, 5)
