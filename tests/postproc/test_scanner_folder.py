"""The scanner's recording folder: a segment image without its line → frame counter record
was skipped without a word ('1 segments, 3125/3125 lines' for a two-strip flight)."""

from __future__ import annotations

from pathlib import Path

import pytest

from postproc.syncio import read_scanner_lines
from sisa.errors import InputError

LINES_CSV = "# the scanner's record\nline_index,frame_counter\n0,7\n1,8\n2,9\n"


def test_a_segment_image_without_its_lines_file_is_an_error(tmp_path: Path) -> None:
    (tmp_path / "segment_000.lines.csv").write_text(LINES_CSV)
    (tmp_path / "segment_000.bil").write_bytes(b"")
    assert read_scanner_lines(tmp_path).line.tolist() == [0, 1, 2]
    (tmp_path / "segment_001.bil").write_bytes(b"")
    with pytest.raises(InputError, match=r"segment_001\.bil: no segment_001\.lines\.csv"):
        read_scanner_lines(tmp_path)
