"""Orthorectification: SISA's nearest-pixel-centre ortho against `gdalwarp -geoloc`.

    .venv/bin/python bench/ortho_speed.py                    20 000 lines x 512 px x 18 bands
    .venv/bin/python bench/ortho_speed.py --codecs zstd      the same with ZSTD (level 1)
    .venv/bin/python bench/ortho_speed.py --big-gb 10        also peak memory on a 10 GB file

A synthetic segment is written to disk: a 512-pixel pushbroom (34.2° field of view, 1 m pixels
at nadir) flown along a gently turning track with smooth turbulence (sideways, yaw and
along-track oscillations), its IGM (float64, pixel centres, UTM 31N) and its raw image (uint16
BIL, band 1 = line + 1 and band 2 = pixel + 1, so any resampler's choice can be decoded; the
other bands a textured scene with sensor noise). Both tools map it onto the same 1 m grid,
nearest neighbour, each in its own process (wall time, and peak RSS from the rusage of that
child), writing the same GeoTIFF layout twice: as the product (tiled 256, band-interleaved,
DEFLATE level 1 with the horizontal predictor) and uncompressed (sparse), which times the
resampling without the compression both pay alike. Every timed run starts alike: the output
of an earlier run deleted and all dirty pages written back (sync), untimed; and each child
runs as on a user's machine, with Python's bytecode cache (PYTHONDONTWRITEBYTECODE, which
some sandboxes and CI images set, is removed from the children's environment: with it, every
start of `sisa ortho` compiled SISA's modules again, ~0.15 s here).

Options each tool gets. Both: the creation options above (DEFLATE level 1 for both, not
gdalwarp's default 6); both compress with GDAL's GTiff driver (libdeflate for DEFLATE), ours
and gdalwarp's "threads" mode on every core (NUM_THREADS=ALL_CPUS). gdalwarp runs three
times per codec, and the speed-up is against the fastest run: "plain" (-wm 512 -wo
SKIP_NOSOURCE=YES, one warping thread, GDAL's default block cache of 5 % of RAM),
"threads" (the same plus -multi, -wo NUM_THREADS=ALL_CPUS, -co NUM_THREADS=ALL_CPUS,
--config GDAL_CACHEMAX 1024; on this 2-core machine shared with other work the threaded run
is often the slower), and "plain-512", plain writing 512-cell tiles (the product's layout
before 2026-11-27: gdalwarp warps in chunks of whole tiles and slows down with smaller ones,
so it keeps its own best). Ours is the `sisa ortho` command on gdalwarp's grid (--cell, --bounds),
as a user runs it, with orthorectify()'s defaults (windows made two at a time on threads by
C kernels, the GeoTIFF compressed by GDAL in a background thread with
NUM_THREADS=ALL_CPUS, GDAL_CACHEMAX 128 MB), which also writes the GLT; and once more with
--no-glt, the GeoTIFF alone, the one product gdalwarp makes: each --ours-runs times (default
5, alternating), the run of median wall time compared. Five, because on this VM a run's
kernel time now and then grows threefold or more (0.5 -> 1.6-2.3 s of system time, a third
of the samples then in copying the written GeoTIFF into the page cache), in either mode:
with three runs, two such took the median. The time of orthorectify() itself is read from
the summary line.

The position error of a cell is the distance from its centre to the ground position of the
pixel chosen for it; the exact nearest neighbour comes from a cKDTree over every pixel.
Targets: ours >= 20x faster than gdalwarp in wall time and >= 10x in CPU time (issue 38; 10x
wall before), uncompressed and DEFLATE, mean error <= exact nearest + 5 %, peak RSS
< 1.5 GB for a 10 GB scanner file (--big-gb: raw DN as a sparse file, the IGM written in
full).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
import rasterio
from rasterio.windows import Window

from postproc.products import (
    TIFF_BLOCK,
    IgmWriter,
    OrthoGrid,
    igm_bounds,
    open_igm,
    orthorectify,
    write_geolocation_vrt,
)

F64 = npt.NDArray[np.float64]
EPSG = 32631
BLOCK = 4096
FOV_DEG = 34.2


@dataclass(frozen=True)
class Flight:
    """A strip's pixel-centre ground positions, line block by line block (no state)."""

    lines: int
    pixels: int
    gsd_m: float = 1.0
    along_m: float = 1.0
    heading_deg: float = 8.0
    turn_deg: float = 6.0
    origin_m: tuple[float, float] = (470_000.0, 4_640_000.0)

    def block(self, lo: int, hi: int) -> tuple[F64, F64, F64]:
        line = np.arange(lo, hi, dtype=np.float64)
        h0 = math.radians(self.heading_deg)
        k = math.radians(self.turn_deg) / max(self.lines, 1)
        head = h0 + k * line
        if k:
            east_c = self.origin_m[0] + self.along_m * (math.cos(h0) - np.cos(head)) / k
            north_c = self.origin_m[1] + self.along_m * (np.sin(head) - math.sin(h0)) / k
        else:
            east_c = self.origin_m[0] + self.along_m * line * math.sin(h0)
            north_c = self.origin_m[1] + self.along_m * line * math.cos(h0)
        tau = 2 * np.pi * line
        lateral = 0.8 * np.sin(tau / 173 + 0.3) + 0.4 * np.sin(tau / 61 + 1.1)
        yaw = head + np.radians(0.5 * np.sin(tau / 211) + 0.3 * np.sin(tau / 47 + 2.0))
        surge = 0.3 * np.sin(tau / 89 + 0.7)
        ifov = math.radians(FOV_DEG) / self.pixels
        c = (self.pixels - 1) / 2
        across = self.gsd_m / ifov * np.tan((c - np.arange(self.pixels)) * ifov)  # to the right
        off = across[None, :] + lateral[:, None]
        east = east_c[:, None] + off * np.cos(yaw)[:, None] + (surge * np.sin(head))[:, None]
        north = north_c[:, None] - off * np.sin(yaw)[:, None] + (surge * np.cos(head))[:, None]
        height = 150.0 + 30.0 * np.sin(east / 400.0) * np.cos(north / 700.0)
        return east, north, height


