"""What one task of a campaign costs, from the records a `sisa campaign process` run left:
wall and CPU time, bytes read and written, the worker's peak RSS, per stage, and per unit of
work (a segment's pixels for the ray casting, its raw image bytes for the ortho).

    .venv/bin/python bench/campaign_costs.py OUT

Each task measures itself (postproc/campaign/tasks.py, `guarded`): CPU and I/O of its worker
process over the task (exact with one thread per worker, as `sisa campaign process` starts
its LocalCluster), bytes through read/write calls whether from the page cache or the disk
(what a network file system would have to carry). Peak RSS is the worker's own since it
started: an upper bound of the task's.
"""

from __future__ import annotations

import json
import statistics
import sys
from pathlib import Path
from typing import Any

MB = 1e6


def main() -> None:
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    out = Path(sys.argv[1])
    stages: dict[str, list[dict[str, Any]]] = {}
    per_unit: dict[str, list[float]] = {}
    for stamp in sorted(out.rglob(".tasks/*.json")):
        doc = json.loads(stamp.read_text())
        rec = doc["outcome"]["record"]
        cost = rec.get("cost")
        if cost is None:
            continue
        stage = stamp.stem.split("_")[0]
        stages.setdefault(stage, []).append(cost)
        seg = rec.get("segment")
        if seg is None or not doc["outcome"]["ok"]:
            continue
        if stage in ("georef", "ortho"):  # per million pixels (rays) of the segment
            mpx = seg["rays"] / 1e6
            image_mb = Path(seg["image"]).stat().st_size / MB
            for what, value in (("cpu_s", cost["cpu_s"]), ("wall_s", cost["wall_s"]),
                                ("read_MB", cost["read_bytes"] / MB),
                                ("written_MB", cost["written_bytes"] / MB),
                                ("image_MB", image_mb)):
                per_unit.setdefault(f"{stage} {what} per Mpx", []).append(value / mpx)
    print(f"{'stage':8} {'tasks':>5} {'wall s':>14} {'CPU s':>14} {'read MB':>14} "
          f"{'written MB':>14} {'peak RSS MB':>12}")
    print(f"{'':8} {'':>5} {'median   max':>14} {'median   max':>14} {'median   max':>14} "
          f"{'median   max':>14} {'max':>12}")
    for stage in ("sync", "georef", "ortho", "flight", "mosaic"):
        costs = stages.get(stage, [])
        if not costs:
            continue

        def fig(key: str, scale: float = 1.0, c: list[dict[str, Any]] = costs) -> str:
            vals = [x[key] / scale for x in c]
            return f"{statistics.median(vals):7.2f}{max(vals):7.2f}"
        rss = max(x["peak_rss_bytes"] for x in costs) / MB
        print(f"{stage:8} {len(costs):5d} {fig('wall_s')} {fig('cpu_s')} "
              f"{fig('read_bytes', MB)} {fig('written_bytes', MB)} {rss:12.0f}")
    for key, vals in per_unit.items():
        if vals:
            print(f"{key}: median {statistics.median(vals):.3f} (of {len(vals)})")


if __name__ == "__main__":
    main()
