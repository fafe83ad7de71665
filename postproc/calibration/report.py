"""What an adjustment reports: estimates with σ, the correlation matrix, residuals of every
observation in pixels and metres, adjusted points, check points, blunders; and the calibration
file itself (a SensorModel TOML with the σ as comments).

σ are a posteriori, but only the observations are rescaled by σ̂0: a prior (δx0's, the
navigation model's) says what is known before the data and is not scaled by how well the data
fit (issue 32). σ̂0² is the observations' weighted square sum over their redundancy
(Σ over observation rows of 1 − h, h the leverage), and the covariance is
(N_obs/σ̂0² + N_prior)⁻¹. Each σ² splits exactly into the part the observations' noise
carries, the part the navigation's error carries and the part the priors carry
(C·N·C summed over the three); a parameter most of whose variance comes from a prior is
reported as set by the prior: the data did not measure it."""

from __future__ import annotations

import math
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from postproc.calibration.adjust import (
    Adjustment,
    CalibrationInput,
    CalibrationOptions,
    CalibrationResult,
    calibrated_sensor,
    check_points,
)
from postproc.calibration.conditioning import Scales, assess
from postproc.calibration.model import line_model
from postproc.calibration.solve import Solution, covariance, posterior, reported
from postproc.georef import SensorModel
from sisa.core.sensor import ARCSEC_RAD

F64 = npt.NDArray[np.float64]
HIGH_CORRELATION: Final = 0.9
SET_BY_PRIOR: Final = 0.5  # a parameter whose variance is mostly its prior's
SHARES: Final = ("observations", "navigation", "prior")


def _image_table(adj: Adjustment, sol: Solution) -> list[dict[str, Any]]:
    pb = adj.problem
    st = pb.layout.unpack(sol.theta)
    w = pb.image_residuals(st, sol.x_m) * pb.row_sigma
    model = line_model(pb.model)
    pr = model.project(st, sol.x_m[model.obs.point], pb.pose_for(st))
    depth = np.abs(pr.p_cam_m[:, 2])
    line_m = depth * np.abs(pb.rate) / pr.focal_m
    pixel_m = depth * model.pitch_m / pr.focal_m
    used = pb.obs_in()
    o = adj.obs
    return [{"id": str(o.point_id[i]), "kind": str(pb.points.kind[pb.model.obs.point[i]]),
             "segment": int(o.segment[i]), "line": float(o.line[i]),
             "pixel": float(o.pixel[i]), "along_px": float(w[i, 0]),
             "across_px": float(w[i, 1]), "along_m": float(w[i, 0] * line_m[i]),
             "across_m": float(w[i, 1] * pixel_m[i]), "used": bool(used[i])}
            for i in range(len(o))]


def _point_table(adj: Adjustment, sol: Solution, sigma0: float) -> list[dict[str, Any]]:
    pb = adj.problem
    cov = covariance(sol.norm)
    r = pb.r_enu
    out = []
    for p in range(pb.points.ids.size):
        q = r.T @ cov.qpp[p] @ r
        row: dict[str, Any] = {"id": str(pb.points.ids[p]), "kind": str(pb.points.kind[p]),
                               "used": bool(pb.point_active[p]),
                               "sigma_enu_m": (sigma0 * np.sqrt(np.diag(q))).tolist()}
        if pb.points.kind[p] == "control":
            row["correction_enu_m"] = (r.T @ (sol.x_m[p] - pb.points.surveyed_m[p])).tolist()
        out.append(row)
    return out


def _rms(values: list[float]) -> float:
    v = np.asarray(values, np.float64)
    return float(np.sqrt(np.mean(v * v))) if v.size else math.nan


def _navigation_summary(adj: Adjustment, sol: Solution, cov: F64) -> dict[str, Any] | None:
    """The navigation model's knots: how many, their spacing, and the GPS error they took
    up (RMS of the estimates against their prior σ, east/north/up)."""
    layout = adj.problem.layout
    knots = layout.knots
    if knots is None:
        return None
    cols = layout.nav_columns
    e = sol.theta[cols].reshape(-1, 3)
    s = np.sqrt(np.diag(cov)[cols]).reshape(-1, 3)
    return {"knots": knots.count, "spacing_s": knots.spacing_s,
            "prior_sigma_enu_m": np.unique(knots.sigma_enu_m, axis=0).tolist(),
            "correlation_s": np.unique(knots.tau_s).tolist(),
            "rms_estimate_enu_m": np.sqrt(np.mean(e * e, axis=0)).tolist(),
            "rms_sigma_enu_m": np.sqrt(np.mean(s * s, axis=0)).tolist()}


