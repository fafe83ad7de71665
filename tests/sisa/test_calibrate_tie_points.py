"""`sisa calibrate --tie-points N` had no upper bound: 10^9 or 10^12 ended in numpy's
MemoryError traceback (6·N candidate points drawn at once), and ~10^6 would exhaust the memory
before a word was said. It is bounded like the other options, before any work."""

from __future__ import annotations

from pathlib import Path

import pytest

from sisa.cli import main
from sisa.commands.calibrate import TIE_POINTS_MAX


@pytest.mark.parametrize("n", [10**9, 10**12, TIE_POINTS_MAX + 1])
def test_too_many_tie_points_is_a_one_line_error(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                 n: int) -> None:
    """The check comes before the run is read: an empty folder is enough to see it (a missing
    one is said first, before any import)."""
    (tmp_path / "run").mkdir()
    out = tmp_path / "cal"
    assert main(["calibrate", str(tmp_path / "run"), "--out", str(out),
                 "--tie-points", str(n)]) == 2
    err = capsys.readouterr().err
    assert err == (f"sisa calibrate: error: --tie-points {n}: must be 0 to {TIE_POINTS_MAX} (tie "
                   "points beyond it add little to the adjustment; each costs ~110 kB and "
                   "~1.3 ms to simulate)\n")
    assert not out.exists()


@pytest.mark.parametrize(("n", "expected"), [
    (TIE_POINTS_MAX, "no flight.mcap: not a run folder"),  # the limit itself is allowed
    (-1, "--tie-points, --blunders and --single-view-control must be ≥ 0"),
])
def test_the_limit_is_allowed_and_a_negative_count_keeps_its_error(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], n: int, expected: str) -> None:
    (tmp_path / "run").mkdir()
    assert main(["calibrate", str(tmp_path / "run"), "--out", str(tmp_path / "cal"),
                 f"--tie-points={n}"]) == 2
    err = capsys.readouterr().err
    assert expected in err
    assert err.count("\n") == 1
