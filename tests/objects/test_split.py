"""The split of clusters shared by tracks that move apart (evperc.objects.split): worked by
hand on small grids, and against the geodesic-Voronoi reference
(tests/objects/reference_split.py) on randomised drives tracked by the real tracker."""

from __future__ import annotations

import numpy as np

from evperc.fusion.twin import DECISION_CODES as D
from evperc.geo.window import Window
from evperc.objects.clusters import Clusterer, ClusterParams, Clusters
from evperc.objects.split import SplitParams, Splitter, warm_up
from evperc.objects.tracking import TrackerState, TrackingParams, footprint_seeds, track_step
from tests.objects import reference_split as ref

RES = 0.5
T0 = 1_000_000_000
DT_NS = 100_000_000  # 0.1 s


def _state(footprints: list[list[tuple[int, int]]], velocities: list[tuple[float, float]],
           missed: list[int] | None = None, moving: list[int] | None = None) -> TrackerState:
    """A tracker state whose tracks hold ``footprints`` (global (iy, ix)) and
    ``velocities`` (m/s), last associated at T0; ``moving``: each track's motion test at
    that association (default: passed)."""
    n = len(footprints)
    s = TrackerState()
    s.prev_ns = T0
    s.id = np.arange(1, n + 1, dtype=np.int64)
    s.hits = np.full(n, 5, np.int64)
    s.missed = np.array(missed or [0] * n, np.int64)
    s.flags = np.zeros((n, 3), np.uint8)
    s.flags[:, 1] = moving or [1] * n
    s.velocity = np.array(velocities, np.float64).reshape(n, 2)
    s.sigma = np.full(n, 0.1)
    s.fp_n = np.array([len(f) for f in footprints], np.int64)
    s.fp = np.array([c for f in footprints for c in f], np.int64).reshape(-1, 2)
    return s


def _one_cluster(window: Window, cells_rc: list[tuple[int, int]]) -> Clusters:
    """One cluster of the given window cells, statistics as the clustering makes them."""
    dec = np.full((window.rows, window.cols), D["free"], np.uint8)
    for r, c in cells_rc:
        dec[r, c] = D["static"]
    r, c = cells_rc[0]
    dec[r, c] = D["moving"]  # the seed
    clusterer = Clusterer(ClusterParams(min_cells=1, seeds="moving"), dec.shape)
    zeros = np.zeros(dec.shape, np.uint8)
    out = clusterer.clusters(dec, zeros, zeros, window)
    assert len(out) == 1 and len(out.cells) == len(cells_rc)
    return out


def _parts(clusters: Clusters, window: Window) -> list[set[tuple[int, int]]]:
    return [{divmod(int(i), window.cols) for i in clusters.cells_of(k)}
            for k in range(len(clusters))]


def _splitter(window: Window, **kw) -> Splitter:
    return Splitter(SplitParams(enabled=True, **kw), (window.rows, window.cols))


