"""Map files → building and road-surface polygons in a metric working CRS (method.md §4, §7).

Sources (read with fiona: GeoJSON, Shapefile, GeoPackage, anything GDAL reads as vectors):

* ``--map`` and ``--roads`` as two files: every polygon of the first is a building (if its
  layer has a ``building`` key, only features with ``building`` set and not ``no``); in the
  second, polygons are road surfaces as they are and lines are buffered into surfaces.
* one multi-layer file with layers ``buildings`` and ``roads`` / ``streets`` (or the names
  in ``map.building_layer`` / ``map.road_layer``);
* one OSM-style file: ``building=*`` polygons are buildings, ``highway=*`` lines are roads.

A line is buffered by half the width ``map.road_width_m[class]`` of its ``highway`` class
(``map.default_road_width_m`` for a missing or unknown class; width 0 = not a road surface,
dropped), AFTER projecting it into the working CRS so that metres are metres. The working
CRS is ``map.crs``, else the UTM zone of the map's centre (:mod:`evperc.geo.crs`).
Invalid polygons are repaired with ``shapely.make_valid`` (polygonal parts kept) and counted.
"""

from __future__ import annotations

import json
import logging
import math
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import fiona
import fiona.errors
import numpy as np
import pyproj
import pyproj.exceptions
import shapely
import shapely.geometry

from evperc.errors import MapError
from evperc.geo.crs import LONLAT, transformer, working_crs

log = logging.getLogger(__name__)

AUTO_BUILDING_LAYERS = ("buildings",)
AUTO_ROAD_LAYERS = ("roads", "streets")
BUILDING_KEY = "building"
HIGHWAY_KEY = "highway"

_POLYGONAL = (shapely.GeometryType.POLYGON, shapely.GeometryType.MULTIPOLYGON)
_LINEAR = (shapely.GeometryType.LINESTRING, shapely.GeometryType.MULTILINESTRING,
           shapely.GeometryType.LINEARRING)
_BUFFER_QUAD_SEGS = 4


@dataclass(frozen=True, eq=False)
class MapData:
    """Building footprints and road surfaces (1-D object arrays of shapely polygons /
    multipolygons) in ``crs``; ``source`` names the file(s), ``repaired`` counts the invalid
    polygons that were repaired on loading."""

    buildings: np.ndarray
    roads: np.ndarray
    crs: pyproj.CRS
    source: str
    repaired: int = 0

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of all polygons in ``crs``; NaNs when there are none."""
        both = np.concatenate([self.buildings, self.roads])
        if len(both) == 0:
            return (math.nan,) * 4
        return tuple(float(v) for v in shapely.total_bounds(both))

    def to_crs(self, crs: pyproj.CRS) -> MapData:
        """The same polygons with their vertices transformed into ``crs`` (pyproj,
        ``always_xy``); returns ``self`` when ``crs`` is already the map's CRS."""
        crs = pyproj.CRS.from_user_input(crs)
        if crs == self.crs:
            return self
        tr = transformer(self.crs, crs)
        return MapData(_transform(self.buildings, tr), _transform(self.roads, tr), crs,
                       self.source, self.repaired)


@dataclass
class _Layer:
    """The features of one layer as read: geometries (2-D) with their two OSM tags."""

    path: Path
    name: str
    crs: pyproj.CRS
    geoms: np.ndarray
    building: np.ndarray  # object: the ``building`` value or None
    highway: np.ndarray   # object: the ``highway`` value or None
    has_building_key: bool
    has_highway_key: bool


