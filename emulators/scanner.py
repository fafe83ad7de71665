"""The pushbroom scanner emulator (CASI-501 class): its frame clock, its wire outputs and its own
recording.

What it does, and why:
- It records one segment per strip window of the trajectory, as an operator switches the CASI
  on over each strip. Frames come from the scanner's own free-running line clock (not GPS):
  period line_period_ms·(1 + drift), white jitter on every mid-exposure time. Post-processing
  must find this clock from the pulses, so it is never aligned to anything.
- Per frame it sends a PPF edge at mid-exposure, and, once the frame is read out (after the
  second half of the integration and 1–3 ms of readout latency), a frame header on RS-232
  (acquisition.scanner_header). The frame counter runs on across segments and wraps.
- A dropped frame (fault `dropped_frame_fraction`) is exposed, so its PPF goes out and its
  counter value is used, but it is not recorded: no header and no image line.
- The recording (with `out_dir`) is what the CASI itself writes: per segment an ENVI BIL of
  uint16 DN, its .hdr, and a CSV of the frame counter of every recorded line, which is the only
  link between an image line and the pulse that timed it. It is written block by block (a
  block's exposed lines in one append, its header rewritten once), so memory does not depend
  on the segment length and the files are not rewritten per line. Lines are rendered by
  emulators.render from the TRUE pose at the frame's true mid-exposure time.
- Truth (table `frames`, and `faults` for dropped frames) stays beside the run: the recording
  holds nothing a real scanner would not know.
"""

from __future__ import annotations

import contextlib
import errno
import heapq
import math
import os
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt

from acquisition.pulses import Edge, PulseLine
from acquisition.scanner_header import FrameHeader, ScannerMode, encode_header
from emulators.render import LineRenderer, raw_dn_envi_header, render_on_one_thread
from emulators.runtime import Device, Output, Port
from emulators.scenario import Scenario
from emulators.terrain import WAVELENGTH_RANGE_NM, Scene, Terrain, band_centres_nm
from emulators.trajectory import TruthTrajectory
from emulators.truth import TruthTable
from sisa.core.errors import RecorderError
from sisa.core.outdir import write_whole

I64 = npt.NDArray[np.int64]
U16 = npt.NDArray[np.uint16]

JITTER_CLIP_SIGMA: Final = 8.0  # jitter is clipped here, so frame times have a hard bound
DEFAULT_BLOCK_LINES: Final = 128  # frames scheduled (and lines rendered) at a time


def frame_table() -> TruthTable:
    return TruthTable("frames", {
        "segment": "recording segment (0-based, one per strip window)",
        "line_index": "line of the segment's BIL file, -1 if the frame was dropped",
        "frame_counter": "the scanner's frame counter (wraps at 2^frame_counter_bits)",
        "t_mid_gps_ns": "true mid-exposure time (GPS ns): the PPF edge time",
        "dropped": "1 if the frame was exposed but not recorded, else 0",
    }, "every frame the scanner exposed, in order")


# ---------------------------------------------------------------------------------------------
# The line clock
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LineClock:
    """The scanner's free-running frame oscillator: tick k is at t0 + k·period (GPS ns)."""

    t0_ns: int
    period_ns: float

    def time_of(self, tick: npt.ArrayLike) -> I64:
        k = np.asarray(tick, dtype=np.int64)
        return np.asarray(self.t0_ns + np.rint(k * self.period_ns).astype(np.int64))

    def first_tick_at_or_after(self, t_ns: int) -> int:
        k = math.ceil((t_ns - self.t0_ns) / self.period_ns)
        while int(self.time_of(k)) < t_ns:
            k += 1
        while k > 0 and int(self.time_of(k - 1)) >= t_ns:
            k -= 1
        return k

    def last_tick_at_or_before(self, t_ns: int) -> int:
        return self.first_tick_at_or_after(t_ns + 1) - 1


@dataclass(frozen=True)
class _Segment:
    number: int
    first_tick: int
    last_tick: int  # inclusive; last < first for a window shorter than a period