def test_a_car_passing_a_parked_car_is_split_between_their_tracks():
    """Window 8 × 12 cells at the origin. The parked car's track held (2,2), (2,3), standing
    still; the passing car's held (2,7), (2,8) at −5 m/s along x: 0.1 s carries it one cell
    (−0.5 m) to (2,6), (2,7). The frame's one cluster is row 2, columns 2-7, and (3,4).
    Fronts: part 0 from (2,2), (2,3); part 1 from (2,6), (2,7). Step 1: (2,4) is next to
    (2,3) and (3,4) too (diagonally), (2,5) next to (2,6); (2,4) is part 0's, (2,5) part 1's.
    (3,4) is one step from (2,3) and two from (2,6)... and (3,4) is diagonal to (2,5) — a cell
    of part 1 only at step 1 — so part 0 takes it at step 1."""
    window = Window(RES, 8, 12, 0, 0)
    cells = [(2, 2), (2, 3), (2, 4), (2, 5), (2, 6), (2, 7), (3, 4)]
    clusters = _one_cluster(window, cells)
    state = _state([[(2, 2), (2, 3)], [(2, 7), (2, 8)]], [(0.0, 0.0), (-5.0, 0.0)])
    dec = np.zeros((8, 12), np.uint8)
    dec[2, 6] = dec[2, 7] = D["moving"]
    betp = np.zeros((8, 12), np.uint8)
    betp[2, 5:8] = 255
    splitter = _splitter(window)
    out = splitter.split(clusters, state, window, T0 + DT_NS, dec, betp, betp * 0)
    assert splitter.last_split == 1
    assert _parts(out, window) == [{(2, 2), (2, 3), (2, 4), (3, 4)}, {(2, 5), (2, 6), (2, 7)}]
    # statistics by hand: part 0's cells' centres x = (2.5, 3.5, 4.5, 4.5) · 0.5, mean 1.875;
    # y = (2.5, 2.5, 2.5, 3.5) · 0.5, mean 1.375; part 1 x (5.5, 6.5, 7.5) · 0.5 = 3.25, y 1.25
    np.testing.assert_allclose(out.centroid_m, [[1.875, 1.375], [3.25, 1.25]], rtol=0,
                               atol=1e-12)
    np.testing.assert_allclose(out.bbox_m, [[1.0, 1.0, 2.5, 2.0], [2.5, 1.0, 4.0, 1.5]])
    assert out.seeds.tolist() == [0, 2]
    np.testing.assert_allclose(out.mean_betp_moving, [0.0, 1.0])
    # the clusterer's scratch is shared by nobody: the splitter's layers are clean again
    assert (splitter._label == -1).all() and (splitter._part == -1).all()
    # one of the two must be moving: two still things' tracks keep their shared cluster
    for moving, split in (([0, 1], 1), ([1, 0], 1), ([0, 0], 0)):
        state.flags[:, 1] = moving
        splitter.split(clusters, state, window, T0 + DT_NS, dec, betp, betp * 0)
        assert splitter.last_split == split, moving
    # and both must have a fitted velocity: a track of one association (σ infinite, v 0) is
    # no still thing yet
    state.flags[:, 1] = 1
    for sigma, split in (([np.inf, 0.1], 0), ([0.1, np.inf], 0), ([0.2, 0.1], 1)):
        state.sigma = np.array(sigma)
        splitter.split(clusters, state, window, T0 + DT_NS, dec, betp, betp * 0)
        assert splitter.last_split == split, sigma


def test_tracks_moving_alike_keep_one_cluster():
    """Two fragments of one car (both at −5 m/s, or differing by less than the bound) are
    left as one cluster; the bound is inclusive (|Δv| = 1.0 splits)."""
    window = Window(RES, 8, 12, 0, 0)
    clusters = _one_cluster(window, [(2, c) for c in range(2, 8)])
    for v2, split in (((-5.0, 0.0), 0), ((-4.2, 0.3), 0), ((-4.0, 0.0), 1)):
        state = _state([[(2, 3), (2, 4)], [(2, 7), (2, 8)]], [(-5.0, 0.0), v2])
        z = np.zeros((8, 12), np.uint8)
        splitter = _splitter(window, speed_difference_m_per_s=1.0)
        out = splitter.split(clusters, state, window, T0 + DT_NS, z, z, z)
        assert splitter.last_split == split, v2
        assert len(out) == 1 + split


def test_a_track_needs_its_overlap_and_a_fresh_footprint():
    """One cell of overlap claims nothing at min_overlap 2 (it does at 1); a track not
    associated last frame (missed 1) paints nothing; one claiming track alone splits
    nothing; the split off leaves the clusters object as it is."""
    window = Window(RES, 8, 12, 0, 0)
    clusters = _one_cluster(window, [(2, c) for c in range(2, 8)])
    z = np.zeros((8, 12), np.uint8)
    fps = [[(2, 2), (2, 3)], [(2, 7), (3, 7)]]  # track 1 covers one cluster cell, (2,7)
    vel = [(0.0, 0.0), (2.0, 0.0)]  # 0.2 m in 0.1 s: under half a cell, no shift
    s = _splitter(window)
    assert s.split(clusters, _state(fps, vel), window, T0 + DT_NS, z, z, z) is clusters
    s = _splitter(window, min_overlap_cells=1)
    out = s.split(clusters, _state(fps, vel), window, T0 + DT_NS, z, z, z)
    # (2,5) is two steps from (2,3) and from (2,7): the tie goes to the lower track row
    assert _parts(out, window) == [{(2, c) for c in range(2, 6)}, {(2, 6), (2, 7)}]
    out = s.split(clusters, _state(fps, vel, missed=[0, 1]), window, T0 + DT_NS, z, z, z)
    assert out is clusters
    off = Splitter(SplitParams(enabled=False, min_overlap_cells=1), (8, 12))
    assert off.split(clusters, _state(fps, vel), window, T0 + DT_NS, z, z, z) is clusters


