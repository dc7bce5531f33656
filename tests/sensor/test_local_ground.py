"""Step 5 of the ground split (``sensor.ground_local_raise_m`` = Δ): the local ground of a
point just above the threshold is the lowest return near the coarse ground (within Δ of it)
within one 0.5 m cell of its own, if higher than the coarse estimate (evperc/sensor/ground.py,
docs/method.md §3)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from evperc.geo.window import Window
from evperc.sensor import sensor_grid
from evperc.sensor.ground import (
    GROUND,
    LOCAL_CELL_M,
    LOCAL_CELLS,
    OBSTACLE,
    Z_BIN_M,
    classify_points,
    histogram_shape,
    local_grid_side,
)
from tests.sensor.scenes import pose
from tests.sensor.test_ground import SENSOR, H, box_points, ground_points, world_to_sensor

RES = 0.5
RAISE = 0.2


def kinds_of(level: np.ndarray, params, raise_m: float) -> np.ndarray:
    """The ground split's kind of each point (level offsets from a level sensor H up)."""
    t = pose(*SENSOR, H)
    kinds = np.empty(len(level), np.uint8)
    sensor_grid(world_to_sensor(level, t), False, t, Window.centred_on(*SENSOR, 60.0, RES),
                replace(params, ground_local_raise_m=raise_m), kinds_out=kinds)
    return kinds


def bowl(slope: float) -> np.ndarray:
    """Ground every 0.5° and 0.1 m from 2 m to 20 m, flat to 6 m, then rising by ``slope``
    per metre of range to 12 m, then flat again: within each 2 m band of the coarse estimate
    the ground rises by 2·slope."""
    az = np.radians(np.arange(0.0, 360.0, 0.5))
    r = np.arange(2.0, 20.0, 0.1)
    a, rr = np.meshgrid(az, r)
    h = slope * np.clip(rr - 6.0, 0.0, 6.0)
    return np.stack([(rr * np.cos(a)).ravel(), (rr * np.sin(a)).ravel(), (h - H).ravel()], 1)


def test_a_slope_steeper_than_the_band_allows_is_ground_with_the_local_step(params):
    """A 20 % rise within a 2 m band (0.4 m) puts the top of each band above the 0.3 m
    threshold over the band's one estimate: obstacles with the coarse estimate alone. Each
    such return's block (1–1.5 m down the slope) holds returns 0.1–0.3 m lower, some of them
    within Δ = 0.2 of the estimate, so with the step every return of the slope is ground."""
    ground = bowl(0.2)
    coarse = kinds_of(ground, params, 0.0)
    assert (coarse == OBSTACLE).sum() > 1000
    assert not (kinds_of(ground, params, RAISE) == OBSTACLE).any()


def test_an_object_beside_visible_ground_splits_as_without_the_step(params):
    """The box on flat ground: the ground beside its face is each face return's block
    minimum, so the split is the coarse one exactly."""
    level = np.vstack([ground_points(), box_points()])
    np.testing.assert_array_equal(kinds_of(level, params, RAISE), kinds_of(level, params, 0.0))


@pytest.mark.parametrize("raise_m", [0.1, 0.2, 0.3])
def test_an_object_with_no_ground_in_sight_keeps_the_coarse_split(params, raise_m):
    """A post 30 m out (face x = 30.1, 0.4 m wide) seen from 0.4 m up (its base hidden) with
    no ground within 1.2 m of it, but ground elsewhere in its 10° × 2 m coarse cell (so the
    coarse estimate is the flat ground): no return near the ground in its returns' blocks, so
    the step leaves them as the coarse estimate splits them — every row an obstacle. (With
    Δ above its lowest row's 0.4 m the post's own lowest returns would count as near the
    ground: Δ is the bound on what the step may take for ground.)"""
    y, z = np.meshgrid(np.arange(0.5, 0.9 + 1e-9, 0.05), np.arange(0.4, 1.55, 0.1))
    post = np.stack([np.full(y.size, 30.1), y.ravel(), z.ravel() - H], 1)
    ground = ground_points(r_max=40.0, box=False)
    ground = ground[(np.abs(ground[:, 0] - 30.1) > 1.2) | (np.abs(ground[:, 1] - 0.7) > 1.4)]
    kinds = kinds_of(np.vstack([ground, post]), params, raise_m)
    assert (kinds[:len(ground)] == GROUND).all()
    assert (kinds[len(ground):] == OBSTACLE).all()


