"""IGM files: the ground position of every pixel centre of a segment, laid out as APL's IGM.

NERC-ARF APL (aplcorr, apltran) writes the IGM of a level-1 image as a 3-band float64 ENVI BIL
with one IGM line per image line and one sample per pixel: band 1 X (easting), band 2 Y
(northing), band 3 height. SISA writes the same layout, so APL's aplmap, ENVI's "Georeference
from IGM" and GDAL's geolocation arrays (through `write_geolocation_vrt`) all read it.

Big files are read with plain file reads by blocks of lines (`EnviRaster.read_lines`): a
memmap would keep every page it touched in the process's resident memory.
"""

from __future__ import annotations

import math
import os
import re
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from fractions import Fraction
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO, Final

import numpy as np
import numpy.typing as npt
import rasterio
from rasterio.crs import CRS
from rasterio.enums import WktVersion
from rasterio.errors import CRSError, NotGeoreferencedWarning, RasterioIOError

from sisa.core.errors import InputError
from sisa.core.outdir import create_partial, write_whole

F64 = npt.NDArray[np.float64]

IGM_BAND_NAMES: Final = ("Easting", "Northing", "Height")
IGM_BLOCK_LINES: Final = 2048
ENVI_DATA_TYPES: Final = {"uint8": 1, "int16": 2, "int32": 3, "float32": 4, "float64": 5,
                          "uint16": 12, "uint32": 13, "int64": 14, "uint64": 15}
GDAL_TYPE_NAMES: Final = {"uint8": "Byte", "int8": "Int8", "uint16": "UInt16", "int16": "Int16",
                          "uint32": "UInt32", "int32": "Int32", "uint64": "UInt64",
                          "int64": "Int64", "float32": "Float32", "float64": "Float64"}
_INTERLEAVES: Final = ("bil", "bsq", "bip")
_WAVELENGTH_SCALE_TO_NM: Final = {"nanometers": 1.0, "nm": 1.0, "micrometers": 1e3,
                                  "microns": 1e3, "um": 1e3, "millimeters": 1e6}
_BYTE_ORDERS: Final = {"0": "<", "1": ">"}  # ENVI: 0 little-endian (LSF), 1 big-endian (MSF)
LAYOUT_DENOMINATORS: Final = 16  # see _layout_hint


# -- ENVI rasters on disk --------------------------------------------------------------------

class CutShortWarning(UserWarning):
    """A raster file holds fewer lines than its header says; the lines it holds are used."""


class HeaderBehindWarning(UserWarning):
    """A raster file holds whole lines past its header's count (a recording stopped between
    writing a block and rewriting its header); every line it holds is used."""


