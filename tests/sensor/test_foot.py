"""A ground return high above the nearer ground frees nothing (``sensor.foot_lift_m``,
docs/method.md §3 "An object's foot").

The scanner and scenes of tests/sensor/test_ground_chain.py: 16 layers 2° apart, 1.8 m up,
returns cast analytically. A 1.2 m fence 30.2 m ahead is met by the −3° layer 0.20–0.22 m up
(under the 0.3 m threshold: ground) and passed over by the −1° layer (1.27 m up there): the
scan holds only the fence's foot, and without the rule its cells are free. The rule keeps a
foot's cell free only where a small object stands beside it (a person over its shoe).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from evperc.geo.window import Window
from evperc.sensor import sensor_grid
from evperc.sensor.ground import GROUND
from tests.sensor.reference import assert_matches_reference
from tests.sensor.scenes import pose
from tests.sensor.test_ground_chain import MOUNT, SENSOR, kinds_of, sparse_scan

FOOT_X = 30.2


def grid(level: np.ndarray, params, foot: float, chain: bool = True):
    t = pose(*SENSOR, MOUNT)
    window = Window.centred_on(*SENSOR, 160.0, 0.5)
    p = replace(params, sensor_height_m=MOUNT, ground_chain=chain, foot_lift_m=foot)
    free, occ = sensor_grid((level @ t[:3, :3]).astype(np.float32), False, t, window, p)
    return window, free, occ


def cells_of(window: Window, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = window.index_of(SENSOR[0] + xy[:, 0], SENSOR[1] + xy[:, 1])
    return np.asarray(rows), np.asarray(cols)


def test_only_the_foot_is_seen(params) -> None:
    level, on_fence = sparse_scan(fence_x=FOOT_X)
    heights = level[on_fence][:, 2] + MOUNT
    assert on_fence.sum() > 50 and heights.min() > 0.19 and heights.max() < 0.23
    assert (kinds_of(level, params, chain=True)[on_fence] == GROUND).all()


def test_the_foot_frees_nothing(params) -> None:
    level, on_fence = sparse_scan(fence_x=FOOT_X)
    foot = cells_of(Window.centred_on(*SENSOR, 160.0, 0.5), level[on_fence][:, :2])
    window, free_off, occ_off = grid(level, params, foot=0.0)
    _, free_on, occ_on = grid(level, params, foot=0.15)
    assert (free_off[foot] > 0).all()              # the paper's model: the fence is free
    assert not (free_on[foot] > 0).any()           # with the rule: unknown, not occupied
    assert not occ_on.any() and not occ_off.any()
    # nothing else changes: every other cell keeps its free mass
    others = np.ones(window.shape, bool)
    others[foot] = False
    np.testing.assert_array_equal(free_on[others], free_off[others])


def test_a_foot_beside_a_seen_object_still_frees(params) -> None:
    """A walker's shoe is a foot too, with the leg seen above it: where a small object (one
    occupied cell here) stands next to the foot's cell, the rule leaves that cell free (the
    free space just ahead of a mover is its arrival evidence). A post 0.5 m behind the fence
    line at y = 0, seen 1 m up, stands for the leg."""
    level, on_fence = sparse_scan(fence_x=FOOT_X)
    post = np.array([[FOOT_X + 0.5, y, 1.0 - MOUNT] for y in (-0.05, 0.0, 0.05)])
    scene = np.vstack([level, post])
    window, free_off, occ_off = grid(scene, params, foot=0.0)
    _, free_on, occ_on = grid(scene, params, foot=0.15)
    np.testing.assert_array_equal(occ_on, occ_off)
    post_cell = cells_of(window, post[:1, :2])
    assert occ_on[post_cell] > 0
    rows, cols = cells_of(window, level[on_fence][:, :2])
    beside = (np.abs(rows - post_cell[0][0]) <= 1) & (np.abs(cols - post_cell[1][0]) <= 1)
    assert beside.any() and (~beside).sum() > 10
    assert (free_on[rows[beside], cols[beside]] == free_off[rows[beside], cols[beside]]).all()
    assert (free_off[rows[beside], cols[beside]] > 0).any()
    assert not (free_on[rows[~beside], cols[~beside]] > 0).any()


def test_a_foot_beside_a_large_object_frees_nothing(params) -> None:
    """A fence or a parked car's foot has a large object beside it: more than
    SMALL_OBJECT_CELLS occupied cells in the 5 × 5 block around the foot's cell. A wall of
    seen returns 0.5 m behind the fence line along y = −1.5…1.5 m, 1 m up, stands for it: the
    foot's cells beside its middle are unfreed as if nothing were seen."""
    level, on_fence = sparse_scan(fence_x=FOOT_X)
    wall = np.array([[FOOT_X + 0.5, y, 1.0 - MOUNT] for y in np.arange(-1.5, 1.51, 0.05)])
    window, free_off, occ_off = grid(np.vstack([level, wall]), params, foot=0.0)
    _, free_on, occ_on = grid(np.vstack([level, wall]), params, foot=0.15)
    np.testing.assert_array_equal(occ_on, occ_off)
    assert (occ_on > 0).sum() >= 6                  # the wall: a large object
    rows, cols = cells_of(window, level[on_fence][:, :2])
    wall_rows, wall_cols = cells_of(window, wall[:, :2])
    beside = np.array([((np.abs(wall_rows - r) <= 1) & (np.abs(wall_cols - c) <= 1)).any()
                       for r, c in zip(rows, cols, strict=True)])
    # the wall's middle (its 5 × 5 blocks hold 5 wall cells or more); at its ends a block
    # holds fewer, and a foot there counts the end as a small object
    middle = beside & (np.abs(level[on_fence][:, 1]) <= 0.5)
    assert middle.sum() >= 2 and (free_off[rows[middle], cols[middle]] > 0).all()
    assert not (free_on[rows[middle], cols[middle]] > 0).any()
    assert not (free_on[rows[~beside], cols[~beside]] > 0).any()


@pytest.mark.parametrize("kerb_m", [0.0, 0.12])
def test_flat_ground_and_a_kerb_keep_their_free_space(params, kerb_m: float) -> None:
    """Ground returns on the flat road and on a 0.12 m pavement (under 0.15 m above the road
    of the nearer band) free their cells as before."""
    level, _ = sparse_scan(fence=False, kerb_m=kerb_m)
    _, free_off, _ = grid(level, params, foot=0.0)
    _, free_on, _ = grid(level, params, foot=0.15)
    assert (free_off > 0).sum() > 10_000
    np.testing.assert_array_equal(free_on, free_off)


@pytest.mark.parametrize("foot", [0.0, 0.15])
def test_matches_oracle(params, foot: float) -> None:
    level, _ = sparse_scan(fence_x=FOOT_X, kerb_m=0.12)
    t = pose(-2.0, 5.0, MOUNT, yaw_deg=-35.0)
    p = replace(params, sensor_height_m=MOUNT, ground_chain=True, foot_lift_m=foot,
                max_range_m=60.0)
    window = Window.centred_on(-2.0, 5.0, 130.0, 0.5)
    want_free, _ = assert_matches_reference((level @ t[:3, :3]).astype(np.float32), False, t,
                                            window, p)
    assert (want_free > 0).sum() > 10_000