def _plan_segments(clock: LineClock, traj: TruthTrajectory) -> list[_Segment]:
    """One recording segment per strip window: the clock ticks that fall inside it."""
    return [_Segment(i, clock.first_tick_at_or_after(s.t_start_ns),
                     clock.last_tick_at_or_before(s.t_end_ns))
            for i, s in enumerate(traj.strips)]


# ---------------------------------------------------------------------------------------------
# The recording
# ---------------------------------------------------------------------------------------------


class BilSegmentWriter:
    """One recording segment as the scanner writes it: `segment_NNN.bil` (uint16 DN,
    little-endian, band-interleaved by line), `segment_NNN.hdr` (ENVI) and
    `segment_NNN.lines.csv` (frame counter of every line). Lines are appended in blocks and
    the header is rewritten (atomically) after each, so an interrupted recording stays
    readable up to its last block.

    A disk error (a full disk: ENOSPC; EIO, EFBIG) puts the segment back as its last whole
    block left it: the BIL and the lines file are cut to the lines the header names, so the
    three agree; a segment that could not be started is removed. Its files are closed and one
    RecorderError names the file and the cause; every later append raises it again."""

    def __init__(self, folder: Path, segment: int, pixels: int, bands: int,
                 frame_counter_bits: int) -> None:
        self.stem = Path(folder) / f"segment_{segment:03d}"
        self.segment = segment
        self.pixels = pixels
        self.bands = bands
        self.lines = 0  # what the header says: the lines the three files agree on
        self._csv_bytes = 0  # the lines file's size with those lines
        self._error: RecorderError | None = None
        self._bil = self._csv = -1
        where = self.bil_path
        try:
            self._bil = _open_for_writing(where)
            where = self.lines_csv_path
            self._csv = _open_for_writing(where)
            head = (_lines_csv_doc(self.bil_path.name, frame_counter_bits)
                    + "line_index,frame_counter\n").encode("utf-8")
            _write_all(self._csv, head)
            self._csv_bytes = len(head)
            where = self.hdr_path
            self._write_header(0)
        except OSError as exc:
            raise self._fail(where, exc) from exc

    @property
    def bil_path(self) -> Path:
        return self.stem.with_suffix(".bil")

    @property
    def hdr_path(self) -> Path:
        return self.stem.with_suffix(".hdr")

    @property
    def lines_csv_path(self) -> Path:
        return self.stem.with_suffix(".lines.csv")

    @property
    def line_bytes(self) -> int:
        return self.pixels * self.bands * 2

    def append(self, dn: U16, frame_counters: npt.ArrayLike) -> None:
        """Lines (lines, bands, pixels) and the frame counter of each: in the three files
        together, or (a disk error: RecorderError) in none of them."""
        if self._error is not None:
            raise self._error
        if self._bil < 0:
            raise ValueError(f"{self.stem.name}: the segment is closed")
        counters = np.asarray(frame_counters, dtype=np.int64)
        if dn.shape != (counters.size, self.bands, self.pixels):
            raise ValueError(f"expected ({counters.size}, {self.bands}, {self.pixels}) lines, "
                             f"got {dn.shape}")
        index = np.arange(self.lines, self.lines + counters.size)
        rows = "".join(f"{i},{c}\n" for i, c in zip(index.tolist(), counters.tolist(),
                                                    strict=True)).encode("utf-8")
        where = self.bil_path
        try:
            _write_all(self._bil, np.ascontiguousarray(dn, dtype="<u2").tobytes())
            where = self.lines_csv_path
            _write_all(self._csv, rows)
            where = self.hdr_path
            self._write_header(self.lines + counters.size)  # the commit
        except OSError as exc:
            raise self._fail(where, exc) from exc
        self.lines += counters.size
        self._csv_bytes += len(rows)

    def close(self) -> None:
        """Close the files (the header is current: rewritten after every block)."""
        self._close_files()

    def _fail(self, where: Path, exc: OSError) -> RecorderError:
        """Cut the BIL and the lines file back to the lines the header names (cutting needs
        no room), or remove the segment if it has none (an ENVI file of no line is not a
        raster), close them, and keep the one error."""
        with contextlib.suppress(OSError):
            os.ftruncate(self._bil, self.lines * self.line_bytes)
        with contextlib.suppress(OSError):
            os.ftruncate(self._csv, self._csv_bytes)
        self._close_files()
        if self.lines:
            kept = (f"is kept up to its last whole block ({self.lines} lines: its .bil, .hdr "
                    "and lines file agree)")
        else:
            for path in (self.bil_path, self.hdr_path, self.lines_csv_path):
                with contextlib.suppress(OSError):
                    path.unlink()
            kept = "is removed (no line of it was written)"
        self._error = RecorderError(f"cannot write {where}: {_reason(exc)}; the scanner's "
                                    f"recording segment {self.stem.name} {kept}")
        return self._error

    def _close_files(self) -> None:
        for fd in (self._bil, self._csv):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._bil = self._csv = -1

    def _write_header(self, lines: int) -> None:
        write_whole(self.hdr_path, envi_header(self.pixels, lines, self.bands, self.segment,
                                               self.lines_csv_path.name))


