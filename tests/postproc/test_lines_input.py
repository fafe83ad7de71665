"""A scanner lines file saved with a UTF-8 byte-order mark (Excel, Windows tools) was refused
with "expected the header line 'line_index,frame_counter'", beside that very line: the mark
was taken as part of it. It is read now; other damage keeps its own one-line error."""

from __future__ import annotations

import codecs
from pathlib import Path

import pytest

from postproc.sync import read_scanner_lines
from sisa.core.errors import InputError

LINES_CSV = "# the scanner's record\nline_index,frame_counter\n0,7\n1,8\n2,9\n"
NAME = "segment_000.lines.csv"


@pytest.mark.parametrize("text", [LINES_CSV, LINES_CSV.split("\n", 1)[1],
                                  LINES_CSV.replace("\n", "\r\n")],
                         ids=["comment first", "header first", "crlf"])
def test_a_byte_order_mark_is_read_past(tmp_path: Path, text: str) -> None:
    (tmp_path / NAME).write_bytes(codecs.BOM_UTF8 + text.encode())
    table = read_scanner_lines(tmp_path)
    assert table.line.tolist() == [0, 1, 2]
    assert table.frame_counter.tolist() == [7, 8, 9]
    assert table.segment.tolist() == [0, 0, 0]


@pytest.mark.parametrize(("text", "expected"), [
    ("line_index;frame_counter\n0,7\n", "expected the header line 'line_index,frame_counter'$"),
    (LINES_CSV + "3,x\n", r"row 6 \('3,x'\): expected two integers, line_index,frame_counter$"),
    (LINES_CSV + "3,-1\n", r"row 6 \('3,-1'\): frame_counter outside 0\.\.4294967295"),
    (LINES_CSV.replace("2,9", "5,9"), "line_index must run 0, 1, 2, ... in file order$"),
], ids=["header", "row", "counter", "line_index"])
def test_damage_after_a_byte_order_mark_keeps_its_error(tmp_path: Path, text: str,
                                                        expected: str) -> None:
    """Rows are still numbered as an editor counts them (the mark is no line)."""
    (tmp_path / NAME).write_bytes(codecs.BOM_UTF8 + text.encode())
    with pytest.raises(InputError, match=rf"{NAME}: {expected}"):
        read_scanner_lines(tmp_path)


@pytest.mark.parametrize("codec", ["utf-16", "utf-16-be"])
def test_utf16_text_is_named_for_what_it_is(tmp_path: Path, codec: str) -> None:
    """Excel's 'Unicode text': was "unreadable: 'utf-8' codec can't decode byte 0xff"."""
    data = LINES_CSV.encode(codec)
    if not data.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        data = codecs.BOM_UTF16_BE + data
    (tmp_path / NAME).write_bytes(data)
    with pytest.raises(InputError, match=rf"{NAME}: UTF-16 text .*: save it as UTF-8"):
        read_scanner_lines(tmp_path)


def test_bytes_that_are_not_utf8_stay_unreadable(tmp_path: Path) -> None:
    (tmp_path / NAME).write_bytes(codecs.BOM_UTF8 + LINES_CSV.encode() + b"3,\xff\n")
    with pytest.raises(InputError, match=rf"{NAME}: unreadable: 'utf-8' codec can't decode"):
        read_scanner_lines(tmp_path)
