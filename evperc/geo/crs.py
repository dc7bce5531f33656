"""The working CRS (method.md §7): metric, east-north; by default the UTM zone of the data.

UTM zones are the standard 6° zones, ``zone = floor((lon + 180) / 6) + 1``, EPSG 326zz north
of the equator (lat ≥ 0) and 327zz south of it. The Norway / Svalbard exceptions of the UTM
grid are not applied: the choice only has to be metric, conformal and deterministic.
"""

from __future__ import annotations

import functools
import math

import pyproj
import pyproj.exceptions

from evperc.errors import ConfigError, GeoreferenceError

#: lon/lat on WGS 84, x = longitude (RFC 7946 order); GeoJSON without a ``crs`` member.
LONLAT = pyproj.CRS.from_user_input("OGC:CRS84")

_METRE_UNITS = {"metre", "meter", "m"}


def utm_crs_for(lon: float, lat: float) -> pyproj.CRS:
    """The WGS 84 / UTM CRS of the standard zone holding ``(lon, lat)`` (degrees).

    ``EPSG = 32600 + zone`` for ``lat ≥ 0``, ``32700 + zone`` below the equator."""
    if not (math.isfinite(lon) and math.isfinite(lat)) or abs(lat) > 90.0:
        raise GeoreferenceError(
            f"position lon={lon!r}, lat={lat!r} is not a valid WGS 84 lon/lat; check the "
            "origin (input.origin_lat_deg / origin_lon_deg) or the GNSS fixes")
    lon = (lon + 180.0) % 360.0 - 180.0
    zone = min(60, int(math.floor((lon + 180.0) / 6.0)) + 1)
    return pyproj.CRS.from_epsg((32600 if lat >= 0.0 else 32700) + zone)


def is_metric(crs: pyproj.CRS) -> bool:
    """True for a projected CRS whose two horizontal axes are in metres."""
    if not crs.is_projected:
        return False
    units = [axis.unit_name.lower() for axis in crs.axis_info[:2]]
    return len(units) == 2 and all(u in _METRE_UNITS for u in units)


def parse_crs(text: str, *, key: str = "map.crs") -> pyproj.CRS:
    """``pyproj.CRS`` from a config string (``"EPSG:32635"``, WKT, PROJ string)."""
    try:
        return pyproj.CRS.from_user_input(text)
    except pyproj.exceptions.CRSError as err:
        raise ConfigError(
            f"{key} = {text!r} is not a CRS pyproj knows; give e.g. \"EPSG:32635\"") from err


def working_crs(config_crs: str, lonlat_hint: tuple[float, float] | None, *,
                key: str = "map.crs") -> pyproj.CRS:
    """The metric CRS all geometry is computed in.

    ``config_crs`` (the ``map.crs`` key) wins when it is not empty; otherwise the UTM zone of
    ``lonlat_hint`` = ``(lon, lat)`` in degrees. A geographic or non-metre CRS is refused
    with :class:`ConfigError` naming ``key``."""
    if config_crs:
        crs = parse_crs(config_crs, key=key)
        if not is_metric(crs):
            kind = "geographic (degrees)" if crs.is_geographic else "not in metres"
            hint = ""
            if lonlat_hint is not None:
                hint = f", e.g. {utm_crs_for(*lonlat_hint).to_string()} here"
            raise ConfigError(
                f"{key} = {config_crs!r} is {kind}; the working CRS must be a projected CRS in "
                f"metres{hint}, or \"\" for the UTM zone of the data")
        return crs
    if lonlat_hint is None:
        raise ConfigError(
            f"{key} is empty and there is no position to choose a UTM zone from; set {key} "
            "(e.g. \"EPSG:32635\")")
    return utm_crs_for(float(lonlat_hint[0]), float(lonlat_hint[1]))


@functools.lru_cache(maxsize=64)
def transformer(src: pyproj.CRS, dst: pyproj.CRS) -> pyproj.Transformer:
    """A cached ``pyproj.Transformer`` from ``src`` to ``dst`` with x = east/longitude
    (``always_xy=True``) whatever the axis order the CRS declares."""
    return pyproj.Transformer.from_crs(src, dst, always_xy=True)
