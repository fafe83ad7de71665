"""The block's local plane: an azimuthal equidistant projection centred on the block, in which
strips are planned (east, north metres), and the UTM zone the products and the DEM use."""

from __future__ import annotations

from functools import cached_property

import numpy as np
import numpy.typing as npt
from pyproj import CRS, Transformer

from emulators.scenario import Scenario
from sisa.core.utm import utm_epsg

FloatArray = npt.NDArray[np.float64]


class LocalPlane:
    """Built once per scenario; converts vectorised between plane, geodetic, ECEF and UTM."""

    def __init__(self, lat0_deg: float, lon0_deg: float) -> None:
        self.lat0_deg = lat0_deg
        self.lon0_deg = lon0_deg
        self.crs = CRS.from_proj4(
            f"+proj=aeqd +lat_0={lat0_deg} +lon_0={lon0_deg} +datum=WGS84 +units=m +no_defs"
        )
        self._to_geo = Transformer.from_crs(self.crs, CRS.from_epsg(4326), always_xy=True)
        self._from_geo = Transformer.from_crs(CRS.from_epsg(4326), self.crs, always_xy=True)
        self._geo_to_ecef = Transformer.from_crs(CRS.from_epsg(4979), CRS.from_epsg(4978),
                                                 always_xy=True)
        self._ecef_to_geo = Transformer.from_crs(CRS.from_epsg(4978), CRS.from_epsg(4979),
                                                 always_xy=True)

    @classmethod
    def for_scenario(cls, scn: Scenario) -> LocalPlane:
        return cls(scn.block.centre_lat_deg, scn.block.centre_lon_deg)

    @cached_property
    def utm_epsg(self) -> int:
        return utm_epsg(self.lon0_deg, self.lat0_deg)

    @cached_property
    def _plane_to_utm(self) -> Transformer:
        return Transformer.from_crs(self.crs, CRS.from_epsg(self.utm_epsg), always_xy=True)

    @cached_property
    def _utm_to_geo(self) -> Transformer:
        return Transformer.from_crs(CRS.from_epsg(self.utm_epsg), CRS.from_epsg(4326),
                                    always_xy=True)

    def plane_to_geodetic(self, east_m: npt.ArrayLike, north_m: npt.ArrayLike
                          ) -> tuple[FloatArray, FloatArray]:
        """(lat_deg, lon_deg) of plane points."""
        lon, lat = self._to_geo.transform(np.asarray(east_m, float), np.asarray(north_m, float))
        return np.asarray(lat), np.asarray(lon)

    def geodetic_to_plane(self, lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike
                          ) -> tuple[FloatArray, FloatArray]:
        e, n = self._from_geo.transform(np.asarray(lon_deg, float), np.asarray(lat_deg, float))
        return np.asarray(e), np.asarray(n)

    def plane_to_utm(self, east_m: npt.ArrayLike, north_m: npt.ArrayLike
                     ) -> tuple[FloatArray, FloatArray]:
        x, y = self._plane_to_utm.transform(np.asarray(east_m, float), np.asarray(north_m, float))
        return np.asarray(x), np.asarray(y)

    def utm_to_geodetic(self, easting_m: npt.ArrayLike, northing_m: npt.ArrayLike
                        ) -> tuple[FloatArray, FloatArray]:
        lon, lat = self._utm_to_geo.transform(np.asarray(easting_m, float),
                                              np.asarray(northing_m, float))
        return np.asarray(lat), np.asarray(lon)

    def geodetic_to_ecef(self, lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike,
                         h_m: npt.ArrayLike) -> FloatArray:
        """ECEF metres, shape (..., 3)."""
        x, y, z = self._geo_to_ecef.transform(np.asarray(lon_deg, float),
                                              np.asarray(lat_deg, float), np.asarray(h_m, float))
        return np.stack([x, y, z], axis=-1)

    def ecef_to_geodetic(self, ecef_m: npt.ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(lat_deg, lon_deg, h_m) from ECEF metres of shape (..., 3)."""
        p = np.asarray(ecef_m, float)
        lon, lat, h = self._ecef_to_geo.transform(p[..., 0], p[..., 1], p[..., 2])
        return np.asarray(lat), np.asarray(lon), np.asarray(h)
