"""Exterior orientation per scan line (postproc.georef.exterior) against hand-worked cases and
independent rotations (scipy's Euler sequences, closed-form WGS84), and its CSV table."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from scipy.spatial.transform import Rotation

from postproc.georef import Pose, nav_from_columns
from postproc.georef.exterior import exterior_orientation, write_eo_csv
from sisa.core.frames import body_to_ned_matrix, ned_to_ecef_matrix
from sisa.core.sensor import Mounting
from sisa.core.timescale import NS_PER_S
from tests.postproc.test_navigation import (
    G_B,
    H0,
    LAT0,
    LON0,
    MM,
    SYN,
    T0_NS,
    geodetic,
    wgs84_ecef,
)

ARCSEC = math.pi / (180 * 3600)


@dataclass(frozen=True)
class Stub:
    """Flies north along the origin's meridian direction at speed_mps with a fixed attitude;
    poses valid on [T0, T0 + 100 s]."""

    roll_deg: float = 0.0
    pitch_deg: float = 0.0
    heading_deg: float = 0.0
    speed_mps: float = 0.0

    @property
    def span_ns(self) -> tuple[int, int]:
        return T0_NS, T0_NS + 100 * NS_PER_S

    def pose_at(self, t_gps_ns: npt.ArrayLike) -> Pose:
        t = np.asarray(t_gps_ns, dtype=np.int64)
        north0 = ned_to_ecef_matrix(math.radians(LAT0), math.radians(LON0))[:, 0]
        ins = wgs84_ecef(LAT0, LON0, H0) + np.outer(self.speed_mps * (t - T0_NS) / NS_PER_S,
                                                    north0)
        lat, lon, _ = geodetic(ins)
        r_bn = body_to_ned_matrix(*np.radians([self.roll_deg, self.pitch_deg, self.heading_deg]))
        r_eb = ned_to_ecef_matrix(np.radians(lat), np.radians(lon)) @ r_bn
        valid = (t >= self.span_ns[0]) & (t <= self.span_ns[1])
        ins[~valid], r_eb[~valid] = np.nan, np.nan
        return Pose(t, ins, r_eb, valid)


T_MID = np.array([T0_NS + 50 * NS_PER_S])


def _ned_unit(k: int) -> np.ndarray:
    """North (0), east (1) or down (2) at the origin, closed form."""
    lat, lon = math.radians(LAT0), math.radians(LON0)
    sl, cl, so, co = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
    return np.array([[-sl * co, -sl * so, cl], [-so, co, 0.0], [-cl * co, -cl * so, -sl]][k])


def test_a_lever_arm_down_puts_the_perspective_centre_below_the_ins() -> None:
    eo = exterior_orientation(Stub(), T_MID, Mounting(lever_arm_m=(0.0, 0.0, 0.3)))
    assert eo.valid.all()
    assert eo.lat_deg[0] == pytest.approx(LAT0, abs=1e-10)
    assert eo.lon_deg[0] == pytest.approx(LON0, abs=1e-10)
    assert eo.height_m[0] == pytest.approx(H0 - 0.3, abs=1e-6)


def test_a_lever_arm_forward_while_heading_east_puts_it_east() -> None:
    eo = exterior_orientation(Stub(heading_deg=90.0), T_MID,
                              Mounting(lever_arm_m=(1.0, 0.0, 0.0)))
    d = eo.centre_ecef_m[0] - wgs84_ecef(LAT0, LON0, H0)
    assert d @ _ned_unit(1) == pytest.approx(1.0, abs=1e-6)
    assert abs(d @ _ned_unit(0)) < 1e-6
    assert abs(d @ _ned_unit(2)) < 1e-6


def test_camera_rotation_is_the_product_of_full_matrices() -> None:
    stub = Stub(roll_deg=10.0, pitch_deg=-5.0, heading_deg=359.99)
    bore = (30.0, -20.0, 100.0)
    eo = exterior_orientation(stub, T_MID, Mounting(boresight_arcsec=bore))
    r_bn = Rotation.from_euler("ZYX", [359.99, -5.0, 10.0], degrees=True).as_matrix()
    r_ne = np.stack([_ned_unit(k) for k in range(3)], axis=1)
    r_cb = np.diag([1.0, -1.0, -1.0]) @ Rotation.from_euler(
        "XYZ", np.array(bore) * ARCSEC).as_matrix()
    np.testing.assert_allclose(eo.r_ecef_from_camera[0], r_ne @ r_bn @ r_cb, atol=1e-12)
    assert math.degrees(eo.roll_rad[0]) == pytest.approx(10.0, abs=1e-9)
    assert math.degrees(eo.pitch_rad[0]) == pytest.approx(-5.0, abs=1e-9)
    assert math.degrees(eo.heading_rad[0]) == pytest.approx(359.99, abs=1e-9)


def test_the_nadir_pixel_of_a_level_scanner_looks_down() -> None:
    eo = exterior_orientation(Stub(heading_deg=123.0), T_MID, Mounting())
    look = eo.r_ecef_from_camera[0] @ np.array([0.0, 0.0, -1.0])
    np.testing.assert_allclose(look, _ned_unit(2), atol=1e-12)
    left = eo.r_ecef_from_camera[0] @ np.array([0.0, 1.0, 0.0])  # camera y: left of the track
    h = math.radians(123.0)
    right_of_track = math.cos(h + math.pi / 2) * _ned_unit(0) + math.sin(h + math.pi / 2) \
        * _ned_unit(1)
    np.testing.assert_allclose(left, -right_of_track, atol=1e-12)


def test_time_delay_samples_the_navigation_later() -> None:
    stub = Stub(speed_mps=100.0)
    t = np.array([T0_NS + 10 * NS_PER_S, -1, T0_NS + 100 * NS_PER_S])
    now = exterior_orientation(stub, t, Mounting())
    later = exterior_orientation(stub, t, Mounting(), time_delay_ns=10_000_000)
    assert now.valid.tolist() == [True, False, True]
    assert later.valid.tolist() == [True, False, False]  # 10 ms past the end of the span
    assert later.t_gps_ns.tolist() == [t[0] + 10_000_000, -1, t[2] + 10_000_000]
    moved = later.centre_ecef_m[0] - now.centre_ecef_m[0]
    assert moved @ _ned_unit(0) == pytest.approx(1.0, abs=1e-6)  # 10 ms at 100 m/s
    assert np.isnan(later.centre_ecef_m[1:]).all()
    assert np.isnan(later.lat_deg[1:]).all()
    early = exterior_orientation(stub, np.array([-1]), Mounting(), time_delay_ns=T0_NS + 1)
    assert not early.valid[0]  # a line without time never borrows one from the delay


def test_exterior_orientation_on_the_navigation_solution() -> None:
    cols, times = SYN.columns()
    traj = nav_from_columns(cols, times, antenna_offset_m=G_B)
    mounting = Mounting(lever_arm_m=(0.8, -0.3, 0.4), antenna_offset_m=tuple(G_B))
    t = np.sort(T0_NS + np.random.default_rng(2).integers(2 * NS_PER_S, 238 * NS_PER_S, 3000))
    eo = exterior_orientation(traj, t, mounting)
    ecef, _, r_bn, r_eb = SYN.state(t)
    truth = ecef + r_eb @ np.array(mounting.lever_arm_m)
    assert eo.valid.all()
    assert np.linalg.norm(eo.centre_ecef_m - truth, axis=1).max() < 1.0 * MM
    err = np.angle(np.exp(1j * (eo.heading_rad - np.arctan2(r_bn[:, 1, 0], r_bn[:, 0, 0]))))
    assert np.abs(err).max() < 0.05 * ARCSEC


def test_eo_csv_names_every_column_and_unit(tmp_path: Path) -> None:
    stub = Stub(roll_deg=2.0, pitch_deg=1.0, heading_deg=181.5, speed_mps=60.0)
    t = T0_NS + np.array([1, 2, 3, -1, 4], dtype=np.int64) * NS_PER_S
    t[3] = -1
    eo = exterior_orientation(stub, t, Mounting(lever_arm_m=(0.1, 0.2, 0.3)))
    path = tmp_path / "segment_003_eo.csv"
    write_eo_csv(path, 3, np.arange(5), eo)
    text = path.read_text(encoding="utf-8")
    header = [ln for ln in text.splitlines() if ln.startswith("#")]
    table = np.genfromtxt(path, delimiter=",", names=True, skip_header=len(header))
    names = table.dtype.names
    assert names is not None
    assert len(names) == 22
    for name in names:  # every column is explained in the commented header, with its unit
        assert any(name in ln for ln in header), name
    assert all(n.endswith(("_m", "_deg", "_ns")) for n in names if n not in {
        "segment", "line", "valid", *(f"r{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3))})
    assert (table["segment"] == 3).all()
    np.testing.assert_array_equal(table["line"], np.arange(5))
    np.testing.assert_array_equal(table["valid"], [1, 1, 1, 0, 1])
    assert table["t_gps_ns"][3] == -1
    assert np.isnan(table["x_ecef_m"][3])
    ok = eo.valid
    np.testing.assert_allclose(table["x_ecef_m"][ok], eo.centre_ecef_m[ok, 0], atol=1e-4)
    np.testing.assert_allclose(table["lat_deg"][ok], eo.lat_deg[ok], atol=1e-10)
    np.testing.assert_allclose(table["heading_deg"][ok], np.degrees(eo.heading_rad[ok]),
                               atol=1e-8)
    np.testing.assert_allclose(table["r23"][ok], eo.r_ecef_from_camera[ok, 1, 2], atol=1e-12)
    ints = [ln.split(",")[2] for ln in text.splitlines() if not ln.startswith("#")][1:]
    assert [int(x) for x in ints] == t.tolist()  # GPS ns exactly, not through a float
