"""Working CRS choice (method.md §7): UTM zones, config override, metric check, transformers."""

from __future__ import annotations

import pyproj
import pytest

from evperc.errors import ConfigError, GeoreferenceError
from evperc.geo.crs import is_metric, transformer, utm_crs_for, working_crs


@pytest.mark.parametrize(("lon", "lat", "epsg"), [
    (24.94, 60.17, 32635),     # Helsinki
    (14.40, 50.10, 32633),     # Prague
    (8.39, 48.98, 32632),      # Karlsruhe (KITTI)
    (151.21, -33.87, 32756),   # Sydney: southern hemisphere
    (-74.0, 40.7, 32618),      # New York
    (-180.0, 0.0, 32601),      # first zone starts at -180, equator is north
    (179.99, -0.01, 32760),    # last zone
    (6.0, 45.0, 32632),        # a zone edge belongs to the zone east of it
])
def test_utm_zone(lon: float, lat: float, epsg: int) -> None:
    assert utm_crs_for(lon, lat).to_epsg() == epsg


@pytest.mark.parametrize(("lon", "lat"), [(24.94, 60.17), (-122.4, 37.8), (116.4, -20.0)])
def test_utm_zone_agrees_with_pyproj_query(lon: float, lat: float) -> None:
    from pyproj.aoi import AreaOfInterest
    from pyproj.database import query_utm_crs_info

    infos = query_utm_crs_info("WGS 84", AreaOfInterest(lon, lat, lon, lat))
    assert utm_crs_for(lon, lat).to_epsg() in {int(i.code) for i in infos}


def test_bad_position() -> None:
    with pytest.raises(GeoreferenceError, match="origin_lat_deg"):
        utm_crs_for(float("nan"), 10.0)
    with pytest.raises(GeoreferenceError):
        utm_crs_for(10.0, 91.0)


def test_config_wins_over_the_hint() -> None:
    assert working_crs("EPSG:3067", (14.4, 50.1)).to_epsg() == 3067
    assert working_crs("", (14.4, 50.1)).to_epsg() == 32633


def test_geographic_or_unknown_crs_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"map.crs = 'EPSG:4326' is geographic.*EPSG:32635"):
        working_crs("EPSG:4326", (24.9, 60.2))
    with pytest.raises(ConfigError, match="input.poses_crs"):
        working_crs("OGC:CRS84", None, key="input.poses_crs")
    with pytest.raises(ConfigError, match="not a CRS"):
        working_crs("EPSG:99999999", None)
    with pytest.raises(ConfigError, match="map.crs is empty"):
        working_crs("", None)
    # US survey feet: projected but not metric
    with pytest.raises(ConfigError, match="not in metres"):
        working_crs("EPSG:2263", None)
    assert is_metric(pyproj.CRS.from_epsg(3857)) and not is_metric(pyproj.CRS.from_epsg(4326))


def test_transformer_is_cached_and_lon_lat_ordered() -> None:
    a = transformer(pyproj.CRS.from_epsg(4326), pyproj.CRS.from_epsg(32635))
    b = transformer(pyproj.CRS.from_epsg(4326), pyproj.CRS.from_epsg(32635))
    assert a is b
    # 27° E is zone 35's central meridian: easting 500 km, northing = 0.9996 · meridian arc
    x, y = a.transform(27.0, 60.0)
    arc = pyproj.Geod(ellps="WGS84").inv(27.0, 0.0, 27.0, 60.0)[2]
    assert x == pytest.approx(500_000.0, abs=1e-6)
    assert y == pytest.approx(0.9996 * arc, abs=1e-3)