def assemble(inp: CalibrationInput, opt: CalibrationOptions, adj: Adjustment, sol: Solution,
             blunders: list[dict[str, Any]]) -> CalibrationResult:
    pb = adj.problem
    n_par = sol.theta.size + 3 * int(pb.point_active.sum())
    dof = int(sol.lin.r.size - n_par)
    sigma0, cov_all, shares = posterior(sol)
    keep = pb.layout.reported
    cov, sig, corr = reported(cov_all, keep)
    st = pb.layout.unpack(sol.theta)
    resid = _image_table(adj, sol)
    for b in blunders:
        match = [r for r in resid if r["id"] == b.get("id") and r.get("line") == b.get("line")]
        if match:
            b.update({k: match[0][k] for k in ("along_px", "across_px", "along_m", "across_m")})
    check, check_list = check_points(adj, sol.theta, cov_all)
    counts = {"observations": len(inp.obs), "observations_in_adjustment": len(adj.obs),
              "observations_used": int(pb.obs_in().sum()),
              "control_points": int(((pb.points.kind == "control") & pb.point_active).sum()),
              "tie_points": int(((pb.points.kind == "tie") & pb.point_active).sum()),
              "check_points_in_adjustment": int(((pb.points.kind == "check")
                                                 & pb.point_active).sum()),
              "dem_rows": int(pb.dem_in().sum()), "check_observations": len(adj.check_ids),
              "strips": len(pb.layout.segments), "parameters": int(sol.theta.size),
              "rows": int(sol.lin.r.size)}
    layout = pb.layout.only_reported()
    sensor = calibrated_sensor(inp.sensor, st)
    scales = Scales.of(sensor, _line_period_ms(inp), _ground_pixel_m(resid))
    conditioning = assess(layout, sig, corr, scales)
    return CalibrationResult(layout, sol.theta[keep], st, sig, corr, cov, sigma0, dof,
                             sol.iterations, sensor, resid, blunders,
                             _point_table(adj, sol, sigma0 if math.isfinite(sigma0) else 1.0),
                             check, check_list, counts,
                             adj.notes.lines + conditioning["messages"],
                             sigma_share=shares[keep],
                             navigation=_navigation_summary(adj, sol, cov_all),
                             conditioning=conditioning)


def _line_period_ms(inp: CalibrationInput) -> float:
    """The median line period over the segments (nan without two timed lines)."""
    periods = [inp.clock.line_period_ns(s) for s in inp.clock.t_by_segment]
    periods = [p for p in periods if math.isfinite(p)]
    return float(np.median(periods)) / 1e6 if periods else math.nan


def _ground_pixel_m(resid: list[dict[str, Any]]) -> float:
    """The median ground size of a pixel across track at the measurements (nan if none)."""
    ratio = [abs(r["across_m"] / r["across_px"]) for r in resid if abs(r["across_px"]) > 1e-6]
    return float(np.median(ratio)) if ratio else math.nan


def parameter_rows(res: CalibrationResult) -> list[dict[str, Any]]:
    start = res.layout.start()
    shares = res.sigma_share if res.sigma_share is not None else \
        np.tile([1.0, 0.0, 0.0], (len(res.layout.params), 1))
    return [{"name": p.name, "segment": p.segment if p.segment >= 0 else None,
             "group": p.group.value, "unit": p.unit, "estimate": float(res.theta[i]),
             "sigma": float(res.sigma[i]), "start": float(start[i]),
             "prior_sigma": p.prior_sigma,
             "sigma_share": dict(zip(SHARES, (float(v) for v in shares[i]), strict=True)),
             "set_by_prior": bool(shares[i][2] >= SET_BY_PRIOR)}
            for i, p in enumerate(res.layout.params)]


def high_correlations(res: CalibrationResult, limit: float = HIGH_CORRELATION
                      ) -> list[dict[str, Any]]:
    labels = res.layout.labels
    out = [{"a": labels[i], "b": labels[j], "r": float(res.correlation[i, j])}
           for i in range(len(labels)) for j in range(i + 1, len(labels))
           if abs(res.correlation[i, j]) >= limit]
    return sorted(out, key=lambda d: -abs(d["r"]))


