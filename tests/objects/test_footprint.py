"""The motion-compensated footprint completion (evperc.objects.footprint) on hand-made object
lists; the expected cells are worked out by hand in the comments (0.5 m cells, 10 Hz)."""

from __future__ import annotations

import numpy as np

from evperc.geo.window import Window
from evperc.objects.footprint import FootprintParams, FootprintState, complete_footprints
from evperc.output.objects import OBJECT_DTYPE, OBJECT_STATES

RES = 0.5
T0 = 1_000_000_000
DT = 100_000_000
SHAPE = (10, 30)
WIN = Window(RES, *SHAPE, 0, 0)
SILENT = np.zeros(SHAPE, bool)  # a scan that says nothing about any cell


def flat(cells):
    return np.array([r * SHAPE[1] + c for r, c in cells], np.uint32)


def obj(cells, v=(5.0, 0.0), state="moving", tid=7):
    rec = np.zeros(1, OBJECT_DTYPE)
    rec["track_id"] = tid
    rec["state"] = OBJECT_STATES[state]
    rec["cell_count"] = len(cells)
    rec["velocity_m_per_s"] = v
    return rec, flat(cells)


def as_set(cells):
    return {divmod(int(c), SHAPE[1]) for c in cells}


def test_past_cells_are_carried_forward_by_the_velocity():
    # a car at 5 m/s east = 0.5 m = one cell per frame. Frame 0 shows its rear (cols 3-4 of
    # rows 4-5), frame 1 only its front face (col 8 of rows 4-5): the rear, carried forward
    # one cell, is cols 4-5 — cells the scan of frame 1 says nothing about.
    state, p = FootprintState(), FootprintParams(frames=3)
    rear = [(4, 3), (4, 4), (5, 3), (5, 4)]
    complete_footprints(state, *obj(rear), WIN, T0, SILENT, p)
    front = [(4, 8), (5, 8)]
    recs, cells = complete_footprints(state, *obj(front), WIN, T0 + DT, SILENT, p)
    assert as_set(cells) == set(front) | {(4, 4), (4, 5), (5, 4), (5, 5)}
    assert recs["cell_count"][0] == 6
    # centroid of the 6 cell centres: x = (4.5+5.5+8.5)·2/6 · 0.5 m, y = 4.5·... + 0.5
    assert np.allclose(recs["centroid_m"][0], [(4.5 + 5.5 + 8.5) / 3 * RES, 5.0 * RES])
    assert np.allclose(recs["bbox_m"][0], [4 * RES, 4 * RES, 9 * RES, 6 * RES])
    # two frames on (0.2 s = 1 m = 2 cells), with frame 1's front as history too
    recs, cells = complete_footprints(state, *obj([(4, 9), (5, 9)]), WIN, T0 + 2 * DT,
                                      SILENT, p)
    assert as_set(cells) == {(4, 9), (5, 9), (4, 5), (4, 6), (5, 5), (5, 6)}


def test_cells_the_scan_sees_are_never_added():
    # the same car, but frame 1's scan sees (4, 5) free and (5, 4) holding a return
    state, p = FootprintState(), FootprintParams(frames=3)
    complete_footprints(state, *obj([(4, 3), (4, 4), (5, 3), (5, 4)]), WIN, T0, SILENT, p)
    speaks = SILENT.copy()
    speaks[4, 5] = speaks[5, 4] = True
    _, cells = complete_footprints(state, *obj([(4, 8), (5, 8)]), WIN, T0 + DT, speaks, p)
    assert as_set(cells) == {(4, 8), (5, 8), (4, 4), (5, 5)}


def test_history_is_the_last_k_moving_frames_only():
    # K = 1: frame 2 is completed by frame 1 (cols 7-8, carried to 8-9) only, not by frame 0
    # (col 3, which would be carried to col 5)
    state, p = FootprintState(), FootprintParams(frames=1)
    complete_footprints(state, *obj([(4, 3), (5, 3)]), WIN, T0, SILENT, p)
    complete_footprints(state, *obj([(4, 7), (4, 8), (5, 7), (5, 8)]), WIN, T0 + DT, SILENT, p)
    _, cells = complete_footprints(state, *obj([(4, 9), (5, 9)]), WIN, T0 + 2 * DT, SILENT, p)
    assert as_set(cells) == {(4, 9), (5, 9), (4, 8), (5, 8)}


def test_a_stopped_object_is_not_completed_and_restarts():
    state, p = FootprintState(), FootprintParams(frames=3)
    complete_footprints(state, *obj([(4, 3), (5, 3)]), WIN, T0, SILENT, p)
    recs, cells = complete_footprints(state, *obj([(4, 8)], state="stopped"), WIN, T0 + DT,
                                      SILENT, p)
    assert as_set(cells) == {(4, 8)} and recs["cell_count"][0] == 1
    _, cells = complete_footprints(state, *obj([(4, 9)]), WIN, T0 + 2 * DT, SILENT, p)
    assert as_set(cells) == {(4, 9)}  # no history from before the stop


def test_off_returns_the_tracker_output_and_other_objects_keep_their_cells():
    state = FootprintState()
    rec, cells = obj([(4, 3), (5, 3)])
    out = complete_footprints(state, rec, cells, WIN, T0, SILENT, FootprintParams(frames=0))
    assert out[0] is rec and out[1] is cells and not state.history
    # two objects: the second's cells follow the first's completed ones, in record order
    p = FootprintParams(frames=2)
    a, b = obj([(1, 1)], tid=1), obj([(8, 20)], v=(0.0, 0.0), tid=2)
    both = (np.concatenate([a[0], b[0]]), np.concatenate([a[1], b[1]]))
    complete_footprints(state, *both, WIN, T0, SILENT, p)
    a2 = obj([(1, 3)], tid=1)
    recs, cells = complete_footprints(state, np.concatenate([a2[0], b[0]]),
                                      np.concatenate([a2[1], b[1]]), WIN, T0 + DT, SILENT, p)
    assert list(recs["cell_count"]) == [2, 1]
    assert as_set(cells[:2]) == {(1, 3), (1, 2)} and as_set(cells[2:]) == {(8, 20)}


def test_checkpoint_round_trip():
    state, p = FootprintState(), FootprintParams(frames=3)
    complete_footprints(state, *obj([(4, 3), (5, 3)]), WIN, T0, SILENT, p)
    complete_footprints(state, *obj([(4, 8), (5, 8)]), WIN, T0 + DT, SILENT, p)
    back = FootprintState.from_arrays(state.to_arrays())
    assert back is not None and back.history.keys() == state.history.keys()
    for (t1, a), (t2, b) in zip(state.history[7], back.history[7], strict=True):
        assert t1 == t2 and np.array_equal(a, b)
    assert FootprintState.from_arrays({}) is None