def test_cells_no_front_reaches_join_the_largest_part():
    """A cluster in two pieces (as the off-building filter can leave one): the piece no
    painted cell lies in joins the larger part."""
    window = Window(RES, 8, 12, 0, 0)
    left = [(2, 1), (2, 2), (2, 3), (2, 4)]
    right = [(2, 7), (2, 8)]
    far = [(6, 10)]
    cells = left + right + far
    # the clustering never returns a disconnected cluster: built by hand, cells in order
    flat = np.array([r * 12 + c for r, c in cells], np.int64)
    clusters = Clusters(flat, np.array([0, len(flat)]), np.zeros((1, 2)), np.zeros((1, 4)),
                        np.zeros(1, np.int64), np.zeros(1, np.float32))
    state = _state([left[:2], right], [(0.0, 0.0), (2.0, 0.0)])
    z = np.zeros((8, 12), np.uint8)
    # 0.1 s at 2 m/s: 0.2 m, under half a cell: no shift
    out = _splitter(window).split(clusters, state, window, T0 + DT_NS, z, z, z)
    assert _parts(out, window) == [set(left) | set(far), set(right)]


def test_footprints_carried_out_of_the_window_paint_nothing():
    """The carried footprint is clipped to the window: a cell carried past the last column
    does not wrap to the next row's first (which the cluster holds here)."""
    window = Window(RES, 4, 6, 10, 20)  # global rows 10-13, cols 20-25
    clusters = _one_cluster(window, [(1, 0), (1, 1), (1, 4), (1, 5), (1, 2), (1, 3), (2, 0)])
    # track 1 at global (11, 26), (11, 27) carried -1 col: (11, 25) in the window, (11, 26)
    # one column past it — wrapped, window cell (2, 0), a second covered cell
    state = _state([[(11, 20), (11, 21)], [(11, 26), (11, 27)]], [(0.0, 0.0), (-5.0, 0.0)])
    z = np.zeros((4, 6), np.uint8)
    s = _splitter(window, min_overlap_cells=2)
    assert s.split(clusters, state, window, T0 + DT_NS, z, z, z) is clusters
    s = _splitter(window, min_overlap_cells=1)
    out = s.split(clusters, state, window, T0 + DT_NS, z, z, z)
    # (1,3) is two steps from (1,1) and from (1,5): the lower track row's
    assert _parts(out, window) == [{(1, 0), (1, 1), (1, 2), (1, 3), (2, 0)}, {(1, 4), (1, 5)}]


OCCUPIED = np.array([D["static"], D["stopped"], D["moving"]], np.uint8)


