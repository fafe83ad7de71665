"""`sisa campaign process` on a simulated campaign of three flights (one log damaged) and a
fourth whose log is noise: everything but the broken flight is made, the orthos and the mosaic
are valid COGs, the STAC catalog validates, each segment's products are those `sisa georef`
makes of the same flight, and a rerun does nothing, quickly."""

import json
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
import rasterio
from pystac.errors import STACValidationError
from rio_cogeo.cogeo import cog_validate

from postproc.campaign import validate_catalog
from postproc.campaign.stac import offline_validator
from tests.campaign import CELL_M, sisa


def _out(processed: Path) -> Path:
    return processed / "out"


def test_the_campaign_is_made_but_for_the_broken_flight(processed):
    stdout, stderr = (processed / "stdout").read_text(), (processed / "stderr").read_text()
    assert (processed / "returncode").read_text() == "3", stderr  # partial: one flight lost
    assert "4 flights, 6 segments mapped" in stdout
    assert "1 mosaics" in stdout
    broken = [ln for ln in stderr.splitlines() if "not made: flight d_broken" in ln]
    assert len(broken) == 1, stderr
    assert "not an MCAP file" in broken[0]
    # the damaged log: said, and what survived it processed
    assert any("c_damaged" in ln and "damaged chunk" in ln for ln in stderr.splitlines()), stderr
    flights = _out(processed) / "flights"
    for name in ("a_north", "b_east", "c_damaged"):
        summary = json.loads((flights / name / "georef_summary.json").read_text())
        assert [s["segment"] for s in summary["segments"]] == [0, 1]
        assert all(s["lines_georeferenced"] > 500 for s in summary["segments"])
    assert not (flights / "d_broken" / "georef_summary.json").exists()
    # bokeh comes with the campaign extra: the dashboard is served, on loopback
    assert "dashboard: http://127.0.0.1:" in stderr, stderr


def test_the_catalog_validates_offline_with_an_item_per_segment(processed):
    collection = _out(processed) / "stac" / "collection.json"
    assert validate_catalog(collection) == 1 + 6
    doc = json.loads(collection.read_text())
    assert any("d_broken" in f for f in doc["sisa:failures"])
    assert [k for k in doc["assets"] if not k.endswith("_quicklook")] == \
        ["mosaic_4b_uint16_0e1e78_epsg32631_1m"]
    items = sorted((_out(processed) / "stac").glob("*/*.json"))
    assert [p.stem for p in items] == [f"{f}-segment_00{s}" for f in
                                       ("a_north", "b_east", "c_damaged") for s in (0, 1)]
    item = json.loads(items[2].read_text())
    props = item["properties"]
    assert props["start_datetime"] < props["end_datetime"]
    assert props["sisa:t_first_gps_ns"] < props["sisa:t_last_gps_ns"]
    assert props["proj:code"] == "EPSG:32631"
    assert props["gsd"] == CELL_M
    assert len(props["sisa:task_keys"]["ortho"]) == 64
    assert props["sisa:accuracy"]["pixels_on_dem_pct"] > 99
    assert {"ortho", "igm", "igm_header", "glt", "geolocation_vrt", "quicklook", "eo",
            "footprints"} <= set(item["assets"])
    assert item["assets"]["ortho"]["type"].endswith("profile=cloud-optimized")
    for asset in item["assets"].values():  # relative hrefs, every one pointing at a file
        assert not asset["href"].startswith("/")
        assert (items[2].parent / asset["href"]).is_file()
    lon0, lat0, lon1, lat1 = item["bbox"]
    assert lon0 < lon1
    assert lat0 < lat1
    assert abs(lat0 - 41.6) < 0.1


def test_the_offline_validator_refuses_a_wrong_item(processed):
    """The validation can fail: a projection field of the wrong type, and a missing datetime."""
    import pystac

    item_path = next((_out(processed) / "stac").glob("b_east/*.json"))
    validator = offline_validator()
    doc = json.loads(item_path.read_text())
    doc["properties"]["proj:shape"] = "512x512"
    with pytest.raises(STACValidationError):
        pystac.Item.from_dict(doc).validate(validator=validator)
    doc = json.loads(item_path.read_text())
    del doc["properties"]["start_datetime"]
    with pytest.raises(STACValidationError):
        pystac.validation.validate_dict(doc, validator=validator)


