"""Each cell's returns: the sums of their offsets from the cell centre and their count
(``sensor_grid(..., sums_out=)``, objects.centroid = "returns"). The oracle sums the scene's
own obstacle points (height in [ground_threshold_m, max_obstacle_height_m]) per cell with
numpy from their world coordinates; ground and ignored points give nothing; the masses are
unchanged."""

from __future__ import annotations

import numpy as np
import pytest

from evperc.geo.window import Window
from evperc.sensor import sensor_grid
from tests.sensor.scenes import pose
from tests.sensor.test_ground import RES, SENSOR
from tests.sensor.test_top_heights import obstacle_points, scene


@pytest.mark.parametrize("attitude", [{}, {"yaw_deg": 90.0, "pitch_deg": -3.0}])
def test_return_sums_are_each_cells_obstacle_points(params, attitude):
    t, level_pts, points, window = scene(attitude)
    sums = np.zeros((*window.shape, 3), np.float32)  # added to: the caller passes zeros
    free, occ = sensor_grid(points, False, t, window, params, sums_out=sums)

    obstacle = obstacle_points(level_pts, params)
    wx = SENSOR[0] + level_pts[obstacle, 0]
    wy = SENSOR[1] + level_pts[obstacle, 1]
    row = np.floor(wy / RES).astype(int) - window.row0
    col = np.floor(wx / RES).astype(int) - window.col0
    want = np.zeros((*window.shape, 3))
    np.add.at(want, (row, col, 0), wx - (np.floor(wx / RES) + 0.5) * RES)
    np.add.at(want, (row, col, 1), wy - (np.floor(wy / RES) + 0.5) * RES)
    np.add.at(want, (row, col, 2), 1.0)
    np.testing.assert_array_equal(sums[..., 2], want[..., 2])  # counts: exact
    # offsets: the points pass through a float32 levelling of a tilted pose (~1e-5 m) and
    # are summed in float32 (15 points a cell at most here); 1 mm is far below the 0.5 m
    # cells whose sub-cell position they give
    np.testing.assert_allclose(sums[..., :2], want[..., :2], atol=1e-3)
    # the person's 14 returns at (11.1, -3.2): their mean is the person's position
    r, c = window.index_of(np.array(SENSOR[0] + 11.1), np.array(SENSOR[1] - 3.2))
    n = sums[int(r), int(c), 2]
    assert n == 14
    centre_x = (window.col0 + int(c) + 0.5) * RES
    assert centre_x + sums[int(r), int(c), 0] / n == pytest.approx(SENSOR[0] + 11.1, abs=1e-3)

    free0, occ0 = sensor_grid(points, False, t, window, params)
    np.testing.assert_array_equal(free, free0)
    np.testing.assert_array_equal(occ, occ0)

    # added to, not overwritten: a second scan into the same array doubles every sum
    sensor_grid(points, False, t, window, params, sums_out=sums)
    np.testing.assert_array_equal(sums[..., 2], 2 * want[..., 2])


def test_a_wrong_sums_array_is_refused(params):
    window = Window.centred_on(*SENSOR, 20.0, RES)
    with pytest.raises(ValueError, match="sums_out must be float32"):
        sensor_grid(np.zeros((1, 3), np.float32), False, pose(*SENSOR, 0.0), window, params,
                    sums_out=np.zeros(window.shape, np.float32))


@pytest.mark.parametrize("attitude", [{}, {"yaw_deg": 90.0, "pitch_deg": -3.0}])
def test_with_the_heights_the_sums_are_written_where_a_cell_holds_a_return(params, attitude):
    """``sums_out`` with ``heights_out`` (the runner's way, one pass): this scan's sums in
    exactly the cells whose height is > 0 — the same values as the sums-only pass into
    zeros, written over whatever the block held (another scan's sums) —, every other cell
    left as it was; the heights the same as without the sums."""
    t, level_pts, points, window = scene(attitude)
    want = np.zeros((*window.shape, 3), np.float32)
    sensor_grid(points, False, t, window, params, sums_out=want)
    top0 = np.empty(window.shape, np.float32)
    sensor_grid(points, False, t, window, params, heights_out=top0)

    rng = np.random.default_rng(3)
    stale = rng.uniform(-5.0, 5.0, (*window.shape, 3)).astype(np.float32)
    sums, top = stale.copy(), np.full(window.shape, 9.0, np.float32)
    sensor_grid(points, False, t, window, params, heights_out=top, sums_out=sums)
    np.testing.assert_array_equal(top, top0)
    hit = top > 0
    assert hit.sum() >= 5  # the scene's obstacles: returns in 5 cells
    np.testing.assert_array_equal(hit, want[..., 2] > 0)  # a return: height > 0
    np.testing.assert_array_equal(sums[hit], want[hit])   # the same float32 sums, bit for bit
    np.testing.assert_array_equal(sums[~hit], stale[~hit])  # the rest untouched


def test_a_return_at_the_threshold_marks_its_cell(params):
    """With ``ground_threshold_m`` 0 an obstacle point may lie 0 m above the ground: its
    cell's height is the least positive float32, not 0, so that it reads as holding a return
    (the sums' validity, the scan's return cells)."""
    from evperc.sensor.ground import OBSTACLE
    from evperc.sensor.projection import (
        TOP_FLOOR,
        scatter_top_heights,
        scatter_top_heights_and_sums,
    )

    window = Window(RES, 4, 4, 0, 0)
    x = np.array([0.3, 1.2], np.float32)
    y = np.array([0.3, 1.2], np.float32)
    kind = np.array([OBSTACLE, OBSTACLE], np.uint8)
    height = np.array([0.0, 0.7], np.float32)
    top = np.zeros(window.shape, np.float32)
    scatter_top_heights(top, window, (0.0, 0.0), x, y, kind, height)
    assert top[0, 0] == TOP_FLOOR > 0 and top[2, 2] == np.float32(0.7)
    assert np.count_nonzero(top) == 2
    top = np.zeros(window.shape, np.float32)
    sums = np.full((*window.shape, 3), 4.0, np.float32)
    scatter_top_heights_and_sums(top, sums, window, (0.0, 0.0), x, y, kind, height)
    assert top[0, 0] == TOP_FLOOR
    np.testing.assert_allclose(sums[0, 0], [0.05, 0.05, 1.0], atol=1e-7)
    np.testing.assert_allclose(sums[2, 2], [-0.05, -0.05, 1.0], atol=1e-7)
    assert (sums[1, 1] == 4.0).all()
