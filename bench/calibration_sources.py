# ruff: noqa: E402  (the BLAS thread count is set before numpy is imported)
"""Which error source does B's σ of the delay leave out? One source at a time (docs/calibration.md).

    .venv/bin/python bench/calibration_sources.py [--flights 0,1,2,3] [--solution phase]
        [--draws data=100,image=20,survey=20,dem=20,gps=25,ins_bias_drift=25,ins_noise=25,
         ins_velocity=25,all=25] [--out runs/calibration_sources]

The Monte Carlo (bench/calibration_mc.py) says whether σ are honest over flights that differ in
everything; this says which source an excess would come from. For a few flights of that bench
(the same geometry, ground points and line times), configuration B (the delay alone, the sensor
known) is adjusted over repeated draws of ONE error source, every other one switched off:

- data rows, each entering the adjustment only through its own rows: image noise (0.45 px on
  lines and pixels), survey noise of the control and check points (2.5 m / 2 m), the DEM's
  error at the tie points (2 m: a tie point's true height off the DEM is the same as a DEM that
  is off at it, so the draw goes into the surface the adjustment reads, and the views stay);
- through the trajectory, which is fused again for every draw (postproc.georef.fuse_ins_gps):
  the GPS receiver's Gauss–Markov error, the INS attitude's bias and drift (with B's "known"
  boresight: the scenario's composed with that draw's bias and mean drift, as in the bench), the
  attitude's white noise, and the velocity's white noise;
- `none`: no error at all (what the model itself gets wrong: the delay grid, linearisation);
- `all`: everything, as in the bench.

For each draw the adjustment's own split of the delay's variance (at unit weight, σ̂0 = 1) into
what the image rows (image noise and the navigation model's bridge variance), control rows,
DEM rows and navigation model carry is recorded beside the error. A source's empirical mean
square error over its draws against its modelled share says whether the stochastic model
represents it: sources it does not model have a share of 0. The line clock and δx0 are no
source in B (the line times are exact, the interior is known).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt
from pyproj import Transformer
from scipy.spatial import cKDTree
from scipy.stats import chi2

sys.path.insert(0, str(Path(__file__).resolve().parent))
import calibration_mc as mc

from emulators.gps import antenna_fix_ecef_m, position_errors
from emulators.ins import AttitudeErrors
from postproc.calibration import CalibrationInput, GroundPoints, ImageObservations, parse_groups
from postproc.calibration.adjust import adjust, build
from postproc.calibration.problem import (
    CONTROL,
    DEM,
    IMAGE_ACROSS,
    IMAGE_ALONG,
    NAV_PRIOR,
    Problem,
)
from postproc.calibration.solve import Solution, posterior
from postproc.calibration.surface import DemSurface
from postproc.georef import AntennaFixes, InsSamples, Trajectory, ecef_to_geodetic, fuse_ins_gps
from sisa.commands.process import sensor_of
from sisa.core.frames import body_to_ned_matrix, ned_to_ecef_matrix
from sisa.core.timescale import NS_PER_S, seconds_since
from sisa.wiring.gcpsim import (
    FlightTruth,
    effective_boresight_arcsec,
    simulate_flight_observations,
)

F64 = npt.NDArray[np.float64]

SOURCES: Final = ("none", "data", "image", "survey", "dem", "gps", "ins_bias_drift",
                  "ins_noise", "ins_velocity", "all")
DATA_SOURCES: Final = frozenset({"image", "survey", "dem"})
NAV_SOURCES: Final = frozenset({"gps", "ins_bias_drift", "ins_noise", "ins_velocity"})
EXPANDS: Final = {"data": DATA_SOURCES, "all": DATA_SOURCES | NAV_SOURCES}
DEFAULT_DRAWS: Final = "data=100,image=20,survey=20,dem=20,gps=25,ins_bias_drift=25," \
                       "ins_noise=25,ins_velocity=25,all=25"
PARTS: Final = ("image", "bridge", "control", "dem", "navigation")


class OffsetSurface:
    """The DEM, off by a given error at each tie point (the nearest one to a query, within
    RADIUS_M): what the adjustment reads when the true tie points are on the DEM and the DEM
    is wrong there."""

    RADIUS_M: Final = 30.0

    def __init__(self, base: DemSurface, tie_ecef_m: F64, error_m: F64) -> None:
        self.base = base
        self.to_map = Transformer.from_crs(4326, base.dem.epsg, always_xy=True)
        self.tree = cKDTree(self._map(tie_ecef_m))
        self.error_m = error_m

    def _map(self, ecef_m: F64) -> F64:
        lat, lon, _ = ecef_to_geodetic(ecef_m)
        e, n = self.to_map.transform(lon, lat)
        return np.stack([np.asarray(e), np.asarray(n)], axis=1)

    def heights(self, ecef_m: F64) -> tuple[F64, F64]:
        h, hs = self.base.heights(ecef_m)
        d, i = self.tree.query(self._map(np.atleast_2d(ecef_m)))
        near = d <= self.RADIUS_M
        out = hs - np.where(near, self.error_m[np.minimum(i, self.error_m.size - 1)], 0.0)
        return h, np.asarray(out, np.float64)


@dataclass
class Exact:
    """One flight of the bench without any error: its exact measurements and ground points."""

    flight: mc.Flight
    obs: ImageObservations
    points: GroundPoints  # control and check at their true coordinates, ties NaN
    true_points: GroundPoints
    t_obs_ns: npt.NDArray[np.int64]  # each view's segment middle (gcpsim's effective boresight)


def exact_flight(k: int, solution: str) -> Exact:
    flight = mc.build_flight(k, solution)
    settings = replace(mc.SETTINGS, seed=flight.scn.seed, noise_px=0.0, gcp_noise_m=(0.0, 0.0),
                       tie_height_noise_m=0.0)
    sim = simulate_flight_observations(flight.truth, flight.points, settings)
    o = sim.obs
    obs = ImageObservations(o.point_id, o.segment, o.line, o.pixel,
                            np.full(len(o), mc.SETTINGS.noise_px))
    mid = {s.number: int(s.t_ns[s.t_ns.size // 2]) for s in flight.truth.segments}
    t_obs = np.array([mid[int(s)] for s in o.segment.tolist()], np.int64)
    return Exact(flight, obs, sim.points, sim.true_points, t_obs)


def navigation(flight: mc.Flight, on: frozenset[str], rng: np.random.Generator
               ) -> tuple[Trajectory, AttitudeErrors]:
    """bench/calibration_mc.navigation with each error switched on or off (same records)."""
    scn, traj = flight.scn, flight.truth.traj
    lo = max(traj.t_start_ns, traj.strips[0].t_start_ns - round(mc.WINDOW_S * NS_PER_S))
    hi = min(traj.t_end_ns, traj.strips[-1].t_end_ns + round(mc.WINDOW_S * NS_PER_S))
    t_fix = np.arange(-(-lo // NS_PER_S) * NS_PER_S, hi + 1, NS_PER_S, dtype=np.int64)
    err, _ = position_errors(scn.gps, t_fix.size, 1.0, rng)
    if "gps" not in on:
        err[:] = 0.0
    fixes = AntennaFixes(t_fix, antenna_fix_ecef_m(traj.state(t_fix),
                                                   scn.mounting.antenna_offset_m, err))
    drawn = AttitudeErrors.draw(scn.ins, rng)
    zero = np.zeros(3)
    att = AttitudeErrors(drawn.bias_rad if "ins_bias_drift" in on else zero,
                         drawn.drift_rad_per_s if "ins_bias_drift" in on else zero,
                         drawn.noise_rad if "ins_noise" in on else zero)
    step = round(NS_PER_S / scn.ins.rate_hz)
    t_ins = np.concatenate([np.arange(max(traj.t_start_ns,
                                          s.t_start_ns - round(mc.WINDOW_S * 1e9)),
                                      min(traj.t_end_ns, s.t_end_ns + round(mc.WINDOW_S * 1e9)),
                                      step, dtype=np.int64) for s in traj.strips])
    st = traj.state(t_ins)
    e = att.at(seconds_since(t_ins, traj.t_start_ns), rng)
    sv = scn.ins.velocity_noise_mps if "ins_velocity" in on else 0.0
    vel = st.vel_ned_mps + rng.normal(0.0, 1.0, (t_ins.size, 3)) * sv
    ins = InsSamples(t_ins, body_to_ned_matrix(st.roll_rad + e[:, 0], st.pitch_rad + e[:, 1],
                                               st.heading_rad + e[:, 2]), vel)
    return (fuse_ins_gps(ins, fixes, antenna_offset_m=scn.mounting.antenna_offset_m,
                         source=scn.block.name), att)


def survey_noise(points: GroundPoints, sigma_m: tuple[float, float], rng: np.random.Generator
                 ) -> GroundPoints:
    """Control and check points off their true place by the survey's σ (north, east, down)."""
    lat, lon, _ = ecef_to_geodetic(points.ecef_m)
    r_ne = ned_to_ecef_matrix(np.radians(lat), np.radians(lon))
    ned = rng.normal(0.0, 1.0, (len(points), 3)) * np.array([sigma_m[0], sigma_m[0],
                                                               sigma_m[1]])
    moved = points.ecef_m + np.einsum("nij,nj->ni", r_ne, ned)
    ecef = np.where((points.kind == "tie")[:, None], points.ecef_m, moved)
    return GroundPoints(points.ids, points.kind, ecef, points.epsg)


