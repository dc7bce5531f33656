"""The compiled struct-of-arrays tracker (evperc.objects.tracking) against the per-track
Python tracker it replaced (tests/objects/reference_tracking.py), on randomised multi-frame
drives: the object records, their cells, the next frame's footprint seeds and the
checkpoint arrays must be equal to the bit, frame by frame (no tolerance: the kernel sums
in numpy's order, so nothing is left to round-off)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from evperc.fusion.twin import DECISION_CODES as D
from evperc.geo.window import Window
from evperc.objects import tracking
from evperc.objects.clusters import Clusterer, ClusterParams
from evperc.objects.tracking import TrackerState, TrackingParams
from tests.objects import reference_tracking as ref

SHAPE = (48, 64)
RES = 0.5
T0 = 1_700_000_000_000_000_000
OCCUPIED = np.array([D["moving"], D["static"], D["stopped"], D["unmapped"]], np.uint8)


def _drive(rng: np.random.Generator, frames: int):
    """Random frames: blocks driving about at random speeds (some stop, some vanish and
    come back), their front cells sometimes decided moving, static clutter, a window that
    drifts (footprints leave it), stamps at 10 Hz with jitter, some repeated stamps."""
    n_obj = int(rng.integers(3, 12))
    pos = rng.uniform([4, 4], [SHAPE[0] - 6, SHAPE[1] - 6], (n_obj, 2))
    vel = rng.normal(0.0, 0.8, (n_obj, 2)) * (rng.random((n_obj, 1)) < 0.7)
    size = rng.integers(1, 5, (n_obj, 2))
    origin = np.array([int(rng.integers(-5, 5)), int(rng.integers(-5, 5))])
    stamp = T0
    for _ in range(frames):
        dec = np.full(SHAPE, D["free"], np.uint8)
        dec[rng.random(SHAPE) < 0.05] = D["unknown"]
        clutter = rng.random(SHAPE) < 0.02
        dec[clutter] = rng.choice(OCCUPIED, int(clutter.sum()))
        for i in range(n_obj):
            if rng.random() < 0.1:  # a frame without it
                continue
            r, c = np.round(pos[i]).astype(int)
            r0, c0 = max(r, 0), max(c, 0)
            r1, c1 = min(r + size[i, 0], SHAPE[0]), min(c + size[i, 1], SHAPE[1])
            if r0 >= r1 or c0 >= c1:
                continue
            dec[r0:r1, c0:c1] = D["static"] if rng.random() < 0.5 else D["stopped"]
            if rng.random() < 0.6:
                dec[r0:r1, c1 - 1] = D["moving"]
        pos += vel + rng.normal(0.0, 0.2, pos.shape)
        pos = np.clip(pos, -2, np.array(SHAPE) + 2)
        vel[rng.random(n_obj) < 0.05] = 0.0  # some stop
        if rng.random() < 0.3:
            origin += rng.integers(-2, 3, 2)
        now = rng.random(SHAPE) < 0.9
        betp = rng.integers(0, 256, SHAPE).astype(np.uint8)
        fo = rng.integers(0, 256, SHAPE).astype(np.uint8)
        window = Window(RES, *SHAPE, int(origin[0]), int(origin[1]))
        yield dec, betp, fo, now, window, stamp
        if rng.random() > 0.03:  # now and then the same stamp again (dt = 0)
            stamp += 100_000_000 + int(rng.integers(-3_000_000, 3_000_000))


def _params(rng: np.random.Generator) -> TrackingParams:
    return TrackingParams(
        gate_m=float(rng.choice([0.5, 1.0, 2.0, 3.0])),
        confirm_frames=int(rng.integers(1, 5)),
        max_missed_frames=int(rng.integers(0, 4)),
        history_frames=int(rng.choice([2, 3, 5, 10, 12])),
        moving_speed_m_per_s=float(rng.choice([0.0, 0.5, 1.0, 2.0])),
        motion_test=float(rng.choice([0.0, 1.0, 4.0])),
        centroid_sigma_m=float(rng.choice([0.0, 0.05, 0.25])),
        motion_evidence_frames=int(rng.integers(0, 4)),
        conflict_cells=int(rng.integers(1, 4)),
        single_conflict_max_cells=int(rng.choice([0, 0, 2, 3, 8])),
        vacated_frames=int(rng.integers(1, 5)),
        vacated_share=float(rng.choice([0.1, 0.3, 0.6])),
        evidence_every_frame=bool(rng.random() < 0.5),
        arrival_share=float(rng.choice([0.0, 0.0, 0.3, 0.5, 1.0])),
        arrival_min_cells=int(rng.choice([0, 0, 3, 5])),
        ego_clearance_m=float(rng.choice([0.0, 0.0, 3.0, 8.0])),
        centroid_sigma_per_m=float(rng.choice([0.0, 0.0, 0.01, 0.05])),
        evidence_expires=bool(rng.random() < 0.5),
        facade_max_speed_m_per_s=float(rng.choice([0.0, 0.0, 0.5, 2.0])),
        growth_kept_share=float(rng.choice([0.0, 0.0, 0.5, 0.9, 1.0])),
        growth_more_cells=int(rng.choice([0, 1, 2, 5])),
        growth_min_cells=int(rng.choice([0, 0, 4, 8])),
        growth_reach_cells=int(rng.choice([0, 0, 1, 2])),
        growth_early=bool(rng.random() < 0.5))


def _assert_same_state(new: TrackerState, old: ref.TrackerState) -> None:
    a, b = new.to_arrays(), old.to_arrays()
    assert list(a) == list(b)
    for key in a:
        x, y = np.asarray(a[key]), np.asarray(b[key])
        assert x.dtype == y.dtype and x.shape == y.shape, key
        assert x.tobytes() == y.tobytes(), key


# 24 drives: the growth rule changes the evidence in 11 of them, with every reach and with
# growth_early (seed 20: reach 1 and early together)
@pytest.mark.parametrize("seed", range(24))
def test_compiled_tracker_equals_the_per_track_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    params = _params(rng)
    # the returns' centroids' own noise floor (objects.centroid_returns_sigma_m), from a
    # generator of its own so that the drives above are those of the seeds before the key
    returns_rng = np.random.default_rng(1000 + seed)
    params = replace(params, centroid_returns_sigma_m=float(
        returns_rng.choice([0.0, 0.05, 0.1, 0.4])))
    flag_share = float(returns_rng.choice([0.0, 0.5, 1.0]))
    cparams = ClusterParams(min_cells=int(rng.integers(1, 4)), seeds="occupied",
                            keep_tracked_small=bool(rng.random() < 0.5))
    clusterer = Clusterer(cparams, SHAPE)
    new, old = TrackerState(), ref.TrackerState()
    with_decision = rng.random() < 0.8
    # the widened buildings: a random band of rows (or none), for facade_max_speed_m_per_s
    near = None
    if rng.random() < 0.7:
        near = np.zeros(SHAPE, np.bool_)
        near[int(rng.integers(0, SHAPE[0])):][:int(rng.integers(2, SHAPE[0]))] = True
    for k, (dec, betp, fo, now, window, stamp) in enumerate(_drive(rng, 60)):
        seeds_new = tracking.footprint_seeds(new, window)
        seeds_old = ref.footprint_seeds(old, window)
        assert seeds_new.tobytes() == seeds_old.tobytes()
        clusters = clusterer.clusters(dec, betp, fo, window, seeds_new, now)
        if flag_share > 0:  # some centroids are their returns' means
            clusters = replace(
                clusters, from_returns=returns_rng.random(len(clusters)) < flag_share)
        decision = dec if with_decision else None
        rn, cn = tracking.track_step(new, clusters, window, stamp, params, decision, near)
        ro, co = ref.track_step(old, clusters, window, stamp, params, decision, near)
        assert rn.dtype == ro.dtype and rn.tobytes() == ro.tobytes(), k
        assert cn.dtype == co.dtype and cn.tobytes() == co.tobytes(), k
        _assert_same_state(new, old)
        if k == 30:  # a checkpoint round trip in the middle of the drive
            new = TrackerState.from_arrays(new.to_arrays())
            old = ref.TrackerState.from_arrays(old.to_arrays())
    assert new.next_id > 5  # the drive made tracks to compare


def test_the_drives_exercise_reports_moving_and_evidence() -> None:
    """The comparison above is not vacuous: over the seeds, objects are reported (moving
    and stopped), tracks are dropped and evidence is counted."""
    states, ever, evidence = set(), 0, 0
    for seed in range(12):
        rng = np.random.default_rng(seed)
        params = _params(rng)
        clusterer = Clusterer(ClusterParams(min_cells=int(rng.integers(1, 4)),
                                            seeds="occupied"), SHAPE)
        state = TrackerState()
        for dec, betp, fo, now, window, stamp in _drive(rng, 60):
            clusters = clusterer.clusters(dec, betp, fo, window,
                                          tracking.footprint_seeds(state, window), now)
            recs, _ = tracking.track_step(state, clusters, window, stamp, params, dec)
            states |= set(int(s) for s in recs["state"])
            ever += int(state.flags[:, 0].sum())
            evidence += int(state.evidence.sum())
    assert states == {1, 2} and ever > 0 and evidence > 0


def test_compiled_fit_equals_numpy_fits_to_the_bit() -> None:
    """The kernel's fit (``_fits``, numpy's pairwise summation order) against
    :func:`velocity_fits` on random histories, widths 2-200 (above 128 numpy halves the
    sum), with exact zeros, negative zeros and equal stamps."""
    rng = np.random.default_rng(5)
    for h in (2, 3, 7, 8, 9, 10, 16, 17, 40, 129, 200):
        n = 300
        count = rng.integers(0, h + 1, n)
        count[:4] = [0, 1, 2, h]
        t = np.sort(rng.uniform(-2.0, 0.0, (n, h)), axis=1)
        t[5, :] = -0.3
        count[5] = h
        xy = rng.normal(0.0, 50.0, (n, h, 2)) * 10.0 ** rng.integers(-3, 4, (n, 1, 1))
        xy[6] = 0.0
        xy[7] = -0.0
        xy[8, :, 0] = 1.25  # constant x: exact zero deviations
        v, sigma = tracking.velocity_fits(t, xy, count, 0.25)
        cv, csigma = tracking._fits(t, xy, count, 0.25)
        assert v.tobytes() == cv.tobytes(), h
        assert sigma.tobytes() == csigma.tobytes(), h


def test_compiled_distances_equal_numpy_within_the_gate() -> None:
    """``_distances`` (predicted centroid to cluster centroid, in the kernel) against the
    numpy formulas the tracker used (``np.hypot`` of the broadcast differences): the same
    bits wherever numpy's distance is within the gate, and beyond it wherever numpy's is
    (the kernel skips the hypot there: +inf); working-CRS-sized coordinates, clusters placed
    around the gate's edge, a history index of 0 (numpy's wrap of −1)."""
    rng = np.random.default_rng(8)
    gate = 2.0
    for n, m, width in ((1, 1, 1), (7, 300, 10), (80, 120, 3), (40, 5, 1)):
        hist_xy = 3.8e5 + rng.normal(0.0, 30.0, (n, width, 2))
        hist_n = rng.integers(0, width + 1, n)
        velocity = rng.normal(0.0, 3.0, (n, 2)) * (rng.random((n, 1)) < 0.8)
        dt = float(rng.choice([0.0, 0.1, 0.0999]))
        last = hist_xy[np.arange(n), hist_n - 1]
        px = last[:, 0] + velocity[:, 0] * dt
        py = last[:, 1] + velocity[:, 1] * dt
        angle = rng.uniform(0.0, 2 * np.pi, m)
        near = rng.integers(0, n, m)
        radius = gate + rng.normal(0.0, 0.3, m) * (rng.random(m) < 0.7) * 10.0 ** rng.integers(
            -12, 1, m)
        centroid = np.stack([px[near] + radius * np.cos(angle),
                             py[near] + radius * np.sin(angle)], axis=1)
        want = np.hypot(px[:, None] - centroid[None, :, 0], py[:, None] - centroid[None, :, 1])
        got = tracking._distances(hist_xy, hist_n, velocity, dt, centroid, gate)
        inside = want <= gate
        assert np.array_equal(got <= gate, inside)
        assert got[inside].tobytes() == want[inside].tobytes()
        assert inside.any() and (~inside).any() or n * m == 1


def test_the_facade_rule_is_exercised_by_the_drives() -> None:
    """The comparison's façade branch is not vacuous: on the same drives, the cells all in
    the widened buildings and the rule on (2 m/s) report fewer moving objects than the
    rule off, and some still (the slow ones)."""
    fewer = still = 0
    for seed in range(12):
        counts = []
        for speed in (0.0, 2.0):
            rng = np.random.default_rng(seed)
            params = replace(_params(rng), facade_max_speed_m_per_s=speed)
            clusterer = Clusterer(ClusterParams(min_cells=1, seeds="occupied"), SHAPE)
            state, moving = TrackerState(), 0
            for dec, betp, fo, now, window, stamp in _drive(rng, 60):
                clusters = clusterer.clusters(dec, betp, fo, window,
                                              tracking.footprint_seeds(state, window), now)
                recs, _ = tracking.track_step(state, clusters, window, stamp, params, dec,
                                              np.ones(SHAPE, np.bool_))
                moving += int((recs["state"] == 1).sum())
            counts.append(moving)
        fewer += counts[1] < counts[0]
        still += counts[1] > 0
    assert fewer > 0 and still > 0
