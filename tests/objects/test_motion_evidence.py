"""Clusters of the cells seen occupied now, the tracker's motion evidence and the fill of the
moving objects' cells (evperc.objects; docs/method.md §8), on hand-made frames whose
expected outcome is worked out in the comments."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from evperc.fusion.twin import DECISION_CODES as D
from evperc.geo.window import Window
from evperc.objects.clusters import Clusterer, ClusterParams
from evperc.objects.stage import fill_moving
from evperc.objects.tracking import TrackerState, TrackingParams, footprint_seeds, track_step
from evperc.output.objects import OBJECT_DTYPE, OBJECT_STATES, moving_object_cells

RES = 0.5
T0 = 1_700_000_000_000_000_000
DT = 100_000_000  # 10 Hz
SHAPE = (20, 60)
WIN = Window(RES, *SHAPE, 0, 0)
Z = np.zeros(SHAPE, np.uint8)
OCCUPIED = ClusterParams(seeds="occupied")
EVIDENCE = TrackingParams(motion_evidence_frames=3, conflict_cells=2, vacated_frames=3,
                          vacated_share=0.3)


def test_occupied_seeds_cluster_what_holds_a_return_now_and_not_the_trail() -> None:
    dec = np.full(SHAPE, D["free"], np.uint8)
    dec[5:7, 10:16] = D["static"]          # 2 x 6 cells decided occupied ...
    now = np.zeros(SHAPE, bool)
    now[5:7, 13:16] = True                 # ... of which the east 2 x 3 hold a return now
    dec[10, 40] = D["moving"]              # a moving cell without a return this scan ...
    dec[10, 41] = D["moving"]
    dec[11, 40] = D["static"]              # ... next to a static one with a return
    now[11, 40] = True
    c = Clusterer(ClusterParams(seeds="occupied", min_cells=1), SHAPE).clusters(
        dec, Z, Z, WIN, occupied_now=now)
    assert len(c) == 2
    first = sorted(c.cells_of(0).tolist())
    # the 6 cells with a return; the 6 remembered cells west of them (the trail) stay out
    assert first == sorted(r * 60 + col for r in (5, 6) for col in (13, 14, 15))
    assert c.seeds[0] == 0                 # no conflict cell in it
    second = sorted(c.cells_of(1).tolist())
    assert second == sorted([10 * 60 + 40, 10 * 60 + 41, 11 * 60 + 40])
    assert c.seeds[1] == 2                 # its two cells decided moving
    # the classic mode: nothing decided moving near the block, so no cluster there
    classic = Clusterer(ClusterParams(seeds="moving", min_cells=1), SHAPE).clusters(
        dec, Z, Z, WIN)
    assert len(classic) == 1 and sorted(classic.cells_of(0).tolist()) == second


class Run:
    """Frames through the clusterer (occupied seeds) and the tracker, as ObjectStage does."""

    def __init__(self, params: TrackingParams) -> None:
        self.state = TrackerState()
        self.clusterer = Clusterer(OCCUPIED, SHAPE)
        self.params = params
        self.k = 0

    def step(self, dec: np.ndarray) -> np.ndarray:
        now = (dec != D["free"]) & (dec != D["unknown"])  # every occupied cell holds a return
        clusters = self.clusterer.clusters(dec, Z, Z, WIN, footprint_seeds(self.state, WIN),
                                           now)
        recs, _ = track_step(self.state, clusters, WIN, T0 + self.k * DT, self.params, dec)
        self.k += 1
        return recs


def _moving_from(frames: list[np.ndarray], params: TrackingParams) -> int | None:
    """The first frame in which an object is reported moving (None: never)."""
    run = Run(params)
    for k, dec in enumerate(frames):
        recs = run.step(dec)
        if (recs["state"] == OBJECT_STATES["moving"]).any():
            return k
    return None


def _car_ahead(k: int) -> np.ndarray:
    """A 2 x 3 block decided static (no conflict: it enters cells that were inside it), one
    cell east per frame; the road it left is seen free."""
    dec = np.full(SHAPE, D["free"], np.uint8)
    dec[5:7, 10 + k:13 + k] = D["static"]
    return dec


def test_a_car_ahead_moves_by_the_cells_it_vacates() -> None:
    frames = [_car_ahead(k) for k in range(10)]
    # velocity: 5 m/s from frame 2 on (3 centroids 0.5 m apart; |v|²/s² = 8 >= 4).
    # vacated: from frame 3 on, the footprint of 3 associations ago (frame k - 3: cols
    # 7+k..9+k) is all free now (share 1 >= 0.3); frames 3, 4, 5 give 3 frames of evidence
    assert _moving_from(frames, EVIDENCE) == 5
    # the same with vacated evidence out of reach (share > 1 never): never moving
    no_vacated = TrackingParams(motion_evidence_frames=3, vacated_share=1.0,
                                vacated_frames=3)
    frames_kept = [f.copy() for f in frames]
    for k, f in enumerate(frames_kept):  # the vacated cells not seen (unknown), not free
        f[5:7, 10:10 + k] = D["unknown"]
    assert _moving_from(frames_kept, no_vacated) is None


def _parked_car_coming_into_view(k: int) -> np.ndarray:
    """A parked car whose side comes into view a column per frame: the cluster grows east,
    its old cells stay occupied (a static object frees nothing)."""
    dec = np.full(SHAPE, D["free"], np.uint8)
    dec[5:7, 10:13 + k] = D["static"]
    return dec


def test_a_growing_static_cluster_is_not_moving_without_evidence() -> None:
    frames = [_parked_car_coming_into_view(k) for k in range(8)]
    # its centroid drifts 0.25 m a frame (2.5 m/s): at frame 3, n = 4, S = 0.05,
    # s = 0.25 / sqrt(0.05) = 1.118, |v|²/s² = 6.25 / 1.25 = 5 >= 4 — the velocity test
    # alone calls it moving there ...
    assert _moving_from(frames, TrackingParams(motion_evidence_frames=0)) == 3
    # ... the evidence does not: no conflict cell, and nothing it held is free now
    assert _moving_from(frames, EVIDENCE) is None


def _conflicting_block(k: int) -> np.ndarray:
    """A 2 x 3 block one cell east per frame, its front column decided moving (2 conflict
    cells), the road behind unknown (not seen: no vacated evidence)."""
    dec = np.full(SHAPE, D["unknown"], np.uint8)
    dec[5:7, 10 + k:13 + k] = D["static"]
    dec[5:7, 12 + k] = D["moving"]
    return dec


def test_conflict_cells_are_evidence_from_the_frames_whose_velocity_passes() -> None:
    frames = [_conflicting_block(k) for k in range(8)]
    # velocity passes from frame 2: conflict evidence in frames 2, 3, 4 -> moving at 4
    assert _moving_from(frames, EVIDENCE) == 4
    # one conflict cell is not enough with conflict_cells = 3
    strict = TrackingParams(motion_evidence_frames=3, conflict_cells=3)
    assert _moving_from(frames, strict) is None


def _walker(k: int) -> np.ndarray:
    """A 1 x 3 group one cell east per frame, only its front cell decided moving (one
    conflict cell: a person steps into one cell seen free at a time), the road behind it
    unknown (no vacated evidence)."""
    dec = np.full(SHAPE, D["unknown"], np.uint8)
    dec[5, 10 + k:13 + k] = D["static"]
    dec[5, 12 + k] = D["moving"]
    return dec


def test_a_small_cluster_shows_conflict_with_one_moving_cell() -> None:
    frames = [_walker(k) for k in range(8)]
    # one conflict cell a frame is short of conflict_cells = 2: never moving
    assert _moving_from(frames, EVIDENCE) is None
    # a cluster of at most 3 cells needs one: the velocity passes from frame 2 (as the
    # 2 x 3 block's above, the same centroids), evidence in frames 2, 3, 4 -> moving at 4
    assert _moving_from(frames, replace(EVIDENCE, single_conflict_max_cells=3)) == 4
    # the bound is on the cluster's cells: 3 cells are more than 2
    assert _moving_from(frames, replace(EVIDENCE, single_conflict_max_cells=2)) is None
    # the 2 x 3 block's two conflict cells pass whatever the bound (6 cells > 3)
    blocks = [_conflicting_block(k) for k in range(8)]
    assert _moving_from(blocks, replace(EVIDENCE, single_conflict_max_cells=3)) == 4


def _fence_coming_into_view(k: int) -> np.ndarray:
    """A fence a sparse scanner's layer sweeps along as the ego drives by: a 2-row block
    that grows a column east per frame, its new column decided moving (seen free before,
    hit now: 2 conflict cells), its old cells still occupied."""
    dec = np.full(SHAPE, D["free"], np.uint8)
    dec[5:7, 10:13 + k] = D["static"]
    dec[5:7, 12 + k] = D["moving"]
    return dec


GROWTH = replace(EVIDENCE, growth_kept_share=0.9, growth_more_cells=2, growth_min_cells=4)


def test_a_cluster_that_only_grows_adds_no_motion_evidence() -> None:
    fence = [_fence_coming_into_view(k) for k in range(10)]
    # the centroid drifts as the parked car's above (0.25 m a frame): the velocity passes
    # from frame 3, and each frame has 2 conflict cells: evidence in frames 3, 4, 5
    assert _moving_from(fence, EVIDENCE) == 5
    # growth: from frame 3 on, the footprint of 3 associations ago (frame k - 3: cols
    # 10..9+k, 2k cells) lies wholly in the cluster (kept 1 >= 0.9), which holds 6 cells
    # more (>= 2): no frame adds evidence, never moving
    assert _moving_from(fence, GROWTH) is None
    # a block that moves leaves its old cells: frame k - 3's cols 7+k..9+k are outside
    # cols 10+k..12+k (kept 0): the rule leaves it as it was
    blocks = [_conflicting_block(k) for k in range(8)]
    assert _moving_from(blocks, GROWTH) == 4
    # ... and so does a fence that grows by less than growth_more_cells: 2 cells a frame
    # over 3 frames are 6 cells, fewer than 7
    assert _moving_from(fence, replace(GROWTH, growth_more_cells=7)) == 5
    # ... or is smaller than growth_min_cells (a person's few cells): the fence holds
    # 2 (k + 3) cells, 12 at frame 3, 14 at frame 4, 16 at frame 5. A floor of 17 leaves
    # frames 3, 4, 5 evidence (moving at 5, as without the rule); a floor of 15 only
    # frames 3 and 4 (the fence is growth from frame 5 on): two frames, never moving
    assert _moving_from(fence, replace(GROWTH, growth_min_cells=17)) == 5
    assert _moving_from(fence, replace(GROWTH, growth_min_cells=15)) is None
    # ... or keeps less than growth_kept_share of its old cells (cols 10..12 cleared from
    # frame 3 on: frame 0's footprint, those 6 cells, none kept at frame 3; frame 1's 8
    # cells, 2 kept at frame 4; frame 2's 10, 4 kept at frame 5)
    cleared = [f.copy() for f in fence]
    for f in cleared[3:]:
        f[5:7, 10:13] = D["unknown"]
    assert _moving_from(cleared, EVIDENCE) == _moving_from(cleared, GROWTH) == 5


def _flickering_fence(k: int) -> np.ndarray:
    """The fence above with its returns a row lower in every odd frame (rows 5-6, 6-7, ...):
    a 16-layer scanner's returns flicker between neighbouring cells."""
    dec = np.full(SHAPE, D["free"], np.uint8)
    r = 5 + k % 2
    dec[r:r + 2, 10:13 + k] = D["static"]
    dec[r:r + 2, 12 + k] = D["moving"]
    return dec


