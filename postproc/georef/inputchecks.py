"""What is refused or said of a job's inputs before it starts: the output CRS (projected, in
metres; its grid's scale, north and datum at the DEM's centre), a DEM or geoid raster of several
bands, a geoid undulation no geoid has, --leap-seconds without a trajectory file."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Final

from pyproj import CRS, Proj, Transformer
from pyproj.transformer import AreaOfInterest

from postproc.georef.dem import band_note, check_undulation_m
from postproc.georef.jobrecords import GeorefOptions
from sisa.core.errors import InputError
from sisa.core.utm import utm_epsg

GRID_SCALE_TOLERANCE: Final = 0.01  # UTM stays within 0.2 % even a zone away
# a transverse Mercator (UTM) used this far in longitude from its central meridian is said:
# a zone away is 9° at most; beyond 90° the grid is true again in scale, turned upside down
CENTRAL_MERIDIAN_MAX_DEG: Final = 10.0


def input_notes(options: GeorefOptions) -> list[str]:
    """What to say of the inputs before the job starts (and the InputError of a geoid
    undulation no geoid has): a DEM or geoid raster of several bands (band 1 is read), and
    --leap-seconds without a trajectory file (the log's navigation is on GPS time: it changed
    nothing, silently)."""
    notes = [band_note(options.dem, "DEM")]
    if isinstance(options.geoid, Path):
        notes.append(band_note(options.geoid, "geoid"))
    elif options.geoid is not None:
        check_undulation_m(float(options.geoid), "geoid undulation")
    if options.leap_seconds is not None and options.trajectory is None:
        notes.append(f"--leap-seconds {options.leap_seconds}: not used: it applies to a "
                     "--trajectory .pos on UTC or JST, and the flight log's navigation is on "
                     "GPS time")
    return [note for note in notes if note is not None]


def check_output_crs(epsg: int) -> CRS:
    """The output CRS of an EPSG code: projected, every axis in metres; else InputError."""
    if epsg <= 0:
        raise InputError(f"EPSG:{epsg}: not a valid EPSG code (a positive integer)")
    try:
        crs = CRS.from_epsg(epsg)
    except Exception:  # pyproj raises CRSError subclasses of several kinds
        raise InputError(f"EPSG:{epsg}: unknown CRS") from None
    if not crs.is_projected:
        raise InputError(f"EPSG:{epsg} ({crs.name}): products need a projected CRS (metres)")
    units = {(a.unit_name, a.unit_conversion_factor) for a in crs.axis_info}
    if not units or any(factor != 1.0 for _, factor in units):
        said = ", ".join(sorted({name for name, _ in units})) or "none"
        raise InputError(f"EPSG:{epsg} ({crs.name}): axes in {said}: products need a projected "
                         "CRS in metres")
    return crs


def crs_notes(crs: CRS, dem_epsg: int, dem_bounds: tuple[float, float, float, float]
              ) -> list[str]:
    """What to say of the output CRS at the DEM's centre (`grid_scale_note`,
    `datum_shift_note`): nothing when its grid is ground metres there and PROJ knows the
    datum shift."""
    centre = _dem_centre_lon_lat(dem_epsg, dem_bounds)
    notes = grid_scale_note(crs, *centre), datum_shift_note(crs, *centre)
    return [note for note in notes if note is not None]


def _dem_centre_lon_lat(dem_epsg: int, dem_bounds: tuple[float, float, float, float]
                        ) -> tuple[float, float]:
    """Where the notes on the output CRS look: the DEM's centre (lon, lat in degrees)."""
    w, s, e, n = dem_bounds
    lon, lat = Transformer.from_crs(dem_epsg, 4326, always_xy=True).transform(
        (w + e) / 2, (s + n) / 2)
    return float(lon), float(lat)