def load_map(map_path: str | Path, roads_path: str | Path | None = None, *,
             config_map: Mapping[str, Any]) -> MapData:
    """Read buildings and road surfaces into :class:`MapData` in the working CRS.

    ``config_map`` is the ``[map]`` table of the config (layer names, road widths, ``crs``).
    Raises :class:`MapError` (one line, naming the file and the fix) when a file is missing,
    unreadable, empty, has no CRS, or holds no building or road feature."""
    map_path = Path(map_path)
    if roads_path is None:
        building_sel, road_sel = _select_combined(map_path, config_map)
    else:
        roads_path = Path(roads_path)
        building_sel = _select_dedicated(map_path, "--map", "building_layer",
                                         AUTO_BUILDING_LAYERS, config_map)
        road_sel = _select_dedicated(roads_path, "--roads", "road_layer", AUTO_ROAD_LAYERS,
                                     config_map)
    source = str(map_path) if roads_path is None else f"{map_path} + {roads_path}"
    for sel in ([building_sel + road_sel] if roads_path is None else [building_sel, road_sel]):
        if sum(len(layer.geoms) for layer, _ in sel) == 0:
            path = sel[0][0].path
            raise MapError(f"{path}: the file holds no features with a geometry; give a map "
                           "file with building / road features")

    polys_b, polys_r, lines_r, widths = [], [], [], []
    for layer, role in building_sel + road_sel:
        b, rp, rl, w = _classify(layer, role, config_map)
        polys_b.append((layer, b))
        polys_r.append((layer, rp))
        lines_r.append((layer, rl))
        widths.append(w)
    n_found = sum(len(g) for _, g in polys_b + polys_r + lines_r)
    if n_found == 0:
        looked = ", ".join(f"'{layer.name}'" for layer, _ in building_sel + road_sel)
        where = str(map_path) if roads_path is None else source
        raise MapError(
            f"{where}: no building or road features (looked in layer(s) {looked} for polygons "
            f"tagged '{BUILDING_KEY}' and lines tagged '{HIGHWAY_KEY}', and for layers "
            f"{'/'.join(AUTO_BUILDING_LAYERS + AUTO_ROAD_LAYERS)}); tag the features or name "
            "the layers with map.building_layer / map.road_layer")

    crs = working_crs(config_map.get("crs", ""), _centre_lonlat(polys_b + polys_r + lines_r))
    buildings = _project(polys_b, crs)
    road_polys = _project(polys_r, crs)
    road_lines = _project(lines_r, crs)
    road_widths = np.concatenate(widths) if widths else np.zeros(0)

    buildings, n_bad_b = _repair(buildings)
    road_polys, n_bad_r = _repair(road_polys)
    repaired = n_bad_b + n_bad_r
    if repaired:
        log.warning("%s: repaired %d invalid polygon(s) (make_valid, polygonal parts kept)",
                    source, repaired)
    surfaces = shapely.buffer(road_lines, road_widths / 2.0, quad_segs=_BUFFER_QUAD_SEGS)
    roads = _concat([road_polys, surfaces])
    roads = roads[~shapely.is_empty(roads)]
    log.info("%s: %d buildings, %d road surfaces (%d buffered lines) in %s", source,
             len(buildings), len(roads), len(surfaces), crs.to_string())
    return MapData(buildings, roads, crs, source, repaired)


#: the last map read by :func:`load_map_cached` in this process: (key, MapData)
_last_map: tuple[tuple, MapData] | None = None
_last_map_lock = threading.Lock()


def load_map_cached(map_path: str | Path, roads_path: str | Path | None = None, *,
                    config_map: Mapping[str, Any]) -> MapData:
    """:func:`load_map`, remembering the last map read in this process: the same files (path,
    size and modification time) with the same ``[map]`` table give the same
    :class:`MapData` object instead of a new read. ``evperc batch`` runs many logs on one
    map in each worker process; a city map takes seconds to read, project and repair."""
    global _last_map
    map_key, roads_key = _file_key(map_path), _file_key(roads_path)
    key = (map_key, roads_key, json.dumps(dict(config_map), sort_keys=True, default=str))
    # a file given but unreadable is never looked up: load_map reports it
    readable = map_key is not None and (roads_path is None or roads_key is not None)
    with _last_map_lock:
        if readable and _last_map is not None and _last_map[0] == key:
            log.debug("%s: map reused from the previous run in this process", map_path)
            return _last_map[1]
    map_data = load_map(map_path, roads_path, config_map=config_map)
    with _last_map_lock:
        _last_map = (key, map_data)
    return map_data


def _file_key(path: str | Path | None) -> tuple[str, int, int] | None:
    """What identifies a file's content for :func:`load_map_cached`; None if unreadable
    (then :func:`load_map` reports it)."""
    if path is None:
        return None
    try:
        resolved = Path(path).expanduser().resolve()
        stat = resolved.stat()
    except OSError:
        return None
    return str(resolved), stat.st_size, stat.st_mtime_ns


def check_overlap(map_data: MapData, xy_bounds: Sequence[float]) -> None:
    """Raise :class:`MapError` when the drive's extent ``(xmin, ymin, xmax, ymax)`` (working
    CRS, the map's CRS) and the map's extent share no point."""
    mx0, my0, mx1, my1 = map_data.bounds
    x0, y0, x1, y1 = (float(v) for v in xy_bounds)
    if not (mx0 <= x1 and x0 <= mx1 and my0 <= y1 and y0 <= my1):  # False on NaN too
        raise MapError(
            f"{map_data.source}: the map (x {mx0:.0f}..{mx1:.0f}, y {my0:.0f}..{my1:.0f} m in "
            f"{map_data.crs.to_string()}) does not overlap the drive (x {x0:.0f}..{x1:.0f}, "
            f"y {y0:.0f}..{y1:.0f} m); give a map of the drive's area or check the "
            "geo-reference (input.origin_lat_deg / origin_lon_deg, GNSS, input.poses_crs)")


# --- choosing layers -------------------------------------------------------------------------

