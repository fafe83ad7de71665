"""Is the adjustment well conditioned enough to write a sensor file from it?

The solver refuses a singular system (`solve._check_separable`, |r| ≳ 1 − 10⁻⁷), but an
adjustment can be far from singular and still leave a parameter of the sensor file undetermined:
on a short flight with a few control points seen once, ω and δy0 move the image alike (they differ
only by f'·ω·tan²θ across the swath: docs/calibration.md) and came out as ω 1282 ± 882″ for a true
13″ (correlation −0.9997). Written into sensor.toml, such a value is noise along the degenerate
direction.

A parameter of the sensor file (boresight, self-calibration, delay, antenna offset) is
**unresolved** when
- it has a prior and its σ exceeds the prior's σ (the data made it worse than what was stated), or
- it has no prior, its σ exceeds what one pixel is worth for it (below), and no parameter that
  holds a prior is what it is coupled to (|r| ≥ COUPLED): a prior on δy0 is a deliberate split
  of ω and δy0, and then ω's σ is the prior's doing.
One pixel's worth: ω, φ the IFOV (pitch / f'); κ the turn that moves the swath's end pixels by one
pixel (1 / c rad, c = (N − 1)/2); δf the change that moves them by one pixel (f'/c); δx0, δy0 one
pixel pitch; the delay one line period; the antenna offset one ground pixel. A parameter known
worse than that does not calibrate anything the images can show.

The parameters an unresolved one is coupled to (|r| ≥ COUPLED) are named with it: those are what
the data cannot separate, and the advice says what would.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from postproc.calibration.params import Group, Layout
from postproc.georef import SensorModel
from sisa.core.sensor import ARCSEC_RAD

COUPLED: Final = 0.99  # |r| at which two parameters are named as moving the image alike
SENSOR_GROUPS: Final = frozenset({Group.BORESIGHT, Group.SELFCAL, Group.DELAY, Group.ANTENNA})

# What separates parameters the data cannot: (names, all needed, advice). The first entry that
# an unresolved parameter and its partners match (all of its names, or any) gives the advice.
ADVICE: Final[tuple[tuple[frozenset[str], bool, str], ...]] = (
    (frozenset({"omega", "delta_y0"}), True,
     "a prior on δy0 (--prior-y0-um, e.g. 20: a slit's mechanical tolerance), measurements "
     "near the swath edges (tie points with the DEM as surface control: --tie-points for a "
     "simulated run), a second flight at another height (sisa calibrate RUN RUN2), or the "
     "interior geometry known (--estimate boresight)"),
    (frozenset({"phi", "delta_x0"}), True,
     "a prior on δx0 (--prior-x0-um), or the interior geometry known (--estimate boresight)"),
    (frozenset({"time_delay"}), False,
     "a second flight with another height-to-speed ratio (sisa calibrate RUN RUN2), or the "
     "boresight known (--sensor KNOWN.toml --estimate delay)"),
    (frozenset({"antenna_dx", "antenna_dy", "antenna_dz"}), False,
     "the boresight known (--sensor KNOWN.toml --estimate antenna), or strips flown both ways "
     "over relief"),
)
GENERIC: Final = ("more control points, tie points with the DEM as surface control, a prior, "
                  "or another flight; or estimate fewer groups (--estimate)")


@dataclass(frozen=True)
class Scales:
    """What one pixel is worth, from the sensor and the flight."""

    ifov_arcsec: float
    end_turn_arcsec: float  # κ that moves the swath's end pixels by one pixel
    end_focal_mm: float  # δf that does
    pitch_um: float
    line_period_ms: float  # nan if unknown
    ground_pixel_m: float  # nan if unknown

    @classmethod
    def of(cls, sensor: SensorModel, line_period_ms: float, ground_pixel_m: float) -> Scales:
        sc = sensor.scanner
        f_mm = sc.focal_length_mm + sc.delta_focal_mm
        half = max((sc.pixels - 1) / 2.0, 1.0)
        return cls(sc.pixel_pitch_um * 1e-3 / f_mm / ARCSEC_RAD, 1.0 / half / ARCSEC_RAD,
                   f_mm / half, sc.pixel_pitch_um, line_period_ms, ground_pixel_m)

    def pixel_worth(self, name: str) -> tuple[float, str]:
        """(one pixel's worth of parameter `name` in its unit, what that is)."""
        if name in ("omega", "phi"):
            return self.ifov_arcsec, "the IFOV, one pixel's look angle"
        if name == "kappa":
            return self.end_turn_arcsec, "the turn that moves the swath's end pixels by one pixel"
        if name == "delta_focal":
            return self.end_focal_mm, "the change that moves the swath's end pixels by one pixel"
        if name in ("delta_x0", "delta_y0"):
            return self.pitch_um, "one pixel pitch"
        if name == "time_delay":
            return self.line_period_ms, "one line period"
        return self.ground_pixel_m, "one ground pixel"


def assess(layout: Layout, sigma: np.ndarray[Any, Any], correlation: np.ndarray[Any, Any],
           scales: Scales) -> dict[str, Any]:
    """{"ill_conditioned", "unresolved": [...], "messages": [...], "coupled_limit",
    "pixel_worth": {name: value}} for calibration.json and the command."""
    params = layout.params
    labels = layout.labels
    unresolved: list[dict[str, Any]] = []
    worth_of: dict[str, float] = {}
    for i, p in enumerate(params):
        if p.group not in SENSOR_GROUPS:
            continue
        s = float(sigma[i])
        partners = [{"label": labels[j], "r": float(correlation[i, j])}
                    for j in np.argsort(-np.abs(correlation[i])).tolist()
                    if j != i and abs(correlation[i, j]) >= COUPLED]
        worth, what = scales.pixel_worth(p.name)
        worth_of[p.label] = worth
        if p.prior_sigma is not None:
            if not s > p.prior_sigma:
                continue
            why = f"σ {s:.4g} {p.unit} beyond its prior σ {p.prior_sigma:g} {p.unit}"
        else:
            held = [q for q in partners if params[labels.index(q["label"])].prior_sigma]
            if held or not math.isfinite(worth) or not s > worth:
                continue
            why = f"σ {s:.4g} {p.unit} beyond one pixel's worth ({what}: {worth:.4g} {p.unit})"
        unresolved.append({"label": p.label, "unit": p.unit, "sigma": s, "why": why,
                           "partners": partners})
    return {"ill_conditioned": bool(unresolved), "coupled_limit": COUPLED,
            "unresolved": unresolved, "pixel_worth": worth_of,
            "messages": _messages(unresolved)}


def _messages(unresolved: list[dict[str, Any]]) -> list[str]:
    """One line per set of parameters the data cannot separate (ω with δy0 and δy0 with ω are
    one set), giving each one's σ against its limit and what would separate them."""
    groups: dict[frozenset[str], list[dict[str, Any]]] = {}
    for u in unresolved:
        names = frozenset({u["label"], *(q["label"] for q in u["partners"])})
        groups.setdefault(names, []).append(u)
    out: list[str] = []
    for names, members in groups.items():
        whys = "; ".join(f"{u['label']}: {u['why']}" for u in members)
        first = members[0]
        if first["partners"]:
            pairs = ", ".join(f"{first['label']} ↔ {q['label']} {q['r']:+.4f}"
                              for q in first["partners"])
            out.append(f"the observations cannot separate "
                       f"{', '.join([first['label'], *(q['label'] for q in first['partners'])])} "
                       f"(correlation {pairs}): {whys}; to separate them add "
                       f"{_advice(names)}")
        else:
            out.append(f"the observations do not determine {whys}; add {_advice(names)}")
    return out


def _advice(names: frozenset[str]) -> str:
    bare = frozenset(n.split("[", 1)[0] for n in names)
    for names_of, all_needed, advice in ADVICE:
        if (names_of <= bare) if all_needed else bool(names_of & bare):
            return advice
    return GENERIC
