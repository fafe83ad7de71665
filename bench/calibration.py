"""System calibration on simulated Garrotxa blocks: the acceptance figures of docs/calibration.md.

    .venv/bin/python bench/calibration.py [--runs runs/calibration] [--seed 0]

Two runs of the Garrotxa scenario (seed 000 Table 1: 14 alternating strips, 2160 m above ground,
3.5 m pixels; boresight (1742, −2, −74)″ and δf 0.6496 mm, δx0 12.74 µm, δy0 64.52 µm as in its
Table 3) are simulated without images the first time (≈ 3–5 min each) and kept in --runs:
`garrotxa` with the seed's GPS code solution (1 m σ) and `garrotxa-phase` with a phase solution
(3 cm σ); and `bellmunt-garrotxa-sensor`, the seed's Bellmunt flight (659 m, 426 km/h, phase)
carrying the Garrotxa sensor, a second flight for the delay. The adjustment uses what a user
has: sync and navigation from the flight log, line times from the sync (lines numbered in
frame-header order: no image files). The measurements come from the truth (sisa.wiring.gcpsim).
Figures:

1. Seed configuration (code GPS; 111 control points, 97 of them on the border seen once, 96
   check points in with their heights as the seed did, tie points up to Table 1's 469
   measurements, DEM surface control σ 2 m, 0.45 px noise, survey σ 2.5 m / 2.0 m):
   boresight and self-calibration against the truth (with the INS's attitude bias folded in:
   the data cannot tell it from the boresight), their σ against the seed's Table 4, the
   correlations; then with an exact survey, without ties and DEM, and with more tie points.
2. Time delay (phase GPS, 85 ms injected): estimated with the boresight known, estimated with
   it, estimated with it from two flights of different H/v adjusted together
   (postproc.calibration.flights), and the seed's sweep (seed 003 §5: ±100 ms, minimum RMS of the
   control points).
3. Antenna offset (phase GPS, the sensor file's offset 1.5 m short along track): per-strip GPS
   shifts alternate with the flying direction; the offset is then estimated.
4. Check points after calibration (phase GPS, exact survey, 0.3 px): RMS against the
   prediction (image noise, parameter covariance, navigation σ).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from emulators.scenario import Scenario, load_scenario, scenario_from_table
from postproc.calibration import (
    CalibrationInput,
    CalibrationOptions,
    CalibrationResult,
    GroundPoints,
    Group,
    NavigationAccuracy,
    SegmentClock,
    calibrate,
    high_correlations,
    join_flights,
    look_angles,
    parameter_rows,
    parse_groups,
    read_ground_points,
    sweep_delay,
)
from postproc.georef import NAV_WANTED, Dem, SensorModel, merged_wanted, nav_from_columns
from postproc.sync import WANTED as SYNC_WANTED
from postproc.sync import SyncResult, sync_input_from_columns, synchronise
from recorder.columns import read_topics
from sisa.commands.process import sensor_of
from sisa.commands.scenario import scenario_toml
from sisa.core.sensor import Mounting
from sisa.wiring.gcpsim import SimSettings, SimulatedObservations, simulate_observations
from sisa.wiring.simulation import simulate

# A second flight for the delay: the seed's Bellmunt block (659 m above ground, 426 km/h: H/v
# 5.6 s against Garrotxa's 29.6 s) flown with the Garrotxa sensor (its Table 3 values), so that
# the two flights share every sensor parameter.
SECOND_FLIGHT: dict[str, Any] = {
    "base": "bellmunt",
    "scanner": {"delta_focal_mm": 0.6496, "delta_principal_point_um": [12.74, 64.52]},
    "mounting": {"boresight_arcsec": [1742.0, -2.0, -74.0]}}
SEED_TABLE4 = {"omega": 345.0, "phi": 512.0, "kappa": 56.0, "delta_focal": 0.003,
               "delta_x0": 24.83, "delta_y0": 17.73}
CORE = ("omega", "phi", "kappa", "delta_focal", "delta_x0", "delta_y0")


@dataclass
class Run:
    path: Path
    scn: Scenario
    cols: dict[str, Any]
    sync: SyncResult
    points: GroundPoints
    dem: Dem

    def input(self, sensor: SensorModel, sim: SimulatedObservations, dem: bool,
              nav_model: bool = True) -> CalibrationInput:
        traj = nav_from_columns(self.cols, self.sync.ins,
                                antenna_offset_m=sensor.mounting.antenna_offset_m)
        gps = self.scn.gps  # the receiver's stated accuracy: the navigation model
        nav = NavigationAccuracy((gps.horizontal_sigma_m, gps.vertical_sigma_m),
                                 gps.noise_correlation_s)
        return CalibrationInput(traj, SegmentClock.from_line_times(self.sync.lines), sim.points,
                                sim.obs, sensor, self.dem if dem else None,
                                nav if nav_model else None)


def ensure_run(root: Path, name: str, table: dict[str, Any]) -> Run:
    path = root / name
    if not (path / "flight.mcap").is_file():
        scn = scenario_from_table(table)
        print(f"simulating {path} (no images) ...", flush=True)
        t0 = time.perf_counter()
        path.mkdir(parents=True, exist_ok=False)
        (path / "scenario.toml").write_text(scenario_toml(scn), encoding="utf-8")
        simulate(scn, path, images=False)
        print(f"  {time.perf_counter() - t0:.0f} s", flush=True)
    scn = load_scenario(path / "scenario.toml")
    t0 = time.perf_counter()
    cols = read_topics([path / "flight.mcap"], merged_wanted(SYNC_WANTED, NAV_WANTED))
    sync = synchronise(sync_input_from_columns(cols))
    print(f"{name}: sync of the log {time.perf_counter() - t0:.0f} s", flush=True)
    return Run(path, scn, cols, sync, read_ground_points(path / "terrain" / "ground_points.csv"),
               Dem.read(path / "terrain" / "dem.tif"))


def truth_values(truth: dict[str, Any]) -> dict[str, float]:
    b = truth["boresight_with_ins_bias_arcsec"]
    return {"omega": b[0], "phi": b[1], "kappa": b[2], "delta_focal": truth["delta_focal_mm"],
            "delta_x0": truth["delta_principal_point_um"][0],
            "delta_y0": truth["delta_principal_point_um"][1],
            "time_delay": truth["time_delay_ms"]}


def block_params(res: CalibrationResult) -> dict[str, tuple[float, float]]:
    return {p["name"]: (p["estimate"], p["sigma"]) for p in parameter_rows(res)
            if p["segment"] is None}


def known_sensor(run: Run, truth: dict[str, Any]) -> SensorModel:
    """The scenario's sensor as a previous calibration would know it: the true interior
    geometry, and the boresight the data see (true boresight ∘ this flight's INS bias)."""
    s = sensor_of(run.scn)
    b = tuple(float(v) for v in truth["boresight_with_ins_bias_arcsec"])
    m = Mounting(lever_arm_m=s.mounting.lever_arm_m, antenna_offset_m=s.mounting.antenna_offset_m,
                 boresight_arcsec=b)
    return s.model_copy(update={"mounting": m})


def table(res: CalibrationResult, truth: dict[str, float], names: tuple[str, ...],
          seed_sigma: bool) -> list[dict[str, Any]]:
    est = block_params(res)
    rows = []
    for n in names:
        if n not in est:
            continue
        e, s = est[n]
        t = truth.get(n, math.nan)
        row = {"name": n, "estimate": e, "sigma": s, "truth": t, "err_over_sigma": (e - t) / s}
        if seed_sigma:
            row["seed_sigma"] = SEED_TABLE4.get(n)
        rows.append(row)
        seed = f"  seed σ {SEED_TABLE4[n]:g}" if seed_sigma and n in SEED_TABLE4 else ""
        print(f"    {n:<12} {e:11.4f} ± {s:<9.4f} truth {t:10.4f}  |err|/σ "
              f"{abs(e - t) / s:4.2f}{seed}")
    return rows


def summary(res: CalibrationResult) -> dict[str, Any]:
    corr = {f"{h['a']}~{h['b']}": h["r"] for h in high_correlations(res, 0.5)}
    look = look_angles(res)
    print(f"    σ0 {res.sigma0:.3f}, {res.counts['observations_used']} measurements, "
          f"{res.counts['tie_points']} tie points, {res.counts['dem_rows']} DEM rows, "
          f"{len(res.blunders)} blunders rejected")
    for k, r in list(corr.items())[:4]:
        print(f"    correlation {k}: {r:+.4f}")
    print(f"    look offsets: along {look['along_um']['value']:.2f} ± "
          f"{look['along_um']['sigma']:.2f} µm, across {look['across_um']['value']:.2f} ± "
          f"{look['across_um']['sigma']:.2f} µm")
    return {"sigma0": res.sigma0, "counts": res.counts, "correlations": corr, "look": look,
            "blunders": len(res.blunders), "check": res.check}


SEED_PHOTO_OBS = 469  # seed 000 Table 1: photogrammetric observations in the Garrotxa block
SEED_SINGLE_VIEW = 97  # ground points with one observation, on the block borders (seed 000 §6)


def seed_settings(run: Run, seed: int, **kw: Any) -> tuple[SimSettings, int]:
    """The seed's measurements: 0.45 px (its residual RMS 0.47 / 0.43 px), survey σ 2.5 m / 2 m,
    97 border control points seen once, the rest of the 111 twice, the check points in every
    strip that sees them (≤ 2), and tie points (two rays each) up to Table 1's 469."""
    s = SimSettings(noise_px=0.45, gcp_noise_m=(2.5, 2.0), single_view_control=SEED_SINGLE_VIEW,
                    seed=seed)
    n = len(simulate_observations(run.path, run.points, s).obs)
    ties = max(0, (SEED_PHOTO_OBS - n) // 2)
    return replace(s, tie_points=ties, **kw), ties


def seed_configuration(run: Run, seed: int) -> dict[str, Any]:
    settings, ties = seed_settings(run, seed)
    print(f"\n1. seed configuration (code GPS, 0.45 px, survey σ 2.5/2.0 m, {SEED_SINGLE_VIEW} "
          f"border control points seen once, {ties} tie points to Table 1's {SEED_PHOTO_OBS} "
          "measurements, DEM surface control σ 2 m, check points in with their heights)")
    sim = simulate_observations(run.path, run.points, settings)
    truth = truth_values(sim.truth)
    start = sensor_of(run.scn, nominal=True)
    base = CalibrationOptions(groups=parse_groups("boresight,selfcal"), gcp_sigma_m=(2.5, 2.0),
                              check_heights=True, dem_sigma_m=2.0)
    out: dict[str, Any] = {"tie_points": ties}
    res = calibrate(run.input(start, sim, dem=True), base)
    out["seed"] = {"params": table(res, truth, CORE, True), **summary(res)}
    c = res.check or {}
    print(f"    check points: RMS along {c['rms_along_m']:.2f} m ({c['rms_along_px']:.2f} px), "
          f"across {c['rms_across_m']:.2f} m ({c['rms_across_px']:.2f} px); predicted "
          f"{c['predicted_rms_along_m']:.2f} / {c['predicted_rms_across_m']:.2f} m (the "
          "navigation model's GPS error included; seed: 4.7 / 4.4 m)")
    print("  the same with the trajectory taken as exact (no navigation model: the seed's "
          "adjustment, and ours before issue 32)")
    res = calibrate(run.input(start, sim, dem=True, nav_model=False), base)
    out["seed_exact_trajectory"] = {"params": table(res, truth, CORE, True), **summary(res)}
    print("  the same with an exact survey (control σ 1 cm): what the survey error costs the "
          "ω/δy0 split")
    sim_x = simulate_observations(run.path, run.points, replace(settings, gcp_noise_m=(0.0, 0.0)))
    res = calibrate(run.input(start, sim_x, dem=True), replace(base, gcp_sigma_m=(0.01, 0.01)))
    out["seed_exact_survey"] = {"params": table(res, truth, CORE, True), **summary(res)}
    print("  control and check points only (every view ≤ 2, no tie points, no DEM)")
    sim_p = simulate_observations(run.path, run.points, SimSettings(
        noise_px=0.45, gcp_noise_m=(2.5, 2.0), seed=seed))
    res = calibrate(run.input(start, sim_p, dem=False), base)
    out["points_only"] = {"params": table(res, truth, CORE, True), **summary(res)}
    for more in (300, 1000):
        print(f"  with {more} tie points instead of {ties} (DEM control σ 2 m)")
        sim_t = simulate_observations(run.path, run.points, replace(settings, tie_points=more))
        res = calibrate(run.input(start, sim_t, dem=True), base)
        out[f"dem_ties_{more}"] = {"params": table(res, truth, CORE, True), **summary(res)}
    out["seed_noise"] = seed_noise(run, start, settings, base, out["seed"]["params"])
    return out


IMAGE_LED = ("kappa", "delta_focal")  # σ set by the image noise: the survey hardly enters


def seed_noise(run: Run, start: SensorModel, settings: SimSettings, base: CalibrationOptions,
               ours: list[dict[str, Any]]) -> dict[str, Any]:
    """Can the seed's σω (345″) come from its stated inputs? κ and δf are fixed by the
    images (their σ barely move with the survey's), so the seed's σκ and σδf against ours
    give the image noise its adjustment had: ours (σ̂0 included) times their ratio. At that
    noise, with the survey as stated and with an exact one, σω is what the seed's
    configuration gives; an exact survey is the most any survey could do."""
    sig = {r["name"]: r["sigma"] for r in ours}
    ratios = {n: SEED_TABLE4[n] / sig[n] for n in IMAGE_LED}
    noise = settings.noise_px * math.sqrt(math.prod(ratios.values()))  # geometric mean
    print("  the seed's image noise from its σκ, σδf: ratios seed/ours "
          + ", ".join(f"{n} {r:.2f}" for n, r in ratios.items())
          + f" → {noise:.2f} px (ours {settings.noise_px:g} px)")
    out: dict[str, Any] = {"ratios": ratios, "noise_px": noise}
    for key, survey in (("stated_survey", settings.gcp_noise_m), ("exact_survey", (0.0, 0.0))):
        sim = simulate_observations(run.path, run.points, replace(
            settings, noise_px=noise, gcp_noise_m=survey))
        opt = replace(base, gcp_sigma_m=(max(survey[0], 0.01), max(survey[1], 0.01)))
        res = calibrate(run.input(start, sim, dem=True), opt)  # weighted with sigma_px = noise
        print(f"  at {noise:.2f} px, survey σ {opt.gcp_sigma_m[0]:g}/{opt.gcp_sigma_m[1]:g} m:")
        out[key] = {"params": table(res, truth_values(sim.truth), CORE, True), **summary(res)}
    return out


def boresight_only(run: Run, seed: int) -> dict[str, Any]:
    print("\n1b. boresight alone, interior geometry known (phase GPS, 0.3 px, 1000 ties, DEM):"
          " the truth with and without the INS bias")
    sim = simulate_observations(run.path, run.points, SimSettings(
        noise_px=0.3, tie_points=1000, seed=seed))
    truth = truth_values(sim.truth)
    opt = CalibrationOptions(groups=(Group.BORESIGHT,), gcp_sigma_m=(0.02, 0.02),
                             dem_sigma_m=0.5)
    res = calibrate(run.input(sensor_of(run.scn), sim, dem=True), opt)
    rows = table(res, truth, ("omega", "phi", "kappa"), False)
    raw = sim.truth["boresight_arcsec"]
    print(f"    (without the INS bias the truth would be {raw[0]:g}, {raw[1]:g}, {raw[2]:g})")
    return {"params": rows, "boresight_without_ins_bias": raw, **summary(res)}


def delay(run: Run, second: Run, seed: int) -> dict[str, Any]:
    print("\n2. time delay: 85 ms injected (phase GPS, 0.3 px, 500 tie points, DEM control)")
    sim = simulate_observations(run.path, run.points, SimSettings(
        noise_px=0.3, delay_ms=85.0, tie_points=500, seed=seed))
    truth = truth_values(sim.truth)
    known = known_sensor(run, sim.truth)
    opt = CalibrationOptions(groups=(Group.DELAY,), gcp_sigma_m=(0.05, 0.05))
    joint_groups = parse_groups("boresight,selfcal,delay")
    nominal = sensor_of(run.scn, nominal=True)
    out: dict[str, Any] = {}
    print("  boresight and self-calibration known (a previous calibration)")
    res = calibrate(run.input(known, sim, dem=True), opt)
    out["known_boresight"] = {"params": table(res, truth, ("time_delay",), False),
                              **summary(res)}
    print("  estimated together with boresight and self-calibration")
    res = calibrate(run.input(nominal, sim, dem=True), replace(opt, groups=joint_groups))
    out["with_boresight"] = {"params": table(res, truth, (*CORE, "time_delay"), False),
                             **summary(res)}
    r = look_angles(res)["along_um"]["correlations"].get("time_delay", 0.0)
    print(f"    correlation of the delay with the along-track look offset δx0 − f'φ: {r:+.3f}"
          " (both move the ground along track; only relief and attitude rates part them)")
    out["with_boresight"]["corr_along_look_delay"] = r
    h1, v1 = run.scn.block.flying_height_agl_m, run.scn.block.ground_speed_kmh
    h2, v2 = second.scn.block.flying_height_agl_m, second.scn.block.ground_speed_kmh
    print(f"  two flights sharing the sensor, adjusted together: this one ({h1:g} m, {v1:g} km/h,"
          f" H/v {h1 / (v1 / 3.6):.1f} s) and {second.path.name} ({h2:g} m, {v2:g} km/h, "
          f"H/v {h2 / (v2 / 3.6):.1f} s; 300 tie points, DEM)")
    sim2 = simulate_observations(second.path, second.points, SimSettings(
        noise_px=0.3, delay_ms=85.0, tie_points=300, seed=seed))
    truth2 = truth_values(sim2.truth)
    both = join_flights([run.input(nominal, sim, dem=True), second.input(nominal, sim2, dem=True)])
    res = calibrate(both, replace(opt, groups=joint_groups))
    print(f"    (truth: the first flight's; the second's boresight with its INS bias is "
          f"{truth2['omega']:.1f}, {truth2['phi']:.1f}, {truth2['kappa']:.1f}″)")
    out["two_flights"] = {"params": table(res, truth, (*CORE, "time_delay"), False),
                          "second_truth": truth2, **summary(res)}
    others = []
    for k in range(1, 4):
        sims = [simulate_observations(r.path, r.points, SimSettings(
            noise_px=0.3, delay_ms=85.0, tie_points=n, seed=seed + k))
            for r, n in ((run, 500), (second, 300))]
        res = calibrate(join_flights([run.input(nominal, sims[0], dem=True),
                                      second.input(nominal, sims[1], dem=True)]),
                        replace(opt, groups=joint_groups))
        e, sg = block_params(res)["time_delay"]
        others.append({"seed": seed + k, "estimate": e, "sigma": sg})
    print("    other noise seeds: " + ", ".join(
        f"{o['estimate']:.2f} ± {o['sigma']:.2f}" for o in others) + " ms")
    out["two_flights"]["other_seeds"] = others
    print(f"  {second.path.name} alone, estimated with boresight and self-calibration")
    res = calibrate(second.input(nominal, sim2, dem=True), replace(opt, groups=joint_groups))
    out["second_alone"] = {"params": table(res, truth2, (*CORE, "time_delay"), False),
                           **summary(res)}
    print("  the seed's sweep: ±100 ms in 5 ms steps, boresight known, minimum control RMS")
    t0 = time.perf_counter()
    sw = sweep_delay(run.input(known, sim, dem=True), opt, np.arange(-100.0, 100.1, 5.0))
    print(f"    minimum at {sw['best_ms']:.2f} ms (RMS {min(sw['rms_m']):.2f} m; 0 ms: "
          f"{sw['rms_m'][20]:.2f} m), {time.perf_counter() - t0:.0f} s")
    out["sweep"] = sw
    return out


def antenna(run: Run, seed: int) -> dict[str, Any]:
    print("\n3. antenna offset: the sensor file's is 1.5 m short along track (phase GPS)")
    sim = simulate_observations(run.path, run.points, SimSettings(
        noise_px=0.3, tie_points=500, seed=seed))
    known = known_sensor(run, sim.truth)
    g = np.asarray(known.mounting.antenna_offset_m) - np.array([1.5, 0.0, 0.0])
    wrong = known.model_copy(update={"mounting": known.mounting.model_copy(
        update={"antenna_offset_m": tuple(float(v) for v in g)})})
    inp = run.input(wrong, sim, dem=True)
    opt = CalibrationOptions(groups=(Group.GPS_STRIP,), gcp_sigma_m=(0.05, 0.05))
    res = calibrate(inp, opt)
    heads = [s.heading_deg for s in _strips(run)]
    rows = [p for p in parameter_rows(res) if p["name"] == "gps_north"]
    print("    per-strip GPS shift north (m), strip heading:")
    shifts = []
    for r, h in zip(rows, heads, strict=False):
        print(f"      strip {r['segment']:2d}  heading {h:5.1f}°  {r['estimate']:+7.3f} ± "
              f"{r['sigma']:.3f}")
        shifts.append({"segment": r["segment"], "heading_deg": h, "north_m": r["estimate"],
                       "sigma_m": r["sigma"]})
    res = calibrate(inp, replace(opt, groups=(Group.ANTENNA,)))
    truth = {"antenna_dx": 1.5, "antenna_dy": 0.0, "antenna_dz": 0.0}
    print("    antenna offset correction Δg (true − file):")
    params = table(res, truth, ("antenna_dx", "antenna_dy", "antenna_dz"), False)
    return {"strip_shifts": shifts, "antenna": params, **summary(res)}


def _strips(run: Run) -> list[Any]:
    from emulators.trajectory import TruthTrajectory

    return list(TruthTrajectory.from_scenario(run.scn).strips)


def check_points(run: Run, seed: int, seeds: int = 8) -> dict[str, Any]:
    print(f"\n4. check points after calibration (phase GPS, exact survey, 0.3 px, 300 ties, DEM;"
          f" {seeds} noise seeds)")
    opt = CalibrationOptions(groups=parse_groups("boresight,selfcal"), gcp_sigma_m=(0.02, 0.02),
                             dem_sigma_m=0.5)
    per_seed = []
    for k in range(seeds):
        sim = simulate_observations(run.path, run.points, SimSettings(
            noise_px=0.3, tie_points=300, seed=seed + k))
        res = calibrate(run.input(sensor_of(run.scn, nominal=True), sim, dem=True), opt)
        c = res.check or {}
        row = {"seed": seed + k, "observations": c["observations"]}
        for axis in ("along", "across"):
            row[f"rms_{axis}_m"] = c[f"rms_{axis}_m"]
            row[f"predicted_{axis}_m"] = c[f"predicted_rms_{axis}_m"]
        per_seed.append(row)
        print(f"    seed {seed + k}: along {row['rms_along_m']:.3f} / "
              f"{row['predicted_along_m']:.3f} m, across {row['rms_across_m']:.3f} / "
              f"{row['predicted_across_m']:.3f} m", flush=True)
    pooled = {}
    for axis in ("along", "across"):
        got = math.sqrt(np.mean([r[f"rms_{axis}_m"] ** 2 for r in per_seed]))
        pred = math.sqrt(np.mean([r[f"predicted_{axis}_m"] ** 2 for r in per_seed]))
        pooled[axis] = {"rms_m": got, "predicted_m": pred, "ratio": got / pred}
        print(f"    pooled {axis:<6} RMS {got:.3f} m, predicted {pred:.3f} m: ratio "
              f"{got / pred:.3f}")
    n = per_seed[0]["observations"]
    print(f"    ({n} measurements per seed: one seed's RMS scatters by ≈ "
          f"{100 / math.sqrt(2 * n):.1f} %)")
    return {"per_seed": per_seed, "pooled": pooled}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=Path, default=Path("runs/calibration"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only-seed-configuration", action="store_true",
                    help="figure 1 alone (simulates only the code-GPS run)")
    args = ap.parse_args()
    args.runs.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    code = ensure_run(args.runs, "garrotxa", {"base": "garrotxa"})
    figures = {"seed_configuration": seed_configuration(code, args.seed)}
    if not args.only_seed_configuration:
        phase = ensure_run(args.runs, "garrotxa-phase",
                           {"base": "garrotxa", "gps": {"solution": "phase"}})
        low = ensure_run(args.runs, "bellmunt-garrotxa-sensor", SECOND_FLIGHT)
        figures |= {"boresight_only": boresight_only(phase, args.seed),
                    "time_delay": delay(phase, low, args.seed),
                    "antenna": antenna(phase, args.seed),
                    "check_points": check_points(phase, args.seed)}
    path = args.runs / ("calibration_bench_seed.json" if args.only_seed_configuration
                        else "calibration_bench.json")
    path.write_text(json.dumps(figures, indent=1, default=float) + "\n", encoding="utf-8")
    print(f"\n{path} written; {time.perf_counter() - t0:.0f} s in all")


if __name__ == "__main__":
    main()