def _crossing_drive(rng: np.random.Generator, frames: int):
    """Random frames in which blocks of cells cross and touch: 3-7 blocks of 1-3 × 2-4
    cells, some standing, the others driving along a row or a column at 1-2 cells a frame
    (5-10 m/s at 0.5 m and 10 Hz) and bouncing off the window's sides; their cells decided
    static or stopped, some of them moving; a little clutter; the window drifts now and
    then; stamps 0.1 s apart."""
    shape = (32, 40)
    n = int(rng.integers(3, 8))
    pos = rng.integers([4, 4], [shape[0] - 6, shape[1] - 6], (n, 2)).astype(np.int64)
    step = np.zeros((n, 2), np.int64)
    axis = rng.integers(0, 2, n)
    speed = rng.integers(1, 3, n) * rng.choice([-1, 1], n)
    step[np.arange(n), axis] = speed * (rng.random(n) < 0.7)
    size = rng.integers([1, 2], [4, 5], (n, 2))
    origin = np.array([int(rng.integers(-5, 5)), int(rng.integers(-5, 5))])
    stamp = T0
    for _ in range(frames):
        dec = np.full(shape, D["free"], np.uint8)
        clutter = rng.random(shape) < 0.01
        dec[clutter] = D["static"]
        for i in range(n):
            r, c = pos[i]
            block = dec[max(r, 0):max(r + size[i, 0], 0), max(c, 0):max(c + size[i, 1], 0)]
            block[...] = rng.choice(OCCUPIED, block.shape, p=[0.4, 0.3, 0.3])
        now = dec != D["free"]
        pos += step
        for a in range(2):  # bounce
            out = (pos[:, a] < 1) | (pos[:, a] + size[:, a] > shape[a] - 1)
            step[out, a] *= -1
        if rng.random() < 0.2:
            origin += rng.integers(-1, 2, 2)
        betp = rng.integers(0, 256, shape).astype(np.uint8)
        fo = rng.integers(0, 256, shape).astype(np.uint8)
        window = Window(RES, *shape, int(origin[0]), int(origin[1]))
        yield dec, betp, fo, now, window, stamp
        stamp += DT_NS


def _compare_on_random_drive(seed: int) -> int:
    """A random drive of crossing blocks (:func:`_crossing_drive`), clustered and tracked
    by the real stages; before each association the split is compared with the reference: the same
    parts, cell for cell in the same order, and each part's statistics as the clustering
    defines them (exact: the same sums in the same order, except the centroid and the mean
    betP, compared to 1e-12 relative: the reference takes numpy's mean, whose summation
    order differs from the kernel's running sum)."""
    rng = np.random.default_rng(1000 + seed)
    shape = (32, 40)
    clusterer = Clusterer(ClusterParams(min_cells=2, seeds="occupied"), shape)
    params = TrackingParams()
    state = TrackerState()
    min_overlap = int(rng.integers(1, 4))
    dv = float(rng.choice([0.0, 0.5, 1.0]))
    splitter = Splitter(SplitParams(True, min_overlap, dv), shape)
    split_total = 0
    for dec, betp, fo, now, window, stamp in _crossing_drive(rng, 30):
        clusters = clusterer.clusters(dec, betp, fo, window, footprint_seeds(state, window),
                                      now)
        out = splitter.split(clusters, state, window, stamp, dec, betp, fo)
        if state.prev_ns is not None and len(state) >= 2:
            expect = ref.split_parts(clusters, state, window, stamp, min_overlap, dv)
        else:
            expect = [clusters.cells_of(k).tolist() for k in range(len(clusters))]
        got = [out.cells_of(k).tolist() for k in range(len(out))]
        assert got == expect
        assert sorted(out.cells.tolist()) == sorted(clusters.cells.tolist())
        split_total += splitter.last_split
        for k, cells in enumerate(expect):
            centroid, bbox, seeds, mean_m = ref.part_stats(cells, window, dec, betp)
            np.testing.assert_allclose(out.centroid_m[k], centroid, rtol=1e-12, atol=0)
            assert tuple(out.bbox_m[k]) == bbox
            assert out.seeds[k] == seeds
            np.testing.assert_allclose(out.mean_betp_moving[k], np.float32(mean_m),
                                       rtol=1e-6)
        track_step(state, out, window, stamp, params, dec)
    return split_total


def test_against_the_geodesic_reference_on_tracked_random_drives():
    """The comparison on 12 drives; not vacuous: the drives do share clusters."""
    splits = [_compare_on_random_drive(seed) for seed in range(12)]
    assert sum(splits) >= 20  # 37 on these seeds


def test_the_warm_up_reaches_every_compiled_pass():
    """The runner's warm-up (split.warm_up) splits its made-up cluster, so the kernel and the
    parts' summary are loaded before the first frame; off, it does nothing."""
    assert warm_up(SplitParams(enabled=True)) == 1
    assert warm_up(SplitParams(enabled=False)) == 0
