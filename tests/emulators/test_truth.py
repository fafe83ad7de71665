"""Truth tables spill to a temporary file past `spill_rows` and write the same CSV as if held."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from emulators.truth import TruthTable, read_truth_csv
from sisa.errors import InputError


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
