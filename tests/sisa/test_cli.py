"""The `sisa` command as a user meets it: help with examples, one-line errors, exit codes."""

import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from sisa.cli import build_parser, main


def _subcommand_paths(parser, prefix=()):
    for action in parser._actions:
        if action.__class__.__name__ == "_SubParsersAction":
            for name, sub in action.choices.items():
                yield (*prefix, name)
                yield from _subcommand_paths(sub, (*prefix, name))


def test_top_level_help_shows_examples(capsys):
    with pytest.raises(SystemExit) as ok:
        main(["--help"])
    assert ok.value.code == 0
    assert "examples:" in capsys.readouterr().out


@pytest.mark.parametrize("path", list(_subcommand_paths(build_parser())))
def test_every_subcommand_help_shows_an_example(path, capsys):
    with pytest.raises(SystemExit) as ok:
        main([*path, "--help"])
    assert ok.value.code == 0
    out = capsys.readouterr().out
    assert "example:" in out
    assert "sisa " in out.split("example:")[1]


def test_bad_scenario_file_is_one_line_and_exit_2(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('base = "bench"\n[block]\nside_overlap_pct = 100\n')
    proc = subprocess.run([sys.executable, "-m", "sisa.cli", "scenario", "show", str(bad)],
                          capture_output=True, text=True, check=False)
    assert proc.returncode == 2
    assert proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1
    assert "block.side_overlap_pct" in lines[0]
    assert "less than 100" in lines[0]


@pytest.mark.parametrize(("argv", "said"), [
    (["ortho", "a.bil", "b.bil", "--out", "o.tif", "--crs", "abc"],
     "sisa ortho: error: argument --crs: invalid int value: 'abc'"),
    (["ortho"], "sisa ortho: error: the following arguments are required: IGM, IMAGE, --out"),
    (["frob"], "sisa: error: argument COMMAND: invalid choice: 'frob'"),
])
def test_a_usage_error_is_one_line_and_exit_2(argv, said, capsys):
    """As every other error: argparse's usage block came first (found by a bad-input sweep)."""
    with pytest.raises(SystemExit) as bad:
        main(argv)
    assert bad.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith(said)
    assert "--help` shows the usage" in err


def test_the_examples_in_the_help_keep_their_line_breaks(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    assert "--scanner runs/bench/scanner \\\n" in out
    assert "seg0_2m.tif" in out.split("segment_000.bil \\\n")[1].splitlines()[0]


@pytest.mark.parametrize(("table", "field"), [
    ('[block]\nground_speed_kmh = -5\n', "block.ground_speed_kmh"),
    ('[flight]\nbank = 3\n', "unknown field 'flight.bank'"),
])
def test_bad_values_exit_2(tmp_path, table, field, capsys):
    bad = tmp_path / "s.toml"
    bad.write_text(table)
    assert main(["scenario", "show", str(bad)]) == 2
    err = capsys.readouterr().err
    assert field in err
    assert err.count("\n") == 1


def test_schema_is_json_with_every_table(capsys):
    import json

    assert main(["scenario", "schema"]) == 0
    schema = json.loads(capsys.readouterr().out)
    for table in ("block", "flight", "terrain", "scanner", "ins", "gps", "mounting", "sisa",
                  "faults"):
        assert table in schema["properties"]


def _show(name, capsys):
    assert main(["scenario", "show", name]) == 0
    out = capsys.readouterr().out
    return tomllib.loads(out), out


def test_show_garrotxa_reports_the_seed_figures(capsys):
    table, _ = _show("garrotxa", capsys)
    d = table["derived"]
    assert abs(d["gsd_across_nadir_m"] / 3.5 - 1) < 0.10
    assert abs(d["line_spacing_along_m"] / 3.5 - 1) < 0.10
    assert d["strip_spacing_m"] == pytest.approx(d["swath_width_m"] / 2, abs=0.1)
    assert d["strips_flown"] == 14
    # 14 strips of 17.5 km at 263 km/h plus the 600 s alignment, climb and turns
    assert 14 * 17500 / (263 / 3.6) + 600 < d["flight_duration_s"] < 3 * 3600
    assert table["block"]["strips"] == 14


def test_show_bellmunt_reports_both_pixel_figures_and_says_so(capsys):
    table, out = _show("bellmunt", capsys)
    d = table["derived"]
    assert abs(d["gsd_across_nadir_m"] - 1.0) < 0.1
    assert d["line_spacing_along_m"] == pytest.approx(1.893, abs=0.001)
    assert "pixels are not square" in out
    assert d["strips_flown"] == 7


def test_show_bench_is_short(capsys):
    table, _ = _show("bench", capsys)
    assert table["derived"]["flight_duration_s"] <= 600


@pytest.mark.parametrize("name", ["bench", "garrotxa", "bellmunt"])
def test_a_shown_scenario_is_a_scenario_file_of_the_same_flight(name, tmp_path, capsys):
    """`sisa scenario show X > my.toml`, edited and flown, is what users do: its [derived]
    figures made the file 'unknown field derived' (found by a bad-input sweep)."""
    from emulators.scenario import load_scenario

    _, out = _show(name, capsys)
    saved = tmp_path / "mine.toml"
    saved.write_text(out, encoding="utf-8")
    assert load_scenario(saved) == load_scenario(name)
    assert main(["scenario", "show", str(saved)]) == 0
    assert capsys.readouterr().out.split("\n", 1)[1] == out.split("\n", 1)[1]


def test_truth_writes_a_whole_run_and_never_overwrites(tmp_path, capsys):
    import rasterio

    out = tmp_path / "run"
    assert main(["truth", "--preset", "bench", "--out", str(out)]) == 0
    for rel in ("scenario.toml", "truth/trajectory.csv", "truth/strips.csv", "truth/phases.csv",
                "terrain/dem.tif", "terrain/scene.tif", "terrain/scene.png",
                "terrain/ground_points.csv"):
        assert (out / rel).is_file(), rel
    with rasterio.open(out / "terrain" / "dem.tif") as dem:
        assert dem.crs.to_epsg() in (32631, None) or "UTM" in dem.crs.to_wkt()
        assert dem.read(1).std() > 1.0
    assert tomllib.loads((out / "scenario.toml").read_text())["block"]["name"] == "bench"
    before = sorted(p.name for p in out.rglob("*"))
    capsys.readouterr()
    assert main(["truth", "--preset", "bench", "--out", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert sorted(p.name for p in out.rglob("*")) == before
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no scratch left
    (out / "mine.txt").write_text("not the command's")
    assert main(["truth", "--preset", "bench", "--out", str(out), "--force"]) == 0
    assert sorted(p.name for p in out.rglob("*")) == before  # replaced whole
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


# Written as they happen, crash-safe: created exclusively, never replaced (not even --force)
NEVER_REPLACED = {("record",), ("emulate",), ("log", "recover")}


def _options(parser):
    return {s for a in parser._actions for s in a.option_strings}


def _parser_at(path):
    parser = build_parser()
    for name in path:
        sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
        parser = sub.choices[name]
    return parser


@pytest.mark.parametrize("path", [p for p in _subcommand_paths(build_parser())
                                  if "--out" in _options(_parser_at(p))
                                  or p == ("log", "recover")])
def test_every_command_that_writes_refuses_an_existing_output_or_takes_force(path):
    """One policy (issue 33, item 5): `sisa ortho` replaced its GeoTIFF silently while the
    others refused. Every output is refused if it exists; --force replaces it, whole."""
    options = _options(_parser_at(path))
    assert ("--force" in options) == (path not in NEVER_REPLACED), path


def test_truth_with_a_bad_scenario_writes_nothing(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[ins]\nrate_hz = 0\n")
    out = tmp_path / "run"
    assert main(["truth", "--scenario", str(bad), "--out", str(out)]) == 2
    assert not out.exists()


def test_truth_creates_missing_parent_folders(tmp_path):
    out = tmp_path / "runs" / "deeper" / "run"
    assert main(["truth", "--preset", "bench", "--out", str(out)]) == 0
    assert (out / "terrain" / "dem.tif").is_file()


def test_show_notes_header_settings_that_cannot_tie_lines(tmp_path, capsys):
    """A scanner at 625 lines/s with the default 12 ms header window: no header can be tied on
    time alone (docs/sync.md, Limits); with a narrow window but a slow read clock, headers
    arrive past its end, where the next frame's pulse is in their window. The bench preset's
    latest headers (11.06 ms: 3 ms latency, 1.56 ms on the wire at 115 200 baud, 1.5 ms USB, a
    5 ms read interval) miss its 10 ms window untied, which can cost no line its time."""
    table, out = _show("bench", capsys)
    notes = "".join(line for line in out.splitlines() if line.startswith("# note"))
    assert "outside sisa.header_window_ms" in notes
    assert "wrong" not in notes
    assert table["derived"]["header_late_by_max_ms"] == 11.062
    fast = tmp_path / "fast.toml"
    fast.write_text('base = "bench"\n[scanner]\nline_period_ms = 1.6\nintegration_time_ms = 1.2\n'
                    "header_latency_ms = [0.1, 0.3]\n", encoding="utf-8")
    table, out = _show(str(fast), capsys)
    assert table["derived"]["header_window_width_ms"] == 12.0
    assert "not narrower than a line period" in out
    narrow = tmp_path / "narrow.toml"
    narrow.write_text(fast.read_text(encoding="utf-8")
                      + "[sisa]\nheader_window_ms = [-0.2, 1.2]\nread_interval_ms = 5.0\n",
                      encoding="utf-8")
    table, out = _show(str(narrow), capsys)
    assert "not narrower than a line period" not in out
    assert table["derived"]["header_late_by_max_ms"] == 8.363
    assert "timed one line period wrong" in out


GC_PROBE = """
import gc, sys
from sisa.cli import main
code = main(sys.argv[1:], batch_gc=True)
print(code, *gc.get_threshold())
"""


@pytest.mark.parametrize(("argv", "batch"), [
    (["scenario", "show", "bench"], True),
    (["record", "--gps", "/nonexistent", "--scanner", "/nonexistent", "--ins",
      "slcan:/nonexistent", "--pulses", "127.0.0.1:1", "--out", "x.mcap"], False),
    (["emulate", "--preset", "no-such-preset", "--out", "x"], False),
])
def test_console_script_collects_less_often_in_batch_commands_only(argv, batch, tmp_path):
    """Batch commands start faster with fewer collections; a real-time loop keeps the
    interpreter's short pauses (the thresholds are set before the command runs)."""
    from sisa.cli import BATCH_GC_THRESHOLDS

    proc = subprocess.run([sys.executable, "-c", GC_PROBE, *argv], capture_output=True,
                          text=True, timeout=60, check=False, cwd=tmp_path)
    code, *thresholds = map(int, proc.stdout.split()[-4:])
    assert code == (0 if batch else 2), proc.stderr
    default = subprocess.run([sys.executable, "-c", "import gc; print(*gc.get_threshold())"],
                             capture_output=True, text=True, check=True).stdout.split()
    assert tuple(thresholds) == (BATCH_GC_THRESHOLDS if batch else tuple(map(int, default)))


def _read_all(master: int) -> bytes:
    """Everything written to a pty whose other side is closed (one read may return part)."""
    import os

    chunks = []
    while True:
        try:
            chunk = os.read(master, 65536)
        except OSError:  # EIO: the other side is closed and everything was read
            break
        if not chunk:
            break
        chunks.append(chunk)
    return b"".join(chunks)


def test_progress_bar_draws_on_a_terminal_stderr_and_never_on_stdout(monkeypatch, capsys):
    """`sisa georef` once drew its bar on stdout: a stray blank line before its summary when
    stdout was a file, and no bar at all. On a terminal: a bar with the count, rate and time
    left."""
    import os
    import pty

    from sisa.commands.progress import progress

    master, slave = pty.openpty()
    with os.fdopen(slave, "w") as tty:
        monkeypatch.setattr(sys, "stderr", tty)
        with progress("georef", "lines", unit="lines") as bar:
            bar.set_total(10)
            bar.advance(4)
            bar.advance(6)
    drawn = _read_all(master)
    os.close(master)
    assert b"lines" in drawn
    assert b"10/10 lines" in drawn
    assert capsys.readouterr().out == ""


def test_progress_when_piped_is_plain_timestamped_lines_every_few_seconds(monkeypatch):
    """Not a terminal (CI, logs, `| tee`): a line on stderr FIRST_LINE_S in, then every
    SISA_PROGRESS_S seconds, with the count, share, rate and time left (issue 33, item 1)."""
    import io
    import time

    from sisa.commands import progress as module

    monkeypatch.setenv(module.PERIOD_ENV, "0.2")
    monkeypatch.setattr(module, "FIRST_LINE_S", 0.1)
    monkeypatch.setattr(module, "MIN_RATE_S", 0.0)
    said = io.StringIO()
    bar = module.Progress("simulate", terminal=False, stream=said)
    bar.step("flight", 100.0, "s")
    for _ in range(10):
        bar.advance(5)
        time.sleep(0.06)
    bar.close()
    lines = said.getvalue().splitlines()
    assert len(lines) >= 2, lines
    for line in lines:
        assert re.fullmatch(r"\d\d:\d\d:\d\d sisa simulate: flight [\d.]+/100 s \(\d+%\), "
                            r"[\d.]+ s/s, \d+:\d\d left", line), line
    assert module.Progress("x", terminal=False, stream=said).line() == "sisa x: working (0:00)"
    monkeypatch.setenv(module.PERIOD_ENV, "off")
    quiet = io.StringIO()
    bar = module.Progress("simulate", terminal=False, stream=quiet)
    time.sleep(0.3)
    bar.close()
    assert quiet.getvalue() == ""


def test_record_status_names_the_file_as_shown_and_counts_disk_where_it_is(monkeypatch, tmp_path):
    """`sisa bench` records into a scratch folder renamed at the end; its status named the
    scratch path. The disk-free figure must still come from where the file is being written
    (the final folder does not exist yet)."""
    import os
    import pty

    from acquisition.runner import Acquisition
    from emulators.scenario import load_scenario
    from sisa.commands.record import _Status
    from sisa.wiring.acqconfig import acquisition_config

    acq = Acquisition(acquisition_config(load_scenario("bench")), lambda _m, _t: None,
                      lambda _e: None)
    (tmp_path / ".scratch").mkdir()
    master, slave = pty.openpty()
    with os.fdopen(slave, "w") as tty:
        monkeypatch.setattr(sys, "stderr", tty)
        status = _Status(acq, tmp_path / ".scratch" / "flight.mcap",
                         Path("runs/bench-7/flight.mcap"), quiet=False)  # short: one line
        status.show()
        status.close()
    drawn = _read_all(master).decode(errors="replace")
    os.close(master)
    assert "sisa record → runs/bench-7/flight.mcap" in re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", drawn)
    assert ".scratch" not in drawn
    assert "disk free" in drawn


def test_sigterm_cleans_up_like_ctrl_c(tmp_path):
    """`timeout`, batch schedulers and systemd stop a job with SIGTERM: it killed the process
    where it stood and left the half-made run folder behind; Ctrl-C removed it."""
    import signal
    import time

    proc = subprocess.Popen([sys.executable, "-m", "sisa.cli", "simulate", "--preset", "bench",
                             "--no-images", "--out", str(tmp_path / "sim")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not list(tmp_path.glob(".sim.partial-*")) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert list(tmp_path.glob(".sim.partial-*")), "the run never started"
    time.sleep(1.0)  # well into the flight
    proc.send_signal(signal.SIGTERM)
    _out, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1] == "sisa simulate: terminated", err
    assert list(tmp_path.iterdir()) == []


def test_own_warnings_are_one_line_and_others_keep_their_form(
        capsys: pytest.CaptureFixture[str]) -> None:
    """The console script says SISA's warnings as it says its errors; a library's warning
    keeps Python's form (file, line, category) so it can be traced."""
    from postproc.georef.dem import DemVoidWarning
    from postproc.georef.trajfiles import PartialRecordWarning
    from sisa.cli import _one_line_warning

    for category in (PartialRecordWarning, DemVoidWarning):
        _one_line_warning(category("a.out: cut"), category, "/x/trajfiles.py", 12)
        assert capsys.readouterr().err == "sisa: warning: a.out: cut\n"
    _one_line_warning(RuntimeWarning("overflow"), RuntimeWarning, "/x/lib.py", 7, line="f()")
    err = capsys.readouterr().err
    assert "/x/lib.py:7: RuntimeWarning: overflow" in err
    assert "f()" in err


def test_a_block_too_small_for_ground_points_is_said_and_flies_without_them(tmp_path, capsys):
    """A 50 m strip has no room for ground points: `scenario show` took it without a word and
    `truth` refused it even with no points asked for (found by a bad-input sweep)."""
    small = tmp_path / "small.toml"
    small.write_text('base = "bench"\n[block]\nstrip_length_m = 50.0\n', encoding="utf-8")
    _, out = _show(str(small), capsys)
    assert "# note: terrain: ground points need 81 m of margin" in out
    assert "(sisa truth and sisa simulate refuse this scenario)" in out
    assert main(["truth", "--scenario", str(small), "--out", str(tmp_path / "refused")]) == 2
    assert "ground points need 81 m of margin" in capsys.readouterr().err
    small.write_text(small.read_text() + "[terrain]\ncontrol_points = 0\ncheck_points = 0\n",
                     encoding="utf-8")
    _, out = _show(str(small), capsys)
    assert "# note: terrain" not in out
    assert main(["truth", "--scenario", str(small), "--out", str(tmp_path / "run")]) == 0
    assert "0 ground points" in capsys.readouterr().out


def test_a_warning_during_a_command_is_named_by_the_command(monkeypatch, capsys):
    """SISA's warnings said 'sisa: warning:' where its errors say 'sisa COMMAND: error:'
    (noticed in a bad-input sweep); after the command, a warning is the toolkit's again."""
    import warnings

    from postproc.georef.dem import DemVoidWarning
    from sisa import cli
    from sisa.commands import scenario

    def warns(_args):
        warnings.warn(DemVoidWarning("dem.tif: 3 cells hold -9999"), stacklevel=1)
        return 0

    monkeypatch.setattr(scenario, "_show", warns)
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        monkeypatch.setattr(warnings, "showwarning", cli._one_line_warning)
        assert cli.main(["scenario", "show", "bench"]) == 0
        assert capsys.readouterr().err == "sisa scenario: warning: dem.tif: 3 cells hold -9999\n"
        cli._one_line_warning(DemVoidWarning("x"), DemVoidWarning, "/x/dem.py", 1)
        assert capsys.readouterr().err == "sisa: warning: x\n"


def test_a_piped_simulate_shows_progress_while_it_flies(tmp_path):
    """`sisa simulate` printed nothing for its 49-62 s (issue 33, item 1). Piped: timestamped
    lines with the flight time flown, rate and time left, while it works."""
    import os
    import signal

    from tests.sisa.piped import PROGRESS_LINE, start, stderr_lines_until

    proc = start("simulate", "--preset", "bench", "--no-images", "--out", tmp_path / "run")
    try:
        lines = stderr_lines_until(proc, "sisa simulate: flight ", 120)
        lines += stderr_lines_until(proc, " s/s, ", 60)  # a rate once a second is flown
        assert proc.poll() is None
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
        proc.wait()
    for line in lines:
        assert re.match(PROGRESS_LINE.format(command="simulate"), line), line
    assert re.search(r"flight [\d.]+/549 s \(\d+%\), [\d.]+ s/s, \d+:\d\d left$", lines[-1])
    assert proc.returncode == 130
    assert err.endswith("sisa simulate: interrupted\n")
    assert not list(tmp_path.iterdir())  # nothing left, not even a scratch folder


@pytest.mark.parametrize("moment", ["importing", "terrain, DEM and ground points", "flight"])
def test_ctrl_c_stops_a_batch_command_at_any_moment_and_leaves_nothing(tmp_path, moment):
    """The one rule (issue 33, item 4), here for a command that computes its output: at any
    moment, exit 130, `interrupted` in one line, no traceback, nothing left (no output, no
    scratch folder). The moments are told by its progress lines."""
    import os
    import signal
    import time

    from tests.sisa.piped import start, stderr_lines_until

    proc = start("simulate", "--preset", "bench", "--no-images", "--out", tmp_path / "run",
                 period_s=0.05)
    try:
        if moment == "importing":
            time.sleep(0.15)
        else:
            stderr_lines_until(proc, f"sisa simulate: {moment}", 120)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == 130
    assert err.splitlines()[-1] == "sisa simulate: interrupted", err
    assert "Traceback" not in err, err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("path", list(_subcommand_paths(build_parser())))
def test_every_help_says_what_ctrl_c_does(path, capsys):
    with pytest.raises(SystemExit):
        main([*path, "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "Ctrl-C (or SIGTERM)" in out
    assert "exit 0" in out if path[0] in ("record", "emulate", "replay") else "exit 130" in out


def test_process_help_names_the_sensor_it_uses(capsys):
    """`sisa process --help` said --sensor defaults to "a nominal CASI-501 with zero offsets";
    it uses the run's scenario's sensor (issue 33, item 7). `sisa georef` keeps its own."""
    for command, says in (("process", "default: the run's scenario's sensor"),
                          ("georef", "default: a nominal CASI-501 with zero offsets")):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        assert says in " ".join(capsys.readouterr().out.split())
    with pytest.raises(SystemExit):
        main(["process", "--help"])
    assert "CASI-501" not in capsys.readouterr().out


def test_process_given_the_runs_flight_log_names_the_run_folder(tmp_path, capsys):
    """`sisa process runs/bench-demo/flight.mcap` said "no flight.mcap"."""
    run = tmp_path / "bench-demo"
    run.mkdir()
    (run / "flight.mcap").write_bytes(b"")
    (run / "scenario.toml").write_text("")
    assert main(["process", str(run / "flight.mcap")]) == 2
    assert capsys.readouterr().err == (
        f"sisa process: error: {run / 'flight.mcap'}: a file, not a run folder: give the folder "
        f"`sisa simulate` or `sisa bench` made (the run folder is {run})\n")


def test_record_status_headers_are_never_cut_in_an_80_column_terminal():
    """A column header showed as `expect…`."""
    from rich.console import Console

    from acquisition.runner import Acquisition
    from emulators.scenario import load_scenario
    from sisa.commands.record import _Status
    from sisa.wiring.acqconfig import acquisition_config

    acq = Acquisition(acquisition_config(load_scenario("bench")), lambda _m, _t: None,
                      lambda _e: None)
    status = _Status.__new__(_Status)  # the table alone, without a live display
    status.acq, status.out = acq, Path("/tmp/flight.mcap")
    status.shown_as = Path("runs/bench-rt/flight.mcap")
    console = Console(width=80, record=True)
    console.print(status._table())
    drawn = console.export_text()
    assert "…" not in drawn
    header = next(line for line in drawn.splitlines() if "stream" in line)
    for name in ("stream", "messages", "rate", "expected", "gaps", "errors", "drops", "late",
                 "link"):
        assert f" {name} " in header, header
    assert "rates in Hz" in drawn
def test_show_refuses_a_gps_port_that_cannot_carry_the_tags_and_warns_near_it(tmp_path, capsys):
    """Issue 32, item 1: 1 of 3 frame pulses to a receiver taking 25 events/s is 20.8 TTT tags a
    second; at 9600 baud (an Ashtech Z-12's) the port is ~99 % loaded (a note), at 4800 it
    cannot carry them (refused, one line, exit 2); at 115 200 it is 8 %."""
    fast = tmp_path / "fast.toml"
    fast.write_text('base = "bench"\n[sisa]\none_of_n = 3\n[gps]\nmax_event_rate_hz = 25.0\n')
    table, out = _show(str(fast), capsys)
    assert table["derived"]["gps_event_rate_hz"] == pytest.approx(20.8333)
    assert table["derived"]["gps_serial_load_pct"] == pytest.approx(8.3, abs=0.2)
    assert "serial port is" not in out
    slow = tmp_path / "slow.toml"
    slow.write_text(fast.read_text() + "serial_baud = 9600\n")
    table, out = _show(str(slow), capsys)
    assert table["derived"]["gps_serial_load_pct"] == pytest.approx(99.0, abs=0.2)
    assert "# note: the receiver's serial port is 99.0% loaded" in out
    slow.write_text(fast.read_text() + "serial_baud = 4800\n")
    assert main(["scenario", "show", str(slow)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "gps.serial_baud: 4800 baud carries 480 bytes a second" in err


def test_show_says_when_the_sync_unit_holds_pulses_back_or_the_ins_loses_them(tmp_path, capsys):
    many = tmp_path / "many.toml"
    many.write_text('base = "bench"\n[sisa]\none_of_n = 1\n[gps]\nmax_event_rate_hz = 40.0\n')
    _, out = _show(str(many), capsys)
    assert "the sync unit holds them to 40 a second" in out
    assert "more than half the INS record rate" in out


def test_the_sentence_sizes_the_port_load_counts_are_what_the_codec_writes():
    from acquisition.nmea import (
        FixQuality,
        ModeIndicator,
        encode,
        gga_from_fix,
        ptt_from_gps_ns,
        rmc_from_fix,
        ttt_from_gps_ns,
        zda_from_gps_ns,
    )
    from emulators.scenario import GGA_BYTES, RMC_BYTES, TAG_BYTES, ZDA_BYTES

    t = 1_465_549_200 * 10**9 + 123_456_789
    assert len(encode(gga_from_fix(t, 18, -41.6, -179.0, 29_650.0, -120.0,
                                   FixQuality.RTK_FIXED, 12, 99.9))) <= GGA_BYTES
    assert len(encode(rmc_from_fix(t, 18, -41.6, -179.0, 999.0, 359.9,
                                   ModeIndicator.RTK_FIXED))) <= RMC_BYTES
    assert len(encode(zda_from_gps_ns(t, 18))) <= ZDA_BYTES
    assert len(encode(ptt_from_gps_ns(t))) == len(encode(ttt_from_gps_ns(t))) == TAG_BYTES
