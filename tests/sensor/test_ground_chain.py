"""The ground estimate's chain along a sector (``sensor.ground_chain``, docs/method.md §3).

A 16-layer scanner 1.8 m up (VLP-16-like: −15°…+15° every 2°) meets flat ground on rings,
the last one at 34.3 m (−3°); the next layer (−1°) would meet it at 103 m. Between them no
ground return falls, so a 2 m band out there holds only what stands in it. The scenes are
built by casting each beam analytically (the nearest of ground and a fence wins), so the
truth of every return — ground, or the fence at a known height — is known without evperc.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from evperc.geo.window import Window
from evperc.sensor import sensor_grid
from evperc.sensor.ground import GROUND, OBSTACLE
from tests.sensor.reference import assert_matches_reference
from tests.sensor.scenes import pose

MOUNT = 1.8
LAYERS_DEG = np.arange(-15.0, 16.0, 2.0)
FENCE_X, FENCE_HALF, FENCE_TOP = 38.2, 5.0, 1.2   # a fence ahead (x off the range-bin edges)
SENSOR = (0.25, 0.25)


def sparse_scan(slope: float = 0.0, fence: bool = True, fence_x: float = FENCE_X,
                kerb_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Level offsets of every return and whether it is on the fence (at ``x = fence_x``).
    The ground rises by ``slope`` per metre towards +x (z = slope·max(x, 0)); with
    ``kerb_m``, the returns at y > 4 m stand that much higher (a pavement behind a kerb;
    their ranges are not recomputed); azimuths every 0.2°."""
    az = np.radians(np.arange(-180.0, 180.0, 0.2))
    pts, on_fence = [], []
    for e in np.radians(LAYERS_DEG):
        if e >= 0:   # never meets the ground; may meet the fence only above its top
            continue
        c, s = np.cos(az), np.sin(az)
        # ground: MOUNT + t·tan e = slope·max(t·c, 0) along the horizontal distance t
        rise = slope * np.maximum(c, 0.0)
        t_ground = MOUNT / (np.tan(-e) + rise)
        t = t_ground.copy()
        hit_fence = np.zeros(az.size, bool)
        if fence:
            with np.errstate(divide="ignore"):
                t_fence = np.where(c > 0, fence_x / c, np.inf)
            y_fence = t_fence * s
            z_fence = MOUNT + t_fence * np.tan(e)
            hit_fence = (np.abs(y_fence) <= FENCE_HALF) & (z_fence >= 0) & (
                z_fence <= FENCE_TOP) & (t_fence < t_ground)
            t = np.where(hit_fence, t_fence, t_ground)
        keep = t < 79.0
        z = MOUNT + t * np.tan(e) + kerb_m * (t * s > 4.0) * ~hit_fence
        pts.append(np.stack([t * c, t * s, z - MOUNT], 1)[keep])
        on_fence.append(hit_fence[keep])
    return np.vstack(pts), np.concatenate(on_fence)


def kinds_of(level: np.ndarray, params, chain: bool, gap: float = 0.0,
             road_only: bool = False, context: np.ndarray | None = None) -> np.ndarray:
    t = pose(*SENSOR, MOUNT)
    kinds = np.empty(len(level), np.uint8)
    sensor_grid((level @ t[:3, :3]).astype(np.float32), False, t, WINDOW,
                replace(params, sensor_height_m=MOUNT, ground_chain=chain,
                        ground_chain_gap_m=gap, ground_chain_gap_road_only=road_only),
                kinds_out=kinds, context=context)
    return kinds


WINDOW = Window.centred_on(*SENSOR, 160.0, 0.5)


def road_where(inside) -> np.ndarray:
    """A map context layer of :data:`WINDOW`: road (1) in the cells whose centre ``(x, y)``
    satisfies ``inside(x, y)``, other (0) elsewhere."""
    x, y = WINDOW.cell_centres()
    return np.broadcast_to(np.where(inside(x[None, :], y[:, None]), 1, 0),
                           WINDOW.shape).astype(np.uint8)


