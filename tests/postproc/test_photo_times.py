"""The photo times table (postproc.georef.phototimes): what it takes, and each way it refuses
a table in one line, naming the row."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from postproc.georef import photo_label, read_photo_times
from sisa.core.errors import InputError


def test_a_truth_table_reads_with_its_comments_and_other_columns(tmp_path: Path) -> None:
    path = tmp_path / "photos.csv"
    path.write_text("# every photo\n# rows: 3\nphoto_number,strip,t_mid_gps_ns,x\n"
                    "7,0,1465290000000000001,1.5\n8,0,-1,2\n65535,1,1465290003000000000,3\n",
                    encoding="utf-8")
    times = read_photo_times(path)
    assert times.photo_number.tolist() == [7, 8, 65535]
    assert times.t_mid_gps_ns.dtype == np.int64
    assert times.t_mid_gps_ns[0] == 1465290000000000001  # exact: no float on the way
    assert times.labels == ["photo_000007", "photo_000008", "photo_065535"]
    assert times.timed().photo_number.tolist() == [7, 65535]
    assert times.time_of(np.array([65535, 9])).tolist() == [1465290003000000000, -1]
    assert photo_label(1234567) == "photo_1234567"


@pytest.mark.parametrize(("text", "says"), [
    ("", "no photo times"),
    ("photo_number,t_ns\n1,2\n", "no column t_mid_gps_ns"),
    ("photo_number,t_mid_gps_ns\n1,1.5e18\n", "data row 1, t_mid_gps_ns"),
    ("photo_number,t_mid_gps_ns\n1,nan\n", "not a whole number"),
    ("photo_number,t_mid_gps_ns\n1,99999999999999999999\n", "not a whole number"),
    ("photo_number,t_mid_gps_ns\n1,5\n1,6\n", "photo number 1 is given twice"),
    ("photo_number,t_mid_gps_ns\n-3,5\n", "negative photo number"),
    ("photo_number,t_mid_gps_ns\n1,5,7\n", "data row 1 has 3 values"),
])
def test_a_bad_table_is_one_error_naming_it(tmp_path: Path, text: str, says: str) -> None:
    path = tmp_path / "t.csv"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(InputError, match=says) as err:
        read_photo_times(path)
    assert str(path) in str(err.value)
    assert "\n" not in str(err.value)


def test_a_binary_file_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "t.csv"
    path.write_bytes(b"\xff\xfe\x00photo")
    with pytest.raises(InputError, match="not a text file"):
        read_photo_times(path)
