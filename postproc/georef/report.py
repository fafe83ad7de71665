"""The processing report: one self-contained HTML file (plots inlined as PNG) that says how a
flight was timed and georeferenced, and — for a simulated run — how accurate it is.

Sections: headline figures; trajectory and footprints map; attitude; sync residuals and clock
drift; ground errors along/across track and in height (every pixel and check points, metres and
pixels); the ortho mosaic quicklook. Accuracy figures are passed in by the caller (only a
simulated run has truth); this module never reads truth itself.
"""

from __future__ import annotations

import base64
import html
import io
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from postproc.georef.exterior import exterior_orientation
from postproc.georef.jobrecords import GeorefResult
from sisa.core.outdir import partial_path
from sisa.core.sensor import Mounting
from sisa.core.timescale import NS_PER_S

if TYPE_CHECKING:
    from matplotlib.figure import Figure

F64 = npt.NDArray[np.float64]
STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }
h1 { font-size: 1.6em; } h2 { border-bottom: 1px solid #ccc; padding-bottom: .2em; }
table { border-collapse: collapse; margin: .5em 0 1em; }
td, th { border: 1px solid #ccc; padding: .25em .6em; text-align: right; }
th { background: #f3f3f3; } td:first-child, th:first-child { text-align: left; }
img { max-width: 100%; } .note { color: #555; font-size: .9em; }
"""


def _subplots(nrows: int, ncols: int, figsize: tuple[float, float], **kw: Any
              ) -> tuple[Figure, Any]:
    """A figure of its own (no pyplot state), matplotlib imported only when a report is drawn:
    georeferencing itself never plots."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols, **kw)


def _png(fig: Figure) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    return f'<img alt="" src="data:image/png;base64,{base64.b64encode(buf.getvalue()).decode()}">'


def _table(header: list[str], rows: list[list[Any]]) -> str:
    def cell(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.4g}" if abs(v) < 1e5 else f"{v:.0f}"
        return html.escape(str(v))

    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{cell(v)}</td>" for v in r) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


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
    ax.set_xlabel("longitude (°)")
    ax.set_ylabel("latitude (°)")
    ax.set_aspect(1.0 / max(np.cos(np.radians(np.nanmean(eo.lat_deg[ok]))), 0.1)
                  if ok.any() else "auto")
    ax.legend(loc="best")
    ax.set_title("trajectory (perspective centre) and segment footprints")
    return _png(fig)


def _attitude(result: GeorefResult, mounting: Mounting) -> str:
    t0, t1 = result.trajectory.span_ns
    t = np.arange(t0, t1, NS_PER_S // 4, dtype=np.int64)
    eo = exterior_orientation(result.trajectory, t, mounting)
    x = (t - t0) / NS_PER_S / 60.0
    fig, axes = _subplots(3, 1, figsize=(9, 6), sharex=True)
    for ax, v, name in zip(axes, (eo.roll_rad, eo.pitch_rad, eo.heading_rad),
                           ("roll", "pitch", "heading"), strict=True):
        ax.plot(x[eo.valid], np.degrees(v[eo.valid]), lw=0.6)
        ax.set_ylabel(f"{name} (°)")
    axes[-1].set_xlabel("minutes since the start of the navigation")
    return _png(fig)


def _sync(result: GeorefResult) -> str:
    sol = result.sync.ins_solution
    fig, (a1, a2) = _subplots(2, 1, figsize=(9, 5.5), sharex=True)
    for r in sol.runs:
        x = sol.latch_x_s[r.latches]
        y = sol.pulse_t_s[r.pulses]
        a1.plot(y / 60.0, (y - r.line(x)) * 1e9, ".", ms=2)
        a2.plot(y / 60.0, (x - y) * 1e3, lw=0.8,
                label=f"piece {r.piece}: {(1.0 / r.line.slope - 1.0) * 1e6:+.2f} ppm")
    a1.set_ylabel("latch residual (ns)")
    a1.set_title("INS clock fits: residual of every matched sync latch")
    a2.set_ylabel("INS clock − GPS (ms)")
    a2.set_xlabel("minutes since the flight epoch")
    if sol.runs:
        a2.legend(loc="best", fontsize=8)
    return _png(fig)


def _errors(acc: dict[str, Any]) -> str:
    sample = np.asarray(acc.get("_sample_px", np.zeros((0, 3))))
    fig, axes = _subplots(1, 4, figsize=(13, 3.4))
    for i, name in enumerate(("along", "across", "height")):
        if sample.size:
            axes[i].hist(sample[:, i], bins=80, color=f"C{i}")
        axes[i].set_xlabel(f"{name} error (px)")
    axes[0].set_ylabel("pixels (sample)")
    cps = acc.get("check_point_list", [])
    if cps:
        e = np.array([c["err_px"] for c in cps])
        axes[3].scatter(e[:, 1], e[:, 0], s=10)
        axes[3].axhline(0, color="0.6", lw=0.5)
        axes[3].axvline(0, color="0.6", lw=0.5)
    axes[3].set_xlabel("check points: across (px)")
    axes[3].set_ylabel("along (px)")
    fig.tight_layout()
    return _png(fig)


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


def _mosaic(out_dir: Path) -> str:
    png = out_dir / "mosaic_quicklook.png"
    if not png.is_file():
        return "<p>no mosaic</p>"
    data = base64.b64encode(png.read_bytes()).decode()
    return f'<img alt="mosaic" src="data:image/png;base64,{data}">'


def write_report(path: Path, result: GeorefResult, out_dir: Path, mounting: Mounting, *,
                 title: str, accuracy: dict[str, Any] | None = None,
                 headline: list[tuple[str, str]] | None = None) -> None:
    """The HTML report; `accuracy` from sisa.wiring.accuracy.run_accuracy for a simulated run."""
    seg_rows = [[s.segment, s.lines, s.lines_timed, s.lines_georeferenced,
                 f"{s.rays_hit / max(s.rays, 1):.2%}", s.gsd_across_m, s.gsd_along_m]
                for s in result.segments]
    sync = result.sync.report
    ins_models = sync["ins"]["clock_models"]
    sync_rows = [[m["piece"], m["latches"], m["records"], m["ins_clock_fast_ppm"],
                  m["residual_rms_ns"], m.get("predicted_record_rms_ns")] for m in ins_models]
    body = [f"<h1>{html.escape(title)}</h1>"]
    if headline:
        body.append(_table(["figure", "value"], [[k, v] for k, v in headline]))
    if result.warnings:  # what was left out and why, where the reader of the report sees it
        body += ["<h2>Warnings</h2>", "<ul>", *(f"<li>{html.escape(w)}</li>"
                                                for w in result.warnings), "</ul>"]
    body += ["<h2>Segments</h2>",
             _table(["segment", "lines", "timed", "georeferenced", "pixels on DEM",
                     "pixel across (m)", "line spacing (m)"], seg_rows),
             "<h2>Recording</h2>", _recording(result),
             "<h2>Trajectory and footprints</h2>", _map(result, out_dir, mounting),
             "<h2>Attitude</h2>", _attitude(result, mounting),
             "<h2>Time synchronisation</h2>",
             _table(["clock piece", "latches", "records", "INS clock fast (ppm)",
                     "residual RMS (ns)", "predicted record RMS (ns)"], sync_rows),
             _sync(result)]
    if accuracy is not None:
        body += ["<h2>Ground accuracy against truth</h2>",
                 '<p class="note">along: direction of flight; across: to its right; height: '
                 "ellipsoidal. Pixels: each segment's median pixel spacing across track "
                 "(along track for the along component).</p>",
                 _accuracy_tables(accuracy), _errors(accuracy)]
    body += ["<h2>Ortho mosaic</h2>", _mosaic(out_dir),
             f'<p class="note">CRS EPSG:{result.epsg}, cell {result.cell_m:g} m. '
             "Generated by sisa.</p>"]
    page = (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
            f"</title><style>{STYLE}</style></head><body>{''.join(body)}</body></html>\n")
    tmp = partial_path(path)
    tmp.write_text(page, encoding="utf-8")
    tmp.replace(path)
