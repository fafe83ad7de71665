"""Products are made under hidden names that nobody can aim elsewhere (issue 39, item 7): the
GLT, the endpoints file and the IGM were written through predictable `.NAME.partial-PID`
names opened without O_EXCL / O_NOFOLLOW, so a local user sharing the folder could plant a
symlink there and have the product written over another file. One helper makes them all
(sisa.core.outdir.create_partial): an unpredictable name, created exclusively, no link followed."""

from __future__ import annotations

import itertools
import os
from pathlib import Path

import numpy as np
import pytest

from postproc.products.footprints import write_footprints_geojson
from postproc.products.igm import IgmWriter
from postproc.products.ortho import GltWriter, OrthoGrid
from sisa.commands import write_endpoints

VICTIM = b"the user's own file\n"


def _plant_links(folder: Path, final: Path, victim: Path) -> list[Path]:
    """Symlinks to `victim` under every hidden name the old code used for `final` (this
    process's id), and a few more pids around it."""
    links = []
    for pid in range(os.getpid() - 2, os.getpid() + 3):
        link = folder / f".{final.name}.partial-{pid}"
        link.symlink_to(victim)
        links.append(link)
    return links


@pytest.fixture
def victim(tmp_path: Path) -> Path:
    path = tmp_path / "elsewhere" / "precious.txt"
    path.parent.mkdir()
    path.write_bytes(VICTIM)
    return path


def test_the_glt_is_not_written_through_a_planted_link(tmp_path: Path, victim: Path) -> None:
    out = tmp_path / "shared"
    out.mkdir()
    _plant_links(out, out / "glt.bil", victim)
    grid = OrthoGrid(461_000.0, 4_661_000.0, 1.0, 7, 5, 32631)
    glt = GltWriter(out / "glt", grid, "a.bil", "a.tif")
    glt.write_window(0, 0, np.ones((5, 2, 7), np.int32))
    glt.close()
    assert victim.read_bytes() == VICTIM
    assert (out / "glt.bil").stat().st_size == 5 * 2 * 7 * 4


def test_the_igm_is_not_written_through_a_planted_link(tmp_path: Path, victim: Path) -> None:
    out = tmp_path / "shared"
    out.mkdir()
    _plant_links(out, out / "igm.bil", victim)
    _plant_links(out, out / "igm.hdr", victim)
    with IgmWriter(out / "igm", 2, 3, 32631) as igm:
        igm.write_block(0, np.ones((2, 3)), np.ones((2, 3)), np.ones((2, 3)))
    assert victim.read_bytes() == VICTIM
    assert (out / "igm.hdr").read_text().startswith("ENVI")


def test_the_endpoints_file_is_not_written_through_a_planted_link(tmp_path: Path,
                                                                   victim: Path) -> None:
    out = tmp_path / "shared"
    out.mkdir()
    _plant_links(out, out / "endpoints.json", victim)
    write_endpoints(out / "endpoints.json", {"gps": "/dev/pts/4"})
    assert victim.read_bytes() == VICTIM
    assert "/dev/pts/4" in (out / "endpoints.json").read_text()


def test_other_products_are_not_written_through_planted_links(tmp_path: Path,
                                                               victim: Path) -> None:
    out = tmp_path / "shared"
    out.mkdir()
    _plant_links(out, out / "footprints.geojson", victim)
    write_footprints_geojson(out / "footprints.geojson", [])
    assert victim.read_bytes() == VICTIM


def test_a_guessed_name_with_a_link_under_it_is_never_followed(
        tmp_path: Path, victim: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Even a name guessed right: the exclusive, link-refusing create fails on it and another
    name is taken; the link and what it points at are left alone."""
    from sisa.core import outdir
    tokens = itertools.chain(["guessed"] * 3, ["fresh"])
    monkeypatch.setattr(outdir.secrets, "token_hex", lambda _n: next(tokens))
    final = tmp_path / "product.bin"
    link = tmp_path / f".product.bin.partial-{os.getpid()}-guessed"
    link.symlink_to(victim)
    tmp, fd = outdir.create_partial(final)
    os.write(fd, b"mine")
    os.close(fd)
    assert tmp.name.endswith("-fresh")
    assert victim.read_bytes() == VICTIM
    assert link.is_symlink()
    monkeypatch.setattr(outdir.secrets, "token_hex", lambda _n: "guessed")
    with pytest.raises(FileExistsError):
        outdir.create_partial(final)
    assert victim.read_bytes() == VICTIM


def test_a_private_folder_is_made_new_and_never_through_a_link(
        tmp_path: Path, victim: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The hidden folder a GeoTIFF or COG is made in (GDAL then creates the file new in it):
    a link planted under a guessed name is passed over, and the folder is the user's alone."""
    import stat

    from sisa.core import outdir
    tokens = iter(["guessed", "fresh"])
    monkeypatch.setattr(outdir.secrets, "token_hex", lambda _n: next(tokens))
    final = tmp_path / "ortho.tif"
    link = tmp_path / f".ortho.tif.partial-{os.getpid()}-guessed"
    link.symlink_to(victim.parent)
    folder, _ = outdir.create_partial(final, outdir.new_private_dir)
    assert folder.name.endswith("-fresh")
    assert folder.is_dir()
    assert not folder.is_symlink()
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    assert list(victim.parent.iterdir()) == [victim]


def test_a_cog_rewritten_in_place_leaves_nothing_beside_it(tmp_path: Path) -> None:
    """write_cog(tif, tif), as the campaign calls it: the COG in place, valid, the same
    pixels, and no hidden folder or set-aside file left in the folder."""
    import rasterio

    from postproc.campaign import check_cog, write_cog
    tif = tmp_path / "seg.tif"
    data = np.arange(3 * 300 * 200, dtype=np.uint16).reshape(3, 300, 200)
    with rasterio.open(tif, "w", driver="GTiff", width=200, height=300, count=3,
                       dtype="uint16", crs="EPSG:32631", nodata=0,
                       transform=rasterio.Affine(1, 0, 461_000, 0, -1, 4_661_000)) as ds:
        ds.write(data)
    write_cog(tif, tif)
    check_cog(tif)
    with rasterio.open(tif) as ds:
        np.testing.assert_array_equal(ds.read(), data)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seg.tif"]
