"""Check-point accuracy of a run whose log ends early: a check point seen on a line that was
not georeferenced has no position, and its NaN made every figure NaN ('nan / nan / nan px')."""

from __future__ import annotations

import json

import numpy as np

from sisa.core.jsonio import write_json
from sisa.wiring.accuracy import CheckPoint, check_point_summary


def _point(pid: str, err_m: list[float]) -> CheckPoint:
    e = np.array(err_m)
    return CheckPoint(pid, 0, 10.0, 20.0, e, e / 2.0)


def test_check_points_without_a_position_are_counted_apart(tmp_path):
    points = [_point("a", [0.3, -0.4, 0.1]), _point("b", [0.5, 0.2, -0.1]),
              _point("c", [np.nan, np.nan, np.nan])]
    s = check_point_summary(points)
    assert (s["points"], s["distinct"], s["not_georeferenced"]) == (2, 2, 1)
    assert np.isclose(s["along"]["rms_m"], np.sqrt((0.3**2 + 0.5**2) / 2))
    assert np.isfinite([s[c]["rms_px"] for c in ("along", "across", "height")]).all()
    none = check_point_summary(points[2:])
    assert none == {"points": 0, "not_georeferenced": 1}


def test_reports_write_null_for_figures_that_could_not_be_computed(tmp_path):
    write_json(tmp_path / "r.json", {"rms": float("nan"), "rows": [1.0, float("inf")],
                                     "n": np.float64("nan")})
    text = (tmp_path / "r.json").read_text()
    assert "NaN" not in text
    assert "Infinity" not in text
    assert json.loads(text) == {"rms": None, "rows": [1.0, None], "n": None}
