"""Garrotxa error budget: how GPS code noise and INS attitude errors reach the ground at the
check points. A Monte-Carlo through the real ray–DEM intersection (postproc.georef.raycast) against
the linear propagation of the scenario's stated error model, per component along track, across
track and in height, in metres and pixels.

    .venv/bin/python bench/georef_error_budget.py [--run RUN] [--draws 300]

RUN is a simulated run of the garrotxa preset (made with `sisa simulate --preset garrotxa
--no-images --out RUN` when missing, a few minutes). The check points are seen where the truth
says (emulators' forward model: TruthProjector), at most twice each nearest nadir, as in seed
000; each draw perturbs the true pose by GPS errors (σ per axis from the scenario) and INS
attitude errors (bias² + (drift·t)² + noise² per axis, t from the scenario start, as the INS
emulator draws them) and casts the same image ray again. The propagated prediction is J·Σ·Jᵀ
with J by finite differences of the same ray cast. If RUN/process/accuracy.json exists (from
`sisa process RUN` on a run with images), its check-point RMS — one realisation of the full
pipeline — is printed beside them, with the seed's figures (1.26 / 1.34 / 0.6 px).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from pyproj import Transformer

from emulators.render import camera_pose_ecef
from emulators.scenario import load_scenario
from emulators.trajectory import TruthTrajectory
from postproc.georef import Dem, intersect
from sisa.core.frames import body_to_ned_matrix, ned_to_ecef_matrix
from sisa.core.sensor import ARCSEC_RAD
from sisa.core.utm import utm_epsg
from sisa.wiring.accuracy import check_points
from sisa.wiring.gcpsim import TruthProjector, truth_segments

SEED_PX = {"along": 1.26, "across": 1.34, "height": 0.6}
STEPS = np.array([0.05, 0.05, 0.05, 0.5 * ARCSEC_RAD, 0.5 * ARCSEC_RAD, 0.5 * ARCSEC_RAD])
COMPONENTS = ("along", "across", "height")


def _frame_to(direction: np.ndarray) -> np.ndarray:
    """Rotations taking +z to each unit direction (so one look vector (0, 0, 1) serves all)."""
    z = direction / np.linalg.norm(direction, axis=1, keepdims=True)
    helper = np.where(np.abs(z[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=2)


class Views:
    """Every check-point view: true pose, the image ray through the point, local axes."""

    def __init__(self, run: Path) -> None:
        self.scn = load_scenario(run / "scenario.toml")
        traj = TruthTrajectory.from_scenario(self.scn)
        self.dem = Dem.read(run / "terrain" / "dem.tif")
        self.epsg = self.dem.epsg
        chk = check_points(run / "terrain" / "ground_points.csv", self.epsg)
        x = chk["ecef_m"]
        enh = np.stack([chk["easting_m"], chk["northing_m"], chk["height_m"]], axis=1)
        proj = TruthProjector(self.scn, traj)
        views: list[tuple[int, float, int]] = []
        for seg in truth_segments(run):
            pixel, t = proj.crossing(seg, x)
            views += [(int(i), float(pixel[i]), int(t[i]))
                      for i in np.flatnonzero(np.isfinite(pixel))]
        centre = self.scn.scanner.centre_pixel
        by_point: dict[int, list[tuple[int, float, int]]] = {}
        for v in views:
            by_point.setdefault(v[0], []).append(v)
        kept = [v for vs in by_point.values()
                for v in sorted(vs, key=lambda v: abs(v[1] - centre))[:2]]
        idx = np.array([v[0] for v in kept])
        self.t_ns = np.array([v[2] for v in kept], dtype=np.int64)
        self.point_enh = enh[idx]
        self.point_ecef = x[idx]
        self.state = traj.state(self.t_ns)
        centre_e, r_ce = camera_pose_ecef(self.state, self.scn.mounting)
        self.look_c = np.einsum("nji,nj->ni", r_ce, self.point_ecef - centre_e)
        self.r_cb = self.scn.mounting.boresight_matrix()
        self.lever = np.asarray(self.scn.mounting.lever_arm_m)
        self.r_ne = ned_to_ecef_matrix(np.radians(self.state.lat_deg),
                                       np.radians(self.state.lon_deg))
        # along track: the ground direction of flight, from the heading and grid convergence
        fwd = self.state.ecef_m + 60.0 * np.einsum("nij,nj->ni", self.r_ne, self.state.vel_ned_mps)
        to_map = Transformer.from_crs(4978, utm_epsg(float(np.mean(self.state.lon_deg)),
                                                     float(np.mean(self.state.lat_deg))),
                                        always_xy=True)
        e0, n0 = to_map.transform(*self.state.ecef_m.T)[:2]
        e1, n1 = to_map.transform(*fwd.T)[:2]
        a = np.stack([np.asarray(e1) - e0, np.asarray(n1) - n0], axis=1)
        self.along = a / np.linalg.norm(a, axis=1, keepdims=True)
        self.right = np.stack([self.along[:, 1], -self.along[:, 0]], axis=1)
        sc = self.scn.scanner
        f_m = (sc.focal_length_mm + sc.delta_focal_mm) * 1e-3
        self.pixel_m = (self.state.height_m - self.point_enh[:, 2]) * sc.pixel_pitch_um * 1e-6 / f_m
        t_h = (self.t_ns - traj.t_start_ns) / 3.6e12
        ins = self.scn.ins
        att = [np.sqrt(np.asarray(ins.attitude_bias_arcsec)[k] ** 2
                       + (np.asarray(ins.attitude_drift_arcsec_per_h)[k] * t_h) ** 2
                       + np.asarray(ins.attitude_noise_arcsec)[k] ** 2) * ARCSEC_RAD
               for k in range(3)]
        gps = self.scn.gps
        h_m, v_m = gps.horizontal_sigma_m, gps.vertical_sigma_m
        self.sigma = np.stack([np.full(len(idx), h_m), np.full(len(idx), h_m),
                               np.full(len(idx), v_m),
                               *att], axis=1)  # (n, 6): δN, δE, δD, δroll, δpitch, δheading

    def ground(self, delta: np.ndarray) -> np.ndarray:
        """(n, 3) E, N, h of every view's image ray with the pose errors delta (n, 6)."""
        st = self.state
        r_bn = body_to_ned_matrix(st.roll_rad + delta[:, 3], st.pitch_rad + delta[:, 4],
                                  st.heading_rad + delta[:, 5])
        r_be = self.r_ne @ r_bn
        ins = st.ecef_m + np.einsum("nij,nj->ni", self.r_ne, delta[:, :3])
        centre = ins + r_be @ self.lever
        direction = np.einsum("nij,nj->ni", r_be @ self.r_cb, self.look_c)
        gp = intersect(self.dem, centre, _frame_to(direction), np.array([[0.0], [0.0], [1.0]]))
        return np.stack([gp.easting_m[:, 0], gp.northing_m[:, 0], gp.height_m[:, 0]], axis=1)

    def components(self, d_enh: np.ndarray) -> np.ndarray:
        """(…, n, 3) E/N/h differences → along/across/height."""
        a = d_enh[..., 0] * self.along[:, 0] + d_enh[..., 1] * self.along[:, 1]
        c = d_enh[..., 0] * self.right[:, 0] + d_enh[..., 1] * self.right[:, 1]
        return np.stack([a, c, d_enh[..., 2]], axis=-1)


