"""scripts/shift_map.py: a map moved by metres, checked in a metric CRS picked here (not the
script's UTM estimate), with the features' properties and the file's CRS kept."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pyproj
import pytest
import shapely

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "scripts"))

import shift_map  # noqa: E402

#: a block of Helsinki (the test map's city), in lon / lat
HELSINKI = shapely.box(24.9430, 60.1690, 24.9440, 60.1695)


def _collection(geom: shapely.Geometry, crs: str | None) -> dict:
    out = {"type": "FeatureCollection",
           "features": [{"type": "Feature", "properties": {"building": "yes", "levels": 3},
                         "geometry": shapely.geometry.mapping(geom)}]}
    if crs is not None:
        out["crs"] = {"type": "name", "properties": {"name": crs}}
    return out


@pytest.mark.parametrize("crs", [None, "urn:ogc:def:crs:OGC:1.3:CRS84", "EPSG:3857"])
@pytest.mark.parametrize("east, north", [(1.0, 0.0), (0.0, -2.5), (0.7, 0.7)])
def test_every_vertex_moves_by_the_metres_asked(tmp_path: Path, crs: str | None, east: float,
                                                north: float) -> None:
    """Each vertex lands ``east``, ``north`` metres from where it was, measured in ETRS89 /
    TM35FIN (EPSG:3067, Finland's national grid: not the UTM zone the script works in, so
    within the two projections' scale difference, 1e-3 m over a few metres); the
    properties and the ``crs`` member are those of the input."""
    block = HELSINKI
    if crs == "EPSG:3857":
        to = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
        block = shapely.transform(HELSINKI, lambda xy: np.column_stack(to.transform(*xy.T)))
    src, dst = tmp_path / "map.geojson", tmp_path / "moved.geojson"
    src.write_text(json.dumps(_collection(block, crs)))
    assert shift_map.main([str(src), str(dst), "--east-m", str(east), "--north-m",
                           str(north)]) == 0
    before, after = json.loads(src.read_text()), json.loads(dst.read_text())
    assert after["features"][0]["properties"] == {"building": "yes", "levels": 3}
    assert after.get("crs") == before.get("crs")
    metric = pyproj.Transformer.from_crs(crs or "EPSG:4326", "EPSG:3067", always_xy=True)
    a = np.array(shapely.geometry.shape(before["features"][0]["geometry"]).exterior.coords)
    b = np.array(shapely.geometry.shape(after["features"][0]["geometry"]).exterior.coords)
    moved = np.column_stack(metric.transform(*b.T)) - np.column_stack(metric.transform(*a.T))
    np.testing.assert_allclose(moved, np.broadcast_to([east, north], moved.shape), atol=1e-3)


def test_an_empty_map_stays_empty() -> None:
    empty = {"type": "FeatureCollection", "features": []}
    assert shift_map.shift(empty, 1.0, 0.0) == empty