def modelled_split(sol: Solution, col: int, pb: Problem) -> dict[str, float]:
    """The delay's variance at unit weight (σ̂0 = 1), split by the rows that carry it: every
    row's gain a·S⁻¹ (a its design row with the points eliminated) squared, summed per kind;
    an image row's share split between image noise and the navigation model's bridge variance
    in proportion to its variance."""
    lin, norm = sol.lin, sol.norm
    q = np.linalg.inv(norm.s)[col]
    a = lin.jg.copy()
    has = lin.pidx >= 0
    w = norm.ngp @ norm.npp_inv  # (P, G, 3)
    a[has] -= np.einsum("mgk,mk->mg", w[lin.pidx[has]], lin.jp[has])
    gain2 = (a @ q) ** 2
    out = {p: 0.0 for p in PARTS}
    img = np.flatnonzero((lin.row_kind == IMAGE_ALONG) | (lin.row_kind == IMAGE_ACROSS))
    item, axis = lin.row_item[img], (lin.row_kind[img] == IMAGE_ACROSS).astype(np.int64)
    noise = pb.model.obs.sigma_px[item] ** 2 / pb.row_sigma[item, axis] ** 2
    out["image"] = float(np.sum(gain2[img] * noise))
    out["bridge"] = float(np.sum(gain2[img] * (1.0 - noise)))
    out["control"] = float(gain2[lin.row_kind == CONTROL].sum())
    out["dem"] = float(gain2[lin.row_kind == DEM].sum())
    out["navigation"] = float(gain2[lin.row_kind == NAV_PRIOR].sum())
    out["total"] = float(q[col])
    return out


