"""Map loading (method.md §4, §7): real OSM extracts, other CRSs, OSM-style files, repair, errors.

Expected values come from the raw files read with json / fiona and projected with pyproj
directly, never from evperc's own output."""

from __future__ import annotations

import json
import math
from pathlib import Path

import fiona
import numpy as np
import pyproj
import pytest
import shapely
from shapely.geometry import mapping

from evperc.config import default_config
from evperc.errors import MapError
from evperc.geo import maps
from evperc.geo.maps import MapData, check_overlap, load_map, load_map_cached

DATA = Path(__file__).parents[1] / "data" / "osm"
HELSINKI_B = DATA / "helsinki_buildings.geojson"
HELSINKI_R = DATA / "helsinki_roads.geojson"
PRAGUE = DATA / "prague_bubenec.gpkg"
GEOD = pyproj.Geod(ellps="WGS84")


@pytest.fixture
def cfg() -> dict:
    return default_config()["map"]


def to_utm35(lon: float, lat: float) -> tuple[float, float]:
    return pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32635", always_xy=True).transform(
        lon, lat)


def write_geojson(path: Path, features: list[tuple[object, dict]], crs: str | None = None
                  ) -> Path:
    doc: dict = {"type": "FeatureCollection",
                 "features": [{"type": "Feature", "properties": props,
                               "geometry": mapping(geom) if geom is not None else None}
                              for geom, props in features]}
    if crs:
        doc["crs"] = {"type": "name", "properties": {"name": crs}}
    path.write_text(json.dumps(doc))
    return path


def write_vector(path: Path, driver: str, crs: str, geoms: list, props: list[dict],
                 schema_props: dict[str, str], layer: str | None = None) -> Path:
    gtype = shapely.get_type_id(geoms[0])
    name = {3: "Polygon", 6: "MultiPolygon", 1: "LineString"}[int(gtype)]
    if len({int(t) for t in shapely.get_type_id(geoms)}) > 1:
        name = "Unknown"
    schema = {"geometry": name, "properties": schema_props}
    kwargs = {"layer": layer} if layer else {}
    with fiona.open(path, "w", driver=driver, crs=crs, schema=schema, **kwargs) as dst:
        for g, p in zip(geoms, props, strict=True):
            dst.write(fiona.Feature.from_dict({"geometry": mapping(g), "properties": p}))
    return path


# --- real data -------------------------------------------------------------------------------

def helsinki_surfaces(cfg: dict) -> list[tuple[dict, float]]:
    """(feature, width) of each Helsinki highway line that is a road surface (width > 0)."""
    raw_r = json.loads(HELSINKI_R.read_text())["features"]
    table = cfg["road_width_m"]
    width = [table.get(f["properties"]["highway"], cfg["default_road_width_m"]) for f in raw_r]
    return [(f, w) for f, w in zip(raw_r, width, strict=True) if w > 0]


def test_helsinki_two_files(cfg: dict) -> None:
    raw_b = json.loads(HELSINKI_B.read_text())["features"]
    surfaces = helsinki_surfaces(cfg)

    m = load_map(HELSINKI_B, HELSINKI_R, config_map=cfg)

    assert len(m.buildings) == len(raw_b) == 446
    assert len(m.roads) == len(surfaces)
    assert m.crs.to_epsg() == 32635
    assert m.repaired == 0
    # first vertex of the first building, projected independently
    lon, lat = raw_b[0]["geometry"]["coordinates"][0][0][0]
    assert shapely.get_coordinates(m.buildings[0])[0] == pytest.approx(to_utm35(lon, lat),
                                                                        abs=1e-6)
    # buffered road area ≈ Σ (geodesic length · width + round caps), less overlap at bends;
    # UTM scale k² ≈ 0.9995 here
    expected = sum(GEOD.line_length(*np.array(f["geometry"]["coordinates"]).T) * w
                   + math.pi * (w / 2) ** 2 for f, w in surfaces)
    area = float(shapely.area(m.roads).sum())
    assert 0.95 * expected < area < 1.0 * expected
    # building areas match geodesic areas within the UTM scale distortion
    geodesic = sum(abs(GEOD.geometry_area_perimeter(shapely.geometry.shape(f["geometry"]))[0])
                   for f in raw_b)
    assert float(shapely.area(m.buildings).sum()) == pytest.approx(geodesic, rel=2e-3)


