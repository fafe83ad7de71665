"""The processing report: one self-contained HTML file (plots inlined as PNG) that says how a
flight was timed and georeferenced, and — for a simulated run — how accurate it is.

Sections: headline figures; the archive record (when and with what software it was made, the
command, every input file with its size and SHA-256, the flight's and each strip's times, the
sensor file); segments; the recorder's health; trajectory and footprints map; attitude; sync
residuals and clock drift; ground errors along/across track and in height (every pixel and
check points, metres and pixels); the ortho mosaic on its map grid. Every plot against time
shares one axis (minutes since the flight epoch, strips shaded), every axis says its unit, and
each figure carries its axes' labels in its `data-axes` attribute (JSON) and its alt text, so a
test or a screen reader can read them. Accuracy figures are passed in by the caller (only a
simulated run has truth); this module never reads truth itself.
"""

from __future__ import annotations

import base64
import datetime as dt
import html
import io
import json
import math
import os
import platform
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

import numpy as np
import numpy.typing as npt

from postproc.georef.exterior import exterior_orientation
from postproc.georef.jobrecords import GeorefResult
from postproc.georef.navigation import ecef_to_geodetic
from postproc.products import RgbView, read_rgb
from sisa.core.outdir import write_whole
from sisa.core.provenance import FileRecord, file_record, software_label
from sisa.core.sensor import Mounting
from sisa.core.timescale import NS_PER_S, datetime_from_gps_ns, gps_span_label, gps_time_label

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