def grid_scale_note(crs: CRS, lon: float, lat: float) -> str | None:
    """A warning when a metre of the output grid is not a metre on the ground at the DEM's
    centre (EPSG:3857 at 42°N: 0.74 m), naming the scale and the UTM zone there; else None.
    Products stay right in the grid's own coordinates, but their cell sizes, GSDs and
    distances are grid metres, which users take for ground metres. A transverse Mercator
    far from its central meridian is said by `central_meridian_note` instead."""
    if (far := central_meridian_note(crs, lon, lat)) is not None:
        return far
    factors = Proj(crs).get_factors(lon, lat)
    scales = (factors.meridional_scale, factors.parallel_scale)
    if all(abs(k - 1) <= GRID_SCALE_TOLERANCE for k in scales) or not all(
            math.isfinite(k) and k > 0 for k in scales):
        return None
    k = max(scales, key=lambda v: abs(v - 1))
    return (f"EPSG:{crs.to_epsg()} ({crs.name}): a metre of its grid is {1 / k:.3f} m on the "
            f"ground at the DEM's centre ({lat:.2f}°, {lon:.2f}°): cell sizes, GSDs and "
            f"distances in the products are grid metres; UTM there (--crs {utm_epsg(lon, lat)}) "
            "keeps them within 0.1 %")


def _central_meridian_deg(crs: CRS) -> float | None:
    """The central meridian (degrees) of a transverse Mercator CRS; None for any other."""
    op = crs.coordinate_operation
    if op is None or "transverse mercator" not in op.method_name.lower():
        return None
    for param in op.params:
        if param.name in ("Longitude of natural origin", "Longitude of origin"):
            return math.degrees(float(param.value) * param.unit_conversion_factor)
    return None


def central_meridian_note(crs: CRS, lon: float, lat: float) -> str | None:
    """A warning when a transverse Mercator CRS (UTM) is used more than
    CENTRAL_MERIDIAN_MAX_DEG of longitude from its central meridian at the DEM's centre; else
    None. Its grid then turns from north and stretches; and across 90° the scale comes back to
    1 (the scale note said nothing) with the grid upside down: UTM zone 1 over a site at 2°E
    gave products turned by 180°, northings of 15 390 km."""
    lon0 = _central_meridian_deg(crs)
    if lon0 is None or not (math.isfinite(lon) and math.isfinite(lat)):
        return None
    dlon = (lon - lon0 + 180.0) % 360.0 - 180.0
    if abs(dlon) <= CENTRAL_MERIDIAN_MAX_DEG:
        return None
    head = (f"EPSG:{crs.to_epsg()} ({crs.name}): the DEM's centre ({lat:.2f}°, {lon:.2f}°) is "
            f"{abs(dlon):.0f}° of longitude from its central meridian ({lon0:g}°)")
    factors = Proj(crs).get_factors(lon, lat)
    turn, scale = factors.meridian_convergence, factors.meridional_scale
    if abs(dlon) > 90.0:
        _, northing = Transformer.from_crs(4326, crs, always_xy=True).transform(lon, lat)
        said = (f"on the far side of the projection: the products come out turned by "
                f"{abs(turn):.0f}° (northings of {northing / 1000:.0f} km)")
    elif math.isfinite(turn) and math.isfinite(scale) and scale > 0:
        said = (f"its grid north is {abs(turn):.0f}° from true north there and a metre of its "
                f"grid {1 / scale:.3f} m on the ground")
    else:
        said = "where its grid is far from true"
    return f"{head}, {said}: UTM there is --crs {utm_epsg(lon, lat)}"


def datum_shift_note(crs: CRS, lon: float, lat: float) -> str | None:
    """A warning when PROJ knows no shift between WGS 84 (the GPS's datum) and the output
    CRS's datum at the DEM's centre, a CRS used far outside its area of use (OSGB36's British
    grid over Catalonia): PROJ then takes the two datums for one (its "ballpark" offset), and
    the products can be metres to hundreds of metres off; else None."""
    if not (math.isfinite(lon) and math.isfinite(lat)):
        return None
    near = AreaOfInterest(lon - 0.01, lat - 0.01, lon + 0.01, lat + 0.01)
    shift = Transformer.from_crs(4326, crs, always_xy=True, area_of_interest=near)
    if "ballpark" not in shift.description.lower():
        return None
    datum = crs.datum.name if crs.datum is not None else "its datum"
    return (f"EPSG:{crs.to_epsg()} ({crs.name}): PROJ knows no shift from WGS 84 to {datum} "
            f"at the DEM's centre ({lat:.2f}°, {lon:.2f}°), far from where this CRS is used, "
            f"and takes the two datums for one: the products can be metres to hundreds of "
            f"metres off; UTM there (--crs {utm_epsg(lon, lat)}) needs no shift")
