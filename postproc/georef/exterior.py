"""Exterior orientation of every scan line: perspective centre and camera attitude in ECEF.

    eo = exterior_orientation(traj, line_times.t_gps_ns, mounting, time_delay_ns=delay_ns)
    write_eo_csv(path, segment, line, eo)

Direct georeferencing (seed 003, eq. 1; docs/conventions.md): the perspective centre is
r^e_PC = r^e_INS(t) + R^e_b(t)·a^b, and a camera-frame vector maps to ECEF through
R^e_c = R^e_b(t)·R^b_c, with t = t_line + time_delay_ns (the line's true exposure is that much
later than its tag; calibration estimates the delay). Rotations are composed as full matrices,
never as angles added to angles; roll, pitch and heading are only reported. A line without a
time (t < 0) or without a navigation pose is invalid, and its values are NaN. The frame
camera's photos take their pose from the same function (`postproc.georef.photos`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Final, NamedTuple, Protocol, TextIO

import numpy as np
import numpy.typing as npt

from postproc.georef.navigation import Trajectory, ecef_to_geodetic, gps_times, r_ecef_from_ned
from sisa.core.frames import euler_from_body_to_ned

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]

WRITE_BLOCK: Final = 50_000

EO_HEADER: Final = (
    "# SISA exterior orientation: one row per scan line (postproc.georef.exterior;\n"
    "# docs/conventions.md).\n"
    "# segment, line: recording segment and 0-based line of its image\n"
    "# t_gps_ns: GPS time of the pose, int64 ns since 1980-01-06T00:00:00 on the GPS scale (no\n"
    "#   leap seconds): the line's mid-exposure plus the time delay; -1 for a line without time\n"
    "# valid: 1 if the line has a time and a navigation pose; 0 otherwise (then the other\n"
    "#   columns are nan)\n"
    "# x_ecef_m, y_ecef_m, z_ecef_m: perspective centre, WGS84 ECEF (EPSG:4978), metres\n"
    "# lat_deg, lon_deg, height_m: perspective centre, WGS84 geodetic (EPSG:4979), degrees and\n"
    "#   ellipsoidal height in metres\n"
    "# roll_deg, pitch_deg, heading_deg: attitude of the INS body frame (x forward, y right,\n"
    "#   z down), R_b^n = Rz(heading) Ry(pitch) Rx(roll), true heading in [0, 360), degrees\n"
    "# r11, r12, r13, r21, r22, r23, r31, r32, r33: R_c^e, the camera frame -> ECEF rotation,\n"
    "#   row-major (ECEF vector = R times camera vector; camera x along flight, y left, z up,\n"
    "#   the scanner looks along -z); dimensionless\n"
    "segment,line,t_gps_ns,valid,x_ecef_m,y_ecef_m,z_ecef_m,lat_deg,lon_deg,height_m,"
    "roll_deg,pitch_deg,heading_deg,r11,r12,r13,r21,r22,r23,r31,r32,r33\n")


class CameraMount(Protocol):
    """What the pose of a camera needs of its mounting: the scanner's `Mounting` and the
    frame camera's `FrameMounting` both give it."""

    @property
    def lever_arm_m(self) -> tuple[float, float, float]:
        """INS centre → perspective centre, body frame, metres."""
        ...

    def boresight_matrix(self) -> F64:
        """R_c^b: camera frame → body frame, nominal mounting included."""
        ...


class LineEo(NamedTuple):
    """Exterior orientation of N lines; invalid rows are NaN."""

    t_gps_ns: I64  # instant of the pose: line time + time_delay_ns (−1: the line has no time)
    centre_ecef_m: F64  # (N, 3) perspective centre
    r_ecef_from_camera: F64  # (N, 3, 3) R_c^e = R_b^e · R_c^b
    lat_deg: F64  # perspective centre, WGS84
    lon_deg: F64
    height_m: F64  # ellipsoidal
    roll_rad: F64  # body attitude: R_b^n at the INS centre
    pitch_rad: F64
    heading_rad: F64  # true, [0, 2π)
    valid: Bool


def exterior_orientation(traj: Trajectory, t_line_gps_ns: npt.ArrayLike, mounting: CameraMount, *,
                         time_delay_ns: int = 0) -> LineEo:
    """Pose of every line's perspective centre and camera, sampled at t_line + time_delay_ns."""
    t_line = gps_times(t_line_gps_ns)
    timed = t_line >= 0
    t = np.where(timed, t_line + np.int64(time_delay_ns), np.int64(-1))
    pose = traj.pose_at(t)
    ok = pose.valid & timed
    n = t.size
    centre, r_ec = np.full((n, 3), np.nan), np.full((n, 3, 3), np.nan)
    lat, lon, h, roll, pitch, heading = (np.full(n, np.nan) for _ in range(6))
    if ok.any():
        r_eb, ins = pose.r_ecef_from_body[ok], pose.ins_ecef_m[ok]
        centre[ok] = ins + r_eb @ np.asarray(mounting.lever_arm_m, np.float64)
        r_ec[ok] = r_eb @ mounting.boresight_matrix()
        lat[ok], lon[ok], h[ok] = ecef_to_geodetic(centre[ok])
        r_bn = np.swapaxes(r_ecef_from_ned(ins), -1, -2) @ r_eb
        roll[ok], pitch[ok], heading[ok] = euler_from_body_to_ned(r_bn)
    return LineEo(t, centre, r_ec, lat, lon, h, roll, pitch, heading, ok)


def _write_rows(fh: TextIO, columns: list[tuple[npt.NDArray[np.generic], str]]) -> None:
    """Columns formatted a block of rows at a time, each row by one %-format of Python numbers:
    4.5x faster than numpy's per-column `np.char.mod`, whose loop of Python calls also lost a
    Ctrl-C that came during it (numpy 2.4)."""
    n = columns[0][0].shape[0]
    row = ",".join(fmt for _, fmt in columns) + "\n"
    for lo in range(0, n, WRITE_BLOCK):
        block = [values[lo:lo + WRITE_BLOCK].tolist() for values, _ in columns]
        fh.write("".join([row % r for r in zip(*block, strict=True)]))


def write_eo_csv(path: Path | str, segment: int | npt.ArrayLike, line: npt.ArrayLike,
                 eo: LineEo) -> None:
    """The EO table as CSV with a commented header naming every column and its unit.
    `segment` may be one number for all rows."""
    n = eo.t_gps_ns.size
    seg = np.broadcast_to(np.asarray(segment, np.int64), (n,))
    ln = np.asarray(line, np.int64)
    if ln.shape != (n,):
        raise ValueError(f"line: {ln.shape} values for {n} rows")
    deg = np.degrees
    cols: list[tuple[npt.NDArray[np.generic], str]] = [
        (seg, "%d"), (ln, "%d"), (eo.t_gps_ns, "%d"), (eo.valid.astype(np.int64), "%d"),
        *((eo.centre_ecef_m[:, k], "%.4f") for k in range(3)),
        (eo.lat_deg, "%.10f"), (eo.lon_deg, "%.10f"), (eo.height_m, "%.4f"),
        (deg(eo.roll_rad), "%.8f"), (deg(eo.pitch_rad), "%.8f"), (deg(eo.heading_rad), "%.8f"),
        *((eo.r_ecef_from_camera[:, i, j], "%.12f") for i in range(3) for j in range(3)),
    ]
    with Path(path).open("w", encoding="utf-8", newline="") as fh:
        fh.write(EO_HEADER)
        if n:
            _write_rows(fh, cols)
