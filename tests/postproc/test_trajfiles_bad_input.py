"""Bad trajectory files (postproc.georef.trajfiles) found by a bad-input sweep of `sisa georef
--trajectory`: each is one clear line (file, line or record, field), never a traceback, a
misplaced blame or a silently wrong IGM.

- `.pos`: a 20-digit Q or ns (int64 overflow), Q 1.5, Q or ns out of RTKLIB's range; second 99
  or 60 (blamed on the next line before); a time of week past the week's end;
- a single impossible fix (`.pos` and SBET): a jump in position or height no aircraft flies;
- SBET attitude out of range (roll, pitch, platform heading, wander angle);
- an empty or binary file named `.pos`, read as an SBET: said so, with the SBET's field names.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from emulators.scenario import load_scenario
from emulators.trajectory import TruthTrajectory
from postproc.georef.trajfiles import read_rtklib_pos, read_sbet, read_trajectory_file
from sisa.core.errors import InputError
from sisa.core.timescale import NS_PER_S
from tests.postproc.test_navigation import G_B, SYN, T0_NS, wgs84_ecef
from tests.postproc.test_trajectory_coverage import (
    _antenna,
    georef,
    write_truth_pos,
    write_truth_sbet,
)
from tests.postproc.test_trajectory_coverage import (  # noqa: F401 (its fixture, by name)
    run as coverage_run,
)
from tests.postproc.test_trajfiles import FIRST, SBET_T, T_POS, antenna_llh, write_pos, write_sbet

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

BAD_LINE = FIRST + 1 + 3  # the 1-based line of the 4th solution, the one edited (26)


def _edit_solution(path: Path, k: int, col: int, change: Callable[[str], str]) -> int:
    """Column `col` of the k-th solution line changed; returns that line's number."""
    lines = path.read_text(encoding="utf-8").splitlines()
    at = [i for i, ln in enumerate(lines) if ln.strip() and not ln.startswith("%")][k]
    tok = lines[at].split()
    tok[col] = change(tok[col])
    lines[at] = " ".join(tok)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return at + 1


def _pos(tmp_path: Path, n: int = 8, **kw: Any) -> Path:
    path = tmp_path / "bad.pos"
    write_pos(path, T_POS[:n], antenna_llh(T_POS[:n]), np.ones(n, dtype=np.int64), **kw)
    return path


def _refused(path: Path, message: str, **kw: Any) -> None:
    with pytest.raises(InputError, match=message) as err:
        read_rtklib_pos(path, **kw)
    assert "\n" not in str(err.value)


# --- .pos: Q, ns and the time fields ----------------------------------------------------------

@pytest.mark.parametrize(("col", "value", "message"), [
    (5, "99999999999999999999",
     r"Q \(solution quality\) '99999999999999999999' is not a whole number 1 to 6"),
    (6, "99999999999999999999",
     r"ns \(satellites\) '99999999999999999999' is not a whole number 0 to 255"),
    (5, "1.5", r"Q \(solution quality\) '1\.5' is not a whole number 1 to 6"),
    (5, "0", r"Q \(solution quality\) '0' is not a whole number 1 to 6"),
    (5, "7", r"Q \(solution quality\) '7' is not a whole number 1 to 6"),
    (6, "-3", r"ns \(satellites\) '-3' is not a whole number 0 to 255"),
    (6, "256", r"ns \(satellites\) '256' is not a whole number 0 to 255"),
])
def test_q_and_ns_are_whole_numbers_in_range(tmp_path: Path, col: int, value: str,
                                             message: str) -> None:
    path = _pos(tmp_path)
    _edit_solution(path, 3, col, lambda _: value)
    _refused(path, rf"bad\.pos:{BAD_LINE}: {message}$")


@pytest.mark.parametrize(("second", "message"), [
    ("99", r"time of day '09:00:99\.600': second 99 is not 0 to 59"),
    ("60", r"time of day '09:00:60\.600': second 60 is not 0 to 59 \(RTKLIB never writes a "
           r"leap second :60\)"),
])
def test_a_second_past_59_is_blamed_on_its_own_line(tmp_path: Path, second: str,
                                                     message: str) -> None:
    """It ran into the next minute, and the next line was blamed: 'time does not increase'."""
    path = _pos(tmp_path)
    _edit_solution(path, 3, 1, lambda clock: clock[:6] + second + clock[8:])
    _refused(path, rf"bad\.pos:{BAD_LINE}: {message}")