def test_helsinki_single_files_are_read_osm_style(cfg: dict) -> None:
    roads = load_map(HELSINKI_R, config_map=cfg)
    assert len(roads.buildings) == 0 and len(roads.roads) == len(helsinki_surfaces(cfg))
    buildings = load_map(HELSINKI_B, config_map=cfg)
    assert len(buildings.buildings) == 446 and len(buildings.roads) == 0


def test_prague_geopackage_layers(cfg: dict) -> None:
    m = load_map(PRAGUE, config_map=cfg)
    assert m.crs.to_epsg() == 32633
    assert len(m.buildings) == 144 and len(m.roads) == 35
    with fiona.open(PRAGUE, layer="buildings") as src:
        raw = np.array([shapely.geometry.shape(f.geometry) for f in src])
    tr = pyproj.Transformer.from_crs("EPSG:3857", "EPSG:32633", always_xy=True)
    expected = shapely.transform(raw, lambda c: np.column_stack(tr.transform(c[:, 0], c[:, 1])))
    assert float(shapely.area(m.buildings).sum()) == pytest.approx(
        float(shapely.area(expected).sum()), rel=1e-9)
    # streets have no highway tag: default width 6 m; area ≈ 6 m · true length + caps
    with fiona.open(PRAGUE, layer="streets") as src:
        lines = [np.array(f.geometry.coordinates) for f in src]
    to_ll = pyproj.Transformer.from_crs("EPSG:3857", "EPSG:4326", always_xy=True)
    lengths = [GEOD.line_length(*to_ll.transform(c[:, 0], c[:, 1])) for c in lines]
    expected_area = sum(6.0 * length + math.pi * 9.0 for length in lengths)
    assert float(shapely.area(m.roads).sum()) == pytest.approx(expected_area, rel=0.03)


def test_configured_layer_names(cfg: dict) -> None:
    cfg = dict(cfg, building_layer="tessellation", road_layer="streets")
    m = load_map(PRAGUE, config_map=cfg)
    plain = load_map(PRAGUE, config_map=default_config()["map"])
    # tessellation cells cover the plots, far more than the footprints
    assert shapely.area(m.buildings).sum() > 2 * shapely.area(plain.buildings).sum()
    with pytest.raises(MapError, match=r"no layer 'houses' \(map.building_layer\).*buildings"):
        load_map(PRAGUE, config_map=dict(cfg, building_layer="houses"))


# --- other CRSs ------------------------------------------------------------------------------

def test_shapefile_in_kkj_reprojects_like_pyproj(tmp_path: Path, cfg: dict) -> None:
    lon, lat = 24.9414, 60.1699
    x, y = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:2393", always_xy=True).transform(
        lon, lat)
    square = shapely.box(x, y, x + 20.0, y + 10.0)
    shp = write_vector(tmp_path / "houses.shp", "ESRI Shapefile", "EPSG:2393", [square],
                       [{"building": "yes"}], {"building": "str"})
    m = load_map(shp, config_map=cfg)
    assert m.crs.to_epsg() == 32635
    corner = shapely.get_coordinates(m.buildings[0])
    # the vertex written at (x, y) is the lon/lat point, projected by pyproj on its own
    d = np.hypot(*(corner - np.array(to_utm35(lon, lat))).T)
    assert d.min() < 0.01
    assert float(shapely.area(m.buildings[0])) == pytest.approx(200.0, rel=2e-3)


def test_same_buildings_in_two_crs_rasterise_alike(tmp_path: Path, cfg: dict) -> None:
    from evperc.geo.prior import PriorRasteriser
    from evperc.geo.window import Window

    with fiona.open(HELSINKI_B) as src:
        raw = np.array([shapely.geometry.shape(f.geometry) for f in src])
    tr = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:3067", always_xy=True)
    in_3067 = shapely.transform(raw, lambda c: np.column_stack(tr.transform(c[:, 0], c[:, 1])))
    shp = write_vector(tmp_path / "b3067.shp", "ESRI Shapefile", "EPSG:3067", list(in_3067),
                       [{"building": "yes"}] * len(raw), {"building": "str"})
    a = load_map(HELSINKI_B, config_map=cfg)
    b = load_map(shp, config_map=cfg)
    assert b.crs.to_epsg() == 32635 and len(b.buildings) == len(a.buildings)
    x, y = to_utm35(24.944, 60.170)
    w = Window.centred_on(x, y, 150.0, 0.5)
    la = PriorRasteriser(a, 0.5, 64).labels(w)
    lb = PriorRasteriser(b, 0.5, 64).labels(w)
    assert 0.2 < (la == 2).mean() < 0.8
    diff = la != lb
    # any difference must sit on a label boundary of the reference
    pad = np.pad(la, 1, mode="edge")
    neighbours = np.stack([pad[1 + dr:1 + dr + la.shape[0], 1 + dc:1 + dc + la.shape[1]]
                           for dr in (-1, 0, 1) for dc in (-1, 0, 1)])
    boundary = (neighbours != la).any(axis=0)
    assert not (diff & ~boundary).any()
    assert diff.mean() < 0.002