def test_growth_within_a_reach_and_from_the_second_association() -> None:
    fence = [_flickering_fence(k) for k in range(12)]
    # frames k and k - 3 are a row apart: of the old footprint only the shared row is held
    # (a half < 0.9), so the rule leaves it as without it (moving at 5, as the fence above)
    assert _moving_from(fence, EVIDENCE) == _moving_from(fence, GROWTH) == 5
    # within one cell every old cell has a cluster cell beside it (kept 1): growth, never moving
    assert _moving_from(fence, replace(GROWTH, growth_reach_cells=1)) is None
    # a stretch that arrives at once: 2 x 3 cells, then 4 columns more a frame, the new 8
    # cells decided moving; at frame 1, 8 of 14 (>= 0.5, >= 4): an arrival, all the evidence
    # at once, moving when confirmed at frame 2 — before the track has 3 footprints behind
    # it, so the rule cannot see it; with growth_early frame 1 is compared with frame 0
    # (6 cells, all held, 8 more) and frame 2 with frame 0 (22 cells): no evidence, never
    def arriving(k: int) -> np.ndarray:
        dec = np.full(SHAPE, D["free"], np.uint8)
        n = 3 + 4 * k
        dec[5:7, 10:10 + n] = D["static"]
        if k > 0:
            dec[5:7, 6 + n:10 + n] = D["moving"]
        return dec
    stretch = [arriving(k) for k in range(8)]
    arrival = replace(EVIDENCE, arrival_share=0.5, arrival_min_cells=4)
    grow = replace(GROWTH, arrival_share=0.5, arrival_min_cells=4)
    assert _moving_from(stretch, arrival) == _moving_from(stretch, grow) == 2
    assert _moving_from(stretch, replace(grow, growth_early=True)) is None


