"""A trajectory that covers only part of the flight, and the files and messages around it.

On a tiny simulated run (two short strips, simulated once per session, shared by the xdist
workers), with trajectory files written here from the run's truth:

- an SBET of strip 0 only, a `.pos` that ends inside strip 1, a log cut between the strips:
  what is covered is georeferenced, what is not is said per segment (stderr, summary), exit 0;
- an SBET of another day: one line giving both time spans, exit 2;
- a `.pos` on UTC: the leap seconds come from the log's receiver messages, the products are
  those of the same `.pos` on GPST; a 1 Hz SBET needs, and takes, `--max-gap-s`.

And without a run (the synthetic flight of test_navigation): a `.pos` whose comments are not
ASCII (UTF-8, Latin-1, a BOM, UTF-16) is read as a `.pos`, not as an SBET; the leap seconds
read from a log's NMEA bytes.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from acquisition.nmea import FixQuality, encode, gga_from_fix, ptt_from_gps_ns, zda_from_gps_ns
from emulators.scenario import load_scenario
from emulators.trajectory import TruthTrajectory
from postproc.georef import ecef_to_geodetic
from postproc.georef.trajfiles import read_trajectory_file, sbet_trajectory
from recorder.messages import Topic
from sisa.cli import main
from sisa.core.errors import InputError
from sisa.core.frames import body_to_ned_matrix, ned_to_ecef_matrix
from sisa.core.timescale import NS_PER_DAY, NS_PER_S, NS_PER_WEEK
from tests.exitcodes import INCOMPLETE, without_losses_line
from tests.postproc import simulated_once
from tests.postproc.test_navigation import G_B, SYN, T0_NS
from tests.postproc.test_trajfiles import T_POS, antenna_llh, write_pos, write_sbet

TINY = """base = "bench"
seed = 5
[block]
strip_length_m = 300.0
flying_height_agl_m = 250.0
[flight]
static_alignment_s = 15.0
figure_eights = 0
climb_rate_mps = 20.0
turn_bank_deg = 45.0
run_in_s = 3.0
takeoff_acceleration_mps2 = 5.0
airfield_offset_m = [-300.0, -1200.0]
[terrain]
margin_m = 400.0
control_points = 4
check_points = 4
"""
LEAP_S = 18  # the bench preset's


# --- the run, once per session -----------------------------------------------------------------

@pytest.fixture(scope="session")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny run, simulated once per session."""
    return simulated_once(tmp_path_factory, "trajectory-coverage-run", TINY)


@pytest.fixture(scope="session")
def truth(run: Path) -> TruthTrajectory:
    return TruthTrajectory.from_scenario(load_scenario(run / "scenario.toml"))


def georef(run: Path, out: Path, capsys: pytest.CaptureFixture[str], *extra: str | Path
           ) -> tuple[int, str, str]:
    capsys.readouterr()
    rc = main(["georef", str(run / "flight.mcap"), "--scanner", str(run / "scanner"),
               "--dem", str(run / "terrain" / "dem.tif"), "--out", str(out), "--no-products",
               *map(str, extra)])
    got = capsys.readouterr()
    return rc, got.out, got.err


def igm(out: Path, segment: int) -> np.ndarray:
    """(3, lines, pixels) easting, northing, height of the segment's IGM."""
    hdr = (out / f"segment_{segment:03d}_igm.hdr").read_text()
    fields = dict(line.split("=", 1) for line in hdr.splitlines() if "=" in line)
    lines, pixels = int(fields["lines "]), int(fields["samples "])
    data = np.fromfile(out / f"segment_{segment:03d}_igm.bil", "<f8")
    return data.reshape(lines, 3, pixels).transpose(1, 0, 2)


def summary(out: Path) -> dict[str, Any]:
    return json.loads((out / "georef_summary.json").read_text())


def _truth_table(truth: TruthTrajectory, t0: int, t1: int, step_ns: int
                 ) -> tuple[np.ndarray, Any]:
    t = np.arange(t0, t1 + 1, step_ns, dtype=np.int64)
    return t, truth.state(t)


