"""Map polygons as outline segments in the working CRS, for drawing over the grids."""

from __future__ import annotations

from typing import Any

import numpy as np
import shapely

RGB = tuple[int, int, int]

BUILDING_OUTLINE: RGB = (255, 255, 255)
ROAD_OUTLINE: RGB = (150, 150, 150)


def outline_segments(geometries: Any) -> np.ndarray:
    """All edges of the geometries' boundaries (or of the lines themselves) as ``(N, 4)``
    float64 x0, y0, x1, y1 in the geometries' CRS."""
    geoms = np.asarray(geometries, dtype=object).ravel()
    geoms = geoms[~shapely.is_missing(geoms)] if len(geoms) else geoms
    if len(geoms) == 0:
        return np.empty((0, 4))
    is_area = np.isin(shapely.get_type_id(geoms), [3, 6])  # Polygon, MultiPolygon
    lines = np.where(is_area, shapely.boundary(geoms), geoms)
    parts = shapely.get_parts(shapely.get_parts(lines))  # MultiLineString → LineStrings
    parts = parts[shapely.get_type_id(parts) == 1] if len(parts) else parts
    coords, index = shapely.get_coordinates(parts, return_index=True)
    if len(coords) < 2:
        return np.empty((0, 4))
    same = index[1:] == index[:-1]
    return np.concatenate([coords[:-1][same], coords[1:][same]], axis=1)


class MapOutlines:
    """Buildings and roads of a map (already in the run's CRS) as outline segments."""

    def __init__(self, buildings: Any = (), roads: Any = ()) -> None:
        self.layers: list[tuple[np.ndarray, RGB]] = [
            (outline_segments(roads), ROAD_OUTLINE),
            (outline_segments(buildings), BUILDING_OUTLINE)]

    @classmethod
    def from_map_data(cls, map_data: Any) -> MapOutlines:
        """From an ``evperc.geo.maps.MapData`` (``.buildings``, ``.roads``)."""
        return cls(getattr(map_data, "buildings", ()), getattr(map_data, "roads", ()))

    def segments_in(self, bounds: tuple[float, float, float, float]
                    ) -> list[tuple[np.ndarray, RGB]]:
        """Per layer, the segments whose bounding box meets ``bounds`` (xmin, ymin, xmax, ymax)."""
        xmin, ymin, xmax, ymax = bounds
        out = []
        for seg, colour in self.layers:
            lo_x = np.minimum(seg[:, 0], seg[:, 2])
            hi_x = np.maximum(seg[:, 0], seg[:, 2])
            lo_y = np.minimum(seg[:, 1], seg[:, 3])
            hi_y = np.maximum(seg[:, 1], seg[:, 3])
            hit = (hi_x >= xmin) & (lo_x <= xmax) & (hi_y >= ymin) & (lo_y <= ymax)
            out.append((seg[hit], colour))
        return out
