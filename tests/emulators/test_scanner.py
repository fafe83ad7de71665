"""The scanner emulator against independent oracles: its own truth table for the line clock, the
acquisition's HeaderStreamDecoder for the wire, GDAL (through rasterio) for the recording, pyproj
and hand-worked poses for the geometry, and a slow pyproj ray march (exact_ground_point) for the
fast ray–DEM intersection and for what the rendered image must show."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rasterio
from pyproj import Geod, Transformer

from acquisition.codec import DecodeStats
from acquisition.pulses import Edge, PulseLine
from acquisition.scanner_header import FrameHeader, HeaderStreamDecoder, ScannerMode
from emulators.faults import fault_table
from emulators.render import (
    GroundIntersector,
    LineRenderer,
    MapPolynomial,
    camera_pose_ecef,
    exact_ground_point,
    pixel_rays_ecef,
    quicklook_bands,
    read_envi_header,
    write_quicklook_png,
)
from emulators.runtime import Output, Port, Runner
from emulators.scanner import ScannerEmulator
from emulators.scenario import Scenario, load_scenario, scenario_from_table
from emulators.terrain import Scene, Terrain, band_centres_nm
from emulators.trajectory import TrajectoryState, TruthTrajectory
from emulators.truth import TruthTable
from sisa.core.frames import ned_to_ecef_matrix

SHORT = {"block": {"strip_length_m": 600.0}}  # two 10 s strips: 625 lines each
# A raw scanner recording has no georeferencing, and GDAL says so when it opens one.
pytestmark = pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")


def bench_with(**tables: dict[str, Any]) -> Scenario:
    table: dict[str, Any] = {"base": "bench", **SHORT}
    for key, value in tables.items():
        table[key] = {**table.get(key, {}), **value}
    return scenario_from_table(table)


@dataclass
class Run:
    scn: Scenario
    traj: TruthTrajectory
    dev: ScannerEmulator
    outputs: list[Output]
    faults: TruthTable
    folder: Path | None

    def edges(self) -> list[Edge]:
        return [o.payload for o in self.outputs if isinstance(o.payload, Edge)]

    def serial(self) -> list[Output]:
        return [o for o in self.outputs if o.port is Port.SCANNER_SERIAL]

    def truth(self, name: str) -> np.ndarray:
        return self.dev.frames.column(name)


def run_scanner(scn: Scenario, folder: Path | None = None, terrain: Terrain | None = None,
                scene: Scene | None = None, traj: TruthTrajectory | None = None) -> Run:
    traj = traj or TruthTrajectory.from_scenario(scn)
    faults = fault_table()
    dev = ScannerEmulator(scn, traj, terrain, scene, np.random.default_rng(scn.seed), faults,
                          folder)
    outputs: list[Output] = []

    def sink(out: Output) -> list[Edge]:
        outputs.append(out)
        return []

    Runner([dev], sink).run()
    return Run(scn, traj, dev, outputs, faults, folder)


@pytest.fixture(scope="module")
def world() -> tuple[Scenario, TruthTrajectory, Terrain, Scene]:
    scn = bench_with(faults={"dropped_frame_fraction": 0.02})
    terrain = Terrain.from_scenario(scn)
    return scn, TruthTrajectory.from_scenario(scn), terrain, Scene.from_scenario(scn, terrain)


@pytest.fixture(scope="module")
def recorded(world: tuple[Scenario, TruthTrajectory, Terrain, Scene],
             tmp_path_factory: pytest.TempPathFactory) -> Run:
    scn, traj, terrain, scene = world
    return run_scanner(scn, tmp_path_factory.mktemp("scanner"), terrain, scene, traj)


def decode_headers(run: Run, chunk_seed: int = 0) -> tuple[list[FrameHeader], DecodeStats]:
    """Every header byte, in time order, through the acquisition's decoder in random chunks."""
    stream = b"".join(bytes(o.payload) for o in run.serial())  # type: ignore[arg-type]
    rng = np.random.default_rng(chunk_seed)
    decoder = HeaderStreamDecoder()
    headers: list[FrameHeader] = []
    at = 0
    while at < len(stream):
        step = int(rng.integers(1, 40))
        headers += [d.message for d in decoder.feed(stream[at:at + step])]
        at += step
    headers += [d.message for d in decoder.finish()]
    return headers, decoder.stats