def write_header(path: Path, lines: int, pixels: int, bands: int) -> None:
    wl = np.linspace(430.0, 950.0, bands)
    path.with_suffix(".hdr").write_text(
        "ENVI\ndescription = {ortho_speed synthetic segment}\n"
        f"samples = {pixels}\nlines = {lines}\nbands = {bands}\nheader offset = 0\n"
        "file type = ENVI Standard\ndata type = 12\ninterleave = bil\nbyte order = 0\n"
        "data ignore value = 0\nwavelength units = Nanometers\n"
        "wavelength = {" + ", ".join(f"{w:.2f}" for w in wl) + "}\n", encoding="ascii")


def make_segment(folder: Path, flight: Flight, bands: int, *, sparse_raw: bool) -> Path:
    """Write seg_igm.bil/.hdr and seg.bil/.hdr; returns the image path."""
    raw = folder / "seg.bil"
    rng = np.random.default_rng(7)
    scale = 1.0 + 0.05 * np.arange(bands)[None, :, None]
    with IgmWriter(folder / "seg_igm", flight.lines, flight.pixels, EPSG) as igm, \
            raw.open("wb") as fh:
        for lo in range(0, flight.lines, BLOCK):
            hi = min(lo + BLOCK, flight.lines)
            e, n, h = flight.block(lo, hi)
            igm.write_block(lo, e, n, h)
            if sparse_raw:
                continue
            scene = 1000 + 400 * np.sin(e / 23.0) * np.cos(n / 31.0)
            dn = scene[:, None, :] * scale + rng.normal(0, 20, (hi - lo, bands, flight.pixels))
            dn = np.clip(dn, 1, 65535).astype("<u2")
            dn[:, 0] = (np.arange(lo, hi) + 1)[:, None] % 65536
            dn[:, 1] = np.arange(1, flight.pixels + 1)[None, :]
            dn.tofile(fh)
        if sparse_raw:
            fh.truncate(flight.lines * bands * flight.pixels * 2)
    write_header(raw, flight.lines, flight.pixels, bands)
    return raw


