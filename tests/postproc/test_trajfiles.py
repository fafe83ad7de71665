"""External trajectories (postproc.georef.trajfiles): real files of both formats written here, read
back, and compared with values computed independently (closed-form WGS84, calendar arithmetic,
the analytic flight of test_navigation).

The RTKLIB writer below follows RTKLIB's own printf formats (solution.c: outsolheads, outpos,
outecef, deg2dms, time2str) so the files have exactly the layout rnx2rtkp prints.
"""

from __future__ import annotations

import datetime as dt
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from postproc.georef.navigation import PiecewiseTrajectory
from postproc.georef.trajfiles import (
    PartialRecordWarning,
    read_rtklib_pos,
    read_sbet,
    read_trajectory_file,
    rtklib_trajectory,
    sbet_times_ns,
    sbet_trajectory,
)
from recorder.messages import Topic
from sisa.core.errors import InputError
from sisa.core.frames import euler_from_body_to_ned
from sisa.core.timescale import NS_PER_S
from tests.postproc.test_navigation import (
    ARCSEC,
    ATT_TOL_RAD,
    G_B,
    MM,
    POS_TOL_M,
    SYN,
    T0_NS,
    geodetic,
    pose_errors,
    wgs84_ecef,
)

GPS_EPOCH = dt.datetime(1980, 1, 6)
WEEK_S = 7 * 86400


# --- an RTKLIB .pos writer (RTKLIB's formats) ---------------------------------------------------

def _calendar(t_ns: int) -> str:
    """time2str(t, s, 3): yyyy/mm/dd hh:mm:ss.sss, computed by calendar arithmetic."""
    whole, frac = divmod(t_ns, NS_PER_S)
    when = GPS_EPOCH + dt.timedelta(seconds=whole)
    return when.strftime("%Y/%m/%d %H:%M:%S") + f".{frac // 1_000_000:03d}"


def _week_tow(t_ns: int) -> str:
    week, tow_ns = divmod(t_ns, WEEK_S * NS_PER_S)
    return f"{week:4d} {tow_ns / NS_PER_S:10.3f}"


def _deg2dms(deg: float) -> tuple[float, float, float]:
    """RTKLIB deg2dms(deg, dms, 5): the sign rides on the degrees (−0 for −0.5°)."""
    sign, a = (-1.0 if deg < 0 else 1.0), abs(deg)
    d = math.floor(a)
    a = (a - d) * 60
    m = math.floor(a)
    s = math.floor((a - m) * 60 / 1e-5 + 0.5) * 1e-5
    if s >= 60:
        s, m = 0.0, m + 1
        if m >= 60:
            m, d = 0, d + 1
    return sign * d, m, s


PROGRAM_HEADER = """\
% program   : RTKPOST ver.2.4.3 b34
% inp file  : rover.obs
% inp file  : base.obs
% inp file  : brdc1660.26n
% obs start : 2026/06/15 09:00:01.0 GPST (week2423  86401.0s)
% pos mode  : kinematic
% freqs     : L1+L2
% solution  : combined
% elev mask : 15.0 deg
% dynamics  : off
% tidecorr  : off
% ionos opt : broadcast
% tropo opt : saastamoinen
% ephemeris : broadcast
% amb res   : fix and hold
% val thres : 3.0
% antenna1  :                       ( 0.0000  0.0000  0.0000)
% antenna2  :                       ( 0.0000  0.0000  0.0000)
% ref pos   :  41.600000000    2.000000000   300.0000
%
"""