# --- line clock and pulses -----------------------------------------------------------------------


@pytest.mark.parametrize(("drift_ppm", "jitter_ns"), [(15.0, 50.0), (-250.0, 2000.0)])
def test_ppf_edges_follow_the_drifting_jittery_line_clock(drift_ppm: float, jitter_ns: float
                                                          ) -> None:
    scn = bench_with(scanner={"line_clock_drift_ppm": drift_ppm,
                              "line_clock_jitter_ns": jitter_ns})
    run = run_scanner(scn)
    edges = run.edges()
    assert all(e.line is PulseLine.PPF for e in edges)
    t_edge = np.array([e.t_ns for e in edges])
    assert np.array_equal(t_edge, np.sort(run.truth("t_mid_gps_ns")))  # one edge per frame
    period_ns = scn.scanner.line_period_ms * 1e6
    for seg, strip in enumerate(run.traj.strips):
        t = run.truth("t_mid_gps_ns")[run.truth("segment") == seg]
        assert strip.t_start_ns - 8 * jitter_ns <= t[0] < strip.t_start_ns + period_ns * 1.001
        assert t[-1] <= strip.t_end_ns + 8 * jitter_ns
        k = np.arange(t.size)
        slope, _ = np.polyfit(k, (t - t[0]).astype(float), 1)
        assert abs((slope / period_ns - 1.0) * 1e6 - drift_ppm) < 1.0
        resid = (t - t[0]) - slope * k
        assert np.std(resid - resid.mean()) == pytest.approx(jitter_ns, rel=0.15)


def test_headers_decode_in_order_after_each_frame_is_read_out(recorded: Run) -> None:
    headers, stats = decode_headers(recorded)
    kept = recorded.truth("dropped") == 0
    assert (stats.errors, stats.bytes_skipped, stats.messages) == (0, 0, kept.sum())
    assert [h.frame_counter for h in headers] == recorded.truth("frame_counter")[kept].tolist()
    assert [h.segment for h in headers] == recorded.truth("segment")[kept].tolist()
    sc = recorded.scn.scanner
    assert {(h.mode, h.bands, h.integration_time_us) for h in headers} == {
        (ScannerMode.RECORDING, sc.bands, round(sc.integration_time_ms * 1000))}
    t_hdr = np.array([o.t_ns for o in recorded.serial()])
    delay_ms = (t_hdr - recorded.truth("t_mid_gps_ns")[kept]) / 1e6 - sc.integration_time_ms / 2
    assert delay_ms.min() >= 1.0 - 1e-6
    assert delay_ms.max() <= 3.0 + 1e-6
    assert np.all(np.diff(t_hdr) > 0)


def test_counters_are_consecutive_except_dropped_frames(recorded: Run) -> None:
    dropped = recorded.truth("dropped") == 1
    assert dropped.sum() > 5  # the profile drops 2 % of about 1250 frames
    counters = recorded.truth("frame_counter")
    assert np.array_equal(counters, np.arange(counters.size))  # across both segments
    headers, _ = decode_headers(recorded, chunk_seed=3)
    gaps = np.diff([h.frame_counter for h in headers]) - 1
    assert np.array_equal(gaps, np.diff(np.flatnonzero(~dropped)) - 1)


def test_frame_counter_wraps_and_runs_on_across_segments() -> None:
    run = run_scanner(bench_with(scanner={"frame_counter_bits": 8}))
    counters = run.truth("frame_counter")
    assert counters.size > 1000
    assert np.array_equal(counters, np.arange(counters.size) % 256)
    seg = run.truth("segment")
    first_of_1 = int(np.argmax(seg == 1))
    assert counters[first_of_1] == (counters[first_of_1 - 1] + 1) % 256
    headers, _ = decode_headers(run)
    assert [h.frame_counter for h in headers] == counters.tolist()


def test_timing_does_not_depend_on_rendering(recorded: Run) -> None:
    fast = run_scanner(recorded.scn, traj=recorded.traj)
    for col in ("t_mid_gps_ns", "frame_counter", "dropped", "line_index"):
        assert np.array_equal(fast.truth(col), recorded.truth(col))
    assert fast.dev.renderer is None


