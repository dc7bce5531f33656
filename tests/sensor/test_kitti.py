"""Real geometry: KITTI odometry 00, scan 0 (HDL-64E, 1.73 m above a residential street with
parked cars on both sides). Needs /work/shared/data/kitti00 (see its README)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from evperc.config import default_config
from evperc.geo.window import Window
from evperc.sensor import SensorParams, sensor_grid
from tests.sensor.scenes import pose

SCAN = Path(__file__).resolve().parents[2] / "../shared/data/kitti00/velodyne/000000.bin"

pytestmark = pytest.mark.skipif(not SCAN.exists(),
                                reason=f"KITTI scan {SCAN} absent (shared data not mounted)")


@pytest.fixture(scope="module")
def grid():
    points = np.fromfile(SCAN, np.float32).reshape(-1, 4)[:, :3]
    # lidar frame: x forward, y left, z up; put it level at an arbitrary UTM-like position
    t = pose(457_000.0, 5_428_000.0, 118.0, yaw_deg=59.6)
    window = Window.centred_on(457_000.0, 5_428_000.0, 100.0, 0.5)
    params = SensorParams.from_config(default_config()["sensor"], 0.5)
    free, occ = sensor_grid(points, False, t, window, params)
    # cell centres as (forward, left) offsets in the lidar frame
    xs, ys = window.cell_centres()
    dx, dy = np.meshgrid(xs - t[0, 3], ys - t[1, 3])
    fwd = dx * t[0, 0] + dy * t[1, 0]
    left = dx * t[0, 1] + dy * t[1, 1]
    return free, occ, fwd, left


def test_road_ahead_is_free_not_occupied(grid):
    free, occ, fwd, left = grid
    road = (fwd >= 5) & (fwd < 15) & (np.abs(left) < 1.5)
    assert (free[road] > 0).mean() >= 0.9        # seen: 1.00
    assert (occ[road] > 0).mean() <= 0.02        # seen: 0.00


def test_parked_cars_on_both_sides_are_occupied(grid):
    free, occ, fwd, left = grid
    ahead = (fwd >= 3) & (fwd < 20)
    right = ahead & (left >= -8) & (left < -2.5)
    left_side = ahead & (left >= 4.5) & (left < 9)
    assert (occ[right] > 0).sum() >= 20          # seen: 38
    assert (occ[left_side] > 0).sum() >= 20      # seen: 44
    # between the two rows of cars the street is free
    assert (free[ahead & (np.abs(left) < 2)] > 0).mean() >= 0.9   # seen: 0.99


def test_plausible_shares_within_40_m(grid):
    free, occ, fwd, left = grid
    disc = np.hypot(fwd, left) < 40
    free_share = (free[disc] > 0).mean()
    occ_share = (occ[disc] > 0).mean()
    assert 0.15 <= free_share <= 0.8            # seen: 0.27 (the rest is shadow / no return)
    assert 0.005 <= occ_share <= 0.1            # seen: 0.019
    assert not np.any((free > 0) & (occ > 0))
