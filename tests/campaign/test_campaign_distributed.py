"""The distributed deployment: a real `dask scheduler` and two `dask worker` processes on
loopback, the campaign given with --scheduler. One worker is killed (SIGKILL) while it runs a
segment's task: Dask gives the task to the other, the campaign completes, and its products are
those of the LocalCluster run (one flight's DEM given as two tiles, read through their VRT)."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.campaign import CELL_M, env

TIMEOUT_S = 300


def _start(*args: object) -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, "-m", *map(str, args)], env=env(),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)


def _stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def _wait_for(what, timeout_s: float, step_s: float = 0.05):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if (got := what()):
            return got
        time.sleep(step_s)
    pytest.fail(f"timed out after {timeout_s} s")


@pytest.fixture
def cluster(tmp_path):
    """(scheduler address, {worker name: its process}), all on 127.0.0.1, stopped after."""
    procs = []
    try:
        sched_file = tmp_path / "scheduler.json"
        procs.append(_start("dask", "scheduler", "--host", "127.0.0.1", "--port", "0",
                            "--no-dashboard", "--scheduler-file", sched_file))
        address = _wait_for(lambda: sched_file.is_file() and
                            json.loads(sched_file.read_text() or "{}").get("address"), 60)
        assert address.startswith("tcp://127.0.0.1:")
        workers = {}
        for name in ("w1", "w2"):
            workers[name] = _start("dask", "worker", address, "--name", name, "--nthreads", 1,
                                   "--no-nanny", "--no-dashboard", "--host", "127.0.0.1")
            procs.append(workers[name])
        yield address, workers
    finally:
        for proc in reversed(procs):
            _stop(proc)


def _tiles(dem: Path, root: Path) -> list[Path]:
    """The DEM cut into a west and an east tile, overlapping by 4 columns."""
    import rasterio
    from affine import Affine
    from rasterio.windows import Window

    tiles = []
    with rasterio.open(dem) as ds:
        half, t = ds.width // 2, ds.transform
        for k, (c0, c1) in enumerate(((0, half + 2), (half - 2, ds.width))):
            win = Window(c0, 0, c1 - c0, ds.height)
            shifted = Affine(t.a, t.b, t.c + c0 * t.a, t.d, t.e, t.f)
            profile = {**ds.profile, "width": c1 - c0, "transform": shifted}
            profile.pop("blockxsize", None)
            profile.pop("blockysize", None)
            profile["tiled"] = False
            path = root / f"dem_{k}.tif"
            with rasterio.open(path, "w", **profile) as out:
                out.write(ds.read(window=win))
            tiles.append(path)
    return tiles


def _campaign_file(root: Path, runs: Path) -> Path:
    from emulators.scenario import load_scenario
    from sisa.commands.process import sensor_of

    lines = ['[campaign]', 'name = "loopback"', f"cell_m = {CELL_M}"]
    for name in ("a_north", "b_east"):
        run = runs / name
        sensor = root / f"{name}.sensor.toml"
        sensor.write_text(sensor_of(load_scenario(run / "scenario.toml")).to_toml())
        dem = f'"{run / "terrain" / "dem.tif"}"'
        if name == "b_east":  # its DEM in two tiles: the VRT of them must read as the whole
            dem = "[" + ", ".join(f'"{t}"' for t in _tiles(run / "terrain" / "dem.tif",
                                                             root)) + "]"
        lines += ["[[flight]]", f'name = "{name}"', f'log = "{run / "flight.mcap"}"',
                  f'scanner = "{run / "scanner"}"', f"dem = {dem}", f'sensor = "{sensor.name}"']
    path = root / "loopback.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_worker_killed_mid_task_on_a_real_cluster_is_survived(cluster, campaign_runs,
                                                                processed, tmp_path):
    from distributed import Client

    address, workers = cluster
    campaign = _campaign_file(tmp_path, campaign_runs / "runs")
    out = tmp_path / "out"
    with Client(address, timeout="30s") as client:
        _wait_for(lambda: len(client.scheduler_info()["workers"]) == 2, 90, 0.2)
        names = {w["name"]: a for a, w in client.scheduler_info()["workers"].items()}
        run = subprocess.Popen([sys.executable, "-m", "sisa.cli", "campaign", "process",
                                campaign, "--out", out, "--scheduler", address],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env=env())
        try:
            def busy_with_a_segment():
                keys = client.processing(workers=[names["w1"]]).get(names["w1"], [])
                return [k for k in keys if str(k).startswith(("georef_", "ortho_"))]

            killed_during = _wait_for(busy_with_a_segment, 120, 0.02)
            workers["w1"].send_signal(signal.SIGKILL)
            workers["w1"].wait(timeout=20)
            stdout, stderr = run.communicate(timeout=TIMEOUT_S)
        finally:
            if run.poll() is None:
                run.kill()
                run.wait()
        assert len(client.scheduler_info()["workers"]) == 1  # w1 is gone for good
    assert run.returncode == 0, stderr
    assert "2 flights, 4 segments mapped" in stdout, (killed_during, stdout, stderr)
    assert f"cluster: {address}, 2 workers" in stderr
    items = sorted(p.stem for p in (out / "stac").glob("*/*.json"))
    assert items == ["a_north-segment_000", "a_north-segment_001", "b_east-segment_000",
                     "b_east-segment_001"]
    assert not list(out.rglob(".*.partial-*"))  # nothing of the killed task left behind
    assert (out / "flights" / "b_east" / "dem_mosaic.vrt").is_file()
    for name in ("a_north", "b_east"):  # the same products as the LocalCluster's
        for s in (0, 1):
            for kind in ("igm.bil", "glt.bil", "eo.csv"):
                f = f"segment_{s:03d}_{kind}"
                mine = (out / "flights" / name / f).read_bytes()
                assert mine == (processed / "out" / "flights" / name / f).read_bytes(), f
