"""UTM zones with the standard's exceptions, and central meridians against PROJ's definitions."""

import pytest
from pyproj import CRS

from sisa.core.utm import central_meridian_deg, utm_epsg, utm_zone


@pytest.mark.parametrize(("lon", "lat", "epsg"), [
    (2.17, 41.39, 32631),     # Barcelona: a regular zone
    (-70.65, -33.45, 32719),  # Santiago: south
    (5.32, 60.39, 32632),     # Bergen: 31V's western part belongs to 32
    (2.99, 60.0, 32631),      # still 31 west of 3°E
    (11.99, 63.99, 32632),    # the corner of 32V
    (12.0, 60.0, 32633),      # east of 32V: regular
    (5.32, 64.0, 32631),      # north of band V: regular
    (15.65, 78.22, 32633),    # Longyearbyen
    (8.99, 80.0, 32631), (9.0, 80.0, 32633), (20.99, 80.0, 32633), (21.0, 80.0, 32635),
    (33.0, 80.0, 32637), (41.99, 80.0, 32637),
    (42.0, 80.0, 32638),      # east of the Svalbard zones: regular
    (10.0, 84.0, 32632),      # band X ends at 84°N
    (180.0, 0.0, 32601), (-180.0, 0.0, 32601), (179.99, 0.0, 32660),
])
def test_zone_at_a_place(lon: float, lat: float, epsg: int) -> None:
    assert utm_epsg(lon, lat) == epsg


@pytest.mark.parametrize("zone", [1, 30, 31, 32, 33, 37, 60])
def test_central_meridian_is_projs(zone: int) -> None:
    op = CRS.from_epsg(32600 + zone).coordinate_operation
    assert op is not None
    (lon_0,) = [p.value for p in op.params if p.name == "Longitude of natural origin"]
    assert central_meridian_deg(zone) == pytest.approx(lon_0)


def test_the_zone_holds_the_place_except_where_the_standard_widens_it() -> None:
    """Regular zones hold their place within 3° of the central meridian; the exceptions (32V:
    3–12°E about 9°E; 31X, 33X, 35X, 37X: 12° wide) within 6°."""
    for lon in range(-180, 180, 3):
        for lat in (-60, 0, 45, 58, 62, 75, 80):
            z = utm_zone(lon + 0.5, lat)
            wide = 6.0 if 56 <= lat < 64 or 72 <= lat < 84 else 3.0
            off = (lon + 0.5 - central_meridian_deg(z) + 180.0) % 360.0 - 180.0
            assert abs(off) <= wide, (lon, lat, z)
