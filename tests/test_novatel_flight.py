"""A whole `bench` flight with `gps.receiver = "novatel_oem7"`, end to end through the command
line: `sisa simulate` (the emulated OEM7 speaks BESTPOSA, TIMEA and MARK1TIMEA; the acquisition
decodes them), then `sisa sync`, which times every INS record and every scan line against the
simulation truth as it does with the default receiver."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from emulators.truth import read_truth_csv
from postproc.sync import SyncInput, SyncResult, read_sync_input, synchronise
from recorder.columns import read_columns
from recorder.messages import Topic
from tests.postproc.test_sync import beyond_latches, every_row_timed_under_a_microsecond

ROOT = Path(__file__).resolve().parents[1]
Flight = tuple[Path, Path, SyncInput, SyncResult]


def _sisa(*args: object) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run([sys.executable, "-m", "sisa.cli", *map(str, args)],
                          capture_output=True, text=True, check=False, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Flight:
    here = tmp_path_factory.mktemp("novatel")
    scenario = here / "novatel.toml"
    scenario.write_text('base = "bench"\n\n[gps]\nreceiver = "novatel_oem7"\n', encoding="utf-8")
    run, out = here / "run", here / "sync"
    _sisa("simulate", "--scenario", scenario, "--out", run, "--no-images")
    _sisa("sync", run / "flight.mcap", "--out", out)
    inp = read_sync_input(run / "flight.mcap")
    return run, out, inp, synchronise(inp)


def test_the_port_carried_novatel_logs_only_and_none_was_refused(flight: Flight) -> None:
    run, _, _, _ = flight
    raw = b"".join(read_columns(run / "flight.mcap", Topic.GPS_RAW)["data"])
    assert raw.count(b"#BESTPOSA,") > 500
    assert raw.count(b"#TIMEA,") > 500
    assert raw.count(b"#MARK1TIMEA,") > 50
    assert b"$" not in raw
    health = read_columns(run / "flight.mcap", Topic.HEALTH)
    gps = health["stream"] == "gps"
    assert int(health["checksum_errors"][gps].max()) == 0
    assert int(health["framing_errors"][gps].max()) == 0


def test_every_tag_is_the_truths(flight: Flight) -> None:
    run, _, _, _ = flight
    tags = read_columns(run / "flight.mcap", Topic.GPS_TIME_TAG)
    events = read_truth_csv(run / "truth" / "events.csv")
    pps = read_truth_csv(run / "truth" / "pps.csv")
    ttt = np.sort(tags["t_gps_ns"][tags["kind"] == "TTT"])
    ptt = np.sort(tags["t_gps_ns"][tags["kind"] == "PTT"])
    assert np.array_equal(ttt, np.sort(events["ttt_gps_ns"][events["accepted"] == 1]))
    assert np.array_equal(ptt, np.sort(pps["ptt_gps_ns"]))


def test_sisa_sync_times_every_record_and_line_well_under_a_microsecond(flight: Flight) -> None:
    run, out, inp, res = flight
    every_row_timed_under_a_microsecond(run, inp, res)
    # what `sisa sync` wrote is what the pipeline gives
    rows = [r.split(",") for r in (out / "line_times.csv").read_text(encoding="utf-8")
            .splitlines() if not r.startswith("#")][1:]
    assert [int(r[3]) for r in rows] == res.lines.t_gps_ns.tolist()
    rows = [r.split(",") for r in (out / "ins_times.csv").read_text(encoding="utf-8")
            .splitlines() if not r.startswith("#")][1:]
    assert [int(r[2]) for r in rows] == res.ins.t_gps_ns.tolist()
    beyond = beyond_latches(res)  # the flight's first and last seconds
    assert [r[3] for r in rows] == ["outside_fit" if b else "ok" for b in beyond.tolist()]
