"""evperc.sensor against the per-point / per-cell plain-Python oracle (tests/sensor/reference.py)
on synthetic scenes: random poses, tilts, 2-D and 3-D, two resolutions."""

from __future__ import annotations

import numpy as np
import pytest

from evperc.geo.window import Window
from evperc.sensor import SensorParams, sensor_grid
from tests.sensor.reference import reference_grid
from tests.sensor.scenes import hdl64_scene, ibeo_scene, pose


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("planar", [False, True])
@pytest.mark.parametrize("chain_foot", [(False, 0.0), (True, 0.15), (True, 0.05)])
def test_matches_oracle_on_a_street(seed, planar, chain_foot):
    rng = np.random.default_rng(seed)
    level = hdl64_scene(seed)[seed::37].astype(np.float64)
    t = pose(5e5 + rng.uniform(0, 10), 5.4e6 + rng.uniform(0, 10), 120.0,
             yaw_deg=rng.uniform(-180, 180), pitch_deg=rng.uniform(-4, 4),
             roll_deg=rng.uniform(-4, 4))
    points = (level @ t[:3, :3]).astype(np.float32)   # level offsets → sensor frame
    points[rng.integers(0, len(points), 5)] = np.nan
    res = (0.5, 1.0)[seed % 2]
    params = SensorParams(range_bin_m=res, max_range_m=35.0, azimuth_resolution_deg=0.7,
                          ground_chain=chain_foot[0], foot_lift_m=chain_foot[1])
    window = Window.centred_on(t[0, 3] + 3.0, t[1, 3] - 2.0, 70.0, res)
    free, occ = sensor_grid(points, planar, t, window, params)
    want_free, want_occ = reference_grid(points, planar, t, window, params)
    # planar: the ground rings themselves are obstacles, so little is free
    assert (want_free > 0).sum() > (30 if planar else 500) and (want_occ > 0).sum() > 50
    np.testing.assert_array_equal(free, want_free)
    np.testing.assert_array_equal(occ, want_occ)


def test_matches_oracle_on_a_four_layer_scan():
    points = ibeo_scene(1)
    t = pose(10.3, -4.6, 0.5, yaw_deg=33.0)
    params = SensorParams(range_bin_m=0.5, max_range_m=60.0, azimuth_resolution_deg=0.25,
                          sensor_height_m=0.5)
    window = Window.centred_on(10.3, -4.6, 100.0, 0.5)
    for planar in (True, False):
        free, occ = sensor_grid(points, planar, t, window, params)
        want_free, want_occ = reference_grid(points, planar, t, window, params)
        assert (want_occ > 0).sum() > 20
        np.testing.assert_array_equal(free, want_free)
        np.testing.assert_array_equal(occ, want_occ)
