"""NovAtel's own decoder SDK (EDIE, the `novatel-edie` package: not a dependency of SISA) reads the
emulated OEM7's stream, and what it writes back from each log is the log we wrote, byte for byte.

    pip install --target /tmp/edie novatel-edie       # apart from the project's venv
    .venv/bin/python bench/novatel_crosscheck.py /tmp/edie    # exit 1 on a mismatch

The stream is a `bench` receiver's (`gps.receiver = "novatel_oem7"`) with 100 events: BESTPOSA,
TIMEA and MARK1TIMEA. For every log: EDIE's fields equal ours (week, seconds, offsets, UTC,
position, σ, counts, enums), its header time equals ours, and its ASCII re-encoding is our raw.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from acquisition.codec import ErrorPolicy  # noqa: E402
from acquisition.novatel import (  # noqa: E402
    BestPos,
    MarkTime,
    NmeaNovatelStreamDecoder,
    TimeLog,
)
from tests.emulators.test_gps import _run  # noqa: E402
from tests.emulators.test_gps_ublox import _events  # noqa: E402

NOVATEL: dict[str, object] = {"gps": {"receiver": "novatel_oem7"}}


def _same(theirs: Any, ours: object) -> bool:
    if not isinstance(ours, MarkTime | TimeLog | BestPos):
        return False
    d = theirs.to_dict()
    h = d["header"]
    if (h["week"], round(h["milliseconds"]) * 1_000_000) != (ours.header.week,
                                                           ours.header.seconds_ns):
        return False
    if isinstance(ours, MarkTime):
        return bool(d["week"] == ours.week and abs(d["seconds"] - ours.seconds_ns / 1e9) < 1e-9
                    and d["offset"] == ours.offset_s and d["utc_offset"] == ours.utc_offset_s
                    and d["status"].name == ours.status.value)
    if isinstance(ours, TimeLog):
        return bool((d["utc_year"], d["utc_month"], d["utc_day"], d["utc_hour"],
                     d["utc_minute"], d["utc_millisecond"]) == (
            ours.utc_year, ours.utc_month, ours.utc_day, ours.utc_hour, ours.utc_minute,
            ours.utc_ms) and d["utc_offset"] == ours.utc_offset_s
            and d["clock_model_status"].name == ours.clock_status.value)
    return bool(d["latitude"] == ours.lat_deg and d["longitude"] == ours.lon_deg
                and d["orthometric_height"] == ours.height_msl_m
                and abs(d["undulation"] - ours.undulation_m) < 1e-4
                and d["solution_status"].name == ours.solution_status.value
                and d["position_type"].name == ours.position_type.value
                and (d["num_svs"], d["num_soln_svs"]) == (ours.svs_tracked, ours.svs_used))


def main() -> int:
    sys.path.append(sys.argv[1] if len(sys.argv) > 1 else "/tmp/edie")
    from novatel_edie import oem  # type: ignore[import-not-found]

    good, _ = _events(NOVATEL)
    _, _, _, stream, _ = _run(NOVATEL, good)  # type: ignore[no-untyped-call]
    ours = NmeaNovatelStreamDecoder(ErrorPolicy.RAISE).feed(stream)
    parser = oem.Parser()
    parser.write(stream)
    fields_differ = raw_differs = 0
    names: dict[str, int] = {}
    for item in ours:
        theirs = parser.read()
        names[type(theirs).__name__] = names.get(type(theirs).__name__, 0) + 1
        fields_differ += not _same(theirs, item.message)
        raw_differs += bytes(theirs.to_ascii().message) != item.raw
    print(f"{len(ours)} logs, EDIE read them as {names}; fields differ in {fields_differ}, "
          f"its ASCII differs from ours in {raw_differs}")
    return 1 if fields_differ or raw_differs else 0


if __name__ == "__main__":
    sys.exit(main())