F64 = npt.NDArray[np.float64]
STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }
h1 { font-size: 1.6em; } h2 { border-bottom: 1px solid #ccc; padding-bottom: .2em; }
table { border-collapse: collapse; margin: .5em 0 1em; }
td, th { border: 1px solid #ccc; padding: .25em .6em; text-align: right; }
th { background: #f3f3f3; } td:first-child, th:first-child { text-align: left; }
img { max-width: 100%; } figure { margin: 1em 0; } .note { color: #555; font-size: .9em; }
dl.archive { display: grid; grid-template-columns: max-content 1fr; gap: .2em 1em; }
dl.archive dt { font-weight: 600; } dl.archive dd { margin: 0; }
code, .hash { font-family: ui-monospace, monospace; font-size: .85em; word-break: break-all; }
pre { background: #f6f6f6; padding: .6em; overflow-x: auto; font-size: .85em; }
"""
DPI: Final = 90
MOSAIC_MAX_PX: Final = 2048  # the overview's longest side, read decimated from mosaic.tif
DETAIL_CELLS: Final = 400  # the detail panel: this many cells square at full resolution
STRIP_COLOURS: Final = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b")


@dataclass(frozen=True)
class Provenance:
    """What the archive record says beyond the result: the command as typed, where it ran, the
    files it read (shown relative to `root`), and the sensor file used and where it came from."""

    command: str
    working_dir: str
    inputs: list[Path] = field(default_factory=list)
    root: Path | None = None
    sensor_source: str = ""


@dataclass(frozen=True)
class TimeAxis:
    """The one time axis of every plot: minutes since the flight epoch (GPS), to the end of
    the navigation or the last sync pulse, whichever is later."""

    t0_ns: int
    t1_ns: int

    @classmethod
    def of(cls, result: GeorefResult) -> TimeAxis:
        t0 = int(result.sync.report["flight_epoch_gps_ns"])
        pulses = result.sync.ins_solution.pulse_t_s
        last = t0 + round(float(pulses.max()) * NS_PER_S) if pulses.size else t0
        return cls(t0, max(int(result.trajectory.span_ns[1]), last))

    def limit(self, ax: Axes) -> None:
        ax.set_xlim(0.0, float(self.minutes(self.t1_ns)))

    @property
    def label(self) -> str:
        when = datetime_from_gps_ns(self.t0_ns).strftime("%Y-%m-%d %H:%M:%S")
        return f"time since {when} GPS (min)"

    def minutes(self, t_ns: npt.ArrayLike) -> F64:
        t = np.asarray(t_ns, dtype=np.int64)
        return np.asarray((t - self.t0_ns) / (60.0 * NS_PER_S), dtype=np.float64)


def _subplots(nrows: int, ncols: int, figsize: tuple[float, float], **kw: Any
              ) -> tuple[Figure, Any]:
    """A figure of its own (no pyplot state), matplotlib imported only when a report is drawn:
    georeferencing itself never plots."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols, **kw)


def axes_labels(fig: Figure) -> list[dict[str, str]]:
    """Title, x and y label of every axes of a figure; an axes sharing x with one below it (its
    tick labels hidden) takes the label of the one that shows it."""
    out = []
    for ax in fig.axes:
        xlabel = ax.get_xlabel()
        if not xlabel:
            xlabel = next((s.get_xlabel() for s in ax.get_shared_x_axes().get_siblings(ax)
                           if s.get_xlabel()), "")
        out.append({"title": ax.get_title(), "x": xlabel, "y": ax.get_ylabel()})
    return out


def _png(fig: Figure, what: str) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, bbox_inches="tight")
    labels = axes_labels(fig)
    alt = what + ". " + "; ".join(
        f"{a['title'] + ': ' if a['title'] else ''}{a['y']} against {a['x']}" for a in labels)
    data = base64.b64encode(buf.getvalue()).decode()
    return (f'<figure><img alt="{html.escape(alt)}" '
            f"data-axes='{html.escape(json.dumps(labels, ensure_ascii=False))}' "
            f'src="data:image/png;base64,{data}"></figure>')


def _table(header: list[str], rows: list[list[Any]]) -> str:
    def cell(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.4g}" if abs(v) < 1e5 else f"{v:.0f}"
        return html.escape(str(v))

    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{cell(v)}</td>" for v in r) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _shade_strips(ax: Axes, result: GeorefResult, axis: TimeAxis, *, label: bool = False
                  ) -> None:
    """Each segment's time span, shaded and (on the top axes) numbered."""
    for k, s in enumerate(result.segments):
        if s.t_first_gps_ns < 0 or s.t_last_gps_ns < 0:
            continue
        a, b = axis.minutes([s.t_first_gps_ns, s.t_last_gps_ns])
        ax.axvspan(a, b, color=STRIP_COLOURS[k % len(STRIP_COLOURS)], alpha=0.08, lw=0)
        if label:
            ax.annotate(f"strip {s.segment}", ((a + b) / 2, 1.0),
                        xycoords=("data", "axes fraction"), ha="center", va="bottom",
                        fontsize=8, color="0.35")


def _map(result: GeorefResult, out_dir: Path, mounting: Mounting) -> str:
    t0, t1 = result.trajectory.span_ns
    t = np.arange(t0, t1, NS_PER_S, dtype=np.int64)
    eo = exterior_orientation(result.trajectory, t, mounting)
    fig, ax = _subplots(1, 1, figsize=(8, 7))
    ok = eo.valid
    ax.plot(eo.lon_deg[ok], eo.lat_deg[ok], lw=0.8, color="0.3", label="trajectory")
    fp = out_dir / "footprints.geojson"
    if fp.is_file():
        for feat in json.loads(fp.read_text(encoding="utf-8"))["features"]:
            ring = np.asarray(feat["geometry"]["coordinates"][0])
            ax.fill(ring[:, 0], ring[:, 1], alpha=0.25)
            ax.plot(ring[:, 0], ring[:, 1], lw=0.8)
            c = ring.mean(axis=0)
            ax.annotate(str(feat["properties"].get("segment", "")), c, ha="center")
    ax.set_xlabel("longitude (° east, WGS 84)")
    ax.set_ylabel("latitude (° north, WGS 84)")
    ax.set_aspect(1.0 / max(np.cos(np.radians(np.nanmean(eo.lat_deg[ok]))), 0.1)
                  if ok.any() else "auto")
    ax.legend(loc="best")
    ax.set_title("trajectory (perspective centre) and segment footprints")
    return _png(fig, "Map of the trajectory and the segments' footprints")


def heading_pm180(heading_rad: F64) -> tuple[F64, npt.NDArray[np.intp]]:
    """Heading in degrees within (−180, 180], NaN between two samples that wrap across ±180
    so that a plot draws no vertical line there (a 0–360 axis made a sawtooth of every
    north-bound strip, ±180 would of every south-bound one); and where the NaNs went in."""
    deg = np.degrees(np.asarray(heading_rad, dtype=np.float64))
    wrapped = -(np.mod(-deg + 180.0, 360.0) - 180.0)
    out = wrapped.copy()
    jump = np.flatnonzero(np.abs(np.diff(wrapped)) > 180.0)
    return np.asarray(np.insert(out, jump + 1, np.nan), dtype=np.float64), jump + 1


def _attitude(result: GeorefResult, mounting: Mounting, axis: TimeAxis) -> str:
    t0, t1 = result.trajectory.span_ns
    t = np.arange(t0, t1, NS_PER_S // 4, dtype=np.int64)
    eo = exterior_orientation(result.trajectory, t, mounting)
    x = axis.minutes(t)
    fig, axes = _subplots(3, 1, figsize=(9, 6.5), sharex=True)
    v = eo.valid
    for ax, values, name in zip(axes[:2], (eo.roll_rad, eo.pitch_rad), ("roll", "pitch"),
                                strict=True):
        ax.plot(x[v], np.degrees(values[v]), lw=0.6)
        ax.set_ylabel(f"{name} (°)")
    heading, at = heading_pm180(eo.heading_rad[v])
    axes[2].plot(np.insert(x[v], at, np.nan), heading, lw=0.6)
    axes[2].set_ylim(-185, 185)
    axes[2].set_yticks([-180, -90, 0, 90, 180])
    axes[2].set_ylabel("true heading (°, ±180)")
    axes[2].set_xlabel(axis.label)
    for k, ax in enumerate(axes):
        _shade_strips(ax, result, axis, label=k == 0)
        axis.limit(ax)
    return _png(fig, "Roll, pitch and true heading of the INS over the flight")


def _latch_rows(result: GeorefResult) -> tuple[list[list[Any]], float]:
    """The clock-fit table's rows and the clock resolution (ns)."""
    sol = result.sync.ins_solution
    res_ns = float(result.sync.report["ins"].get("clock_resolution_ns") or math.nan)
    rows = []
    for m in result.sync.report["ins"]["clock_models"]:
        by_mode: dict[int, list[float]] = {1: [], 2: []}
        for r in sol.runs:
            if r.piece != m["piece"]:
                continue
            resid = (sol.pulse_t_s[r.pulses] - r.line(sol.latch_x_s[r.latches])) * 1e9
            for mode in by_mode:
                by_mode[mode] += resid[sol.pulse_mode[r.pulses] == mode].tolist()
        rms = [float(np.sqrt(np.mean(np.square(v)))) if v else math.nan
               for v in by_mode.values()]
        rows.append([m["piece"], m["latches"], m["records"], m["ins_clock_fast_ppm"],
                     m["residual_rms_ns"], rms[0], rms[1], m.get("predicted_record_rms_ns")])
    return rows, res_ns


def _sync(result: GeorefResult, axis: TimeAxis, res_ns: float) -> str:
    sol = result.sync.ins_solution
    epoch_ns = int(result.sync.report["flight_epoch_gps_ns"])
    fig, (a1, a2) = _subplots(2, 1, figsize=(9, 6), sharex=True)
    shown = set()
    for r in sol.runs:
        x = sol.latch_x_s[r.latches]
        y = sol.pulse_t_s[r.pulses]
        minutes = axis.minutes(epoch_ns + np.round(y * NS_PER_S).astype(np.int64))
        resid = (y - r.line(x)) * 1e9
        mode = sol.pulse_mode[r.pulses]
        for m, colour, name in ((1, "C0", "gated PPS (mode 1)"), (2, "C1", "frame pulse (mode 2)")):
            sel = mode == m
            if sel.any():
                a1.plot(minutes[sel], resid[sel], ".", ms=2.5, color=colour,
                        label=None if m in shown else name)
                shown.add(m)
        a2.plot(minutes, (x - y) * 1e3, lw=0.8,
                label=f"piece {r.piece}: {(1.0 / r.line.slope - 1.0) * 1e6:+.2f} ppm")
    if math.isfinite(res_ns):
        for s in (-0.5, 0.5):
            a1.axhline(s * res_ns, color="0.5", lw=0.6, ls="--")
    a1.set_ylabel("latch residual (ns)")
    a1.set_title("INS clock fits: residual of every matched sync latch (dashed: ± half the "
                 "clock's resolution)")
    a2.set_ylabel("INS clock − GPS (ms)")
    a2.set_xlabel(axis.label)
    if shown:
        a1.legend(loc="upper right", fontsize=8, markerscale=3)
    if sol.runs:
        a2.legend(loc="best", fontsize=8)
    for k, ax in enumerate((a1, a2)):
        _shade_strips(ax, result, axis, label=k == 0)
        axis.limit(ax)
    return _png(fig, "INS clock fit residuals of the sync latches, and the INS clock against "
                "GPS time")


def _sync_note(res_ns: float) -> str:
    res = f"{res_ns:g} ns" if math.isfinite(res_ns) else "its resolution"
    return (
        '<p class="note">Why the latch residuals are hundreds of ns while a record\'s time is '
        f"good to tens: the INS latches a sync pulse by reading its own clock, truncated to "
        f"{res} (centred by adding half a step). One latch is therefore uncertain by a whole "
        f"step: uniformly spread over ±{res_ns / 2:g} ns (RMS {res_ns / math.sqrt(12):.0f} ns) "
        "for a pulse at a random phase of the clock's ticks, as the frame pulses are; and "
        f"exactly ±{res_ns / 2:g} ns for a pulse locked to a tick, as the gated PPS of the "
        "emulated INS is (its clock starts on a whole second with a whole-µs drift, so a PPS "
        "lands on a tick and is truncated by 0 or one step): the two bands. A clock fit "
        "averages hundreds of latches, so the time it gives each INS record is far better: the "
        "predicted record RMS in the table (docs/sync.md, \"Accuracy\").</p>")


def _errors(acc: dict[str, Any]) -> str:
    sample = np.asarray(acc.get("_sample_px", np.zeros((0, 3))))
    fig, axes = _subplots(1, 4, figsize=(13, 3.4))
    for i, name in enumerate(("along", "across", "height")):
        if sample.size:
            axes[i].hist(sample[:, i], bins=80, color=f"C{i}")
        axes[i].set_xlabel(f"{name} error (px)")
        axes[i].set_ylabel("pixels of the sample (count)")
    cps = acc.get("check_point_list", [])
    if cps:
        e = np.array([c["err_px"] for c in cps])
        axes[3].scatter(e[:, 1], e[:, 0], s=10)
        axes[3].axhline(0, color="0.6", lw=0.5)
        axes[3].axvline(0, color="0.6", lw=0.5)
    axes[3].set_xlabel("check points: across error (px)")
    axes[3].set_ylabel("along error (px)")
    fig.tight_layout()
    return _png(fig, "Ground errors against truth: histograms of a sample of pixels, and the "
                "check points")


def _accuracy_tables(acc: dict[str, Any]) -> str:
    parts = []
    for title, key in (("every pixel vs truth", "pixels"), ("check points", "check_points")):
        s = acc.get(key, {})
        if not s or "along" not in s:
            parts.append(f"<p>{title}: none</p>")
            continue
        count = s.get("pixels", s.get("points"))
        rows = [[c, s[c]["rms_m"], s[c]["rms_px"], s[c].get("mean_m", float("nan")),
                 s[c].get("max_abs_px", float("nan"))] for c in ("along", "across", "height")]
        parts.append(f"<h3>{title} ({count})</h3>"
                     + _table(["component", "RMS (m)", "RMS (px)", "mean (m)", "max |px|"],
                              rows))
    return "".join(parts)


def _recording(result: GeorefResult) -> str:
    """The recorder's own counts over the flight (`sisa log info`), a verdict first."""
    from recorder.health import COUNTERS, HEADINGS

    health = result.recording_health
    if health is None or not health.streams:
        return "<p>the log holds no health reports of its recorder</p>"
    said = health.verdict()
    rows = [[t.stream, t.messages, *(t.counts[c] for c in COUNTERS)] for t in health.ordered()]
    return (f"<p>The recorder counted: {html.escape(said)}.</p>"
            + _table(["stream", "messages", *HEADINGS], rows))


def _scale_bar(ax: Axes, span_m: float) -> None:
    """A bar of a round length (about a fifth of the view) in the lower left, labelled."""
    target = span_m / 5.0
    step = 10 ** math.floor(math.log10(target)) if target > 0 else 1.0
    length = max((m * step for m in (1, 2, 5) if m * step <= target), default=step)
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    left, bottom = x0 + 0.06 * (x1 - x0), y0 + 0.05 * (y1 - y0)
    km = length / 1000.0  # axes are in km
    ax.plot([left, left + km], [bottom, bottom], color="black", lw=4, solid_capstyle="butt")
    ax.plot([left, left + km], [bottom, bottom], color="white", lw=1.5, solid_capstyle="butt")
    text = f"{length / 1000:g} km" if length >= 1000 else f"{length:g} m"
    ax.annotate(text, (left + km / 2, bottom), xytext=(0, 6), textcoords="offset points",
                ha="center", va="bottom", fontsize=9, fontweight="bold",
                bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.8})


def _band_legend(view: Any) -> str:
    names = ("red", "green", "blue")
    parts = []
    for colour, band, wl, desc in zip(names, view.bands, view.wavelengths_nm, view.descriptions,
                                      strict=True):
        said = desc if desc and (wl is None or "nm" in desc) else (
            f"band {band}" + (f" ({wl:g} nm)" if wl is not None else ""))
        parts.append(f"{colour}: {said}")
    return "; ".join(parts) + "; each stretched over 2–98 % of its valid values"


def mosaic_overview(tif: Path) -> RgbView | None:
    """The whole of a mosaic, read decimated for its figure; None without one."""
    return read_rgb(tif, max_size_px=MOSAIC_MAX_PX) if tif.is_file() else None


def mosaic_figure(tif: Path, cell: float, what: str, *,
                  overview: RgbView | None = None) -> str:
    """A mosaic on its map grid: the whole of it, and a full-resolution detail of its centre,
    with coordinates, a scale bar and which band is shown in which colour; `overview`:
    `mosaic_overview(tif)`, read before."""
    if not tif.is_file():
        return "<p>no mosaic</p>"
    if overview is None:
        overview = read_rgb(tif, max_size_px=MOSAIC_MAX_PX)
    if overview.bounds is None:
        return "<p>the mosaic has no map grid</p>"
    w, s, e, n = overview.bounds
    full_rows, full_cols = round((n - s) / cell), round((e - w) / cell)
    half = min(DETAIL_CELLS, full_rows, full_cols) / 2 * cell
    ce, cn = _densest_centre(overview, (w, s, e, n))
    dw, ds_, de, dn = ce - half, cn - half, ce + half, cn + half
    detail = read_rgb(tif, max_size_px=2 * DETAIL_CELLS, bounds=(dw, ds_, de, dn))
    fig, (a1, a2) = _subplots(1, 2, figsize=(12, 10), width_ratios=(1, 1.6))
    km = 1000.0
    a1.imshow(np.moveaxis(overview.rgba, 0, -1), extent=(w / km, e / km, s / km, n / km),
              interpolation="antialiased")
    a1.add_patch(_rectangle(dw / km, ds_ / km, (de - dw) / km, (dn - ds_) / km))
    a2.imshow(np.moveaxis(detail.rgba, 0, -1), extent=(dw / km, de / km, ds_ / km, dn / km),
              interpolation="nearest")
    crs = f"EPSG:{overview.epsg}" if overview.epsg else "its CRS"
    for ax, title in ((a1, "whole mosaic (box: the detail)"),
                      (a2, f"detail at full resolution ({cell:g} m cells)")):
        ax.set_xlabel(f"easting, {crs} (km)")
        ax.set_ylabel(f"northing, {crs} (km)")
        ax.set_title(title)
        ax.ticklabel_format(useOffset=False, style="plain")
        x0, x1 = ax.get_xlim()
        _scale_bar(ax, (x1 - x0) * km)
    legend = _band_legend(overview)
    return (_png(fig, f"{what} on its map grid ({crs}, {cell:g} m cells): the whole "
                      f"mosaic and a detail; {legend}")
            + f'<p class="note">Colours — {html.escape(legend)}. Nodata is white.</p>')


def _rectangle(x: float, y: float, width: float, height: float) -> Any:
    from matplotlib.patches import Rectangle

    return Rectangle((x, y), width, height, fill=False, ec="red", lw=1.2)


def _densest_centre(view: Any, bounds: tuple[float, float, float, float]) -> tuple[float, float]:
    """The map position of the valid cell nearest the centroid of the valid cells."""
    valid = view.rgba[3] > 0
    w, s, e, n = bounds
    rows, cols = valid.shape
    if not valid.any():
        return (w + e) / 2, (s + n) / 2
    r, c = np.nonzero(valid)
    k = int(np.argmin((r - r.mean()) ** 2 + (c - c.mean()) ** 2))
    return w + (c[k] + 0.5) / cols * (e - w), n - (r[k] + 0.5) / rows * (n - s)


def _versions() -> str:
    """The libraries the products depend on, with their versions."""
    import matplotlib
    import pyproj
    import rasterio

    return (f"Python {platform.python_version()}, numpy {np.__version__}, GDAL "
            f"{rasterio.__gdal_version__} (rasterio {rasterio.__version__}), PROJ "
            f"{pyproj.proj_version_str} (pyproj {pyproj.__version__}), matplotlib "
            f"{matplotlib.__version__}")


def _strip_rows(result: GeorefResult) -> list[list[Any]]:
    rows: list[list[Any]] = []
    for s in result.segments:
        ok = s.t_first_gps_ns >= 0 and s.t_last_gps_ns >= 0
        rows.append([s.segment, s.lines,
                     gps_time_label(s.t_first_gps_ns) if ok else "untimed",
                     gps_time_label(s.t_last_gps_ns) if ok else "untimed",
                     (s.t_last_gps_ns - s.t_first_gps_ns) / NS_PER_S if ok else math.nan])
    for skip in result.skipped:
        if skip.whole_segment:
            rows.append([skip.segment, skip.lines, f"not georeferenced: {skip.reason}", "", ""])
    return rows


def input_records(prov: Provenance) -> list[FileRecord]:
    """Size and SHA-256 of each input file the provenance names (those that are files)."""
    return [file_record(p, prov.root) for p in prov.inputs if Path(p).is_file()]


def _archive(result: GeorefResult, prov: Provenance, files: list[FileRecord], sensor_toml: str,
             axis: TimeAxis, sensor_name: str) -> str:
    """The archive record: what a report kept with its data must say about how it was made;
    `files`: `input_records(prov)`."""
    made = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")
    t0, t1 = result.trajectory.span_ns
    file_rows = "".join(f"<tr><td><code>{html.escape(f.shown)}</code></td><td>{f.size_bytes}</td>"
                        f'<td class="hash">{f.sha256}</td></tr>' for f in files)
    summary = result.summary
    items = [
        ("made", made),
        ("software", f"{software_label()}; {_versions()}"),
        ("command", f"<code>{html.escape(prov.command)}</code> in "
                    f"<code>{html.escape(prov.working_dir)}</code>"),
        ("flight (navigation)", f"{gps_span_label(t0, t1)}, {(t1 - t0) / NS_PER_S / 60:.1f} min"),
        ("time axis of the plots", f"minutes since the flight epoch, "
                                   f"{gps_time_label(axis.t0_ns)} (the log's first whole GPS "
                                   "second)"),
        ("products", f"EPSG:{result.epsg}, heights {summary.get('vertical', 'ellipsoidal')}, "
                     f"ortho cell {result.cell_m:g} m"),
        ("sensor file", html.escape(f"{sensor_name}" + (f" — {prov.sensor_source}"
                                                        if prov.sensor_source else ""))),
    ]
    dl = "".join(f"<dt>{html.escape(k)}</dt><dd>{v}</dd>" for k, v in items)
    return (f'<section id="archive"><h2>Archive record</h2><dl class="archive">{dl}</dl>'
            "<h3>Strips</h3>"
            + _table(["segment", "lines", "first line (GPS)", "last line (GPS)", "duration (s)"],
                     _strip_rows(result))
            + "<h3>Input files</h3><table><tr><th>file</th><th>bytes</th><th>SHA-256</th></tr>"
            + file_rows + "</table>"
            + "<details><summary>the sensor file used (TOML)</summary><pre>"
            + html.escape(sensor_toml) + "</pre></details></section>")


def _photo_map(result: GeorefResult, photos_dir: Path) -> str:
    """The photos' footprints over the trajectory, numbered."""
    fp = photos_dir / "footprints.geojson"
    if not fp.is_file():
        return "<p>no photo footprints</p>"
    t0, t1 = result.trajectory.span_ns
    pose = result.trajectory.pose_at(np.arange(t0, t1, NS_PER_S, dtype=np.int64))
    fig, ax = _subplots(1, 1, figsize=(8, 7))
    lat, lon, _ = ecef_to_geodetic(pose.ins_ecef_m[pose.valid])
    ax.plot(lon, lat, lw=0.8, color="0.3", label="trajectory (INS centre)")
    for feat in json.loads(fp.read_text(encoding="utf-8"))["features"]:
        ring = np.asarray(feat["geometry"]["coordinates"][0])
        ax.plot(ring[:, 0], ring[:, 1], lw=0.6, color="tab:blue", alpha=0.7)
    ax.set_xlabel("longitude (° east, WGS 84)")
    ax.set_ylabel("latitude (° north, WGS 84)")
    if lat.size:
        ax.set_aspect(1.0 / max(float(np.cos(np.radians(np.mean(lat)))), 0.1))
    ax.legend(loc="best")
    ax.set_title("the frame camera's photo footprints (image corners on the DEM)")
    return _png(fig, "Map of the trajectory and the photos' footprints")


def _photos(result: GeorefResult, photos_dir: Path, summary: dict[str, Any]) -> str:
    """The frame camera: how many photos, timed, posed, with a footprint and an ortho; the
    EO's stated σ and, for a simulated run, its error against truth; the footprints and the
    photos' mosaic."""
    sig = summary.get("sigma", {})
    rows = [["photos", summary["photos"]], ["timed", summary["timed"]],
            ["with a navigation pose", summary["posed"]],
            ["footprints", summary["footprints"]], ["orthophotos", summary["orthos"]],
            ["ortho cell (m)", summary["cell_m"] if summary["cell_m"] else "-"],
            ["EO σ stated: horizontal / vertical (m), attitude (°)",
             f"{sig.get('horizontal_m', '-')} / {sig.get('vertical_m', '-')}, "
             f"{sig.get('attitude_deg', '-')}"]]
    acc = summary.get("accuracy")
    if acc and acc.get("photos"):
        pos, att = acc["position_rms_m"], acc["attitude_rms_arcsec"]
        rows += [["EO error against truth, perspective centre RMS horizontal / vertical (m)",
                  f"{pos['horizontal']:.3f} / {pos['vertical']:.3f}"],
                 ["EO error against truth, attitude RMS roll / pitch / heading (″)",
                  f"{att['roll']:.1f} / {att['pitch']:.1f} / {att['heading']:.1f}"]]
    parts = [_table(["frame camera", "value"], rows)]
    if summary.get("warnings"):
        parts += ["<ul>", *(f"<li>{html.escape(w)}</li>" for w in summary["warnings"]),
                  "</ul>"]
    parts.append(_photo_map(result, photos_dir))
    if summary.get("mosaic"):
        parts.append(mosaic_figure(photos_dir / summary["mosaic"], float(summary["cell_m"]),
                                   "Photo mosaic"))
    return "".join(parts)


def write_report(path: Path, result: GeorefResult, out_dir: Path, mounting: Mounting, *,
                 title: str, accuracy: dict[str, Any] | None = None,
                 headline: list[tuple[str, str]] | None = None,
                 provenance: Provenance | None = None, sensor_toml: str = "",
                 sensor_name: str = "", photos: dict[str, Any] | None = None) -> None:
    """The HTML report; `accuracy` from sisa.wiring.accuracy.RunAccuracy for a simulated run;
    `provenance` (and the sensor file's TOML and name) for the archive record; `photos`: the
    frame camera's summary (postproc.georef.photo_products), its products in out_dir/photos."""
    axis = TimeAxis.of(result)
    body = [f"<h1>{html.escape(title)}</h1>"]
    if headline:
        body.append(_table(["figure", "value"], [[k, v] for k, v in headline]))
    if result.warnings:  # what was left out and why, where the reader of the report sees it
        body += ["<h2>Warnings</h2>", "<ul>", *(f"<li>{html.escape(w)}</li>"
                                                for w in result.warnings), "</ul>"]
    prov = provenance or Provenance(command="", working_dir=os.getcwd())
    # the input files' hashes and the mosaic's overview read on threads (hashlib and GDAL
    # release the GIL) while the figures are drawn: the report was one core's work alone
    with ThreadPoolExecutor(2, thread_name_prefix="sisa-report") as pool:
        hashed = pool.submit(input_records, prov)
        overview = pool.submit(mosaic_overview, out_dir / "mosaic.tif")
        rest = _sections(result, out_dir, mounting, axis, accuracy, overview, photos)
        archive = _archive(result, prov, hashed.result(), sensor_toml, axis, sensor_name)
    body += [archive, *rest]
    page = (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
            f"</title><style>{STYLE}</style></head><body>{''.join(body)}</body></html>\n")
    write_whole(path, page)


def _sections(result: GeorefResult, out_dir: Path, mounting: Mounting, axis: TimeAxis,
              accuracy: dict[str, Any] | None, overview: Future[RgbView | None],
              photos: dict[str, Any] | None) -> list[str]:
    """The report's body after its archive record, in order."""
    seg_rows = [[s.segment, s.lines, s.lines_timed, s.lines_georeferenced,
                 f"{s.rays_hit / max(s.rays, 1):.2%}", s.gsd_across_m, s.gsd_along_m]
                for s in result.segments]
    latch_rows, res_ns = _latch_rows(result)
    body = ["<h2>Segments</h2>",
            _table(["segment", "lines", "timed", "georeferenced", "pixels on DEM",
                     "pixel across (m)", "line spacing (m)"], seg_rows),
             "<h2>Recording</h2>", _recording(result),
             "<h2>Trajectory and footprints</h2>", _map(result, out_dir, mounting),
             "<h2>Attitude</h2>", _attitude(result, mounting, axis),
             "<h2>Time synchronisation</h2>",
             _table(["clock piece", "latches", "records", "INS clock fast (ppm)",
                     "latch residual RMS (ns)", "of gated PPS (ns)", "of frame pulses (ns)",
                     "predicted error of a record's time, RMS (ns)"], latch_rows),
             _sync(result, axis, res_ns), _sync_note(res_ns)]
    if accuracy is not None:
        body += ["<h2>Ground accuracy against truth</h2>",
                 '<p class="note">along: direction of flight; across: to its right; height: '
                 "ellipsoidal. Pixels: each segment's median pixel spacing across track "
                 "(along track for the along component).</p>",
                 _accuracy_tables(accuracy), _errors(accuracy)]
    body += ["<h2>Ortho mosaic</h2>",
             mosaic_figure(out_dir / "mosaic.tif", result.cell_m, "Ortho mosaic",
                           overview=overview.result()),
             f'<p class="note">CRS EPSG:{result.epsg}, cell {result.cell_m:g} m. '
             "Generated by sisa.</p>"]
    if photos is not None:
        body += ["<h2>Frame camera</h2>", _photos(result, out_dir / "photos", photos)]
    return body