def write_pos(path: Path, t_ns: np.ndarray, values: np.ndarray, q: np.ndarray, *,
              layout: str = "deg", scale: str = "GPST", week_tow: bool = False,
              height: str = "ellipsoidal", sep: str = " ") -> list[str]:
    """values: lat/lon/h (deg, deg, m) or ECEF x/y/z. Returns the data lines written."""
    tw = 8 + 3 + 1 if week_tow else 16 + 3 + 1
    frame = "x/y/z-ecef=WGS84" if layout == "xyz" else f"lat/lon/height=WGS84/{height}"
    head = [f"% ({frame},Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)"]
    sds = ("sdx(m)", "sdy(m)", "sdz(m)", "sdxy(m)", "sdyz(m)", "sdzx(m)") if layout == "xyz" \
        else ("sdn(m)", "sde(m)", "sdu(m)", "sdne(m)", "sdeu(m)", "sdun(m)")
    labels = {"deg": ("latitude(deg)", "longitude(deg)", 14),
              "dms": ("latitude(d'\")", "longitude(d'\")", 16),
              "xyz": ("x-ecef(m)", "y-ecef(m)", 14)}[layout]
    cols = [f"{labels[0]:>{labels[2]}}", f"{labels[1]:>{labels[2]}}",
            f"{'z-ecef(m)':>14}" if layout == "xyz" else f"{'height(m)':>10}",
            f"{'Q':>3}", f"{'ns':>3}", *(f"{s:>8}" for s in sds), f"{'age(s)':>6}",
            f"{'ratio':>6}"]
    head.append(f"%  {scale:<{tw}}{sep}" + sep.join(cols))
    lines = []
    for k, t in enumerate(t_ns.tolist()):
        stamp = _week_tow(t) if week_tow else _calendar(t)
        if week_tow and sep != " ":
            stamp = stamp.replace(" ", sep, 1)
        a, b, c = values[k]
        if layout == "xyz":
            pos = f"{a:14.4f}{sep}{b:14.4f}{sep}{c:14.4f}"
        elif layout == "dms":
            d1, d2 = _deg2dms(a), _deg2dms(b)
            pos = sep.join([f"{d1[0]:4.0f}{sep}{d1[1]:02.0f}{sep}{d1[2]:08.5f}",
                            f"{d2[0]:4.0f}{sep}{d2[1]:02.0f}{sep}{d2[2]:08.5f}",
                            f"{c:10.4f}"])
        else:
            pos = f"{a:14.9f}{sep}{b:14.9f}{sep}{c:10.4f}"
        rest = [f"{int(q[k]):3d}", f"{9:3d}", f"{0.0071:8.4f}", f"{0.0052:8.4f}",
                f"{0.0143:8.4f}", f"{-0.0011:8.4f}", f"{0.0023:8.4f}", f"{-0.0031:8.4f}",
                f"{1.0:6.2f}", f"{12.5:6.1f}"]
        lines.append(f"{stamp}{sep}{pos}{sep}" + sep.join(rest))
    path.write_text(PROGRAM_HEADER + "\n".join(head + lines) + "\n", encoding="utf-8")
    return lines


def antenna_llh(t_ns: np.ndarray) -> np.ndarray:
    ecef, _, _, r_eb = SYN.state(t_ns)
    lat, lon, h = geodetic(ecef + r_eb @ G_B)
    return np.stack([lat, lon, h], axis=-1)


@pytest.fixture(scope="module")
def synthetic() -> Any:
    return SYN.columns()


