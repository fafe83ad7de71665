"""Post-processing says when the recorder counted problems while recording: decode errors,
drops, late edges or disconnects mean the log may hold less than the devices sent, and `sync`,
`georef`/`process` and `calibrate` said nothing of it (it was in `/sisa/health` alone)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from sisa.cli import main

SCENARIO = """base = "bench"
[block]
strips = 1
strip_length_m = 300.0
[flight]
static_alignment_s = 10.0
figure_eights = 0
run_in_s = 1.0
[terrain]
margin_m = 300.0
control_points = 1
check_points = 0
"""
FAULTS = """[faults]
corrupt_byte_rate = 0.0005
lost_can_frame_fraction = 0.01
"""


def _simulate(root: Path, text: str, *options: str) -> Path:
    root.mkdir()
    (root / "s.toml").write_text(text)
    assert main(["simulate", "--scenario", str(root / "s.toml"), "--out", str(root / "run"),
                 *options]) == 0
    return root / "run"


@pytest.fixture(scope="module")
def faulty(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """~3 min of flight, one short strip, bytes corrupted and CAN frames lost on the wires."""
    return _simulate(tmp_path_factory.mktemp("health") / "faulty", SCENARIO + FAULTS)


def _counted(run: Path, capsys: pytest.CaptureFixture[str]) -> str:
    """What `log info --json` says the recorder counted, as the notes phrase it."""
    capsys.readouterr()
    assert main(["log", "info", "--json", str(run / "flight.mcap")]) == 0
    problems = json.loads(capsys.readouterr().out)["health"]["problems"]
    assert any("decode error" in p for p in problems), problems
    assert any("drop" in p for p in problems), problems
    return ", ".join(problems)


def test_sync_says_what_the_recorder_counted(faulty: Path, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    counted = _counted(faulty, capsys)
    assert main(["sync", str(faulty / "flight.mcap"), "--out", str(tmp_path / "s")]) == 0
    err = capsys.readouterr().err.splitlines()
    note = (f"the recorder counted {counted} while recording flight.mcap: records or lines may "
            f"be missing for it (per stream: sisa log info {faulty / 'flight.mcap'})")
    notes = json.loads((tmp_path / "s" / "sync_report.json").read_text())["notes"]
    # corrupt bytes cost frame headers too: without --scanner their gaps make the header-order
    # line numbers unsure from there on, and that is said as well (after the recorder's note)
    assert notes[0] == note
    assert len(notes) == 2
    assert notes[1].startswith("lines numbered by frame-header order")
    assert err == [f"sisa sync: warning: {n}" for n in notes]


def test_process_puts_it_in_the_summary_and_the_report(faulty: Path,
                                                        capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    counted = _counted(faulty, capsys)
    assert main(["process", str(faulty)]) == 0
    assert f"sisa process: warning: the recorder counted {counted} " in capsys.readouterr().err
    summary = json.loads((faulty / "process" / "georef_summary.json").read_text())
    assert sum(w.startswith(f"the recorder counted {counted} ") for w in summary["warnings"]) == 1
    report = (faulty / "process" / "report.html").read_text()
    assert f"the recorder counted {counted} " in report  # the warning
    assert f"<h2>Recording</h2><p>The recorder counted: {counted}.</p>" in report  # its table
    assert summary["recording_health"]["problems"] == counted.split(", ")
    ins = summary["recording_health"]["streams"]["ins"]
    assert ins["drops"] > 0
    assert ins["messages"] == summary["ins_records"]  # the records the log holds


def test_calibrate_warns_of_it(faulty: Path, tmp_path: Path,
                               capsys: pytest.CaptureFixture[str]) -> None:
    counted = _counted(faulty, capsys)
    main(["calibrate", str(faulty), "--out", str(tmp_path / "cal")])  # one control point
    assert (f"sisa calibrate: warning: the recorder counted {counted} "
            in capsys.readouterr().err)


def test_a_clean_recording_gets_no_such_note(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    run = _simulate(tmp_path / "clean", SCENARIO, "--no-images")
    capsys.readouterr()
    assert main(["sync", str(run / "flight.mcap"), "--out", str(tmp_path / "s")]) == 0
    assert "recorder counted" not in capsys.readouterr().err