@pytest.mark.parametrize(("raise_m", "lifted"), [(0.1, False), (0.2, True), (0.3, True)])
def test_an_object_on_a_verge_loses_at_most_the_verge(params, raise_m, lifted):
    """The same post standing on a verge 0.17 m high around its base (ground by the coarse
    estimate g, the centre of its histogram bin, Z_BIN_M / 2 above the flat ground) and seen
    from 0.4 m up. With Δ above the verge's height over g the verge is each return's block
    minimum and the local ground rises to it: exactly the rows below threshold + 0.17 m turn
    ground (the 0.4 m row). With Δ = 0.1 the verge is too high above g to count as ground
    near the coarse estimate: the post keeps its coarse split."""
    y, z = np.meshgrid(np.arange(0.5, 0.9 + 1e-9, 0.05), np.arange(0.4, 1.55, 0.1))
    post = np.stack([np.full(y.size, 30.1), y.ravel(), z.ravel() - H], 1)
    ground = ground_points(r_max=40.0, box=False)
    near = (np.abs(ground[:, 0] - 30.1) <= 1.2) & (np.abs(ground[:, 1] - 0.7) <= 1.4)
    verge = ground[near & (np.hypot(ground[:, 0], ground[:, 1]) < 30.0)]
    verge[:, 2] += 0.17
    ground = ground[~near]
    kinds = kinds_of(np.vstack([ground, verge, post]), params, raise_m)
    assert (kinds[:len(ground) + len(verge)] == GROUND).all()
    h = post[:, 2] + H
    bound = params.ground_threshold_m + (0.17 if lifted else Z_BIN_M / 2)
    got = kinds[len(ground) + len(verge):]
    np.testing.assert_array_equal(got == GROUND, h < bound)
    assert (got[h > bound] == OBSTACLE).all()
    assert (h < bound).sum() == (9 if lifted else 0)  # the 0.4 m row


def reference_split(x, y, h, coarse_ground, kind0, threshold, raise_m, max_range_m):
    """Step 5 by brute force over the points (each point's kind and height above its
    ground, NaN for a non-obstacle): a point with coarse height d in
    [threshold, threshold + Δ) takes max(lowest, g) as its ground, lowest the
    minimum height of the returns near the coarse ground (d below Δ) in the 3 × 3 block of
    LOCAL_CELL_M cells around its own (cells aligned on ±max_range_m around the sensor);
    with no such return there it keeps its coarse split."""
    ix = np.floor((x + max_range_m) / LOCAL_CELL_M).astype(int)
    iy = np.floor((y + max_range_m) / LOCAL_CELL_M).astype(int)
    d0 = h - coarse_ground
    low = d0 < raise_m
    kind = kind0.copy()
    height = np.where(kind0 == OBSTACLE, d0, np.nan).astype(np.float32)
    for i in np.flatnonzero((d0 >= threshold) & (d0 < threshold + raise_m) & (kind0 == OBSTACLE)):
        block = (low & (np.abs(ix - ix[i]) <= LOCAL_CELLS) & (np.abs(iy - iy[i]) <= LOCAL_CELLS))
        if not block.any():
            continue
        lowest = h[block].min()
        g = max(lowest, coarse_ground[i])
        height[i] = h[i] - g
        if h[i] - g < threshold:
            kind[i] = GROUND
            height[i] = np.nan
    return kind, height


def test_the_compiled_step_equals_a_brute_force_reference():
    """Random rough terrain (a sum of bumps and a slope, 3000 points up to 30 m): the
    compiled split with Δ = 0.25 against the reference above, given the coarse split
    (Δ = 0) and its heights above the estimate."""
    rng = np.random.default_rng(5)
    n, max_range = 3000, 30.0
    r = np.sqrt(rng.uniform(1.0, max_range**2 * 0.99, n))
    a = rng.uniform(-math.pi, math.pi, n)
    x, y = (r * np.cos(a)).astype(np.float32), (r * np.sin(a)).astype(np.float32)
    h = (0.04 * x + 0.3 * np.sin(x / 1.7) * np.cos(y / 2.3)
         + rng.exponential(0.15, n) * (rng.random(n) < 0.3)).astype(np.float32)
    z = (h - np.float32(H)).astype(np.float32)
    n_az = 720
    az_bin = ((a + math.pi) / (2 * math.pi) * n_az).astype(np.int32) % n_az
    range_m = np.hypot(x, y).astype(np.float32)
    hist = np.empty(math.prod(histogram_shape(max_range)), np.int32)
    args = (z, range_m, az_bin, n_az, max_range, False, np.float32(H), np.float32(0.3),
            np.float32(2.5), hist)
    kind0 = np.empty(n, np.uint8)
    d0 = np.empty(n, np.float32)
    classify_points(*args, kind0, True, d0)
    # the coarse estimate under each point: from an obstacle's d, or from a second split
    # with a threshold that makes every point an obstacle
    everything = np.empty(n, np.uint8)
    d_all = np.empty(n, np.float32)
    classify_points(z, range_m, az_bin, n_az, max_range, False, np.float32(H),
                    np.float32(-10.0), np.float32(100.0), hist, everything, True, d_all)
    assert (everything == OBSTACLE).all()
    coarse_ground = h - d_all
    raise_m = np.float32(0.25)
    kind = np.empty(n, np.uint8)
    height = np.empty(n, np.float32)
    local_min = np.empty(local_grid_side(max_range) ** 2, np.float32)
    classify_points(*args, kind, True, height, raise_m, x, y, local_min)
    want, want_height = reference_split(x, y, h, coarse_ground, kind0, 0.3, raise_m, max_range)
    assert (kind0 == OBSTACLE).sum() > 300 and (want != kind0).sum() > 20
    np.testing.assert_array_equal(kind, want)
    # float32 sums in a different order: 1e-5 m is far below any height that matters
    np.testing.assert_allclose(height, want_height, atol=1e-5)