def test_checkpoint_keeps_the_evidence_and_the_past_footprints() -> None:
    frames = [_car_ahead(k) for k in range(10)]
    a, b = Run(EVIDENCE), Run(EVIDENCE)
    for dec in frames[:4]:
        a.step(dec)
        b.step(dec)
    b.state = TrackerState.from_arrays(b.state.to_arrays())
    t = b.state.tracks[0]
    assert (t.conflict_evidence, t.vacated_evidence, len(t.past)) == (0, 1, 3)
    for dec in frames[4:]:
        ra, rb = a.step(dec), b.step(dec)
        assert ra.tobytes() == rb.tobytes()


def test_fill_moving_decides_only_the_moving_objects_cells() -> None:
    dec = np.full((4, 5), D["static"], np.uint8)
    dec[0, 0] = D["moving"]
    objects = np.zeros(2, OBJECT_DTYPE)
    objects["track_id"] = [1, 2]
    objects["state"] = [OBJECT_STATES["moving"], OBJECT_STATES["stopped"]]
    objects["cell_count"] = [3, 2]
    cells = np.array([0, 1, 6, 18, 19], np.uint32)  # object 1: (0,0) (0,1) (1,1); 2: (3,3) (3,4)
    assert fill_moving(dec, moving_object_cells(objects, cells)) == 2   # (0,0) was moving already
    expected = np.full((4, 5), D["static"], np.uint8)
    expected[0, 0] = expected[0, 1] = expected[1, 1] = D["moving"]
    np.testing.assert_array_equal(dec, expected)
    assert fill_moving(dec, moving_object_cells(objects[:0], cells[:0])) == 0


