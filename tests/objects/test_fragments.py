"""The fragment merge of the footprint stage (evperc.objects.footprint.complete_footprints,
its _merge pass) on hand-made object lists (0.5 m cells, 10 Hz); expected outcomes worked out
in the comments."""

from __future__ import annotations

import numpy as np

from evperc.geo.window import Window
from evperc.objects.footprint import FootprintParams, FootprintState, complete_footprints
from evperc.output.objects import OBJECT_DTYPE, OBJECT_STATES, object_labels

RES = 0.5
T0 = 1_000_000_000
DT = 100_000_000
SHAPE = (20, 40)
WIN = Window(RES, *SHAPE, 0, 0)
SILENT = np.zeros(SHAPE, bool)
P = FootprintParams(frames=3, fragment_gap_cells=2, fragment_extent_m=6.0)


def block(r0, r1, c0, c1):
    return [(r, c) for r in range(r0, r1) for c in range(c0, c1)]


def frame(*objs):
    """objs: (track id, cells, age, state) → records and flat cells in record order."""
    recs = np.zeros(len(objs), OBJECT_DTYPE)
    cells = []
    for k, (tid, cs, age, state) in enumerate(objs):
        recs[k]["track_id"] = tid
        recs[k]["state"] = OBJECT_STATES[state]
        recs[k]["cell_count"] = len(cs)
        recs[k]["age_frames"] = age
        recs[k]["velocity_m_per_s"] = (0.0, 0.0)  # no carry: the completion adds nothing
        cells += [r * SHAPE[1] + c for r, c in cs]
    return recs, np.array(cells, np.uint32)


def labels_of(recs, cells):
    lab = object_labels(recs, cells, SHAPE)
    return {int(t): {divmod(int(i), SHAPE[1]) for i in np.flatnonzero(lab.reshape(-1) == t)}
            for t in recs["track_id"]}


def test_two_clusters_one_empty_cell_apart_are_one_object_of_the_longer_moving_track():
    # a car's near face (rows 5-6, cols 10-17: 4 m) and its side (rows 8-9, cols 10-13):
    # row 7 between them is empty, Chebyshev gap 2. Joined box: rows 5-9, cols 10-17 =
    # 2.5 m x 4 m <= 6 m. Track 3 was reported moving one frame earlier (track 2 not
    # reported yet), so it keeps the agent even though track 2 is older by age.
    state = FootprintState()
    face, side = block(5, 7, 10, 18), block(8, 10, 10, 14)
    complete_footprints(state, *frame((3, face, 5, "moving")), WIN, T0, SILENT, P)
    recs, cells = complete_footprints(
        state, *frame((2, side, 10, "moving"), (3, face, 6, "moving")), WIN, T0 + DT,
        SILENT, P)
    assert list(recs["track_id"]) == [3]
    assert labels_of(recs, cells) == {3: set(face) | set(side)}
    assert recs["cell_count"][0] == 16 + 8
    assert np.allclose(recs["extent_m"][0], [8 * RES, 5 * RES])  # x: cols 10-17, y: rows 5-9
    # the tracker's two tracks both keep their history (the merge is in the report only)
    assert set(state.history) == {2, 3}


def test_clusters_two_empty_cells_apart_or_too_long_together_stay_apart():
    # (a) gap 3 (rows 7-8 empty): two objects.
    a, b = block(5, 7, 10, 14), block(9, 11, 10, 14)
    recs, _ = complete_footprints(FootprintState(),
                                  *frame((1, a, 5, "moving"), (2, b, 5, "moving")),
                                  WIN, T0, SILENT, P)
    assert sorted(recs["track_id"]) == [1, 2]
    # (b) gap 2 but the joined box is cols 0-12 = 6.5 m > 6 m (two cars nose to tail).
    c, d = block(5, 7, 0, 6), block(5, 7, 7, 13)
    recs, _ = complete_footprints(FootprintState(),
                                  *frame((1, c, 5, "moving"), (2, d, 5, "moving")),
                                  WIN, T0, SILENT, P)
    assert sorted(recs["track_id"]) == [1, 2]
    # (c) gap 2 with a stopped object: not a moving fragment, stays apart.
    recs, _ = complete_footprints(FootprintState(),
                                  *frame((1, a, 5, "moving"), (2, block(8, 10, 10, 14), 5,
                                                                 "stopped")),
                                  WIN, T0, SILENT, P)
    assert sorted(recs["track_id"]) == [1, 2]


def test_off_by_default_keeps_the_object_list():
    p = FootprintParams(frames=3)
    assert p.fragment_gap_cells == 0
    a, b = block(5, 7, 10, 14), block(8, 10, 10, 14)
    recs, cells = complete_footprints(FootprintState(),
                                      *frame((1, a, 5, "moving"), (2, b, 5, "moving")),
                                      WIN, T0, SILENT, p)
    assert sorted(recs["track_id"]) == [1, 2]
    assert len(cells) == 16
