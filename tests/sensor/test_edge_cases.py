"""Bad returns, empty scans, range limits, and max-priority where polar cells are denser."""

from __future__ import annotations

import math

import numpy as np
import pytest

from evperc.config import default_config
from evperc.geo.window import Window
from evperc.sensor import SensorParams, sensor_grid
from tests.sensor.scenes import pose


def polar_points(ranges_m, azimuths_deg) -> np.ndarray:
    a = np.radians(np.asarray(azimuths_deg, float))
    r = np.asarray(ranges_m, float)
    return np.stack([r * np.cos(a), r * np.sin(a), np.zeros_like(r)], 1).astype(np.float32)


def test_from_config_reads_every_sensor_key():
    cfg = default_config()
    cfg["sensor"]["mu_free"] = 0.6
    cfg["sensor"]["free_margin_m"] = 0.75
    cfg["sensor"]["free_erosion_m"] = 0.25
    cfg["sensor"]["ground_fallback"] = "scan"
    cfg["sensor"]["ground_local_raise_m"] = 0.15
    cfg["sensor"]["ground_chain"] = False
    cfg["sensor"]["foot_lift_m"] = 0.2
    cfg["sensor"]["ground_chain_gap_m"] = 2.0
    p = SensorParams.from_config(cfg["sensor"], 0.25)
    assert p == SensorParams(0.6, 0.8, 1.0, 80.0, 0.5, 0.3, 2.5, 1.73, 0.25, 0.75, 0.25, "scan",
                             0.15, False, 0.2, 2.0)


@pytest.mark.parametrize("planar", [True, False])
def test_nan_and_inf_points_are_dropped(params, planar):
    good = np.array([[10.1, 0.0, -0.5]], np.float32)
    bad = np.array([[np.nan, 1, 0], [5, np.inf, 0], [3, 0, -np.inf], [np.nan] * 3], np.float32)
    window = Window.centred_on(0.25, 0.25, 40.0, 0.5)
    t = pose(0.25, 0.25, 1.73)
    clean = sensor_grid(good, planar, t, window, params)
    dirty = sensor_grid(np.vstack([bad[:2], good, bad[2:]]), planar, t, window, params)
    np.testing.assert_array_equal(dirty[0], clean[0])
    np.testing.assert_array_equal(dirty[1], clean[1])
    assert (clean[1] > 0).sum() == 1 and (clean[0] > 0).sum() == 18   # as in test_planar


@pytest.mark.parametrize("points", [np.zeros((0, 3), np.float32),
                                    np.full((5, 3), np.nan, np.float32)])
@pytest.mark.parametrize("planar", [True, False])
def test_no_returns_give_an_all_unknown_grid(params, points, planar):
    free, occ = sensor_grid(points, planar, pose(3.0, 4.0, 1.0, yaw_deg=30),
                            Window.centred_on(3.0, 4.0, 50.0, 0.5), params)
    assert free.shape == (100, 100) and not free.any() and not occ.any()


def test_min_and_max_range(params):
    # 0.8 m (a self-return, < min 1 m) and 80.5 m (> max 80 m) are dropped: nothing at all;
    # 79.6 m is kept: its cell occupied, the ray before it free up to bin 158 = [79, 79.5).
    window = Window.centred_on(0.25, 0.25, 200.0, 0.5)
    t = pose(0.25, 0.25, 1.0)
    free, occ = sensor_grid(polar_points([0.8, 80.5], [0.0, 90.0]), True, t, window, params)
    assert not free.any() and not occ.any()
    free, occ = sensor_grid(polar_points([79.6], [0.0]), True, t, window, params)
    row, col = (np.array(v) for v in window.index_of(0.25 + 79.6, 0.25))
    assert occ[row, col] == np.float32(0.8) and (occ > 0).sum() == 1
    ray = free[row, :]
    cols = np.nonzero(ray)[0] - int(col) + 159   # offsets from the sensor's cell
    np.testing.assert_array_equal(cols, np.arange(2, 159))
    assert (free > 0).sum() == 157
    # cells beyond max_range are never free, even with ground returns up to it (3-D); the free
    # scatter may mark a cell whose centre is just beyond 80 m but which holds the centre
    # (79.75 m) of the last free polar cell: allow half a cell diagonal
    ring = polar_points(np.full(720, 79.9), np.arange(0, 360, 0.5))
    ring[:, 2] = -1.73
    free, occ = sensor_grid(ring, False, pose(0.25, 0.25, 1.73), window, params)
    xs, ys = window.cell_centres()
    r = np.hypot(xs[None, :] - 0.25, ys[:, None] - 0.25)
    assert not free[r >= 80.0 + 0.5 * math.sqrt(0.5)].any() and not occ.any()
    assert free[(r >= 1.0) & (r < 79.0)].all()
    assert not free[r < 1.0].any()


