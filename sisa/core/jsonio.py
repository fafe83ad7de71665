"""JSON reports: JSON has no NaN or infinity, so a figure that could not be computed is null
(a bare NaN is what Python's json writes by default, and what other readers refuse)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any


def finite_json(value: Any) -> Any:
    """`value` with every non-finite float replaced by None, in nested dicts and lists."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: finite_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite_json(v) for v in value]
    return value


def write_json(path: Path, doc: Any) -> None:
    """`doc` as indented JSON, non-finite figures as null."""
    Path(path).write_text(json.dumps(finite_json(doc), indent=1, allow_nan=False) + "\n",
                          encoding="utf-8")