# --- the recording --------------------------------------------------------------------------------


def test_dropped_frames_leave_no_line_and_are_in_the_truth(recorded: Run) -> None:
    assert recorded.folder is not None
    dropped = recorded.truth("dropped") == 1
    assert np.all(recorded.truth("line_index")[dropped] == -1)
    faults = recorded.faults
    assert set(faults.column("kind")) == {"dropped_frame"}
    assert np.array_equal(faults.column("t_gps_ns"), recorded.truth("t_mid_gps_ns")[dropped])
    assert len(recorded.edges()) == recorded.dev.frames_exposed  # the exposure still happened
    for seg in range(len(recorded.traj.strips)):
        rows = (recorded.truth("segment") == seg) & ~dropped
        lines = np.loadtxt(recorded.folder / f"segment_{seg:03d}.lines.csv", delimiter=",",
                           comments="#", skiprows=6, dtype=np.int64)
        assert np.array_equal(lines[:, 0], recorded.truth("line_index")[rows])
        assert np.array_equal(lines[:, 1], recorded.truth("frame_counter")[rows])
        assert int(read_envi_header(recorded.folder / f"segment_{seg:03d}.hdr")["lines"]) \
            == rows.sum()


def test_bil_opens_in_gdal_with_the_right_shape_and_wavelengths(recorded: Run) -> None:
    assert recorded.folder is not None
    sc = recorded.scn.scanner
    bil = recorded.folder / "segment_001.bil"
    lines = int(((recorded.truth("segment") == 1) & (recorded.truth("dropped") == 0)).sum())
    assert bil.stat().st_size == lines * sc.bands * sc.pixels * 2
    raw = np.fromfile(bil, dtype="<u2").reshape(lines, sc.bands, sc.pixels)
    with rasterio.open(bil) as ds:
        assert ds.driver == "ENVI"
        assert (ds.count, ds.height, ds.width) == (sc.bands, lines, sc.pixels)
        assert ds.dtypes == ("uint16",) * sc.bands
        assert ds.nodata == 0
        # one wavelength per description (issue 33: "band 1 (495.0 nm) (495.00 Nanometers)",
        # the header's name holding it and GDAL appending it again)
        assert ds.descriptions == tuple(f"band {b + 1} ({w:.2f} Nanometers)"
                                        for b, w in enumerate(band_centres_nm(sc.bands)))
        cube = ds.read()
    assert np.array_equal(np.moveaxis(cube, 0, 1), raw)  # band-interleaved by line
    hdr = read_envi_header(bil.with_suffix(".hdr"))
    wl = np.array([float(x) for x in hdr["wavelength"].split(",")])
    assert np.allclose(wl, band_centres_nm(sc.bands), atol=0.01)
    assert (hdr["interleave"], hdr["byte order"], hdr["data type"]) == ("bil", "0", "12")
    assert raw[raw > 0].min() > 0
    assert raw.max() < 4096


def test_recording_is_written_as_it_goes_and_closed_cleanly(
        world: tuple[Scenario, TruthTrajectory, Terrain, Scene], tmp_path: Path) -> None:
    scn, traj, terrain, scene = world
    dev = ScannerEmulator(scn, traj, terrain, scene, np.random.default_rng(1), fault_table(),
                          tmp_path, block_lines=64)
    line_bytes = scn.scanner.bands * scn.scanner.pixels * 2
    while (t := dev.next_time_ns()) is not None and t < traj.strips[0].t_start_ns + 4e9:
        dev.emit(t)
    hdr_lines = int(read_envi_header(tmp_path / "segment_000.hdr")["lines"])
    assert 0 < hdr_lines < 625
    assert (tmp_path / "segment_000.bil").stat().st_size == hdr_lines * line_bytes
    dev.finish()
    dev.finish()  # idempotent
    exposed = int((dev.frames.column("line_index") >= 0).sum())
    assert hdr_lines <= exposed < hdr_lines + 64  # written by whole blocks, the rest at the end
    assert not (tmp_path / "segment_001.bil").exists()  # stopped before the second strip
    with rasterio.open(tmp_path / "segment_000.bil") as ds:
        assert ds.height == exposed
    assert int(read_envi_header(tmp_path / "segment_000.hdr")["lines"]) == exposed


