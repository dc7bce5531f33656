"""2-D scans: one wall point, hand-worked cell by cell (method.md §3)."""

from __future__ import annotations

import numpy as np
import pytest

from evperc.geo.window import Window
from evperc.sensor import sensor_grid
from tests.sensor.scenes import pose

RES = 0.5


def expected_ray(window: Window, sensor_cell: tuple[int, int], step: tuple[int, int],
                 n_free: tuple[int, int], hits: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Masks of the free and occupied cells: along the global lattice from ``sensor_cell``
    (iy, ix) in unit ``step``, cells n_free[0]..n_free[1] free and cells ``hits`` occupied."""
    free = np.zeros(window.shape, bool)
    occ = np.zeros(window.shape, bool)
    for n in range(n_free[0], n_free[1] + 1):
        free[sensor_cell[0] + n * step[0] - window.row0,
             sensor_cell[1] + n * step[1] - window.col0] = True
    for n in hits:
        occ[sensor_cell[0] + n * step[0] - window.row0,
            sensor_cell[1] + n * step[1] - window.col0] = True
    return free, occ


@pytest.mark.parametrize(
    ("sensor_xy", "yaw_deg", "sensor_cell", "step"),
    [
        ((100.25, 200.25), 0.0, (400, 200), (0, 1)),       # looking east
        ((37.75, -12.25), 90.0, (-25, 75), (1, 0)),        # turned to north, elsewhere
        ((-3.25, 7.75), 180.0, (15, -7), (0, -1)),         # looking west
    ],
)
def test_single_wall_point_straight_ahead(params, sensor_xy, yaw_deg, sensor_cell, step):
    # point 10.1 m ahead: range bin 20 = [10, 10.5); free bins 2..19 (bin 1 centre 0.5 m is
    # below min_range 1 m); the world cells on the ray are the cells n = 2..19 from the
    # sensor's cell, the wall cell is n = 20, everything else unknown.
    t = pose(*sensor_xy, 2.0, yaw_deg=yaw_deg)
    window = Window.centred_on(*sensor_xy, 60.0, RES)
    points = np.array([[10.1, 0.0, 0.0]], np.float32)
    free, occ = sensor_grid(points, True, t, window, params)
    want_free, want_occ = expected_ray(window, sensor_cell, step, (2, 19), (20,))
    assert free.dtype == np.float32 and occ.dtype == np.float32
    assert free.shape == occ.shape == window.shape
    np.testing.assert_array_equal(occ, np.where(want_occ, np.float32(0.8), 0))
    np.testing.assert_array_equal(free, np.where(want_free, np.float32(0.7), 0))


def test_sensor_pitch_does_not_shorten_the_planar_ray(params):
    # a 2-D scanner pitched down 10°: the return 10.1 m along its beam lies 10.1·cos 10° =
    # 9.947 m ahead horizontally: polar bin 19 = [9.5, 10) is occupied. World cell n covers
    # [0.5·n − 0.25, 0.5·n + 0.25) ahead of the sensor: cell 19 (centre 9.5 m, in bin 19) is
    # occupied by sampling, cell 20 (holding the point) by the point scatter; 2..18 free.
    t = pose(0.25, 0.25, 2.0, pitch_deg=10.0)
    window = Window.centred_on(0.25, 0.25, 40.0, RES)
    free, occ = sensor_grid(np.array([[10.1, 0, 0]], np.float32), True, t, window, params)
    want_free, want_occ = expected_ray(window, (0, 0), (0, 1), (2, 18), (19, 20))
    np.testing.assert_array_equal(occ > 0, want_occ)
    np.testing.assert_array_equal(free > 0, want_free)


def test_other_azimuths_stay_unknown_and_masses_are_exclusive(params):
    rng = np.random.default_rng(3)
    angles = rng.uniform(-np.pi, np.pi, 200)
    ranges = rng.uniform(2, 25, 200)
    points = np.stack([ranges * np.cos(angles), ranges * np.sin(angles),
                       np.zeros(200)], 1).astype(np.float32)
    window = Window.centred_on(0.0, 0.0, 60.0, RES)
    free, occ = sensor_grid(points, True, pose(0.1, -0.2, 1.0), window, params)
    assert set(np.unique(free)) <= {np.float32(0), np.float32(0.7)}
    assert set(np.unique(occ)) <= {np.float32(0), np.float32(0.8)}
    assert not np.any((free > 0) & (occ > 0))
    # every cell beyond the furthest return (25 m + one bin) is unknown
    xs, ys = window.cell_centres()
    far = np.hypot(xs[None, :] - 0.1, ys[:, None] + 0.2) > 25.6
    assert not free[far].any() and not occ[far].any()
