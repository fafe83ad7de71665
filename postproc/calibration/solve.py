"""Gauss–Newton on the normal equations, with the ground points eliminated (Schur complement).

Each point's 3×3 block is independent of the others, so the normal matrix
    [N_gg  N_gp]   reduces to   S = N_gg − Σ_p N_gp,p · N_pp,p⁻¹ · N_pg,p
    [N_pg  N_pp]
of the size of θ (tens of parameters) however many points there are. The inverse of S is the
parameters' cofactor matrix; the point blocks and every row's leverage h = a·Q·aᵀ follow from it
(leverages give the redundancy numbers 1 − h for data snooping). Columns are scaled to a unit
diagonal before factorising, so arcsec, mm and ms sit side by side; a singular or nearly
singular S means the observations cannot separate some parameters, and the error names them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt
from scipy.linalg import LinAlgError, cho_factor, cho_solve

from postproc.calibration.problem import DATA_ROWS, NAV_PRIOR, PRIOR, Linear, Problem
from sisa.core.errors import InputError

F64 = npt.NDArray[np.float64]

SINGULAR_RCOND: Final = 1e-7  # |r| ≳ 1 − 1e-7: the data do not separate them
MAX_ITERATIONS: Final = 30
MAX_HALVINGS: Final = 8
STEP_TOL: Final = 1e-4  # converged when every step is below this fraction of its σ
OVERFLOW: Final = ("the normal equations overflow: a stated σ (sigma_px, --gcp-sigma-m, "
                   "--dem-sigma-m, a prior) is too small for double precision")


@dataclass
class Normal:
    """The reduced system and what the covariance needs."""

    s: F64  # (G, G)
    ngp: F64  # (P, G, 3)
    npp_inv: F64  # (P, 3, 3)
    bg: F64
    bp: F64  # (P, 3)


@dataclass
class Covariance:
    """Cofactors (unit weight): multiply by σ0² for covariances."""

    qgg: F64
    qgp: F64  # (P, G, 3)
    qpp: F64  # (P, 3, 3)


def normal_equations(lin: Linear, n_points: int) -> Normal:
    g = lin.jg.shape[1]
    has_p = lin.pidx >= 0
    pid = lin.pidx[has_p]
    jg, jp, r = lin.jg[has_p], lin.jp[has_p], lin.r[has_p]
    ngp = np.zeros((n_points, g, 3))
    npp = np.zeros((n_points, 3, 3))
    bp = np.zeros((n_points, 3))
    with np.errstate(over="ignore", invalid="ignore"):  # checked below, said in one line
        ngg = lin.jg.T @ lin.jg
        bg = -lin.jg.T @ lin.r
        np.add.at(ngp, pid, np.einsum("mg,mk->mgk", jg, jp))
        np.add.at(npp, pid, np.einsum("mi,mk->mik", jp, jp))
        np.add.at(bp, pid, -jp * r[:, None])
    if not all(np.isfinite(a).all() for a in (ngg, bg, ngp, npp, bp)):
        raise InputError(OVERFLOW)
    npp[np.bincount(pid, minlength=n_points) == 0] = np.eye(3)  # points left out: inert
    det = np.linalg.det(npp)
    if np.any(~(np.abs(det) > 0)):
        raise InputError("a ground point in the adjustment is not determined by its "
                         "observations (a tie point needs two strips)")
    npp_inv = np.asarray(np.linalg.inv(npp), np.float64)
    w = ngp @ npp_inv  # (P, G, 3): one matrix product (BLAS), not an einsum over P·G²
    s = ngg - np.swapaxes(w, 0, 1).reshape(g, 3 * n_points) @ \
        np.swapaxes(ngp, 0, 1).reshape(g, 3 * n_points).T
    bg_red = bg - np.einsum("pgi,pi->g", w, bp)
    return Normal(s, ngp, npp_inv, bg_red, bp)


def _check_separable(s: F64, labels: list[str]) -> F64:
    """The column scale (1/√diag); InputError naming parameters the data cannot separate."""
    d = np.diag(s)
    dead = [labels[i] for i in np.flatnonzero(~(d > 0))]
    if dead:
        raise InputError(f"no observation depends on parameter {dead[0]}: drop its group from "
                         "--estimate")
    scale = 1.0 / np.sqrt(d)
    w, v = np.linalg.eigh(s * scale[:, None] * scale[None, :])
    if w[0] < SINGULAR_RCOND * w[-1]:
        vec = v[:, 0]
        top = np.argsort(-np.abs(vec))[:3]
        names = ", ".join(labels[i] for i in top if abs(vec[i]) > 0.2)
        raise InputError(f"the observations cannot separate parameters {names}: estimate fewer "
                         "groups, add a prior or add observations (tie points, DEM, strips)")
    return np.asarray(scale, np.float64)


def solve_step(norm: Normal, labels: list[str]) -> tuple[F64, F64, F64]:
    """(Δθ, ΔX (P, 3), the scaled S⁻¹ diagonal as σ of θ at unit weight)."""
    if norm.s.shape[0] == 0:
        dg = np.zeros(0)
        sig = np.zeros(0)
    else:
        scale = _check_separable(norm.s, labels)
        ss = norm.s * scale[:, None] * scale[None, :]
        try:
            fac = cho_factor(ss)
        except LinAlgError:
            raise InputError("the normal equations are not positive definite: the parameters "
                             "are not determined by these observations") from None
        dg = scale * cho_solve(fac, scale * norm.bg)
        sig = scale * np.sqrt(np.diag(cho_solve(fac, np.eye(ss.shape[0]))))
    rhs = norm.bp - np.einsum("pgi,g->pi", norm.ngp, dg)
    dp = np.einsum("pij,pj->pi", norm.npp_inv, rhs)
    return dg, dp, sig


def covariance(norm: Normal) -> Covariance:
    g = norm.s.shape[0]
    if g:
        scale = 1.0 / np.sqrt(np.diag(norm.s))
        qgg = np.linalg.inv(norm.s * scale[:, None] * scale[None, :]) * scale[:, None] * \
            scale[None, :]
    else:
        qgg = np.zeros((0, 0))
    a = norm.ngp @ norm.npp_inv  # (P, G, 3)
    qgp = -(qgg @ a)  # (P, G, 3): −Q_gg·N_gp·N_pp⁻¹
    qpp = norm.npp_inv + np.swapaxes(a, 1, 2) @ (qgg @ a)
    return Covariance(qgg, qgp, np.asarray(qpp, np.float64))


def leverages(lin: Linear, cov: Covariance) -> F64:
    """h = a·Q·aᵀ of every row (its redundancy number is 1 − h)."""
    h = np.einsum("mg,mg->m", lin.jg @ cov.qgg, lin.jg)
    has_p = lin.pidx >= 0
    p = lin.pidx[has_p]
    jg, jp = lin.jg[has_p], lin.jp[has_p]
    h[has_p] += 2.0 * np.einsum("mg,mgi,mi->m", jg, cov.qgp[p], jp)
    h[has_p] += np.einsum("mi,mij,mj->m", jp, cov.qpp[p], jp)
    return np.asarray(np.clip(h, 0.0, 1.0), np.float64)


def _cost(lin: Linear) -> float:
    """Σ r² of the weighted residuals; InputError if it overflows (weights of a σ ~1e-300
    gave numpy warnings, then an error that blamed the points)."""
    with np.errstate(over="ignore", invalid="ignore"):
        cost = float(lin.r @ lin.r)
    if not math.isfinite(cost):
        raise InputError(OVERFLOW)
    return cost


@dataclass
class Solution:
    theta: F64
    x_m: F64
    lin: Linear
    norm: Normal
    iterations: int
    cost: float


def gauss_newton(problem: Problem, theta: F64, x_m: F64) -> Solution:
    """Iterate to convergence; a step that raises the cost is halved (damped Gauss–Newton)."""
    labels = problem.layout.labels
    n_points = x_m.shape[0]
    cost = math.inf
    iterations = 0
    for _ in range(MAX_ITERATIONS):
        iterations += 1
        problem.update_rates(theta, x_m)
        lin = problem.linearise(theta, x_m)
        cost = _cost(lin)
        norm = normal_equations(lin, n_points)
        dg, dp, sig = solve_step(norm, labels)
        p_sig = np.sqrt(np.maximum(np.einsum("pii->pi", norm.npp_inv), 1e-30))
        for _ in range(MAX_HALVINGS):
            with np.errstate(over="ignore", invalid="ignore"):  # an inf cost: halve the step
                new_cost = problem.cost(theta + dg, x_m + dp)
            if new_cost <= cost * (1.0 + 1e-9) or not math.isfinite(cost):
                break
            dg, dp = dg / 2.0, dp / 2.0
        theta, x_m = theta + dg, x_m + dp
        small = (np.all(np.abs(dg) <= STEP_TOL * np.maximum(sig, 1e-12))
                 and np.all(np.abs(dp) <= STEP_TOL * np.maximum(p_sig, 1e-3)))
        if small:
            break
    problem.update_rates(theta, x_m)
    lin = problem.linearise(theta, x_m)
    return Solution(theta, x_m, lin, normal_equations(lin, n_points), iterations, _cost(lin))


def posterior(sol: Solution) -> tuple[float, F64, F64]:
    """(σ̂0 of the observations, covariance with only the observations rescaled, the share
    of each variance carried by observations, navigation and priors (G, 3))."""
    lin = sol.lin
    h = leverages(lin, covariance(sol.norm))
    data = np.isin(lin.row_kind, DATA_ROWS)
    redundancy = float(np.sum(1.0 - h[data]))
    sigma0 = math.sqrt(float(lin.r[data] @ lin.r[data]) / redundancy) if redundancy > 0 \
        else math.nan
    g = sol.theta.size
    if g == 0:
        return sigma0, np.zeros((0, 0)), np.zeros((0, 3))
    parts = {k: lin.jg[lin.row_kind == k] for k in (PRIOR, NAV_PRIOR)}
    n_prior, n_nav = (parts[k].T @ parts[k] for k in (PRIOR, NAV_PRIOR))
    n_obs = (sol.norm.s - n_prior - n_nav) / (sigma0**2 if math.isfinite(sigma0) else 1.0)
    m = n_obs + n_prior + n_nav
    scale = 1.0 / np.sqrt(np.diag(m))
    cov = np.linalg.inv(m * scale[:, None] * scale[None, :]) * scale[:, None] * scale[None, :]
    var = np.diag(cov)
    shares = np.stack([np.einsum("ij,ji->i", cov @ n, cov) / var  # diag(C·N·C)
                       for n in (n_obs, n_nav, n_prior)], axis=1)
    return sigma0, np.asarray(cov, np.float64), np.asarray(shares, np.float64)


def reported(cov_all: F64, keep: npt.NDArray[np.int64]) -> tuple[F64, F64, F64]:
    """(covariance, σ, correlation) of the parameters a result reports (`Layout.reported`:
    the navigation knots left out) from the whole covariance."""
    cov = cov_all[np.ix_(keep, keep)]
    sig = np.sqrt(np.diag(cov))
    corr = cov / np.outer(sig, sig) if sig.size else cov
    return np.asarray(cov, np.float64), np.asarray(sig, np.float64), np.asarray(corr, np.float64)