def test_a_run_stopped_early_records_only_the_frames_it_exposed(
        world: tuple[Scenario, TruthTrajectory, Terrain, Scene], tmp_path: Path) -> None:
    """Frames are scheduled and rendered a block ahead; `sisa emulate --duration` (or Ctrl-C)
    stopping inside a block left that block's later frames in the BIL and the truth, exposed
    and not dropped, though their PPF never went out."""
    scn, traj, terrain, scene = world
    dev = ScannerEmulator(scn, traj, terrain, scene, np.random.default_rng(1), fault_table(),
                          tmp_path, block_lines=64)
    outputs: list[Output] = []

    def sink(out: Output) -> list[Edge]:
        outputs.append(out)
        return []

    until_ns = traj.strips[0].t_start_ns + 1_500_000_000 + 3_000_000  # inside a block
    Runner([dev], sink).run(until_ns=until_ns)
    ppf = [o.payload.t_ns for o in outputs if isinstance(o.payload, Edge)]
    t_mid = dev.frames.column("t_mid_gps_ns")
    assert len(t_mid) == len(ppf) > 64  # every frame whose PPF went out, and no other
    assert np.array_equal(t_mid, ppf)
    assert t_mid.max() <= until_ns
    kept = int((dev.frames.column("dropped") == 0).sum())
    line_bytes = scn.scanner.bands * scn.scanner.pixels * 2
    assert (tmp_path / "segment_000.bil").stat().st_size == kept * line_bytes
    assert int(read_envi_header(tmp_path / "segment_000.hdr")["lines"]) == kept
    lines_csv = (tmp_path / "segment_000.lines.csv").read_text().splitlines()
    assert len([ln for ln in lines_csv if ln[:1].isdigit()]) == kept


def test_fast_mode_renders_nothing() -> None:
    run = run_scanner(bench_with())
    assert run.dev.renderer is None
    assert run.dev.missed_pixels == 0
    assert len(run.serial()) == run.dev.frames_exposed


# --- geometry and rendering -----------------------------------------------------------------------


def _level_state(lat_deg: float, lon_deg: float, height_m: float, heading_deg: float
                 ) -> TrajectoryState:
    x, y, z = Transformer.from_crs(4979, 4978, always_xy=True).transform(lon_deg, lat_deg,
                                                                         height_m)
    one = np.ones(1)
    return TrajectoryState(np.zeros(1, np.int64), lat_deg * one, lon_deg * one, height_m * one,
                           np.array([[x, y, z]]), np.zeros((1, 3)), np.zeros((1, 3)), 0 * one,
                           0 * one, math.radians(heading_deg) * one, np.zeros((1, 3)))


def test_camera_pose_by_hand_level_flight() -> None:
    """Heading 90° (east), level: camera x → east, camera y (left) → north, camera −z → down,
    and the 0.3 m lever arm (body z, down) puts the perspective centre 0.3 m lower."""
    scn = load_scenario("bench")
    lat, lon = 41.6, 2.0
    centre, r_ce = camera_pose_ecef(_level_state(lat, lon, 900.0, 90.0), scn.mounting)
    sl, cl, so, co = (math.sin(math.radians(lat)), math.cos(math.radians(lat)),
                      math.sin(math.radians(lon)), math.cos(math.radians(lon)))
    east = np.array([-so, co, 0.0])
    north = np.array([-sl * co, -sl * so, cl])
    up = np.array([cl * co, cl * so, sl])
    assert np.allclose(r_ce[0] @ [1, 0, 0], east, atol=1e-12)
    assert np.allclose(r_ce[0] @ [0, 1, 0], north, atol=1e-12)
    assert np.allclose(r_ce[0] @ [0, 0, -1], -up, atol=1e-12)
    ins = _level_state(lat, lon, 900.0, 90.0).ecef_m[0]
    assert np.allclose(centre[0] - ins, -0.3 * up, atol=1e-9)