def test_the_scene_is_what_the_docstring_says() -> None:
    level, on_fence = sparse_scan()
    ground = level[~on_fence]
    r = np.hypot(ground[:, 0], ground[:, 1])
    assert r.max() < 34.5 and np.abs(ground[:, 2] + MOUNT).max() < 1e-9
    top = level[on_fence][:, 2] + MOUNT   # the −1° layer meets the fence 1.14 m up
    assert on_fence.sum() > 50 and np.allclose(top, MOUNT - FENCE_X * math.tan(
        math.radians(1.0)), atol=0.01)


def test_a_band_without_ground_takes_the_nearer_ground_with_the_chain(params) -> None:
    """Without the chain, the fence's band has only fence returns; their low percentile
    (1.14 m) lies within the prior's bound at 40 m (0.5 + 0.1·40 m), so the fence becomes the
    band's ground and every return on it is ground. With the chain the band must also lie
    within 0.5 + 0.1·(40 − 36) m of the band of the last ring (ground 0): it is rejected, the
    band keeps the ring's ground and the fence is an obstacle."""
    level, on_fence = sparse_scan()
    assert_fence_turns_obstacle(kinds_of(level, params, chain=False),
                                kinds_of(level, params, chain=True), on_fence)


def assert_fence_turns_obstacle(before: np.ndarray, after: np.ndarray, on_fence: np.ndarray
                                ) -> None:
    """Every fence return ground before and an obstacle after; every ground return ground in
    both."""
    assert (before[on_fence] == GROUND).all()
    assert (after[on_fence] == OBSTACLE).all()
    np.testing.assert_array_equal(after[~on_fence], GROUND)
    np.testing.assert_array_equal(before[~on_fence], GROUND)


@pytest.mark.parametrize("slope", [0.05, 0.09])
def test_the_chain_keeps_rising_ground_ground(params, slope: float) -> None:
    """Ground rising within the slope bound (10 %) ahead stays ground along the sector: the
    chain changes no return's kind. (Without it too, a few returns are obstacles: where a
    ring crosses a band's edge near a sector's edge, the band holds fewer than 5 returns and
    takes a nearer band's ground, lower on this slope; and at the sides, ±70–85°, where this
    scene's ground folds at x = 0 within a sector.)"""
    level, _ = sparse_scan(slope=slope, fence=False)
    ahead = np.abs(np.degrees(np.arctan2(level[:, 1], level[:, 0]))) < 60.0
    assert level[ahead, 2].max() + MOUNT > 1.0   # the far rings stand more than a metre higher
    kinds = kinds_of(level, params, chain=True)
    np.testing.assert_array_equal(kinds, kinds_of(level, params, chain=False))
    assert (kinds[ahead] == GROUND).mean() > 0.995


def test_fence_cells_are_occupied_not_free(params) -> None:
    """What the split changes in the grid: the fence's cells are occupied with the chain and
    free without it (a ground return is free space)."""
    level, on_fence = sparse_scan()
    t = pose(*SENSOR, MOUNT)
    window = Window.centred_on(*SENSOR, 160.0, 0.5)
    sensor = (level @ t[:3, :3]).astype(np.float32)
    cells = {window.index_of(np.array(SENSOR[0] + x), np.array(SENSOR[1] + y))
             for x, y in level[on_fence][:, :2]}
    cells = tuple(np.array(v) for v in zip(*((int(r), int(c)) for r, c in cells), strict=True))
    for chain, want in ((False, "free"), (True, "occupied")):
        free, occ = sensor_grid(sensor, False, t, window,
                                replace(params, sensor_height_m=MOUNT, ground_chain=chain))
        grid = free if want == "free" else occ
        assert (grid[cells] > 0).all(), chain


FAR_FENCE_X = 44.2   # the −1° layer meets it 1.03 m up, 10 m past the band of the last ring


