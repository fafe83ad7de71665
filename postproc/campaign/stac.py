"""The campaign as a STAC catalog (pystac): a Collection for the campaign, with its mosaics as
assets, and an Item per segment: its footprint, its time span, the instrument and how it was
processed (sensor file, calibration, accuracy figures, the task keys it was made under), and
its products as assets. Written whole (a scratch folder renamed into OUT/stac) and validated
offline: pystac's bundled core schemas plus the projection extension's schema, vendored in
`schemas/` (stac-extensions/projection v2.0.0, Apache-2.0); nothing is fetched over the
network.

STAC datetimes are UTC: GPS time minus the leap seconds (the flight's, when its settings give
them, else the IERS count at that date, `LEAP_SECONDS`). The exact GPS nanoseconds are kept in
`sisa:t_first_gps_ns` / `sisa:t_last_gps_ns`.
"""

from __future__ import annotations

import datetime as dt
import json
import shutil
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

from postproc.campaign.runner import CampaignRun, FlightRun, MosaicRun
from sisa.core.outdir import partial_path, replace_dir
from sisa.core.timescale import gps_ns_from_datetime, utc_datetime_from_gps_ns

if TYPE_CHECKING:
    import pystac

PROJECTION: Final = "https://stac-extensions.github.io/projection/v2.0.0/schema.json"
COG_TYPE: Final = "image/tiff; application=geotiff; profile=cloud-optimized"
INSTRUMENT: Final = "casi-501"
# GPS - UTC from each date on (IERS Bulletin C); 18 s since 2017-01-01, none announced since
LEAP_SECONDS: Final = (
    ("1981-07-01", 1), ("1982-07-01", 2), ("1983-07-01", 3), ("1985-07-01", 4),
    ("1988-01-01", 5), ("1990-01-01", 6), ("1991-01-01", 7), ("1992-07-01", 8),
    ("1993-07-01", 9), ("1994-07-01", 10), ("1996-01-01", 11), ("1997-07-01", 12),
    ("1999-01-01", 13), ("2006-01-01", 14), ("2009-01-01", 15), ("2012-07-01", 16),
    ("2015-07-01", 17), ("2017-01-01", 18))


def leap_seconds_at(t_gps_ns: int) -> int:
    """GPS - UTC at a GPS time, from the table (0 before the first leap second)."""
    count = 0
    for day, n in LEAP_SECONDS:
        start = gps_ns_from_datetime(dt.datetime.fromisoformat(day)) + n * 1_000_000_000
        if t_gps_ns >= start:
            count = n
    return count


def _utc(t_gps_ns: int, leap: int | None) -> dt.datetime:
    return utc_datetime_from_gps_ns(t_gps_ns, leap_seconds_at(t_gps_ns) if leap is None
                                    else leap)


def write_catalog(run: CampaignRun) -> Path:
    """OUT/stac/collection.json and an Item per segment made, validated; its path."""
    import pystac

    final = run.out / "stac"
    scratch = partial_path(final)
    shutil.rmtree(scratch, ignore_errors=True)
    scratch.mkdir(parents=True)
    try:
        collection = _collection(run, scratch)
        collection.set_self_href(str(scratch / "collection.json"))
        for item in collection.get_items(recursive=True):
            item.set_self_href(str(scratch / item.properties["sisa:flight"] / f"{item.id}.json"))
        collection.make_all_asset_hrefs_relative()
        collection.save(catalog_type=pystac.CatalogType.SELF_CONTAINED)
        validate_catalog(scratch / "collection.json")
        if final.exists():
            replace_dir(scratch, final)
        else:
            scratch.rename(final)
    except BaseException:
        shutil.rmtree(scratch, ignore_errors=True)
        raise
    return final / "collection.json"


