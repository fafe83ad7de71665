"""postproc.georef.raycast: the fast ray–DEM intersection against independent oracles — its own slow
reference (pyproj at every point), the emulator's forward model (emulators.render), and
hand-worked cases — on the bench terrain and on a synthetic steep DEM with cliffs and a narrow
ridge that occludes rays."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from pyproj import Transformer

from emulators.render import exact_ground_point
from emulators.scenario import load_scenario
from emulators.terrain import Terrain
from postproc.georef import CastStats, Dem, GroundPoints, intersect, reference_intersect
from postproc.georef.raycast import fastpath
from sisa.core.frames import body_to_ned_matrix, ned_to_ecef_matrix
from sisa.core.sensor import R_NOMINAL_C_TO_B, ScannerGeometry

F64 = npt.NDArray[np.float64]
UTM31N = 32631
TOLERANCE_M = 1e-3


def ecef_of(epsg: int, e: F64, n: F64, h: F64) -> F64:
    lon, lat = Transformer.from_crs(epsg, 4326, always_xy=True).transform(e, n)
    return np.stack(Transformer.from_crs(4979, 4978, always_xy=True).transform(lon, lat, h), -1)


def poses(epsg: int, east_m: npt.ArrayLike, north_m: npt.ArrayLike, height_m: npt.ArrayLike,
          roll_rad: F64, pitch_rad: F64, heading_rad: F64) -> tuple[F64, F64]:
    """Perspective centres (ECEF) and camera → ECEF rotations for the nominal mounting."""
    lon, lat = Transformer.from_crs(epsg, 4326, always_xy=True).transform(east_m, north_m)
    x, y, z = Transformer.from_crs(4979, 4978, always_xy=True).transform(lon, lat, height_m)
    r_ne = ned_to_ecef_matrix(np.radians(lat), np.radians(lon))
    rot = r_ne @ body_to_ned_matrix(roll_rad, pitch_rad, heading_rad) @ R_NOMINAL_C_TO_B
    return np.stack([x, y, z], axis=-1), rot


def strip(dem: Dem, lines: int, agl_m: float, seed: int, step_m: float = 1.2
          ) -> tuple[F64, F64, F64]:
    """A CASI strip flown north over the middle of the DEM with ~0.3° attitude noise."""
    rng = np.random.default_rng(seed)
    w, s, e, _ = dem.bounds_m
    north = s + 400.0 + step_m * np.arange(lines)
    east = np.full(lines, 0.5 * (w + e)) + rng.uniform(-200.0, 200.0)
    height = np.full(lines, float(np.nanmax(dem.heights_m)) + agl_m)
    att = np.radians(0.3) * np.cumsum(rng.standard_normal((3, lines)), axis=1) / 5.0
    centre, rot = poses(dem.epsg, east, north, height, att[0], att[1], att[2])
    return centre, rot, ScannerGeometry().look_vectors_camera()


def range_and_distance_m(dem: Dem, centre: F64, got: GroundPoints, ref: GroundPoints
                         ) -> tuple[F64, F64]:
    """|range difference| along each ray and 3-D distance between the points, rays both hit."""
    both = got.hit & ref.hit
    p_got = ecef_of(dem.epsg, got.easting_m[both], got.northing_m[both], got.height_m[both])
    p_ref = ecef_of(dem.epsg, ref.easting_m[both], ref.northing_m[both], ref.height_m[both])
    c = np.broadcast_to(centre[:, None, :], (*both.shape, 3))[both]
    dr = np.abs(np.linalg.norm(p_got - c, axis=-1) - np.linalg.norm(p_ref - c, axis=-1))
    return dr, np.linalg.norm(p_got - p_ref, axis=-1)


def assert_matches_reference(dem: Dem, centre: F64, rot: F64, look: F64,
                             got: GroundPoints) -> GroundPoints:
    ref = reference_intersect(dem, centre, rot, look)
    np.testing.assert_array_equal(got.hit, ref.hit)
    dr, d3 = range_and_distance_m(dem, centre, got, ref)
    assert dr.max(initial=0.0) < TOLERANCE_M
    assert d3.max(initial=0.0) < TOLERANCE_M
    for a in (got.easting_m, got.northing_m, got.height_m):
        assert np.isnan(a[~got.hit]).all()
    return ref


@pytest.fixture(scope="module")
def bench_terrain() -> Terrain:
    return Terrain.from_scenario(load_scenario("bench"))


@pytest.fixture(scope="module")
def bench_dem(bench_terrain: Terrain, tmp_path_factory: pytest.TempPathFactory) -> Dem:
    path = tmp_path_factory.mktemp("dem") / "bench.tif"
    bench_terrain.write_dem(path)
    return Dem.read(path)


@pytest.fixture(scope="module")
def bench_strip(bench_dem: Dem) -> tuple[F64, F64, F64]:
    return strip(bench_dem, 600, 900.0, seed=4)


def test_fast_path_matches_the_reference_on_the_bench_dem(
        bench_dem: Dem, bench_strip: tuple[F64, F64, F64]) -> None:
    centre, rot, look = bench_strip
    stats = CastStats()
    got = intersect(bench_dem, centre, rot, look, stats=stats)
    assert got.hit.all()
    assert stats.fast > 0.99 * got.hit.size
    lines = np.sort(np.random.default_rng(8).choice(centre.shape[0], 5, replace=False))
    sub = GroundPoints(got.easting_m[lines], got.northing_m[lines], got.height_m[lines],
                       got.hit[lines])
    assert_matches_reference(bench_dem, centre[lines], rot[lines], look, sub)


def test_agrees_with_the_emulators_forward_model(bench_terrain: Terrain, bench_dem: Dem,
                                                 bench_strip: tuple[F64, F64, F64]) -> None:
    """emulators.render.exact_ground_point marches the emulator's own terrain sampler."""
    centre, rot, look = bench_strip
    got = intersect(bench_dem, centre, rot, look)
    rng = np.random.default_rng(9)
    li = rng.integers(0, centre.shape[0], 300)
    pj = rng.integers(0, look.shape[1], 300)
    d = np.einsum("nij,jn->ni", rot[li], look[:, pj])
    exact = exact_ground_point(bench_terrain, centre[li], d)
    assert not np.isnan(exact).any()
    mine = np.stack([got.easting_m[li, pj], got.northing_m[li, pj], got.height_m[li, pj]], -1)
    assert np.abs(mine - exact).max() < TOLERANCE_M


