"""The simulated world: mapped buildings, unmapped street furniture, all in the working CRS.

Classes (method.md §1): buildings are I (they are in the map file); poles, trees, bollards and
fences are U (never written to the map); vehicles and pedestrians are agents
(:mod:`evperc.sim.traffic`), S or M depending on their speed at each instant.

Geometry is 2.5-D: a building is the vertical walls of its outline (segments) up to its
height; poles, trees, bollards are vertical cylinders; fences are thin boxes.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyproj
import shapely

from evperc.errors import MapError
from evperc.sim.roads import DRIVABLE, RoadGraph

log = logging.getLogger(__name__)

#: shape kinds of :class:`Solids`
BOX, CYLINDER = 0, 1
#: truth classes, numbered like evperc's decision codes (docs/output-format.md)
FREE, MOVING, STOPPED, INFRASTRUCTURE, UNMAPPED = 1, 2, 4, 5, 6


_BUILDING_LAYERS = ("buildings", "building")
_ROAD_LAYERS = ("roads", "streets", "highways")


@dataclass(frozen=True)
class MapLayers:
    """Map features in their own CRS: building polygons, highway lines and their classes."""

    buildings: np.ndarray   # shapely (Multi)Polygons
    roads: np.ndarray       # shapely LineStrings
    highway: np.ndarray     # str per road
    crs: pyproj.CRS


@dataclass(frozen=True)
class Solids:
    """Vertical solids: boxes (centre, heading, length × width) or cylinders (radius)."""

    kind: np.ndarray      # (N,) BOX or CYLINDER
    x: np.ndarray         # (N,) centre, metres
    y: np.ndarray
    heading: np.ndarray   # (N,) radians (boxes)
    length: np.ndarray    # (N,) box extent along heading; cylinder diameter
    width: np.ndarray     # (N,) box extent across heading; cylinder diameter
    height: np.ndarray    # (N,)
    label: np.ndarray     # (N,) truth class

    @staticmethod
    def empty() -> Solids:
        z = np.zeros(0)
        return Solids(z.astype(np.int8), z, z, z, z, z, z, z.astype(np.uint8))

    def __len__(self) -> int:
        return len(self.x)

    def polygons(self) -> np.ndarray:
        """Footprints as shapely polygons (cylinders as 16-gons)."""
        corners = box_corners(self.x, self.y, self.heading, self.length, self.width)
        boxes = shapely.polygons(corners)
        circles = shapely.buffer(shapely.points(np.column_stack([self.x, self.y])),
                                 self.length / 2, quad_segs=4)
        return np.where(self.kind == BOX, boxes, circles)


def box_corners(x: np.ndarray, y: np.ndarray, heading: np.ndarray, length: np.ndarray,
                width: np.ndarray) -> np.ndarray:
    """(N, 4, 2) corners of oriented rectangles, counter-clockwise."""
    u = np.array([1.0, -1.0, -1.0, 1.0]) / 2
    v = np.array([1.0, 1.0, -1.0, -1.0]) / 2
    lx = np.asarray(length)[:, None] * u
    ly = np.asarray(width)[:, None] * v
    c, s = np.cos(heading)[:, None], np.sin(heading)[:, None]
    return np.stack([x[:, None] + c * lx - s * ly, y[:, None] + s * lx + c * ly], axis=-1)


@dataclass(frozen=True)
class Scene:
    """Everything static in the working CRS ``crs``."""

    crs: pyproj.CRS
    buildings: np.ndarray       # shapely polygons (class I)
    walls: np.ndarray           # (W, 4) x0, y0, x1, y1 of building outline segments
    wall_height: np.ndarray     # (W,)
    furniture: Solids           # class U
    roads: np.ndarray           # drivable centre lines (shapely), working CRS
    road_width_m: np.ndarray    # per road
    graph: RoadGraph
    map_layers: MapLayers       # the input map, untouched (written back as map.geojson)


def read_map_layers(map_path: Path, roads_path: Path | None = None) -> MapLayers:
    """Buildings and highway lines from an OSM-style GeoJSON / GeoPackage (one file with
    both, or buildings in ``map_path`` and highways in ``roads_path``). Buildings: polygons
    with a ``building`` value or in a layer named ``buildings``; roads: LineStrings with a
    ``highway`` value or in a layer named ``roads`` / ``streets`` (class ``unclassified``).

    Kept behind this one function so it can be replaced by ``evperc.geo.maps.load_map``.
    """
    import fiona

    polys, lines, classes, crs = [], [], [], None
    for path in [p for p in (map_path, roads_path) if p is not None]:
        if not Path(path).is_file():
            raise MapError(f"{path}: map file not found; give an existing GeoJSON or GPKG")
        try:
            layers = fiona.listlayers(path)
            for layer in layers:
                with fiona.open(path, layer=layer) as src:
                    crs = crs or pyproj.CRS.from_user_input(src.crs_wkt or "OGC:CRS84")
                    for feat in src:
                        if feat.geometry is None:
                            continue
                        geom = shapely.geometry.shape(feat.geometry)
                        props = dict(feat.properties or {})
                        if (geom.geom_type in ("Polygon", "MultiPolygon")
                                and (props.get("building") or layer in _BUILDING_LAYERS)):
                            polys.append(geom)
                        elif geom.geom_type == "LineString" and (props.get("highway")
                                                                 or layer in _ROAD_LAYERS):
                            lines.append(geom)
                            classes.append(str(props.get("highway") or "unclassified"))
        except fiona.errors.FionaError as err:
            raise MapError(f"{path}: cannot read map ({err})") from err
    if not polys:
        raise MapError(f"{map_path}: no building polygons; give a map with buildings")
    if not lines:
        raise MapError(f"{roads_path or map_path}: no highway=* lines; give --roads with the "
                       "road centre lines")
    return MapLayers(np.array(polys, dtype=object), np.array(lines, dtype=object),
                     np.array(classes, dtype=object), crs)


def utm_crs_for(lon: float, lat: float) -> pyproj.CRS:
    """The WGS 84 / UTM zone CRS holding ``(lon, lat)``."""
    try:
        from evperc.geo.crs import utm_crs_for as shared
    except ImportError:
        zone = int((lon + 180.0) // 6.0) + 1
        return pyproj.CRS.from_epsg((32600 if lat >= 0 else 32700) + zone)
    return shared(lon, lat)


def project_layers(layers: MapLayers, crs: pyproj.CRS | None) -> tuple[MapLayers, pyproj.CRS]:
    """The layers in ``crs`` (default: the UTM zone of the map's centre)."""
    if crs is None:
        to_geo = pyproj.Transformer.from_crs(layers.crs, "OGC:CRS84", always_xy=True)
        cx, cy = shapely.get_coordinates(shapely.centroid(shapely.union_all(
            shapely.envelope(layers.buildings)))).ravel()
        lon, lat = to_geo.transform(cx, cy)
        crs = utm_crs_for(lon, lat)
    tf = pyproj.Transformer.from_crs(layers.crs, crs, always_xy=True)

    def move(geoms: np.ndarray) -> np.ndarray:
        return shapely.transform(geoms, lambda xy: np.column_stack(tf.transform(*xy.T)))

    return MapLayers(move(layers.buildings), move(layers.roads), layers.highway, crs), crs


def build_scene(layers: MapLayers, road_widths: dict[str, float], default_width_m: float,
                crs: pyproj.CRS | None, rng: np.random.Generator,
                furniture_spacing_m: float) -> Scene:
    """Project the map, build the road graph, and scatter unmapped furniture on pavements."""
    local, crs = project_layers(layers, crs)
    drivable = np.array([h in DRIVABLE for h in local.highway], dtype=bool)
    if not drivable.any():
        raise MapError("map: no drivable highway lines (primary, residential, service, …)")
    roads = local.roads[drivable]
    widths = np.array([road_widths.get(h, default_width_m) for h in local.highway[drivable]])
    widths = np.where(widths > 0, widths, default_width_m)
    graph = RoadGraph.from_lines(roads, widths)
    buildings = shapely.make_valid(local.buildings)
    walls, heights = _walls(buildings, rng)
    furniture = _furniture(roads, widths, buildings, rng, furniture_spacing_m)
    log.info("scene: %d buildings (%d walls), %d roads, %d unmapped objects, CRS %s",
             len(buildings), len(walls), len(roads), len(furniture), crs.to_string())
    return Scene(crs, buildings, walls, heights, furniture, roads, widths, graph, layers)


def _walls(buildings: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Outline segments of every building ring, with one height per building (8–25 m)."""
    parts, part_building = shapely.get_parts(buildings, return_index=True)
    rings, ring_part = shapely.get_rings(parts, return_index=True)
    coords, ring_index = shapely.get_coordinates(rings, return_index=True)
    same = ring_index[1:] == ring_index[:-1]
    segs = np.column_stack([coords[:-1][same], coords[1:][same]])
    building_height = rng.uniform(8.0, 25.0, size=len(buildings))
    heights = building_height[part_building[ring_part[ring_index[:-1][same]]]]
    return segs, heights


def _curb_samples(roads: np.ndarray, widths: np.ndarray, spacing_m: float,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                     np.ndarray]:
    """Random points along the roads about every ``spacing_m``: (x, y, heading, width)."""
    lengths = shapely.length(roads)
    counts = rng.poisson(lengths / spacing_m)
    road = np.repeat(np.arange(len(roads)), counts)
    s = rng.uniform(0.0, 1.0, size=len(road)) * lengths[road]
    here = shapely.line_interpolate_point(roads[road], s)
    ahead = shapely.line_interpolate_point(roads[road], np.minimum(s + 0.5, lengths[road]))
    behind = shapely.line_interpolate_point(roads[road], np.maximum(s - 0.5, 0.0))
    p = shapely.get_coordinates(here)
    d = shapely.get_coordinates(ahead) - shapely.get_coordinates(behind)
    return p[:, 0], p[:, 1], np.arctan2(d[:, 1], d[:, 0]), widths[road]


def kerb_offset_m(width_m: np.ndarray) -> np.ndarray:
    """Lateral offset of parked cars' centres from the centre line: inside the road edge."""
    return np.maximum(np.asarray(width_m) / 2.0 - 0.9, 3.5)


def _furniture(roads: np.ndarray, widths: np.ndarray, buildings: np.ndarray,
               rng: np.random.Generator, spacing_m: float) -> Solids:
    """Poles, trees and bollards on the pavement edge, fences along the back of pavements,
    kept out of buildings and off road surfaces."""
    x, y, heading, width = _curb_samples(roads, widths, spacing_m, rng)
    n = len(x)
    side = rng.choice([-1.0, 1.0], size=n)
    is_fence = rng.random(n) < 0.15
    offset = kerb_offset_m(width) + np.where(is_fence, 5.0, 1.4)
    px = x + side * offset * np.sin(heading)
    py = y - side * offset * np.cos(heading)
    kind_pick = rng.integers(0, 3, size=n)               # pole, tree trunk, bollard
    radius = np.choose(kind_pick, [0.12, 0.3, 0.1])
    height = np.choose(kind_pick, [6.0, 5.0, 1.0])
    length = np.where(is_fence, rng.uniform(4.0, 12.0, n), 2 * radius)
    solids = Solids(
        kind=np.where(is_fence, BOX, CYLINDER).astype(np.int8), x=px, y=py, heading=heading,
        length=length, width=np.where(is_fence, 0.1, 2 * radius),
        height=np.where(is_fence, 1.2, height), label=np.full(n, UNMAPPED, dtype=np.uint8))
    footprints = solids.polygons()
    surfaces = shapely.buffer(roads, widths / 2.0, cap_style="flat")
    blocked = shapely.STRtree(np.concatenate([buildings, surfaces]))
    hit = np.unique(blocked.query(footprints, predicate="intersects")[0])
    keep = np.ones(n, dtype=bool)
    keep[hit] = False
    return select(solids, keep)


def select(solids: Solids, keep: np.ndarray) -> Solids:
    """The solids where ``keep`` is true."""
    return Solids(*(getattr(solids, f)[keep] for f in Solids.__dataclass_fields__))
