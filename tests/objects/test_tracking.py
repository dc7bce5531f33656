"""The tracker on hand-made frames (evperc.objects.tracking); expected velocities and
uncertainties worked out by hand in the comments."""

from __future__ import annotations

import math

import numpy as np
import pytest

from evperc.fusion.twin import DECISION_CODES as D
from evperc.geo.window import Window
from evperc.objects.clusters import Clusterer, ClusterParams
from evperc.objects.tracking import (
    TrackerState,
    TrackingParams,
    footprint_seeds,
    is_moving,
    track_step,
    velocity_fit,
    velocity_fits,
)
from evperc.output.objects import OBJECT_STATES, object_labels

RES = 0.5
T0 = 1_700_000_000_000_000_000
DT = 100_000_000  # 10 Hz
SHAPE = (20, 60)
WIN = Window(RES, *SHAPE, 0, 0)


def _frame(blocks, moving=True):
    """Decision layer with 3x2 blocks (3 cols, 2 rows) at (row, col) of their SW cell; the
    front column (east) decided moving if ``moving``, the rest static."""
    dec = np.full(SHAPE, D["free"], np.uint8)
    for r, c in blocks:
        dec[r:r + 2, c:c + 3] = D["stopped"] if not moving else D["static"]
        if moving:
            dec[r:r + 2, c + 2] = D["moving"]
    return dec


class Run:
    def __init__(self, params=None):
        self.state = TrackerState()
        self.clusterer = Clusterer(ClusterParams(), SHAPE)
        self.params = params or TrackingParams()
        self.k = 0

    def step(self, dec):
        z = np.zeros(SHAPE, np.uint8)
        seeds = footprint_seeds(self.state, WIN)
        clusters = self.clusterer.clusters(dec, z, z, WIN, seeds)
        out = track_step(self.state, clusters, WIN, T0 + self.k * DT, self.params)
        self.k += 1
        return out


def test_block_one_cell_per_frame_is_5_m_per_s_with_hand_computed_sigma():
    run = Run()
    reported = []
    for k in range(10):
        recs, cells = run.step(_frame([(5, 10 + k)]))
        reported.append(recs)
    # frames 0, 1: fewer than confirm_frames = 3 associations
    assert len(reported[0]) == len(reported[1]) == 0
    # frame 2: n = 3 centroids 0.5 m apart at 0.1 s: v = 5 m/s exactly;
    # S = 0.1² · (1 + 0 + 1) = 0.02, s = 0.25 / sqrt(0.02) = 1.7678 m/s;
    # |v|² / s² = 25 / 3.125 = 8 >= 4: moving
    r2 = reported[2]
    assert len(r2) == 1 and r2["state"][0] == OBJECT_STATES["moving"]
    np.testing.assert_allclose(r2["velocity_m_per_s"][0], [5.0, 0.0], atol=1e-5)
    assert r2["speed_sigma_m_per_s"][0] == pytest.approx(0.25 / math.sqrt(0.02), rel=1e-6)
    # frame 9: n = 10, S = 0.01 · Σ (k − 4.5)² = 0.01 · 82.5 = 0.825
    r9 = reported[9]
    np.testing.assert_allclose(r9["velocity_m_per_s"][0], [5.0, 0.0], atol=1e-5)
    assert r9["speed_sigma_m_per_s"][0] == pytest.approx(0.25 / math.sqrt(0.825), rel=1e-6)
    assert {int(r["track_id"][0]) for r in reported[2:]} == {1}
    # block at cols 19..21, rows 5..6: centroid x = (20 + 0.5) · 0.5, y = (5.5 + 0.5) · 0.5
    np.testing.assert_allclose(r9["centroid_m"][0], [10.25, 3.0])
    np.testing.assert_allclose(r9["extent_m"][0], [1.5, 1.0])
    assert r9["cell_count"][0] == 6 and r9["age_frames"][0] == 10
    labels = object_labels(r9, cells, SHAPE)
    assert (labels == 1).sum() == 6 and labels[5, 19] == labels[6, 21] == 1


def test_stopped_object_is_kept_by_its_footprint_and_reported_stopped():
    run = Run()
    for k in range(10):
        run.step(_frame([(5, 10 + k)]))
    # it stops at cols 19..21; its cells are now decided stopped: no moving seed at all
    for _ in range(12):
        recs, _ = run.step(_frame([(5, 19)], moving=False))
    # after 10 stationary frames the fit over the last 10 centroids is v = 0
    assert len(recs) == 1 and recs["track_id"][0] == 1
    assert recs["state"][0] == OBJECT_STATES["stopped"]
    np.testing.assert_allclose(recs["velocity_m_per_s"][0], [0.0, 0.0], atol=1e-9)
    # it drives off again: still track 1, moving again once the fit sees it
    for k in range(6):
        recs, _ = run.step(_frame([(5, 20 + k)]))
    assert recs["track_id"][0] == 1 and recs["state"][0] == OBJECT_STATES["moving"]


