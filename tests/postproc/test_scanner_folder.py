"""The scanner's recording folder: a segment image without its line → frame counter record
was skipped without a word ('1 segments, 3125/3125 lines' for a two-strip flight)."""

from __future__ import annotations

from pathlib import Path

import pytest

from postproc.sync import read_scanner_lines
from sisa.core.errors import InputError

LINES_CSV = "# the scanner's record\nline_index,frame_counter\n0,7\n1,8\n2,9\n"


def test_a_segment_image_without_its_lines_file_is_an_error(tmp_path: Path) -> None:
    (tmp_path / "segment_000.lines.csv").write_text(LINES_CSV)
    (tmp_path / "segment_000.bil").write_bytes(b"")
    assert read_scanner_lines(tmp_path).line.tolist() == [0, 1, 2]
    (tmp_path / "segment_001.bil").write_bytes(b"")
    with pytest.raises(InputError, match=r"segment_001\.bil: no segment_001\.lines\.csv"):
        read_scanner_lines(tmp_path)


@pytest.mark.parametrize(("row", "shown"), [("garbage,,x", "'garbage,,x'"), ("3,", "'3,'"),
                                            ("3,10,1", "'3,10,1'"), ("3,1.5", "'3,1.5'"),
                                            ("3,99999999999999999999",
                                             "'3,99999999999999999999'"),
                                            ("3,+-5", "'3,\\+-5'")])
def test_a_damaged_row_of_a_lines_file_is_named_by_its_row_number(tmp_path: Path, row: str,
                                                                  shown: str) -> None:
    (tmp_path / "segment_000.lines.csv").write_text(LINES_CSV + row + "\n4,11\n")
    with pytest.raises(InputError, match=rf"segment_000\.lines\.csv: row 6 \({shown}\): "
                       "expected two integers, line_index,frame_counter$"):
        read_scanner_lines(tmp_path)


@pytest.mark.parametrize("counter", ["9223372036854775807", "4294967296", "-1"])
def test_a_frame_counter_no_header_can_hold_is_named_by_its_row(tmp_path: Path,
                                                                counter: str) -> None:
    """2^63 − 1 was an OverflowError traceback in the unwrapping; -1 went through (found by a
    bad-input sweep of `sisa georef`)."""
    (tmp_path / "segment_000.lines.csv").write_text(LINES_CSV + f"3,{counter}\n4,11\n")
    with pytest.raises(InputError, match=rf"segment_000\.lines\.csv: row 6 \('3,{counter}'\): "
                       r"frame_counter outside 0\.\.4294967295, what a frame header holds$"):
        read_scanner_lines(tmp_path)


def test_a_segment_number_no_header_can_hold_is_refused(tmp_path: Path) -> None:
    """An OverflowError traceback for a 20-digit number in the file name."""
    name = "segment_99999999999999999999.lines.csv"
    (tmp_path / name).write_text(LINES_CSV)
    with pytest.raises(InputError, match=rf"{name}: segment 99999999999999999999 outside "
                       r"0\.\.65535, what a frame header holds$"):
        read_scanner_lines(tmp_path)


def test_a_segment_image_that_is_no_file_is_named_for_what_it_is(tmp_path: Path) -> None:
    """A folder, or a link to nothing, named segment_000.bil was called missing (found by a
    bad-input sweep)."""
    from postproc.georef.segments import segment_image

    with pytest.raises(InputError, match=r"segment_000\.bil: missing, but the lines file lists "
                                         r"segment 0$"):
        segment_image(tmp_path, 0)
    (tmp_path / "segment_000.bil").mkdir()
    with pytest.raises(InputError, match=r"segment_000\.bil: not a file, but the lines file"):
        segment_image(tmp_path, 0)
    (tmp_path / "segment_001.bil").symlink_to(tmp_path / "nowhere.bil")
    with pytest.raises(InputError, match=r"segment_001\.bil: a link to nothing, but the lines"):
        segment_image(tmp_path, 1)
    (tmp_path / "segment_002.bil").write_bytes(b"")
    assert segment_image(tmp_path, 2) == tmp_path / "segment_002.bil"


def _segment(folder: Path, image_lines: int, listed: int) -> None:
    """segment_000: a 4-pixel, 2-band uint16 BIL of `image_lines` lines, and a lines file
    listing `listed`."""
    from emulators.scanner import envi_header

    (folder / "segment_000.bil").write_bytes(bytes(image_lines * 2 * 4 * 2))
    (folder / "segment_000.hdr").write_text(envi_header(4, image_lines, 2, 0,
                                                        "segment_000.lines.csv"))
    rows = "".join(f"{i},{i + 7}\n" for i in range(listed))
    (folder / "segment_000.lines.csv").write_text(f"line_index,frame_counter\n{rows}")


def test_a_lines_file_longer_than_its_image_is_an_input_error(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`sisa sync` took a lines file of 1 M rows more than its BIL: exit 0, 999 926 lines
    flagged. The rows past the image cannot be its lines: the file is not this image's."""
    from sisa.cli import main
    from tests.recorder import write_sample_log

    scanner = tmp_path / "scanner"
    scanner.mkdir()
    _segment(scanner, 5, 5)
    assert read_scanner_lines(scanner).line.size == 5
    _segment(scanner, 5, 6)
    with pytest.raises(InputError, match=r"segment_000\.lines\.csv: lists 6 lines, but its "
                       r"image segment_000\.bil holds 5: a lines file that does not match"):
        read_scanner_lines(scanner)
    _segment(scanner, 5, 200_005)
    flight = tmp_path / "flight.mcap"
    write_sample_log(flight)
    assert main(["sync", str(flight), "--scanner", str(scanner), "--out",
                 str(tmp_path / "sync")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "lists 200005 lines, but its image segment_000.bil holds 5" in err
    assert not (tmp_path / "sync").exists()


def test_a_lines_file_shorter_than_its_image_is_still_timed_and_said(tmp_path: Path) -> None:
    """A recording cut short: the lines it lists are timed, the rest said (unchanged)."""
    from postproc.sync.files import unlisted_line_notes

    _segment(tmp_path, 5, 3)
    table = read_scanner_lines(tmp_path)
    assert table.line.size == 3
    assert unlisted_line_notes(tmp_path, table.segment, table.line, "timed") == [
        f"{tmp_path / 'segment_000.bil'}: its lines file lists 3 of its 5 lines: the other 2 "
        "have no frame counter: not timed"]