def _open_for_writing(path: Path) -> int:
    return os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o644)


def _write_all(fd: int, data: bytes) -> None:
    """All of `data`, or OSError (a write that took part of it is followed by one that fails:
    what reached the file is then cut away by the caller)."""
    view = memoryview(data)
    while view:
        written = os.write(fd, view)
        if written <= 0:  # (not for a regular file; never loop on it)
            raise OSError(errno.EIO, os.strerror(errno.EIO))
        view = view[written:]


def _reason(exc: OSError) -> str:
    return exc.strerror or str(exc)


def envi_header(pixels: int, lines: int, bands: int, segment: int, lines_csv: str) -> str:
    """ENVI header of a raw-DN BIL segment, with its bands' wavelengths."""
    centres = band_centres_nm(bands)
    fwhm = (WAVELENGTH_RANGE_NM[1] - WAVELENGTH_RANGE_NM[0]) / bands
    return raw_dn_envi_header(
        description=f"SISA emulated pushbroom scanner (CASI-501 class), recording segment "
                    f"{segment}: raw DN, one line per recorded frame, lines in recording "
                    f"order; frame counter of every line in {lines_csv}",
        samples=pixels, lines=lines, bands=bands, sensor_type="CASI-501 class (emulated)",
        extra={
            "wavelength units": "Nanometers",
            "wavelength": "{" + ", ".join(f"{c:.2f}" for c in centres) + "}",
            "fwhm": "{" + ", ".join(f"{fwhm:.2f}" for _ in centres) + "}",
            # names without the wavelength: GDAL appends it ("band 1 (495.00 Nanometers)")
            "band names": "{" + ", ".join(f"band {i + 1}" for i in range(len(centres))) + "}",
        })


def _lines_csv_doc(bil_name: str, frame_counter_bits: int) -> str:
    return (f"# Frame counter of every line of {bil_name}, in file order: the scanner's own\n"
            f"# record, written as it records. line_index: 0-based line of the BIL file.\n"
            f"# frame_counter: counter of the frame the line came from; it wraps at\n"
            f"# 2^{frame_counter_bits} and runs on across segments. A gap means frames that\n"
            f"# were exposed (their PPF pulse went out) but not recorded.\n")


# ---------------------------------------------------------------------------------------------
# The device
# ---------------------------------------------------------------------------------------------


@dataclass
class _Block:
    """A run of consecutive frames of one segment."""

    segment: int
    t_mid_ns: I64
    t_header_ns: I64
    counters: I64
    dropped: npt.NDArray[np.bool_]

    def part(self, lo: int, hi: int | None = None) -> _Block:
        return _Block(self.segment, self.t_mid_ns[lo:hi], self.t_header_ns[lo:hi],
                      self.counters[lo:hi], self.dropped[lo:hi])


class _Lines:
    """A block's rendered lines (its kept frames'), rendered at once or on the render-ahead
    thread: `get` waits for them."""

    def __init__(self, dn: U16 | None = None, future: Future[U16] | None = None) -> None:
        self._dn, self._future = dn, future

    def get(self) -> U16:
        if self._dn is None:
            assert self._future is not None
            self._dn = self._future.result()
            self._future = None
        return self._dn


