"""Real-time runs say what they will fly before they fly it (issue 33, item 2): `sisa bench
--preset bench --duration 30` exited 0 with `frame headers 0` and `sisa process` then failed;
strip 0 starts ~346 s in, and the help's own example ended before it. `sisa bench` and `sisa
emulate` print the flight's timeline, take --strip N, warn when their window holds no imaging,
and the examples in their help record imagery."""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from emulators.scenario import load_scenario
from emulators.trajectory import TruthTrajectory
from sisa.cli import build_parser, main
from sisa.commands.emulate import (
    MODE1_BEFORE_S,
    STRIP_LEAD_S,
    STRIP_TAIL_S,
    check_span,
    imaging_warning,
    timeline,
)


@pytest.fixture(scope="module")
def bench() -> tuple[object, TruthTrajectory]:
    scn = load_scenario("bench")
    return scn, TruthTrajectory.from_scenario(scn)


def _span(args: str, traj: TruthTrajectory, scn: object) -> argparse.Namespace:
    ns = build_parser().parse_args(["bench", "--out", "x", *shlex.split(args)])
    check_span(scn, traj, ns)  # type: ignore[arg-type]
    return ns


def _seconds(ns: int, traj: TruthTrajectory) -> float:
    return (ns - traj.t_start_ns) / 1e9


def test_strip_n_starts_before_the_strip_and_ends_after_it(bench) -> None:
    scn, traj = bench
    for strip in traj.strips:
        ns = _span(f"--strip {strip.index}", traj, scn)
        a, b = _seconds(strip.t_start_ns, traj), _seconds(strip.t_end_ns, traj)
        assert ns.start == pytest.approx(a - STRIP_LEAD_S)
        assert ns.start + ns.duration == pytest.approx(min(b + STRIP_TAIL_S, traj.duration_s))
        assert imaging_warning(traj, ns.start, ns.duration) is None
    ns = _span("--strip 1 --duration 40", traj, scn)  # a --duration given is kept
    assert ns.duration == 40


@pytest.mark.parametrize(("args", "says"), [
    ("--strip 2", "--strip 2: the bench flight has strips 0 to 1"),
    ("--strip -1", "--strip -1: the bench flight has strips 0 to 1"),
    ("--strip 0 --start 10", "--strip N sets the start: give --strip or --start, not both"),
])
def test_a_strip_that_is_not_there_is_one_line(args: str, says: str,
                                               capsys: pytest.CaptureFixture[str],
                                               tmp_path: Path) -> None:
    for command in ("bench", "emulate"):
        assert main([command, "--out", str(tmp_path / "run"), *shlex.split(args)]) == 2
        err = capsys.readouterr().err
        assert err == f"sisa {command}: error: {says}\n"
    assert not list(tmp_path.iterdir())


def test_the_timeline_gives_every_strip_and_what_the_run_holds(bench) -> None:
    scn, traj = bench
    lines = timeline(scn, traj, 0.0, 30.0)  # type: ignore[arg-type]
    assert lines[0] == "timeline of bench (549 s; --start counts from 0):"
    assert "     0-60 s  static alignment (engines off)" in lines
    assert "  346-396 s  strip 0 (--strip 0 starts at 311 s)" in lines
    assert "  489-539 s  strip 1 (--strip 1 starts at 454 s)" in lines
    assert lines[-1] == "this run: 0-30 s, no strip"
    assert timeline(scn, traj, 311.0, 90.0)[-1] == "this run: 311-401 s, strip 0"  # type: ignore[arg-type]
    assert timeline(scn, traj, 300.0, None)[-1] == "this run: 300-549 s, strips 0, 1"  # type: ignore[arg-type]


def test_a_window_without_imaging_is_warned_of(bench) -> None:
    _, traj = bench
    said = imaging_warning(traj, 0.0, 30.0)
    assert said is not None
    assert said.startswith("this run (0-30 s of the flight) holds no strip: the scanner records "
                           "no image")
    assert said.endswith("strip 0 is at 346-396 s (--strip 0)")
    assert "strip 1 is at 489-539 s (--strip 1)" in (imaging_warning(traj, 400.0, 60.0) or "")
    inside = imaging_warning(traj, 351.0, 5.0)  # inside strip 0: no scanner-off block before
    assert inside is not None
    assert f"needs about {MODE1_BEFORE_S:g} s of scanner-off" in inside
    assert imaging_warning(traj, 320.0, 60.0) is None  # the README's desk run


def _example(command: str) -> str:
    parser = build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    epilog = sub.choices[command].epilog or ""
    return epilog.split("example:\n", 1)[1].splitlines()[0].strip().split("   (")[0]


@pytest.mark.parametrize("command", ["bench", "emulate"])
def test_the_help_examples_fly_a_strip(command: str, bench) -> None:
    """The help's own `--duration 120` example ended before any strip."""
    scn, traj = bench
    words = shlex.split(_example(command))
    assert words[:2] == ["sisa", command]
    ns = build_parser().parse_args(words[1:])
    check_span(scn, traj, ns)  # type: ignore[arg-type]
    assert imaging_warning(traj, ns.start, ns.duration) is None
    assert not timeline(scn, traj, ns.start, ns.duration)[-1].endswith("no strip")  # type: ignore[arg-type]


def test_emulate_prints_the_timeline_and_warns_of_no_imaging(tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "sisa.cli", "emulate", "--out",
                           str(tmp_path / "emu"), "--duration", "1", "--no-images"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "  346-396 s  strip 0 (--strip 0 starts at 311 s)\n" in proc.stdout
    assert "this run: 0-1 s, no strip\n" in proc.stdout
    assert ("sisa emulate: warning: this run (0-1 s of the flight) holds no strip: the scanner "
            "records no image") in proc.stderr