def _list_layers(path: Path, option: str) -> list[str]:
    if not path.exists():
        raise MapError(f"{path}: map file not found; check the path given to {option}")
    try:
        return list(fiona.listlayers(path))
    except (fiona.errors.FionaError, OSError) as err:
        raise MapError(
            f"{path}: not a readable vector file ({_one_line(err)}); give a GeoJSON, Shapefile "
            f"or GeoPackage to {option}") from err


def _find_layer(path: Path, layers: list[str], key: str, auto: tuple[str, ...],
                config_map: Mapping[str, Any]) -> str | None:
    """The configured layer (an error if absent) or the first automatic name present."""
    wanted = config_map.get(key, "")
    if wanted:
        if wanted not in layers:
            raise MapError(f"{path}: no layer '{wanted}' (map.{key}); its layers are "
                           f"{', '.join(layers)}")
        return wanted
    lower = {name.lower(): name for name in layers}
    return next((lower[a] for a in auto if a in lower), None)


def _select_combined(path: Path, config_map: Mapping[str, Any]
                     ) -> tuple[list[tuple[_Layer, str]], list[tuple[_Layer, str]]]:
    """Layers of one file with their roles: ``buildings`` / ``roads`` layers when named
    (config, or automatic names in a multi-layer file), else every layer OSM-style
    (``tagged``)."""
    layers = _list_layers(path, "--map")
    b_name = _find_layer(path, layers, "building_layer", AUTO_BUILDING_LAYERS, config_map)
    r_name = _find_layer(path, layers, "road_layer", AUTO_ROAD_LAYERS, config_map)
    configured = bool(config_map.get("building_layer") or config_map.get("road_layer"))
    if (configured or len(layers) > 1) and (b_name or r_name):
        if b_name is not None and b_name == r_name:
            return [(_read_layer(path, b_name), "tagged")], []
        b = [(_read_layer(path, b_name), "buildings")] if b_name else []
        r = [(_read_layer(path, r_name), "roads")] if r_name else []
        return b, r
    selected = []
    for name in layers:
        layer = _read_layer(path, name)
        role = "tagged"
        if not (layer.has_building_key or layer.has_highway_key):
            # an untagged single-purpose layer still says what it holds by its name
            role = ("buildings" if name == b_name else "roads" if name == r_name else role)
        selected.append((layer, role))
    return selected, []


def _select_dedicated(path: Path, option: str, key: str, auto: tuple[str, ...],
                      config_map: Mapping[str, Any]) -> list[tuple[_Layer, str]]:
    """The one layer of a buildings-only (``--map``) or roads-only (``--roads``) file."""
    layers = _list_layers(path, option)
    name = _find_layer(path, layers, key, auto, config_map)
    if name is None:
        if len(layers) != 1:
            raise MapError(
                f"{path}: {len(layers)} layers ({', '.join(layers)}) and none named "
                f"{' or '.join(auto)}; choose one with map.{key}")
        name = layers[0]
    role = "buildings" if option == "--map" else "roads"
    return [(_read_layer(path, name), role)]


# --- reading ---------------------------------------------------------------------------------

def _read_layer(path: Path, name: str) -> _Layer:
    try:
        with fiona.open(path, layer=name) as src:
            crs = _layer_crs(path, name, src)
            props = src.schema.get("properties", {})
            geoms, building, highway = [], [], []
            for feat in src:
                if feat.geometry is None:
                    continue
                geoms.append(shapely.geometry.shape(feat.geometry))
                building.append(feat.properties.get(BUILDING_KEY))
                highway.append(feat.properties.get(HIGHWAY_KEY))
    except (fiona.errors.FionaError, OSError) as err:
        raise MapError(f"{path}: cannot read layer '{name}' ({_one_line(err)}); check the file "
                       "opens in a GIS (e.g. ogrinfo) and export it again") from err
    arr = shapely.force_2d(np.array(geoms, dtype=object).reshape(-1))
    return _Layer(path, name, crs, arr, np.array(building, dtype=object),
                  np.array(highway, dtype=object), BUILDING_KEY in props, HIGHWAY_KEY in props)


def _layer_crs(path: Path, name: str, src: Any) -> pyproj.CRS:
    """The layer's CRS; GeoJSON without one is lon/lat (RFC 7946), others are an error."""
    wkt = src.crs_wkt
    if not wkt:
        if src.driver == "GeoJSON":
            return LONLAT
        fix = ("write its .prj" if src.driver == "ESRI Shapefile" else "assign one")
        raise MapError(
            f"{path}: layer '{name}' has no CRS; {fix}, e.g. "
            f"`ogr2ogr -a_srs EPSG:4326 fixed{path.suffix} {path}` with the right EPSG code")
    try:
        return pyproj.CRS.from_wkt(wkt)
    except pyproj.exceptions.CRSError as err:
        raise MapError(f"{path}: layer '{name}' has a CRS pyproj does not understand "
                       f"({_one_line(err)}); reproject the file, e.g. to EPSG:4326") from err


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split()) or type(err).__name__