def test_a_time_of_week_past_the_week_is_blamed_on_its_own_line(tmp_path: Path) -> None:
    path = _pos(tmp_path, week_tow=True)
    _edit_solution(path, 3, 1, lambda _: "604800.500")
    _refused(path, rf"bad\.pos:{BAD_LINE}: time of week 604800\.500 s is not 0 to 604800 s")


# --- one impossible fix -----------------------------------------------------------------------

@pytest.mark.parametrize(("col", "change", "message"), [
    (2, lambda v: f"{float(v) + 1.0:.9f}",  # latitude + 1°: 111 km in 0.2 s
     r"the position jumps 111 km in 0\.2 s from the fix before \(555,\d{3} m/s; an aircraft "
     r"flies < 400 m/s\): a bad fix\?$"),
    (3, lambda _: "359.000000000",  # longitude 359° (−1°) on a flight at 2°
     r"the position jumps 2\d\d km in 0\.2 s from the fix before \(1,\d{3},\d{3} m/s;"),
    (4, lambda v: f"{float(v) + 50_000:.4f}",
     r"the height changes 50 km in 0\.2 s from the fix before \(250,000 m/s; an aircraft "
     r"climbs or descends < 100 m/s\): a bad fix\?$"),
])
def test_one_impossible_pos_fix_is_refused(tmp_path: Path, col: int, change: Any,
                                           message: str) -> None:
    path = _pos(tmp_path)
    _edit_solution(path, 3, col, change)
    _refused(path, rf"bad\.pos:{BAD_LINE}: {message}")


def test_one_impossible_ecef_fix_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "bad.pos"
    t = T_POS[:8]
    write_pos(path, t, wgs84_ecef(*antenna_llh(t).T), np.ones(8, np.int64), layout="xyz")
    _edit_solution(path, 3, 2, lambda v: f"{float(v) + 3000.0:.4f}")
    # x + 3 km at 41.6° N, 2° E: 1.98 km across, 2.24 km up
    _refused(path, rf"bad\.pos:{BAD_LINE}: the position jumps 1\.98 km in 0\.2 s")


@pytest.mark.parametrize(("t_s", "llh", "q"), [
    ([0.0, 3600.0, 5400.0],  # gaps: 200 km in an hour, then 300 km in half an hour
     [[41.6, 2.0, 300.0], [43.4, 2.0, 300.0], [41.6, 4.0, 300.0]], [1, 1, 1]),
    ([0.0, 0.2, 0.4, 0.6],  # the antimeridian crossed at 110 m/s
     [[0.0, 179.9999, 1000.0], [0.0, -179.9999, 1000.0], [0.0, -179.9997, 1000.0],
      [0.0, -179.9995, 1000.0]], [1, 1, 1, 1]),
    ([0.0, 0.2, 0.4, 0.6],  # a single-point solution 55 m off across, 60 m up
     [[41.6, 2.0, 300.0], [41.6002, 2.0002, 300.0], [41.6009, 2.0002, 360.0],
      [41.6006, 2.0006, 300.0]], [1, 1, 5, 1]),
])
def test_what_an_aircraft_does_is_not_refused(tmp_path: Path, t_s: list[float],
                                              llh: list[list[float]], q: list[int]) -> None:
    t = T_POS[0] + np.rint(np.array(t_s) * NS_PER_S).astype(np.int64)
    write_pos(tmp_path / "ok.pos", t, np.array(llh), np.array(q))
    np.testing.assert_allclose(read_rtklib_pos(tmp_path / "ok.pos").ecef_m,
                               wgs84_ecef(*np.array(llh).T), rtol=0, atol=1e-3)


@pytest.mark.parametrize(("field", "change", "message"), [
    (1, lambda v: v + 0.01,
     r"the position jumps 63\.\d km in 0\.005 s from the fix before \(12,\d{3},\d{3} m/s; an "
     r"aircraft flies < 400 m/s\): a bad fix\?$"),
    (3, lambda v: v + 5000.0,
     r"the height changes 5 km in 0\.005 s from the fix before \(1,000,000 m/s; an aircraft "
     r"climbs or descends < 100 m/s\)"),
    # attitude out of its range (gave a wrong IGM, or 'no pixel could be georeferenced')
    (7, lambda _: 1e300, r"roll 1e\+300 rad outside -3\.14159 to 3\.14159 rad$"),
    (7, lambda _: -3.2, r"roll -3\.2 rad outside -3\.14159 to 3\.14159 rad$"),
    (8, lambda _: 1e10, r"pitch 1e\+10 rad outside -1\.5708 to 1\.5708 rad$"),
    (9, lambda _: 1e300, r"platform heading 1e\+300 rad outside -6\.28319 to 6\.28319 rad$"),
    (10, lambda _: -1e300, r"wander angle -1e\+300 rad outside -6\.28319 to 6\.28319 rad$"),
])
def test_one_impossible_sbet_record_is_refused(tmp_path: Path, field: int, change: Any,
                                               message: str) -> None:
    path = tmp_path / "sbet.out"
    write_sbet(path, SBET_T[:400])
    table = np.fromfile(path, "<f8").reshape(-1, 17)
    table[100, field] = change(table[100, field])
    table.tofile(path)
    with pytest.raises(InputError, match=rf"sbet\.out: record 100: {message}") as err:
        read_sbet(path, T0_NS)
    assert "\n" not in str(err.value)


