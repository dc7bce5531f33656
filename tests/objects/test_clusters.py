"""Clusters on hand-made grids (evperc.objects.clusters); expected values worked out by hand
in the comments, and the cells against scipy's 8-connected labelling as an independent
reference on random grids."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from evperc.fusion.twin import DECISION_CODES as D
from evperc.geo.window import Window
from evperc.objects.clusters import Clusterer, ClusterParams

RES = 0.5
WIN = Window(RES, 10, 12, 10, 20)  # south-west cell at lattice (10, 20): x 10 m, y 5 m


def _grids(shape=(10, 12)):
    dec = np.full(shape, D["free"], np.uint8)
    return dec, np.zeros(shape, np.uint8), np.zeros(shape, np.uint8)


def _cluster(dec, betp_m, fo, params=None, extra=None, window=WIN):
    params = params or ClusterParams()
    return Clusterer(params, dec.shape).clusters(dec, betp_m, fo, window, extra)


def test_block_with_moving_front_is_one_cluster_with_hand_computed_geometry():
    dec, betp_m, fo = _grids()
    dec[2:4, 4:6] = D["static"]      # rows 2-3, cols 4-5: the car's body, never seen free
    dec[2:4, 6] = D["moving"]        # col 6: its front, seen moving
    betp_m[2:4, 6] = 255
    betp_m[2:4, 4:6] = 51
    c = _cluster(dec, betp_m, fo)
    assert len(c) == 1
    # cells rows 2,3 x cols 4,5,6: mean col 5, mean row 2.5
    # x = (20 + 5 + 0.5) * 0.5 = 12.75, y = (10 + 2.5 + 0.5) * 0.5 = 6.5
    np.testing.assert_allclose(c.centroid_m[0], [12.75, 6.5])
    # outer edges: cols 4..6 -> x 12.0 .. 13.5; rows 2..3 -> y 6.0 .. 7.0
    np.testing.assert_allclose(c.bbox_m[0], [12.0, 6.0, 13.5, 7.0])
    assert c.seeds[0] == 2
    assert sorted(c.cells_of(0)) == sorted(r * 12 + col for r in (2, 3) for col in (4, 5, 6))
    # (2·255 + 4·51) / 6 / 255 = 714 / 1530
    assert c.mean_betp_moving[0] == pytest.approx(714 / 1530, abs=1e-6)


def test_growth_is_8_connected_through_occupied_not_infrastructure_nor_free():
    dec, betp_m, fo = _grids()
    dec[5, 5] = D["moving"]
    dec[5, 6] = D["stopped"]
    dec[6, 7] = D["unmapped"]          # diagonal neighbour of (5, 6): joins
    dec[4, 4] = D["static"]            # diagonal of the seed: joins
    dec[5, 4] = D["infrastructure"]    # a mapped building: does not join
    dec[6, 3] = D["static"]            # touches only the building cell: does not join
    dec[7, 9] = D["static"]            # two cells from (6, 7): does not join
    dec[4, 5] = D["unknown"]
    c = _cluster(dec, betp_m, fo)
    assert len(c) == 1
    assert sorted(c.cells_of(0)) == sorted([5 * 12 + 5, 5 * 12 + 6, 6 * 12 + 7, 4 * 12 + 4])


def test_no_seed_no_cluster_and_small_or_long_clusters_dropped():
    dec, betp_m, fo = _grids()
    dec[1:3, 1:4] = D["static"]        # 6 occupied cells, none moving
    dec[8, 0] = D["moving"]            # 2 cells: below min_cells = 3
    dec[8, 1] = D["static"]
    assert len(_cluster(dec, betp_m, fo)) == 0
    assert len(_cluster(dec, betp_m, fo, ClusterParams(min_cells=2))) == 1
    wall = np.full((4, 60), D["free"], np.uint8)
    wall[1, :] = D["static"]           # 60 cells = 30 m of wall
    wall[1, 30] = D["moving"]          # one false seed on it
    z = np.zeros_like(wall)
    w = Window(RES, 4, 60, 0, 0)
    assert len(_cluster(wall, z, z, window=w)) == 0
    assert len(_cluster(wall, z, z, ClusterParams(max_extent_m=30.0), window=w)) == 1
    wall[1, 40:] = D["free"]           # 40 cells = 20.0 m: at the limit, kept
    assert len(_cluster(wall, z, z, window=w)) == 1


def test_conflict_seeds_from_threshold_and_extra_seeds():
    dec, betp_m, fo = _grids()
    dec[2, 2:5] = D["static"]
    fo[2, 3] = 153                     # 153 / 255 = 0.6
    assert len(_cluster(dec, betp_m, fo)) == 0                      # off by default
    assert len(_cluster(dec, betp_m, fo, ClusterParams(seed_conflict_fo=0.6))) == 1
    assert len(_cluster(dec, betp_m, fo, ClusterParams(seed_conflict_fo=0.61))) == 0
    extra = np.array([2 * 12 + 4, 9 * 12 + 11, -5, 10_000], np.int64)  # 2 occupied-less/outside
    c = _cluster(dec, betp_m, fo, extra=extra)
    assert len(c) == 1 and c.seeds[0] == 0 and len(c.cells_of(0)) == 3


def test_scratch_is_cleared_between_frames():
    dec, betp_m, fo = _grids()
    dec[3, 3:6] = D["moving"]
    clusterer = Clusterer(ClusterParams(), dec.shape)
    a = clusterer.clusters(dec, betp_m, fo, WIN)
    b = clusterer.clusters(dec, betp_m, fo, WIN)
    assert len(a) == len(b) == 1
    np.testing.assert_array_equal(a.cells, b.cells)


def test_against_scipy_labelling_on_random_grids():
    ndimage = pytest.importorskip("scipy.ndimage")
    rng = np.random.default_rng(7)
    codes = np.array([D["free"], D["unknown"], D["moving"], D["static"], D["stopped"],
                      D["infrastructure"], D["unmapped"]], np.uint8)
    for _ in range(20):
        dec = codes[rng.choice(7, size=(40, 50), p=[.45, .1, .03, .2, .1, .07, .05])]
        z = np.zeros_like(dec)
        w = Window(RES, 40, 50, 0, 0)
        got = _cluster(dec, z, z, ClusterParams(min_cells=1, max_extent_m=1e3), window=w)
        occupied = np.isin(dec, [D["moving"], D["static"], D["stopped"], D["unmapped"]])
        labels, _ = ndimage.label(occupied, structure=np.ones((3, 3)))
        seeded = np.unique(labels[dec == D["moving"]])
        expected = {frozenset(np.flatnonzero(labels.ravel() == k)) for k in seeded}
        found = {frozenset(c) for c in (got.cells_of(k) for k in range(len(got)))}
        assert found == expected


def test_isolated_small_cluster_kept_unless_an_obstacle_is_within_the_clearance():
    # a walking person: 2 cells decided moving at rows 5, cols 5-6, in the open (free /
    # unknown around); min_cells 3 drops it, isolated_min_cells 2 keeps it
    dec, betp_m, fo = _grids()
    dec[5, 5:7] = D["moving"]
    iso = ClusterParams(isolated_min_cells=2, isolated_clearance_m=1.0)  # 1.0 m = 2 cells
    dec[0:2, :] = D["unknown"]
    assert len(_cluster(dec, betp_m, fo)) == 0
    c = _cluster(dec, betp_m, fo, iso)
    assert len(c) == 1 and sorted(c.cells_of(0).tolist()) == [5 * 12 + 5, 5 * 12 + 6]
    # a remembered obstacle 2 cells (1.0 m, centre to centre) below: spill, dropped
    for code in ("static", "stopped", "unmapped", "infrastructure"):
        d = dec.copy()
        d[3, 8] = D[code]              # Chebyshev distance to (5, 6): max(2, 2) = 2
        assert len(_cluster(d, betp_m, fo, iso)) == 0, code
    # 3 cells away (1.5 m): beyond the clearance, kept; and within 1.5 m, dropped
    d = dec.copy()
    d[2, 6] = D["static"]              # distance 3
    assert len(_cluster(d, betp_m, fo, iso)) == 1
    assert len(_cluster(d, betp_m, fo, ClusterParams(isolated_min_cells=2,
                                                     isolated_clearance_m=1.5))) == 0
    # one cell is under isolated_min_cells = 2; isolated_min_cells = 1 keeps it
    d = dec.copy()
    d[5, 6] = D["free"]
    assert len(_cluster(d, betp_m, fo, iso)) == 0
    assert len(_cluster(d, betp_m, fo, ClusterParams(isolated_min_cells=1))) == 1


def test_small_cluster_holding_a_moving_cell_kept_beside_an_obstacle():
    # a person of two cells, one stepping into a cell seen free (decided moving), beside a
    # parked car (static, one free cell away), both seen now (the default seeds): the
    # person is under min_cells 3 and not isolated; small_conflict_min_cells keeps it
    dec, betp_m, fo = _grids()
    dec[0:2, :] = D["unknown"]
    dec[5, 5] = D["moving"]
    dec[5, 6] = D["static"]            # the person's other cell, no conflict in it
    dec[5, 8:11] = D["static"]         # the parked car's side

    def kept(d, **keys):
        params = ClusterParams(seeds="occupied", **keys)
        c = Clusterer(params, d.shape).clusters(d, betp_m, fo, WIN, None, d != D["free"])
        return sorted(sorted(c.cells_of(k).tolist()) for k in range(len(c)))

    person, car = [5 * 12 + 5, 5 * 12 + 6], [5 * 12 + 8, 5 * 12 + 9, 5 * 12 + 10]
    assert kept(dec) == [car]
    assert kept(dec, isolated_min_cells=1, isolated_clearance_m=1.0) == [car]
    assert kept(dec, small_conflict_min_cells=1) == [person, car]
    assert kept(dec, small_conflict_min_cells=2) == [person, car]
    assert kept(dec, small_conflict_min_cells=3) == [car]    # min_cells' own size
    d = dec.copy()
    d[5, 6] = D["free"]                # the person's one cell
    assert kept(d, small_conflict_min_cells=2) == [car]
    assert kept(d, small_conflict_min_cells=1) == [[5 * 12 + 5], car]
    # no moving cell: a small static group (the car's spill) is not kept
    d = dec.copy()
    d[5, 5] = D["static"]
    assert kept(d, small_conflict_min_cells=1) == [car]
    # the height bound (isolated_min_height_m): the person's highest return within one
    # cell, here 0.35 m (ground the split called an obstacle) or 0.4 m (kept)
    heights = np.zeros(dec.shape, np.float32)
    heights[5, 8:11] = 1.4             # the car, two cells from the person
    heights[5, 5:7] = 0.35
    params = ClusterParams(seeds="occupied", small_conflict_min_cells=1,
                           isolated_min_height_m=0.4)
    clusterer = Clusterer(params, dec.shape)
    assert len(clusterer.clusters(dec, betp_m, fo, WIN, None, dec != D["free"], heights)) == 1
    heights[4, 7] = 0.4                # diagonal to (5, 6)
    assert len(clusterer.clusters(dec, betp_m, fo, WIN, None, dec != D["free"], heights)) == 2


def test_isolated_small_cluster_needs_a_return_above_the_height_bound():
    dec, betp_m, fo = _grids()
    dec[5, 5:7] = D["moving"]
    now = np.zeros(dec.shape, bool)
    heights = np.full(dec.shape, -np.inf, np.float32)   # no return
    heights[5, 5:7] = 0.35                              # ground points 0.35 m up
    params = ClusterParams(isolated_min_cells=2, isolated_min_height_m=0.4)
    clusterer = Clusterer(params, dec.shape)
    assert len(clusterer.clusters(dec, betp_m, fo, WIN, None, now, heights)) == 0
    assert len(clusterer.clusters(dec, betp_m, fo, WIN, None, now, None)) == 1  # no heights
    heights[4, 7] = 0.4               # a return at the bound, diagonal to (5, 6): kept
    assert len(clusterer.clusters(dec, betp_m, fo, WIN, None, now, heights)) == 1
    heights[4, 7] = 1.2
    heights[5, 5:7] = 0.1
    dec[5, 7] = D["static"]           # 3 cells: the size test, no height condition
    heights[4, 7] = 0.0
    assert len(clusterer.clusters(dec, betp_m, fo, WIN, None, now, heights)) == 1


def test_isolated_clusters_against_scipy_labelling_and_dilation():
    """The kept clusters of a random grid against an independent computation: scipy's
    8-connected components of the occupied decisions seeded by a moving cell, kept if
    they have min_cells cells, or isolated_min_cells, no still decision (static,
    stopped, unmapped, infrastructure) outside them in their dilation by a
    (2 reach + 1)-square, and a 3 × 3 maximum filter of the heights reaching the height
    bound on one of their cells."""
    ndimage = pytest.importorskip("scipy.ndimage")
    rng = np.random.default_rng(11)
    codes = np.array([D["free"], D["unknown"], D["moving"], D["static"], D["stopped"],
                      D["infrastructure"], D["unmapped"]], np.uint8)
    still = [D["static"], D["stopped"], D["unmapped"], D["infrastructure"]]
    kept_small = 0
    for trial in range(30):
        dec = codes[rng.choice(7, size=(40, 50), p=[.6, .2, .06, .06, .03, .03, .02])]
        z = np.zeros_like(dec)
        res = float(rng.choice([0.2, 0.5]))
        clearance = float(rng.choice([0.5, 1.0, 1.5]))
        iso = int(rng.integers(1, 3))
        w = Window(res, 40, 50, 0, 0)
        heights = rng.uniform(-0.5, 1.0, dec.shape).astype(np.float32)
        min_height = float(rng.choice([0.0, 0.4, 0.8]))
        got = Clusterer(ClusterParams(min_cells=3, max_extent_m=1e3, isolated_min_cells=iso,
                                      isolated_clearance_m=clearance,
                                      isolated_min_height_m=min_height), dec.shape).clusters(
            dec, z, z, w, None, None, heights)
        top = ndimage.maximum_filter(heights, size=3, mode="constant", cval=-np.inf)
        occupied = np.isin(dec, [D["moving"], D["static"], D["stopped"], D["unmapped"]])
        labels, _ = ndimage.label(occupied, structure=np.ones((3, 3)))
        reach = int(round(clearance / res))   # the test's values divide exactly
        box = np.ones((2 * reach + 1, 2 * reach + 1), bool)
        expected = set()
        for k in np.unique(labels[dec == D["moving"]]):
            own = labels == k
            size = int(own.sum())
            near = ndimage.binary_dilation(own, structure=box)
            alone = not (near & ~own & np.isin(dec, still)).any()
            alone &= min_height <= 0 or bool(top[own].max() >= np.float32(min_height))
            if size >= 3 or (size >= iso and alone):
                expected.add(frozenset(np.flatnonzero(own.ravel())))
                kept_small += size < 3
        found = {frozenset(c) for c in (got.cells_of(k) for k in range(len(got)))}
        assert found == expected, trial
    assert kept_small > 10  # the rule was exercised, not only the size test


def _facade_and_person():
    """A 12 × 20 window: a building's outline (infrastructure) in rows 0-1, its façade's
    returns one cell outside it (row 2, cols 0-19, decided stopped, hit now) — all of row 2
    within the widened building (``near``, rows 0-2) — and a person against the wall (rows
    3-4, cols 8-9: two cells decided moving, two static, all hit now)."""
    shape = (12, 20)
    dec, betp_m, fo = _grids(shape)
    dec[0:2, :] = D["infrastructure"]
    dec[2, :] = D["stopped"]
    dec[3, 8:10] = D["moving"]
    dec[4, 8:10] = D["static"]
    now = np.zeros(shape, bool)
    now[2:5, :] = True
    now[3:5, 10:] = False
    now[3:5, :8] = False
    near = np.zeros(shape, bool)
    near[0:3, :] = True
    return dec, betp_m, fo, now, near


def test_a_cluster_keeps_no_facade_cells_off_buildings():
    """The person's group takes in the whole façade strip (24 cells, 10 m long); with
    ``off_buildings`` its cluster is the 4 cells of the person, worked out by hand: cols 8-9
    of rows 3-4, centroid x = (20 + 8.5 + 0.5) · 0.5 = 14.5, y = (10 + 3.5 + 0.5) · 0.5 = 7.0,
    box x 14.0-15.0, y 6.5-7.5, two seeds."""
    dec, betp_m, fo, now, near = _facade_and_person()
    window = Window(RES, 12, 20, 10, 20)
    params = ClusterParams(seeds="occupied")
    plain = Clusterer(params, dec.shape).clusters(dec, betp_m, fo, window, None, now,
                                                  near_building=near)
    assert len(plain) == 1 and len(plain.cells_of(0)) == 24  # 20 façade + 4 person cells
    assert plain.bbox_m[0][2] - plain.bbox_m[0][0] == pytest.approx(10.0)
    off = Clusterer(replace(params, off_buildings=True), dec.shape)
    c = off.clusters(dec, betp_m, fo, window, None, now, near_building=near)
    assert len(c) == 1
    assert sorted(c.cells_of(0)) == [3 * 20 + 8, 3 * 20 + 9, 4 * 20 + 8, 4 * 20 + 9]
    np.testing.assert_allclose(c.centroid_m[0], [14.5, 7.0])
    np.testing.assert_allclose(c.bbox_m[0], [14.0, 6.5, 15.0, 7.5])
    assert c.seeds[0] == 2
    # the group the small-group rules read is the flood fill's, façade included
    cells, sizes = off.groups()
    assert sizes.tolist() == [24]
    assert sorted(cells.tolist()) == sorted(plain.cells_of(0).tolist())
    # without the layer (no map) nothing is left out
    assert len(off.clusters(dec, betp_m, fo, window, None, now).cells_of(0)) == 24


def test_off_buildings_keeps_moving_cells_and_drops_a_facade_only_group():
    """A cell decided moving inside the widened building stays in its cluster (only
    static, stopped and unmapped cells are left out); a group of façade cells alone keeps no
    cell and is no cluster."""
    dec, betp_m, fo, now, near = _facade_and_person()
    window = Window(RES, 12, 20, 10, 20)
    off = Clusterer(ClusterParams(seeds="occupied", off_buildings=True), dec.shape)
    dec[3:5, 8:10] = D["free"]  # the person gone: the strip alone
    assert len(off.clusters(dec, betp_m, fo, window, None, now, near_building=near)) == 0
    dec[2, 5:8] = D["moving"]   # three strip cells decided moving: they stay, the rest not
    c = off.clusters(dec, betp_m, fo, window, None, now, near_building=near)
    assert len(c) == 1 and sorted(c.cells_of(0)) == [45, 46, 47]
    dec[2, 5:8] = D["unmapped"]  # unmapped, like stopped and static, is left out
    assert len(off.clusters(dec, betp_m, fo, window, None, now, near_building=near)) == 0


def test_a_person_walking_along_the_wall_keeps_its_cells():
    """A person within the widened building (3 cells decided static — the motion gate is
    closed there — all in ``near``, hit now; 1.5 m along the wall): a group at most
    ``off_buildings_small_m`` on each side is kept whole (one cluster of the 3 cells), and
    without that bound it loses every cell and is no cluster."""
    dec, betp_m, fo, now, near = _facade_and_person()
    window = Window(RES, 12, 20, 10, 20)
    dec[2, :] = D["free"]             # no façade returns now
    dec[3:5, 8:10] = D["free"]
    now[:] = False
    dec[2, 10:13] = D["static"]       # the walker, one cell outside the outline
    now[2, 10:13] = True
    small = ClusterParams(seeds="occupied", off_buildings=True, off_buildings_small_m=2.0)
    c = Clusterer(small, dec.shape).clusters(dec, betp_m, fo, window, None, now,
                                             near_building=near)
    assert len(c) == 1 and sorted(c.cells_of(0)) == [50, 51, 52]
    no_bound = replace(small, off_buildings_small_m=0.0)
    assert len(Clusterer(no_bound, dec.shape).clusters(dec, betp_m, fo, window, None, now,
                                                       near_building=near)) == 0
    # 1.0 m: the 1.5 m group is no longer small enough to keep its cells
    assert len(Clusterer(replace(small, off_buildings_small_m=1.0), dec.shape).clusters(
        dec, betp_m, fo, window, None, now, near_building=near)) == 0


def test_a_small_group_reaching_up_a_facade_is_no_walker():
    """``off_buildings_max_height_m``: the walker's group of the test above (1.5 m along the
    wall, every cell static and near the building) is kept whole when its returns are a
    person's height (1.8 m), and loses its cells — no cluster — when one of them holds a
    return 3 m above the ground (a fragment of the façade hit up its height). With the
    bound at 0, or without the heights layer, there is no height condition."""
    dec, betp_m, fo, now, near = _facade_and_person()
    window = Window(RES, 12, 20, 10, 20)
    dec[2, :] = D["free"]
    dec[3:5, 8:10] = D["free"]
    now[:] = False
    dec[2, 10:13] = D["static"]
    now[2, 10:13] = True
    heights = np.zeros(dec.shape, np.float32)
    heights[2, 10:13] = 1.8
    params = ClusterParams(seeds="occupied", off_buildings=True, off_buildings_small_m=2.0,
                           off_buildings_max_height_m=2.2)

    def cells(p: ClusterParams, h: np.ndarray | None) -> list[list[int]]:
        c = Clusterer(p, dec.shape).clusters(dec, betp_m, fo, window, None, now, h,
                                             near_building=near)
        return [sorted(c.cells_of(k).tolist()) for k in range(len(c))]

    assert cells(params, heights) == [[50, 51, 52]]
    heights[2, 11] = 3.0
    assert cells(params, heights) == []
    heights[2, 11] = 2.2  # the bound itself is a façade's height
    assert cells(params, heights) == []
    assert cells(replace(params, off_buildings_max_height_m=0.0), heights) == [[50, 51, 52]]
    assert cells(params, None) == [[50, 51, 52]]


def test_return_centroids_are_the_mean_of_the_returns_in_the_cells():
    """objects.centroid = "returns" (:func:`with_return_centroids`): hand-computed means."""
    from evperc.objects.clusters import with_return_centroids
    dec, betp_m, fo = _grids()
    dec[2:4, 4:6] = D["moving"]      # cluster 0: rows 2-3, cols 4-5
    dec[7, 9:11] = D["moving"]       # cluster 1: row 7, cols 9-10 (two cells, no returns)
    c = _cluster(dec, betp_m, fo, ClusterParams(min_cells=2))
    assert len(c) == 2
    sums = np.zeros((10, 12, 3), np.float32)
    # cell (2, 4): centre x = (20 + 4 + 0.5) * 0.5 = 12.25, y = (10 + 2 + 0.5) * 0.5 = 6.25;
    # three returns at +0.2 m east, +0.1 m north of it: sums 0.6, 0.3, count 3
    sums[2, 4] = (0.6, 0.3, 3.0)
    # cell (3, 5): centre x = 12.75, y = 6.75; one return 0.1 m east: sums 0.1, 0, count 1
    sums[3, 5] = (0.1, 0.0, 1.0)
    out = with_return_centroids(c, sums, WIN)
    # x = (3 * 12.25 + 0.6 + 12.75 + 0.1) / 4 = 50.2 / 4 = 12.55;
    # y = (3 * 6.25 + 0.3 + 6.75) / 4 = 25.8 / 4 = 6.45 (float32 sums: 1e-6 m)
    np.testing.assert_allclose(out.centroid_m[0], [12.55, 6.45], atol=1e-6)
    # the cell centres' mean would be (12.5, 6.5): the cells without a return weigh nothing
    np.testing.assert_allclose(c.centroid_m[0], [12.5, 6.5])
    # cluster 1 holds no return: its cell centres' mean, x = (20 + 9.5 + 0.5) * 0.5 = 15.0,
    # y = (10 + 7 + 0.5) * 0.5 = 8.75
    np.testing.assert_allclose(out.centroid_m[1], [15.0, 8.75])
    # everything else is the clustering's
    np.testing.assert_array_equal(out.cells, c.cells)
    np.testing.assert_array_equal(out.bbox_m, c.bbox_m)
