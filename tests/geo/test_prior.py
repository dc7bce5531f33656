"""The GIS prior grid (method.md §4): cell-centre classification against a brute-force check,
edge cases, priority, the tile cache, and the prior masses."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyproj
import pytest
import shapely
import shapely.affinity
from hypothesis import given, settings
from hypothesis import strategies as st

from evperc.config import default_config
from evperc.geo.maps import MapData, load_map
from evperc.geo.prior import (
    CONTEXT_BUILDING,
    CONTEXT_OTHER,
    CONTEXT_ROAD,
    MIN_INNER_MARGIN_M,
    PriorRasteriser,
    prior_masses,
)
from evperc.geo.window import Window

DATA = Path(__file__).parents[1] / "data" / "osm"
UTM35 = pyproj.CRS.from_epsg(32635)


def map_of(buildings: list, roads: list) -> MapData:
    return MapData(np.array(buildings, dtype=object).reshape(-1),
                   np.array(roads, dtype=object).reshape(-1), UTM35, "test")


def brute_force(md: MapData, window: Window) -> np.ndarray:
    """Every cell centre tested one by one with ``polygon.covers(point)``."""
    xs, ys = window.cell_centres()
    out = np.zeros(window.shape, dtype=np.uint8)
    for r, y in enumerate(ys):
        for c, x in enumerate(xs):
            p = shapely.Point(x, y)
            if any(g.covers(p) for g in md.buildings):
                out[r, c] = CONTEXT_BUILDING
            elif any(g.covers(p) for g in md.roads):
                out[r, c] = CONTEXT_ROAD
    return out


def random_map(seed: int) -> MapData:
    rng = np.random.default_rng(seed)

    def polygons(n: int) -> list:
        out = []
        for _ in range(n):
            cx, cy = rng.uniform(-15, 15, 2)
            rect = shapely.box(-rng.uniform(0.5, 4), -rng.uniform(0.5, 4),
                               rng.uniform(0.5, 4), rng.uniform(0.5, 4))
            out.append(shapely.affinity.translate(
                shapely.affinity.rotate(rect, rng.uniform(0, 180)), cx, cy))
        return out

    roads = polygons(6) + [shapely.buffer(shapely.LineString([(-20, -3), (5, 2), (20, 18)]),
                                          3.0)]
    return map_of(polygons(10), roads)


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize(("tile", "row0", "col0"), [(16, -30, -40), (7, -33, -29)])
def test_labels_match_brute_force(seed: int, tile: int, row0: int, col0: int) -> None:
    md = random_map(seed)
    w = Window(0.5, 70, 80, row0, col0)
    labels = PriorRasteriser(md, 0.5, tile).labels(w)
    expected = brute_force(md, w)
    assert labels.dtype == np.uint8 and labels.shape == (70, 80)
    assert np.array_equal(labels, expected)
    assert {0, 1, 2} <= set(np.unique(labels).tolist())


def test_centre_on_a_polygon_edge_counts_as_inside() -> None:
    # resolution 1 m: centres at k + 0.5; the square's edges and corners run through centres
    square = shapely.box(0.5, 0.5, 2.5, 2.5)
    md = map_of([square], [])
    labels = PriorRasteriser(md, 1.0, 8).labels(Window(1.0, 4, 4, 0, 0))
    expected = np.zeros((4, 4), dtype=np.uint8)
    expected[0:3, 0:3] = CONTEXT_BUILDING  # closed polygon: edge and corner centres inside
    assert np.array_equal(labels, expected)
    # shapely.contains would keep only the one interior centre
    assert not shapely.contains_xy(square, 0.5, 0.5) and shapely.contains_xy(square, 1.5, 1.5)
    # two buildings sharing the edge x = 1.5 leave no gap on it
    halves = map_of([shapely.box(0.0, 0.0, 1.5, 3.0), shapely.box(1.5, 0.0, 3.0, 3.0)], [])
    both = PriorRasteriser(halves, 1.0, 8).labels(Window(1.0, 3, 3, 0, 0))
    assert (both == CONTEXT_BUILDING).all()


def test_building_wins_over_road() -> None:
    md = map_of([shapely.box(2, 2, 4, 4)], [shapely.box(0, 0, 6, 6)])
    labels = PriorRasteriser(md, 1.0, 16).labels(Window(1.0, 8, 8, 0, 0))
    expected = np.zeros((8, 8), dtype=np.uint8)
    expected[0:6, 0:6] = CONTEXT_ROAD
    expected[2:4, 2:4] = CONTEXT_BUILDING
    assert np.array_equal(labels, expected)
    # row 0 is the southern row: a building in the north-west corner lands in the last row
    nw = map_of([shapely.box(0, 7, 1, 8)], [])
    lab = PriorRasteriser(nw, 1.0, 16).labels(Window(1.0, 8, 8, 0, 0))
    assert lab[7, 0] == CONTEXT_BUILDING and lab.sum() == CONTEXT_BUILDING


def test_tile_cache_reuses_tiles_and_matches_uncached() -> None:
    md = random_map(3)
    r = PriorRasteriser(md, 0.5, 32)
    w = Window(0.5, 40, 40, -20, -20)  # global rows/cols -20..19: tiles -1..0 → 4 tiles
    first = r.labels(w)
    assert r.stats == {"tiles_rasterised": 4, "tile_hits": 0, "tiles_cached": 4}
    moved = Window(0.5, 40, 40, -17, -22)  # a few cells, same four tiles
    again = r.labels(moved)
    assert r.stats["tiles_rasterised"] == 4 and r.stats["tile_hits"] == 4
    assert np.array_equal(again, r.rasterise(moved))
    assert np.array_equal(again, brute_force(md, moved))
    assert np.array_equal(first, PriorRasteriser(md, 0.5, 5).labels(w))
    # moving 20 cells east enters column-tile 1: two new tiles, two reused
    r.labels(Window(0.5, 40, 40, -20, 0))
    assert r.stats["tiles_rasterised"] == 6 and r.stats["tile_hits"] == 6


def test_cache_is_bounded_and_stays_correct() -> None:
    md = random_map(4)
    r = PriorRasteriser(md, 0.5, 8, max_tiles=4)
    fresh = PriorRasteriser(md, 0.5, 1000)
    for step in range(0, 60, 6):
        w = Window(0.5, 12, 12, -40 + step, -40 + step)
        assert np.array_equal(r.labels(w), fresh.rasterise(w))
        assert r.stats["tiles_cached"] <= 4
    # a window bigger than the cache still comes out whole
    big = Window(0.5, 60, 60, -30, -30)
    assert np.array_equal(r.labels(big), fresh.rasterise(big))


def test_resolution_mismatch_is_refused() -> None:
    r = PriorRasteriser(random_map(0), 0.5, 16)
    with pytest.raises(ValueError, match="resolution"):
        r.labels(Window(1.0, 4, 4, 0, 0))


def test_helsinki_window_matches_union_check() -> None:
    md = load_map(DATA / "helsinki_buildings.geojson", DATA / "helsinki_roads.geojson",
                  config_map=default_config()["map"])
    x, y = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32635", always_xy=True).transform(
        24.948, 60.166)
    w = Window.centred_on(x, y, 60.0, 0.5)
    labels = PriorRasteriser(md, 0.5, 256).labels(w)
    xs, ys = w.cell_centres()
    gx, gy = np.meshgrid(xs, ys)
    in_b = shapely.intersects_xy(shapely.union_all(md.buildings), gx, gy)
    in_r = shapely.intersects_xy(shapely.union_all(md.roads), gx, gy)
    expected = np.where(in_b, CONTEXT_BUILDING, np.where(in_r, CONTEXT_ROAD, CONTEXT_OTHER))
    assert np.array_equal(labels, expected)
    share = np.bincount(labels.ravel(), minlength=3) / labels.size
    assert (share > 0.1).all()  # buildings, roads and other in the window


def test_prior_masses_per_context() -> None:
    labels = np.array([[CONTEXT_OTHER, CONTEXT_ROAD], [CONTEXT_BUILDING, CONTEXT_OTHER]],
                      dtype=np.uint8)
    m = prior_masses(labels, 0.9, 0.7, 0.6)
    assert m.shape == (2, 2, 32) and m.dtype == np.float32
    # bit0 F, bit1 I, bit2 U, bit3 S, bit4 M
    fusm, fsm, i, omega = 0b11101, 0b11001, 0b00010, 0b11111
    expected = np.zeros((2, 2, 32))
    expected[0, 0, fusm], expected[0, 0, omega] = 0.6, 0.4
    expected[0, 1, fsm], expected[0, 1, omega] = 0.7, 0.3
    expected[1, 0, i], expected[1, 0, omega] = 0.9, 0.1
    expected[1, 1, fusm], expected[1, 1, omega] = 0.6, 0.4
    assert np.allclose(m, expected, atol=1e-7)
    assert prior_masses(labels, 0.9, 0.7, 0.6, dtype=np.float64).dtype == np.float64
    with pytest.raises(ValueError):
        prior_masses(labels, 1.2, 0.7, 0.6)


def test_widened_building_covers_cells_within_the_margin() -> None:
    # a 10 m square building [0, 10]² at 0.5 m cells, widened by 0.5 m. Cell column ix has
    # its centre at x = (ix + 0.5)·0.5: column 20 (x = 10.25, 0.25 m outside the east face)
    # becomes building, column 21 (x = 10.75, 0.75 m out) does not; at the north-east corner
    # the cell (20, 20) (centre 0.354 m from the corner) is in, (20, 21) (0.79 m) is out.
    from evperc.geo.maps import MapData

    square = shapely.box(0.0, 0.0, 10.0, 10.0)
    data = MapData(buildings=np.array([square], dtype=object),
                   roads=np.array([], dtype=object), crs=pyproj.CRS("EPSG:32635"),
                   source="test")
    window = Window(0.5, 30, 30, -5, -5)        # cells -5..24 in both axes
    plain = PriorRasteriser(data, 0.5, 16).labels(window)
    wide = PriorRasteriser(data, 0.5, 16, building_margin_m=0.5).labels(window)

    def at(labels: np.ndarray, iy: int, ix: int) -> int:
        return int(labels[iy - window.row0, ix - window.col0])

    assert at(plain, 5, 20) == CONTEXT_OTHER and at(wide, 5, 20) == CONTEXT_BUILDING
    assert at(wide, 5, 21) == CONTEXT_OTHER
    assert at(wide, 5, -1) == CONTEXT_BUILDING and at(wide, 5, -2) == CONTEXT_OTHER
    assert at(wide, 20, 20) == CONTEXT_BUILDING and at(wide, 20, 21) == CONTEXT_OTHER
    # the building grows by one ring of cells, corners included (0.354 m from the corner):
    # 20² → 22² cells
    assert int((plain == CONTEXT_BUILDING).sum()) == 400
    assert int((wide == CONTEXT_BUILDING).sum()) == 484


def widened_brute_force(md: MapData, margin: float, window: Window) -> np.ndarray:
    """:func:`brute_force` of the buildings buffered as :func:`widen_polygons` does, without
    roads (the runner's rasteriser of widened buildings)."""
    wide = shapely.buffer(md.buildings, margin, quad_segs=4)
    return brute_force(map_of(list(wide), []), window)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), margin=st.floats(1e-3, 3.0), tile=st.sampled_from([7, 16, 64]),
       row0=st.integers(-45, -20), col0=st.integers(-45, -20))