@dataclass(frozen=True)
class Run:
    wall_s: float
    cpu_s: float  # user + system, all threads: less sensitive than wall time to a busy machine
    peak_rss_mb: float
    stdout: str


def measured(cmd: list[str], cwd: Path | None = None, outputs: tuple[Path, ...] = ()) -> Run:
    """`cmd` under a fresh Python that reports the child's wall time and peak RSS
    (RUSAGE_CHILDREN of a process whose only child is `cmd`). Each run starts alike: its
    `outputs` from an earlier run deleted and every dirty page written back (sync), untimed;
    else a run pays for deleting the previous output or for writing back the one before."""
    for path in outputs:
        path.unlink(missing_ok=True)
    os.sync()
    wrapper = [sys.executable, __file__, "--measure", "--", *cmd]
    proc = subprocess.run(wrapper, capture_output=True, text=True, check=False, cwd=cwd,
                          env=CHILD_ENV)
    if proc.returncode != 0:
        raise SystemExit(f"{cmd[0]} failed: {proc.stderr.strip()[-2000:]}")
    got = json.loads(proc.stdout)
    return Run(got["wall_s"], got["cpu_s"], got["peak_rss_mb"], got["stdout"])


def _measure_main(cmd: list[str]) -> None:
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out, err = proc.communicate()
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.stderr.write(err)
        raise SystemExit(proc.returncode)
    use = resource.getrusage(resource.RUSAGE_CHILDREN)
    print(json.dumps({"wall_s": wall, "cpu_s": use.ru_utime + use.ru_stime,
                      "peak_rss_mb": use.ru_maxrss / 1024, "stdout": out}))


def ours_outputs(folder: Path, tag: str) -> tuple[Path, ...]:
    return tuple(folder / f"ours_{tag}{end}" for end in (".tif", "_glt.bil", "_glt.hdr"))


SUMMARY = re.compile(r"(?P<filled>\d+) of (?P<cells>\d+) cells filled.*; ortho "
                     r"(?P<ortho_s>[\d.]+) s")


def ours_cmd(folder: Path, grid: OrthoGrid, tag: str, compress: str, glt: bool = True
             ) -> list[str]:
    """`sisa ortho` as a user runs it, on gdalwarp's grid (its -te and -tr); each repeat
    replaces the last one's products (--force), as gdalwarp's -overwrite."""
    return [sys.executable, "-m", "sisa.cli", "ortho", str(folder / "seg_igm.bil"),
            str(folder / "seg.bil"), "--out", str(folder / f"ours_{tag}.tif"),
            "--cell", repr(grid.cell_m), "--bounds", *(repr(v) for v in grid.bounds_m),
            "--compress", compress, "--force", *([] if glt else ["--no-glt"])]


def ours_summary(run: Run) -> tuple[int, float]:
    """(cells filled, seconds in orthorectify()) from `sisa ortho`'s summary line."""
    got = SUMMARY.search(run.stdout)
    if got is None:
        raise SystemExit(f"sisa ortho: no summary line in {run.stdout!r}")
    return int(got["filled"]), float(got["ortho_s"])


GDAL_BLOCK_BEFORE = 512  # the product's block size until 2026-11-27 (and COG's default)


@dataclass(frozen=True)
class GdalMode:
    threads: bool
    block: int  # GeoTIFF tile side, cells


# gdalwarp is timed writing the product's layout, and (plain) writing 512-cell tiles too: with
# smaller tiles it warps in smaller chunks and slows down (128: 2.8x), so the comparison is
# against whichever of its layouts is faster, never one chosen to slow it down
GDAL_MODES = {"plain": GdalMode(False, TIFF_BLOCK), "threads": GdalMode(True, TIFF_BLOCK),
              f"plain-{GDAL_BLOCK_BEFORE}": GdalMode(False, GDAL_BLOCK_BEFORE)}


