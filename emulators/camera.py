"""The frame camera emulator (issue 37): when it exposes, what it sends, and the truth of every
photo. `CameraDevice` puts it on the runtime: its photo messages on its own serial port
(`Port.CAMERA_SERIAL`), its mid-exposure pulses on the pulse line `PulseLine.CAMERA` into the
sync unit (which shares its GPS event input with the scanner: docs/sync.md).

What it does, and why:
- The camera is on only over the strips, as the scanner records (one window per strip of the
  truth trajectory). Within a window it is triggered by an intervalometer (a photo every
  `trigger_interval_s`, the first at the window's start) or by the flight management system
  (a photo every `trigger_distance_m` of ground track flown, on the ellipsoid, the first at
  the window's start). Photo numbers run on across strips from `first_photo_number` and wrap.
- Per exposure it sends a pulse at mid-exposure, and, `message_latency_ms` after the end of the
  exposure, a photo message on its own serial port (acquisition.camera_photo). A lost pulse
  (fault `lost_pulse_fraction`) leaves the photo and its message; a lost photo number (fault
  `lost_photo_number_fraction`) leaves the photo and its pulse without a message.
- A photo is rendered (`PhotoRenderer`) from the TRUE pose at its true mid-exposure time:
  each pixel centre's ray from `sisa.core.framecamera.image_to_camera`, cast onto the DEM by
  the scanner's ray caster, the scene sampled there and turned into DN by the scanner's
  detector model, in the scene's bands (no motion blur: the pose is the mid-exposure one).
- Truth (table `photos`) holds every exposure: its photo number, true mid-exposure time, which
  of its outputs went out, and its true exterior orientation from the truth trajectory
  (perspective centre `r^e = r^e_INS + R_b^e·a^b`, `emulators.render.camera_pose_ecef`, the
  scanner's own function).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt
from pyproj import Geod, Transformer

from acquisition.camera_photo import PhotoMessage, encode_photo
from acquisition.pulses import Edge, PulseLine
from emulators.render import (
    GroundIntersector,
    SensorResponse,
    camera_pose_ecef,
    dn_from_radiance,
    raw_dn_envi_header,
)
from emulators.runtime import Device, Output, Port
from emulators.scenario import CameraSettings
from emulators.terrain import Scene, Terrain
from emulators.trajectory import FlownStrip, TrajectoryState, TruthTrajectory
from emulators.truth import TruthTable
from sisa.core.errors import ConfigError
from sisa.core.framecamera import image_to_camera
from sisa.core.outdir import write_whole
from sisa.core.timescale import NS_PER_S, seconds_since

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]
U16 = npt.NDArray[np.uint16]

_WGS84: Final = Geod(ellps="WGS84")
WGS84_A_M: Final = float(_WGS84.a)
WGS84_E2: Final = float(_WGS84.es)  # first eccentricity squared
TRACK_STEP_S: Final = 0.1  # the track is integrated at the truth spline's node spacing
RENDER_ROWS: Final = 64  # image rows cast and shaded at a time (memory per photo stays flat)
_ECEF_TO_GEODETIC: Final = Transformer.from_crs(4978, 4979, always_xy=True)


# ---------------------------------------------------------------------------------------------
# When the camera exposes
# ---------------------------------------------------------------------------------------------


def _interval_times(strip: FlownStrip, interval_ns: int) -> I64:
    count = (strip.t_end_ns - strip.t_start_ns) // interval_ns + 1
    return strip.t_start_ns + interval_ns * np.arange(max(count, 0), dtype=np.int64)


def track_distance_m(traj: TruthTrajectory, t0_ns: int, t1_ns: int) -> tuple[I64, F64]:
    """(times, length of the ground track flown since t0 at each) from t0 to t1 inclusive,
    every TRACK_STEP_S. The ground track is the aircraft's foot on the WGS 84 ellipsoid (what a
    flight management system measures from GNSS latitude and longitude): its speed is the true
    horizontal velocity scaled down from the flying height, √((v_N·M/(M+h))² + (v_E·N/(N+h))²)
    with M, N the meridian and prime-vertical radii (at 1 km it is 0.016 % slower), integrated
    by the trapezoidal rule."""
    step_ns = round(TRACK_STEP_S * NS_PER_S)
    t = np.arange(t0_ns, t1_ns, step_ns, dtype=np.int64)
    t = np.append(t, np.int64(t1_ns))
    state = traj.state(t)
    w = np.sqrt(1.0 - WGS84_E2 * np.sin(np.radians(state.lat_deg)) ** 2)
    m, n = WGS84_A_M * (1.0 - WGS84_E2) / w**3, WGS84_A_M / w
    speed = np.hypot(state.vel_ned_mps[:, 0] * m / (m + state.height_m),
                     state.vel_ned_mps[:, 1] * n / (n + state.height_m))
    dt_s = np.diff(seconds_since(t, t0_ns))
    return t, np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * dt_s)])


def _distance_times(traj: TruthTrajectory, strip: FlownStrip, distance_m: float) -> I64:
    t, flown = track_distance_m(traj, strip.t_start_ns, strip.t_end_ns)
    marks = distance_m * np.arange(int(flown[-1] // distance_m) + 1)
    t_s = np.interp(marks, flown, seconds_since(t, strip.t_start_ns))
    return np.asarray(strip.t_start_ns + np.rint(t_s * NS_PER_S).astype(np.int64))


def exposure_times(camera: CameraSettings, traj: TruthTrajectory) -> tuple[I64, I64]:
    """(mid-exposure GPS ns, strip index) of every photo the camera takes over the strips, in
    time order: a photo every `trigger_interval_s` from each strip window's start to its end,
    or every `trigger_distance_m` of ground track flown (`track_distance_m`). A pure function of
    the settings and the trajectory (no random draw); the camera's trigger delay and its jitter
    are not modelled: the mid-exposure time is the trigger time."""
    times: list[I64] = []
    strips: list[I64] = []
    for strip in traj.strips:
        if camera.trigger_distance_m is not None:
            t = _distance_times(traj, strip, camera.trigger_distance_m)
        elif camera.trigger_interval_s is not None:
            t = _interval_times(strip, round(camera.trigger_interval_s * NS_PER_S))
        else:  # CameraSettings refuses this
            raise ConfigError("camera: give one of trigger_interval_s and trigger_distance_m")
        times.append(t)
        strips.append(np.full(t.size, strip.index, dtype=np.int64))
    if not times:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    return np.concatenate(times), np.concatenate(strips)


# ---------------------------------------------------------------------------------------------
# What it sends
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CameraShots:
    """Every exposure of a flight, in time order, and what of it went out."""

    photo_number: I64  # wraps at 2^photo_counter_bits
    strip: I64  # strip index (FlownStrip.index)
    t_mid_ns: I64  # true mid-exposure time, GPS ns: the pulse's time
    t_message_ns: I64  # when the photo message goes out on the camera's port
    pulse_sent: Bool
    message_sent: Bool

    def __len__(self) -> int:
        return int(self.t_mid_ns.size)


def plan_shots(camera: CameraSettings, traj: TruthTrajectory,
               rng: np.random.Generator) -> CameraShots:
    """The exposures of `exposure_times`, numbered, with their message times (exposure end plus
    a latency drawn uniformly from message_latency_ms, never before the previous message) and
    the camera's faults drawn from `rng` (its own stream)."""
    t_mid, strip = exposure_times(camera, traj)
    n = t_mid.size
    numbers = (camera.first_photo_number + np.arange(n, dtype=np.int64)) % (
        1 << camera.photo_counter_bits)
    half_exposure_ns = round(camera.exposure_time_ms * 5e5)
    latency_ns = np.rint(rng.uniform(*camera.message_latency_ms, n) * 1e6).astype(np.int64)
    t_message = np.maximum.accumulate(t_mid + half_exposure_ns + latency_ns) if n else t_mid
    pulse_lost = rng.random(n) < camera.faults.lost_pulse_fraction
    message_lost = rng.random(n) < camera.faults.lost_photo_number_fraction
    return CameraShots(numbers, strip, t_mid, t_message, ~pulse_lost, ~message_lost)