def test_out_buffers_are_reused_and_checked(bench_dem: Dem,
                                            bench_strip: tuple[F64, F64, F64]) -> None:
    centre, rot, look = bench_strip
    first = intersect(bench_dem, centre[:40], rot[:40], look)
    out = GroundPoints.empty(40, look.shape[1])
    again = intersect(bench_dem, centre[:40], rot[:40], look, out=out)
    assert again is out
    np.testing.assert_array_equal(out.easting_m, first.easting_m)
    np.testing.assert_array_equal(out.hit, first.hit)
    with pytest.raises(ValueError, match="out buffers"):
        intersect(bench_dem, centre[:41], rot[:41], look, out=out)
    with pytest.raises(ValueError, match="expected centre"):
        intersect(bench_dem, centre[:40], rot[:39], look)


def test_lines_without_a_pose_give_nan(bench_dem: Dem,
                                       bench_strip: tuple[F64, F64, F64]) -> None:
    centre, rot, look = (a.copy() for a in bench_strip)
    full = intersect(bench_dem, centre[:30], rot[:30], look)
    centre[[3, 17]] = np.nan
    rot[20] = np.nan
    got = intersect(bench_dem, centre[:30], rot[:30], look)
    assert not got.hit[[3, 17, 20]].any()
    assert np.isnan(got.easting_m[[3, 17, 20]]).all()
    keep = np.setdiff1d(np.arange(30), [3, 17, 20])
    np.testing.assert_allclose(got.easting_m[keep], full.easting_m[keep], atol=1e-4)
    ref = reference_intersect(bench_dem, centre[2:5], rot[2:5], look[:, ::64])
    assert not ref.hit[1].any()
    assert ref.hit[[0, 2]].all()