T_POS = np.arange(T0_NS + NS_PER_S, SYN.end_ns - NS_PER_S, NS_PER_S // 5, dtype=np.int64)


# --- RTKLIB .pos --------------------------------------------------------------------------------

def test_reads_the_exact_rtklib_layout(tmp_path: Path) -> None:
    llh = antenna_llh(T_POS)
    q = np.where(np.arange(T_POS.size) % 7 == 3, 2, 1)
    lines = write_pos(tmp_path / "rover.pos", T_POS, llh, q)
    assert lines[0].startswith("2026/06/15 09:00:01.000   41.6")  # as rnx2rtkp prints it
    assert len(lines[0].split()) == 15
    pos = read_rtklib_pos(tmp_path / "rover.pos")
    np.testing.assert_array_equal(pos.t_gps_ns, T_POS)
    printed = np.array([[float(x) for x in ln.split()[2:5]] for ln in lines])
    np.testing.assert_allclose(pos.ecef_m, wgs84_ecef(*printed.T), rtol=0, atol=1e-6)
    np.testing.assert_array_equal(pos.q, q)
    assert (pos.ns == 9).all()
    np.testing.assert_array_equal(pos.sigma_m[0], [0.0071, 0.0052, 0.0143])
    assert pos.line[0] == PROGRAM_HEADER.count("\n") + 3


def test_week_tow_ecef_and_dms_variants_read_the_same(tmp_path: Path) -> None:
    t = T_POS[:50]
    llh = antenna_llh(t)
    ecef = wgs84_ecef(*llh.T)
    q = np.ones(t.size, dtype=np.int64)
    write_pos(tmp_path / "wt.pos", t, llh, q, week_tow=True)
    write_pos(tmp_path / "xyz.pos", t, ecef, q, layout="xyz")
    write_pos(tmp_path / "dms.pos", t, llh, q, layout="dms")
    write_pos(tmp_path / "csv.pos", t, llh, q, sep=",", week_tow=True)
    for name, tol_m in (("wt", 1e-3), ("xyz", 1e-4), ("dms", 1e-3), ("csv", 1e-3)):
        pos = read_rtklib_pos(tmp_path / f"{name}.pos")
        np.testing.assert_array_equal(pos.t_gps_ns, t, err_msg=name)
        assert np.abs(pos.ecef_m - ecef).max() < tol_m, name


def test_dms_signs_west_and_south_of_zero(tmp_path: Path) -> None:
    """−0.5° is printed '  -0 30 00.00000': the sign sits on a zero degree."""
    llh = np.array([[-0.5, -3.25, 10.0], [-33.875, 151.2, 20.0]])
    t = T_POS[0] + np.array([0, 86400 * NS_PER_S])  # a day apart: a flight, not a jump
    lines = write_pos(tmp_path / "south.pos", t, llh, np.ones(2, dtype=np.int64), layout="dms")
    assert "  -0 30 00.00000" in lines[0]
    pos = read_rtklib_pos(tmp_path / "south.pos")
    np.testing.assert_allclose(pos.ecef_m, wgs84_ecef(*llh.T), atol=1e-3)


def test_utc_times_need_and_use_the_leap_seconds(tmp_path: Path) -> None:
    t = T_POS[:10]
    write_pos(tmp_path / "utc.pos", t - 18 * NS_PER_S, antenna_llh(t),
              np.ones(10, dtype=np.int64), scale="UTC ")
    with pytest.raises(InputError, match=r"utc\.pos:\d+: times are UTC: give the leap-second"):
        read_rtklib_pos(tmp_path / "utc.pos")
    np.testing.assert_array_equal(read_rtklib_pos(tmp_path / "utc.pos", leap_seconds=18)
                                  .t_gps_ns, t)


def _swap(lines: list[str], i: int, j: int) -> list[str]:
    out = list(lines)
    out[i], out[j] = out[j], out[i]
    return out


FIRST = PROGRAM_HEADER.count("\n") + 2  # index of the first solution line (line 23)


@pytest.mark.parametrize(("edit", "message"), [
    (lambda L: [ln.replace("WGS84/ellipsoidal", "WGS84/geodetic") for ln in L],
     r"bad\.pos:21: heights are geodetic"),
    (lambda L: [*L[:FIRST], L[FIRST].replace(" 41.6", " 4x.6", 1), *L[FIRST + 1:]],
     r"bad\.pos:23: could not convert string to float: '4x\.6\d+'"),
    (lambda L: _swap(L, FIRST + 1, FIRST + 2),
     r"bad\.pos:25: time does not increase after line 24"),
    (lambda L: [ln for ln in L if "latitude(deg)" not in ln],
     r"bad\.pos:22: a solution before the column header"),
    (lambda L: [*L[:FIRST], " ".join(L[FIRST].split()[:5]), *L[FIRST + 1:]],
     r"bad\.pos:23: 5 fields, need at least 6"),
    (lambda L: [*L[:FIRST], L[FIRST].replace("09:00:01", "09:0O:01"), *L[FIRST + 1:]],
     r"bad\.pos:23: not a time of day '09:0O:01\.000'"),
    # tracebacks from int64 overflow and from a spline over infinite ECEF coordinates (found by
    # a bad-input sweep of `sisa georef --trajectory`)
    (lambda L: [*L[:FIRST], " ".join(["9999/12/31", *L[FIRST].split()[1:]]), *L[FIRST + 1:]],
     r"bad\.pos:23: time 9999/12/31 09:00:01\.000 is outside GPS time as nanoseconds hold it"),
    (lambda L: [*L[:FIRST], " ".join(["1970/01/01", *L[FIRST].split()[1:]]), *L[FIRST + 1:]],
     r"bad\.pos:23: time 1970/01/01 .* is outside GPS time"),
    (lambda L: [*L[:FIRST + 1], " ".join([*L[FIRST + 1].split()[:4], "1e308",
                                           *L[FIRST + 1].split()[5:]]), *L[FIRST + 2:]],
     r"bad\.pos:24: ellipsoidal height 1e\+308 m outside -10000 to 100000 m"),
])
def test_a_bad_pos_file_is_one_clear_line(tmp_path: Path, edit: Any, message: str) -> None:
    path = tmp_path / "bad.pos"
    write_pos(path, T_POS[:5], antenna_llh(T_POS[:5]), np.ones(5, dtype=np.int64))
    path.write_text("\n".join(edit(path.read_text(encoding="utf-8").splitlines())) + "\n",
                    encoding="utf-8")
    with pytest.raises(InputError, match=message) as err:
        read_rtklib_pos(path)
    assert "\n" not in str(err.value)


def test_rtklib_antenna_positions_fused_with_the_log_ins(tmp_path: Path, synthetic: Any) -> None:
    cols, times = synthetic
    llh = antenna_llh(T_POS)
    q = np.ones(T_POS.size, dtype=np.int64)
    wild = (T_POS > T0_NS + 100 * NS_PER_S) & (T_POS < T0_NS + 104 * NS_PER_S)
    q[wild] = 5  # single-point solutions, metres off
    llh[wild, 2] += 3.0
    write_pos(tmp_path / "rover.pos", T_POS, llh, q)
    t = np.sort(T0_NS + np.random.default_rng(5).integers(2 * NS_PER_S, 238 * NS_PER_S, 5000))
    traj = rtklib_trajectory(tmp_path / "rover.pos", cols, times, antenna_offset_m=G_B,
                             accept_q=(1, 2))
    dp, da = pose_errors(SYN, traj.pose_at(t))
    assert traj.pose_at(t).valid.all()
    assert dp.max() < POS_TOL_M, f"{dp.max() / MM:.3f} mm"
    assert da.max() < ATT_TOL_RAD
    loose = rtklib_trajectory(tmp_path / "rover.pos", cols, times, antenna_offset_m=G_B)
    dp_loose, _ = pose_errors(SYN, loose.pose_at(t))
    assert dp_loose.max() > 1.0  # the filter is what kept the single solutions out
    same = read_trajectory_file(tmp_path / "rover.pos", cols, times, antenna_offset_m=G_B)
    np.testing.assert_array_equal(same.pose_at(t).ins_ecef_m, loose.pose_at(t).ins_ecef_m)


# --- Applanix SBET ------------------------------------------------------------------------------

SBET_T = np.arange(T0_NS + NS_PER_S // 2, SYN.end_ns - NS_PER_S // 2, NS_PER_S // 200,
                   dtype=np.int64)


def write_sbet(path: Path, t_ns: np.ndarray, offset_b: np.ndarray | None = None) -> np.ndarray:
    """A 200 Hz SBET of the synthetic flight, 17 little-endian doubles per record in Applanix's
    order; with offset_b, of the point INS centre + R·offset. Returns the wander angle."""
    ecef, vel, r_bn, r_eb = SYN.state(t_ns)
    point = ecef if offset_b is None else ecef + r_eb @ offset_b
    lat, lon, h = geodetic(point)
    roll, pitch, heading = euler_from_body_to_ned(r_bn)
    t_s = (t_ns - T0_NS) / NS_PER_S
    wander = 0.3 + 0.01 * t_s
    platform = np.angle(np.exp(1j * (heading + wander)))  # true heading = platform − wander
    c, s = np.cos(wander), np.sin(wander)
    tow = ((t_ns % (WEEK_S * NS_PER_S)) / NS_PER_S)
    z = np.zeros(t_ns.size)
    table = np.column_stack([tow, np.radians(lat), np.radians(lon), h,
                             c * vel[:, 0] + s * vel[:, 1], -s * vel[:, 0] + c * vel[:, 1],
                             -vel[:, 2], roll, pitch, platform, wander, z, z, z, z, z, z])
    table.astype("<f8").tofile(path)
    return wander


def test_sbet_is_read_to_within_1mm_and_005arcsec(tmp_path: Path) -> None:
    write_sbet(tmp_path / "sbet_001.out", SBET_T)
    traj = sbet_trajectory(tmp_path / "sbet_001.out", T0_NS + 3 * 86400 * NS_PER_S)
    assert traj.span_ns == (int(SBET_T[0]), int(SBET_T[-1]))
    t = np.sort(T0_NS + np.random.default_rng(9).integers(NS_PER_S, 239 * NS_PER_S, 6000))
    pose = traj.pose_at(t)
    assert pose.valid.all()
    dp, da = pose_errors(SYN, pose)
    assert dp.max() < POS_TOL_M, f"{dp.max() / MM:.3f} mm"
    assert da.max() < ATT_TOL_RAD, f"{da.max() / ARCSEC:.4f} arcsec"


def test_sbet_of_the_antenna_is_shifted_to_the_ins_centre(tmp_path: Path) -> None:
    write_sbet(tmp_path / "antenna.out", SBET_T, offset_b=G_B)
    t = SBET_T[::997] + 1_234_567
    plain = sbet_trajectory(tmp_path / "antenna.out", T0_NS)
    shifted = sbet_trajectory(tmp_path / "antenna.out", T0_NS, reference_offset_m=G_B)
    dp_plain, _ = pose_errors(SYN, plain.pose_at(t))
    dp, _ = pose_errors(SYN, shifted.pose_at(t))
    assert dp_plain.min() > 1.5  # |g^b| = 1.6 m
    assert dp.max() < POS_TOL_M


def test_sbet_week_from_a_reference_within_half_a_week() -> None:
    tow = np.array([118800.0, 118800.005])  # Monday 09:00: T0, the flight's first second
    week_start = T0_NS - 9 * 3600 * NS_PER_S - 86400 * NS_PER_S  # Sunday 2026-06-14 00:00
    assert dt.date(2026, 6, 14).isoweekday() == 7
    expected = T0_NS + np.array([0, 5_000_000])
    for days in (-3.4, 0.0, 3.4):
        ref = T0_NS + round(days * 86400 * NS_PER_S)
        np.testing.assert_array_equal(sbet_times_ns(tow, ref), expected)
    rollover = np.array([604799.0, 604799.5, 0.0, 0.5])
    t = sbet_times_ns(rollover, week_start + (WEEK_S - 3600) * NS_PER_S)  # Saturday 23:00
    np.testing.assert_array_equal(np.diff(t), [NS_PER_S // 2] * 3)
    assert t[2] == week_start + WEEK_S * NS_PER_S


@pytest.mark.parametrize(("damage", "message"), [
    (lambda b: b[:100], r"sbet\.out: 100 bytes is not a whole number of 136-byte"),
    (lambda b: b"", r"sbet\.out: 0 bytes"),
    (lambda b: b[:136 * 2 + 8 * 8] + np.float64(np.nan).tobytes() + b[136 * 2 + 8 * 9:],
     r"sbet\.out: record 2 \(byte 272\): pitch \(rad\) is not finite"),
    (lambda b: b[:136] + b[272:408] + b[136:272], r"sbet\.out: record 2: time .* not increase"),
    (lambda b: b[:136 + 3 * 8] + np.float64(1e300).tobytes() + b[136 + 4 * 8:],
     r"sbet\.out: record 1: ellipsoidal height 1e\+300 m outside -10000 to 100000 m"),
])
def test_a_bad_sbet_is_one_clear_line(tmp_path: Path, damage: Any, message: str) -> None:
    path = tmp_path / "sbet.out"
    write_sbet(path, SBET_T[:3])
    path.write_bytes(damage(path.read_bytes()))
    with pytest.raises(InputError, match=message) as err:
        read_sbet(path, T0_NS)
    assert "\n" not in str(err.value)


def test_an_sbet_cut_mid_record_keeps_its_whole_records(tmp_path: Path, synthetic: Any
                                                         ) -> None:
    """An SBET logger stopped while writing: the records before the partial one are read
    (the file was refused whole before), and what was left out is said: in the report's
    warnings (georef prints them and keeps them in its summary), else as a warning."""
    path = tmp_path / "sbet.out"
    write_sbet(path, SBET_T)
    whole = read_sbet(path, T0_NS)
    assert whole.cut_note is None
    keep = SBET_T.size - 40
    path.write_bytes(path.read_bytes()[:136 * keep + 77])
    cut = read_sbet(path, T0_NS)
    assert cut.cut_note is not None
    assert "last 77 bytes are not a whole 136-byte SBET record" in cut.cut_note
    assert f"read the {keep} records before them" in cut.cut_note
    np.testing.assert_array_equal(cut.t_gps_ns, whole.t_gps_ns[:keep])
    assert cut.records.tobytes() == whole.records[:keep].tobytes()
    cols, times = synthetic
    info: dict[str, Any] = {}
    traj = read_trajectory_file(path, cols, times, antenna_offset_m=G_B, report=info)
    assert traj.span_ns == (int(SBET_T[0]), int(SBET_T[keep - 1]))
    assert info["warnings"] == [cut.cut_note]
    with pytest.warns(PartialRecordWarning, match="last 77 bytes"):
        sbet_trajectory(path, T0_NS)


def test_trajectory_file_told_apart_by_content(tmp_path: Path, synthetic: Any) -> None:
    cols, times = synthetic
    write_sbet(tmp_path / "nav.bin", SBET_T)
    traj = read_trajectory_file(tmp_path / "nav.bin", cols, times, antenna_offset_m=G_B)
    assert isinstance(traj, PiecewiseTrajectory)
    assert traj.span_ns == (int(SBET_T[0]), int(SBET_T[-1]))  # the SBET's, not the log's fixes
    assert traj.span_ns != (int(cols[Topic.GPS_FIX]["t_gps_ns"][0]),
                            int(cols[Topic.GPS_FIX]["t_gps_ns"][-1]))
    dp, _ = pose_errors(SYN, traj.pose_at(SBET_T[100:-100:50] + 1_000_000))
    assert dp.max() < POS_TOL_M