# --- classifying, projecting, repairing -----------------------------------------------------

def _classify(layer: _Layer, role: str, config_map: Mapping[str, Any]
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(building polygons, road polygons, road lines, widths of those lines) of a layer."""
    types = shapely.get_type_id(layer.geoms)
    polygonal = np.isin(types, _POLYGONAL)
    linear = np.isin(types, _LINEAR)
    tagged_b = np.array([v is not None and str(v).lower() != "no" for v in layer.building],
                        dtype=bool)
    tagged_h = np.array([v is not None for v in layer.highway], dtype=bool)
    width = _widths(layer.highway, config_map)
    none = np.zeros(len(layer.geoms), dtype=bool)
    if role == "buildings":
        is_b = polygonal & (tagged_b if layer.has_building_key else True)
        is_rp, is_rl = none, none
    elif role == "roads":
        is_b = none
        is_rp = polygonal
        is_rl = linear & (width > 0)
    else:  # tagged: OSM style
        is_b = polygonal & tagged_b
        is_rp = polygonal & tagged_h & ~tagged_b & (width > 0)
        is_rl = linear & tagged_h & (width > 0)
    return layer.geoms[is_b], layer.geoms[is_rp], layer.geoms[is_rl], width[is_rl]


def _widths(highway: np.ndarray, config_map: Mapping[str, Any]) -> np.ndarray:
    """Road-surface width per feature from its highway class (default width if unknown)."""
    table = config_map["road_width_m"]
    default = float(config_map["default_road_width_m"])
    return np.array([float(table.get(str(v), default)) if v is not None else default
                     for v in highway], dtype=np.float64)


def _centre_lonlat(groups: list[tuple[_Layer, np.ndarray]]) -> tuple[float, float]:
    """(lon, lat) of the centre of the bounding box of all selected geometries."""
    boxes = []
    for layer, geoms in groups:
        if len(geoms):
            bx = shapely.total_bounds(geoms)
            boxes.append(transformer(layer.crs, LONLAT).transform_bounds(*bx))
    b = np.array(boxes, dtype=np.float64)
    lon = (b[:, 0].min() + b[:, 2].max()) / 2.0
    lat = (b[:, 1].min() + b[:, 3].max()) / 2.0
    if not (math.isfinite(lon) and math.isfinite(lat)):
        raise MapError(f"{groups[0][0].path}: coordinates cannot be placed on the Earth in the "
                       "file's CRS; check the file's CRS")
    return float(lon), float(lat)


def _transform(geoms: np.ndarray, tr: pyproj.Transformer) -> np.ndarray:
    """Every vertex of ``geoms`` through ``tr`` at once (``always_xy`` transformer)."""
    if len(geoms) == 0:
        return np.asarray(geoms, dtype=object)

    def apply(coords: np.ndarray) -> np.ndarray:
        x, y = tr.transform(coords[:, 0], coords[:, 1])
        return np.column_stack([x, y])

    return shapely.transform(geoms, apply)


def _project(groups: list[tuple[_Layer, np.ndarray]], crs: pyproj.CRS) -> np.ndarray:
    """The geometries of every layer, each transformed from its layer's CRS into ``crs``."""
    return _concat([_transform(g, transformer(layer.crs, crs)) for layer, g in groups])


def _repair(geoms: np.ndarray) -> tuple[np.ndarray, int]:
    """Invalid polygons → ``make_valid`` → their polygonal parts; empty results dropped.

    Returns the repaired array and how many geometries were invalid."""
    bad = np.flatnonzero(~shapely.is_valid(geoms))
    if bad.size == 0:
        return geoms, 0
    out = geoms.copy()
    fixed = shapely.make_valid(geoms[bad])
    parts, idx = shapely.get_parts(fixed, return_index=True)      # collections → members
    parts2, idx2 = shapely.get_parts(parts, return_index=True)    # multi-parts → single
    idx = idx[idx2]
    keep = shapely.get_type_id(parts2) == shapely.GeometryType.POLYGON
    polys = np.full(bad.size, shapely.MultiPolygon(), dtype=object)
    if keep.any():
        shapely.multipolygons(parts2[keep], indices=idx[keep], out=polys)
    out[bad] = polys
    return out[~shapely.is_empty(out)], int(bad.size)


def _concat(arrays: list[np.ndarray]) -> np.ndarray:
    if not arrays:
        return np.zeros(0, dtype=object)
    return np.concatenate([np.asarray(a, dtype=object) for a in arrays])