def write_truth_sbet(path: Path, truth: TruthTrajectory, t0: int, t1: int, *,
                     step_ns: int = NS_PER_S // 200, shift_ns: int = 0) -> None:
    """An SBET of the INS centre from the truth (wander angle 0), on [t0, t1]; `shift_ns` moves
    its seconds of week (another day)."""
    t, s = _truth_table(truth, t0, t1, step_ns)
    z = np.zeros(t.size)
    table = np.column_stack([((t + shift_ns) % NS_PER_WEEK) / NS_PER_S, np.radians(s.lat_deg),
                             np.radians(s.lon_deg), s.height_m, s.vel_ned_mps[:, 0],
                             s.vel_ned_mps[:, 1], -s.vel_ned_mps[:, 2], s.roll_rad, s.pitch_rad,
                             np.angle(np.exp(1j * s.heading_rad)), z, z, z, z, *s.body_rate_rps.T])
    table.astype("<f8").tofile(path)


def write_truth_pos(path: Path, truth: TruthTrajectory, antenna_b: np.ndarray, t0: int, t1: int,
                    *, scale: str = "GPST") -> None:
    """An RTKLIB .pos of the true antenna phase centre at 1 Hz on [t0, t1] (UTC: the times
    written LEAP_S earlier)."""
    t0 = -(-t0 // NS_PER_S) * NS_PER_S
    t, s = _truth_table(truth, t0, t1, NS_PER_S)
    r_eb = (ned_to_ecef_matrix(np.radians(s.lat_deg), np.radians(s.lon_deg))
            @ body_to_ned_matrix(s.roll_rad, s.pitch_rad, s.heading_rad))
    lat, lon, h = ecef_to_geodetic(s.ecef_m + r_eb @ antenna_b)
    written = t - (LEAP_S * NS_PER_S if scale == "UTC" else 0)
    write_pos(path, written, np.column_stack([lat, lon, h]), np.ones(t.size, np.int64),
              scale=f"{scale:<4}")


def _antenna(run: Path) -> np.ndarray:
    return np.asarray(load_scenario(run / "scenario.toml").mounting.antenna_offset_m)


# --- fault 1: partial coverage ----------------------------------------------------------------

@pytest.fixture(scope="session")
def full_sbet(run: Path, truth: TruthTrajectory, tmp_path_factory: pytest.TempPathFactory
              ) -> Path:
    """The products with an SBET of the whole flight (the reference)."""
    root = tmp_path_factory.mktemp("full")
    write_truth_sbet(root / "full.out", truth, truth.t_start_ns + NS_PER_S, truth.t_end_ns)
    assert main(["georef", str(run / "flight.mcap"), "--scanner", str(run / "scanner"),
                 "--dem", str(run / "terrain" / "dem.tif"), "--out", str(root / "geo"),
                 "--no-products", "--trajectory", str(root / "full.out")]) == 0
    return root / "geo"


def test_a_fully_covering_trajectory_skips_nothing(full_sbet: Path) -> None:
    s = summary(full_sbet)
    assert [seg["segment"] for seg in s["segments"]] == [0, 1]
    assert all(seg["lines_georeferenced"] == seg["lines"] for seg in s["segments"])
    assert s["skipped"] == []
    assert s["warnings"] == []
    assert s["trajectory"]["format"] == "Applanix SBET"


def test_sbet_of_strip_0_georeferences_strip_0_and_skips_strip_1(
        run: Path, truth: TruthTrajectory, full_sbet: Path, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    strip = truth.strips[0]
    write_truth_sbet(tmp_path / "strip0.out", truth, strip.t_start_ns - 3 * NS_PER_S,
                     strip.t_end_ns + 3 * NS_PER_S)
    rc, out, err = georef(run, tmp_path / "geo", capsys, "--trajectory", tmp_path / "strip0.out")
    assert rc == INCOMPLETE, err  # lines promised, not all made
    err = without_losses_line(err)
    warning, = err.splitlines()
    assert warning.startswith("sisa georef: warning: segment 1: skipped")
    assert "strip0.out" in warning
    assert warning.count(" GPS (week ") == 2  # the lines' span and the trajectory's
    assert "1 of 2 segments (1 skipped), " in out
    s = summary(tmp_path / "geo")
    assert [seg["segment"] for seg in s["segments"]] == [0]
    assert s["segments"][0]["lines_georeferenced"] == s["segments"][0]["lines"]
    skip, = s["skipped"]
    assert (skip["segment"], skip["whole_segment"], skip["reason"]) == (1, True, "no pose")
    assert skip["spans"][0]["t_first_gps_ns"] > s["trajectory"]["t_last_gps_ns"]
    assert s["warnings"] == [skip["message"]]
    assert not (tmp_path / "geo" / "segment_001_igm.bil").exists()
    np.testing.assert_allclose(igm(tmp_path / "geo", 0), igm(full_sbet, 0), rtol=0, atol=1e-3)


def test_pos_ending_inside_strip_1_georeferences_the_lines_it_covers(
        run: Path, truth: TruthTrajectory, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    strip = truth.strips[1]
    end = (strip.t_start_ns + strip.t_end_ns) // 2
    write_truth_pos(tmp_path / "part.pos", truth, _antenna(run), truth.t_start_ns, end)
    rc, _, err = georef(run, tmp_path / "geo", capsys, "--trajectory", tmp_path / "part.pos")
    assert rc == INCOMPLETE, err  # lines promised, not all made
    err = without_losses_line(err)
    warning, = err.splitlines()
    assert "segment 1: " in warning
    assert "lines not georeferenced, no pose (lines " in warning
    s = summary(tmp_path / "geo")
    seg0, seg1 = s["segments"]
    assert seg0["lines_georeferenced"] == seg0["lines"]
    skip, = s["skipped"]
    assert not skip["whole_segment"]
    assert 0 < skip["lines_skipped"] < seg1["lines"]
    assert seg1["lines_georeferenced"] == seg1["lines"] - skip["lines_skipped"]
    span, = skip["spans"]
    assert span["last_line"] == seg1["lines"] - 1
    last_fix = end // NS_PER_S * NS_PER_S
    assert 0 < span["t_first_gps_ns"] - last_fix < 20_000_000  # the line after (16 ms apart)
    empty = np.isnan(igm(tmp_path / "geo", 1)[0]).all(axis=1)
    np.testing.assert_array_equal(np.flatnonzero(empty),
                                  np.arange(span["first_line"], seg1["lines"]))


def _cut_log(src: Path, dst: Path, before_log_ns: int) -> None:
    """The log cut at the first chunk that starts after `before_log_ns` (as a recorder that
    lost power then leaves it)."""
    from mcap.reader import make_reader

    with src.open("rb") as fh:
        chunks = make_reader(fh).get_summary().chunk_indexes
    cut = min(c.chunk_start_offset for c in chunks if c.message_start_time > before_log_ns)
    dst.write_bytes(src.read_bytes()[:cut])


def test_log_cut_between_the_strips_georeferences_strip_0(
        run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from recorder.columns import read_topics

    headers = read_topics(run / "flight.mcap", {Topic.SCANNER_HEADER: ("segment",)})[
        Topic.SCANNER_HEADER]
    seg, log_ns = headers["segment"], headers["log_time_ns"]
    between = (int(log_ns[seg == 0].max()) + int(log_ns[seg == 1].min())) // 2
    cut = tmp_path / "cut"
    cut.mkdir()
    _cut_log(run / "flight.mcap", cut / "flight.mcap", between)
    rc = main(["georef", str(cut / "flight.mcap"), "--scanner", str(run / "scanner"),
               "--dem", str(run / "terrain" / "dem.tif"), "--out", str(tmp_path / "geo"),
               "--no-products"])
    err = capsys.readouterr().err
    assert rc == INCOMPLETE, err  # lines promised, not all made
    err = without_losses_line(err)
    cut_short, warning = err.splitlines()
    assert cut_short.startswith(f"sisa georef: warning: {cut / 'flight.mcap'}: cut short")
    assert "segment 1: skipped, none of its " in warning
    assert "lines has a GPS time (sync: " in warning
    s = summary(tmp_path / "geo")
    assert [seg["segment"] for seg in s["segments"]] == [0]
    assert s["segments"][0]["lines_georeferenced"] == s["segments"][0]["lines"]
    assert s["skipped"][0]["reason"] == "no line time"


def test_image_cut_mid_line_georeferences_its_whole_lines(
        run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A segment image shorter than its header (a copy interrupted): the job no longer fails
    whole; the lines before the cut are georeferenced as from the intact file, the rest are
    named in one warning (stderr and summary)."""
    from postproc.products import EnviRaster

    scanner = tmp_path / "scanner"
    scanner.mkdir()
    for f in (run / "scanner").iterdir():
        (scanner / f.name).write_bytes(f.read_bytes())
    raw = EnviRaster.open(scanner / "segment_001.bil")
    keep = raw.lines // 3
    os.truncate(scanner / "segment_001.bil", keep * raw.line_bytes + 77)
    rc, _, err = georef(run, tmp_path / "whole", capsys)
    assert rc == 0, err
    capsys.readouterr()
    rc = main(["georef", str(run / "flight.mcap"), "--scanner", str(scanner),
               "--dem", str(run / "terrain" / "dem.tif"), "--out", str(tmp_path / "cut"),
               "--no-products"])
    err = capsys.readouterr().err
    assert rc == INCOMPLETE, err  # lines promised, not all made
    err = without_losses_line(err)
    warning, = err.splitlines()
    assert warning == (f"sisa georef: warning: segment 1: segment_001.bil is cut short: {keep} "
                       f"of its header's {raw.lines} lines are in the file (a copy or a "
                       f"recording interrupted?): lines {keep}-{raw.lines - 1} are not "
                       "georeferenced")
    s = summary(tmp_path / "cut")
    assert s["warnings"] == [warning.removeprefix("sisa georef: warning: ")]
    seg0, seg1 = s["segments"]
    assert seg1["lines"] == keep
    assert seg0 == summary(tmp_path / "whole")["segments"][0]
    np.testing.assert_array_equal(igm(tmp_path / "cut", 0), igm(tmp_path / "whole", 0))
    # the ray caster works relative to an origin set by the lines it is given: 0.01 mm here,
    # well inside its < 1 mm contract
    np.testing.assert_allclose(igm(tmp_path / "cut", 1), igm(tmp_path / "whole", 1)[:, :keep],
                               rtol=0, atol=1e-4)


def test_sbet_of_another_day_is_one_line_with_both_spans(
        run: Path, truth: TruthTrajectory, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    write_truth_sbet(tmp_path / "late.out", truth, truth.t_start_ns + NS_PER_S, truth.t_end_ns,
                     step_ns=NS_PER_S // 50, shift_ns=3 * NS_PER_DAY)
    rc, out, err = georef(run, tmp_path / "geo", capsys, "--trajectory", tmp_path / "late.out")
    assert rc == 2
    assert out == ""
    line, = err.splitlines()
    assert line.startswith("sisa georef: error: the trajectory ")
    assert "does not cover the scan lines" in line
    assert "2026-06-18T" in line  # the SBET placed 3 days later
    assert "2026-06-15T" in line  # the lines
    assert line.count(" GPS (week ") == 2
    assert "3 days apart" in line
    assert not (tmp_path / "geo").exists()


# --- fault 3: the leap seconds and the max gap, as options and from the log -----------------------

def test_utc_pos_takes_the_leap_seconds_from_the_log(
        run: Path, truth: TruthTrajectory, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    for scale in ("GPST", "UTC"):
        write_truth_pos(tmp_path / f"{scale}.pos", truth, _antenna(run),
                        truth.t_start_ns + NS_PER_S, truth.t_end_ns, scale=scale)
        rc, _, err = georef(run, tmp_path / scale, capsys, "--trajectory",
                            tmp_path / f"{scale}.pos")
        assert rc == 0, err
        assert err == ""
    traj = summary(tmp_path / "UTC")["trajectory"]
    assert (traj["time_scale"], traj["leap_seconds"]) == ("UTC", LEAP_S)
    assert traj["leap_seconds_from"].startswith("flight log")
    for seg in (0, 1):
        name = f"segment_{seg:03d}_igm.bil"
        assert (tmp_path / "UTC" / name).read_bytes() == (tmp_path / "GPST" / name).read_bytes()


def test_one_hz_sbet_needs_and_takes_max_gap(
        run: Path, truth: TruthTrajectory, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    write_truth_sbet(tmp_path / "1hz.out", truth, truth.t_start_ns + NS_PER_S, truth.t_end_ns,
                     step_ns=NS_PER_S)
    rc, _, err = georef(run, tmp_path / "no", capsys, "--trajectory", tmp_path / "1hz.out")
    assert rc == 2
    assert "--max-gap-s S" in err
    rc, out, err = georef(run, tmp_path / "geo", capsys, "--trajectory", tmp_path / "1hz.out",
                          "--max-gap-s", "1.5")
    assert rc == 0, err
    assert "2 segments, " in out


def _nmea_columns(leap_s: int, host_offset_ns: int, seconds: int = 40,
                  zda: bool = True) -> dict[str, dict[str, np.ndarray]]:
    """/gps/raw as a receiver sends it, and the PTT tags the recorder decoded from it: PTT 25 ms
    after each PPS, GGA 40 ms and ZDA 50 ms after the epoch (a ZDA split over two reads), read
    by a host whose clock is `host_offset_ns` off UTC."""
    reads: list[tuple[int, bytes]] = []
    tags: list[tuple[int, int]] = []
    start = T0_NS // NS_PER_S * NS_PER_S
    for k in range(seconds):
        t = start + k * NS_PER_S
        host = t - leap_s * NS_PER_S + host_offset_ns
        reads.append((host + 25_000_000, encode(ptt_from_gps_ns(t + 20))))
        tags.append((host + 25_000_000, t + 20))
        gga = gga_from_fix(t, leap_s, 41.6, 2.0, 900.0, 50.0, FixQuality.RTK_FIXED, 9, 0.9)
        reads.append((host + 40_000_000, encode(gga)))
        if zda:
            sentence = encode(zda_from_gps_ns(t, leap_s))
            reads += [(host + 48_000_000, sentence[:9]), (host + 50_000_000, sentence[9:])]
    data = np.empty(len(reads), dtype=object)
    data[:] = [b for _, b in reads]
    return {Topic.GPS_RAW: {"t_host_ns": np.array([h for h, _ in reads], np.int64),
                            "data": data},
            Topic.GPS_TIME_TAG: {"t_host_ns": np.array([h for h, _ in tags], np.int64),
                                 "kind": np.array(["PTT"] * len(tags)),
                                 "t_gps_ns": np.array([g for _, g in tags], np.int64)}}


@pytest.mark.parametrize(("leap_s", "host_offset_ns"), [(18, 0), (18, 3_700_000_000),
                                                        (13, -250_000_000), (0, 0)])
def test_leap_seconds_read_from_the_receivers_messages(leap_s: int, host_offset_ns: int) -> None:
    from postproc.georef.trajfiles import leap_seconds_from_log

    assert leap_seconds_from_log(_nmea_columns(leap_s, host_offset_ns)) == leap_s
    assert leap_seconds_from_log(_nmea_columns(leap_s, host_offset_ns, zda=False)) == leap_s


def test_leap_seconds_unknown_without_the_receivers_messages() -> None:
    from postproc.georef.trajfiles import leap_seconds_from_log

    assert leap_seconds_from_log({}) is None
    cols = _nmea_columns(18, 0, seconds=2)  # too few to tell
    assert leap_seconds_from_log(cols) is None


def test_utc_pos_leap_seconds_given_from_log_or_scenario(tmp_path: Path) -> None:
    cols, times = SYN.columns()
    t = T_POS[:40]
    write_pos(tmp_path / "utc.pos", t - LEAP_S * NS_PER_S, antenna_llh(t),
              np.ones(t.size, np.int64), scale="UTC ")
    with pytest.raises(InputError, match=r"times are UTC: give the leap-second count "
                                         r"\(--leap-seconds N"):
        read_trajectory_file(tmp_path / "utc.pos", cols, times, antenna_offset_m=G_B)
    spans = set()
    for kwargs, source in (({"leap_seconds": LEAP_S}, "--leap-seconds"),
                           ({"fallback_leap_seconds": LEAP_S}, "scenario")):
        report: dict[str, Any] = {}
        traj = read_trajectory_file(tmp_path / "utc.pos", cols, times, antenna_offset_m=G_B,
                                    report=report, **kwargs)
        assert (report["leap_seconds"], report["leap_seconds_from"]) == (LEAP_S, source)
        spans.add(traj.span_ns)
    report = {}
    with_log = {**cols, **_nmea_columns(LEAP_S, 0)}
    traj = read_trajectory_file(tmp_path / "utc.pos", with_log, times, antenna_offset_m=G_B,
                                report=report, fallback_leap_seconds=3)
    assert report["leap_seconds"] == LEAP_S
    assert report["leap_seconds_from"].startswith("flight log")
    spans.add(traj.span_ns)
    assert spans == {(int(t[0]), int(t[-1]))}
    report = {}
    read_trajectory_file(tmp_path / "utc.pos", with_log, times, antenna_offset_m=G_B,
                         report=report, leap_seconds=17)
    warning, = report["warnings"]
    assert "using 17 leap seconds as given" in warning
    assert "receiver messages say 18" in warning


def test_decimated_sbet_message_names_the_option_that_exists(tmp_path: Path) -> None:
    t = np.arange(T0_NS + NS_PER_S, SYN.end_ns - NS_PER_S, NS_PER_S, dtype=np.int64)
    write_sbet(tmp_path / "1hz.out", t)
    with pytest.raises(InputError, match=r"--max-gap-s S bridges longer gaps"):
        sbet_trajectory(tmp_path / "1hz.out", T0_NS)
    traj = sbet_trajectory(tmp_path / "1hz.out", T0_NS, max_gap_s=1.5)
    assert traj.span_ns == (int(t[0]), int(t[-1]))


# --- fault 2: a .pos with other than ASCII is still a .pos ----------------------------------------

def _encodings(text: str) -> dict[str, bytes]:
    vol = text.replace("% inp file  : rover.obs",
                       "% inp file  : C:\\Vols\\Garrotxa_vol_ñ\\rover.obs")
    assert vol != text
    return {"utf-8": vol.encode("utf-8"), "latin-1": vol.encode("latin-1"),
            "utf-8 bom": b"\xef\xbb\xbf" + text.encode("ascii"),
            "utf-8 bom, non-ascii": b"\xef\xbb\xbf" + vol.encode("utf-8"),
            "utf-16 bom": vol.encode("utf-16"),
            "crlf, latin-1": vol.replace("\n", "\r\n").encode("latin-1")}


@pytest.mark.parametrize("encoding", list(_encodings("% inp file  : rover.obs\n")))
def test_pos_with_non_ascii_comments_is_read_as_pos(tmp_path: Path, encoding: str) -> None:
    cols, times = SYN.columns()
    plain = tmp_path / "plain.pos"
    write_pos(plain, T_POS, antenna_llh(T_POS), np.ones(T_POS.size, np.int64))
    other = tmp_path / "other.pos"
    other.write_bytes(_encodings(plain.read_text(encoding="ascii"))[encoding])
    got = read_trajectory_file(other, cols, times, antenna_offset_m=G_B)  # not an SBET
    want = read_trajectory_file(plain, cols, times, antenna_offset_m=G_B)
    assert got.span_ns == want.span_ns
    t = T_POS[5:-5:7] + 123_456
    np.testing.assert_array_equal(got.pose_at(t).ins_ecef_m, want.pose_at(t).ins_ecef_m)


def test_sbet_is_still_told_apart_from_text(tmp_path: Path) -> None:
    cols, times = SYN.columns()
    t = np.arange(T0_NS + NS_PER_S, SYN.end_ns - NS_PER_S, NS_PER_S // 200, dtype=np.int64)
    write_sbet(tmp_path / "nav.out", t)
    report: dict[str, Any] = {}
    read_trajectory_file(tmp_path / "nav.out", cols, times, antenna_offset_m=G_B, report=report)
    assert report["format"] == "Applanix SBET"


@pytest.mark.parametrize("kind", ["GPST .pos", "SBET"])
def test_leap_seconds_for_a_trajectory_on_gps_time_are_said_unused(
        run: Path, truth: TruthTrajectory, tmp_path: Path, capsys: pytest.CaptureFixture[str],
        kind: str) -> None:
    """--leap-seconds with a .pos on GPST or an SBET changed nothing, without a word (found by
    a bad-input sweep): one warning, the products as without it."""
    path = tmp_path / ("gps.pos" if kind == "GPST .pos" else "nav.out")
    if kind == "SBET":
        write_truth_sbet(path, truth, truth.t_start_ns + NS_PER_S, truth.t_end_ns)
    else:
        write_truth_pos(path, truth, _antenna(run), truth.t_start_ns + NS_PER_S, truth.t_end_ns)
    rc, _, err = georef(run, tmp_path / "geo", capsys, "--trajectory", path,
                        "--leap-seconds", "17")
    assert rc == 0, err
    article = "an SBET" if kind == "SBET" else "a .pos"
    assert err.splitlines() == [f"sisa georef: warning: --leap-seconds 17: not used: {path} is "
                                f"{article} on GPS time (the option is for a .pos on UTC or "
                                "JST)"]
    assert summary(tmp_path / "geo")["warnings"] == [err.splitlines()[0].removeprefix(
        "sisa georef: warning: ")]