@pytest.mark.parametrize(("chain", "gap", "fence_x"), [(False, 0.0, FENCE_X),
                                                       (True, 0.0, FENCE_X),
                                                       (True, 2.0, FAR_FENCE_X),
                                                       (True, 4.0, FAR_FENCE_X)])
def test_matches_oracle_on_the_sparse_scan(params, chain: bool, gap: float,
                                           fence_x: float) -> None:
    """The fence is occupied (more than 20 cells) with the chain — at 44.2 m only with the
    gap capped —, nowhere without it; evperc equal to the oracle either way."""
    level, _ = sparse_scan(fence_x=fence_x)
    t = pose(3.0, -7.0, MOUNT, yaw_deg=20.0)
    p = replace(params, sensor_height_m=MOUNT, ground_chain=chain, ground_chain_gap_m=gap,
                max_range_m=60.0)
    window = Window.centred_on(3.0, -7.0, 130.0, 0.5)
    _, want_occ = assert_matches_reference((level @ t[:3, :3]).astype(np.float32), False, t,
                                           window, p)
    assert (want_occ > 0).sum() > 20 if chain else not want_occ.any()



def test_a_far_band_without_ground_needs_the_gap_cap(params) -> None:
    """Past the last ring the chain's bound grows with the gap, 0.5 + 0.1·(46 − 36) m = 1.5 m
    at a fence 44.2 m out: its returns, 1.03 m up (a car's side there looks the same), pass
    for the band's ground and are ground. With ``ground_chain_gap_m`` = 2 the bound is
    0.5 + 0.1·2 = 0.7 m: the band is rejected, keeps the ring's ground (0), and the fence is
    an obstacle; the ground returns stay ground either way."""
    level, on_fence = sparse_scan(fence_x=FAR_FENCE_X)
    top = level[on_fence][:, 2] + MOUNT
    assert on_fence.sum() > 50 and np.allclose(top, 1.03, atol=0.01)
    assert_fence_turns_obstacle(kinds_of(level, params, True, 0.0),
                                kinds_of(level, params, True, 2.0), on_fence)


@pytest.mark.parametrize("slope", [0.05, 0.09])
def test_the_gap_cap_keeps_rising_ground_ground(params, slope: float) -> None:
    """On ground rising towards +x every layer meets the road nearer (the −1° layer at
    1.8 / (0.0175 + slope) m), so no band ahead lies far past a ring: the cap changes no
    return's kind there."""
    level, _ = sparse_scan(slope=slope, fence=False)
    out = {gap: kinds_of(level, params, True, gap) for gap in (0.0, 2.0)}
    ahead = np.abs(np.degrees(np.arctan2(level[:, 1], level[:, 0]))) < 60.0
    np.testing.assert_array_equal(out[2.0][ahead], out[0.0][ahead])
    assert (out[2.0][ahead] == GROUND).mean() > 0.995


def _histogram(bands: dict[int, float], n_band: int = 10, n_z: int = 120) -> np.ndarray:
    """One sector's ground histogram (``_accepted``'s layout): 20 returns at each band's
    height (m above the prior plane)."""
    hist = np.zeros(n_band * n_z, np.int32)
    for band, height in bands.items():
        hist[band * n_z + int((height + 3.0) / 0.05)] = 20
    return hist


def fill_ground(hist: np.ndarray, gap: float) -> tuple[np.ndarray, np.ndarray]:
    """The chained ground of :func:`_histogram`'s one sector (10 bands), chain on."""
    from evperc.sensor.ground import _accepted, _chained
    return _chained(*_accepted(hist, 1, 10, 120), 1, 10, False, True, gap)


@pytest.mark.parametrize("gap", [0.0, 2.0])
def test_a_sectors_first_kept_band_keeps_the_priors_bound(gap: float) -> None:
    """A band 10–12 m out with nothing nearer kept (a parked car's side beside the sensor, no
    ring before it) is bounded by the prior only, 0.5 + 0.1·12 m, with the cap or without."""
    ground, _ = fill_ground(_histogram({5: 1.0}), gap)
    assert ground[5] == pytest.approx(1.025)   # the band's own estimate (bin centre)