def test_vertical_ray_over_flat_ellipsoidal_dem_by_hand() -> None:
    """Flat DEM at h = 250 m: a ray along the ellipsoid normal from 700 m above meets it at the
    camera's own map position (pyproj) and height 250 m."""
    h = np.full((400, 400), 250.0, np.float32)
    dem = Dem(h, 400_001.0, 4_600_799.0, 2.0, 2.0, UTM31N)
    e0, n0 = 400_351.3, 4_600_402.7
    lon, lat = Transformer.from_crs(UTM31N, 4326, always_xy=True).transform(e0, n0)
    centre = np.array([Transformer.from_crs(4979, 4978, always_xy=True).transform(
        lon, lat, 950.0)])
    r_ne = ned_to_ecef_matrix(math.radians(lat), math.radians(lon))
    rot = (r_ne @ np.diag([1.0, 1.0, -1.0]) @ np.diag([1.0, 1.0, -1.0]))[None]  # z → down
    look = np.array([[0.0], [0.0], [1.0]])  # along camera z = NED down
    for method in (intersect, reference_intersect):
        gp = method(dem, centre, rot, look)
        assert gp.hit.all()
        assert gp.easting_m[0, 0] == pytest.approx(e0, abs=1e-4)
        assert gp.northing_m[0, 0] == pytest.approx(n0, abs=1e-4)
        assert gp.height_m[0, 0] == pytest.approx(250.0, abs=1e-4)


# ---------------------------------------------------------------------------------------------
# A steep DEM: a cliff and a narrow ridge that comes and goes along track
# ---------------------------------------------------------------------------------------------


def steep_dem() -> Dem:
    """2 m cells, base 300 m sloping gently; a 6 m wide ridge, 60 m tall in 6 m sections with
    4 m gaps along north, 80 m west of the strip; an 80 m cliff 150 m east of it."""
    rows, cols = 500, 400
    e = np.arange(cols) * 2.0
    n = np.arange(rows) * 2.0
    base = 300.0 + 0.05 * e[None, :] + 0.02 * n[:, None]
    ridge = ((np.abs(e - 320.0) <= 3.0)[None, :] & ((n % 10.0) < 6.0)[:, None]) * 60.0
    cliff = (e >= 550.0)[None, :] * 80.0
    heights = (base + ridge + cliff).astype(np.float32)
    return Dem(heights, 400_001.0, 4_600_999.0, 2.0, 2.0, UTM31N)


def fan(lines: int, north0_m: float, step_m: float, height_m: float, east_m: float,
        pixels: int, half_angle_deg: float) -> tuple[F64, F64, F64]:
    """Level flight north; look vectors fanned ±half_angle across track."""
    north = north0_m + step_m * np.arange(lines)
    centre, rot = poses(UTM31N, np.full(lines, east_m), north, np.full(lines, height_m),
                        np.zeros(lines), np.zeros(lines), np.zeros(lines))
    ang = np.radians(np.linspace(-half_angle_deg, half_angle_deg, pixels))
    look = np.stack([np.zeros(pixels), np.tan(ang), -np.ones(pixels)])
    return centre, rot, look


def test_occluding_ridge_and_cliff_give_the_first_intersection() -> None:
    dem = steep_dem()
    """Lines cross the ridge's sections and gaps in turn, so a pixel that saw the ground
    behind the ridge on one line is stopped by the ridge on the next: starting from the
    neighbour's range would find the later crossing."""
    dem = steep_dem()
    centre, rot, look = fan(30, 4_600_300.0, 1.7, 780.0, 400_401.0, 128, 40.0)
    stats = CastStats()
    got = intersect(dem, centre, rot, look, stats=stats)
    assert stats.safe_hit > 0  # the steep parts cannot be certified by the fast path
    assert_matches_reference(dem, centre, rot, look, got)
    on_ridge = got.hit & (np.abs(got.easting_m - 400_321.0) < 4.0) & (got.height_m > 330.0)
    behind_before = np.zeros_like(on_ridge)
    behind_before[1:] = on_ridge[1:] & (got.easting_m[:-1] < 400_314.0)
    assert on_ridge.sum() >= 10
    assert behind_before.sum() >= 3


def test_rays_off_the_dem_into_nodata_or_above_the_horizon_miss(bench_dem: Dem) -> None:
    heights = bench_dem.heights_m.copy()
    heights[300:340, 150:200] = np.nan  # a hole near the strip
    dem = Dem(heights, bench_dem.first_easting_m, bench_dem.first_northing_m,
              bench_dem.cell_e_m, bench_dem.cell_n_m, bench_dem.epsg)
    _w, s, e, n = dem.bounds_m
    hole_e = dem.first_easting_m + 175 * dem.cell_e_m
    hole_n = dem.first_northing_m - 320 * dem.cell_n_m
    top = float(np.nanmax(heights))
    # camera 1: over the hole; camera 2: near the east edge looking out; camera 3: looks up
    east = np.array([hole_e, e - 150.0, hole_e - 800.0])
    north = np.array([hole_n, 0.5 * (s + n), hole_n])
    height = np.full(3, top + 500.0)
    centre, rot = poses(dem.epsg, east, north, height, np.zeros(3), np.zeros(3), np.zeros(3))
    ang = np.radians(np.linspace(-50.0, 50.0, 41))
    look = np.stack([np.zeros(41), np.tan(ang), -np.ones(41)])
    up = np.array([[0.0, 0.0], [0.3, -0.3], [1.0, 1.0]])  # camera z is up
    got = intersect(dem, centre, rot, look)
    assert not got.hit[0, 15:26].any()  # straight down into the hole
    assert got.hit[0, :3].all()
    assert got.hit[0, -3:].all()
    assert not got.hit[1, :8].any()
    assert got.hit[1, -8:].all()
    assert_matches_reference(dem, centre, rot, look, got)
    sky = intersect(dem, centre, rot, up)
    assert not sky.hit.any()
    assert np.isnan(sky.easting_m).all()