def adjust_b(ex: Exact, traj: Trajectory, points: GroundPoints, obs: ImageObservations,
             surface: OffsetSurface | DemSurface, boresight: tuple[float, float, float]
             ) -> dict[str, Any]:
    f = ex.flight
    s = sensor_of(f.scn)
    m = s.mounting.model_copy(update={"boresight_arcsec": boresight})
    sensor = s.model_copy(update={"mounting": m, "time_delay_ms": 0.0})
    inp = CalibrationInput(traj, f.clock, points, obs, sensor, surface, f.navigation)
    opt = replace(mc.OPTIONS, groups=parse_groups("delay"))
    adj = build(inp, opt)
    sol, blunders = adjust(adj, opt)
    col = adj.layout.labels.index("time_delay")
    sigma0, cov, _ = posterior(sol)
    split = modelled_split(sol, col, adj.problem)
    est = float(adj.layout.unpack(sol.theta).delay_ms)
    return {"error_ms": est - mc.DELAY_MS, "sigma_ms": float(math.sqrt(cov[col, col])),
            "sigma0": sigma0, "blunders": len(blunders), "split_ms2": split}


def draw(ex: Exact, source: str, i: int, base_traj: Trajectory, base_surface: DemSurface
         ) -> dict[str, Any]:
    on = frozenset(EXPANDS.get(source, {source} - {"none"}))
    f = ex.flight
    rng = np.random.default_rng([f.scn.seed, SOURCES.index(source), i, 3232])
    obs, points = ex.obs, ex.points
    surface: OffsetSurface | DemSurface = base_surface
    noise = mc.SETTINGS.noise_px
    if "image" in on:
        n = len(obs)
        obs = ImageObservations(obs.point_id, obs.segment, obs.line + rng.normal(0, noise, n),
                                obs.pixel + rng.normal(0, noise, n), obs.sigma_px)
    if "survey" in on:
        points = survey_noise(points, mc.SETTINGS.gcp_noise_m, rng)
    if "dem" in on:
        ties = ex.true_points.kind == "tie"
        err = rng.normal(0.0, mc.SETTINGS.tie_height_noise_m, int(ties.sum()))
        surface = OffsetSurface(base_surface, ex.true_points.ecef_m[ties], err)
    b = f.scn.mounting.boresight_arcsec
    boresight = (float(b[0]), float(b[1]), float(b[2]))
    traj = base_traj
    if on & NAV_SOURCES:
        traj, att = navigation(f, on, rng)
        arcsec = math.pi / (180 * 3600)
        truth = FlightTruth(f.truth.scn, f.truth.traj, f.truth.segments, f.truth.dem,
                            att.bias_rad / arcsec, att.drift_rad_per_s * 3600.0 / arcsec)
        boresight = effective_boresight_arcsec(truth, ex.t_obs_ns)  # B's "known" boresight
    out = adjust_b(ex, traj, points, obs, surface, boresight)
    out.update({"flight": int(f.scn.seed - 32_000), "source": source, "draw": i})
    return out