def gdal_cmd(folder: Path, grid: OrthoGrid, tag: str, compress: str, mode: str) -> list[str]:
    """gdalwarp writing what orthorectify writes: tiled, band-interleaved, same codec
    (DEFLATE: level 1, horizontal predictor; ZSTD: level 1, horizontal predictor; none:
    sparse), with 512 MB of warp memory and SKIP_NOSOURCE (chunks that no input pixel reaches
    are not warped). Mode "threads" adds every threading option gdalwarp has: -multi (I/O
    and warping overlap), -wo NUM_THREADS=ALL_CPUS (warping), -co NUM_THREADS=ALL_CPUS
    (compression) and a 1 GB block cache (--config GDAL_CACHEMAX 1024); "plain" is one
    thread with GDAL's default cache (5 % of RAM). Each mode has its tile size (GDAL_MODES)."""
    w, s, e, n = grid.bounds_m
    exe = shutil.which("gdalwarp")
    if exe is None:
        raise SystemExit("gdalwarp not found (GDAL command-line tools)")
    if mode not in GDAL_MODES:
        raise SystemExit(f"gdalwarp mode {mode!r}: use one of {', '.join(GDAL_MODES)}")
    block = GDAL_MODES[mode].block
    co = ["TILED=YES", f"BLOCKXSIZE={block}", f"BLOCKYSIZE={block}", "INTERLEAVE=BAND",
          "BIGTIFF=IF_SAFER", f"COMPRESS={compress.upper()}"]
    if compress == "deflate":
        co += ["ZLEVEL=1", "PREDICTOR=2"]
    if compress == "zstd":
        co += ["ZSTD_LEVEL=1", "PREDICTOR=2"]
    if compress == "none":
        co += ["SPARSE_OK=TRUE"]
    multi = ["-multi", "-wo", "NUM_THREADS=ALL_CPUS", "-co", "NUM_THREADS=ALL_CPUS",
             "--config", "GDAL_CACHEMAX", "1024"] if GDAL_MODES[mode].threads else []
    return [exe, "-q", "-overwrite", "-geoloc", "-r", "near", "-t_srs", f"EPSG:{grid.epsg}",
            "-te", *(repr(v) for v in (w, s, e, n)), "-tr", repr(grid.cell_m), repr(grid.cell_m),
            "-wm", "512", "-wo", "SKIP_NOSOURCE=YES", *multi,
            *(x for c in co for x in ("-co", c)),
            str(folder / "seg_geoloc.vrt"), str(folder / f"gdal_{tag}.tif")]


# The children run as on a user's machine, where Python keeps the compiled bytecode of SISA's
# modules (__pycache__): a PYTHONDONTWRITEBYTECODE in this shell (some sandboxes and CI
# images set it) would have every run of `sisa ortho` compile them afresh (~0.15 s here).
CHILD_ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def warm_up(folder: Path) -> None:
    """One untimed run of each tool on a small segment: the C kernels loaded, SISA's
    bytecode compiled and cached, GDAL's and PROJ's files read once."""
    small = folder / "warm"
    small.mkdir()
    make_segment(small, Flight(300, 64), 3, sparse_raw=False)
    grid = OrthoGrid.covering(igm_bounds(small / "seg_igm.bil"), 1.0, EPSG)
    orthorectify(small / "seg_igm.bil", small / "seg.bil", grid, small / "o.tif", small / "g")
    measured(ours_cmd(small, grid, "warm", "none"))
    shutil.rmtree(small)


# -- accuracy --------------------------------------------------------------------------------