def test_geojson_without_crs_member_is_lonlat(tmp_path: Path, cfg: dict) -> None:
    lon, lat = 14.40, 50.10
    d = 0.0002
    poly = shapely.box(lon, lat, lon + d, lat + d)
    path = write_geojson(tmp_path / "b.geojson", [(poly, {"building": "yes"})])
    m = load_map(path, config_map=cfg)
    assert m.crs.to_epsg() == 32633
    expected = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32633", always_xy=True).transform(
        lon, lat)
    assert np.hypot(*(shapely.get_coordinates(m.buildings[0]) - expected).T).min() < 1e-6


def test_config_crs_wins(cfg: dict) -> None:
    m = load_map(HELSINKI_B, config_map=dict(cfg, crs="EPSG:3067"))
    assert m.crs.to_epsg() == 3067


def test_to_crs_round_trip_and_bounds(cfg: dict) -> None:
    m = load_map(PRAGUE, config_map=cfg)
    assert m.to_crs(pyproj.CRS.from_epsg(32633)) is m
    other = m.to_crs(pyproj.CRS.from_epsg(3035))
    assert other.crs.to_epsg() == 3035 and len(other.roads) == len(m.roads)
    back = other.to_crs(m.crs)
    assert np.allclose(shapely.get_coordinates(back.buildings),
                       shapely.get_coordinates(m.buildings), atol=1e-4)
    xmin, ymin, xmax, ymax = m.bounds
    coords = np.concatenate([shapely.get_coordinates(m.buildings),
                             shapely.get_coordinates(m.roads)])
    assert (xmin, ymin) == pytest.approx(tuple(coords.min(axis=0)))
    assert (xmax, ymax) == pytest.approx(tuple(coords.max(axis=0)))


# --- one OSM-style file ----------------------------------------------------------------------

def test_osm_style_file_with_buildings_and_highways(tmp_path: Path, cfg: dict) -> None:
    lon, lat = 24.9414, 60.1699
    d = 0.0005  # ≈ 28 m east-west, 56 m north-south
    line = shapely.LineString([(lon, lat), (lon + 4 * d, lat)])
    features = [
        (shapely.box(lon, lat + d, lon + d, lat + 2 * d), {"building": "yes"}),
        (shapely.box(lon + d, lat + d, lon + 2 * d, lat + 2 * d), {"building": "no"}),
        (shapely.box(lon, lat - 3 * d, lon + d, lat - 2 * d), {"landuse": "grass"}),
        (line, {"highway": "residential"}),                        # 7 m
        (shapely.LineString([(lon, lat + 3 * d), (lon + d, lat + 3 * d)]),
         {"highway": "footway"}),                                   # 0 m: not a road
        (shapely.LineString([(lon, lat - d), (lon + d, lat - d)]),
         {"highway": "bogus_class"}),                               # default 6 m
        (shapely.box(lon + 2 * d, lat - 2 * d, lon + 3 * d, lat - d),
         {"highway": "pedestrian", "area": "yes"}),                 # 0 m: dropped
        (shapely.box(lon + 3 * d, lat - 2 * d, lon + 4 * d, lat - d),
         {"highway": "service", "area": "yes"}),                    # road polygon as is
        (shapely.Point(lon, lat), {"highway": "bus_stop"}),
        (None, {"building": "yes"}),
    ]
    m = load_map(write_geojson(tmp_path / "osm.geojson", features), config_map=cfg)
    assert len(m.buildings) == 1 and len(m.roads) == 3
    # the residential surface: 3.4 m from the centre line inside, 3.6 m outside
    (x0, y0), (x1, _) = to_utm35(lon, lat), to_utm35(lon + 4 * d, lat)
    mid_x = (x0 + x1) / 2
    mid_y = float(np.interp(mid_x, [x0, x1], [y0, to_utm35(lon + 4 * d, lat)[1]]))
    roads = shapely.union_all(m.roads)
    assert shapely.intersects_xy(roads, mid_x, mid_y + 3.4)
    assert not shapely.intersects_xy(roads, mid_x, mid_y + 3.6)
    # the unknown class gets the default width (6 m): 2.9 m in, 3.1 m out
    bx0, by0 = to_utm35(lon, lat - d)
    bx1, by1 = to_utm35(lon + d, lat - d)
    cx, cy = (bx0 + bx1) / 2, (by0 + by1) / 2
    assert shapely.intersects_xy(roads, cx, cy - 2.9)
    assert not shapely.intersects_xy(roads, cx, cy - 3.1)