def summary(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per source (over all flights): n, mean error, mean square error, the modelled share of
    that source (mean over draws), their ratio with its 95 % range for honest σ."""
    out = []
    for source in SOURCES:
        rs = [r for r in rows if r["source"] == source]
        if not rs:
            continue
        e = np.array([r["error_ms"] for r in rs])
        parts = _modelled_parts(source)
        model = np.array([sum(r["split_ms2"][p] for p in parts) for r in rs])
        z2 = e**2 / np.where(model > 0, model, np.nan)
        n = e.size
        lo, hi = (chi2.ppf(q, n) / n for q in (0.025, 0.975))
        total = np.array([r["split_ms2"]["total"] for r in rs])
        out.append({"source": source, "n": n, "mean_ms": float(e.mean()),
                    "mse_ms2": float(np.mean(e**2)), "modelled_ms2": float(model.mean()),
                    "ratio": float(np.nanmean(z2)) if np.all(model > 0) else math.inf,
                    "ratio_honest_95": [float(lo), float(hi)],
                    "share_of_total": float(np.mean(e**2) / total.mean()),
                    "sigma_ms": float(np.mean([r["sigma_ms"] for r in rs])),
                    "z_rms": float(np.sqrt(np.mean([(r["error_ms"] / r["sigma_ms"]) ** 2
                                                    for r in rs])))})
    return out


def _modelled_parts(source: str) -> tuple[str, ...]:
    """Which parts of the modelled variance a source is: what each source is meant to be."""
    by = {"image": ("image",), "survey": ("control",), "dem": ("dem",),
          "gps": ("navigation", "bridge"), "ins_bias_drift": (), "ins_noise": (),
          "ins_velocity": (), "none": ()}
    if source in EXPANDS:
        return tuple(p for s in sorted(EXPANDS[source]) for p in by[s])
    return by[source]


def print_summary(tab: list[dict[str, Any]]) -> None:
    print(f"\n{'source':<16}{'n':>5}{'mean ms':>10}{'MSE ms²':>11}{'model ms²':>11}"
          f"{'ratio':>8}{'  honest 95 %':>14}{'of σ²':>8}")
    for r in tab:
        lo, hi = r["ratio_honest_95"]
        ratio = f"{r['ratio']:8.3f}" if math.isfinite(r["ratio"]) else f"{'—':>8}"
        print(f"{r['source']:<16}{r['n']:>5}{r['mean_ms']:>+10.4f}{r['mse_ms2']:>11.5f}"
              f"{r['modelled_ms2']:>11.5f}{ratio}{f'{lo:.2f}–{hi:.2f}':>14}"
              f"{100 * r['share_of_total']:>7.2f}%")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flights", default="0,1,2,3", help="flight numbers of the bench")
    ap.add_argument("--solution", default="phase", choices=("phase", "code"))
    ap.add_argument("--draws", default=DEFAULT_DRAWS, help="source=count,…")
    ap.add_argument("--out", type=Path, default=Path("runs/calibration_sources"))
    args = ap.parse_args()
    counts = {}
    for item in args.draws.split(","):
        name, _, n = item.partition("=")
        if name not in SOURCES or not n.isdigit():
            ap.error(f"--draws: {item!r}: source=count, sources {', '.join(SOURCES)}")
        counts[name] = int(n)
    counts["none"] = 1
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"sources_{args.solution}.json"
    rows: list[dict[str, Any]] = json.loads(path.read_text()) if path.is_file() else []
    done = {(r["flight"], r["source"], r["draw"]) for r in rows}
    t0 = time.perf_counter()
    for k in (int(v) for v in args.flights.split(",")):
        ex = exact_flight(k, args.solution)
        base_traj, _ = navigation(ex.flight, frozenset(), np.random.default_rng(0))
        base_surface = DemSurface(ex.flight.truth.dem)
        for source in SOURCES:
            for i in range(counts.get(source, 0)):
                if (k, source, i) in done:
                    continue
                r = draw(ex, source, i, base_traj, base_surface)
                rows.append(r)
                print(f"flight {k} {source:<15}{i:4d} error {r['error_ms']:+8.4f} ms  σ "
                      f"{r['sigma_ms']:.3f}  σ̂0 {r['sigma0']:.3f}", flush=True)
            path.write_text(json.dumps(rows, default=float) + "\n", encoding="utf-8")
    tab = summary(rows)
    print_summary(tab)
    (args.out / f"summary_{args.solution}.json").write_text(json.dumps(tab, indent=1) + "\n",
                                                             encoding="utf-8")
    print(f"\n{path}: {len(rows)} adjustments, {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
