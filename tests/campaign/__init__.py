"""A small simulated campaign, made once per test run and shared by every pytest-xdist worker:
three short flights (two seeds on north-south strips, one flown east-west), one of them with
its log damaged, and a fourth whose log is not a flight log at all."""

from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

from tests.recorder import overwrite_middle

ROOT = Path(__file__).resolve().parents[2]
CELL_M = 1.0  # one cell for every flight: one mosaic

# short flights: no figure-eight, the airfield near the block, 30 s of alignment (~18 s each)
TINY = """
base = "bench"
[block]
strip_length_m = 900.0
first_strip_heading_deg = {heading}
[flight]
static_alignment_s = 30.0
figure_eights = 0
airfield_offset_m = {offset}
"""
FLIGHTS = (("a_north", 0.0, [-600.0, -1500.0], 2), ("b_east", 90.0, [-1500.0, -600.0], 3),
           ("c_damaged", 0.0, [-600.0, -1500.0], 4))
DAMAGE_BYTES = 400_000


def env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT), "SISA_PROGRESS_S": "off"}


def sisa(*args: object, check: bool = True, timeout: float = 600
         ) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run([sys.executable, "-m", "sisa.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=timeout, env=env())
    if check:
        assert proc.returncode in (0, 3), proc.stderr
    return proc


def shared_dir(base: Path, name: str, make: object) -> Path:
    """`base/name`, made once by whichever test process gets there first (a lock beside it);
    the others wait for it and reuse it."""
    target = base / name
    with (base / f"{name}.lock").open("w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        if not (target / ".done").is_file():
            shutil.rmtree(target, ignore_errors=True)
            target.mkdir(parents=True)
            make(target)  # type: ignore[operator]
            (target / ".done").write_text("")
    return target


def make_runs(root: Path) -> None:
    """The campaign's run folders in root/runs (and the sensor file of each in root)."""
    runs = root / "runs"
    runs.mkdir()
    procs = []
    for name, heading, offset, seed in FLIGHTS:  # at once: the other test workers wait
        scn = root / f"{name}.toml"
        scn.write_text(TINY.format(heading=heading, offset=offset), encoding="utf-8")
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "sisa.cli", "simulate", "--scenario", str(scn), "--seed",
             str(seed), "--out", str(runs / name)], env=env(), stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE, text=True))
    for proc in procs:
        _, err = proc.communicate(timeout=600)
        assert proc.returncode == 0, err
    log = runs / "c_damaged" / "flight.mcap"
    intact = root / "c_intact.mcap"
    shutil.copy2(log, intact)
    overwrite_middle(intact, log, n_bytes=DAMAGE_BYTES, seed=5)
    broken = runs / "d_broken"  # a run whose log is noise: the flight fails, the rest goes on
    shutil.copytree(runs / "a_north", broken)
    (broken / "flight.mcap").write_bytes(np.random.default_rng(1).bytes(100_000))


def make_processed(root: Path, runs: Path) -> None:
    """The campaign processed on a LocalCluster of two workers, its stdout and stderr kept."""
    proc = sisa("campaign", "process", runs, "--out", root / "out", "--workers", 2,
                "--cell", CELL_M)
    (root / "returncode").write_text(str(proc.returncode))
    (root / "stdout").write_text(proc.stdout)
    (root / "stderr").write_text(proc.stderr)
