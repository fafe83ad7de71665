"""What writing a large file costs this machine's kernel, by where its page-cache pages come from.

    .venv/bin/python bench/page_cache_cost.py [--mb 812] [--runs 3] [--pause-s 5] [--dir DIR]

The uncompressed GeoTIFF of bench/ortho_speed.py was ~812 MB when its tiles were 512 cells (the
default size, as measured in docs/georef.md; ~600 MB with today's 256); how long the kernel
takes to copy it into the page cache decides whether a run of `sisa ortho` takes ~1.1 s or
~2 s. Three ways
to write the same bytes (1 MB writes, in a child process each, system time from its rusage):

- reused: a file of the same size written, then deleted just before (as bench/ortho_speed.py
  deletes the previous run's output): its pages, just freed, are taken again;
- fresh: the same, then `--pause-s` idle: on a virtual machine with free-page reporting
  (/sys/module/page_reporting) the guest meanwhile hands the freed memory back to the host,
  and each page written then costs the host a fault and a page to clear;
- write-behind: fresh, but the file's finished part handed to the disk (sync_file_range) and
  dropped from the cache two 32 MB chunks later (posix_fadvise DONTNEED), so its pages are
  taken again as it grows: the kernel's write-back work falls inside the run instead.

Tried in `sisa ortho` on 2026-11-27 and not adopted: see docs/georef.md, "Why runs of
the ortho vary on this machine".
"""

from __future__ import annotations

import argparse
import ctypes
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHUNK = 32 << 20
LAG_CHUNKS = 2
SYNC_FILE_RANGE_WRITE = 2


def write_file(path: Path, mb: int, behind: bool) -> None:
    """The child: `mb` MB in 1 MB writes, optionally with write-behind."""
    block = os.urandom(1 << 20)
    start_writeback = ctypes.CDLL(None, use_errno=True).sync_file_range
    start_writeback.argtypes = [ctypes.c_int, ctypes.c_int64, ctypes.c_int64, ctypes.c_uint]
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        started = dropped = 0
        for i in range(mb):
            os.write(fd, block)
            done = (i + 1) << 20
            if behind and done % CHUNK == 0:
                start_writeback(fd, started, done - started, SYNC_FILE_RANGE_WRITE)
                started = done
                drop_to = started - LAG_CHUNKS * CHUNK
                if drop_to > dropped:
                    os.posix_fadvise(fd, dropped, drop_to - dropped, os.POSIX_FADV_DONTNEED)
                    dropped = drop_to
    finally:
        os.close(fd)


def one_run(path: Path, mb: int, mode: str, pause_s: float) -> tuple[float, float]:
    """(wall s, system s) of one child writing the file in `mode`."""
    if mode == "reused":  # a whole file's pages in the cache, to be freed just before
        write_file(path, mb, behind=False)
    path.unlink(missing_ok=True)
    os.sync()
    if mode != "reused":
        time.sleep(pause_s)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, __file__, "--child", str(path), "--mb", str(mb),
                    *(["--behind"] if mode == "write-behind" else [])], check=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, after.ru_stime - before.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mb", type=int, default=812)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--pause-s", type=float, default=5.0)
    ap.add_argument("--dir", type=Path, default=None,
                    help="a folder on the disk to test (default: the system's temp folder)")
    ap.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--behind", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child is not None:
        write_file(args.child, args.mb, args.behind)
        return
    if args.mb < 1 or args.runs < 1 or args.pause_s < 0:
        ap.error("--mb and --runs must be at least 1, --pause-s 0 or more")
    if args.dir is not None and not args.dir.is_dir():
        ap.error(f"--dir {args.dir}: no such folder")
    reporting = Path("/sys/module/page_reporting").exists()
    print(f"writing {args.mb} MB, {args.runs} run(s) a mode (alternating), pause "
          f"{args.pause_s:g} s; free-page reporting on this kernel: "
          f"{'yes' if reporting else 'no'}")
    modes = ("reused", "fresh", "write-behind")
    times: dict[str, list[tuple[float, float]]] = {m: [] for m in modes}
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        path = Path(tmp) / "big.bin"
        for _ in range(args.runs):
            for mode in modes:
                times[mode].append(one_run(path, args.mb, mode, args.pause_s))
        path.unlink(missing_ok=True)
    for mode in modes:
        walls = [w for w, _ in times[mode]]
        syss = [s for _, s in times[mode]]
        print(f"  {mode:12s} system {statistics.median(syss):5.2f} s (range {min(syss):.2f}-"
              f"{max(syss):.2f}), wall {statistics.median(walls):5.2f} s (range "
              f"{min(walls):.2f}-{max(walls):.2f}), median of {args.runs}")


if __name__ == "__main__":
    main()