def test_pixel_zero_images_right_of_track_at_the_nominal_ground_sample(
        world: tuple[Scenario, TruthTrajectory, Terrain, Scene]) -> None:
    scn, traj, terrain, _ = world
    strip = traj.strips[0]
    t = np.full(3, (strip.t_start_ns + strip.t_end_ns) // 2)
    state = traj.state(t)
    pixels = [0, 255, 256]
    c, d = pixel_rays_ecef(state, scn.scanner, scn.mounting, pixels)
    ground = exact_ground_point(terrain, c, d)
    lat, lon = Transformer.from_crs(terrain.epsg, 4326, always_xy=True).transform(
        ground[:, 0], ground[:, 1])[::-1]
    geod = Geod(ellps="WGS84")
    az, _, dist = geod.inv(lon[[1, 1]], lat[[1, 1]], lon[[0, 2]], lat[[0, 2]])
    heading = math.degrees(state.heading_rad[0])
    assert (az[0] - heading) % 360 == pytest.approx(90.0, abs=2.0)  # pixel 0: right wing side
    agl = state.height_m[0] - ground[1, 2]
    half_fov = math.atan(255.0 * 15e-6 / 9.33e-3)
    assert dist[0] == pytest.approx(agl * math.tan(half_fov), rel=0.05)
    assert dist[1] == pytest.approx(agl * 15e-6 / 9.33e-3, rel=0.05)  # one pixel across


@pytest.mark.parametrize("preset", ["bench", "garrotxa"])
def test_fast_intersection_matches_the_exact_reference(preset: str) -> None:
    """A few hundred rays at random times and pixels of every strip, 0.6 km (bench) and 2.2 km
    (Garrotxa: curvature and UTM scale matter) from the ground: within 5 cm of the oracle."""
    scn = load_scenario(preset)
    traj, terrain = TruthTrajectory.from_scenario(scn), Terrain.from_scenario(scn)
    rng = np.random.default_rng(7)
    t = np.sort(np.concatenate([rng.integers(s.t_start_ns, s.t_end_ns, 300 // len(traj.strips))
                                for s in traj.strips]))
    state = traj.state(t)
    c, d = pixel_rays_ecef(state, scn.scanner, scn.mounting,
                           rng.integers(0, scn.scanner.pixels, t.size))
    fast = GroundIntersector(terrain).intersect_rays(c, d)
    exact = exact_ground_point(terrain, c, d)
    assert not np.isnan(exact).any()
    err_m = np.linalg.norm(fast - exact, axis=1)
    assert err_m.max() <= 0.05
    assert np.allclose(fast[:, 2], terrain.height_at(fast[:, 0], fast[:, 1]), atol=1e-3)


def test_a_camera_below_the_highest_hill_still_finds_the_ground(
        world: tuple[Scenario, TruthTrajectory, Terrain, Scene]) -> None:
    """30 m above the lowest DEM cell, below the highest: rays fanned out to 40° off nadir."""
    _, _, terrain, _ = world
    r, c = np.unravel_index(np.argmin(terrain.heights[50:-50, 50:-50]), (
        terrain.heights.shape[0] - 100, terrain.heights.shape[1] - 100))
    t = terrain.transform
    e, n = t.c + (c + 50.5) * t.a, t.f + (r + 50.5) * t.e
    h = float(terrain.heights[r + 50, c + 50]) + 30.0
    assert h < terrain.heights.max()
    lon, lat = Transformer.from_crs(terrain.epsg, 4326, always_xy=True).transform(e, n)
    state = _level_state(lat, lon, h, 0.0)
    off, az = np.meshgrid(np.radians([0.0, 10.0, 25.0, 40.0]), np.radians(np.arange(0, 360, 30)))
    ned = np.stack([np.sin(off) * np.cos(az), np.sin(off) * np.sin(az), np.cos(off)], -1)
    r_ne = ned_to_ecef_matrix(math.radians(lat), math.radians(lon))
    d = ned.reshape(-1, 3) @ r_ne.T
    centre = np.repeat(state.ecef_m, d.shape[0], axis=0)
    fast = GroundIntersector(terrain).intersect_rays(centre, d)
    exact = exact_ground_point(terrain, centre, d)
    assert not np.isnan(exact).any()
    assert np.linalg.norm(fast - exact, axis=1).max() <= 0.05


def test_map_polynomial_matches_pyproj_at_fresh_points() -> None:
    scn = load_scenario("garrotxa")
    gi = GroundIntersector(Terrain.from_scenario(scn))
    poly: MapPolynomial = gi.map
    lo, hi = poly.centre_m - 1 / poly.scale_per_m, poly.centre_m + 1 / poly.scale_per_m
    enu = np.random.default_rng(99).uniform(lo, hi, (500, 3))
    ecef = gi.frame.to_ecef(enu)
    lon, lat, h = Transformer.from_crs(4978, 4979, always_xy=True).transform(*ecef.T)
    e, n = Transformer.from_crs(4326, gi.epsg, always_xy=True).transform(lon, lat)
    assert np.abs(poly(enu) - np.stack([e, n, h], axis=-1)).max() < 1e-3


def test_rays_that_miss_the_dem_are_counted_and_black(
        world: tuple[Scenario, TruthTrajectory, Terrain, Scene]) -> None:
    scn, _, terrain, scene = world
    renderer = LineRenderer(scn.scanner, scn.mounting, terrain, scene, np.random.default_rng(0))
    far = _level_state(scn.block.centre_lat_deg + 0.5, scn.block.centre_lon_deg, 900.0, 0.0)
    dn = renderer.render(far)
    assert dn.shape == (1, scn.scanner.bands, scn.scanner.pixels)
    assert not dn.any()
    assert renderer.missed_rays == renderer.rays == scn.scanner.pixels
    gi = renderer.intersector
    up = gi.intersect_rays(far.ecef_m, far.ecef_m / np.linalg.norm(far.ecef_m))
    assert np.isnan(up).all()


def test_rendered_lines_show_the_scene_where_the_exact_model_says(
        recorded: Run, world: tuple[Scenario, TruthTrajectory, Terrain, Scene]) -> None:
    """DN of sampled pixels against the scene radiance at their EXACT ground points: strongly
    correlated; the same pixels mirrored across the line are not (the test can tell)."""
    assert recorded.folder is not None
    scn, traj, terrain, scene = world
    with rasterio.open(recorded.folder / "segment_000.bil") as ds:
        cube = ds.read()
    rng = np.random.default_rng(11)
    lines = rng.integers(0, cube.shape[1], 400)
    pixels = rng.integers(0, cube.shape[2], 400)
    rows = (recorded.truth("segment") == 0) & (recorded.truth("dropped") == 0)
    t_mid = recorded.truth("t_mid_gps_ns")[rows][lines]
    state = traj.state(t_mid)

    def radiance_at(pix: np.ndarray) -> np.ndarray:
        c, d = pixel_rays_ecef(state, scn.scanner, scn.mounting, pix)
        g = exact_ground_point(terrain, c, d)
        return scene.radiance(g[:, 0], g[:, 1])

    dn = cube[:, lines, pixels].astype(float)
    right = radiance_at(pixels)
    mirrored = radiance_at(scn.scanner.pixels - 1 - pixels)
    for b in range(scn.scanner.bands):
        assert np.corrcoef(dn[b], right[b])[0, 1] > 0.95  # brief: > 0.8; measured 0.999
        assert np.corrcoef(dn[b], mirrored[b])[0, 1] < 0.5


def test_quicklook_png(recorded: Run, tmp_path: Path) -> None:
    assert recorded.folder is not None
    png = tmp_path / "q.png"
    write_quicklook_png(recorded.folder / "segment_000.bil", png, max_size_px=300)
    with rasterio.open(png) as ds:
        rgb = ds.read()
    lines = int(read_envi_header(recorded.folder / "segment_000.hdr")["lines"])
    k = math.ceil(lines / 300)
    assert rgb.shape == (3, lines // k, 512 // k)
    assert all(np.ptp(rgb[c]) > 150 for c in range(3))


def test_quicklook_bands_true_colour_or_colour_infrared() -> None:
    assert quicklook_bands(band_centres_nm(8)) == [3, 1, 0]  # 658, 528, 463 nm: true colour
    assert quicklook_bands(band_centres_nm(4)) == [3, 1, 0]  # 885, 625, 495 nm: NIR, red, green
    assert quicklook_bands(band_centres_nm(19)) == [7, 4, 1]