def test_the_cap_bounds_a_band_past_a_kept_one() -> None:
    """A ring kept at 2–4 m (ground 0), then a band at 10–12 m 1.0 m up: without the cap the
    bound is 0.5 + 0.1·(12 − 4) = 1.3 m (kept), with G = 2 m it is 0.7 m (rejected: the band
    takes the ring's ground)."""
    hist = _histogram({1: 0.0, 5: 1.0})
    uncapped, _ = fill_ground(hist, 0.0)
    capped, _ = fill_ground(hist, 2.0)
    assert uncapped[5] == pytest.approx(1.025)
    assert capped[5] == pytest.approx(0.025) and capped[1] == pytest.approx(0.025)


def test_the_road_only_cap_holds_on_the_road_alone(params) -> None:
    """``ground_chain_gap_road_only``: the far fence (1.03 m up, 44.2 m out: a car's side or
    rising terrain, the ground split cannot tell) is an obstacle where its returns lie in
    road cells of the map and ground elsewhere — point by point, a road under half of it
    splits it —; without a map no return is capped. The ground returns stay ground."""
    level, on_fence = sparse_scan(fence_x=FAR_FENCE_X)
    uncapped = kinds_of(level, params, True, 0.0)
    capped = kinds_of(level, params, True, 2.0)
    assert_fence_turns_obstacle(uncapped, capped, on_fence)
    world_y = level[:, 1] + SENSOR[1]
    for inside, want_capped in [
            (lambda x, y: (x > 40.0) & (x < 48.0) & (np.abs(y) < 6.0), on_fence),   # on it
            (lambda x, y: np.abs(y) > 20.0, np.zeros_like(on_fence)),          # elsewhere
            (lambda x, y: (x > 40.0) & (y < 0.0), on_fence & (world_y < 0.0))]:  # half
        got = kinds_of(level, params, True, 2.0, True, road_where(inside))
        np.testing.assert_array_equal(got, np.where(want_capped, capped, uncapped))
    assert 0 < (on_fence & (world_y < 0.0)).sum() < on_fence.sum()   # the half: a split
    np.testing.assert_array_equal(kinds_of(level, params, True, 2.0, True, None), uncapped)


@pytest.mark.parametrize("half", ["south", "north"])
def test_matches_oracle_with_the_road_only_cap(params, half: str) -> None:
    """evperc against the oracle with the cap on the road alone, the road under one half of
    the window (the fence's returns on both sides of its edge)."""
    level, _ = sparse_scan(fence_x=FAR_FENCE_X)
    t = pose(3.0, -7.0, MOUNT, yaw_deg=20.0)
    p = replace(params, sensor_height_m=MOUNT, ground_chain=True, ground_chain_gap_m=2.0,
                ground_chain_gap_road_only=True, max_range_m=60.0)
    window = Window.centred_on(3.0, -7.0, 130.0, 0.5)
    _, y = window.cell_centres()
    south = np.broadcast_to((y < -7.0)[:, None], window.shape)   # the fence: y -12 to -2 m
    context = np.where(south if half == "south" else ~south, 1, 0).astype(np.uint8)
    _, want_occ = assert_matches_reference((level @ t[:3, :3]).astype(np.float32), False, t,
                                           window, p, context)
    capped = replace(p, ground_chain_gap_road_only=False)
    uncapped = replace(p, ground_chain_gap_m=0.0, ground_chain_gap_road_only=False)
    from tests.sensor.reference import reference_grid
    _, all_occ = reference_grid((level @ t[:3, :3]).astype(np.float32), False, t, window, capped)
    _, none_occ = reference_grid((level @ t[:3, :3]).astype(np.float32), False, t, window,
                                 uncapped)
    # between the two: some of the fence's cells occupied, fewer than with the cap everywhere
    assert (none_occ > 0).sum() < (want_occ > 0).sum() < (all_occ > 0).sum()
