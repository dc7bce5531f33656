"""Ray casting and truth painting on hand-made scenes, checked against hand geometry."""

from __future__ import annotations

import numpy as np
import pytest

from evperc.geo.window import Window
from evperc.sim.lidar import GROUND, LidarProfile, cast, make_profile
from evperc.sim.scene import BOX, CYLINDER, FREE, INFRASTRUCTURE, STOPPED, Solids
from evperc.sim.truth import paint_solids, visible_cells

NO_WALLS = np.zeros((0, 4))


def solids(*rows: tuple) -> Solids:
    """rows of (kind, x, y, heading, length, width, height, label)."""
    cols = list(zip(*rows, strict=True))
    return Solids(np.array(cols[0], dtype=np.int8), *(np.array(c, dtype=float)
                                                      for c in cols[1:7]),
                  np.array(cols[7], dtype=np.uint8))


def exact(profile: LidarProfile, **kw: object) -> LidarProfile:
    return LidarProfile(**{**profile.__dict__, "range_noise_m": 0.0, "dropout": 0.0, **kw})


def test_box_in_front_is_hit_on_its_front_face() -> None:
    prof = exact(make_profile("ibeo4"))
    box = solids((BOX, 10.0, 0.0, 0.0, 4.0, 2.0, 1.5, STOPPED))
    hits = cast(prof, 0.0, 0.0, 0.0, NO_WALLS, np.zeros(0), box, np.random.default_rng(0))
    # face x = 8 spans |y| <= 1: beams with |8 tan a| <= 1 hit it at horizontal 8 / cos a
    on_face = np.abs(8.0 * np.tan(prof.azimuths)) < 0.999
    assert on_face.sum() >= 5
    expected = 8.0 / np.cos(prof.azimuths[on_face])
    for layer in range(4):  # z at 8 m is 0.5 ± 0.17: every layer is within [0, 1.5]
        np.testing.assert_allclose(hits.horizontal_m[layer, on_face], expected, rtol=1e-9)
        assert (hits.label[layer, on_face] == STOPPED).all()
    pts, _, _ = hits.points()
    front = np.abs(pts[:, 1]) < 0.99
    near = pts[front & (pts[:, 0] < 20)]
    np.testing.assert_allclose(near[:, 0], 8.0, atol=1e-4)


def test_box_roof_wall_cylinder_and_ground() -> None:
    # one azimuth straight ahead, five elevations, lidar 1.9 m up
    tan = np.array([-0.04, -0.1, 0.0, 0.05, -0.06])
    prof = LidarProfile("t", np.zeros(1), np.arctan(tan), 80.0, 0.1, 0.0, 0.0, (0.0, 0.0, 1.9))
    box = solids((BOX, 10.0, 0.0, 0.0, 4.0, 2.0, 1.5, STOPPED))
    hits = cast(prof, 0.0, 0.0, 0.0, NO_WALLS, np.zeros(0), box, np.random.default_rng(0))
    h = hits.horizontal_m[:, 0]
    assert h[0] == pytest.approx((1.9 - 1.5) / 0.04)    # z(8) = 1.58 > 1.5: roof at s = 10
    assert h[1] == pytest.approx(8.0)                   # z(8) = 1.1: front face
    assert np.isnan(h[2]) and np.isnan(h[3])            # over the box, nothing beyond
    assert h[4] == pytest.approx(8.0)                   # z(8) = 1.42
    assert (hits.label[[0, 1, 4], 0] == STOPPED).all()
    np.testing.assert_allclose(hits.range_m[:, 0], h / np.cos(np.arctan(tan)))
    wall = np.array([[30.0, -5.0, 30.0, 5.0]])
    pole = solids((CYLINDER, 20.0, 0.0, 0.0, 1.0, 1.0, 1.0, 6))
    hits = cast(prof, 0.0, 0.0, 0.0, wall, np.array([10.0]), pole, np.random.default_rng(0))
    h, lab = hits.horizontal_m[:, 0], hits.label[:, 0]
    # z(19.5) = 1.12 > 1 and the roof level (s = 22.5) lies beyond the pole: the wall at 30 m
    # (z = 0.7) comes before the ground (47.5 m)
    assert h[0] == pytest.approx(30.0) and lab[0] == INFRASTRUCTURE
    assert h[1] == pytest.approx(19.0) and lab[1] == GROUND     # z(19.5) < 0
    assert h[2] == pytest.approx(30.0) and h[3] == pytest.approx(30.0)   # z 1.9 and 3.4
    assert h[4] == pytest.approx(19.5) and lab[4] == 6          # z(19.5) = 0.73: the pole