def test_invalid_polygons_are_repaired(tmp_path: Path, cfg: dict, caplog) -> None:
    lon, lat = 24.9414, 60.1699
    d = 0.0002
    bowtie = shapely.Polygon([(lon, lat), (lon + d, lat + d), (lon + d, lat), (lon, lat + d)])
    good = shapely.box(lon + 2 * d, lat, lon + 3 * d, lat + d)
    path = write_geojson(tmp_path / "b.geojson", [(bowtie, {"building": "yes"}),
                                                  (good, {"building": "yes"})])
    with caplog.at_level("WARNING"):
        m = load_map(path, config_map=cfg)
    assert m.repaired == 1
    assert shapely.is_valid(m.buildings).all()
    assert shapely.get_type_id(m.buildings[0]) == shapely.GeometryType.MULTIPOLYGON
    # the two triangles of the bow-tie: half of the square's area
    assert shapely.area(m.buildings[0]) == pytest.approx(shapely.area(m.buildings[1]) / 2,
                                                         rel=1e-3)
    assert sum("repaired 1 invalid" in r.message for r in caplog.records) == 1


# --- errors: one line, naming the file -------------------------------------------------------

def one_line(err: pytest.ExceptionInfo, path: Path | str) -> str:
    msg = str(err.value)
    assert "\n" not in msg
    assert str(path) in msg
    return msg


def test_missing_files(tmp_path: Path, cfg: dict) -> None:
    with pytest.raises(MapError) as err:
        load_map(tmp_path / "nope.geojson", config_map=cfg)
    assert "not found" in one_line(err, tmp_path / "nope.geojson") and "--map" in str(err.value)
    with pytest.raises(MapError) as err:
        load_map(HELSINKI_B, tmp_path / "roads.gpkg", config_map=cfg)
    assert "--roads" in one_line(err, tmp_path / "roads.gpkg")


def test_not_a_vector_file(tmp_path: Path, cfg: dict) -> None:
    path = tmp_path / "map.geojson"
    path.write_text("this is not\na map\n")
    with pytest.raises(MapError) as err:
        load_map(path, config_map=cfg)
    assert "not a readable vector file" in one_line(err, path)


def test_no_features(tmp_path: Path, cfg: dict) -> None:
    path = write_geojson(tmp_path / "empty.geojson", [])
    with pytest.raises(MapError) as err:
        load_map(path, config_map=cfg)
    assert "no features" in one_line(err, path)


def test_no_building_or_road_features(tmp_path: Path, cfg: dict) -> None:
    path = write_geojson(tmp_path / "landuse.geojson",
                         [(shapely.box(24.94, 60.17, 24.941, 60.171), {"landuse": "grass"})])
    with pytest.raises(MapError) as err:
        load_map(path, config_map=cfg)
    msg = one_line(err, path)
    assert "'building'" in msg and "'highway'" in msg and "map.building_layer" in msg


def test_shapefile_without_prj(tmp_path: Path, cfg: dict) -> None:
    shp = write_vector(tmp_path / "b.shp", "ESRI Shapefile", "EPSG:3067",
                       [shapely.box(385000, 6672000, 385010, 6672010)], [{"building": "yes"}],
                       {"building": "str"})
    (tmp_path / "b.prj").unlink()
    with pytest.raises(MapError) as err:
        load_map(shp, config_map=cfg)
    assert "no CRS" in one_line(err, shp) and ".prj" in str(err.value)


