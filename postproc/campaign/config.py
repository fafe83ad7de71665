"""A campaign as its TOML file lists it: flights (log parts, scanner folder, DEM, sensor file,
optional trajectory and geoid) and the settings every flight shares. Relative paths are taken
from the file's folder. A folder of simulated runs is turned into the same records by the
`sisa campaign` command (it reads each run's scenario, which post-processing never does).

    [campaign]
    name = "garrotxa-2026"          # the STAC Collection's id
    title = "Garrotxa, June 2026"   # optional
    cell_m = 2.0                    # optional: one ortho cell for every flight
    crs = 32631                     # optional: one output CRS (default: each DEM's)

    [[flight]]
    name = "f01"
    log = "f01/flight.mcap"         # or a list of parts
    scanner = "f01/scanner"
    dem = "f01/dem.tif"             # or a list of DEM tiles on one grid (mosaicked in a VRT)
    sensor = "casi.toml"            # optional: a nominal CASI-501
    trajectory = "f01/rtk.pos"      # optional
    geoid_m = 49.5                  # or geoid = "egm.tif": the DEM holds orthometric heights
    leap_seconds = 18               # optional, for a .pos on UTC
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from postproc.georef import GeorefOptions, SensorModel, check_undulation_m
from sisa.core.errors import InputError

NAME_RE: Final = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
MAX_FLIGHTS: Final = 10_000
MAX_DEM_TILES: Final = 10_000
MAX_FILE_BYTES: Final = 4 << 20  # a campaign file of 10 000 flights is well under this
FLIGHT_KEYS: Final = frozenset({"name", "log", "scanner", "dem", "sensor", "trajectory",
                                "geoid", "geoid_m", "leap_seconds"})
CAMPAIGN_KEYS: Final = frozenset({"name", "title", "cell_m", "crs"})


@dataclass(frozen=True)
class FlightSpec:
    """One flight of the campaign: where its inputs are and how to georeference it.
    `sensor_text` is the sensor file's content (what a change is judged by)."""

    name: str
    log: tuple[Path, ...]
    scanner: Path
    options: GeorefOptions
    sensor_source: str  # where the sensor model came from, for the catalog
    dems: tuple[Path, ...] = ()  # DEM tiles, when several: mosaicked into a VRT at run time

    @property
    def sensor_text(self) -> str:
        return self.options.sensor.to_toml()


@dataclass(frozen=True)
class CampaignSpec:
    name: str
    title: str
    flights: tuple[FlightSpec, ...]
    source: Path  # the TOML file or the folder of runs


def check_name(name: object, where: str) -> str:
    """A name fit for a folder and a STAC id: letters, digits, '.', '_', '-', at most 64."""
    if not isinstance(name, str) or NAME_RE.fullmatch(name) is None:
        shown = repr(name)[:70]
        raise InputError(f"{where}: name {shown}: use 1-64 letters, digits, '.', '_' or '-', "
                         "starting with a letter or digit")
    return name


def load_campaign(path: Path) -> CampaignSpec:
    """The campaign TOML file `path`, checked: every flight named once, every input there
    (InputError naming the first that is not)."""
    try:
        if path.stat().st_size > MAX_FILE_BYTES:
            raise InputError(f"{path}: over {MAX_FILE_BYTES >> 20} MiB: not a campaign file")
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise InputError(f"{path}: cannot be read: {exc.strerror}") from None
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputError(f"{path}: not a TOML file: {str(exc)[:200]}") from None
    head = _table(doc.get("campaign", {}), f"{path}: [campaign]")
    _no_unknown(head, CAMPAIGN_KEYS, f"{path}: [campaign]")
    flights = doc.get("flight")
    if not isinstance(flights, list) or not flights:
        raise InputError(f"{path}: no [[flight]]: a campaign lists its flights")
    if len(flights) > MAX_FLIGHTS:
        raise InputError(f"{path}: {len(flights)} flights: at most {MAX_FLIGHTS}")
    unknown = set(doc) - {"campaign", "flight"}
    if unknown:
        raise InputError(f"{path}: unknown table {sorted(unknown)[0]!r}: [campaign] and "
                         "[[flight]] only")
    name = check_name(head.get("name", path.stem), f"{path}: [campaign]")
    cell = _number(head.get("cell_m"), f"{path}: [campaign] cell_m")
    crs = head.get("crs")
    if crs is not None and (not isinstance(crs, int) or isinstance(crs, bool) or crs <= 0):
        raise InputError(f"{path}: [campaign] crs: an EPSG code (a positive integer)")
    if cell is not None and not 0 < cell <= 10_000:
        raise InputError(f"{path}: [campaign] cell_m: a size in metres, above 0, at most "
                         "10000")
    specs = [_flight(_table(f, f"{path}: flight {k + 1}"), path.parent, cell, crs,
                     f"{path}: flight {k + 1}") for k, f in enumerate(flights)]
    check_unique([f.name for f in specs], str(path))
    title = head.get("title", name)
    if not isinstance(title, str):
        raise InputError(f"{path}: [campaign] title: a string")
    return CampaignSpec(name, title[:200], tuple(specs), path)


