"""Issue 21's recall mechanisms of the tracker and the clusterer on hand-made frames
(objects.arrival_share, objects.evidence_every_frame, objects.keep_tracked_small); the
expected frames are worked out in the comments (0.5 m cells, 10 Hz)."""

from __future__ import annotations

import numpy as np

from evperc.fusion.twin import DECISION_CODES as D
from evperc.geo.window import Window
from evperc.objects.clusters import Clusterer, ClusterParams
from evperc.objects.tracking import TrackerState, TrackingParams, footprint_seeds, track_step
from evperc.output.objects import OBJECT_STATES

RES = 0.5
T0 = 1_700_000_000_000_000_000
DT = 100_000_000
SHAPE = (20, 60)
WIN = Window(RES, *SHAPE, 0, 0)
Z = np.zeros(SHAPE, np.uint8)
EVIDENCE = dict(motion_evidence_frames=3, conflict_cells=2, vacated_frames=3,
                vacated_share=0.3)


OCCUPIED = ClusterParams(seeds="occupied")


def _states(frames, params, cluster_params=OCCUPIED):
    """Per frame, the reported objects' states (list of OBJECT_STATES codes)."""
    state, clusterer, out = TrackerState(), Clusterer(cluster_params, SHAPE), []
    for k, dec in enumerate(frames):
        now = (dec != D["free"]) & (dec != D["unknown"])
        clusters = clusterer.clusters(dec, Z, Z, WIN, footprint_seeds(state, WIN), now)
        recs, _ = track_step(state, clusters, WIN, T0 + k * DT, params, dec)
        out.append(list(recs["state"]))
    return out


def _first_moving(frames, params, **kw):
    for k, states in enumerate(_states(frames, params, **kw)):
        if OBJECT_STATES["moving"] in states:
            return k
    return None


def _block(k, moving_cols):
    """A 2 x 3 block one cell east per frame; its ``moving_cols`` east columns decided
    moving (arrived in cells seen free), the rest static, the road behind unknown."""
    dec = np.full(SHAPE, D["unknown"], np.uint8)
    dec[5:7, 10 + k:13 + k] = D["static"]
    dec[5:7, 13 + k - moving_cols:13 + k] = D["moving"]
    return dec


def test_arrival_gives_the_whole_evidence_at_once() -> None:
    # the velocity passes from frame 2 (three centroids 0.5 m apart, |v|²/s² = 8 >= 4)
    arrived = [_block(k, 3) for k in range(8)]   # every cell decided moving: share 1
    face = [_block(k, 1) for k in range(8)]      # 2 of 6 cells: share 1/3
    classic = TrackingParams(**EVIDENCE)
    assert _first_moving(arrived, classic) == 4  # evidence in frames 2, 3, 4
    arrival = TrackingParams(**EVIDENCE, arrival_share=0.5)
    assert _first_moving(arrived, arrival) == 2  # frame 2's evidence counts 3
    assert _first_moving(face, arrival) == 4     # 1/3 < 0.5: counted frame by frame
    assert _first_moving(face, TrackingParams(**EVIDENCE, arrival_share=0.3)) == 2


def test_arrival_needs_its_least_count_of_moving_cells() -> None:
    # 3 x 1 cells (the clusters' least size), all decided moving (share 1: arrival with
    # arrival_min_cells <= 3), one cell east per frame: the velocity passes from frame 2
    def small(k):
        dec = np.full(SHAPE, D["unknown"], np.uint8)
        dec[5:8, 10 + k] = D["moving"]
        return dec
    frames = [small(k) for k in range(8)]
    assert _first_moving(frames, TrackingParams(**EVIDENCE, arrival_share=0.5)) == 2
    assert _first_moving(frames, TrackingParams(**EVIDENCE, arrival_share=0.5,
                                                arrival_min_cells=3)) == 2
    # 3 moving cells < 4: counted frame by frame (frames 2, 3, 4), as without arrival
    assert _first_moving(frames, TrackingParams(**EVIDENCE, arrival_share=0.5,
                                                arrival_min_cells=4)) == 4
    assert _first_moving(frames, TrackingParams(**EVIDENCE)) == 4
    # the 6-cell arrival of the test above still arrives at once with 4 (6 moving cells)
    arrived = [_block(k, 3) for k in range(8)]
    assert _first_moving(arrived, TrackingParams(**EVIDENCE, arrival_share=0.5,
                                                 arrival_min_cells=4)) == 2
    assert _first_moving(arrived, TrackingParams(**EVIDENCE, arrival_share=0.5,
                                                 arrival_min_cells=7)) == 4