def test_sparse_lines_flown_east_match_the_reference(bench_dem: Dem) -> None:
    """Lines 6 m apart flown east, along the DEM's rows: the start range (the previous line's)
    is poorer than on dense lines, so a first Newton step can leave the cell it started in
    (the ray restarts from there), and the prefetched cells run down the columns."""
    w, s, _, n = bench_dem.bounds_m
    lines = 60
    rng = np.random.default_rng(5)
    east = w + 400.0 + 6.0 * np.arange(lines)
    north = np.full(lines, 0.5 * (s + n))
    height = np.full(lines, float(np.nanmax(bench_dem.heights_m)) + 900.0)
    att = np.radians(0.3) * np.cumsum(rng.standard_normal((3, lines)), axis=1) / 5.0
    centre, rot = poses(bench_dem.epsg, east, north, height, att[0], att[1],
                        att[2] + np.pi / 2)
    look = ScannerGeometry().look_vectors_camera()
    stats = CastStats()
    got = intersect(bench_dem, centre, rot, look, stats=stats)
    assert got.hit.all()
    assert stats.fast > 0.99 * got.hit.size
    lines_checked = np.array([1, 29, 59])
    sub = GroundPoints(got.easting_m[lines_checked], got.northing_m[lines_checked],
                       got.height_m[lines_checked], got.hit[lines_checked])
    assert_matches_reference(bench_dem, centre[lines_checked], rot[lines_checked], look, sub)


def alpine_dem(relief_m: float) -> Dem:
    """12 km × 3 km at 5 m cells: a valley floor at 600 m rising `relief_m` along north, with
    ±150 m ribs across it (slopes up to ~1 m/m)."""
    rows, cols, cell = 2400, 600, 5.0
    n = np.arange(rows)[:, None] * cell
    e = np.arange(cols)[None, :] * cell
    h = (600.0 + relief_m / 2 * (1 - np.cos(2 * np.pi * n / 12_000.0))
         + 150.0 * np.sin(2 * np.pi * e / 1500.0) * np.sin(2 * np.pi * n / 900.0))
    return Dem(h.astype(np.float32), 400_001.0, 4_600_000.0 + rows * cell - 1, cell, cell, UTM31N)


def test_alpine_relief_keeps_the_fast_path_and_the_reference_answer() -> None:
    """3.8 km of relief in one DEM: each block's map spans the terrain its rays can meet, not
    the whole DEM's range. Before, every map missed its tolerance and every ray took the
    reference method (1 M rays: 430 s against ~1 s)."""
    dem = alpine_dem(3500.0)
    assert np.ptp(dem.heights_m) > 3700.0
    centre, rot, look = strip(dem, 240, 1000.0, seed=3, step_m=45.0)  # 10.8 km of the valley
    stats = CastStats()
    got = intersect(dem, centre, rot, look, stats=stats)
    assert stats.exact == 0
    assert stats.fast > 0.9 * got.hit.size
    assert stats.map_error_m <= 3e-5
    lines = np.array([0, 61, 130, 239])  # valley floor, slope and the high end
    sub = GroundPoints(got.easting_m[lines], got.northing_m[lines], got.height_m[lines],
                       got.hit[lines])
    ref = assert_matches_reference(dem, centre[lines], rot[lines], look, sub)
    assert np.ptp(ref.height_m[ref.hit]) > 2000.0