def _collection(run: CampaignRun, root: Path) -> pystac.Collection:
    import pystac

    items = [item for fl in run.flights.values() for item in _items(run, fl)]
    bboxes = [i.bbox for i in items if i.bbox is not None]
    bbox = ([min(b[0] for b in bboxes), min(b[1] for b in bboxes),
             max(b[2] for b in bboxes), max(b[3] for b in bboxes)] if bboxes
            else [-180.0, -90.0, 180.0, 90.0])
    starts = [i.common_metadata.start_datetime for i in items]
    ends = [i.common_metadata.end_datetime for i in items]
    interval = [min(s for s in starts if s is not None) if any(starts) else None,
                max(e for e in ends if e is not None) if any(ends) else None]
    collection = pystac.Collection(
        id=run.spec.name, title=run.spec.title,
        description=f"SISA campaign {run.spec.name}: {len(run.flights)} flights of a pushbroom "
                    "scanner, directly georeferenced (INS + GPS) and orthorectified, segment "
                    "by segment",
        extent=pystac.Extent(pystac.SpatialExtent([bbox]),
                             pystac.TemporalExtent([interval])),
        license="other", stac_extensions=[PROJECTION],
        extra_fields={"sisa:failures": run.failures(),
                      "sisa:flights": sorted(run.flights)})
    collection.summaries.add("instruments", [INSTRUMENT])
    for m in run.mosaics.values():
        _mosaic_assets(collection, run, m)
    collection.add_items(items)
    return collection


def _mosaic_assets(collection: pystac.Collection, run: CampaignRun, m: MosaicRun) -> None:
    import pystac

    if m.outcome is None or not m.outcome.ok:
        return
    rec = m.outcome.record
    folder = run.out / "mosaics"
    collection.add_asset(m.name, pystac.Asset(
        str(folder / rec["mosaic"]), media_type=COG_TYPE, roles=["data"],
        title=f"mosaic of {len(m.members)} segments, EPSG:{m.epsg}, {m.cell_m:g} m",
        extra_fields={"proj:code": f"EPSG:{m.epsg}", "proj:shape": rec["shape"],
                      "proj:transform": rec["transform"], "sisa:task_key": m.key}))
    collection.add_asset(f"{m.name}_quicklook", pystac.Asset(
        str(folder / rec["quicklook"]), media_type=pystac.MediaType.PNG, roles=["overview"]))


def _items(run: CampaignRun, fl: FlightRun) -> list[pystac.Item]:
    import pystac

    out: list[pystac.Item] = []
    opt = fl.spec.options
    leap = opt.leap_seconds if opt.leap_seconds is not None else opt.leap_seconds_fallback
    registration = (fl.finish.record.get("strip_registration", [])
                    if fl.finish is not None and fl.finish.ok else [])
    for s, o in sorted(fl.orthos.items()):
        if not o.ok:
            continue
        seg, ortho = o.record["segment"], o.record.get("ortho")
        feature = o.record.get("footprint") or {}
        geometry = feature.get("geometry")
        t0, t1 = int(seg["t_first_gps_ns"]), int(seg["t_last_gps_ns"])
        props = _properties(fl, seg, s, registration)
        props["start_datetime"] = _utc(t0, leap).isoformat().replace("+00:00", "Z")
        props["end_datetime"] = _utc(t1, leap).isoformat().replace("+00:00", "Z")
        item = pystac.Item(
            id=f"{fl.spec.name}-segment_{s:03d}", geometry=geometry,
            bbox=_bbox(geometry), datetime=None, properties=props,
            stac_extensions=[PROJECTION])
        item.common_metadata.start_datetime = _utc(t0, leap)
        item.common_metadata.end_datetime = _utc(t1, leap)
        if ortho is not None:
            w, so, e, n = ortho["bounds"]
            props.update({"proj:code": f"EPSG:{fl.epsg}", "proj:bbox": [w, so, e, n],
                          "proj:shape": ortho["shape"], "proj:transform": ortho["transform"],
                          "gsd": fl.cell_m})
        _assets(item, fl, seg["files"])
        out.append(item)
    return out