def test_every_ortho_and_the_mosaic_are_valid_cogs(processed):
    out = _out(processed)
    cogs = sorted(out.glob("flights/*/segment_*_ortho.tif")) + sorted(out.glob("mosaics/*.tif"))
    assert len(cogs) == 7
    for path in cogs:
        ok, errors, _ = cog_validate(str(path), quiet=True)
        assert ok, (path, errors)
        with rasterio.open(path) as ds:
            assert ds.overviews(1), path
            assert ds.profile["tiled"]
            assert ds.compression.name == "deflate"
            assert ds.nodata is not None
    with rasterio.open(cogs[-1]) as ds:  # the mosaic holds all three flights' strips
        data = ds.read(1, out_shape=(ds.height // 4, ds.width // 4))
        assert (data != ds.nodata).mean() > 0.2


def test_segment_products_are_those_of_sisa_georef(processed, campaign_runs, tmp_path):
    """b_east through `sisa georef` with the same sensor and cell: the same bytes for the EO,
    IGM, GLT, sync tables and quicklooks, the same pixels and grid in the ortho (a plain
    GeoTIFF there, a COG here), the same footprints."""
    from emulators.scenario import load_scenario
    from sisa.commands.process import sensor_of

    run = campaign_runs / "runs" / "b_east"
    sensor = tmp_path / "sensor.toml"
    sensor.write_text(sensor_of(load_scenario(run / "scenario.toml")).to_toml())
    geo = tmp_path / "geo"
    sisa("georef", run / "flight.mcap", "--scanner", run / "scanner", "--dem",
         run / "terrain" / "dem.tif", "--sensor", sensor, "--cell", CELL_M, "--out", geo)
    mine = _out(processed) / "flights" / "b_east"
    same = ["sync/line_times.csv", "sync/ins_times.csv"]
    for s in (0, 1):
        stem = f"segment_{s:03d}"
        same += [f"{stem}_eo.csv", f"{stem}_igm.bil", f"{stem}_igm.hdr", f"{stem}_glt.bil",
                 f"{stem}_glt.hdr", f"{stem}_quicklook.png"]
        with rasterio.open(geo / f"{stem}_ortho.tif") as a, \
                rasterio.open(mine / f"{stem}_ortho.tif") as b:
            assert (a.transform, a.crs, a.nodata, a.dtypes, a.shape) == \
                (b.transform, b.crs, b.nodata, b.dtypes, b.shape)
            assert a.descriptions == b.descriptions
            assert np.array_equal(a.read(), b.read())
    for name in same:
        assert (geo / name).read_bytes() == (mine / name).read_bytes(), name
    feats = [json.loads((d / "footprints.geojson").read_text())["features"] for d in (geo, mine)]
    assert feats[0] == feats[1]


def _copy(processed: Path, tmp_path: Path) -> Path:
    out = tmp_path / "out"
    shutil.copytree(_out(processed), out, copy_function=shutil.copy2,
                    ignore=shutil.ignore_patterns(".campaign.lock"))
    return out


def _mtimes(out: Path) -> dict[str, int]:
    return {str(p.relative_to(out)): p.stat().st_mtime_ns for p in out.rglob("*")
            if p.is_file() and p.name != ".campaign.lock"}


def test_a_rerun_does_no_work_and_ends_within_5_s(processed, campaign_runs, tmp_path):
    out = _copy(processed, tmp_path)  # (moved: the records name products inside it)
    before = _mtimes(out)
    started = time.monotonic()
    proc = sisa("campaign", "process", campaign_runs / "runs", "--out", out, "--workers", 2,
                "--cell", CELL_M)
    elapsed_s = time.monotonic() - started
    assert proc.returncode == 3, proc.stderr  # the broken flight is still broken
    assert "; 0 tasks run, 20 reused;" in proc.stdout
    assert "cluster:" not in proc.stderr  # no cluster started
    assert elapsed_s < 5.0, elapsed_s
    assert _mtimes(out) == before


def test_a_new_setting_reruns_only_the_tasks_it_touches(processed, campaign_runs, tmp_path):
    """Another cell: every ortho, flight and mosaic again; no sync and no ray cast."""
    out = _copy(processed, tmp_path)
    igm = out / "flights" / "a_north" / "segment_000_igm.bil"
    igm_mtime = igm.stat().st_mtime_ns
    proc = sisa("campaign", "process", campaign_runs / "runs", "--out", out, "--workers", 2,
                "--cell", 2.0)
    assert proc.returncode == 3, proc.stderr
    assert "; 10 tasks run, 10 reused;" in proc.stdout  # 6 orthos, 3 flights, 1 mosaic
    assert igm.stat().st_mtime_ns == igm_mtime
    with rasterio.open(out / "flights" / "a_north" / "segment_000_ortho.tif") as ds:
        assert ds.res == (2.0, 2.0)
    assert validate_catalog(out / "stac" / "collection.json") == 7
    doc = json.loads((out / "stac" / "collection.json").read_text())
    assert [k for k in doc["assets"] if not k.endswith("_quicklook")] == \
        ["mosaic_4b_uint16_0e1e78_epsg32631_2m"]