def on_frames(shots: CameraShots, frame_times_ns: Callable[[I64], I64], fraction: float,
              rng: np.random.Generator) -> tuple[CameraShots, I64]:
    """Fault `on_frame_fraction`: that share of the exposures moved onto the nearest scanner
    frame's mid-exposure (`frame_times_ns` gives the frame time nearest each time asked), its
    message moved with it; the photo is then taken there (the truth follows). Drawn from `rng`
    (a stream of its own: the camera's other draws do not change). Returns the shots and the
    indices moved."""
    moved = np.flatnonzero(rng.random(len(shots)) < fraction) if fraction > 0 else np.empty(
        0, np.int64)
    if not moved.size:
        return shots, moved
    t_mid = shots.t_mid_ns.copy()
    shift = frame_times_ns(t_mid[moved]) - t_mid[moved]
    t_mid[moved] += shift
    t_message = shots.t_message_ns.copy()
    t_message[moved] += shift
    order = np.argsort(t_mid, kind="stable")
    if np.any(np.diff(t_mid[order]) <= 0):  # two exposures on one frame: keep the plan
        return shots, np.empty(0, np.int64)
    return replace(shots, t_mid_ns=t_mid, t_message_ns=np.maximum.accumulate(t_message)), moved


class CameraDevice(Device):
    """The camera on the runtime: its pulses (that left it) and its photo messages (that were
    sent), in time order; a pulse before a message due at the same instant."""

    name = "camera"

    def __init__(self, camera: CameraSettings, shots: CameraShots) -> None:
        items = [(int(t), 0, Output(int(t), Port.PULSES, Edge(PulseLine.CAMERA, 0, int(t))))
                 for t in pulse_times_ns(shots)]
        items += [(t, 1, Output(t, Port.CAMERA_SERIAL, data))
                  for t, data in photo_messages(camera, shots)]
        items.sort(key=lambda item: item[:2])
        self._outputs = [out for _, _, out in items]
        self._pos = 0

    def next_time_ns(self) -> int | None:
        return self._outputs[self._pos].t_ns if self._pos < len(self._outputs) else None

    def emit(self, t_ns: int) -> list[Output]:
        start = self._pos
        while self._pos < len(self._outputs) and self._outputs[self._pos].t_ns <= t_ns:
            self._pos += 1
        return self._outputs[start:self._pos]