def test_occupied_wins_over_free_where_polar_cells_are_denser():
    # 2 m world cells, 0.5° azimuth bins: a far wall at 30 m over −10°..10° makes those bins
    # free up to 30 m. The sensor sits at the centre (1, 1) of cell (0, 0); a near return at
    # (6.3, 0.35) m from it (azimuth 3.2°, bin 6) lies at (7.3, 1.35), in cell (row 0, col 3),
    # whose centre (7, 1) is at azimuth 0° (bin 0, free): sampling alone would call it free.
    params = SensorParams(range_bin_m=2.0)
    window = Window.centred_on(1.0, 1.0, 100.0, 2.0)
    near = np.array([[6.3, 0.35, 0.0]], np.float32)
    wall = polar_points(np.full(41, 30.0), np.arange(-10.0, 10.01, 0.5))
    free, occ = sensor_grid(np.vstack([wall, near]), True, pose(1.0, 1.0, 1.0), window, params)
    row, col = (int(v) for v in window.index_of(np.array(7.3), np.array(1.35)))
    assert occ[row, col] == np.float32(0.8) and free[row, col] == 0
    # the cells before it on the same row are free (other bins pass through them)
    assert free[row, col - 1] == np.float32(0.7) and free[row, col - 2] == np.float32(0.7)
    # and the cell behind it along azimuth 0° is free: bins 0..5 are not blocked
    assert free[row, col + 1] == np.float32(0.7)


def test_free_wins_over_unknown_for_a_ray_between_cell_centres():
    # one return at 20 m, azimuth 10°, 2 m cells: the ray crosses cells whose centres lie at
    # other (empty, unknown) azimuths; the free polar cells' centres still mark them free.
    params = SensorParams(range_bin_m=2.0)
    window = Window.centred_on(1.0, 1.0, 100.0, 2.0)
    t = pose(1.0, 1.0, 1.0)
    free, occ = sensor_grid(polar_points([20.0], [10.0]), True, t, window, params)
    off_ray = 0
    for r in (3.0, 7.0, 11.0, 15.0):   # centres of range bins 1, 3, 5, 7
        x, y = 1.0 + r * math.cos(math.radians(10)), 1.0 + r * math.sin(math.radians(10))
        row, col = (int(v) for v in window.index_of(np.array(x), np.array(y)))
        centre_az = math.degrees(math.atan2((row + window.row0 + 0.5) * 2 - 1.0,
                                            (col + window.col0 + 0.5) * 2 - 1.0))
        assert free[row, col] == np.float32(0.7), (r, centre_az)
        off_ray += abs(centre_az - 10.0) > 0.25   # centre outside bin 20 = [9.75°, 10.25°)
    assert off_ray >= 3
    assert (occ > 0).sum() == 1


def test_bad_shapes_are_programming_errors(params):
    window = Window.centred_on(0, 0, 10.0, 0.5)
    with pytest.raises(ValueError, match="points"):
        sensor_grid(np.zeros((4, 2), np.float32), True, np.eye(4), window, params)
    with pytest.raises(ValueError, match="T_crs_sensor"):
        sensor_grid(np.zeros((4, 3), np.float32), True, np.eye(3), window, params)
