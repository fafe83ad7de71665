"""Virtual-time emulation speed: the whole flight of a preset, image lines included.

    .venv/bin/python bench/emulate_speed.py [--preset garrotxa] [--no-images]

Prints the emulated flight time, the wall time and the speed-up over real time (target ≥ 50x for
garrotxa with images), with the output counts per wire.
"""

from __future__ import annotations

import argparse
import collections
import resource
import tempfile
import time
from pathlib import Path

from emulators.runtime import Output, Runner
from emulators.scenario import load_scenario
from emulators.system import EmulatedSystem


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--preset", default="garrotxa")
    parser.add_argument("--no-images", action="store_true")
    args = parser.parse_args()
    scn = load_scenario(args.preset)
    counts: collections.Counter[str] = collections.Counter()

    def sink(out: Output) -> tuple[()]:
        counts[out.port.value] += 1
        return ()

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        system = EmulatedSystem(scn, None if args.no_images else Path(tmp) / "scanner")
        t_build = time.perf_counter() - t0
        runner = Runner(system.devices, system.faulty(sink))
        t1 = time.perf_counter()
        runner.run()
        t_run = time.perf_counter() - t1
        image_bytes = sum(p.stat().st_size for p in Path(tmp).rglob("*.bil"))
    flight_s = (system.traj.t_end_ns - system.traj.t_start_ns) / 1e9
    wall_s = t_build + t_run
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"preset {args.preset}: {flight_s:.0f} s of flight "
          f"({len(system.traj.strips)} strips, images {'off' if args.no_images else 'on'})")
    print(f"  build (trajectory, terrain, scene): {t_build:6.1f} s")
    print(f"  run (all devices, virtual time):    {t_run:6.1f} s")
    print("  outputs: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    print(f"  image data written: {image_bytes / 1e6:.0f} MB; peak RSS {peak_mb:.0f} MB")
    print(f"  speed-up over real time: {flight_s / wall_s:.1f}x (target >= 50x)")


if __name__ == "__main__":
    main()