# --- a binary or empty `.pos`: read as an SBET, and said so -----------------------------------

SNIFFED = r"\.pos \(read as an Applanix SBET: binary, not RTKLIB text\): "


@pytest.fixture(scope="module")
def synthetic() -> Any:
    return SYN.columns()


def test_an_empty_pos_says_it_was_read_as_an_sbet(tmp_path: Path, synthetic: Any) -> None:
    (tmp_path / "empty.pos").write_bytes(b"")
    with pytest.raises(InputError, match=rf"empty{SNIFFED}0 bytes is not a whole number of "
                                         "136-byte SBET records"):
        read_trajectory_file(tmp_path / "empty.pos", *synthetic, antenna_offset_m=G_B)


def test_a_binary_pos_names_the_sbet_field_in_words(tmp_path: Path, synthetic: Any) -> None:
    write_sbet(tmp_path / "nav.pos", SBET_T[:400])
    table = np.fromfile(tmp_path / "nav.pos", "<f8").reshape(-1, 17)
    table[1, 14] = np.nan
    table.tofile(tmp_path / "nav.pos")
    with pytest.raises(InputError, match=rf"nav{SNIFFED}record 1 \(byte 136\): x angular rate "
                                         r"\(rad/s\) is not finite$"):
        read_trajectory_file(tmp_path / "nav.pos", *synthetic, antenna_offset_m=G_B)


# --- the command line: exit 2, one line -------------------------------------------------------

@pytest.fixture(scope="module")
def run(request: pytest.FixtureRequest) -> Path:
    """The tiny simulated run of test_trajectory_coverage (simulated once per session)."""
    path: Path = request.getfixturevalue("coverage_run")
    return path


@pytest.fixture(scope="module")
def truth(run: Path) -> TruthTrajectory:
    return TruthTrajectory.from_scenario(load_scenario(run / "scenario.toml"))


def _jumping_pos(path: Path, run: Path, truth: TruthTrajectory) -> str:
    write_truth_pos(path, truth, _antenna(run), truth.t_start_ns + NS_PER_S, truth.t_end_ns)
    line = _edit_solution(path, 30, 2, lambda v: f"{float(v) + 1.0:.9f}")
    return rf"jump\.pos:{line}: the position jumps 111 km in 1 s from the fix before"


def _spinning_sbet(path: Path, run: Path, truth: TruthTrajectory) -> str:
    write_truth_sbet(path, truth, truth.t_start_ns + NS_PER_S, truth.t_end_ns)
    table = np.fromfile(path, "<f8").reshape(-1, 17)
    table[1234, 9] = 1e300
    table.tofile(path)
    return r"spin\.out: record 1234: platform heading 1e\+300 rad outside"


def _empty_pos(path: Path, run: Path, truth: TruthTrajectory) -> str:
    path.write_bytes(b"")
    return rf"empty{SNIFFED}0 bytes"


@pytest.mark.parametrize(("name", "make"), [
    ("jump.pos", _jumping_pos), ("spin.out", _spinning_sbet), ("empty.pos", _empty_pos)])
def test_georef_with_a_bad_trajectory_exits_2_with_one_line(
        run: Path, truth: TruthTrajectory, tmp_path: Path, capsys: pytest.CaptureFixture[str],
        name: str, make: Callable[[Path, Path, TruthTrajectory], str]) -> None:
    message = make(tmp_path / name, run, truth)
    rc, out, err = georef(run, tmp_path / "geo", capsys, "--trajectory", tmp_path / name)
    assert rc == 2
    assert out == ""
    line, = err.splitlines()
    assert line.startswith("sisa georef: error: ")
    assert re.search(message, line), line
    assert not (tmp_path / "geo").exists()
