"""Each cell's highest return above the local ground (``sensor_grid(..., heights_out=)``,
objects.moving_min_height_m): over flat ground the local estimate is the plane, so a cell's
value is the height of its highest obstacle point, computed here from the scene's own
coordinates; ground and ignored points give nothing; the masses are unchanged. (No box: a
wall of returns biases the local ground estimate of its coarse cell, which is the ground
split's business, tested in test_ground.py.)"""

from __future__ import annotations

import numpy as np
import pytest

from evperc.geo.window import Window
from evperc.sensor import sensor_grid
from tests.sensor.scenes import pose
from tests.sensor.test_all_hits import BEHIND, BESIDE, TOO_HIGH, level
from tests.sensor.test_ground import RES, SENSOR, H, cell, ground_points

LOW = (5.0, -6.0, 0.4)        # a return just above the 0.3 m threshold: a low obstacle
#: a person 11 m out: returns every 0.1 m from 0.4 m to 1.7 m, and a second one beside
PERSON = tuple((11.1, -3.2, 0.4 + 0.1 * k) for k in range(14)) + ((11.6, -3.2, 1.1),)


def scene(attitude: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, Window]:
    """The flat ground, the obstacles above and the person, seen from a sensor posed with
    ``attitude``: (pose, points in the level frame, points in the sensor frame, window)."""
    t = pose(*SENSOR, 50.0, **attitude)
    level_pts = np.vstack([ground_points(box=False),
                           level(BEHIND, BESIDE, TOO_HIGH, LOW, *PERSON)])
    points = (level_pts @ t[:3, :3]).astype(np.float32)
    return t, level_pts, points, Window.centred_on(*SENSOR, 60.0, RES)


def obstacle_points(level_pts: np.ndarray, params) -> np.ndarray:
    """bool: the points whose height above the flat ground is in [ground_threshold_m,
    max_obstacle_height_m] (the ground split's OBSTACLE over a flat scene)."""
    height = level_pts[:, 2] + H
    return (height >= params.ground_threshold_m) & (height <= params.max_obstacle_height_m)


@pytest.mark.parametrize("attitude", [{}, {"yaw_deg": 90.0, "pitch_deg": -3.0}])
def test_top_heights_are_the_highest_obstacle_point_of_each_cell(params, attitude):
    t, level_pts, points, window = scene(attitude)
    top = np.full(window.shape, 7.0, np.float32)  # stale contents must be overwritten
    free, occ = sensor_grid(points, False, t, window, params, heights_out=top)

    # independent: the highest point of each cell among those whose height is in
    # [ground_threshold_m, max_obstacle_height_m]
    height = level_pts[:, 2] + H
    obstacle = obstacle_points(level_pts, params)
    want = np.zeros(window.shape, np.float32)
    for (x, y, _), h in zip(level_pts[obstacle], height[obstacle], strict=True):
        at = cell(window, x, y)
        want[at] = max(want[at], h)
    # the local ground estimate of a flat scene is the plane to within its 5 cm height bins
    # and float32 levelling of a tilted pose: 6 cm (a person is 1.7 m, a ghost 0.3-0.5 m)
    np.testing.assert_allclose(top, want, atol=0.06)
    assert ((top > 0) == (want > 0)).all()
    assert top[cell(window, *BEHIND[:2])] == pytest.approx(0.8, abs=0.06)
    assert top[cell(window, *LOW[:2])] == pytest.approx(0.4, abs=0.06)
    assert top[cell(window, *TOO_HIGH[:2])] == 0
    assert top[cell(window, 11.1, -3.2)] == pytest.approx(1.7, abs=0.06)  # the person's head
    assert top[cell(window, 11.6, -3.2)] == pytest.approx(1.1, abs=0.06)
    assert top[cell(window, 2.0, 0.0)] == 0  # ground

    # the masses do not depend on it
    free0, occ0 = sensor_grid(points, False, t, window, params)
    np.testing.assert_array_equal(free, free0)
    np.testing.assert_array_equal(occ, occ0)


def test_a_planar_scan_has_no_ground_so_every_return_is_tall(params):
    t = pose(*SENSOR, 0.0)
    pts = np.array([[6.0, 1.0, 0.0], [-4.0, 3.0, 0.0]], np.float32)
    window = Window.centred_on(*SENSOR, 40.0, RES)
    top = np.zeros(window.shape, np.float32)
    sensor_grid(pts, True, t, window, params, heights_out=top)
    assert np.isinf(top[cell(window, 6.0, 1.0)]) and np.isinf(top[cell(window, -4.0, 3.0)])
    assert np.count_nonzero(top) == 2


def test_a_wrong_heights_array_is_refused(params):
    window = Window.centred_on(*SENSOR, 20.0, RES)
    with pytest.raises(ValueError, match="heights_out must be float32"):
        sensor_grid(np.zeros((1, 3), np.float32), False, pose(*SENSOR, 0.0), window, params,
                    heights_out=np.zeros(window.shape, np.float64))