def test_widened_tiles_from_inner_match_brute_force(seed: int, margin: float, tile: int,
                                                    row0: int, col0: int) -> None:
    # the rasteriser of widened buildings takes the cells its inner (the prior's) labels
    # building without testing them: the same labels as testing every cell, checked one
    # centre at a time against the buffered polygons
    md = random_map(seed)
    buildings_only = map_of(list(md.buildings), [])
    inner = PriorRasteriser(md, 0.5, tile)
    wide = PriorRasteriser(buildings_only, 0.5, tile, building_margin_m=margin, inner=inner)
    w = Window(0.5, 50, 60, row0, col0)
    inner.labels(w)  # as the runner does: the prior's tiles first (wide fetches them anyway)
    labels = wide.labels(w)
    assert np.array_equal(labels, widened_brute_force(md, margin, w))
    assert np.array_equal(labels, PriorRasteriser(buildings_only, 0.5, tile,
                                                  building_margin_m=margin).labels(w))
    assert (labels == CONTEXT_BUILDING).any()


def test_widened_tiles_take_the_inner_building_cells_untested() -> None:
    # an inner that labels one more building than the widened rasteriser knows: its cells
    # come out building (taken, not tested); below the least margin the inner is ignored
    md = map_of([shapely.box(0.0, 0.0, 4.0, 4.0)], [])
    extra = map_of([shapely.box(0.0, 0.0, 4.0, 4.0), shapely.box(8.0, 8.0, 10.0, 10.0)], [])
    inner = PriorRasteriser(extra, 0.5, 16)
    w = Window(0.5, 30, 30, -5, -5)
    taken = PriorRasteriser(md, 0.5, 16, building_margin_m=0.5, inner=inner).labels(w)
    plain = PriorRasteriser(md, 0.5, 16, building_margin_m=0.5).labels(w)
    extra_cells = inner.labels(w) == CONTEXT_BUILDING
    extra_cells &= ~(plain == CONTEXT_BUILDING)
    assert extra_cells.sum() == 16  # the 2 m square's 4 × 4 cells
    assert (taken[extra_cells] == CONTEXT_BUILDING).all()
    assert np.array_equal(taken[~extra_cells], plain[~extra_cells])
    tiny = MIN_INNER_MARGIN_M / 2
    assert np.array_equal(
        PriorRasteriser(md, 0.5, 16, building_margin_m=tiny, inner=inner).labels(w),
        PriorRasteriser(md, 0.5, 16, building_margin_m=tiny).labels(w))