def photo_messages(camera: CameraSettings, shots: CameraShots) -> list[tuple[int, bytes]]:
    """(send time GPS ns, bytes) of every photo message that goes out, in time order."""
    exposure_us = round(camera.exposure_time_ms * 1000.0)
    return [(int(t), encode_photo(PhotoMessage(int(k), exposure_us),
                                  photo_counter_bits=camera.photo_counter_bits))
            for t, k in zip(shots.t_message_ns[shots.message_sent],
                            shots.photo_number[shots.message_sent], strict=True)]


def pulse_times_ns(shots: CameraShots) -> I64:
    """Mid-exposure pulse edges that leave the camera (GPS ns, emulation timeline)."""
    return shots.t_mid_ns[shots.pulse_sent]


# ---------------------------------------------------------------------------------------------
# Truth
# ---------------------------------------------------------------------------------------------


def photo_table() -> TruthTable:
    return TruthTable("photos", {
        "photo_number": "the camera's photo number (wraps at 2^photo_counter_bits)",
        "strip": "strip index the photo was taken over",
        "t_mid_gps_ns": "true mid-exposure time (GPS ns): the camera's pulse time",
        "pulse_sent": "1 if the mid-exposure pulse left the camera, 0 if lost (fault)",
        "message_sent": "1 if the photo message was sent, 0 if lost (fault)",
        "t_message_gps_ns": "when the photo message goes out (GPS ns), sent or not",
        "x_ecef_m": "true perspective centre, ECEF (EPSG:4978)",
        "y_ecef_m": "true perspective centre, ECEF (EPSG:4978)",
        "z_ecef_m": "true perspective centre, ECEF (EPSG:4978)",
        "lat_deg": "true perspective centre, WGS 84 geodetic latitude",
        "lon_deg": "true perspective centre, WGS 84 geodetic longitude",
        "height_m": "true perspective centre, ellipsoidal height",
        "roll_deg": "true body roll at mid-exposure, R_b^n = Rz(heading) Ry(pitch) Rx(roll)",
        "pitch_deg": "true body pitch at mid-exposure",
        "heading_deg": "true body heading (true north) at mid-exposure, [0, 360)",
    }, "every photo the frame camera took, its outputs and its true exterior orientation")