def _go_stop_go(k: int) -> np.ndarray:
    """A 2 x 3 block: frames 0-5 one cell east a frame with its front column decided moving
    (2 conflict cells); frames 6-10 standing where frame 5 left it, all static; frames 11-16
    one cell east a frame again, all static (no conflict), the road behind it unknown (no
    vacated evidence)."""
    col = 10 + min(k, 5) + max(k - 10, 0)
    dec = np.full(SHAPE, D["unknown"], np.uint8)
    dec[5:7, col:col + 3] = D["static"]
    if k <= 5:
        dec[5:7, col + 2] = D["moving"]
    return dec


def test_motion_evidence_expires_while_the_track_stands() -> None:
    frames = [_go_stop_go(k) for k in range(17)]
    # history of 3 centroids: the velocity passes from frame 2 (5 m/s, |v|²/s² = 8 >= 4, as
    # above) to frame 5; at frame 6 the fit of (0, 0.5, 0.5) m is 2.5 m/s, |v|²/s² = 2 < 4,
    # and 0 from frame 7 to 11; from frame 12 (0, 0.5, 1.0) m passes again.
    # Conflict evidence in frames 2, 3, 4, 5: moving from frame 4 to 5, stopped from 6.
    kept = TrackingParams(motion_evidence_frames=3, conflict_cells=2, vacated_frames=3,
                          vacated_share=0.3, history_frames=3)
    # the counts only grow: 4 frames of evidence, moving again as soon as the velocity
    # passes at frame 12, with no evidence since frame 5
    run = Run(kept)
    states = [run.step(dec)["state"].tolist() for dec in frames]
    moving, stopped = [OBJECT_STATES["moving"]], [OBJECT_STATES["stopped"]]
    assert [k for k, s in enumerate(states) if s == moving] == [4, 5, *range(12, 17)]
    assert run.state.tracks[0].conflict_evidence == 4
    # evidence_expires: kept at most 3 (frame 5: 4 -> 3), one off in each frame whose fitted
    # speed is under the 1 m/s floor — frames 7-10 (0 m/s; frames 6 and 11 fit 2.5 m/s, which
    # fails the motion test but is no standstill) — 3 -> 0 by frame 9, none gained from
    # frame 12: stopped to the end
    run = Run(replace(kept, evidence_expires=True))
    states, counts = [], []
    for dec in frames:
        states.append(run.step(dec)["state"].tolist())
        counts.append(run.state.tracks[0].conflict_evidence)
    assert counts[2:12] == [1, 2, 3, 3, 3, 2, 1, 0, 0, 0]
    assert [k for k, s in enumerate(states) if s == moving] == [4, 5]
    assert all(states[k] == stopped for k in range(6, 17))
    assert run.state.tracks[0].conflict_evidence == 0