def errors(folder: Path, grid: OrthoGrid, tag: str) -> dict[str, float]:
    """Mean position error (m) of gdalwarp, ours and the exact nearest pixel."""
    from scipy.spatial import cKDTree  # only here: keeps the timed child's start-up short

    igm = open_igm(folder / "seg_igm.bil")
    e, n = np.asarray(igm[:, 0]), np.asarray(igm[:, 1])
    tree = cKDTree(np.stack([e.ravel(), n.ravel()], axis=1))
    sums = dict.fromkeys(("gdal", "ours", "nn", "gdal_c", "ours_c", "nn_c"), 0.0)
    counts = dict.fromkeys(("gdal", "ours", "both", "ours_not_gdal", "gdal_not_ours", "same"), 0)
    with rasterio.open(folder / f"gdal_{tag}.tif") as g, \
            rasterio.open(folder / f"ours_{tag}.tif") as o:
        for r0 in range(0, grid.height, 2048):
            win = Window(0, r0, grid.width, min(2048, grid.height - r0))
            gl, gp = g.read(1, window=win).astype(np.int64), g.read(2, window=win).astype(np.int64)
            ol, op = o.read(1, window=win).astype(np.int64), o.read(2, window=win).astype(np.int64)
            rows, cols = np.mgrid[r0:r0 + win.height, 0:grid.width]
            cx, cy = grid.centre_x_m(cols), grid.centre_y_m(rows)
            g_ok, o_ok = (gl > 0) & (gp > 0), (ol > 0) & (op > 0)
            d_g = np.hypot(e[gl[g_ok] - 1, gp[g_ok] - 1] - cx[g_ok],
                           n[gl[g_ok] - 1, gp[g_ok] - 1] - cy[g_ok])
            d_o = np.hypot(e[ol[o_ok] - 1, op[o_ok] - 1] - cx[o_ok],
                           n[ol[o_ok] - 1, op[o_ok] - 1] - cy[o_ok])
            d_nn, k = tree.query(np.stack([cx[o_ok], cy[o_ok]], axis=1), workers=2)
            both = (g_ok & o_ok)[o_ok]
            both_g = (g_ok & o_ok)[g_ok]
            sums["gdal"] += float(d_g.sum())
            sums["ours"] += float(d_o.sum())
            sums["nn"] += float(d_nn.sum())
            sums["gdal_c"] += float(d_g[both_g].sum())
            sums["ours_c"] += float(d_o[both].sum())
            sums["nn_c"] += float(d_nn[both].sum())
            counts["gdal"] += int(g_ok.sum())
            counts["ours"] += int(o_ok.sum())
            counts["both"] += int((g_ok & o_ok).sum())
            counts["ours_not_gdal"] += int((o_ok & ~g_ok).sum())
            counts["gdal_not_ours"] += int((g_ok & ~o_ok).sum())
            counts["same"] += int((k == (ol[o_ok] - 1) * e.shape[1] + op[o_ok] - 1).sum())
    return {
        "gdal_mean_m": sums["gdal"] / max(counts["gdal"], 1),
        "ours_mean_m": sums["ours"] / max(counts["ours"], 1),
        "nn_mean_m": sums["nn"] / max(counts["ours"], 1),
        "gdal_common_m": sums["gdal_c"] / max(counts["both"], 1),
        "ours_common_m": sums["ours_c"] / max(counts["both"], 1),
        "nn_common_m": sums["nn_c"] / max(counts["both"], 1),
        "ours_equal_nn_pct": 100.0 * counts["same"] / max(counts["ours"], 1),
        **{f"cells_{k}": float(v) for k, v in counts.items() if k != "same"},
    }


# -- the runs --------------------------------------------------------------------------------

