#!/usr/bin/env python3
"""A GeoJSON map moved by a few metres: the map error of a real drive (an outline traced off
the aerial image, a road polygon a metre beside the kerb), to measure what a key that reads
the map costs when the map is wrong (docs/evaluation.md § Since 2026-12-08).

    python scripts/shift_map.py IN.geojson OUT.geojson --east-m 1.0 [--north-m 0.0]

Every geometry is moved by (east, north) metres in the UTM zone of the map's centre (pyproj's
``estimate_utm_crs``), then written back in the input's CRS with its properties unchanged —
a simulated drive's map (``evperc simulate``'s ``map.geojson``, CRS84) or any GeoJSON whose
CRS pyproj reads (its ``crs`` member; CRS84 when it has none, as RFC 7946 says).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pyproj
import shapely
from pyproj.aoi import AreaOfInterest
from pyproj.database import query_utm_crs_info

CRS84 = "urn:ogc:def:crs:OGC:1.3:CRS84"


def _crs(collection: dict[str, Any]) -> pyproj.CRS:
    name = collection.get("crs", {}).get("properties", {}).get("name", CRS84)
    return pyproj.CRS.from_user_input(name)


def _utm_of(geoms: Sequence[shapely.Geometry], crs: pyproj.CRS) -> pyproj.CRS:
    x0, y0, x1, y1 = shapely.total_bounds(geoms)
    to_lonlat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    lon, lat = to_lonlat.transform((x0 + x1) / 2, (y0 + y1) / 2)
    info = query_utm_crs_info(datum_name="WGS 84",
                              area_of_interest=AreaOfInterest(lon, lat, lon, lat))
    return pyproj.CRS.from_epsg(int(info[0].code))


def shift(collection: dict[str, Any], east_m: float, north_m: float) -> dict[str, Any]:
    """``collection`` (a GeoJSON FeatureCollection) with every geometry moved by ``east_m``,
    ``north_m`` metres in its centre's UTM zone; the rest of it as it was."""
    crs = _crs(collection)
    features = collection["features"]
    geoms = [shapely.geometry.shape(f["geometry"]) for f in features]
    if not geoms:
        return collection
    utm = _utm_of(geoms, crs)
    forward = pyproj.Transformer.from_crs(crs, utm, always_xy=True)
    back = pyproj.Transformer.from_crs(utm, crs, always_xy=True)

    def moved(xy: Any) -> Any:
        x, y = forward.transform(xy[:, 0], xy[:, 1])
        x, y = back.transform(x + east_m, y + north_m)
        xy = xy.copy()
        xy[:, 0], xy[:, 1] = x, y
        return xy

    out = dict(collection)
    out["features"] = [{**f, "geometry": shapely.geometry.mapping(shapely.transform(g, moved))}
                       for f, g in zip(features, geoms, strict=True)]
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("src", type=Path, help="a GeoJSON FeatureCollection")
    parser.add_argument("dst", type=Path, help="where the moved map is written")
    parser.add_argument("--east-m", type=float, default=0.0, help="metres east (default 0)")
    parser.add_argument("--north-m", type=float, default=0.0, help="metres north (default 0)")
    args = parser.parse_args(argv)
    collection = json.loads(args.src.read_text())
    args.dst.write_text(json.dumps(shift(collection, args.east_m, args.north_m)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
