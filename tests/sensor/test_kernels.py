"""The compiled sensor grid against the per-point / per-cell oracle (tests/sensor/reference.py)
on random clouds and on edge cases: points on cell edges, range-bin edges and either side of
beam edges, at the range limits, NaN / inf rows, 2-D scans, windows off the sensor; plus the
kernels' reused work arrays (no output shared between calls, concurrent threads)."""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from evperc.geo.window import Window
from evperc.sensor import SensorParams, sensor_grid
from tests.sensor.reference import reference_grid
from tests.sensor.scenes import pose


def assert_matches_oracle(points, planar, t, window, params):
    free, occ = sensor_grid(points, planar, t, window, params)
    want_free, want_occ = reference_grid(points, planar, t, window, params)
    assert free.dtype == occ.dtype == np.float32 and free.shape == window.shape
    np.testing.assert_array_equal(free, want_free)
    np.testing.assert_array_equal(occ, want_occ)
    return want_free, want_occ


def random_cloud(rng: np.random.Generator, n: int, reach_m: float) -> np.ndarray:
    """Uniform on a disc a little wider than ``reach_m``: a third on a flat road 1.73 m below
    the sensor, a third at heights from below the road to above the obstacle band, a third
    in clumps of 40 around random heights from 5 m below the road to 4 m above (pits,
    roofs: ground cells whose estimate falls in an edge bin or outside the slope bound)."""
    r = reach_m * 1.1 * np.sqrt(rng.uniform(0, 1, n))
    a = rng.uniform(-math.pi, math.pi, n)
    z = rng.uniform(-3.0, 2.0, n)
    z[: n // 3] = -1.73 + rng.normal(0, 0.03, n // 3)
    clumps = np.arange(n - n // 3, n)
    centre = rng.choice(clumps, len(clumps) // 40 + 1)
    for i, j in enumerate(clumps):
        c = centre[i // 40]
        r[j] = r[c] + rng.uniform(-1.0, 1.0)
        a[j] = a[c] + rng.uniform(-0.05, 0.05)
        z[j] = -1.73 + (((c * 7919) % 90) / 10.0 - 5.0) + rng.normal(0, 0.02)
    return np.stack([r * np.cos(a), r * np.sin(a), z], 1)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("planar", [False, True])
def test_random_clouds(seed, planar):
    rng = np.random.default_rng(100 + seed)
    res = (0.5, 1.0, 0.25)[seed % 3]
    params = SensorParams(range_bin_m=(None, 0.5, 0.7)[seed % 3],
                          azimuth_resolution_deg=(0.5, 1.5, 4.0)[seed % 3],
                          min_range_m=(1.0, 0.0, 2.5)[seed % 3], max_range_m=(25.0, 30.0)[seed % 2])
    t = pose(rng.uniform(-1e5, 1e5), rng.uniform(-1e5, 1e5), 50.0,
             yaw_deg=rng.uniform(-180, 180), pitch_deg=rng.uniform(-5, 5),
             roll_deg=rng.uniform(-5, 5))
    level = random_cloud(rng, 3000, params.max_range_m)
    points = (level @ t[:3, :3]).astype(np.float32)   # level offsets → sensor frame
    # the window may leave part of the range disc out
    window = Window.centred_on(t[0, 3] + rng.uniform(-15, 15), t[1, 3] + rng.uniform(-15, 15),
                               rng.uniform(30.0, 60.0), res)
    want_free, want_occ = assert_matches_oracle(points, planar, t, window, params)
    assert (want_free > 0).sum() > 50 and (want_occ > 0).sum() > 20


def test_points_on_cell_and_range_bin_edges(params):
    # sensor on a cell corner, level: points at whole multiples of the 0.5 m cell size lie on
    # cell edges (and the ones on an axis on range-bin edges) in float32 and float64 alike
    t = pose(10.0, -4.0, 1.73)
    grid = np.arange(-12.0, 12.01, 0.5)
    gx, gy = np.meshgrid(grid, grid)
    keep = (np.hypot(gx, gy) >= 1.0) & ((gx == 0) | (gy == 0) | (np.abs(gx) == np.abs(gy))
                                         | (np.abs(gx) == 6.0) | (np.abs(gy) == 9.5))
    ring = np.stack([gx[keep], gy[keep], np.full(keep.sum(), 0.4)], 1)   # obstacles
    road = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, -1.73)], 1)
    points = np.vstack([ring, road]).astype(np.float32)
    window = Window.centred_on(10.0, -4.0, 40.0, 0.5)
    for planar in (False, True):
        want_free, want_occ = assert_matches_oracle(points, planar, t, window, params)
        assert (want_occ > 0).sum() > 30


@pytest.mark.parametrize("azimuth_resolution_deg", [0.5, 2.0, 45.0])
def test_points_either_side_of_beam_edges(azimuth_resolution_deg):
    # returns 1e-4 rad either side of every other beam edge (a ± ½)·Δ + ψ, at ranges that
    # differ between the two sides: each side must land in its own bin
    params = SensorParams(range_bin_m=0.5, azimuth_resolution_deg=azimuth_resolution_deg,
                          max_range_m=20.0)
    yaw = 17.3
    t = pose(3.3, 2.1, 1.0, yaw_deg=yaw)
    n_az = round(360 / azimuth_resolution_deg)
    step = 2 * math.pi / n_az
    edges = (np.arange(0, n_az, 2) + 0.5) * step
    angles = np.concatenate([edges - 1e-4, edges + 1e-4])
    ranges = np.concatenate([np.full(edges.size, 6.2), np.full(edges.size, 11.7)])
    points = np.stack([ranges * np.cos(angles), ranges * np.sin(angles),
                       np.zeros_like(ranges)], 1).astype(np.float32)   # sensor frame
    window = Window.centred_on(3.3, 2.1, 30.0, 0.5)
    want_free, want_occ = assert_matches_oracle(points, True, t, window, params)
    assert (want_occ > 0).sum() >= min(edges.size, 40)


def test_range_limits_nan_inf_and_the_sensor_itself():
    # level, unrotated pose at a cell centre: the offsets are exact in float32 and float64
    # alike (a rotation by 90° is not: cos 90° = 6e-17 would move points on cell edges
    # differently in the two); the cell centre 1 m east lies exactly at min range and is
    # free from the road ahead, and the last polar cell centre 12.25 m ahead exactly at max
    # range (not scattered)
    params = SensorParams(range_bin_m=0.5, min_range_m=1.0, max_range_m=12.25)
    t = pose(0.25, 0.25, 1.73)
    points = np.array([
        [0.0, 1.0, 0.0],          # exactly min range: kept
        [0.0, 12.25, 0.0],        # exactly max range: dropped
        [0.0, -12.24, 0.0],       # just inside
        [5.0, 0.0, -1.73],        # road ahead
        [12.1, 0.0, -1.73],       # road in the last range bin
        [0.0, 0.0, 0.0],          # the sensor itself: below min range
        [0.5, 0.5, 0.0],          # below min range
        [300.0, 2.0, 0.0],        # far beyond
        [np.nan, 1.0, 1.0], [3.0, np.inf, 0.0], [-np.inf, 0.0, 0.0], [4.0, 4.0, np.nan],
        [1e30, 1e30, 0.0],        # finite, but its range overflows float32
        [6.0, -3.0, 5.0],         # above max_obstacle_height: ignored (3-D)
        [-7.0, 2.0, -1.73],       # road
    ], np.float32)
    window = Window.centred_on(0.25, 0.25, 30.0, 0.5)
    for planar in (False, True):
        assert_matches_oracle(points, planar, t, window, params)
    # with no minimum the sensor's own position is a return in bin 0
    assert_matches_oracle(points, True, t, window, SensorParams(range_bin_m=0.5, min_range_m=0.0,
                                                                max_range_m=12.25))


@pytest.mark.parametrize("height_m", [-4.5, -3.2, 3.2, 4.5])
def test_ground_estimate_in_the_edge_bins(height_m):
    # far clumps (26–28 m, where the slope bound reaches 3 m) whose low percentile lies
    # in the lowest or highest histogram bin (|h| > 2.95 m) or just inside: the estimate is
    # rejected in the edge bins only; behind each clump a road return decides what is free
    params = SensorParams(range_bin_m=0.5, max_range_m=40.0)
    t = pose(0.25, 0.25, 1.73, yaw_deg=25.0)
    rng = np.random.default_rng(int(height_m * 10) + 50)
    clumps = []
    for sector in range(0, 36, 3):
        a = math.radians(sector * 10 + 5) + rng.uniform(-0.05, 0.05, 60)
        r = rng.uniform(26.0, 27.9, 60)
        z = -1.73 + height_m + rng.normal(0, 0.2, 60)
        clumps.append(np.stack([r * np.cos(a), r * np.sin(a), z], 1))
        road = rng.uniform(5.0, 35.0, 30)
        clumps.append(np.stack([road * np.cos(a[:30]), road * np.sin(a[:30]),
                                np.full(30, -1.73)], 1))
    points = (np.vstack(clumps) @ t[:3, :3]).astype(np.float32)
    window = Window.centred_on(0.25, 0.25, 80.0, 0.5)
    want_free, want_occ = assert_matches_oracle(points, False, t, window, params)
    assert (want_free > 0).sum() > 1000


def test_window_beside_the_sensor_and_empty_clouds():
    rng = np.random.default_rng(7)
    t = pose(500.0, 500.0, 1.73, yaw_deg=-40.0)
    points = random_cloud(rng, 2000, 40.0).astype(np.float32)
    params = SensorParams(range_bin_m=0.5, max_range_m=40.0)
    for centre in ((540.0, 530.0), (650.0, 500.0)):   # a corner of the disc; outside it
        window = Window.centred_on(*centre, 30.0, 0.5)
        assert_matches_oracle(points, False, t, window, params)
    free, occ = sensor_grid(np.zeros((0, 3), np.float32), False, t,
                            Window.centred_on(500.0, 500.0, 30.0, 0.5), params)
    assert not free.any() and not occ.any()


def test_outputs_are_not_shared_between_calls(params):
    # the kernels reuse work arrays from call to call; the returned grids must not be
    # among them
    t = pose(0.25, 0.25, 1.73)
    window = Window.centred_on(0.25, 0.25, 30.0, 0.5)
    rng = np.random.default_rng(1)
    first = sensor_grid(random_cloud(rng, 2000, 14.0).astype(np.float32), False, t, window,
                        params)
    kept = (first[0].copy(), first[1].copy())
    second = sensor_grid(random_cloud(rng, 5000, 14.0).astype(np.float32), True, t, window,
                         params)
    np.testing.assert_array_equal(first[0], kept[0])
    np.testing.assert_array_equal(first[1], kept[1])
    assert not np.array_equal(first[1], second[1])


def test_concurrent_threads_give_the_sequential_grids(params):
    rng = np.random.default_rng(5)
    t = pose(0.25, 0.25, 1.73, yaw_deg=30.0)
    window = Window.centred_on(0.25, 0.25, 60.0, 0.5)
    clouds = [random_cloud(rng, int(rng.integers(1000, 30000)), 30.0).astype(np.float32)
              for _ in range(8)]
    want = [sensor_grid(c, False, t, window, params) for c in clouds]
    with ThreadPoolExecutor(4) as pool:
        for _ in range(3):
            got = list(pool.map(lambda c: sensor_grid(c, False, t, window, params), clouds))
            for (f, o), (wf, wo) in zip(got, want, strict=True):
                np.testing.assert_array_equal(f, wf)
                np.testing.assert_array_equal(o, wo)
