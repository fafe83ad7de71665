"""End to end on a short error-free flight: simulate → sync → georeference → products → report.
With no navigation errors, every pixel must land where the emulator's own forward model (a
different ray caster in a different frame) says it looked."""

import hashlib
import json
import re
import shutil
import subprocess
import sys
from html.parser import HTMLParser

import numpy as np
import pytest
import rasterio
from PIL import Image

from tests.recorder import overwrite_middle

SHORT_ERROR_FREE = """
base = "bench"
[block]
strip_length_m = 1200.0
[flight]
static_alignment_s = 40.0
"""


def _sisa(*args, check=True):
    proc = subprocess.run([sys.executable, "-m", "sisa.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=600)
    if check:
        assert proc.returncode == 0, proc.stderr
    return proc


@pytest.fixture(scope="module")
def processed(tmp_path_factory):
    root = tmp_path_factory.mktemp("process")
    scn = root / "short.toml"
    scn.write_text(SHORT_ERROR_FREE, encoding="utf-8")
    _sisa("simulate", "--scenario", scn, "--error-free", "--out", root / "run")
    out = _sisa("process", root / "run").stdout
    return root / "run", root / "run" / "process", out


def test_every_pixel_within_a_hundredth_of_a_pixel(processed):
    _, out, stdout = processed
    acc = json.loads((out / "accuracy.json").read_text())
    pixels = acc["pixels"]
    assert pixels["pixels"] > 500 * 512
    for comp in ("along", "across", "height"):
        assert pixels[comp]["max_abs_px"] < 0.01, (comp, pixels[comp])
    assert acc["check_points"]["points"] >= 3
    for comp in ("along", "across", "height"):
        assert acc["check_points"][comp]["max_abs_px"] < 0.01
    assert "report:" in stdout
    assert "every pixel vs truth" in stdout
    _time_split_adds_up(stdout)


def _time_split_adds_up(stdout: str) -> None:
    """Issue 38: where the time goes, by step; the steps sum to the total."""
    head = re.search(r"^  time ([\d.]+) s, CPU (\d+) % of a core:$", stdout, re.M)
    assert head is not None, stdout
    steps = dict(re.findall(r"^    (\S.*?)\s+([\d.]+) s  CPU +\d+ %$", stdout, re.M))
    for step in ("reading the flight log and synchronising", "georeferencing",
                 "ortho, mosaic, footprints", "accuracy against truth", "report"):
        assert step in steps, stdout
    assert abs(sum(map(float, steps.values())) - float(head.group(1))) < 0.1 * len(steps)


# the IGM and the geolocation VRT have geolocation arrays, no geotransform: by design
@pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")
def test_products_are_read_by_gdal(processed):
    _, out, _ = processed
    summary = json.loads((out / "georef_summary.json").read_text())
    assert summary["segments"]
    for seg in summary["segments"]:
        for key in ("igm", "ortho", "glt", "geolocation_vrt"):
            with rasterio.open(out / seg["files"][key]) as ds:
                assert ds.width > 0
                assert ds.height > 0
        with rasterio.open(out / seg["files"]["ortho"]) as ds:
            assert ds.crs.to_epsg() == int(summary["crs"].split(":")[1])
            band = ds.read(1, masked=True)
            assert 0.2 < band.count() / band.size <= 1.0  # a swath, with nodata around it
    with rasterio.open(out / "mosaic.tif") as ds:
        assert ds.nodata is not None
        assert np.ma.count(ds.read(1, masked=True)) > 0
    features = json.loads((out / "footprints.geojson").read_text())["features"]
    assert len(features) == len(summary["segments"])


def test_report_has_every_section(processed):
    _, out, _ = processed
    page = (out / "report.html").read_text()
    for title in ("Trajectory and footprints", "Attitude", "Time synchronisation",
                  "Ground accuracy against truth", "Ortho mosaic"):
        assert title in page
    assert page.count("data:image/png;base64,") >= 5


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
# After the page has loaded, every image's decoded size goes into the DOM that --dump-dom prints.
PROBE = ("<script>window.addEventListener('load', () => document.body.setAttribute("
         "'data-probe', JSON.stringify([...document.images].map("
         "i => [i.complete, i.naturalWidth, i.naturalHeight]))));</script>")
UNIT = re.compile(r"\S.*\(([^()]+)\)$")  # "roll (°)", "time since ... GPS (min)"


def _chromium(tmp_path, *args):
    if CHROMIUM is None:
        pytest.fail("headless Chromium is needed to check the report (Debian: apt-get install "
                    "chromium)")
    proc = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu",
                           "--hide-scrollbars", f"--user-data-dir={tmp_path / 'profile'}", *args],
                          capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout


class _Page(HTMLParser):
    """The figures' axes labels, the archive record's terms and the input files' rows."""

    def __init__(self):
        super().__init__()
        self.figures, self.terms, self.files, self.probe = [], [], [], None
        self._in, self._row, self._text = None, None, []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "img":
            self.figures.append((a.get("alt", ""), json.loads(a.get("data-axes") or "null")))
        if tag == "body" and "data-probe" in a:
            self.probe = json.loads(a["data-probe"])
        if tag in ("dt", "td"):
            self._in, self._text = tag, []
        if tag == "tr":
            self._row = []

    def handle_data(self, data):
        if self._in:
            self._text.append(data)

    def handle_endtag(self, tag):
        if tag == self._in:
            text = "".join(self._text).strip()
            (self.terms if tag == "dt" else self._row).append(text)
            self._in = None
        if tag == "tr" and self._row and re.fullmatch(r"[0-9a-f]{64}", self._row[-1]):
            self.files.append(self._row)


def test_the_report_renders_in_headless_chromium_with_its_archive_record(processed, tmp_path):
    """Issue 33, item 9: the page renders (every image decodes, the screenshot is not blank);
    every plot has labelled axes with units (read from the figures' own labels, kept in the
    page); one time axis for all plots against time; heading within ±180°; the archive record
    (date, software, command, input files with sizes and checksums, flight and strip times,
    sensor file); the mosaic on a map grid with its band legend; the latch residuals
    explained."""
    run, out, _ = processed
    page_path = out / "report.html"
    page = page_path.read_text(encoding="utf-8")
    probe = tmp_path / "probe.html"
    probe.write_text(page.replace("</body>", PROBE + "</body>"), encoding="utf-8")
    dom = _Page()
    dom.feed(_chromium(tmp_path, "--dump-dom", probe.as_uri()))
    assert dom.probe, "the page did not finish loading"
    assert all(done and w > 100 and h > 100 for done, w, h in dom.probe), dom.probe
    assert len(dom.probe) == len(dom.figures) >= 5
    times = set()
    for alt, axes in dom.figures:
        assert alt
        assert axes, alt
        for ax in axes:
            for key in ("x", "y"):
                assert UNIT.match(ax[key]), (alt, ax)
            if "time since" in ax["x"]:
                times.add(ax["x"])
    assert len(times) == 1, times  # attitude and sync on one axis
    assert {"made", "software", "command", "flight (navigation)", "time axis of the plots",
            "sensor file"} <= set(dom.terms)
    assert "sisa process " in page
    shown = {row[0]: row for row in dom.files}
    for name in ("flight.mcap", "scenario.toml", "terrain/dem.tif", "scanner/segment_000.bil"):
        data = (run / name).read_bytes()
        assert shown[name][1:] == [str(len(data)), hashlib.sha256(data).hexdigest()], name
    summary = json.loads((out / "georef_summary.json").read_text())
    assert page.count("(week ") >= 2 * len(summary["segments"]) + 1  # strips' first/last, flight
    assert "[scanner]" in page  # the sensor file's TOML
    assert "of gated PPS (ns)" in page
    assert "Why the latch residuals" in page
    mosaic = next(axes for alt, axes in dom.figures if alt.startswith("Ortho mosaic"))
    assert mosaic[0]["x"] == f"easting, {summary['crs']} (km)"
    assert "red: band " in page
    shot = tmp_path / "shot.png"
    _chromium(tmp_path, f"--screenshot={shot}", "--window-size=1200,7000", page_path.as_uri())
    pixels = np.asarray(Image.open(shot).convert("RGB"), dtype=np.int16)
    assert pixels.shape == (7000, 1200, 3)
    inked = np.any(pixels < 200, axis=2)
    assert inked.mean() > 0.03  # text, tables and plots, not a blank page
    assert len(np.unique(pixels.reshape(-1, 3)[::97], axis=0)) > 200  # plots and the mosaic


def test_heading_is_drawn_within_180_degrees_without_wrap_lines():
    from postproc.georef.report import heading_pm180

    heading, at = heading_pm180(np.radians([350.0, 10.0, 170.0, 190.0, 200.0]))
    np.testing.assert_allclose(heading[:3], [-10.0, 10.0, 170.0])
    assert np.isnan(heading[3])  # a break, not a line across the plot
    np.testing.assert_allclose(heading[4:], [-170.0, -160.0])
    assert at.tolist() == [3]


def test_an_existing_output_is_refused_and_left_alone(processed):
    run, out, _ = processed
    before = sorted(p.name for p in out.iterdir())
    proc = _sisa("process", run, check=False)
    assert proc.returncode == 2
    assert "already exists" in proc.stderr
    assert proc.stderr.count("\n") == 1
    assert sorted(p.name for p in out.iterdir()) == before


def _copy_run(run, dest):
    """The run without its products, to be damaged and processed again."""
    shutil.copytree(run, dest, ignore=shutil.ignore_patterns("process"))
    return dest


def test_an_image_cut_short_is_processed_over_the_lines_it_holds(processed, tmp_path):
    """A copy of the run whose first image lost its second half (a copy interrupted): the
    lines it holds are georeferenced and judged against truth, the rest said to be missing.
    (The accuracy report indexed truth by the header's line count and crashed.)"""
    run, _, _ = processed
    cut = _copy_run(run, tmp_path / "run")
    image = cut / "scanner" / "segment_000.bil"
    whole = image.stat().st_size
    with open(image, "r+b") as f:
        f.truncate(whole // 2 + 777)  # mid-line
    proc = _sisa("process", cut, check=False)
    # the headline counts against what the inputs promised (the header's and lines file's
    # lines), not what the cut file holds ("4345/4345 lines georeferenced" while 1905 were
    # lost), and the exit code says so (issue 33, item 6)
    assert proc.returncode == 3, proc.stderr
    listed = sum(len([r for r in (run / "scanner" / f"segment_{s:03d}.lines.csv").read_text()
                      .splitlines() if r[:1].isdigit()]) for s in (0, 1))
    held = json.loads((cut / "process" / "georef_summary.json").read_text())["segments"]
    geo = sum(s["lines_georeferenced"] for s in held)
    assert geo < listed
    assert f", {geo}/{listed} lines georeferenced, " in proc.stdout, proc.stdout
    assert proc.stderr.endswith(f"sisa process: finished with losses: {listed - geo} of "
                                f"{listed} scan lines not georeferenced (exit code 3)\n")
    said = [line for line in proc.stderr.splitlines() if "cut short" in line]
    # once, by the georeferencing (the ortho said it again, naming the hidden staging folder)
    assert len(said) == 1, proc.stderr
    assert said[0].startswith("sisa process: warning: segment 0: segment_000.bil is cut short")
    acc = json.loads((cut / "process" / "accuracy.json").read_text())
    full = json.loads((run / "process" / "accuracy.json").read_text())
    assert 0 < acc["pixels"]["pixels"] < full["pixels"]["pixels"]
    for comp in ("along", "across", "height"):
        assert acc["pixels"][comp]["max_abs_px"] < 0.01, (comp, acc["pixels"][comp])


@pytest.mark.parametrize(("removed", "says"), [
    ("truth", "no such folder: no accuracy against truth"),
    ("terrain/ground_points.csv", "no such file: no check points"),
])
def test_accuracy_the_run_cannot_give_is_said(processed, tmp_path, removed, says):
    """Without truth/ (or the ground points) the headline's accuracy lines were left out
    without a word (found by a bad-input sweep)."""
    run, _, _ = processed
    copy = _copy_run(run, tmp_path / "run")
    shutil.rmtree(copy / removed) if (copy / removed).is_dir() else (copy / removed).unlink()
    proc = _sisa("process", copy, "--no-products")
    warning, = proc.stderr.splitlines()
    assert warning == f"sisa process: warning: {copy / removed}: {says}"
    assert ("every pixel vs truth" in proc.stdout) == (removed != "truth")
    assert "check points, RMS" not in proc.stdout


def test_a_scenario_edited_after_the_run_is_refused(processed, tmp_path):
    """The truth is rebuilt from RUN/scenario.toml: one that no longer describes the run (here
    moved 11 m north) judged the run against another flight, silently (found by a bad-input
    sweep: 8 px for another seed, 393 278 px for another latitude)."""
    run, _, _ = processed
    copy = _copy_run(run, tmp_path / "run")
    toml = copy / "scenario.toml"
    text = toml.read_text()
    assert "centre_lat_deg = 41.6\n" in text
    toml.write_text(text.replace("centre_lat_deg = 41.6\n", "centre_lat_deg = 41.6001\n"))
    proc = _sisa("process", copy, "--no-products", check=False)
    assert proc.returncode == 2, proc.stderr
    error, = proc.stderr.splitlines()
    assert error.startswith(f"sisa process: error: {toml}: the flight it describes passes 11.1 m "
                            "(median over ")
    assert error.endswith("not the scenario this run was made from (edited after the run?)")
    assert not (copy / "process").exists()


def test_a_damaged_log_is_processed_and_the_damage_said_in_the_report(processed, tmp_path):
    """20 kB overwritten in the middle of the log: the run is processed from the rest, and the
    skipped chunk is said once on stderr, in the summary and in the report."""
    run, _, _ = processed
    bad = _copy_run(run, tmp_path / "run")
    log = overwrite_middle(run / "flight.mcap", bad / "flight.mcap", seed=3)
    proc = _sisa("process", bad, check=False)
    assert proc.returncode == 0, proc.stderr
    said = [line for line in proc.stderr.splitlines() if "damaged chunk" in line]
    assert len(said) == 1, proc.stderr
    assert said[0].startswith(f"sisa process: warning: {log}: ")
    note = said[0].removeprefix("sisa process: warning: ")
    summary = json.loads((bad / "process" / "georef_summary.json").read_text())
    assert note in summary["warnings"]
    page = (bad / "process" / "report.html").read_text()
    assert "<h2>Warnings</h2>" in page
    assert "damaged chunk" in page


@pytest.mark.parametrize(("name", "text", "says"), [
    ("terrain/ground_points.csv", "", "ground_points.csv"),
    ("terrain/ground_points.csv", "a,b,c\n1,2\nxyz\n", "ground_points.csv"),
    ("truth/frames.csv", "frame,t\n1\n", "frames.csv: data row 1 has 1 values for 2 columns"),
    ("scenario.toml", 'base = "garrotxa"\n', "not the scenario this run was made from"),
])
def test_a_damaged_table_of_the_run_is_one_line_naming_it(processed, tmp_path, name, text,
                                                          says):
    """Were IndexError / ValueError tracebacks after the georeferencing (found by a bad-input
    sweep); check points now come from the reader `sisa calibrate` uses."""
    run, _, _ = processed
    bad = _copy_run(run, tmp_path / "run")
    (bad / name).write_text(text)
    proc = _sisa("process", bad, check=False)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert lines[-1].startswith("sisa process: error: "), proc.stderr
    assert says in lines[-1], proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (bad / "process").exists()


def test_sync_of_a_log_cut_short_counts_against_the_scanners_lines_and_exits_3(processed,
                                                                               tmp_path):
    """`sisa sync` of a truncated log exited 0 with `scan lines 0/6250 timed` (issue 33, item
    6): complete is 0, finished with losses 3 (said on stderr), failed 1 or 2."""
    run, _, _ = processed
    whole = run / "flight.mcap"
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole.read_bytes()[:whole.stat().st_size // 3])
    listed = sum(len([r for r in (run / "scanner" / f"segment_{s:03d}.lines.csv").read_text()
                      .splitlines() if r[:1].isdigit()]) for s in (0, 1))
    proc = _sisa("sync", cut, "--scanner", run / "scanner", "--out", tmp_path / "s", check=False)
    assert proc.returncode == 3, proc.stderr
    got = re.search(r"scan lines (\d+)/(\d+) timed", proc.stdout)
    assert got is not None, proc.stdout
    timed = int(got[1])
    assert int(got[2]) == listed
    assert timed < listed
    assert proc.stderr.splitlines()[-1].startswith("sisa sync: finished with losses: ")
    assert f"{listed - timed} of {listed} scan lines" in proc.stderr.splitlines()[-1]
    assert proc.stderr.endswith(" not timed (exit code 3)\n")
    complete = _sisa("sync", whole, "--scanner", run / "scanner", "--out", tmp_path / "w")
    assert f"scan lines {listed}/{listed} timed" in complete.stdout  # and exit 0 (checked)


def test_sync_says_the_lines_its_lines_files_leave_out(processed, tmp_path):
    """`sisa sync --scanner` read only the lines files: one holding its header alone, or cut
    short, left a segment or lines untimed without a word, where georef warned (found by a
    bad-input sweep)."""
    run, _, _ = processed
    scanner = shutil.copytree(run / "scanner", tmp_path / "scanner")
    for seg, keep in ((0, 0), (1, 100)):
        lines_csv = scanner / f"segment_{seg:03d}.lines.csv"
        rows = lines_csv.read_text().splitlines(keepends=True)
        data_at = next(i for i, r in enumerate(rows) if r.startswith("line_index"))
        lines_csv.write_text("".join(rows[:data_at + 1 + keep]))
    proc = _sisa("sync", run / "flight.mcap", "--scanner", scanner, "--out", tmp_path / "s",
                 check=False)
    assert proc.returncode == 3, proc.stderr  # lines the log's frame headers promised: untimed
    assert "  scan lines not in the scanner's files: " in proc.stdout
    said = [line for line in proc.stderr.splitlines() if line.startswith("sisa sync: warning:")]
    assert said[0] == (f"sisa sync: warning: {scanner / 'segment_000.bil'}: its lines file "
                       "lists no line: not timed")
    assert said[1].startswith(f"sisa sync: warning: {scanner / 'segment_001.bil'}: its lines "
                              "file lists 100 of its ")
    assert said[1].endswith("have no frame counter: not timed")
    report = json.loads((tmp_path / "s" / "sync_report.json").read_text())
    assert report["notes"] == [w.removeprefix("sisa sync: warning: ") for w in said]


def test_two_lines_claiming_one_frame_are_neither_timed(processed, tmp_path):
    """A lines file listing a frame counter twice gave both lines the frame's time, flagged ok
    (found by a bad-input sweep): which line the frame was is unknown, so both are ambiguous,
    and every other line keeps its time."""
    run, _, _ = processed
    scanner = shutil.copytree(run / "scanner", tmp_path / "scanner")
    lines_csv = scanner / "segment_000.lines.csv"
    rows = lines_csv.read_text().splitlines(keepends=True)
    at = next(i for i, r in enumerate(rows) if r.startswith("line_index")) + 1
    counter_10 = rows[at + 10].split(",")[1]
    rows[at + 11] = f"11,{counter_10}"
    lines_csv.write_text("".join(rows))
    _sisa("sync", run / "flight.mcap", "--scanner", run / "scanner", "--out", tmp_path / "a")
    assert _sisa("sync", run / "flight.mcap", "--scanner", scanner, "--out", tmp_path / "b",
                 check=False).returncode == 3  # two lines not timed

    def table(folder):
        text = (folder / "line_times.csv").read_text().splitlines()
        return [r.split(",") for r in text if r[:1].isdigit()]

    whole, twice = table(tmp_path / "a"), table(tmp_path / "b")
    assert [r[4] for r in twice[10:12]] == ["ambiguous", "ambiguous"]
    assert [r[3] for r in twice[10:12]] == ["-1", "-1"]
    assert twice[:10] + twice[12:] == whole[:10] + whole[12:]
    assert whole[10][4] == whole[11][4] == "ok"


def test_lines_the_lines_file_does_not_list_are_said_to_be_left_out(processed, tmp_path):
    """A lines file cut short (or holding only its header) left lines, or a whole segment, out
    of the products without a word (found by a bad-input sweep)."""
    run, _, _ = processed
    cut = _copy_run(run, tmp_path / "run")
    lines_csv = cut / "scanner" / "segment_000.lines.csv"
    rows = lines_csv.read_text().splitlines(keepends=True)
    data_at = next(i for i, r in enumerate(rows) if r.startswith("line_index"))
    lines_csv.write_text("".join(rows[:data_at + 101]))
    proc = _sisa("process", cut, check=False)
    assert proc.returncode == 3, proc.stderr  # the image's lines, promised, not all made
    assert "segment_000.bil: its lines file lists 100 of its" in proc.stderr
    assert "have no frame counter: not georeferenced" in proc.stderr
    summary = json.loads((cut / "process" / "georef_summary.json").read_text())
    assert any("lists 100 of its" in w for w in summary["warnings"])


def test_a_piped_process_shows_progress_while_it_works(processed, tmp_path):
    """Piped (CI, logs, `| tee`), `sisa process` printed only at the end (issue 33, item 1):
    plain timestamped lines on stderr every few seconds, during the work."""
    import os
    import signal

    from tests.sisa.piped import PROGRESS_LINE, start, stderr_lines_until

    run, _, _ = processed
    proc = start("process", run, "--out", tmp_path / "again")
    try:
        lines = stderr_lines_until(proc, "sisa process: georeferencing ", 120)
        assert proc.poll() is None  # while it works
        progress = [x for x in lines if re.match(PROGRESS_LINE.format(command="process"), x)]
        assert progress == lines, lines  # stderr holds progress lines only, so far
        assert re.search(r"georeferencing \d+/\d+ lines \(\d+%\)", lines[-1]), lines[-1]
        os.killpg(proc.pid, signal.SIGINT)  # enough seen: Ctrl-C
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == 130
    assert err.endswith("sisa process: interrupted\n"), err
    assert not (tmp_path / "again").exists()
    assert not list(tmp_path.iterdir())


def test_a_ctrl_c_that_c_code_loses_is_raised_again(processed, tmp_path, monkeypatch):
    """A Ctrl-C that came while numpy formatted the EO table was lost in numpy's loop: the run
    finished with exit 0 and its outputs in place (found by a loop of Ctrl-Cs at random
    moments; CI saw the same run die of SIGINT at exit). Lost here on purpose, the stop must
    still end the command with 130 and nothing kept."""
    import os
    import signal
    import time

    import postproc.georef.exterior as exterior
    from sisa.cli import main

    write_rows = exterior._write_rows
    swallowed = []

    def losing_the_interrupt(fh, columns):
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(5)  # the handler runs here
        except KeyboardInterrupt:
            swallowed.append(True)  # as C code that clears the error did
        write_rows(fh, columns)

    monkeypatch.setattr(exterior, "_write_rows", losing_the_interrupt)
    run, _, _ = processed
    assert main(["process", str(run), "--out", str(tmp_path / "again")]) == 130
    assert swallowed
    assert not list(tmp_path.iterdir())