def test_a_cluster_that_stays_put_is_never_reported():
    """A false seed on a static structure: the cluster is tracked but never moves."""
    run = Run()
    for _ in range(15):
        recs, _ = run.step(_frame([(5, 10)]))
        assert len(recs) == 0
    assert len(run.state.tracks) == 1 and not run.state.tracks[0].ever_moving


def test_two_objects_opposite_directions_keep_their_ids():
    run = Run()
    for k in range(8):
        recs, _ = run.step(_frame([(2, 5 + k), (14, 50 - k)]))
    assert list(recs["track_id"]) == [1, 2]
    np.testing.assert_allclose(recs["velocity_m_per_s"], [[5.0, 0.0], [-5.0, 0.0]], atol=1e-5)


def test_gap_within_max_missed_keeps_the_id_a_longer_one_does_not():
    run = Run()
    for k in range(5):
        run.step(_frame([(5, 10 + k)]))
    for _ in range(2):  # 2 frames without it (max_missed_frames = 3)
        run.step(_frame([]))
    # reappears where constant velocity (5 m/s, 1 cell a frame) predicts it: col 14 + 3
    recs, _ = run.step(_frame([(5, 17)]))
    assert list(recs["track_id"]) == [1]
    for _ in range(4):
        run.step(_frame([]))
    run.step(_frame([(5, 22)]))
    assert [t.track_id for t in run.state.tracks] == [2]


def test_jump_beyond_gate_is_a_new_track():
    run = Run(TrackingParams(gate_m=1.0))
    for k in range(4):
        run.step(_frame([(5, 10 + k)]))
    run.step(_frame([(5, 20)]))  # 3.5 m beyond the prediction
    assert sorted(t.track_id for t in run.state.tracks) == [1, 2]


