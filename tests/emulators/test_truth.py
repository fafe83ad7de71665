"""Truth tables spill to a temporary file past `spill_rows` and write the same CSV as if held."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from emulators.truth import TruthTable, read_truth_csv
from sisa.core.errors import InputError


def _table(spill_rows: int) -> TruthTable:
    table = TruthTable("t", {"i": "index", "x_m": "a float", "kind": "a word"}, "a test table",
                       spill_rows=spill_rows)
    for i in range(23):
        table.append(i=i, x_m=i / 7, kind="odd" if i % 2 else "even")
    table.extend(i=[23, 24], x_m=[float("nan"), 1e300], kind=["a,b", 'q"q'])
    return table


def test_a_spilled_table_writes_what_a_held_one_does(tmp_path: Path) -> None:
    held, spilled = _table(1_000_000), _table(5)
    assert len(held) == len(spilled) == 25
    (tmp_path / "held").mkdir()
    (tmp_path / "spilled").mkdir()
    a = held.write_csv(tmp_path / "held").read_bytes()
    b = spilled.write_csv(tmp_path / "spilled").read_bytes()
    assert a == b
    cols = read_truth_csv(tmp_path / "spilled" / "t.csv")
    assert cols["i"].tolist() == list(range(25))
    assert cols["kind"][-2:].tolist() == ["a,b", 'q"q']
    # the table goes on after a write, and columns read back across the spill
    spilled.append(i=25, x_m=0.5, kind="end")
    assert spilled.column("i").tolist() == list(range(26))
    assert np.allclose(spilled.column("x_m")[:23], np.arange(23) / 7)
    assert held.column("i").tolist() == list(range(25))


@pytest.mark.parametrize(("text", "says"), [
    (None, "unreadable truth table"),
    ("", "empty truth table"),
    ("# only a comment\n", "empty truth table"),
    ("a,b,c\n1,2,3\n4,5\n", "data row 2 has 2 values for 3 columns"),
    # an OverflowError traceback in `sisa process` (found by a bad-input sweep)
    ("a,t_ns\n1,2\n2,99999999999999999999\n", "data row 2: t_ns = 99999999999999999999 is "
     "beyond a 64-bit integer"),
])
def test_a_missing_empty_or_cut_truth_table_is_named(tmp_path: Path, text: str | None,
                                                     says: str) -> None:
    """Were FileNotFoundError / IndexError tracebacks in `sisa process` and `calibrate` (found
    by a bad-input sweep)."""
    path = tmp_path / "frames.csv"
    if text is not None:
        path.write_text(text)
    with pytest.raises(InputError, match=rf"frames\.csv: {says}"):
        read_truth_csv(path)


@pytest.mark.parametrize("spill_rows", [1_000_000, 5])
def test_a_table_cut_at_a_row_boundary_is_told_by_its_row_count(tmp_path: Path,
                                                                spill_rows: int) -> None:
    """A copy cut after a whole row read as a shorter table (found by a bad-input sweep): the
    header now declares the row count. A table without it (written before) reads as it is."""
    path = _table(spill_rows).write_csv(tmp_path)
    text = path.read_text()
    assert "# rows: 25\n" in text
    assert len(read_truth_csv(path)["i"]) == 25
    cut = text[:text.index("\n20,") + 1]  # rows 0-19: a whole number of rows
    path.write_text(cut)
    with pytest.raises(InputError, match=r"t\.csv: 20 data rows where its header says 25: the "
                                         r"truth table is cut or damaged"):
        read_truth_csv(path)
    path.write_text(cut.replace("# rows: 25\n", ""))
    assert len(read_truth_csv(path)["i"]) == 20