def _header_offset(path: Path, text: str) -> int:
    """The header's `header offset`: a whole number of bytes, or an InputError naming it."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 0 and value == int(value)):
        raise InputError(f"{path}: ENVI header offset {text.strip()!r} is not a whole number "
                         "of bytes")
    return int(value)


@dataclass(frozen=True)
class EnviRaster:
    """Where the numbers of an ENVI raster lie in its file, from its header (read by GDAL)."""

    path: Path
    lines: int
    bands: int
    pixels: int
    dtype: np.dtype[Any]  # with the file's byte order
    interleave: str  # bil | bsq | bip
    header_offset: int
    nodata: float | None
    band_names: tuple[str, ...]
    wavelengths_nm: tuple[float | None, ...]
    envi: dict[str, str]  # the header's fields as GDAL parsed them (keys with underscores)
    header_lines: int = -1  # lines the header declares; more than `lines` in a file cut short
    file_bytes: int = -1  # the file's size when opened

    @classmethod
    def open(cls, path: Path) -> EnviRaster:
        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: no such file")
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NotGeoreferencedWarning)
                with rasterio.open(path) as ds:
                    if ds.driver != "ENVI":
                        raise InputError(f"{path}: not an ENVI raster (GDAL reads it as "
                                         f"{ds.driver}); is its .hdr missing?")
                    envi = dict(ds.tags(ns="ENVI"))
                    shape = (int(ds.height), int(ds.count), int(ds.width))
                    dtype = np.dtype(ds.dtypes[0])
                    nodata = ds.nodata
                    names = tuple(d or "" for d in ds.descriptions)
                    wl = tuple(_wavelength_nm(ds.tags(b), envi) for b in range(1, ds.count + 1))
        except RasterioIOError as exc:
            raise InputError(f"{path}: unreadable raster: {exc}") from None
        if "data_type" not in envi:  # GDAL then reads bytes, whatever the file holds
            raise InputError(f"{path}: the ENVI header gives no data type (the kind of number "
                             "the file holds)")
        interleave = envi.get("interleave", "bsq").strip().lower()
        if interleave not in _INTERLEAVES:
            raise InputError(f"{path}: ENVI interleave {interleave!r} is not bil, bsq or bip")
        order = envi.get("byte_order", "0").strip()
        if order not in _BYTE_ORDERS:  # GDAL reads any other value as little-endian
            raise InputError(f"{path}: ENVI byte order {order!r} is neither 0 (little-endian) "
                             "nor 1 (big-endian)")
        dtype = dtype.newbyteorder(_BYTE_ORDERS[order])
        raster = cls(path, *shape, dtype,
                     interleave, _header_offset(path, envi.get("header_offset", "0")),
                     None if nodata is None else float(nodata), names, wl, envi)
        return raster._whole_lines()

    @property
    def line_bytes(self) -> int:
        return self.bands * self.pixels * self.dtype.itemsize

    @property
    def cut_short(self) -> bool:
        return self.lines < self.header_lines

    def cut_short_text(self, name: object) -> str:
        """The start of every warning about this file being cut short (`name`: how to call it)."""
        hint = _layout_hint(self.file_bytes - self.header_offset,
                            self.header_lines * self.line_bytes)
        return (f"{name} is cut short: {self.lines} of its header's {self.header_lines} lines "
                f"are in the file (a copy or a recording interrupted?{hint and ' or ' + hint})")

    def _whole_lines(self) -> EnviRaster:
        """The raster as far as its file holds whole lines. A BIL or BIP file shorter than its
        header (a copy or a recording interrupted) keeps the lines before the cut (`lines`;
        the header's count in `header_lines`: callers say what is missing); a BSQ file, whose
        every band would be cut, or one without a whole line, is refused. A BIL or BIP file
        holding whole lines past its header's count is a recording stopped between a block and
        its header's rewrite (the scanner writes the header after each block): every line is
        read, with a HeaderBehindWarning, so that no line recorded is lost. Any other surplus
        (part of a line, or a whole multiple of the data, as from `bands = 1` for 4) is a
        header of another layout and refused: read with it, the image came out striped."""
        need = self.header_offset + self.lines * self.line_bytes
        have = self.path.stat().st_size
        if have > need:
            data, described = have - self.header_offset, need - self.header_offset
            behind = (self.interleave != "bsq" and self.line_bytes > 0 and described > 0
                      and data % self.line_bytes == 0 and data % described != 0)
            if not behind:
                raise InputError(
                    f"{self.path} holds {have} bytes, its header describes {need} ({self.lines} "
                    f"lines x {self.pixels} samples x {self.bands} bands x "
                    f"{self.dtype.itemsize} bytes + {self.header_offset} offset): a header of "
                    "another file or layout, or damaged?")
            lines = data // self.line_bytes
            warnings.warn(HeaderBehindWarning(
                f"{self.path} holds {lines} lines, {lines - self.lines} more than its header's "
                f"{self.lines} (a recording stopped before its header was rewritten?): all "
                f"{lines} are read"), stacklevel=3)
            return replace(self, lines=lines, header_lines=lines, file_bytes=have)
        if have == need:
            return replace(self, header_lines=self.lines, file_bytes=have)
        whole = max(have - self.header_offset, 0) // self.line_bytes if self.line_bytes else 0
        if self.interleave == "bsq" or whole == 0:
            hint = _layout_hint(have - self.header_offset, need - self.header_offset)
            raise InputError(f"{self.path}: truncated: {have} bytes, the header needs {need}"
                             f"{hint and ' (' + hint + ')'}")
        return replace(self, lines=whole, header_lines=self.lines, file_bytes=have)

    def read_lines(self, line0: int, line1: int) -> npt.NDArray[Any]:
        """Lines [line0, line1) as an array (lines, bands, pixels) in native byte order."""
        if not 0 <= line0 <= line1 <= self.lines:
            raise InputError(f"{self.path}: lines [{line0}, {line1}) outside 0..{self.lines}")
        n = line1 - line0
        with self.path.open("rb") as fh:
            if self.interleave == "bsq":
                per_band = [self._read(fh, (b * self.lines + line0) * self.pixels, n * self.pixels)
                            .reshape(n, self.pixels) for b in range(self.bands)]
                out = np.stack(per_band, axis=1) if per_band else np.zeros((n, 0, self.pixels))
            else:
                flat = self._read(fh, line0 * self.bands * self.pixels,
                                  n * self.bands * self.pixels)
                out = (flat.reshape(n, self.bands, self.pixels) if self.interleave == "bil"
                       else flat.reshape(n, self.pixels, self.bands).transpose(0, 2, 1))
        return np.ascontiguousarray(out, dtype=self.dtype.newbyteorder("="))

    def _read(self, fh: BinaryIO, first_value: int, count: int) -> npt.NDArray[Any]:
        fh.seek(self.header_offset + first_value * self.dtype.itemsize)
        data = np.fromfile(fh, dtype=self.dtype, count=count)
        if data.size != count:
            raise InputError(f"{self.path}: truncated while reading")
        return data


def _layout_hint(have: int, need: int) -> str:
    """Where a file holds exactly a simple fraction (1/2, 1/4, 3/4...) of the data its header
    describes, the header may describe another layout (more bands, a wider data type) rather
    than the file be cut short: said as a second guess. An interrupted copy hardly ends on
    such a byte."""
    if not 0 < have < need:
        return ""
    part = Fraction(have, need)
    if part.denominator > LAYOUT_DENOMINATORS:
        return ""
    return f"a header of another layout: the file holds exactly {part} of the data it describes"


def _wavelength_nm(band_tags: dict[str, str], envi: dict[str, str]) -> float | None:
    units = envi.get("wavelength_units", "nanometers").strip().lower()
    try:
        value = float(band_tags["wavelength"])
    except (KeyError, ValueError):
        return None
    return value * _WAVELENGTH_SCALE_TO_NM.get(units, 1.0)


# -- writing ENVI files ----------------------------------------------------------------------

def replace_file(tmp: Path, final: Path) -> None:
    """Rename the finished `tmp` to `final`, replacing any file there. A file in the way is
    renamed aside first and deleted after: ext4 (auto_da_alloc) writes the whole new file
    out to disk inside a rename that replaces one, seconds for a GB product (a re-run of
    `sisa ortho` soon after the first: 13.7 s against 4.1 s). Should the process die between
    the renames, the old file is left beside, hidden, not lost."""
    if final.is_dir() or not os.path.lexists(final):
        os.replace(tmp, final)  # nothing to set aside (a folder: os.replace's own error)
        return
    aside = final.with_name(f".{final.name}.old-{os.getpid()}")
    os.rename(final, aside)
    try:
        os.rename(tmp, final)
    except BaseException:
        os.rename(aside, final)
        raise
    aside.unlink()


def envi_list(items: Sequence[object]) -> str:
    return "{" + ", ".join(str(i) for i in items) + "}"


def envi_header_text(*, description: str, samples: int, lines: int, bands: int,
                     dtype: npt.DTypeLike, fields: Sequence[tuple[str, str]] = ()) -> str:
    """The text of an ENVI header for a little-endian BIL file without an embedded header."""
    name = np.dtype(dtype).name
    if name not in ENVI_DATA_TYPES:
        raise InputError(f"ENVI has no data type for {name}")
    desc = re.sub(r"\s+", " ", description.replace("{", "(").replace("}", ")")).strip()
    rows = [("description", "{" + desc + "}"), ("samples", str(samples)),
            ("lines", str(lines)), ("bands", str(bands)), ("header offset", "0"),
            ("file type", "ENVI Standard"), ("data type", str(ENVI_DATA_TYPES[name])),
            ("interleave", "bil"), ("byte order", "0"), *fields]
    return "ENVI\n" + "".join(f"{k} = {v}\n" for k, v in rows)


def commit_envi(tmp_data: Path, data: Path, header_text: str) -> None:
    """Move a finished ENVI data file to its name and write its header last.

    The old header goes first: if the process dies in between, a data file is left without a
    header, which no reader takes for a complete product.
    """
    hdr = data.with_suffix(".hdr")
    tmp_hdr, fd = create_partial(hdr)
    with os.fdopen(fd, "wb") as fh:
        fh.write(header_text.encode("ascii"))
    hdr.unlink(missing_ok=True)
    replace_file(tmp_data, data)
    os.replace(tmp_hdr, hdr)


# Products' CRSs go through GDAL's (rasterio's CRS), which the raster I/O loads anyway:
# pyproj's first CRS cost a `sisa ortho` run ~45 ms of its ~1 s (pyproj stays for transforms).

def projected_crs(epsg: int) -> CRS:
    try:
        with rasterio.Env():  # GDAL's errors as the exception only, not also on stderr
            crs = CRS.from_epsg(int(epsg))
    except CRSError:
        raise InputError(f"EPSG:{epsg}: unknown CRS") from None
    if not crs.is_projected:
        raise InputError(f"EPSG:{epsg}: not a projected CRS (products need metres)")
    return crs


def crs_name(crs: CRS) -> str:
    """The CRS's own name, e.g. 'WGS 84 / UTM zone 31N' (the first string of its WKT)."""
    found = re.match(r'\s*\w+\["([^"]*)"', crs.to_wkt())
    return found[1] if found else str(crs.to_string())


def coordinate_system_string(crs: CRS) -> str:
    """ENVI's `coordinate system string`: ESRI-flavoured WKT1, as ENVI and GDAL write it."""
    return "{" + str(crs.to_wkt(version=WktVersion.WKT1_ESRI)) + "}"


# -- the IGM ---------------------------------------------------------------------------------

class IgmWriter:
    """Writes `<stem>.bil` + `<stem>.hdr` block by block; nothing appears under those names
    until every line is written and the writer is closed without an error.

        with IgmWriter(stem, lines, pixels, epsg) as igm:
            igm.write_block(0, easting_m, northing_m, height_m)   # (block_lines, pixels) each
    """

    def __init__(self, stem: Path, lines: int, pixels: int, epsg: int, *,
                 source: str = "") -> None:
        if lines <= 0 or pixels <= 0:
            raise InputError(f"IGM {stem}: needs at least one line and one pixel, got "
                             f"{lines} x {pixels}")
        self.crs = projected_crs(epsg)
        self.epsg = int(epsg)
        self.lines, self.pixels, self.source = int(lines), int(pixels), source
        self.path = Path(f"{stem}.bil")
        if not self.path.parent.is_dir():
            raise InputError(f"{self.path.parent}: no such folder")
        self._tmp, fd = create_partial(self.path)
        self._fh: BinaryIO | None = os.fdopen(fd, "wb")
        self._next = 0

    def __enter__(self) -> IgmWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def write_block(self, line0: int, easting_m: npt.ArrayLike, northing_m: npt.ArrayLike,
                    height_m: npt.ArrayLike) -> None:
        """Lines [line0, line0 + n) of pixel-centre positions, each (n, pixels); blocks must
        follow each other. A pixel with any coordinate not finite is written all NaN."""
        if self._fh is None:
            raise InputError(f"{self.path}: IGM writer already closed")
        if line0 != self._next:
            raise InputError(f"{self.path}: block starts at line {line0}, expected {self._next}")
        e, n, h = (np.asarray(a, dtype=np.float64) for a in (easting_m, northing_m, height_m))
        if e.ndim != 2 or e.shape[1] != self.pixels or not e.shape == n.shape == h.shape:
            raise InputError(f"{self.path}: block shapes {e.shape}, {n.shape}, {h.shape}; "
                             f"expected (lines, {self.pixels}) each")
        if line0 + e.shape[0] > self.lines:
            raise InputError(f"{self.path}: block ends at line {line0 + e.shape[0]}, beyond "
                             f"the {self.lines} lines declared")
        block = np.stack([e, n, h], axis=1)
        missed = ~np.asarray(np.isfinite(block).all(axis=1), dtype=np.bool_)
        np.copyto(block, np.nan, where=missed[:, None, :])
        block.astype("<f8", copy=False).tofile(self._fh)
        self._next += e.shape[0]

    def close(self) -> None:
        """Finish: rename the data into place and write the header, or raise if incomplete."""
        if self._fh is None:
            return
        self._fh.close()
        self._fh = None
        if self._next != self.lines:
            self._tmp.unlink(missing_ok=True)
            raise InputError(f"{self.path}: only {self._next} of {self.lines} lines written; "
                             "no IGM produced")
        commit_envi(self._tmp, self.path, self.header_text())

    def abort(self) -> None:
        """Drop what was written; the final names are left untouched."""
        if self._fh is not None:
            self._fh.close()
            self._fh = None
        self._tmp.unlink(missing_ok=True)

    def header_text(self) -> str:
        of = f" of {self.source}" if self.source else ""
        desc = (f"SISA IGM{of}: ground position of the CENTRE of every pixel, one IGM line per "
                "image line and one sample per pixel. Band 1 easting (m), band 2 northing (m) "
                f"in EPSG:{self.epsg} ({crs_name(self.crs)}); band 3 ellipsoidal height (m above "
                "the WGS 84 ellipsoid). NaN (the data ignore value) where the pixel's ray "
                "missed the DEM or the line has no pose.")
        return envi_header_text(
            description=desc, samples=self.pixels, lines=self.lines, bands=3, dtype=np.float64,
            fields=[("band names", envi_list(IGM_BAND_NAMES)), ("data ignore value", "NaN"),
                    ("map info", IGM_MAP_INFO),
                    ("coordinate system string", coordinate_system_string(self.crs))])


# An IGM's raster is the image's grid (samples across, lines along the flight), not a map grid:
# ENVI's "Arbitrary" map info says so. GDAL reads an ENVI header's `coordinate system string`
# only with a `map info`, so without one it showed no CRS for the coordinates in the bands; with
# this one it shows the bands' CRS, its geotransform being pixel units (x = sample, y = −line)
# that mean nothing on the ground (every pixel's position is in the bands).
IGM_MAP_INFO: Final = "{Arbitrary, 1, 1, 0, 0, 1, 1, 0, North}"


def igm_raster(path: Path) -> EnviRaster:
    """The IGM's layout, checked: 3 bands of float64 (easting, northing, height)."""
    raster = EnviRaster.open(Path(path))
    if raster.bands != 3 or raster.dtype.kind != "f" or raster.dtype.itemsize != 8:
        raise InputError(f"{path}: not an IGM (needs 3 float64 bands, has {raster.bands} of "
                         f"{raster.dtype.name})")
    return raster


def open_igm(path: Path) -> np.memmap[Any, np.dtype[np.float64]]:
    """A read-only memmap view (lines, 3, pixels) of an IGM; band axis: easting, northing,
    height. Convenient for small reads; `iter_igm_blocks(path)` keeps memory flat."""
    raster = igm_raster(path)
    if raster.interleave != "bil":
        raise InputError(f"{path}: IGM must be BIL to map as (lines, 3, pixels)")
    return np.memmap(raster.path, dtype=raster.dtype, mode="r", offset=raster.header_offset,
                     shape=(raster.lines, 3, raster.pixels))


def igm_epsg(path: Path) -> int | None:
    """The EPSG code of an IGM's `coordinate system string`, or None if it has none."""
    wkt = igm_raster(path).envi.get("coordinate_system_string", "").strip().strip("{}")
    if not wkt:
        return None
    try:
        with rasterio.Env():
            code = CRS.from_wkt(wkt).to_epsg()
    except CRSError:
        raise InputError(f"{path}: unreadable coordinate system string") from None
    return None if code is None else int(code)


IgmSource = Path | npt.NDArray[np.float64]


def iter_igm_blocks(igm: IgmSource, block_lines: int = IGM_BLOCK_LINES
                    ) -> Iterator[tuple[int, F64]]:
    """(line0, block (n, 3, pixels)) over an IGM file (file reads) or an in-memory array."""
    if isinstance(igm, np.ndarray):
        if igm.ndim != 3 or igm.shape[1] != 3:
            raise InputError(f"IGM array must be (lines, 3, pixels), got {igm.shape}")
        for lo in range(0, igm.shape[0], block_lines):
            yield lo, np.asarray(igm[lo:lo + block_lines], dtype=np.float64)
        return
    raster = igm_raster(Path(igm))
    for lo in range(0, raster.lines, block_lines):
        yield lo, raster.read_lines(lo, min(lo + block_lines, raster.lines))


def igm_bounds(igm: IgmSource) -> tuple[float, float, float, float]:
    """(west, south, east, north) of the finite positions, in the IGM's CRS; read by blocks."""
    west = south = np.inf
    east = north = -np.inf
    for _, blk in iter_igm_blocks(igm):
        ok = np.isfinite(blk[:, 0]) & np.isfinite(blk[:, 1])
        if ok.any():
            e, n = blk[:, 0][ok], blk[:, 1][ok]
            west, east = min(west, float(e.min())), max(east, float(e.max()))
            south, north = min(south, float(n.min())), max(north, float(n.max()))
    if not np.isfinite(west):
        raise InputError(f"{igm if isinstance(igm, Path) else 'IGM'}: no finite position")
    return west, south, east, north


def igm_pixel_spacing_m(path: Path, sample_lines: int = 64) -> float:
    """Median distance between neighbouring pixel centres of a line (across track), from
    `sample_lines` lines spread over the IGM; NaN if no two neighbours have positions."""
    igm = open_igm(path)
    rows = np.unique(np.linspace(0, igm.shape[0] - 1, min(sample_lines, igm.shape[0]))
                     .astype(np.int64))
    east, north = np.asarray(igm[rows, 0]), np.asarray(igm[rows, 1])
    with np.errstate(invalid="ignore", over="ignore"):  # inf or garbage: not a step, no warning
        step = np.hypot(np.diff(east, axis=1), np.diff(north, axis=1)).ravel()
    step = step[np.isfinite(step)]
    return float(np.median(step)) if step.size else float("nan")


# -- GDAL geolocation arrays -----------------------------------------------------------------

def write_geolocation_vrt(vrt_path: Path, image_path: Path, igm_path: Path, epsg: int) -> None:
    """A VRT over the raw image whose GEOLOCATION metadata points at the IGM, so that
    `gdalwarp -geoloc` maps it. Paths are relative to the VRT: the folder can be moved.

    GDAL 3.6 forgets X_DATASET_RELATIVE_TO_SOURCE when it warps with `-wo NUM_THREADS` (the
    IGM is then looked for from the working directory, and gdalwarp may crash): run such a
    gdalwarp from the VRT's folder."""
    vrt_path, image_path, igm_path = Path(vrt_path), Path(image_path), Path(igm_path)
    image = EnviRaster.open(image_path)
    igm = igm_raster(igm_path)
    if (igm.lines, igm.pixels) != (image.lines, image.pixels):
        raise InputError(f"{igm_path}: IGM is {igm.lines} x {igm.pixels}, the image "
                         f"{image_path} {image.lines} x {image.pixels}")
    crs = projected_crs(epsg)
    root = ET.Element("VRTDataset", rasterXSize=str(image.pixels),
                      rasterYSize=str(image.lines))
    geoloc = ET.SubElement(root, "Metadata", domain="GEOLOCATION")
    igm_rel = _relative(igm_path, vrt_path)
    for key, value in (("SRS", crs.to_wkt()), ("X_DATASET", igm_rel),
                       ("X_DATASET_RELATIVE_TO_SOURCE", "YES"), ("X_BAND", "1"),
                       ("Y_DATASET", igm_rel), ("Y_DATASET_RELATIVE_TO_SOURCE", "YES"),
                       ("Y_BAND", "2"), ("PIXEL_OFFSET", "0"), ("LINE_OFFSET", "0"),
                       ("PIXEL_STEP", "1"), ("LINE_STEP", "1"),
                       ("GEOREFERENCING_CONVENTION", "PIXEL_CENTER")):
        ET.SubElement(geoloc, "MDI", key=key).text = value
    for b in range(image.bands):
        _vrt_band(root, image, b, _relative(image_path, vrt_path))
    ET.indent(root)
    write_whole(vrt_path, ET.tostring(root, encoding="utf-8", xml_declaration=False) + b"\n")


def band_labels(raw: EnviRaster) -> list[str]:
    """Each band's name in the ENVI header (not GDAL's description, which appends the
    wavelength to it: 'band 1 (495.0 nm) (495.00 Nanometers)' for a name that had it), with
    its wavelength in nm if the name does not already say it."""
    labels = []
    for b in range(raw.bands):
        name = _envi_band_name(raw, b) or f"band {b + 1}"
        wl = raw.wavelengths_nm[b]
        labels.append(name if wl is None or "nm" in name else f"{name} ({wl:.1f} nm)")
    return labels


def _envi_band_name(raw: EnviRaster, b: int) -> str:
    names = raw.envi.get("band_names", "").strip().strip("{}").split(",")
    return names[b].strip() if len(names) == raw.bands else raw.band_names[b]


def _vrt_band(root: ET.Element, image: EnviRaster, b: int, source: str) -> None:
    gdal_type = GDAL_TYPE_NAMES.get(image.dtype.name)
    if gdal_type is None:
        raise InputError(f"{image.path}: data type {image.dtype.name} not supported")
    band = ET.SubElement(root, "VRTRasterBand", dataType=gdal_type, band=str(b + 1))
    ET.SubElement(band, "Description").text = band_labels(image)[b]
    wl = image.wavelengths_nm[b]
    if wl is not None:
        md = ET.SubElement(band, "Metadata")
        ET.SubElement(md, "MDI", key="wavelength").text = f"{wl:g}"
        ET.SubElement(md, "MDI", key="wavelength_units").text = "Nanometers"
    if image.nodata is not None:
        ET.SubElement(band, "NoDataValue").text = repr(image.nodata)
    src = ET.SubElement(band, "SimpleSource")
    ET.SubElement(src, "SourceFilename", relativeToVRT="1").text = source
    ET.SubElement(src, "SourceBand").text = str(b + 1)
    ET.SubElement(src, "SourceProperties", RasterXSize=str(image.pixels),
                  RasterYSize=str(image.lines), DataType=gdal_type,
                  BlockXSize=str(image.pixels), BlockYSize="1")


def _relative(target: Path, vrt_path: Path) -> str:
    return Path(os.path.relpath(target.resolve(), vrt_path.resolve().parent)).as_posix()
