"""What `sisa campaign process` refuses (one line, exit 2, nothing written), and the
fingerprints its reruns are judged by."""

import os
from pathlib import Path

import numpy as np
import pytest

from postproc.campaign import file_fingerprint, load_campaign
from sisa.cli import main
from sisa.core.errors import InputError


def _sisa(capsys, *args):
    """The command in this process (no interpreter to start): (exit code, stderr)."""
    code = main([str(a) for a in args])
    return code, capsys.readouterr().err


def _files(tmp_path: Path) -> Path:
    """A flight's inputs as files (their content does not matter to the checks)."""
    (tmp_path / "scanner").mkdir()
    for name in ("flight.mcap", "dem.tif"):
        (tmp_path / name).write_bytes(b"x")
    return tmp_path


FLIGHT = '[[flight]]\nname = "f1"\nlog = "flight.mcap"\nscanner = "scanner"\ndem = "dem.tif"\n'


@pytest.mark.parametrize(("text", "says"), [
    ("[campaign\n", "not a TOML file"),
    ('[campaign]\nname = "x"\n', "no [[flight]]"),
    ('[campaign]\ncolour = 1\n' + FLIGHT, "unknown key 'colour'"),
    (FLIGHT.replace('"dem.tif"', '"nowhere.tif"'), "dem"),
    (FLIGHT.replace('"scanner"', '"dem.tif"'), "scanner"),
    (FLIGHT + FLIGHT, "flight 'f1' is listed twice"),
    (FLIGHT.replace('"f1"', '"../up"'), "name '../up'"),
    ('[campaign]\ncell_m = -1\n' + FLIGHT, "cell_m"),
    (FLIGHT + 'geoid_m = 500\n', "geoid_m 500"),
    (FLIGHT.replace('dem = "dem.tif"', 'dem = []'), "a list of 1 to 10000 DEM tiles"),
])
def test_a_bad_campaign_file_is_one_line_and_exit_2(tmp_path, capsys, text, says):
    root = _files(tmp_path)
    camp = root / "camp.toml"
    camp.write_text(text, encoding="utf-8")
    with pytest.raises(InputError) as refused:
        load_campaign(camp)
    assert says in str(refused.value)
    code, err = _sisa(capsys, "campaign", "process", camp, "--out", root / "out")
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("sisa campaign: error: ")
    assert says in lines[0]
    assert not (root / "out").exists()


def test_a_good_campaign_file_resolves_paths_from_its_folder(tmp_path):
    root = _files(tmp_path)
    camp = root / "camp.toml"
    camp.write_text('[campaign]\nname = "season"\ncell_m = 2\ncrs = 32631\n' + FLIGHT)
    spec = load_campaign(camp)
    assert spec.name == "season"
    (f,) = spec.flights
    assert f.log == (root / "flight.mcap",)
    assert f.options.dem == root / "dem.tif"
    assert f.options.cell_m == 2.0
    assert f.options.epsg == 32631


def test_an_output_folder_of_something_else_is_refused(tmp_path, capsys):
    root = _files(tmp_path)
    camp = root / "camp.toml"
    camp.write_text(FLIGHT)
    other = root / "other"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    code, err = _sisa(capsys, "campaign", "process", camp, "--out", other)
    assert code == 2
    assert "is not a campaign's output folder" in err
    assert sorted(p.name for p in other.iterdir()) == ["keep.txt"]


def test_a_fingerprint_reads_the_ends_only_and_sees_size_mtime_and_ends(tmp_path):
    """The documented trade: a change in the middle that keeps size and mtime goes unseen;
    any change of size, mtime or the first or last 64 KiB is seen."""
    path = tmp_path / "big.bin"
    data = bytearray(np.random.default_rng(0).bytes(1 << 20))
    path.write_bytes(data)
    st = path.stat()
    first = file_fingerprint(path)
    assert len(first) == 64
    assert file_fingerprint(path) == first

    def rewrite(mutate):
        buf = bytearray(data)
        mutate(buf)
        path.write_bytes(buf)
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))
        return file_fingerprint(path)

    assert rewrite(lambda b: b.__setitem__(500_000, b[500_000] ^ 1)) == first  # unseen
    assert rewrite(lambda b: b.__setitem__(10, b[10] ^ 1)) != first
    assert rewrite(lambda b: b.__setitem__(-10, b[-10] ^ 1)) != first
    path.write_bytes(data)  # the same bytes, a new time (a copy, a re-export)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))
    assert file_fingerprint(path) != first
    assert rewrite(lambda b: b.extend(b"!")) != first
    assert file_fingerprint(tmp_path / "none") == "missing"


@pytest.mark.parametrize("address", ["notanaddress", "tcp://host-without-port"])
def test_a_scheduler_address_dask_cannot_take_is_refused_before_anything(tmp_path, capsys,
                                                                        address):
    root = _files(tmp_path)
    camp = root / "camp.toml"
    camp.write_text(FLIGHT)
    code, err = _sisa(capsys, "campaign", "process", camp, "--out", root / "out",
                      "--scheduler", address)
    assert code == 2
    assert "not a scheduler address such as tcp://HOST:8786" in err
    assert not (root / "out").exists()


def _dem(path: Path, west: float, north: float, heights: np.ndarray, cell: float = 5.0,
         nodata: float | None = -9999.0) -> Path:
    import rasterio
    from affine import Affine

    with rasterio.open(path, "w", driver="GTiff", width=heights.shape[1],
                       height=heights.shape[0], count=1, dtype="float32", crs="EPSG:32631",
                       transform=Affine(cell, 0.0, west, 0.0, -cell, north), nodata=nodata) as ds:
        ds.write(heights.astype(np.float32), 1)
    return path


def test_dem_tiles_read_as_one_dem_through_their_vrt(tmp_path):
    """Two tiles of one DEM (overlapping by 3 columns, the first with a void there): their
    VRT reads as the whole DEM, the void filled from the second tile."""
    import rasterio

    from postproc.campaign.demvrt import write_dem_vrt

    whole = np.random.default_rng(0).uniform(200, 400, size=(40, 60))
    left = whole[:, :33].copy()
    left[10, 31] = -9999.0
    a = _dem(tmp_path / "a.tif", 400_000.0, 4_600_000.0, left)
    b = _dem(tmp_path / "b.tif", 400_000.0 + 30 * 5.0, 4_600_000.0, whole[:, 30:])
    vrt = tmp_path / "dem.vrt"
    write_dem_vrt([a, b], vrt)
    with rasterio.open(vrt) as ds:
        assert (ds.width, ds.height, ds.res) == (60, 40, (5.0, 5.0))
        assert ds.crs.to_epsg() == 32631
        got = ds.read(1)
    assert np.array_equal(got, whole.astype(np.float32))
    mtime = vrt.stat().st_mtime_ns
    write_dem_vrt([a, b], vrt)  # the same tiles: the file left as it was (keys stay put)
    assert vrt.stat().st_mtime_ns == mtime
    odd = _dem(tmp_path / "odd.tif", 400_000.0 + 2.5, 4_600_000.0, whole[:, 30:])
    with pytest.raises(InputError, match=r"off .* grid"):
        write_dem_vrt([a, odd], vrt)
    coarse = _dem(tmp_path / "coarse.tif", 400_000.0, 4_600_000.0, whole, cell=10.0)
    with pytest.raises(InputError, match="cell 10 x 10 differs"):
        write_dem_vrt([a, coarse], vrt)