def median_run(runs: list[Run]) -> Run:
    """The run of median wall time (the lower middle one of an even count)."""
    return sorted(runs, key=lambda r: r.wall_s)[(len(runs) - 1) // 2]


def spread(runs: list[Run]) -> str:
    if len(runs) < 2:
        return ""
    walls = sorted(r.wall_s for r in runs)
    return f"; median of {len(runs)} runs, {walls[0]:.2f}-{walls[-1]:.2f} s"


def main_run(work: Path, lines: int, pixels: int, bands: int, cell_m: float,
             codecs: list[str], gdal_modes: list[str], ours_repeats: int) -> None:
    folder = work / "main"
    folder.mkdir()
    t0 = time.perf_counter()
    make_segment(folder, Flight(lines, pixels), bands, sparse_raw=False)
    write_geolocation_vrt(folder / "seg_geoloc.vrt", folder / "seg.bil",
                          folder / "seg_igm.bil", EPSG)
    grid = OrthoGrid.covering(igm_bounds(folder / "seg_igm.bil"), cell_m, EPSG)
    raw_gb = (folder / "seg.bil").stat().st_size / 1e9
    print(f"segment: {lines} lines x {pixels} px x {bands} bands uint16 ({raw_gb:.2f} GB), "
          f"IGM {(folder / 'seg_igm.bil').stat().st_size / 1e9:.2f} GB, written in "
          f"{time.perf_counter() - t0:.1f} s")
    print(f"grid: {grid.width} x {grid.height} cells of {cell_m} m (EPSG:{EPSG})")
    for mode in gdal_modes:
        shown = gdal_cmd(folder, grid, "deflate", "deflate", mode)
        print(f"gdalwarp ({mode}) "
              f"{' '.join(Path(a).name if '/' in a else a for a in shown[1:])}")
    for compress in codecs:
        # GDAL 3.6 + NUM_THREADS needs the VRT's folder as working directory: see igm.py
        gds = {mode: measured(gdal_cmd(folder, grid, compress, compress, mode), cwd=folder,
                              outputs=(folder / f"gdal_{compress}.tif",))
               for mode in gdal_modes}
        ours_runs: list[Run] = []
        alone_runs: list[Run] = []
        for _ in range(ours_repeats):  # alternating: a slow minute hits both alike
            ours_runs.append(measured(ours_cmd(folder, grid, compress, compress),
                                      outputs=ours_outputs(folder, compress)))
            alone_runs.append(measured(
                ours_cmd(folder, grid, f"{compress}_alone", compress, glt=False),
                outputs=ours_outputs(folder, f"{compress}_alone")))
        us, alone = median_run(ours_runs), median_run(alone_runs)
        _, ortho_s = ours_summary(us)
        _, alone_ortho_s = ours_summary(alone)
        print(f"[{compress} GeoTIFF, tiled {TIFF_BLOCK}]  (load average "
              f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)")
        for mode, gd in gds.items():
            print(f"  gdalwarp ({mode:9s}): {gd.wall_s:7.2f} s wall, {gd.cpu_s:7.2f} s CPU, "
                  f"peak RSS {gd.peak_rss_mb:6.0f} MB")
        print(f"  sisa ortho:          {us.wall_s:7.2f} s wall, {us.cpu_s:7.2f} s CPU, peak RSS "
              f"{us.peak_rss_mb:6.0f} MB (orthorectify() itself {ortho_s:.2f} s wall)"
              f"{spread(ours_runs)}")
        print(f"  ... --no-glt:        {alone.wall_s:7.2f} s wall, {alone.cpu_s:7.2f} s CPU, peak "
              f"RSS {alone.peak_rss_mb:6.0f} MB (orthorectify() itself {alone_ortho_s:.2f} s "
              f"wall): the GeoTIFF alone, as gdalwarp makes{spread(alone_runs)}")
        best = min(gds, key=lambda m: gds[m].wall_s)
        gd = gds[best]
        print(f"  speed-up against the faster gdalwarp ({best}): {gd.wall_s / us.wall_s:.1f}x "
              f"wall, {gd.cpu_s / us.cpu_s:.1f}x CPU (whole processes); "
              f"{gd.wall_s / ortho_s:.1f}x wall against orthorectify() alone; the GeoTIFF "
              f"alone (--no-glt): {gd.wall_s / alone.wall_s:.1f}x wall, "
              f"{gd.cpu_s / alone.cpu_s:.1f}x CPU")
    err = errors(folder, grid, codecs[0])
    print(f"cells filled: gdalwarp {err['cells_gdal']:.0f}, ours {err['cells_ours']:.0f}; "
          f"ours but not gdalwarp {err['cells_ours_not_gdal']:.0f}, "
          f"gdalwarp but not ours {err['cells_gdal_not_ours']:.0f}")
    print("mean position error (cell centre -> chosen pixel centre), each on its own cells: "
          f"gdalwarp {err['gdal_mean_m']:.4f} m, ours {err['ours_mean_m']:.4f} m, "
          f"exact nearest {err['nn_mean_m']:.4f} m")
    print(f"  on the {err['cells_both']:.0f} cells both filled: gdalwarp "
          f"{err['gdal_common_m']:.4f} m, ours {err['ours_common_m']:.4f} m, exact nearest "
          f"{err['nn_common_m']:.4f} m; ours = exact nearest on {err['ours_equal_nn_pct']:.2f} % "
          f"of our cells; ours / exact = {err['ours_mean_m'] / err['nn_mean_m']:.4f}")


def big_run(work: Path, size_gb: float, pixels: int, bands: int, cell_m: float) -> None:
    folder = work / "big"
    folder.mkdir()
    lines = int(size_gb * 1e9 / (bands * pixels * 2))
    t0 = time.perf_counter()
    flight = Flight(lines, pixels, heading_deg=0.0, turn_deg=0.0)
    make_segment(folder, flight, bands, sparse_raw=True)
    grid = OrthoGrid.covering(igm_bounds(folder / "seg_igm.bil"), cell_m, EPSG)
    print(f"\nbig: {lines} lines x {pixels} px x {bands} bands = "
          f"{(folder / 'seg.bil').stat().st_size / 1e9:.2f} GB raw (sparse), IGM "
          f"{(folder / 'seg_igm.bil').stat().st_size / 1e9:.2f} GB, made in "
          f"{time.perf_counter() - t0:.0f} s; grid {grid.width} x {grid.height}")
    us = measured(ours_cmd(folder, grid, "big", "deflate"), outputs=ours_outputs(folder, "big"))
    print(f"sisa ortho: {us.wall_s:8.1f} s wall, {us.cpu_s:.1f} s CPU, peak RSS "
          f"{us.peak_rss_mb:7.0f} MB ({ours_summary(us)[0]} cells filled)")


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--measure":
        _measure_main(sys.argv[3:])
        return
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--lines", type=int, default=20_000)
    ap.add_argument("--pixels", type=int, default=512)
    ap.add_argument("--bands", type=int, default=18)
    ap.add_argument("--cell-m", type=float, default=1.0)
    ap.add_argument("--big-gb", type=float, default=0.0,
                    help="also measure peak RSS on a scanner file of this many GB")
    ap.add_argument("--codecs", default="deflate,none",
                    help="GeoTIFF codecs to time, comma-separated (deflate, zstd, lzw, none); "
                         "positions are checked on the first")
    ap.add_argument("--gdal-modes", default=",".join(GDAL_MODES),
                    help="gdalwarp runs per codec: plain (one thread), threads (-multi, "
                         "NUM_THREADS=ALL_CPUS, GDAL_CACHEMAX 1 GB), both in the product's "
                         f"tiles; plain-{GDAL_BLOCK_BEFORE} (one thread, {GDAL_BLOCK_BEFORE}-cell "
                         "tiles); the speed-up is against the fastest")
    ap.add_argument("--ours-runs", type=int, default=5,
                    help="runs of `sisa ortho` per codec (with and without GLT, alternating); "
                         "the median is compared (gdalwarp takes 10x longer: one run a mode)")
    ap.add_argument("--work", type=Path, default=None, help="scratch folder (default: a temp)")
    ap.add_argument("--keep", action="store_true", help="keep the scratch files")
    args = ap.parse_args()
    if args.work is not None and not args.work.is_dir():
        ap.error(f"--work {args.work}: no such folder")
    work = Path(tempfile.mkdtemp(prefix="ortho_speed_", dir=args.work))
    try:
        warm_up(work)
        main_run(work, args.lines, args.pixels, args.bands, args.cell_m,
                 args.codecs.split(","), args.gdal_modes.split(","), max(args.ours_runs, 1))
        if args.big_gb > 0:
            big_run(work, args.big_gb, args.pixels, args.bands, args.cell_m)
    finally:
        if args.keep:
            print(f"files kept in {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    os.environ.setdefault("PYTHONHASHSEED", "0")
    main()
