"""The all-returns obstacle mask (``sensor_grid(..., hits_out=)``, objects.cluster_on =
"all_returns"): every cell holding an obstacle return, also behind the first return of its
azimuth bin; ground and ignored (too high) points are not in it; the masses are unchanged."""

from __future__ import annotations

import numpy as np
import pytest

from evperc.geo.window import Window
from evperc.sensor import sensor_grid
from tests.sensor.scenes import pose
from tests.sensor.test_ground import RES, SENSOR, H, box_points, cell, ground_points

#: level offsets (x, y, height above the ground) of extra returns
BEHIND = (12.2, 0.3, 0.8)     # behind the box's face, in the azimuth bins it occupies
BESIDE = (-6.0, 4.0, 0.5)     # an obstacle alone in its azimuth bin (a first return)
TOO_HIGH = (-9.0, -7.0, 4.0)  # above max_obstacle_height_m (2.5 m): ignored


def level(*points: tuple[float, float, float]) -> np.ndarray:
    return np.array([[x, y, h - H] for x, y, h in points])


@pytest.mark.parametrize("attitude", [{}, {"yaw_deg": 90.0, "pitch_deg": -3.0}])
def test_mask_is_the_cells_of_the_obstacle_points(params, attitude):
    t = pose(*SENSOR, 50.0, **attitude)
    extra = level(BEHIND, BESIDE, TOO_HIGH)
    level_pts = np.vstack([ground_points(), box_points(), extra])
    points = (level_pts @ t[:3, :3]).astype(np.float32)
    window = Window.centred_on(*SENSOR, 60.0, RES)
    hits = np.ones(window.shape, np.bool_)  # stale contents must be overwritten
    free, occ = sensor_grid(points, False, t, window, params, hits_out=hits)

    # independent check: the cells of the points whose height above the (flat) ground is in
    # [ground_threshold_m, max_obstacle_height_m] (0.3 m, 2.5 m), by the window's own lookup;
    # +1 mm: a face point at 0.3 m may fall either side in float32 (same cell as the ones above)
    height = level_pts[:, 2] + H
    obstacle = ((height >= params.ground_threshold_m + 1e-3)
                & (height <= params.max_obstacle_height_m))
    want = np.zeros(window.shape, bool)
    for x, y, _ in level_pts[obstacle]:
        want[cell(window, x, y)] = True
    np.testing.assert_array_equal(hits, want)

    behind = cell(window, *BEHIND[:2])
    assert hits[behind] and occ[behind] == 0 and free[behind] == 0  # unknown to the grid
    assert hits[cell(window, *BESIDE[:2])] and occ[cell(window, *BESIDE[:2])] > 0
    assert not hits[cell(window, *TOO_HIGH[:2])]
    for dx, dy in [(2.0, 0.0), (5.0, 0.5), (-10.0, 0.0), (0.0, 15.0)]:  # ground returns
        assert not hits[cell(window, dx, dy)], (dx, dy)
    # every occupied cell of the box's face holds a return (no rasterised-only cell here)
    assert (hits | ~(occ > 0)).all()

    # the masses do not depend on the mask
    free0, occ0 = sensor_grid(points, False, t, window, params)
    np.testing.assert_array_equal(free, free0)
    np.testing.assert_array_equal(occ, occ0)


def test_mask_of_wrong_shape_is_refused(params):
    window = Window.centred_on(*SENSOR, 20.0, RES)
    with pytest.raises(ValueError, match="hits_out"):
        sensor_grid(np.zeros((0, 3), np.float32), False, np.eye(4), window, params,
                    hits_out=np.zeros((3, 3), np.bool_))
