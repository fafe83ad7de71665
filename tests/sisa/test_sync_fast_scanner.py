"""A scanner faster than the sync filter's header window (line period 0.11 ms against the
12 ms default window, docs/sync.md 'Limits'): no frame header is tied to its pulse, every line
is no_pulses, and `sisa sync` said only the counts. It now says why, in one warning (and in
sync_report.json's notes); `georef` (and `process`) in the one line of their error, `calibrate`
in a warning before its own."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest

from postproc.sync.report import frames_untied, untied_frames_note
from sisa.cli import main

FAST = """base = "bench"
[block]
strips = 1
strip_length_m = 100.0
flying_height_agl_m = 150.0
[flight]
static_alignment_s = 10.0
figure_eights = 0
run_in_s = 1.0
[terrain]
margin_m = 300.0
control_points = 1
check_points = 0
[scanner]
line_period_ms = 0.11
integration_time_ms = 0.05
"""


@pytest.fixture(scope="module")
def fast_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """~2 min of flight, one 100 m strip at 9091 lines/s (~10 s to simulate, with images for
    georef); the log keeps the window it was recorded with."""
    root = tmp_path_factory.mktemp("fast")
    (root / "fast.toml").write_text(FAST)
    assert main(["simulate", "--scenario", str(root / "fast.toml"), "--out", str(root / "run")]
                ) == 0
    return root / "run"


def _sync(flight: Path, out: Path, capsys: pytest.CaptureFixture[str]
          ) -> tuple[str, dict[str, Any]]:
    assert main(["sync", str(flight), "--out", str(out)]) == 3  # finished, no line timed
    captured = capsys.readouterr()
    assert "scan lines flagged: no_pulses" in captured.out
    err, losses = captured.err.rsplit("sisa sync: finished with losses: ", 1)
    assert losses.endswith(" scan lines not timed (exit code 3)\n")
    return err, json.loads((out / "sync_report.json").read_text())


def test_sync_says_the_header_window_is_wider_than_a_line_period(
        fast_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    capsys.readouterr()  # the fixture's simulate
    err, report = _sync(fast_run / "flight.mcap", tmp_path / "sync", capsys)
    lines = report["lines"]
    assert lines["status"] == {"no_pulses": lines["lines"]}
    assert lines["frame_pulses_forwarded"] > 0
    assert lines["frame_pulses_with_counter"] == 0
    assert lines["header_line_period_ns"] == pytest.approx(110_000, rel=0.02)
    said = err.splitlines()
    assert len(said) == 1, err
    assert said[0].startswith(f"sisa sync: warning: {lines['lines']} scan lines not timed "
                              "(no_pulses): none of the ")
    assert ("the header window (sisa.header_window_ms [-2, 10] as flight.mcap was recorded:"
            " 12 ms wide) is not narrower than the scanner's line period (0.11 ms, from the "
            "frame headers)") in said[0]
    assert "set sisa.header_window_ms (and sisa.read_interval_ms) narrower" in said[0]
    assert report["notes"] == [said[0].removeprefix("sisa sync: warning: ")]


def test_the_log_carries_its_window(fast_run: Path, tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    """The flight log alone, away from its run folder, still names the window it was
    recorded with: the recorder keeps it in the log's metadata."""
    (tmp_path / "log").mkdir()
    shutil.copy(fast_run / "flight.mcap", tmp_path / "log" / "flight.mcap")
    capsys.readouterr()
    err, _ = _sync(tmp_path / "log" / "flight.mcap", tmp_path / "sync", capsys)
    assert "(sisa.header_window_ms [-2, 10] as flight.mcap was recorded: 12 ms wide)" in err


def test_a_log_without_its_settings_names_the_default_window(
        fast_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A log recorded before the settings were kept: the period from the headers, and the
    window the recorder has by default, said as such."""
    import recorder.parts

    monkeypatch.setattr(recorder.parts, "recording_metadata", lambda _path: {})
    capsys.readouterr()
    err, _ = _sync(fast_run / "flight.mcap", tmp_path / "sync", capsys)
    said = err.splitlines()
    assert len(said) == 1, err
    assert ("the frame headers show a line period of 0.11 ms; a header window not narrower "
            "(sisa.header_window_ms; the default [-2, 10] is 12 ms wide)") in said[0]


WHY = ("the header window (sisa.header_window_ms [-2, 10] as flight.mcap was recorded: 12 ms "
       "wide) is not narrower than the scanner's line period (0.11 ms, from the frame headers)")


def test_georef_says_why_no_line_is_timed(fast_run: Path, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    """It failed with "no scan line could be put on GPS time (sync: 15151 no pulses)"."""
    capsys.readouterr()
    assert main(["georef", str(fast_run / "flight.mcap"), "--scanner", str(fast_run / "scanner"),
                 "--dem", str(fast_run / "terrain" / "dem.tif"),
                 "--out", str(tmp_path / "geo")]) != 0
    said = capsys.readouterr().err.splitlines()
    assert len(said) == 1, said
    assert said[0].startswith("sisa georef: error: nothing to georeference: ")
    assert "scan lines not timed (no_pulses)" in said[0]
    assert WHY in said[0]
    assert not (tmp_path / "geo").exists()


def test_calibrate_warns_why_its_observations_are_left_out(
        fast_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    capsys.readouterr()
    assert main(["calibrate", str(fast_run), "--out", str(tmp_path / "cal")]) != 0
    said = capsys.readouterr().err.splitlines()
    assert len(said) == 2, said
    assert said[0].startswith("sisa calibrate: warning: ")
    assert WHY in said[0]
    assert said[1].startswith("sisa calibrate: error: ")


def _lines(forwarded: int, named: int, no_pulses: int, period_ns: float | None) -> dict[str, Any]:
    return {"frame_pulses_forwarded": forwarded, "frame_pulses_with_counter": named,
            "header_line_period_ns": period_ns,
            "status": {"no_pulses": no_pulses} if no_pulses else {"ok": 10}}


def test_the_note_blames_the_window_only_when_it_is_the_cause() -> None:
    assert not frames_untied(_lines(5, 1, 100, 110_000.0))  # one frame named: lines timed
    assert not frames_untied(_lines(0, 0, 100, 110_000.0))  # no frame pulse at all
    assert not frames_untied(_lines(5, 0, 0, 110_000.0))
    assert frames_untied(_lines(5, 0, 100, 16e6))
    # a 16 ms scanner and a 12 ms window: something else (lost or late headers); not guessed
    note = untied_frames_note(_lines(5, 0, 100, 16e6), (-2.0, 10.0), "as flight.mcap was recorded")
    assert note == ("100 scan lines not timed (no_pulses): none of the 5 forwarded frame pulses "
                    "carries its frame counter (no frame header was tied to its pulse; "
                    "docs/sync.md, Limits)")
    assert "not narrower" in untied_frames_note(_lines(5, 0, 100, 12.4e6), (-2.0, 10.0), None)
