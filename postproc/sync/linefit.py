"""Straight-line fits that survive outliers and say how well they predict.

Every clock in synchronisation is an offset plus a rate (a line) between two time scales, fitted
from pairs that are mostly right and sometimes grossly wrong (a spurious pulse, a wrong
association). `robust_line` starts from a median-based line, so a gross outlier never steers the
start, then iterates least squares on the points within k robust sigmas. `Line.leverage` gives the
variance factor of a prediction, so callers can state the error the fit itself adds.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]

MAD_TO_SIGMA: Final = 1.4826
MAX_ITERATIONS: Final = 8


@dataclass(frozen=True)
class Line:
    """y = y0 + slope·(x − x0), x0 the mean of the fitted x (so offset and slope are
    uncorrelated). `sigma`: residual standard deviation (n − 2 degrees of freedom)."""

    x0: float
    y0: float
    slope: float
    n: int
    sxx: float  # Σ (x − x0)² over the fitted points
    sigma: float
    x_min: float
    x_max: float

    def __call__(self, x: npt.ArrayLike) -> F64:
        return self.y0 + self.slope * (np.asarray(x, dtype=np.float64) - self.x0)

    def leverage(self, x: npt.ArrayLike) -> F64:
        """Variance of a prediction at x over the variance of one fitted point."""
        dx = np.asarray(x, dtype=np.float64) - self.x0
        lev: F64 = 1.0 / self.n + (dx * dx / self.sxx if self.sxx > 0 else 0.0 * dx)
        return lev


def fit_line(x: F64, y: F64, slope: float | None = None) -> Line:
    """Least squares through the points (a given slope fits only the offset)."""
    n = x.size
    if n == 0:
        raise ValueError("no points to fit")
    x0 = float(x.mean())
    dx = x - x0
    sxx = float(dx @ dx)
    if slope is None:
        slope = float(dx @ (y - y.mean()) / sxx) if n > 1 and sxx > 0 else 0.0
    y0 = float(np.mean(y - slope * dx))
    resid = y - (y0 + slope * dx)
    dof = n - 2 if n > 2 else 1
    sigma = float(np.sqrt(resid @ resid / dof))
    return Line(x0, y0, slope, n, sxx, sigma, float(x.min()), float(x.max()))


def _median_line(x: F64, y: F64, slope: float | None) -> Line:
    """A start that outliers cannot steer: median of slopes between points half the data
    apart (x sorted), then the median offset."""
    if slope is None:
        order = np.argsort(x, kind="stable")
        xs, ys = x[order], y[order]
        half = xs.size // 2
        dx = xs[half:half * 2] - xs[:half]
        ok = dx > 0
        slope = float(np.median((ys[half:half * 2] - ys[:half])[ok] / dx[ok])) if ok.any() else 0.0
    x0 = float(np.median(x))
    y0 = float(np.median(y - slope * (x - x0)))
    return Line(x0, y0, slope, x.size, 0.0, 0.0, float(x.min()), float(x.max()))


def robust_line(x: F64, y: F64, *, sigma_floor: float, k: float = 5.0,
                slope: float | None = None) -> tuple[Line, Bool]:
    """Line through the inliers: points within k·max(robust sigma, sigma_floor) of the line.

    `slope` fixes the slope (only the offset is fitted). Returns the line and the inlier mask.
    """
    line = _median_line(x, y, slope)
    inliers = np.ones(x.size, dtype=np.bool_)
    for _ in range(MAX_ITERATIONS):
        resid = y - line(x)
        scale = max(MAD_TO_SIGMA * float(np.median(np.abs(resid[inliers]))), sigma_floor)
        new = np.abs(resid) <= k * scale
        if not new.any():
            break
        line = fit_line(x[new], y[new], slope)
        if np.array_equal(new, inliers):
            break
        inliers = new
    return line, inliers


def prediction_rms(x_fit: F64, sigma_fit: F64, x: F64) -> float:
    """RMS over the points x of the error of a least-squares line through (x_fit, y_fit) whose
    y_fit have independent errors of standard deviation sigma_fit (one each, or one for all).

    The prediction at x is Σ w_i(x)·y_i with w_i = 1/n + (x − x̄)(x_i − x̄)/Sxx, so its variance
    is Σ w_i² σ_i²: expanded in powers of (x − x̄) and averaged over x.
    """
    n = x_fit.size
    s2 = np.broadcast_to(np.asarray(sigma_fit, dtype=np.float64) ** 2, x_fit.shape)
    d = x_fit - x_fit.mean()
    sxx = float(d @ d)
    a = float(s2.sum()) / n**2
    b = float((d * s2).sum()) / (n * sxx) if sxx > 0 else 0.0
    c = float((d * d * s2).sum()) / sxx**2 if sxx > 0 else 0.0
    dx = x - x_fit.mean()
    return float(np.sqrt(np.mean(a + 2.0 * b * dx + c * dx * dx)))