def test_multi_layer_roads_file_without_a_roads_layer(tmp_path: Path, cfg: dict) -> None:
    gpkg = tmp_path / "two.gpkg"
    for layer in ("a", "b"):
        write_vector(gpkg, "GPKG", "EPSG:32635", [shapely.box(0, 0, 1, 1)], [{"k": "v"}],
                     {"k": "str"}, layer=layer)
    with pytest.raises(MapError) as err:
        load_map(HELSINKI_B, gpkg, config_map=cfg)
    assert "map.road_layer" in one_line(err, gpkg)


def test_no_overlap_quotes_both_extents(cfg: dict) -> None:
    m = load_map(PRAGUE, config_map=cfg)
    xmin, ymin, xmax, ymax = m.bounds
    check_overlap(m, (xmax - 10, ymax - 10, xmax + 90, ymax + 90))  # touches: fine
    with pytest.raises(MapError) as err:
        check_overlap(m, (xmax + 1000, ymin, xmax + 1100, ymin + 100))
    msg = one_line(err, PRAGUE)
    assert f"x {xmin:.0f}..{xmax:.0f}" in msg and f"x {xmax + 1000:.0f}..{xmax + 1100:.0f}" in msg
    assert "EPSG:32633" in msg
    empty = MapData(np.zeros(0, object), np.zeros(0, object), m.crs, "empty.geojson")
    with pytest.raises(MapError):
        check_overlap(empty, (0, 0, 1, 1))


def test_untagged_files_named_by_layer(tmp_path: Path, cfg: dict) -> None:
    # no building / highway keys at all: a single-layer file named "buildings" holds buildings
    lon, lat = 24.9414, 60.1699
    d = 0.0002
    b = write_geojson(tmp_path / "buildings.geojson",
                      [(shapely.box(lon, lat, lon + d, lat + d), {"name": "a"})])
    m = load_map(b, config_map=cfg)
    assert len(m.buildings) == 1 and len(m.roads) == 0
    # a roads file without classes: lines get map.default_road_width_m, polygons kept
    line = shapely.LineString([(lon, lat - d), (lon + 5 * d, lat - d)])
    r = write_geojson(tmp_path / "r.geojson",
                      [(line, {}), (shapely.box(lon, lat - 4 * d, lon + d, lat - 3 * d), {})])
    m2 = load_map(b, r, config_map=dict(cfg, default_road_width_m=4.0))
    assert len(m2.buildings) == 1 and len(m2.roads) == 2
    (x0, y0), (x1, y1) = to_utm35(lon, lat - d), to_utm35(lon + 5 * d, lat - d)
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    assert shapely.intersects_xy(m2.roads[1], cx, cy + 1.9)
    assert not shapely.intersects_xy(m2.roads[1], cx, cy + 2.1)


def test_cached_map_is_reused_only_for_the_same_files_and_settings(
        tmp_path: Path, cfg: dict, monkeypatch: pytest.MonkeyPatch) -> None:
    """load_map_cached (evperc batch workers): the same file and [map] table give the same
    object without a new read; another road width, or the file changed on disk, read
    again; a missing file is an error every time."""
    reads = []
    monkeypatch.setattr(maps, "load_map", lambda *a, **k: reads.append(a) or load_map(*a, **k))
    path = tmp_path / "map.geojson"
    path.write_bytes(HELSINKI_B.read_bytes())
    first = load_map_cached(path, HELSINKI_R, config_map=cfg)
    assert load_map_cached(path, HELSINKI_R, config_map=dict(cfg)) is first
    assert len(reads) == 1
    wider = {**cfg, "default_road_width_m": cfg["default_road_width_m"] + 2}
    assert load_map_cached(path, HELSINKI_R, config_map=wider) is not first
    assert len(reads) == 2
    features = json.loads(path.read_text())
    features["features"] = features["features"][:10]
    path.write_text(json.dumps(features))
    fewer = load_map_cached(path, HELSINKI_R, config_map=wider)
    assert len(reads) == 3 and len(fewer.buildings) == 10 < len(first.buildings)
    for _ in range(2):
        with pytest.raises(MapError):
            load_map_cached(tmp_path / "gone.geojson", HELSINKI_R, config_map=cfg)
    # the buildings alone, then the same buildings with a roads file that is missing: the
    # error, not the map read without roads
    alone = load_map_cached(HELSINKI_B, config_map=cfg)
    assert load_map_cached(HELSINKI_B, config_map=cfg) is alone
    with pytest.raises(MapError, match="gone-roads.geojson"):
        load_map_cached(HELSINKI_B, tmp_path / "gone-roads.geojson", config_map=cfg)