def predicted_variance(views: Views) -> np.ndarray:
    """(n, 3) variance of along/across/height by linear propagation (finite-difference J)."""
    base = views.ground(np.zeros((len(views.t_ns), 6)))
    var = np.zeros((len(views.t_ns), 3))
    for k in range(6):
        d = np.zeros((len(views.t_ns), 6))
        d[:, k] = STEPS[k]
        jac = views.components(views.ground(d) - base) / STEPS[k]
        var += (jac * views.sigma[:, k:k + 1]) ** 2
    return var


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", type=Path, default=Path("runs/garrotxa-budget"))
    ap.add_argument("--draws", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if not (args.run / "flight.mcap").is_file():
        print(f"simulating {args.run} (garrotxa, no images) ...", flush=True)
        subprocess.run([sys.executable, "-m", "sisa.cli", "simulate", "--preset", "garrotxa",
                        "--no-images", "--out", str(args.run)], check=True)
    started = time.perf_counter()
    views = Views(args.run)
    n = len(views.t_ns)
    base = views.ground(np.zeros((n, 6)))
    closure = np.abs(views.components(base - views.point_enh)).max()
    var = predicted_variance(views)
    rng = np.random.default_rng(args.seed)
    errs = np.empty((args.draws, n, 3))
    for k in range(args.draws):
        delta = rng.normal(size=(n, 6)) * views.sigma
        errs[k] = views.components(views.ground(delta) - base)
    px = views.pixel_m[None, :, None]
    print(f"garrotxa check points: {len({tuple(p) for p in views.point_enh.tolist()})} points, "
          f"{n} views; GPS σ {views.sigma[0, 0]:.2f} m horizontal, {views.sigma[0, 2]:.2f} m "
          f"vertical; INS attitude σ (incl. drift) "
          f"{np.round(views.sigma[:, 3:].mean(axis=0) / ARCSEC_RAD, 1).tolist()} arcsec; "
          f"pixel {views.pixel_m.mean():.2f} m; error-free closure {closure * 1e3:.3f} mm; "
          f"{args.draws} draws in {time.perf_counter() - started:.1f} s")
    print(f"{'component':>10} {'predicted m':>12} {'MC m':>8} {'MC/pred':>8} {'predicted px':>13} "
          f"{'MC px':>7} {'seed px':>8}")
    mc_px = np.sqrt(np.mean((errs / px) ** 2, axis=(0, 1)))
    pred_px = np.sqrt(np.mean(var / views.pixel_m[:, None] ** 2, axis=0))
    for i, c in enumerate(COMPONENTS):
        pred_m = float(np.sqrt(var[:, i].mean()))
        mc_m = float(np.sqrt(np.mean(errs[..., i] ** 2)))
        print(f"{c:>10} {pred_m:12.3f} {mc_m:8.3f} {mc_m / pred_m:8.3f} {pred_px[i]:13.3f} "
              f"{mc_px[i]:7.3f} {SEED_PX[c]:8.2f}")
    acc_path = args.run / "process" / "accuracy.json"
    if acc_path.is_file():
        cp = json.loads(acc_path.read_text())["check_points"]
        if cp.get("points"):
            print("full pipeline, one realisation (sisa process): check-point RMS "
                  + " / ".join(f"{cp[c]['rms_px']:.3f}" for c in COMPONENTS)
                  + f" px along / across / height ({cp['points']} views)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