def test_arrival_needs_conflict_a_growing_parked_car_still_never_moves() -> None:
    frames = []
    for k in range(8):  # its side comes into view a column per frame, nothing conflicts
        dec = np.full(SHAPE, D["free"], np.uint8)
        dec[5:7, 10:13 + k] = D["static"]
        frames.append(dec)
    assert _first_moving(frames, TrackingParams(**EVIDENCE, arrival_share=0.5)) is None
    assert _first_moving(frames, TrackingParams(**EVIDENCE, evidence_every_frame=True)) is None


def test_evidence_of_every_frame_counts_the_frames_before_the_velocity_passes() -> None:
    face = [_block(k, 1) for k in range(8)]
    # conflict evidence in frames 0, 1, 2 (2 cells each); the velocity passes at frame 2
    assert _first_moving(face, TrackingParams(**EVIDENCE, evidence_every_frame=True)) == 2


def test_a_moving_track_keeps_its_object_when_seen_as_one_cell() -> None:
    frames = [_block(k, 1) for k in range(6)]      # moving from frame 4 (classic evidence)
    glimpse = np.full(SHAPE, D["unknown"], np.uint8)
    glimpse[5, 17] = D["moving"]                   # frame 6: one cell of its front (the block
    frames.append(glimpse)                         # of frame 5 held cols 15-17)
    params = TrackingParams(**EVIDENCE)
    keep = ClusterParams(seeds="occupied", keep_tracked_small=True)
    assert _states(frames, params, cluster_params=keep)[6] == [OBJECT_STATES["moving"]]
    # without the key the one-cell cluster is dropped (min_cells 3): no object in frame 6
    assert _states(frames, params)[6] == []


def test_only_the_small_clusters_grown_from_a_tracked_cell_are_kept() -> None:
    dec = np.full(SHAPE, D["free"], np.uint8)
    dec[2, 2] = dec[2, 3] = D["static"]            # two cells, a tracked cell among them
    dec[10, 30] = D["static"]                      # one cell, untracked
    now = dec != D["free"]
    extra = np.array([2 * 60 + 3], np.int64)
    c = Clusterer(ClusterParams(seeds="occupied", keep_tracked_small=True), SHAPE).clusters(
        dec, Z, Z, WIN, extra, now)
    assert len(c) == 1 and sorted(c.cells_of(0).tolist()) == [2 * 60 + 2, 2 * 60 + 3]
    off = Clusterer(ClusterParams(seeds="occupied"), SHAPE).clusters(dec, Z, Z, WIN, extra, now)
    assert len(off) == 0


def test_a_track_never_away_from_the_sensor_passes_no_motion_test() -> None:
    # the window's centre cell (row 10, column 30: x 15.25 m, y 5.25 m) holds the sensor;
    # the block's centroid (x 5.75 + 0.5 k, y 3.0 m in frame k) comes towards it: 9.76 m
    # away in frame 0, 8.79 in frame 2, 7.35 in frame 5
    arrived = [_block(k, 3) for k in range(8)]
    params = dict(**EVIDENCE, arrival_share=0.5)
    assert _first_moving(arrived, TrackingParams(**params)) == 2
    # never 10 m away: the vehicle's own returns as far as the rule can tell
    assert _first_moving(arrived, TrackingParams(**params, ego_clearance_m=10.0)) is None
    # 9.76 m away when first seen: its motion counts, also once it is nearer than 7.5 m
    states = _states(arrived, TrackingParams(**params, ego_clearance_m=7.5))
    assert _first_moving(arrived, TrackingParams(**params, ego_clearance_m=7.5)) == 2
    assert states[5] == states[7] == [OBJECT_STATES["moving"]]
    # first seen at 9.76 m, never 9.8 m away: never reported
    assert _first_moving(arrived, TrackingParams(**params, ego_clearance_m=9.8)) is None
