"""An ortho `--cell` wider than half the swath is refused at the first block of rays, not after
the whole flight has been cast (c29a61b checked it only then: minutes on a long flight before
the error); without products there is no ortho and no check.

On the tiny two-strip run of test_trajectory_coverage (simulated once per session, shared), in
blocks of 64 lines so that the flight is several blocks."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

import postproc.georef.casting as casting_module
from postproc.georef import GeorefJob, GeorefOptions, SensorModel, raycast
from sisa.core.errors import InputError
from tests.postproc.test_trajectory_coverage import (  # noqa: F401 (its fixture, by name)
    run as coverage_run,
)

BLOCK = 64


@pytest.fixture
def run(request: pytest.FixtureRequest) -> Path:
    """The session's tiny run (test_trajectory_coverage's fixture, simulated once)."""
    path: Path = request.getfixturevalue("coverage_run")
    return path


@pytest.fixture
def cast_blocks(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The lines of every block of rays the job casts, in order."""
    blocks: list[int] = []
    real = raycast.intersect

    def counting(dem: Any, centre: Any, *args: Any, **kwargs: Any) -> Any:
        blocks.append(len(centre))
        return real(dem, centre, *args, **kwargs)

    monkeypatch.setattr(casting_module, "intersect", counting)
    return blocks


def _job(run: Path, out: Path, **options: Any) -> GeorefJob:
    return GeorefJob([run / "flight.mcap"], run / "scanner", out, GeorefOptions(
        sensor=SensorModel(), dem=run / "terrain" / "dem.tif", block_lines=BLOCK, **options))


def test_a_cell_wider_than_half_the_swath_is_refused_at_the_first_block(
        run: Path, tmp_path: Path, cast_blocks: list[int]) -> None:
    with pytest.raises(InputError) as exc:
        _job(run, tmp_path / "geo", cell_m=1000.0).run()
    assert cast_blocks == [BLOCK]  # one block cast, not the flight's
    said = re.fullmatch(r"--cell 1000: wider than half the swath \(segment 0: (\d+) m wide, "
                        r"0\.[34]\d m pixels\): its ortho would hold a cell or two across, or "
                        r"none; use at most (\d+) m", str(exc.value))
    assert said is not None, exc.value
    width, most = (int(v) for v in said.groups())
    assert 190 < width < 230
    assert width // 2 - 1 <= most <= width // 2
    assert not (tmp_path / "geo" / "segment_001_eo.csv").exists()


def test_a_cell_that_fits_and_no_products_cast_the_whole_flight(
        run: Path, tmp_path: Path, cast_blocks: list[int]) -> None:
    """The check refuses nothing it should not: --cell 50 over the ~210 m swath makes every
    product; --cell 1000 without products (no ortho) casts every block and succeeds."""
    result = _job(run, tmp_path / "fits", cell_m=50.0).run()
    assert [s.segment for s in result.segments] == [0, 1]
    assert result.mosaic is not None
    assert result.mosaic.is_file()
    flight = list(cast_blocks)
    assert len(flight) > 2
    cast_blocks.clear()
    result = _job(run, tmp_path / "ortho-free", cell_m=1000.0, products=False).run()
    assert cast_blocks == flight
    assert result.mosaic is None
    assert not list((tmp_path / "ortho-free").glob("*_ortho.tif"))