def look_angles(res: CalibrationResult) -> dict[str, Any]:
    """What the images fix even when the parameters are inseparable: the along-track look
    offset δx0 − f'·φ and the across-track one δy0 + f'·ω (µm on the focal plane, f' = f + δf;
    φ and δx0 are exactly equivalent for a line, ω and δy0 nearly)."""
    st, sc = res.state, res.sensor.scanner
    f_um = (sc.focal_length_mm + st.selfcal[0]) * 1e3
    w, p = (float(a) * ARCSEC_RAD for a in st.boresight_arcsec[:2])
    values = {"along_um": float(st.selfcal[1]) - f_um * p,
              "across_um": float(st.selfcal[2]) + f_um * w}
    grads: dict[str, dict[tuple[str, str], float]] = {
        "along_um": {("boresight", "phi"): -f_um * ARCSEC_RAD,
                     ("selfcal", "delta_focal"): -1e3 * p, ("selfcal", "delta_x0"): 1.0},
        "across_um": {("boresight", "omega"): f_um * ARCSEC_RAD,
                      ("selfcal", "delta_focal"): 1e3 * w, ("selfcal", "delta_y0"): 1.0}}
    out: dict[str, Any] = {}
    for key, value in values.items():
        g = np.array([grads[key].get((q.group.value, q.name), 0.0) if q.segment < 0 else 0.0
                      for q in res.layout.params])
        cov_g = res.covariance @ g if g.size else g
        sigma = float(np.sqrt(g @ cov_g)) if g.size else 0.0
        corr = {lab: float(cov_g[i] / (sigma * res.sigma[i]))
                for i, lab in enumerate(res.layout.labels)
                if sigma > 0 and res.sigma[i] > 0 and g[i] == 0.0
                and abs(cov_g[i] / (sigma * res.sigma[i])) >= HIGH_CORRELATION / 2}
        out[key] = {"value": value, "sigma": sigma, "value_px": value / sc.pixel_pitch_um,
                    "sigma_px": sigma / sc.pixel_pitch_um, "correlations": corr}
    return out


def report_json(res: CalibrationResult, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    used = [r for r in res.residuals if r["used"]]
    return {
        "sigma0": res.sigma0, "dof": res.dof, "iterations": res.iterations,
        "groups": [g.value for g in res.layout.groups], "counts": res.counts,
        "parameters": parameter_rows(res),
        "correlation": {"labels": res.layout.labels, "matrix": res.correlation.tolist()},
        "high_correlations": high_correlations(res), "look_offsets": look_angles(res),
        "residual_rms": {k: _rms([r[k] for r in used])
                         for k in ("along_px", "across_px", "along_m", "across_m")},
        "navigation_model": res.navigation,
        "residuals": res.residuals, "blunders": res.blunders, "points": res.points,
        "check_points": res.check, "check_list": res.check_list, "notes": res.notes,
        "conditioning": res.conditioning,
        "sensor": res.sensor.model_dump(mode="json"), **(extra or {}),
    }


def sensor_toml(res: CalibrationResult) -> str:
    """The calibration file: a SensorModel TOML, estimates ± σ in the leading comments."""
    lines = ["# SISA calibration (sisa calibrate; docs/calibration.md): a sensor file for "
             "`sisa georef --sensor`.",
             *(f"# WARNING, ill-conditioned: {m}"
               for m in res.conditioning.get("messages", [])),
             f"# sigma0 = {res.sigma0:.3f}, {res.dof} degrees of freedom; estimates ± σ (a "
             "posteriori); fixed values are the starting sensor file's."]
    for p in parameter_rows(res):
        if p["segment"] is None:
            lines.append(f"#   {p['name']:<12} = {p['estimate']:12.4f} ± {p['sigma']:.4f} "
                         f"{p['unit']}" + ("  (set by its prior)" if p["set_by_prior"] else ""))
    for h in high_correlations(res)[:6]:
        lines.append(f"#   correlation {h['a']} ↔ {h['b']}: {h['r']:+.3f}")
    return "\n".join(lines) + "\n\n" + res.sensor.to_toml()


def load_check(text: str) -> SensorModel:
    """The TOML text back as a SensorModel (a self-check before writing)."""
    import tomllib

    return SensorModel.model_validate(tomllib.loads(text))