def test_every_compiled_loop_is_in_the_kernel_file() -> None:
    """numba's on-disk cache is invalidated only by a change to the cached function's own file:
    a compiled function elsewhere in the package calling the kernel's (or taking its constants)
    would go on running stale code after the kernel changed. So only kernel.py compiles."""
    package = Path(intersect.__code__.co_filename).parent
    assert (package / "kernel.py").is_file()
    for path in sorted(package.glob("*.py")):
        if path.name != "kernel.py":
            text = path.read_text(encoding="utf-8")
            assert not any(word in text for word in ("njit", "intrinsic", "@_jit")), path.name


def _cpu_has_avx2_and_fma() -> bool:
    flags = set()
    for line in Path("/proc/cpuinfo").read_text(encoding="utf-8").splitlines():
        if line.startswith("flags"):
            flags.update(line.split(":", 1)[1].split())
    return {"avx2", "fma"} <= flags


def test_the_c_kernel_is_built_and_used_where_the_cpu_can_run_it() -> None:
    """The C tests below skip only on a CPU without AVX2/FMA: on one that has them (this
    machine, CI's) an extension that failed to build must not pass as a silent fallback."""
    if not Path("/proc/cpuinfo").is_file():
        pytest.skip("no /proc/cpuinfo to ask the CPU's features")
    assert (fastpath.LIB is not None) == _cpu_has_avx2_and_fma()


@pytest.fixture(params=["c", "numba"])
def kernel_path(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """Each test taking this runs on both fast paths: the C one (AVX2 + FMA; skipped where this
    CPU or build has none) and numba's, the fallback."""
    if request.param == "c" and fastpath.LIB is None:
        pytest.skip("the C fast path is not built or this CPU lacks AVX2/FMA")
    if request.param == "numba":
        monkeypatch.setattr(fastpath, "LIB", None)
    return str(request.param)


def test_fast_path_within_a_tenth_of_a_millimetre_on_steep_slopes_and_strip_edges(
        kernel_path: str) -> None:
    """The accuracy the fast path is held to (issue 38: < 0.1 mm against the float64
    reference), on every pixel of lines over ribs with slopes up to ~1 m/m, both strip edges
    included: the float32 Newton steps (with fused multiply-adds) keep it, in C and numba."""
    dem = alpine_dem(1000.0)
    centre, rot, look = strip(dem, 120, 1000.0, seed=6, step_m=1.5)
    stats = CastStats()
    got = intersect(dem, centre, rot, look, stats=stats)
    assert stats.fast > 0.9 * got.hit.size
    lines = np.array([0, 1, 47, 119])
    sub = GroundPoints(got.easting_m[lines], got.northing_m[lines], got.height_m[lines],
                       got.hit[lines])
    ref = assert_matches_reference(dem, centre[lines], rot[lines], look, sub)
    dr, d3 = range_and_distance_m(dem, centre[lines], sub, ref)
    assert d3.size == sub.hit.size
    assert d3.max() < 1e-4
    assert dr.max() < 1e-4


@pytest.mark.skipif(fastpath.LIB is None, reason="the C fast path is not built or this CPU "
                    "lacks AVX2/FMA")
@pytest.mark.parametrize("terrain", ["alpine", "steep"])
def test_the_c_and_numba_paths_agree(terrain: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Which kernel a CPU runs changes no hit and moves no point by 0.1 mm: on alpine ribs
    (slopes to ~1 m/m, some rays on the safe path) and on the ridge and cliff (many)."""
    if terrain == "alpine":
        dem = alpine_dem(1000.0)
        centre, rot, look = strip(dem, 200, 1000.0, seed=6, step_m=1.5)
    else:
        dem = steep_dem()
        centre, rot, look = fan(40, 4_600_300.0, 1.7, 780.0, 400_401.0, 128, 40.0)
    got: dict[str, tuple[GroundPoints, CastStats]] = {}
    for path in ("c", "numba"):
        if path == "numba":
            monkeypatch.setattr(fastpath, "LIB", None)
        stats = CastStats()
        got[path] = intersect(dem, centre, rot, look, stats=stats), stats
    (c, c_stats), (nb, nb_stats) = got["c"], got["numba"]
    np.testing.assert_array_equal(c.hit, nb.hit)
    assert c.hit.any()
    d3 = np.sqrt((c.easting_m - nb.easting_m) ** 2 + (c.northing_m - nb.northing_m) ** 2
                 + (c.height_m - nb.height_m) ** 2)[c.hit]
    assert d3.max() < 1e-4
    if terrain == "steep":  # the safe path ran after the C one
        assert c_stats.safe_hit > 0
    assert abs(c_stats.fast - nb_stats.fast) < 0.01 * c.hit.size
