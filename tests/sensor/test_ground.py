"""3-D clouds: ground / obstacle split and the resulting free / occupied / unknown cells."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from evperc.geo.window import Window
from evperc.sensor import sensor_grid
from evperc.sensor.ground import GROUND, OBSTACLE
from tests.sensor.scenes import pose

H = 1.73   # sensor height above the flat ground
RES = 0.5
SENSOR = (0.25, 0.25)   # centre of global cell (0, 0)
BOX = (8.1, 9.9, -1.9, 1.9, 1.5)   # x0, x1, y0, y1, height (level frame, sensor at origin)


def ground_points(r_max: float = 20.0, box: bool = True) -> np.ndarray:
    """Flat ground every 0.5° (the polar bin centres) and 0.5 m from 2 m to r_max; with
    ``box``, without the points the box hides (inside its azimuth span, beyond its face)."""
    az = np.radians(np.arange(0.0, 360.0, 0.5))
    r = np.arange(2.0, r_max + 1e-9, 0.5)
    a, rr = np.meshgrid(az, r)
    x, y = rr * np.cos(a), rr * np.sin(a)
    hidden = (x > BOX[0]) & (np.abs(y / x) <= BOX[3] / BOX[0]) & box
    return np.stack([x[~hidden], y[~hidden], np.full((~hidden).sum(), -H)], 1)


def box_points() -> np.ndarray:
    """The box's front face x = 8.1, every 0.05 m across and 0.1 m up."""
    y, z = np.meshgrid(np.arange(BOX[2], BOX[3] + 1e-9, 0.05), np.arange(0.0, BOX[4], 0.1))
    return np.stack([np.full(y.size, BOX[0]), y.ravel(), z.ravel() - H], 1)


