"""Simulated image measurements of ground points, from a simulated run's TRUTH.

What a photogrammetric operator would measure on the images of a run, made without images: for
each ground point and each segment, the true pose (emulators.trajectory + render.camera_pose_ecef,
the emulator's forward model, not postproc's) and the true scanner geometry give the instant the
point crosses the scan line (u = x0 + δx0, solved on the true trajectory) and the pixel it falls
on; the instant becomes a fractional line through the TRUE line times (truth/frames.csv),
shifted by an injected delay: a line tagged t was really exposed at t + delay. Then Gaussian
noise (σ px), optional blunders, survey noise on the control/check coordinates, and tie points in
strip overlaps (on the run's DEM). A point is kept in at most `max_views` segments (one or two,
as in seed 000), its most central views; `single_view_control` control points, those nearest
the block's border, in one only (seed 000 §6: 97 of Garrotxa's 111 ground points "have only 1
photogrammetric observation, these points are identified on the block borders"). Truth is read
here only; post-processing gets the measurements.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt
from pyproj import Transformer
from scipy.spatial import ConvexHull

from emulators.render import camera_pose_ecef
from emulators.scenario import Scenario, load_scenario
from emulators.trajectory import TruthTrajectory
from emulators.truth import read_truth_csv
from postproc.calibration import GroundPoints, ImageObservations
from postproc.georef import Dem, ecef_to_geodetic, geodetic_to_ecef
from sisa.core.errors import InputError
from sisa.core.framecamera import FrameMounting
from sisa.core.frames import body_to_ned_matrix, ned_to_ecef_matrix
from sisa.core.sensor import ARCSEC_RAD, R_NOMINAL_C_TO_B, Mounting
from sisa.wiring.accuracy import run_trajectory

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

COARSE_STEP_NS: Final = 1_000_000_000
NEWTON_STEPS: Final = 8
TIE_CANDIDATES: Final = 6  # candidates drawn per wanted tie point


@dataclass(frozen=True)
class SimSettings:
    noise_px: float = 0.3
    max_views: int = 2
    single_view_control: int = 0  # control points nearest the border measured in one image
    tie_points: int = 0
    delay_ms: float = 0.0  # true exposure − line tag
    gcp_noise_m: tuple[float, float] = (0.0, 0.0)  # survey error σ, horizontal and vertical
    blunders: int = 0
    blunder_px: float = 20.0
    seed: int = 0
    # the DEM's own error at the tie points: their true heights are off the DEM by this σ
    tie_height_noise_m: float = 0.0


@dataclass(frozen=True)
class SimulatedObservations:
    obs: ImageObservations
    points: GroundPoints  # what the adjustment gets: surveyed (noisy) coordinates, ties unknown
    true_points: GroundPoints  # the true coordinates, ties included
    blunder_rows: I64
    truth: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class TruthSegment:
    number: int
    line: I64
    t_ns: I64


@dataclass(frozen=True)
class FlightTruth:
    """What the measurements are made from: the scenario, its true trajectory, the true line
    times of every segment, the DEM, and the INS's drawn attitude errors (roll, pitch, heading:
    bias ″ and drift ″/h; None: none known)."""

    scn: Scenario
    traj: TruthTrajectory
    segments: list[TruthSegment]
    dem: Dem
    ins_bias_arcsec: F64 | None = None
    ins_drift_arcsec_per_h: F64 | None = None


def flight_truth(run: Path) -> FlightTruth:
    """A simulated run folder's truth (scenario, truth/frames.csv, terrain/dem.tif,
    truth/ins_errors.csv)."""
    scn = load_scenario(run / "scenario.toml")
    segs = truth_segments(run)
    traj = run_trajectory(run, scn, np.concatenate([s.t_ns for s in segs]) if segs
                          else np.zeros(0, np.int64))
    bias = drift = None
    err_path = run / "truth" / "ins_errors.csv"
    if err_path.is_file():
        e = read_truth_csv(err_path)
        bias = np.asarray(e["bias_arcsec"][:3], np.float64)
        drift = np.asarray(e["drift_arcsec_per_h"][:3], np.float64)
    return FlightTruth(scn, traj, segs, Dem.read(run / "terrain" / "dem.tif"), bias, drift)


def truth_segments(run: Path) -> list[TruthSegment]:
    path = run / "truth" / "frames.csv"
    if not path.is_file():
        raise InputError(f"{run}: no truth/frames.csv: not a simulated run folder")
    fr = read_truth_csv(path)
    keep = fr["line_index"] >= 0
    out = []
    for s in np.unique(fr["segment"][keep]).tolist():
        sel = keep & (fr["segment"] == s)
        order = np.argsort(fr["line_index"][sel])
        out.append(TruthSegment(int(s), fr["line_index"][sel][order].astype(np.int64),
                            fr["t_mid_gps_ns"][sel][order].astype(np.int64)))
    return out


class TruthProjector:
    """The emulator's forward model for one scenario."""

    def __init__(self, scn: Scenario, traj: TruthTrajectory) -> None:
        sc = scn.scanner
        self.scn, self.traj = scn, traj
        self.f_m = (sc.focal_length_mm + sc.delta_focal_mm) * 1e-3
        self.x0_m = (sc.principal_point_um[0] + sc.delta_principal_point_um[0]) * 1e-6
        self.y0_m = (sc.principal_point_um[1] + sc.delta_principal_point_um[1]) * 1e-6
        self.pitch_m = sc.pixel_pitch_um * 1e-6

    def camera(self, t_ns: I64, x: F64) -> F64:
        """The points x (N, 3, ECEF) in the camera frame at t_ns (N)."""
        centre, r_ce = camera_pose_ecef(self.traj.state(t_ns), self.scn.mounting)
        return np.asarray(np.einsum("nji,nj->ni", r_ce, x - centre), np.float64)

    def misclosure(self, t_ns: I64, x: F64) -> F64:
        p = self.camera(t_ns, x)
        return np.asarray(-self.f_m * p[:, 0] / p[:, 2] - self.x0_m, np.float64)

    def crossing(self, seg: TruthSegment, x: F64) -> tuple[F64, I64]:
        """(pixel, crossing time) of every point in a segment; NaN pixel where unseen."""
        t_lo, t_hi = int(seg.t_ns[0]), int(seg.t_ns[-1])
        grid = np.arange(t_lo, t_hi + 1, COARSE_STEP_NS, dtype=np.int64)
        n, m = x.shape[0], grid.size
        g = self.misclosure(np.repeat(grid, n), np.tile(x, (m, 1))).reshape(m, n)
        sign = np.sign(g)
        change = (sign[:-1] > 0) & (sign[1:] <= 0)
        has = change.any(axis=0)
        k = np.argmax(change, axis=0)
        t = np.where(has, grid[k] + COARSE_STEP_NS // 2, t_lo)
        for _ in range(NEWTON_STEPS):
            h = 1_000_000
            d = (self.misclosure(t + h, x) - self.misclosure(t - h, x)) / (2 * h)
            step = np.where(np.abs(d) > 0, -self.misclosure(t, x) / np.where(d != 0, d, 1.0), 0)
            t = np.clip(t + np.rint(np.clip(step, -2e9, 2e9)).astype(np.int64), t_lo, t_hi)
        p = self.camera(t, x)
        sc = self.scn.scanner
        pixel = sc.centre_pixel + (-self.f_m * p[:, 1] / p[:, 2] - self.y0_m) / self.pitch_m
        ok = has & (p[:, 2] < 0) & (np.abs(self.misclosure(t, x)) < 1e-9) & \
            (pixel >= 0) & (pixel <= sc.pixels - 1)
        return np.where(ok, pixel, np.nan), t


def _fractional_line(seg: TruthSegment, t_tag_ns: I64) -> F64:
    rel = (seg.t_ns - seg.t_ns[0]).astype(np.float64)
    q = (t_tag_ns - seg.t_ns[0]).astype(np.float64)
    inside = (q >= rel[0]) & (q <= rel[-1])
    return np.where(inside, np.interp(q, rel, seg.line.astype(np.float64)), np.nan)


def _views(proj: TruthProjector, segs: list[TruthSegment], x: F64, delay_ns: int
           ) -> list[tuple[int, int, float, float]]:
    """(point row, segment, line, pixel) of every view, exact."""
    out = []
    for seg in segs:
        pixel, t = proj.crossing(seg, x)
        line = _fractional_line(seg, t - delay_ns)
        for i in np.flatnonzero(np.isfinite(pixel) & np.isfinite(line)).tolist():
            out.append((i, seg.number, float(line[i]), float(pixel[i])))
    return out


def _limit_views(views: list[tuple[int, int, float, float]], max_views: int, centre: float,
                 single: frozenset[int] = frozenset()) -> list[tuple[int, int, float, float]]:
    by_point: dict[int, list[tuple[int, int, float, float]]] = {}
    for v in views:
        by_point.setdefault(v[0], []).append(v)
    out = []
    for p, vs in by_point.items():
        out += sorted(vs, key=lambda v: abs(v[3] - centre))[:1 if p in single else max_views]
    return sorted(out, key=lambda v: (v[0], v[1]))


def border_control(points: GroundPoints, count: int) -> frozenset[int]:
    """Rows of the `count` control points nearest the border of the control points' extent
    (their convex hull, on the local horizontal plane)."""
    ctl = np.flatnonzero(points.kind == "control")
    if count <= 0 or ctl.size == 0:
        return frozenset()
    lat, lon, _ = ecef_to_geodetic(points.ecef_m[ctl])
    r = 6_371_000.0
    xy = np.stack([np.radians(lon - lon.mean()) * r * math.cos(math.radians(lat.mean())),
                   np.radians(lat - lat.mean()) * r], axis=1)
    hull = xy[ConvexHull(xy).vertices]
    a, b = hull, np.roll(hull, -1, axis=0)
    ab = b - a
    s = np.clip(np.einsum("pki,ki->pk", xy[:, None, :] - a[None], ab)
                / np.einsum("ki,ki->k", ab, ab), 0.0, 1.0)
    d = np.linalg.norm(xy[:, None, :] - (a[None] + s[..., None] * ab[None]), axis=2).min(axis=1)
    return frozenset(ctl[np.argsort(d, kind="stable")[:count]].tolist())


def _tie_candidates(dem: Dem, points: GroundPoints, n: int, rng: np.random.Generator,
                    height_noise_m: float = 0.0) -> GroundPoints:
    """n·TIE_CANDIDATES points on the DEM (off it by `height_noise_m` σ: the DEM's error)
    inside the control points' extent."""
    lat, lon, _ = ecef_to_geodetic(points.ecef_m)
    to_map = Transformer.from_crs(4326, dem.epsg, always_xy=True)
    e, nn = (np.asarray(v) for v in to_map.transform(lon, lat))
    m = n * TIE_CANDIDATES
    ce = rng.uniform(e.min(), e.max(), m)
    cn = rng.uniform(nn.min(), nn.max(), m)
    h = dem.height_at(ce, cn)
    if height_noise_m > 0:
        h = h + rng.normal(0.0, height_noise_m, h.size)
    ok = np.isfinite(h)
    clon, clat = Transformer.from_crs(dem.epsg, 4326, always_xy=True).transform(ce[ok], cn[ok])
    ids = np.array([f"T{i + 1:05d}" for i in range(int(ok.sum()))])
    return GroundPoints(ids, np.full(ids.size, "tie"),
                        geodetic_to_ecef(np.asarray(clat), np.asarray(clon), h[ok]), dem.epsg)


def _survey_noise(points: GroundPoints, sigma: tuple[float, float], rng: np.random.Generator
                  ) -> GroundPoints:
    if sigma == (0.0, 0.0):
        return points
    lat, lon, _ = ecef_to_geodetic(points.ecef_m)
    r_ne = ned_to_ecef_matrix(np.radians(lat), np.radians(lon))
    ned = rng.normal(0.0, 1.0, (len(points), 3)) * np.array([sigma[0], sigma[0], sigma[1]])
    surveyed = points.kind != "tie"
    ecef = points.ecef_m + np.where(surveyed[:, None], np.einsum("nij,nj->ni", r_ne, ned), 0.0)
    return GroundPoints(points.ids, points.kind, ecef, points.epsg)


def effective_boresight_arcsec(flight: FlightTruth, t_ns: I64,
                               mounting: Mounting | FrameMounting | None = None,
                               r_nominal: F64 = R_NOMINAL_C_TO_B) -> tuple[float, float, float]:
    """The boresight the data can see: the true one composed with the INS's attitude error
    (bias + drift, truth/ins_errors.csv) averaged over the observation times. `mounting` and
    its nominal rotation: the scanner's (default), or the frame camera's."""
    scn, traj = flight.scn, flight.traj
    mounting = scn.mounting if mounting is None else mounting
    bias, drift = flight.ins_bias_arcsec, flight.ins_drift_arcsec_per_h
    if bias is None or drift is None or t_ns.size == 0:
        return tuple(float(a) for a in mounting.boresight_arcsec)  # type: ignore[return-value]
    hours = (t_ns - traj.t_start_ns).astype(np.float64) / 3.6e12
    err = [(bias[k] + drift[k] * hours) * ARCSEC_RAD for k in range(3)]
    st = traj.state(t_ns)
    r_true = body_to_ned_matrix(st.roll_rad, st.pitch_rad, st.heading_rad)
    r_ins = body_to_ned_matrix(st.roll_rad + err[0], st.pitch_rad + err[1],
                               st.heading_rad + err[2])
    r_cb = mounting.boresight_matrix()
    m = np.einsum("nji,njk->nik", r_ins, r_true) @ r_cb  # R_b(ins)^b(true) · R_c^b
    u, _, vt = np.linalg.svd(r_nominal.T @ m.mean(axis=0))
    rot = u @ vt
    phi = math.asin(float(np.clip(rot[0, 2], -1, 1)))
    omega = math.atan2(-float(rot[1, 2]), float(rot[2, 2]))
    kappa = math.atan2(-float(rot[0, 1]), float(rot[0, 0]))
    return (omega / ARCSEC_RAD, phi / ARCSEC_RAD, kappa / ARCSEC_RAD)


def simulate_observations(run: Path, points: GroundPoints, settings: SimSettings
                          ) -> SimulatedObservations:
    """Measurements of `points` (control and check) and of new tie points, from the truth of
    a simulated run folder."""
    return simulate_flight_observations(flight_truth(run), points, settings)


def simulate_flight_observations(flight: FlightTruth, points: GroundPoints,
                                 settings: SimSettings) -> SimulatedObservations:
    """Measurements of `points` (control and check) and of new tie points, from a flight's
    truth (a run folder's, or one built in memory)."""
    scn, segs, traj = flight.scn, flight.segments, flight.traj
    rng = np.random.default_rng([settings.seed, 7])
    pts = points
    if settings.tie_points > 0:
        pts = GroundPoints.concat(points, _tie_candidates(
            flight.dem, points, settings.tie_points, rng, settings.tie_height_noise_m))
    proj = TruthProjector(scn, traj)
    views = _views(proj, segs, pts.ecef_m, round(settings.delay_ms * 1e6))
    views = _limit_views(views, settings.max_views, scn.scanner.centre_pixel,
                         border_control(pts, settings.single_view_control))
    views = _keep_ties(views, pts, settings.tie_points)
    keep = np.zeros(len(pts), dtype=np.bool_)
    keep[[v[0] for v in views]] = True
    keep |= pts.kind != "tie"
    row = np.cumsum(keep) - 1
    true_pts = pts.select(keep)
    n = len(views)
    line = np.array([v[2] for v in views]) + rng.normal(0.0, settings.noise_px, n)
    pixel = np.array([v[3] for v in views]) + rng.normal(0.0, settings.noise_px, n)
    bad = rng.choice(n, min(settings.blunders, n), replace=False) if n else np.zeros(0, int)
    for k in bad.tolist():
        size = settings.blunder_px * rng.choice([-1.0, 1.0]) * rng.uniform(1.0, 1.5)
        if rng.uniform() < 0.5:
            pixel[k] += size
        else:
            line[k] += size
    obs = ImageObservations(true_pts.ids[row[[v[0] for v in views]]],
                            np.array([v[1] for v in views], dtype=np.int64), line, pixel,
                            np.full(n, max(settings.noise_px, 0.05)))
    surveyed = _survey_noise(true_pts, settings.gcp_noise_m, rng)
    adj_pts = GroundPoints(surveyed.ids, surveyed.kind,
                           np.where((surveyed.kind == "tie")[:, None], np.nan, surveyed.ecef_m),
                           surveyed.epsg)
    mid = {s.number: int(s.t_ns[s.t_ns.size // 2]) for s in segs}
    t_obs = np.array([mid[v[1]] for v in views], dtype=np.int64)
    truth = _truth(flight, t_obs, settings)
    return SimulatedObservations(obs, adj_pts, true_pts, np.sort(bad).astype(np.int64), truth)


def _keep_ties(views: list[tuple[int, int, float, float]], pts: GroundPoints, wanted: int
               ) -> list[tuple[int, int, float, float]]:
    """Tie points seen in two segments or more, the first `wanted` of them."""
    segs: dict[int, set[int]] = {}
    for v in views:
        segs.setdefault(v[0], set()).add(v[1])
    ties = [p for p in sorted(segs) if pts.kind[p] == "tie" and len(segs[p]) >= 2][:wanted]
    chosen = set(ties)
    return [v for v in views if pts.kind[v[0]] != "tie" or v[0] in chosen]


def _truth(flight: FlightTruth, t_obs: I64, settings: SimSettings) -> dict[str, Any]:
    scn = flight.scn
    sc, m = scn.scanner, scn.mounting
    return {
        "boresight_arcsec": list(m.boresight_arcsec),
        "boresight_with_ins_bias_arcsec": list(effective_boresight_arcsec(flight, t_obs)),
        "delta_focal_mm": sc.delta_focal_mm,
        "delta_principal_point_um": list(sc.delta_principal_point_um),
        "time_delay_ms": settings.delay_ms,
        "antenna_offset_m": list(m.antenna_offset_m), "lever_arm_m": list(m.lever_arm_m),
        "noise_px": settings.noise_px, "gcp_noise_m": list(settings.gcp_noise_m),
        "gps_sigma_m": [scn.gps.horizontal_sigma_m, scn.gps.vertical_sigma_m],
    }
