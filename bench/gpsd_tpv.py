"""Our GGA/RMC/ZDA against gpsd itself: each standard-valid sentence of gpsd's regression logs
paired with the TPV in which gpsd states its epoch (tests/acquisition/gpsd_tpv.py: how gpsd's
.chk is read, what standard-valid is, the verdicts).

    .venv/bin/python bench/gpsd_tpv.py                          # the 80 logs of gpsd_corpus/
    .venv/bin/python bench/gpsd_tpv.py path/to/gpsd/test/daemon --show 3

A folder of `NAME.log` + `NAME.log.chk`. Per sentence type: candidates (a right checksum),
standard-valid, decoded by us, matched (a TPV states its time, position or height from it),
equal (every value gpsd states of it equal to ours: time to gpsd's ms, lat/lon, altMSL and
altHAE within 1 mm); then the exceptions by verdict (gpsd states nothing of the sentence, or
otherwise by its design) and the defects of the non-standard ones.

Exit status 1 if a standard-valid sentence is not decoded, if under 99 % of the matched ones
are equal, or if a difference or an unstated sentence has no named cause.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.acquisition.gpsd_tpv import FIELDS, KINDS, Verdict, tally_folder  # noqa: E402

TARGET = 0.99
COLUMNS = ("candidates", "standard-valid", "decoded", "matched", Verdict.EQUAL)
UNEXPLAINED = (Verdict.DIFFERS, Verdict.UNSTATED, Verdict.REFUSED, Verdict.NOT_ECHOED)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", nargs="?", type=Path,
                        default=ROOT / "tests" / "acquisition" / "gpsd_corpus")
    parser.add_argument("--show", type=int, default=2, help="examples shown per exception")
    args = parser.parse_args(argv)
    logs = [log for log in sorted(args.folder.glob("*.log"))
            if (log.parent / f"{log.name}.chk").exists()]
    tally = tally_folder(args.folder)
    print(f"{len(logs)} log(s) in {args.folder}")
    print(f"{'type':4} " + " ".join(f"{c:>14}" for c in COLUMNS) + f" {'equal/matched':>14}")
    for kind in [*KINDS, None]:
        row = [tally.of(c, kind) for c in COLUMNS]
        share = row[4] / row[3] if row[3] else float("nan")
        print(f"{kind or 'all':4} " + " ".join(f"{n:14d}" for n in row) + f" {share:14.2%}")
    print("fields compared (sentences): " + ", ".join(
        f"{name} {tally.of(f'{name} compared')}" for name in FIELDS))
    valid, decoded = tally.of("standard-valid"), tally.of("decoded")
    matched, equal = tally.of("matched"), tally.of(Verdict.EQUAL)
    unexplained = sum(sum(tally.exceptions.get(v, {}).values()) for v in UNEXPLAINED)
    met = decoded == valid and matched and equal >= TARGET * matched and not unexplained
    print(f"target: every standard-valid sentence decoded, ≥ {TARGET:.0%} of those gpsd states "
          f"equal, every other one a named exception: {'met' if met else 'NOT MET'}")
    print("exceptions (standard-valid, not equal):")
    for found, by_file in sorted(tally.exceptions.items(), key=lambda kv: -sum(kv[1].values())):
        print(f"  {sum(by_file.values()):4d}  {found}  ({len(by_file)} log(s))")
        for example in tally.examples.get(found, [])[:args.show]:
            print(f"          {example[:200]}")
    print("not standard-valid (left out):")
    for defect, n in tally.defects.most_common():
        print(f"  {n:4d}  {defect}")
    return 0 if met else 1


if __name__ == "__main__":
    sys.exit(main())