@dataclass
class _Staged:
    """Frames scheduled and rendered ahead of time, not yet exposed: they join the recording
    and the truth only when their PPF goes out, so a run stopped early holds no frame it
    never exposed."""

    block: _Block
    lines: _Lines | None  # the kept frames' lines (rendering on)
    first_line: int  # of `lines`: the first not yet recorded (a block exposed in parts)
    ends_segment: bool


class ScannerEmulator(Device):
    """The scanner on the emulation timeline: PPF edges, frame headers and (with out_dir) its
    recording. Terrain and scene are needed only to render, i.e. when out_dir is given.

    Frames are scheduled, and their lines rendered, `block_lines` at a time, when the device
    runs out of outputs (right after a frame's header, before the next PPF). Large blocks give
    throughput in virtual time; in real time pass a block that renders within the gap between
    a header and the next PPF (line period − integration/2 − 3 ms), e.g. 8–16 lines, so that
    rendering never delays an output.

    `render_ahead` (virtual time): a block is rendered on a thread of its own while the
    emulation runs on (its lines are wanted only once its frames are exposed, seconds of
    flight later), so on two cores rendering leaves the event loop's path. One thread, in
    block order, rendering on one core: the detector noise is drawn in the same order, the
    lines are the same.
    """

    name = "scanner"

    def __init__(self, scn: Scenario, traj: TruthTrajectory, terrain: Terrain | None,
                 scene: Scene | None, rng: np.random.Generator, faults: TruthTable,
                 out_dir: Path | None, *, block_lines: int = DEFAULT_BLOCK_LINES,
                 render_ahead: bool = False) -> None:
        self.scn = scn
        self.traj = traj
        self.faults = faults
        self.frames = frame_table()
        self.block_lines = block_lines
        timing_rng, noise_rng = rng.spawn(2)  # rendering never shifts the frame timing
        self._rng = timing_rng
        sc = scn.scanner
        period_ns = sc.line_period_ms * 1e6 * (1.0 + sc.line_clock_drift_ppm * 1e-6)
        self.clock = LineClock(traj.t_start_ns + int(timing_rng.uniform(0.0, period_ns)),
                               period_ns)
        self._segments = _plan_segments(self.clock, traj)
        self._seg_pos = 0
        self._next_tick = self._segments[0].first_tick if self._segments else 0
        self._counter = 0
        self._staged: list[_Staged] = []
        # exposed frames not yet in the recording and the frames table: (frames, line index
        # of each, the lines of their block, the range of those that are theirs)
        self._unwritten: list[tuple[_Block, I64, _Lines | None, int, int]] = []
        self._render_ahead = render_ahead
        self._render_thread: ThreadPoolExecutor | None = None
        self._lines_segment, self._lines_in_segment = -1, 0
        self._pending: list[tuple[int, int, Output]] = []
        self._order = 0
        self._last_header_ns = -1
        self._horizon_tick, self._horizon = -1, 0
        self.out_dir = out_dir
        self._writer: BilSegmentWriter | None = None
        self.renderer: LineRenderer | None = None
        if out_dir is not None:
            if terrain is None or scene is None:
                raise ValueError("rendering a recording needs the terrain and the scene")
            Path(out_dir).mkdir(parents=True, exist_ok=True)
            self.renderer = LineRenderer(sc, scn.mounting, terrain, scene, noise_rng)
        self._skip_empty_segments()

    # --- Device -------------------------------------------------------------------------------

    def next_time_ns(self) -> int | None:
        while self._seg_pos < len(self._segments) and (
                not self._pending or self._pending[0][0] >= self._horizon_ns()):
            self._schedule_block()
        return self._pending[0][0] if self._pending else None

    def emit(self, t_ns: int) -> list[Output]:
        out = []
        while self._pending and self._pending[0][0] <= t_ns:
            out.append(heapq.heappop(self._pending)[2])
        self._expose_until(t_ns)
        return out

    def finish(self) -> None:
        self._staged.clear()  # scheduled, never exposed: the run stopped before them
        try:
            self._write_exposed()
        finally:
            self._close_writer()
            if self._render_thread is not None:  # (its last renders done: the counts whole)
                self._render_thread.shutdown(wait=True)
                self._render_thread = None

    # --- truth and statistics -----------------------------------------------------------------

    @property
    def tables(self) -> tuple[TruthTable, ...]:
        """Truth tables this device fills (the shared `faults` table is the caller's)."""
        return (self.frames,)

    @property
    def frames_exposed(self) -> int:
        return len(self.frames)

    @property
    def frames_dropped(self) -> int:
        return int(self.frames.column("dropped").sum()) if len(self.frames) else 0

    @property
    def missed_pixels(self) -> int:
        """Rendered pixels whose ray missed the DEM (recorded as DN 0)."""
        return self.renderer.missed_rays if self.renderer is not None else 0

    # --- scheduling ---------------------------------------------------------------------------

    def _horizon_ns(self) -> int:
        """No frame not yet scheduled can output anything before this time."""
        if self._horizon_tick != self._next_tick:
            jitter_bound = math.ceil(JITTER_CLIP_SIGMA * self.scn.scanner.line_clock_jitter_ns)
            self._horizon_tick = self._next_tick
            self._horizon = int(self.clock.time_of(self._next_tick)) - jitter_bound - 1
        return self._horizon

    def _skip_empty_segments(self) -> None:
        while (self._seg_pos < len(self._segments)
               and self._next_tick > self._segments[self._seg_pos].last_tick):
            self._seg_pos += 1
            if self._seg_pos < len(self._segments):
                self._next_tick = self._segments[self._seg_pos].first_tick

    def _schedule_block(self) -> None:
        seg = self._segments[self._seg_pos]
        stop = min(self._next_tick + self.block_lines, seg.last_tick + 1)
        block = self._draw_block(seg.number, np.arange(self._next_tick, stop, dtype=np.int64))
        self._next_tick = stop
        kept = ~block.dropped
        lines = (self._render(block.t_mid_ns[kept])
                 if self.renderer is not None and kept.any() else None)
        self._staged.append(_Staged(block, lines, 0, ends_segment=stop > seg.last_tick))
        self._queue(block)
        if self._next_tick > seg.last_tick:
            self._skip_empty_segments()

    def _expose_until(self, t_ns: int) -> None:
        """Frames whose PPF has gone out by `t_ns` into the recording and the truth."""
        while self._staged:
            staged = self._staged[0]
            n = int(np.searchsorted(staged.block.t_mid_ns, t_ns, side="right"))
            if n == 0:
                return
            if n < staged.block.counters.size:
                k = int((~staged.block.dropped[:n]).sum())
                head, tail = staged.block.part(0, n), staged.block.part(n)
                self._record(head, staged.lines, staged.first_line)
                self._staged[0] = _Staged(tail, staged.lines, staged.first_line + k,
                                          staged.ends_segment)
                return
            self._staged.pop(0)
            self._record(staged.block, staged.lines, staged.first_line)
            self._write_exposed()
            if staged.ends_segment:
                self._close_writer()

    def _draw_block(self, segment: int, ticks: I64) -> _Block:
        sc, n = self.scn.scanner, ticks.size
        sigma = sc.line_clock_jitter_ns
        jitter = np.clip(self._rng.normal(0.0, 1.0, n), -JITTER_CLIP_SIGMA, JITTER_CLIP_SIGMA)
        t_mid = self.clock.time_of(ticks) + np.rint(jitter * sigma).astype(np.int64)
        latency_ns = self._rng.uniform(*sc.header_latency_ms, n) * 1e6
        t_hdr = t_mid + round(sc.integration_time_ms * 5e5) + np.rint(latency_ns).astype(np.int64)
        t_hdr = np.maximum.accumulate(np.maximum(t_hdr, self._last_header_ns + 1))
        self._last_header_ns = int(t_hdr[-1])
        counters = (self._counter + np.arange(n, dtype=np.int64)) % (1 << sc.frame_counter_bits)
        self._counter = int(counters[-1]) + 1
        dropped = self._rng.random(n) < self.scn.faults.dropped_frame_fraction
        return _Block(segment, t_mid, t_hdr, counters, dropped)

    def _render(self, t_mid_ns: I64) -> _Lines:
        """The lines of frames at these mid-exposure times: rendered now, or on the
        render-ahead thread."""
        renderer = self.renderer
        assert renderer is not None

        def render() -> U16:
            return renderer.render(self.traj.state(t_mid_ns))

        if not self._render_ahead:
            return _Lines(render())
        if self._render_thread is None:
            # on one core: the event loop has the other (numba's thread count is per thread)
            self._render_thread = ThreadPoolExecutor(1, thread_name_prefix="sisa-render",
                                                     initializer=render_on_one_thread)
        return _Lines(future=self._render_thread.submit(render))

    def _record(self, block: _Block, lines: _Lines | None, first_line: int) -> None:
        """Exposed frames (their rendered lines from `first_line` of `lines`, if any): their
        dropped-frame faults now, their lines and their rows of the frames table once their
        block is exposed (`_write_exposed`)."""
        if block.segment != self._lines_segment:
            self._lines_segment, self._lines_in_segment = block.segment, 0
        kept = ~block.dropped
        line_index = np.full(block.counters.size, -1, dtype=np.int64)
        line_index[kept] = self._lines_in_segment + np.arange(int(kept.sum()))
        self._lines_in_segment += int(kept.sum())
        self._unwritten.append((block, line_index, lines, first_line,
                                first_line + int(kept.sum())))
        for i in np.flatnonzero(block.dropped):
            self.faults.append(t_gps_ns=int(block.t_mid_ns[i]), kind="dropped_frame",
                               target="scanner", detail=f"segment {block.segment} frame_counter "
                               f"{int(block.counters[i])}")

    def _write_exposed(self) -> None:
        """The exposed frames not yet written: their lines in one append (the recording),
        then their rows of the frames table (the truth of what was recorded, no more: a disk
        error leaves both at the last whole block). A block's frames are exposed one
        emission at a time; an append per frame rewrote the segment's header for every line,
        most of a garrotxa simulation's time went in those files' renames."""
        if not self._unwritten:
            return
        parts, self._unwritten = self._unwritten, []
        lines = [(source.get()[lo:hi], block.counters[~block.dropped])
                 for block, _, source, lo, hi in parts if source is not None and hi > lo]
        if lines:
            writer = self._writer_for(parts[0][0].segment)
            if len(lines) == 1:
                writer.append(*lines[0])
            else:
                writer.append(np.concatenate([d for d, _ in lines]),
                              np.concatenate([c for _, c in lines]))
        for block, line_index, *_ in parts:
            self._log_truth(block, line_index)

    def _writer_for(self, segment: int) -> BilSegmentWriter:
        if self._writer is None:
            assert self.out_dir is not None
            sc = self.scn.scanner
            self._writer = BilSegmentWriter(Path(self.out_dir), segment, sc.pixels, sc.bands,
                                            sc.frame_counter_bits)
        return self._writer

    def _close_writer(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def _log_truth(self, block: _Block, line_index: I64) -> None:
        n = block.counters.size
        self.frames.extend(segment=[block.segment] * n, line_index=line_index.tolist(),
                           frame_counter=block.counters.tolist(),
                           t_mid_gps_ns=block.t_mid_ns.tolist(),
                           dropped=block.dropped.astype(int).tolist())

    def _queue(self, block: _Block) -> None:
        sc = self.scn.scanner
        integration_us = round(sc.integration_time_ms * 1000.0)
        for i in range(block.counters.size):
            self._push(Output(int(block.t_mid_ns[i]), Port.PULSES,
                              Edge(PulseLine.PPF, 0, int(block.t_mid_ns[i]))))
            if block.dropped[i]:
                continue
            header = FrameHeader(int(block.counters[i]), integration_us, ScannerMode.RECORDING,
                                 block.segment, sc.bands)
            self._push(Output(int(block.t_header_ns[i]), Port.SCANNER_SERIAL,
                              encode_header(header, frame_counter_bits=sc.frame_counter_bits)))

    def _push(self, out: Output) -> None:
        heapq.heappush(self._pending, (out.t_ns, self._order, out))
        self._order += 1
