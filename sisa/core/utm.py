"""The UTM zone of a place on WGS 84, with the standard's zone exceptions (south-western Norway,
Svalbard), so that the emulators' terrain, the post-processor's default grid and its advice all
name the same zone. EPSG's own areas of use for the UTM CRSs are the regular 6° bands, so
pyproj's database query cannot give the exceptions."""

from __future__ import annotations

_SVALBARD_ZONES = ((9.0, 31), (21.0, 33), (33.0, 35), (42.0, 37))  # (east limit °E, zone)


def utm_zone(lon_deg: float, lat_deg: float) -> int:
    """UTM zone number 1–60 at (lon, lat) degrees: 6° bands from 180°W, but 32 over 3–12°E
    between 56 and 64°N (band V, Norway), and 31/33/35/37 over 0–42°E between 72 and 84°N
    (band X, Svalbard)."""
    if 56.0 <= lat_deg < 64.0 and 3.0 <= lon_deg < 12.0:
        return 32
    if 72.0 <= lat_deg < 84.0 and 0.0 <= lon_deg < 42.0:
        return next(zone for east, zone in _SVALBARD_ZONES if lon_deg < east)
    return int((lon_deg + 180.0) // 6.0) % 60 + 1


def utm_epsg(lon_deg: float, lat_deg: float) -> int:
    """EPSG code of the WGS 84 UTM CRS at (lon, lat) degrees (326zz north, 327zz south)."""
    return (32600 if lat_deg >= 0 else 32700) + utm_zone(lon_deg, lat_deg)


def central_meridian_deg(zone: int) -> float:
    """Longitude of a UTM zone's central meridian, degrees."""
    return 6.0 * zone - 183.0