def check_unique(names: list[str], where: str) -> None:
    seen: set[str] = set()
    for n in names:
        if n in seen:
            raise InputError(f"{where}: flight {n!r} is listed twice")
        seen.add(n)


def _flight(raw: dict[str, Any], base: Path, cell_m: float | None, crs: int | None,
            where: str) -> FlightSpec:
    _no_unknown(raw, FLIGHT_KEYS, where)
    name = check_name(raw.get("name"), where)
    where = f"{where} ({name})"
    logs = raw.get("log")
    logs = [logs] if isinstance(logs, str) else logs
    if not isinstance(logs, list) or not logs or not all(isinstance(p, str) for p in logs):
        raise InputError(f"{where}: log: the flight log's path, or a list of its parts")
    log = tuple(_path(base, p, where, "log", "file") for p in logs)
    scanner = _path(base, raw.get("scanner"), where, "scanner", "folder")
    dem_raw = raw.get("dem")
    tiles = dem_raw if isinstance(dem_raw, list) else [dem_raw]
    if not tiles or len(tiles) > MAX_DEM_TILES:
        raise InputError(f"{where}: dem: a DEM, or a list of 1 to {MAX_DEM_TILES} DEM tiles")
    dems = tuple(_path(base, d, where, "dem", "file") for d in tiles)
    dem = dems[0]  # several: the runner puts their VRT mosaic in its place
    sensor_path = (None if raw.get("sensor") is None else
                   _path(base, raw["sensor"], where, "sensor", "file"))
    sensor = SensorModel() if sensor_path is None else SensorModel.load(sensor_path)
    trajectory = (None if raw.get("trajectory") is None else
                  _path(base, raw["trajectory"], where, "trajectory", "file"))
    geoid: Path | float | None = None
    if raw.get("geoid") is not None and raw.get("geoid_m") is not None:
        raise InputError(f"{where}: geoid and geoid_m: one or the other")
    if raw.get("geoid") is not None:
        geoid = _path(base, raw["geoid"], where, "geoid", "file")
    elif (g := _number(raw.get("geoid_m"), f"{where}: geoid_m")) is not None:
        check_undulation_m(g, f"{where}: geoid_m")
        geoid = g
    leap = raw.get("leap_seconds")
    if leap is not None and (not isinstance(leap, int) or isinstance(leap, bool)
                             or not 0 <= leap <= 60):
        raise InputError(f"{where}: leap_seconds: GPS - UTC, 0 to 60")
    options = GeorefOptions(sensor=sensor, dem=dem, geoid=geoid, epsg=crs, cell_m=cell_m,
                            trajectory=trajectory, leap_seconds=leap)
    source = str(sensor_path) if sensor_path is not None else "a nominal CASI-501"
    return FlightSpec(name, log, scanner, options, source, dems if len(dems) > 1 else ())


def _table(value: object, where: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise InputError(f"{where}: a table")
    return value


def _no_unknown(table: dict[str, Any], known: frozenset[str], where: str) -> None:
    unknown = sorted(set(table) - known)
    if unknown:
        raise InputError(f"{where}: unknown key {unknown[0][:40]!r} (known: "
                         f"{', '.join(sorted(known))})")


def _number(value: object, where: str) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InputError(f"{where}: a number")
    return float(value)


def _path(base: Path, value: object, where: str, key: str, kind: str) -> Path:
    if not isinstance(value, str) or not value:
        raise InputError(f"{where}: {key}: a path")
    path = base / value
    ok = path.is_dir() if kind == "folder" else path.is_file()
    if not ok:
        raise InputError(f"{where}: {key} {path}: no such {kind}")
    return path