def test_checkpoint_round_trip_continues_identically():
    a, b = Run(), Run()
    frames = [_frame([(5, 10 + k), (12, 40 - (k // 2))]) for k in range(14)]
    for k in range(7):
        a.step(frames[k])
        b.step(frames[k])
    b.state = TrackerState.from_arrays(b.state.to_arrays())
    for k in range(7, 14):
        ra, ca = a.step(frames[k])
        rb, cb = b.step(frames[k])
        assert ra.tobytes() == rb.tobytes() and ca.tobytes() == cb.tobytes()
    assert TrackerState.from_arrays({}) is None


def test_a_checkpoint_without_the_ever_far_flag_reads_its_tracks_as_far():
    # checkpoints written before objects.ego_clearance_m hold two flag columns: their
    # tracks keep being judged as before (ever far), the other columns unchanged
    run = Run()
    for k in range(5):
        run.step(_frame([(5, 10 + k), (12, 30)]))
    arrays = run.state.to_arrays()
    flags = arrays["objects_flags"]
    assert flags.shape == (2, 3)
    old = {**arrays, "objects_flags": flags[:, :2].copy()}
    state = TrackerState.from_arrays(old)
    assert state.flags.shape == (2, 3)
    np.testing.assert_array_equal(state.flags[:, :2], flags[:, :2])
    assert state.flags[:, 2].tolist() == [1, 1]


def test_velocity_fit_residual_noise_and_motion_test():
    t = np.array([-0.3, -0.2, -0.1, 0.0])
    xy = np.array([[0.0, 0.0], [0.2, 0.0], [0.2, 0.0], [0.4, 0.0]])
    v, s = velocity_fit(t, xy, sigma0=0.01)
    # x: t̄ = -0.15, S = 0.05; Σ dt·dx = (-.15)(-.2) + (-.05)(0) + (.05)(0) + (.15)(.2) = 0.06
    assert v[0] == pytest.approx(1.2) and v[1] == 0.0
    # residuals x − (x̄ + v dt): -0.2+0.18 = -0.02, 0+0.06 = 0.06, 0-0.06 = -0.06, 0.2-0.18 = 0.02
    # RSS = 0.008, / (2·2) = 0.002 > σ0² = 1e-4; s = sqrt(0.002 / 0.05) = 0.2
    assert s == pytest.approx(0.2)
    p = TrackingParams(moving_speed_m_per_s=1.0, motion_test=4.0)
    assert is_moving(v, s, p)                  # 1.44 / 0.04 = 36
    assert not is_moving(v, 0.7, p)            # 1.44 / 0.49 = 2.9 < 4
    assert not is_moving(np.array([0.9, 0.0]), 0.01, p)  # below 1 m/s
    assert velocity_fit(t[:1], xy[:1], 0.1)[1] == math.inf


def test_vectorised_fits_equal_the_per_track_fit():
    """velocity_fits (one numpy pass per frame) against velocity_fit (plain floats, the
    reference checked by hand above) on random histories of 0-10 centroids. Tolerance
    1e-9 relative: the two sum in a different order, so they differ by round-off (~1e-15 of
    values of order 1-100), never by a formula."""
    rng = np.random.default_rng(3)
    n, h = 200, 10
    count = rng.integers(0, h + 1, n)
    count[:3] = [0, 1, 2]
    t = np.sort(rng.uniform(-1.0, 0.0, (n, h)), axis=1)
    t[5, :] = -0.3  # equal stamps: S = 0
    count[5] = 4
    xy = rng.normal(0.0, 20.0, (n, h, 2)) + t[..., None] * rng.normal(0, 8, (n, 1, 2))
    v, sigma = velocity_fits(t, xy, count, 0.25)
    for i in range(n):
        m = int(count[i])
        ref_v, ref_sigma = velocity_fit(list(t[i, :m]), [tuple(p) for p in xy[i, :m]], 0.25)
        np.testing.assert_allclose(v[i], ref_v, rtol=1e-9, atol=1e-12)
        if math.isinf(ref_sigma):
            assert math.isinf(sigma[i])
        else:
            assert sigma[i] == pytest.approx(ref_sigma, rel=1e-9)


def test_the_noise_floor_grows_with_the_range_from_the_ego():
    """objects.centroid_sigma_per_m: σ₀ = max(centroid_sigma_m, k · r), r from the centre of
    the window's centre cell — here (rows 20, cols 60, origin 0): x = (30 + 0.5) · 0.5 =
    15.25, y = (10 + 0.5) · 0.5 = 5.25. The block of the test above at frame 2: centroid
    (x, y) = (6.75, 3.0) (cols 12..14, rows 5..6), r = hypot(8.5, 2.25) = 8.793 m."""
    k = 0.05  # σ₀ = 0.440 m: s = 0.440 / sqrt(0.02) = 3.11 m/s, |v|²/s² = 25 / 9.67 = 2.6 < 4
    run = Run(TrackingParams(centroid_sigma_per_m=k))
    reported = [run.step(_frame([(5, 10 + j)]))[0] for j in range(10)]
    r2 = reported[2]
    assert len(r2) == 0  # confirmed but not moving yet, never moved: not reported
    # frame 3: n = 4, S = 0.05, x = 7.25, r = hypot(8.0, 2.25) = 8.310, σ₀ = 0.416:
    # s = 1.858, |v|²/s² = 7.24 >= 4: moving
    r3 = reported[3]
    assert len(r3) == 1 and r3["state"][0] == OBJECT_STATES["moving"]
    sigma3 = k * math.hypot(15.25 - 7.25, 2.25) / math.sqrt(0.05)
    assert r3["speed_sigma_m_per_s"][0] == pytest.approx(sigma3, rel=1e-6)
    # the floor wins where k · r is smaller: k = 0.01 gives 0.093 < 0.25, the test above
    run = Run(TrackingParams(centroid_sigma_per_m=0.01))
    reported = [run.step(_frame([(5, 10 + j)]))[0] for j in range(3)]
    assert reported[2]["speed_sigma_m_per_s"][0] == pytest.approx(0.25 / math.sqrt(0.02))


@pytest.mark.parametrize(("cols_per_frame", "band_rows", "moving"), [
    (1, (4, 8), False),   # 5 m/s, every cell in the widened building: a façade's spot
    (1, (5, 7), False),   # the band just covers the block's rows 5 and 6
    (1, (6, 8), True),    # row 5 outside the band: a cell off the building, tested as before
    (0.25, (4, 8), True),  # 1.25 m/s inside the band: a person along the wall, tested as before
])
def test_a_fast_cluster_all_in_the_widened_buildings_passes_no_motion_test(
        cols_per_frame: float, band_rows: tuple[int, int], moving: bool) -> None:
    """objects.facade_max_speed_m_per_s = 3: the block of the first test (rows 5 and 6)
    moving east at 5 m/s (one column a frame) or 1.25 m/s (one column every fourth frame;
    the fit over 10 frames: 1.25 m/s, σ small enough for the test) inside a band of rows
    marked as the widened buildings."""
    near = np.zeros(SHAPE, np.bool_)
    near[band_rows[0]:band_rows[1]] = True
    params = TrackingParams(facade_max_speed_m_per_s=3.0, motion_evidence_frames=0)
    assert (OBJECT_STATES["moving"] in _block_states(params, near, cols_per_frame)) == moving
    # without the map (no layer) or with the rule off, every case moves
    off = TrackingParams(motion_evidence_frames=0)
    assert OBJECT_STATES["moving"] in _block_states(params, None, cols_per_frame)
    assert OBJECT_STATES["moving"] in _block_states(off, near, cols_per_frame)


def _block_states(params: TrackingParams, near: np.ndarray | None, cols_per_frame: float
                  ) -> list[int]:
    """The states reported over 12 frames of the block at rows 5-6 moving east."""
    state, clusterer = TrackerState(), Clusterer(ClusterParams(), SHAPE)
    states = []
    for k in range(12):
        dec = _frame([(5, 10 + int(k * cols_per_frame))])
        z = np.zeros(SHAPE, np.uint8)
        clusters = clusterer.clusters(dec, z, z, WIN, footprint_seeds(state, WIN))
        recs, _ = track_step(state, clusters, WIN, T0 + k * DT, params, near_building=near)
        states += [int(s) for s in recs["state"]]
    return states