def _properties(fl: FlightRun, seg: dict[str, Any], s: int,
                registration: list[dict[str, Any]]) -> dict[str, Any]:
    sensor = fl.spec.options.sensor
    rays = max(int(seg["rays"]), 1)
    return {
        "instruments": [INSTRUMENT], "sisa:flight": fl.spec.name, "sisa:segment": s,
        "sisa:t_first_gps_ns": int(seg["t_first_gps_ns"]),
        "sisa:t_last_gps_ns": int(seg["t_last_gps_ns"]),
        "sisa:sensor": sensor.name, "sisa:sensor_file": fl.spec.sensor_source,
        "sisa:calibration": {
            "boresight_arcsec": list(sensor.mounting.boresight_arcsec),
            "lever_arm_m": list(sensor.mounting.lever_arm_m),
            "antenna_offset_m": list(sensor.mounting.antenna_offset_m),
            "time_delay_ms": sensor.time_delay_ms},
        "sisa:processing": {
            "dem": str(fl.spec.options.dem), "crs": f"EPSG:{fl.epsg}", "cell_m": fl.cell_m,
            "trajectory": str(fl.spec.options.trajectory or "flight log"),
            "vertical": "ellipsoidal (WGS 84)" if fl.spec.options.geoid is None
            else "ellipsoidal (DEM + geoid)"},
        "sisa:accuracy": {
            "lines": seg["lines"], "lines_timed": seg["lines_timed"],
            "lines_georeferenced": seg["lines_georeferenced"],
            "pixels_on_dem_pct": round(100.0 * int(seg["rays_hit"]) / rays, 4),
            "gsd_across_m": seg["gsd_across_m"], "gsd_along_m": seg["gsd_along_m"],
            "strip_registration": [r for r in registration if s in r["segments"]]},
        "sisa:task_keys": {"sync": fl.sync_key, "georef": fl.cast_keys.get(s, ""),
                           "ortho": fl.ortho_keys.get(s, "")},
    }


_ASSETS: Final = (  # key in the record's files, asset key, media type, roles
    ("ortho", "ortho", COG_TYPE, ["data"]),
    ("igm", "igm", "application/octet-stream", ["data", "georeferencing"]),
    ("glt", "glt", "application/octet-stream", ["data", "georeferencing"]),
    ("geolocation_vrt", "geolocation_vrt", "application/xml", ["georeferencing"]),
    ("quicklook", "quicklook", "image/png", ["overview"]),
    ("eo", "eo", "text/csv", ["metadata"]),
)


def _assets(item: pystac.Item, fl: FlightRun, files: dict[str, str]) -> None:
    import pystac

    for name, key, media, roles in _ASSETS:
        if name in files:
            item.add_asset(key, pystac.Asset(str(fl.out / files[name]), media_type=media,
                                             roles=roles))
            if name in ("igm", "glt"):
                hdr = Path(files[name]).with_suffix(".hdr")
                item.add_asset(f"{key}_header", pystac.Asset(
                    str(fl.out / hdr), media_type="text/plain", roles=["metadata"]))
    item.add_asset("footprints", pystac.Asset(
        str(fl.out / "footprints.geojson"), media_type=pystac.MediaType.GEOJSON,
        roles=["metadata"], title="swath outlines of the flight's segments"))


def _bbox(geometry: dict[str, Any] | None) -> list[float] | None:
    if not geometry:
        return None
    ring = geometry["coordinates"][0]
    lons, lats = [p[0] for p in ring], [p[1] for p in ring]
    return [min(lons), min(lats), max(lons), max(lats)]


# --- offline validation ------------------------------------------------------------------

def validate_catalog(collection_json: Path) -> int:
    """Validate the collection and every item against the STAC core schemas and the
    projection extension's, offline (pystac.errors.STACValidationError naming the first that
    fails); how many objects were validated."""
    import pystac

    validator = offline_validator()
    collection = pystac.Collection.from_file(str(collection_json))
    collection.validate(validator=validator)
    count = 1
    for item in collection.get_items(recursive=True):
        item.validate(validator=validator)
        count += 1
    return count


def offline_validator() -> Any:
    """pystac's JSON-schema validator with every schema it may need already in its cache, and
    any other refused rather than fetched."""
    from pystac.validation.stac_validator import GetSchemaError, JsonSchemaSTACValidator

    class Offline(JsonSchemaSTACValidator):
        def _get_schema(self, schema_uri: str) -> dict[str, Any]:
            if schema_uri not in self.schema_cache:
                raise GetSchemaError(schema_uri, LookupError("not bundled (no network use)"))
            return self.schema_cache[schema_uri]

    validator = Offline()
    text = resources.files("postproc.campaign").joinpath(
        "schemas/projection-v2.0.0.json").read_text(encoding="utf-8")
    validator.schema_cache[PROJECTION] = json.loads(text)
    return validator