def world_to_sensor(level: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Sensor-frame coordinates of points given as level offsets from the sensor: R⁻¹·p."""
    return (level @ t[:3, :3]).astype(np.float32)


def cell(window: Window, dx: float, dy: float) -> tuple[int, int]:
    """Window (row, col) of the cell holding the point ``(dx, dy)`` from the sensor."""
    row, col = window.index_of(np.array(SENSOR[0] + dx), np.array(SENSOR[1] + dy))
    return int(row), int(col)


@pytest.mark.parametrize("attitude", [
    {},                                           # level
    {"pitch_deg": 4.0, "roll_deg": -2.0},         # tilted, the pose knows it
    {"yaw_deg": 90.0, "pitch_deg": -3.0},         # turned and tilted
])
def test_ground_plane_and_box(params, attitude):
    t = pose(*SENSOR, 50.0, **attitude)
    points = world_to_sensor(np.vstack([ground_points(), box_points()]), t)
    window = Window.centred_on(*SENSOR, 60.0, RES)
    free, occ = sensor_grid(points, False, t, window, params)

    # the box's front face: every cell it crosses is occupied, nothing else is
    want_occ = np.zeros(window.shape, bool)
    for dy in np.arange(BOX[2], BOX[3] + 1e-9, 0.05):
        want_occ[cell(window, BOX[0], dy)] = True
    np.testing.assert_array_equal(occ > 0, want_occ)
    # free between sensor and box, and on ground in every other direction up to 20 m
    for dx, dy in [(2.0, 0.0), (5.0, 0.5), (7.5, -1.0), (-10.0, 0.0), (0.0, 15.0),
                   (-13.0, -13.0), (19.0, 5.0), (3.0, -19.0)]:
        assert free[cell(window, dx, dy)] == np.float32(0.7), (dx, dy)
    # unknown: behind the box, beyond the furthest ground return (20 m, bin 40), inside min range
    for dx, dy in [(12.0, 0.0), (25.0, 1.0), (-21.0, 0.0), (0.0, 0.0), (15.0, 17.0)]:
        assert free[cell(window, dx, dy)] == 0 and occ[cell(window, dx, dy)] == 0, (dx, dy)


@pytest.mark.parametrize(("height_m", "state"), [
    (0.2, "ground"), (0.29, "ground"), (0.5, "obstacle"), (2.4, "obstacle"), (3.0, "ignored"),
])
def test_point_height_above_ground(params, height_m, state):
    # a bar of points at that height, 10.1 m out, azimuths 146°..154° every 0.25° (wide
    # enough that the cell 15 m out at 150° lies in its shadow), over flat ground
    az = np.radians(np.arange(146.0, 154.01, 0.25))
    bar = np.stack([10.1 * np.cos(az), 10.1 * np.sin(az), np.full(az.size, height_m - H)], 1)
    t = pose(*SENSOR, 5.0)
    points = world_to_sensor(np.vstack([ground_points(box=False), bar]), t)
    window = Window.centred_on(*SENSOR, 60.0, RES)
    free, occ = sensor_grid(points, False, t, window, params)
    mid = math.radians(150.0)
    at = cell(window, 10.1 * math.cos(mid), 10.1 * math.sin(mid))
    behind = cell(window, 15 * math.cos(mid), 15 * math.sin(mid))
    if state == "obstacle":
        assert occ[at] == np.float32(0.8) and free[at] == 0
        assert free[behind] == 0 and occ[behind] == 0
        for x, y in bar[:, :2]:
            assert occ[cell(window, x, y)] == np.float32(0.8)
        # no other occupied cells than those around the bar: r in bin 20 ± a cell, 146°..154°
        xs, ys = window.cell_centres()
        dx, dy = np.meshgrid(xs - SENSOR[0], ys - SENSOR[1])
        near_bar = (np.abs(np.hypot(dx, dy) - 10.25) < 0.7) & (
            np.abs(np.degrees(np.arctan2(dy, dx)) - 150.0) < 4.5)
        assert not (occ > 0)[~near_bar].any()
    else:   # ground or ignored: the whole disc of ground is free, nothing occupied
        assert free[at] == np.float32(0.7) and free[behind] == np.float32(0.7)
        assert not occ.any()


def test_unknown_pitch_is_absorbed_by_the_local_ground_estimate(params):
    # sensor really pitched up 2° but the pose says level: the ground appears to rise by
    # r·tan 2° (0.7 m at 20 m); the local estimate per 2 m band follows it
    true_pose = pose(*SENSOR, 0.0, pitch_deg=2.0)
    points = world_to_sensor(ground_points(box=False), true_pose)
    window = Window.centred_on(*SENSOR, 60.0, RES)
    free, occ = sensor_grid(points, False, pose(*SENSOR, 0.0), window, params)
    assert not occ.any()
    xs, ys = window.cell_centres()
    r = np.hypot(xs[None, :] - SENSOR[0], ys[:, None] - SENSOR[1])
    assert (free[(r >= 1.0) & (r < 19.5)] == np.float32(0.7)).all()


def test_ground_with_a_kerb_and_a_gentle_slope_is_not_an_obstacle(params):
    # 5 % slope up towards +x, plus a 0.12 m kerb at y > 4 m
    g = ground_points(box=False)
    g[:, 2] += 0.05 * np.maximum(g[:, 0], 0) + 0.12 * (g[:, 1] > 4.0)
    t = pose(*SENSOR, 0.0)
    free, occ = sensor_grid(world_to_sensor(g, t), False, t,
                            Window.centred_on(*SENSOR, 60.0, RES), params)
    assert not occ.any()
    assert (free > 0).sum() > 0.9 * math.pi * (20.0**2 - 1.0) / RES**2


def bumper_ring() -> np.ndarray:
    """A sensor 0.5 m above flat ground (an IBEO at a bumper), its lowest layer meeting the
    road on a ring at 23.9 m: 0.75° apart over 150° in front, except a 20° sector (30°–50°)
    where something near hides all but 3 returns; level offsets from the sensor."""
    az = np.radians(np.arange(-75.0, 75.0, 0.75))
    keep = (az < np.radians(30.0)) | (az >= np.radians(50.0))
    hidden = np.flatnonzero(~keep)[1::7][:3]  # 30.75°, 36°, 41.25°: inside the sector
    az = np.concatenate([az[keep], az[hidden]])
    r = np.full(az.size, 23.9)
    return np.stack([r * np.cos(az), r * np.sin(az), np.full(az.size, -0.5)], 1)


def test_a_low_sensor_with_the_scan_fallback_keeps_its_sparse_ground_ground(params):
    """The prior puts the ground 1.73 m below; the ring is 1.23 m above that plane. Where
    a 10° sector holds ≥ 5 ring returns, the local estimate finds the ground (both
    fallbacks); in the hidden sector 3 returns are too few and with the prior as fallback
    they are obstacles — the false ring of the simulated IBEO drives — while with the
    scan's median (the ring's height everywhere else) they are ground."""
    ring = bumper_ring()
    t = pose(*SENSOR, 0.5)
    window = Window.centred_on(*SENSOR, 60.0, RES)
    sparse = np.arange(len(ring)) >= len(ring) - 3  # bumper_ring puts them last
    for fallback, sparse_kind in (("prior", OBSTACLE), ("scan", GROUND)):
        kinds = np.empty(len(ring), np.uint8)
        sensor_grid(world_to_sensor(ring, t), False, t, window,
                    replace(params, ground_fallback=fallback), kinds_out=kinds)
        assert (kinds[~sparse] == GROUND).all(), fallback
        assert (kinds[sparse] == sparse_kind).all(), fallback


def test_the_scan_fallback_keeps_a_box_an_obstacle(params):
    """The fallback moves no accepted estimate: the flat-ground-and-box scene splits the
    same with both fallbacks."""
    t = pose(*SENSOR, H)
    pts = world_to_sensor(np.vstack([ground_points(), box_points()]), t)
    window = Window.centred_on(*SENSOR, 60.0, RES)
    a = sensor_grid(pts, False, t, window, params)
    b = sensor_grid(pts, False, t, window, replace(params, ground_fallback="scan"))
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert a[1].any()