def photo_truth(camera: CameraSettings, shots: CameraShots,
                traj: TruthTrajectory) -> TruthTable:
    """The `photos` truth table of these exposures."""
    table = photo_table()
    if not len(shots):
        return table
    state = traj.state(shots.t_mid_ns)
    centre, _ = camera_pose_ecef(state, camera.mounting)
    lon, lat, h = _ECEF_TO_GEODETIC.transform(centre[:, 0], centre[:, 1], centre[:, 2])
    deg = np.degrees
    table.extend(photo_number=shots.photo_number.tolist(), strip=shots.strip.tolist(),
                 t_mid_gps_ns=shots.t_mid_ns.tolist(),
                 pulse_sent=shots.pulse_sent.astype(int).tolist(),
                 message_sent=shots.message_sent.astype(int).tolist(),
                 t_message_gps_ns=shots.t_message_ns.tolist(),
                 x_ecef_m=centre[:, 0].tolist(), y_ecef_m=centre[:, 1].tolist(),
                 z_ecef_m=centre[:, 2].tolist(), lat_deg=np.asarray(lat).tolist(),
                 lon_deg=np.asarray(lon).tolist(), height_m=np.asarray(h).tolist(),
                 roll_deg=deg(state.roll_rad).tolist(), pitch_deg=deg(state.pitch_rad).tolist(),
                 heading_deg=deg(state.heading_rad).tolist())
    return table


# ---------------------------------------------------------------------------------------------
# Rendering a photo
# ---------------------------------------------------------------------------------------------


class PhotoRenderer:
    """Renders whole photos from true poses: pixel rays → DEM → scene → DN, (rows, bands, cols)
    BIL order. Built once per terrain (the ray caster's set-up is the costly part)."""

    def __init__(self, camera: CameraSettings, terrain: Terrain, scene: Scene,
                 rng: np.random.Generator, response: SensorResponse | None = None,
                 intersector: GroundIntersector | None = None) -> None:
        self.camera = camera
        self.scene = scene
        self.rng = rng
        self.response = response or SensorResponse()
        self.intersector = intersector or GroundIntersector(terrain)
        self.missed_rays = 0

    def _rows_look(self, row0: int, row1: int) -> F64:
        iop = self.camera.model
        cols, rows = np.meshgrid(np.arange(iop.width_px, dtype=np.float64),
                                 np.arange(row0, row1, dtype=np.float64))
        return np.ascontiguousarray(image_to_camera(cols.ravel(), rows.ravel(), iop).T)

    def ground(self, state: TrajectoryState) -> F64:
        """Ground (E, N, h) of every pixel of the photo at this one state, (rows, cols, 3), in
        the terrain's CRS; NaN where a ray misses the DEM."""
        if state.t_gps_ns.size != 1:
            raise ValueError("a photo has one pose: give the state at one instant")
        iop = self.camera.model
        centre, r_ke = camera_pose_ecef(state, self.camera.mounting)
        out = np.empty((iop.height_px, iop.width_px, 3))
        for row0 in range(0, iop.height_px, RENDER_ROWS):
            row1 = min(row0 + RENDER_ROWS, iop.height_px)
            hits = self.intersector.intersect_lines(centre, r_ke, self._rows_look(row0, row1))
            out[row0:row1] = hits[0].reshape(row1 - row0, iop.width_px, 3)
        return out

    def render(self, state: TrajectoryState) -> U16:
        """DN of the photo at this one state, shape (rows, bands, cols)."""
        hits = self.ground(state)
        rows, cols = hits.shape[:2]
        self.missed_rays += int(np.isnan(hits[..., 0]).sum())
        rad = self.scene.radiance(hits[..., 0].ravel(), hits[..., 1].ravel())
        return dn_from_radiance(rad.reshape(-1, rows, cols), self.rng, self.response)


def photo_envi_header(cols: int, rows: int, bands: int, photo_number: int,
                      t_mid_gps_ns: int) -> str:
    """ENVI header of a rendered photo (raw DN, uint16 little-endian, BIL)."""
    return raw_dn_envi_header(
        description=f"SISA emulated frame camera, photo {photo_number}, mid-exposure "
                    f"{t_mid_gps_ns} GPS ns: raw DN, row 0 at the top of the image, column "
                    "0 at its left",
        samples=cols, lines=rows, bands=bands, sensor_type="frame camera (emulated)")


def write_photo(folder: Path, dn: U16, photo_number: int, t_mid_gps_ns: int) -> Path:
    """`folder/photo_NNNNNN.bil` and its `.hdr`, each written whole; returns the .bil path."""
    rows, bands, cols = dn.shape
    bil = Path(folder) / f"photo_{photo_number:06d}.bil"
    write_whole(bil, np.ascontiguousarray(dn, dtype="<u2").tobytes())
    write_whole(bil.with_suffix(".hdr"),
                photo_envi_header(cols, rows, bands, photo_number, t_mid_gps_ns))
    return bil