def test_box_cells_are_its_class_and_hits_land_in_them() -> None:
    prof = exact(make_profile("ibeo4"))
    box = solids((BOX, 10.0, 0.0, 0.0, 4.0, 2.0, 1.5, STOPPED))
    hits = cast(prof, 0.0, 0.0, 0.0, NO_WALLS, np.zeros(0), box, np.random.default_rng(0))
    win = Window.centred_on(0.0, 0.0, 40.0, 0.5)
    classes = np.full(win.shape, FREE, dtype=np.uint8)
    ids = np.zeros(win.shape, dtype=np.int32)
    paint_solids(classes, ids, win, box)
    cx, cy = win.cell_centres()
    inside = (np.abs(cx[None, :] - 10.0) <= 2.0) & (np.abs(cy[:, None]) <= 1.0)
    np.testing.assert_array_equal(classes == STOPPED, inside)
    assert inside.sum() == 8 * 4
    np.testing.assert_array_equal(ids == 1, inside)
    pts, _, _ = hits.points()
    on_box = pts[(pts[:, 0] < 12.5) & (np.abs(pts[:, 1]) <= 1.0)]
    row, col = win.index_of(on_box[:, 0], on_box[:, 1])
    assert len(on_box) > 0 and (classes[row, col] == STOPPED).all()
    vis = visible_cells(win, hits, 0.0, 0.0, 0.0)
    assert vis[row, col].all()
    r_behind, c_behind = win.index_of(np.array([14.0]), np.array([0.0]))
    assert not vis[r_behind[0], c_behind[0]]       # hidden behind the box
    r_beside, c_beside = win.index_of(np.array([5.0]), np.array([0.1]))
    assert vis[r_beside[0], c_beside[0]]           # crossed by beams before the box
    r_back, c_back = win.index_of(np.array([-5.0]), np.array([0.0]))
    assert not vis[r_back[0], c_back[0]]           # outside the 150° field of view


def test_small_object_covers_the_cell_of_its_centre() -> None:
    pole = solids((CYLINDER, 3.3, 3.3, 0.0, 0.2, 0.2, 6.0, 6))
    win = Window(0.5, 20, 20, 0, 0)
    classes = np.full(win.shape, FREE, dtype=np.uint8)
    paint_solids(classes, None, win, pole)
    assert list(zip(*np.nonzero(classes == 6), strict=True)) == [(6, 6)]  # 3.3 / 0.5 = 6.6


def test_painting_solids_that_all_lie_outside_the_window_changes_nothing() -> None:
    """Regression: a scene whose solids are all far from the window (a long drive leaving
    them behind) used to raise IndexError."""
    window = Window(0.5, 20, 20, 0, 0)
    classes = np.full(window.shape, FREE, dtype=np.uint8)
    far = solids((BOX, 500.0, 500.0, 0.0, 4.0, 2.0, 1.5, STOPPED),
                 (CYLINDER, -300.0, 20.0, 0.0, 0.3, 0.3, 3.0, INFRASTRUCTURE))
    paint_solids(classes, None, window, far)
    assert np.all(classes == FREE)


def test_visible_stops_at_the_nearest_obstacle_not_the_farthest_layer() -> None:
    """An upper layer passing over a parked car and hitting a wall behind it says nothing
    about the cells between car and wall (the sensor model gives them no evidence)."""
    from evperc.sim.lidar import Hits

    az = np.array([-0.2, 0.0, 0.2])
    nan = np.nan
    horizontal = np.array([[5.2, 5.2, 5.2],      # lower layer: the car's face at 5.2 m
                           [20.2, 20.2, 20.2],   # upper layer: over the car, a wall at 20 m
                           [nan, nan, nan]])
    label = np.array([[STOPPED] * 3, [INFRASTRUCTURE] * 3, [GROUND] * 3], dtype=np.uint8)
    hits = Hits(horizontal, horizontal, label, az, np.array([-0.05, 0.05, -0.2]))
    window = Window(0.5, 10, 60, -5, -5)   # x from -2.5 to 27.5 m, y from -2.5 to 2.5 m
    seen = visible_cells(window, hits, 0.0, 0.0, 0.0)
    row, col = window.index_of(np.array([3.0, 5.2, 12.0, 20.2]), np.zeros(4))
    assert seen[row[0], col[0]] and seen[row[1], col[1]]          # before and at the car
    assert not seen[row[2], col[2]] and not seen[row[3], col[3]]  # behind it, and the wall
    nine = np.full((3, 3), 9.0)
    ground_only = Hits(nine, nine, np.full((3, 3), GROUND, np.uint8), az,
                       np.array([-0.2] * 3))
    seen = visible_cells(window, ground_only, 0.0, 0.0, 0.0)
    row, col = window.index_of(np.array([8.5, 12.0]), np.zeros(2))
    assert seen[row[0], col[0]] and not seen[row[1], col[1]]      # free up to the ground hit