@pytest.mark.parametrize("inner_args", [(1.0, 16, 0.0), (0.5, 8, 0.0), (0.5, 16, 0.5)])
def test_an_inner_of_another_lattice_or_widened_is_refused(inner_args: tuple) -> None:
    res, tile, margin = inner_args
    md = random_map(0)
    inner = PriorRasteriser(md, res, tile, building_margin_m=margin)
    with pytest.raises(ValueError, match="inner"):
        PriorRasteriser(md, 0.5, 16, building_margin_m=0.5, inner=inner)


def test_widened_tiles_of_a_map_without_buildings_are_empty() -> None:
    # a roads-only map: the inner's tiles hold no building cell, the widened layer none
    roads_only = map_of([], [shapely.box(-5.0, -1.0, 5.0, 1.0)])
    inner = PriorRasteriser(roads_only, 0.5, 16)
    w = Window(0.5, 20, 20, -10, -10)
    assert (inner.labels(w) == CONTEXT_ROAD).any()
    wide = PriorRasteriser(map_of([], []), 0.5, 16, building_margin_m=0.5, inner=inner)
    assert (wide.labels(w) == CONTEXT_OTHER).all()


def test_widened_roads_cover_the_cells_within_the_reach() -> None:
    """``road_margin_m`` (the roads' reach of ``sensor.ground_chain_gap_road_reach_m``): a
    straight road 4 m wide, y in [0, 4], widened by 2 m. A cell's centre at distance d from
    the strip (computed here from the strip's edges, not by shapely) is road iff d ≤ 2 m;
    the buildings keep their own label and win where both cover a cell, as in the prior."""
    road = shapely.box(-50.0, 0.0, 50.0, 4.0)
    house = shapely.box(0.0, 5.0, 5.0, 15.0)        # 1 m from the road's north edge
    md = map_of([house], [road])
    window = Window(0.5, 40, 40, -12, -20)           # y from -6 m to 14 m, x from -10 m to 10 m
    wide = PriorRasteriser(md, 0.5, 16, road_margin_m=2.0).labels(window)
    plain = PriorRasteriser(md, 0.5, 16).labels(window)
    xs, ys = window.cell_centres()
    distance = np.maximum(np.maximum(0.0 - ys, ys - 4.0), 0.0)[:, None] + 0 * xs[None, :]
    in_house = ((xs[None, :] >= 0.0) & (xs[None, :] <= 5.0)
                & (ys[:, None] >= 5.0) & (ys[:, None] <= 15.0))
    want = np.where(in_house, CONTEXT_BUILDING,
                    np.where(distance <= 2.0, CONTEXT_ROAD, CONTEXT_OTHER))
    np.testing.assert_array_equal(wide, want)
    # the reach adds four rows of cells on each side (centres 0.25 … 1.75 m from the edge),
    # but for the house's 10 columns in the two rows of the north side that it covers
    assert in_house.sum() == 10 * 18
    assert int((wide == CONTEXT_ROAD).sum()) - int((plain == CONTEXT_ROAD).sum()) == 8 * 40 - 20
    with pytest.raises(ValueError, match="road_margin_m"):
        PriorRasteriser(md, 0.5, 16, road_margin_m=-1.0)
