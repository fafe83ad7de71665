"""The navigation's own error in the adjustment: what the trajectory's producer states about its
accuracy, turned into a stochastic model, so that σ cover it (docs/calibration.md).

The adjustment takes the trajectory as given, but a GPS solution has errors of its own that
stay correlated for minutes: a code solution ~1 m, a phase one a few cm, with a correlation
time of about a minute. Every observation taken within that time shares them, so they do not
average out like image noise, and σ that leave them out are too small (issue 32: z RMS 2.4 for
κ with a code solution). The model is the textbook one for such an error, a first-order
Gauss–Markov process per axis (east, north, up):

    e(t)  with  E[e] = 0,  E[e(t)·e(t')] = σ²·exp(−|t − t'|/τ)

σ (horizontal, vertical) and τ are the trajectory's STATED accuracy (`NavigationAccuracy`: a
run's scenario states them for its receiver, a real flight's user states them), never the
simulation's truth. The process is sampled at knots every τ/KNOTS_PER_TAU seconds over each
segment's observations; the knots are nuisance parameters of the adjustment (a shift of the
perspective centre) with the process's exact prior: for knots in time order,

    e_0 / σ ~ N(0, 1),   (e_k − ρ_k·e_{k−1}) / (σ·√(1 − ρ_k²)) ~ N(0, 1),   ρ_k = exp(−Δt_k/τ)

(the Markov property makes this the joint law of the knots, across strips too: the turn
between two strips lasts a few τ, so their errors are nearly, not quite, independent). At an
observation between two knots the error is the process's conditional mean given both (weights
a, b from the exponential covariance), and what is left, the bridge variance
σ²·(1 − a·ρ₁ − b·ρ₂) (at most ~0.17σ² for knots τ/3 apart), is added to the observation's
variance. Flights with another stated accuracy are separate chains (independent errors).

The INS attitude is not in this model: a constant attitude error is a boresight (calibrated
with it), and a navigation-grade INS's drift over a block (a few ″) and white noise (2–3″)
move a point by less than 0.01 px at the CASI's 15 µm pixels and 10 mm focal length. A poorer
INS can estimate per-strip `attitude` (and `drift`) with priors from its stated accuracy.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from sisa.core.errors import ConfigError

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

KNOTS_PER_TAU: Final = 3  # knot spacing τ/3: bridge variance ≤ 0.17σ², and few knots
MAX_KNOTS: Final = 600  # beyond this the spacing grows (every knot is 3 parameters)
MIN_SPACING_S: Final = 1.0  # the GPS gives one fix a second: no finer knots than that
ENU_NAMES: Final = ("nav_east", "nav_north", "nav_up")


@dataclass(frozen=True)
class NavigationAccuracy:
    """The trajectory's stated accuracy: σ of its GPS antenna positions (horizontal,
    vertical; metres) and the correlation time of their error (s, first-order Gauss–Markov)."""

    gps_sigma_m: tuple[float, float]
    gps_correlation_s: float = 60.0

    def __post_init__(self) -> None:
        h, v = self.gps_sigma_m
        if not (math.isfinite(h) and math.isfinite(v) and h >= 0 and v >= 0):
            raise ConfigError("navigation accuracy: σ must be finite and ≥ 0")
        if not (math.isfinite(self.gps_correlation_s) and self.gps_correlation_s > 0):
            raise ConfigError("navigation accuracy: the correlation time must be > 0 s")

    @property
    def modelled(self) -> bool:
        return max(self.gps_sigma_m) > 0

    @property
    def sigma_enu_m(self) -> F64:
        h, v = self.gps_sigma_m
        return np.array([h, h, v], np.float64)


Navigation = NavigationAccuracy | Mapping[int, NavigationAccuracy] | None


def per_segment(nav: Navigation, segments: list[int]) -> dict[int, NavigationAccuracy]:
    """The stated accuracy of every segment that has one (a model that is not off)."""
    if nav is None:
        return {}
    if isinstance(nav, NavigationAccuracy):
        return {s: nav for s in segments if nav.modelled}
    return {s: nav[s] for s in segments if s in nav and nav[s].modelled}


@dataclass(frozen=True)
class NavWeights:
    """Where each observation sits among the knots: e(t) ≈ w0·e[i0] + w1·e[i1] (ENU), and the
    variance left over (N, 3). Rows without a model have w0 = w1 = 0."""

    i0: I64
    i1: I64
    w0: F64
    w1: F64
    bridge_var_m2: F64  # (N, 3)

    @staticmethod
    def none(n: int) -> NavWeights:
        z = np.zeros(n, np.int64)
        return NavWeights(z, z.copy(), np.zeros(n), np.zeros(n), np.zeros((n, 3)))

    def error(self, knots_enu_m: F64) -> F64:
        """(N, 3) ENU error at every observation."""
        if knots_enu_m.shape[0] == 0:
            return np.zeros((self.i0.size, 3))
        return np.asarray(self.w0[:, None] * knots_enu_m[self.i0]
                          + self.w1[:, None] * knots_enu_m[self.i1], np.float64)


@dataclass(frozen=True)
class NavKnots:
    """The knots of the Gauss–Markov model, in time order over all segments."""

    t_ns: I64
    segment: I64
    chain: I64  # knots of one chain (one stated accuracy) are correlated
    sigma_enu_m: F64  # (K, 3)
    tau_s: F64  # (K,)
    rho_prev: F64  # correlation with the previous knot of the chain (0 at a chain's start)
    spacing_s: float

    @property
    def count(self) -> int:
        return int(self.t_ns.size)

    def weights(self, segment: I64, t_ns: I64) -> NavWeights:
        """Interpolation weights of observations (segment, time) from the two knots around
        them (the Gauss–Markov conditional mean) and the bridge variance."""
        n = t_ns.size
        out = NavWeights.none(n)
        if self.count == 0 or n == 0:
            return out
        chain_of = {int(s): int(c) for s, c in zip(self.segment.tolist(), self.chain.tolist(),
                                                   strict=True)}
        i0, i1 = out.i0, out.i1
        w0, w1, bv = out.w0, out.w1, out.bridge_var_m2
        for c in np.unique(self.chain).tolist():
            kk = np.flatnonzero(self.chain == c)
            rows = np.flatnonzero(np.array([chain_of.get(int(s), -1) == c
                                            for s in segment.tolist()], dtype=np.bool_))
            if rows.size == 0:
                continue
            tk = self.t_ns[kk]
            tau = float(self.tau_s[kk[0]])
            s2 = self.sigma_enu_m[kk[0]] ** 2
            t = t_ns[rows]
            j = np.clip(np.searchsorted(tk, t, side="right") - 1, 0, tk.size - 1)
            before = t < tk[0]
            after = t >= tk[-1]
            inner = ~before & ~after
            lo, hi = j, np.minimum(j + 1, tk.size - 1)
            r1 = np.exp(-np.abs(t - tk[lo]).astype(np.float64) * 1e-9 / tau)
            r2 = np.where(inner, np.exp(-np.abs(tk[hi] - t).astype(np.float64) * 1e-9 / tau),
                          0.0)
            rho = np.where(inner, np.exp(-(tk[hi] - tk[lo]).astype(np.float64) * 1e-9 / tau),
                           0.0)
            den = np.where(inner, 1.0 - rho * rho, 1.0)
            a = np.where(inner, (r1 - rho * r2) / den, r1)
            b = np.where(inner, (r2 - rho * r1) / den, 0.0)
            i0[rows], i1[rows] = kk[lo], kk[hi]
            w0[rows], w1[rows] = a, b
            left = np.clip(1.0 - a * r1 - b * r2, 0.0, 1.0)
            bv[rows] = left[:, None] * s2[None, :]
        return out

    def prior_rows(self) -> tuple[F64, I64, I64, F64]:
        """The whitened AR(1) prior, per knot and axis: (coefficient of the knot itself,
        column of the previous knot (−1 at a chain's start), its column, coefficient of the
        previous knot). Row value = c_self·e_k + c_prev·e_{k−1}. Columns count 3·k + axis."""
        k = self.count
        c_self = np.empty(3 * k)
        c_prev = np.zeros(3 * k)
        col = np.arange(3 * k, dtype=np.int64)
        prev = np.full(3 * k, -1, np.int64)
        for i in range(k):
            rho = float(self.rho_prev[i])
            s = self.sigma_enu_m[i] * math.sqrt(1.0 - rho * rho)
            for a in range(3):
                c_self[3 * i + a] = 1.0 / s[a]
                if rho > 0.0:
                    c_prev[3 * i + a] = -rho / s[a]
                    prev[3 * i + a] = 3 * (i - 1) + a
        return c_self, prev, col, c_prev


def knot_spacing_s(spans_s: list[float], tau_s: float) -> float:
    """τ/KNOTS_PER_TAU, coarser if the knots would exceed MAX_KNOTS, never below a second."""
    spacing = max(tau_s / KNOTS_PER_TAU, MIN_SPACING_S)
    total = sum(spans_s)
    if total / spacing + 2 * len(spans_s) > MAX_KNOTS:
        spacing = total / max(MAX_KNOTS - 2 * len(spans_s), 1)
    return spacing


def build_knots(accuracy: dict[int, NavigationAccuracy], spans_ns: dict[int, tuple[int, int]]
                ) -> NavKnots | None:
    """Knots over each segment's span (first to last observation), evenly spaced, chained in
    time order per stated accuracy."""
    segs = sorted((s for s in accuracy if s in spans_ns), key=lambda s: spans_ns[s][0])
    if not segs:
        return None
    chains: dict[NavigationAccuracy, int] = {}
    for s in segs:
        chains.setdefault(accuracy[s], len(chains))
    t_all: list[int] = []
    seg_all: list[int] = []
    for s in segs:
        lo, hi = spans_ns[s]
        acc = accuracy[s]
        spacing = knot_spacing_s([(spans_ns[x][1] - spans_ns[x][0]) * 1e-9 for x in segs
                                  if accuracy[x] == acc], acc.gps_correlation_s)
        n = max(2, math.ceil((hi - lo) * 1e-9 / spacing) + 1)
        t = np.rint(np.linspace(lo, hi, n)).astype(np.int64) if hi > lo else \
            np.array([lo, lo + 1], np.int64)
        t_all += t.tolist()
        seg_all += [s] * t.size
    order = np.argsort(np.asarray(t_all), kind="stable")
    t_ns = np.asarray(t_all, np.int64)[order]
    seg = np.asarray(seg_all, np.int64)[order]
    chain = np.array([chains[accuracy[int(s)]] for s in seg.tolist()], np.int64)
    sig = np.stack([accuracy[int(s)].sigma_enu_m for s in seg.tolist()])
    tau = np.array([accuracy[int(s)].gps_correlation_s for s in seg.tolist()])
    rho = np.zeros(t_ns.size)
    last: dict[int, int] = {}
    for i, c in enumerate(chain.tolist()):
        if c in last:
            j = last[c]
            rho[i] = math.exp(-(int(t_ns[i]) - int(t_ns[j])) * 1e-9 / float(tau[i]))
        last[c] = i
    # a chain's knots must follow each other: reorder so each chain is contiguous in time
    spacing = min(knot_spacing_s([(spans_ns[x][1] - spans_ns[x][0]) * 1e-9 for x in segs
                                  if accuracy[x] == a], a.gps_correlation_s)
                  for a in chains)
    return _contiguous(NavKnots(t_ns, seg, chain, sig, tau, rho, spacing))


def _contiguous(k: NavKnots) -> NavKnots:
    """Knots sorted by (chain, time): a knot's previous one in its chain is the row before."""
    order = np.lexsort((k.t_ns, k.chain))
    rho = k.rho_prev[order]
    return NavKnots(k.t_ns[order], k.segment[order], k.chain[order], k.sigma_enu_m[order],
                    k.tau_s[order], rho, k.spacing_s)
