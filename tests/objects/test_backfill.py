"""The object list's fixed-lag backfill (objects.backfill_frames, evperc/objects/backfill.py):
hand-built frames with the records worked out by hand, the candidates read from a tracker
state, and whole runs with and without it compared frame by frame — the rule checked on the
outputs alone (the backfill does not change what the tracker does, so every record it adds
must be a track the causal run reports moving within the lag, absent from that frame)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import evperc
from evperc.config import ConfigError, load_config
from evperc.fusion.twin import DECISION_CODES as D
from evperc.geo.window import Window
from evperc.objects.backfill import (
    Backfill,
    Candidates,
    HeldFrame,
    backfill_frames,
    bridge_cells,
    candidates,
)
from evperc.objects.tracking import TrackerState
from evperc.output.objects import OBJECT_DTYPE, OBJECT_STATES, empty_objects, object_labels
from evperc.runner import RunRequest, run

MOVING = OBJECT_STATES["moving"]
W = Window(0.5, 10, 10, 100, 200)  # rows 100-109, cols 200-209 of the lattice


def _frame(candidates: dict, objects: np.ndarray | None = None,
           cells: np.ndarray | None = None, betp: int = 51) -> HeldFrame:
    decision = np.full(W.shape, D["free"], np.uint8)
    return HeldFrame(W, decision, np.full(W.shape, betp, np.uint8),
                     empty_objects() if objects is None else objects,
                     np.zeros(0, np.uint32) if cells is None else cells,
                     Candidates.from_dict({k: (np.array(v, np.int64), age)
                                           for k, (v, age) in candidates.items()}))


def _record(track: int, state: int = MOVING, cells: int = 1,
            velocity: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    r = np.zeros(1, OBJECT_DTYPE)
    r["track_id"], r["state"], r["cell_count"] = track, state, cells
    r["velocity_m_per_s"], r["speed_sigma_m_per_s"] = velocity, 0.125
    return r


def test_a_track_reported_moving_later_is_filled_into_the_held_frames() -> None:
    """Lag 2. Track 7 is a candidate in frames 0 and 1 (associated, not reported), reported
    moving in frame 2: frames 0 and 1 get its record and their cells decided moving; track
    9 (frame 0, never reported) and cells outside the window get nothing; frame 3 reports
    7 again and adds nothing twice."""
    backfill = Backfill(2)
    f0 = _frame({7: ([[101, 202], [101, 203]], 1), 9: ([[105, 205]], 4)})
    f1 = _frame({7: ([[101, 203], [101, 204], [100, 199]], 2)},  # (100, 199): outside
                objects=_record(12), cells=np.array([55], np.uint32), betp=102)
    assert backfill.push(f0) == [] and backfill.push(f1) == []
    report = _record(7, cells=1, velocity=(1.5, -0.25))
    f2 = _frame({}, objects=report, cells=np.array([14], np.uint32))
    assert backfill.push(f2) == [f0]
    # frame 0: cells (1, 2), (1, 3) of the window
    assert np.flatnonzero(f0.decision.reshape(-1) == D["moving"]).tolist() == [12, 13]
    (r,) = f0.objects
    assert (r["track_id"], r["state"], r["cell_count"], r["age_frames"]) == (7, MOVING, 2, 1)
    # centre of cells (101, 202) and (101, 203): x = (202.5 + 0.5) * 0.5, y = 101.5 * 0.5
    np.testing.assert_allclose(r["centroid_m"], [101.5, 50.75])
    np.testing.assert_allclose(r["bbox_m"], [101.0, 50.5, 102.0, 51.0])
    np.testing.assert_allclose(r["extent_m"], [1.0, 0.5])
    np.testing.assert_allclose(r["velocity_m_per_s"], [1.5, -0.25])
    assert r["speed_sigma_m_per_s"] == np.float32(0.125)
    assert r["mean_betp_moving"] == np.float32(51 / 255)
    assert f0.object_cells.tolist() == [12, 13] and f0.added == [7]
    assert np.count_nonzero(f0.decision != D["free"]) == 2  # the two cells, nothing else
    assert 9 in f0.candidates and 7 not in f0.candidates
    # frame 1: the record joins track 12's, in id order, cells reordered with it
    assert f1.objects["track_id"].tolist() == [7, 12]
    assert f1.object_cells.tolist() == [13, 14, 55]
    assert f1.objects["cell_count"].tolist() == [2, 1]
    assert f1.objects[0]["mean_betp_moving"] == np.float32(102 / 255)
    labels = object_labels(f1.objects, f1.object_cells, W.shape).reshape(-1)
    assert labels[13] == labels[14] == 7 and labels[55] == 12
    f3 = _frame({}, objects=_record(7), cells=np.array([15], np.uint32))
    assert backfill.push(f3) == [f1]
    assert f1.objects["track_id"].tolist() == [7, 12]  # filled once
    assert backfill.flush() == [f2, f3] and backfill.flush() == []
    assert len(f2.objects) == 1  # the reporting frame itself is unchanged


def test_a_report_that_drops_out_and_returns_fills_the_frame_between() -> None:
    """Lag 3. Track 7 is a candidate in frame 0, reported moving in frame 1 (frame 0
    filled), associated but not reported in frame 2, moving again in frames 3 and 4: frame 2
    is filled at frame 3 (a report after a frame without one fills); frame 4's report, the
    same track moving in the frame before, has nothing left to fill."""
    backfill = Backfill(3)
    f0 = _frame({7: ([[101, 202]], 1)})
    f1 = _frame({}, objects=_record(7), cells=np.array([13], np.uint32))
    f2 = _frame({7: ([[101, 204]], 3)})
    backfill.push(f0)
    backfill.push(f1)
    assert f0.added == [7]
    backfill.push(f2)
    f3 = _frame({}, objects=_record(7), cells=np.array([15], np.uint32))
    assert backfill.push(f3) == [f0]
    assert f2.added == [7] and f2.objects["age_frames"].tolist() == [3]
    assert np.flatnonzero(f2.decision.reshape(-1) == D["moving"]).tolist() == [14]
    f4 = _frame({}, objects=_record(7), cells=np.array([16], np.uint32))
    assert backfill.push(f4) == [f1]
    assert f0.added == f2.added == [7] and f1.added == f3.added == []


def test_a_report_fills_candidates_only_within_the_candidate_frames() -> None:
    """Lag 4, objects.backfill_candidate_frames 2: track 7 is a candidate in frames 0-3 and
    reported moving in frame 4; only the two frames before the report (2 and 3) get its
    record, frames 0 and 1 keep none and stay candidates (a report within 2 frames of them
    could still fill them). The same frames with the window at its default (-1, every held
    frame) fill all four: the count is what limits it."""
    def frames() -> list[HeldFrame]:
        return [_frame({7: ([[101, 202 + k]], k + 1)}) for k in range(4)]
    limited, every = frames(), frames()
    for backfill, held in ((Backfill(4, candidate_frames=2), limited), (Backfill(4), every)):
        for f in held:
            assert backfill.push(f) == []
        backfill.push(_frame({}, objects=_record(7), cells=np.array([16], np.uint32)))
    assert [f.added for f in limited] == [[], [], [7], [7]]
    assert [7 in f.candidates for f in limited] == [True, True, False, False]
    assert np.flatnonzero(limited[2].decision.reshape(-1) == D["moving"]).tolist() == [14]
    assert np.count_nonzero(limited[0].decision == D["moving"]) == 0
    assert [f.added for f in every] == [[7], [7], [7], [7]]
    assert Backfill.from_config(load_config()).candidate_frames == 6  # -1: the lag's 6
    assert Backfill.from_config(load_config(overrides={"objects.backfill_frames": 10})
                                ).candidate_frames == 10  # -1 follows the lag
    assert Backfill.from_config(load_config(overrides={
        "objects.backfill_frames": 10, "objects.backfill_candidate_frames": 3})
        ).candidate_frames == 3
    with pytest.raises(ConfigError, match="backfill_candidate_frames"):
        load_config(overrides={"objects.backfill_candidate_frames": -2})


def _gap_frames(before_state: int = MOVING, reach: int = 1, trace: bool = False
                ) -> tuple[Backfill, list[HeldFrame]]:
    """Lag 3, frames 0.5 s apart: track 7 (velocity 1 m/s along x: one 0.5 m cell a frame)
    has a record in frame 0 on window cell (2, 2), none in frame 1, and is reported moving
    in frame 2 on (2, 4). Frame 1 holds a stopped record of track 12 on (1, 2); its cells
    occupied now: (2, 3) and (3, 4) (within one cell of the prediction (2, 3) from both
    ends), (2, 5) (two cells away) and (1, 2) (track 12's). ``trace``: :attr:`Backfill.trace`."""
    backfill = Backfill(3, bridge_reach=reach, trace=trace)

    def frame(k: int, objects: np.ndarray, cells: list[int], occupied: list[int]
              ) -> HeldFrame:
        f = _frame({}, objects=objects, cells=np.array(cells, np.uint32))
        f.stamp_ns = k * 500_000_000
        f.occupied = np.zeros(W.shape, np.bool_)
        f.occupied.reshape(-1)[occupied] = True
        return f

    frames = [frame(0, _record(7, state=before_state, velocity=(1.0, 0.0)), [22], [22]),
              frame(1, _record(12, state=OBJECT_STATES["stopped"]), [12], [23, 34, 25, 12]),
              frame(2, _record(7, velocity=(1.0, 0.0)), [24], [24])]
    return backfill, frames


def test_a_gap_between_two_moving_records_is_bridged() -> None:
    """The gap frame gets track 7's record on its occupied cells within one cell of the
    predicted (2, 3), not on the cell two away nor on track 12's; they are decided moving,
    the record takes the age of the record before the gap and the report's velocity; traced,
    the frame notes them as the gap's."""
    backfill, (f0, f1, f2) = _gap_frames(trace=True)
    f0.objects["age_frames"] = 5
    for f in (f0, f1, f2):
        backfill.push(f)
    assert f1.added == [7] and f1.objects["track_id"].tolist() == [7, 12]
    assert f1.object_cells.tolist() == [23, 34, 12]
    assert np.flatnonzero(f1.decision.reshape(-1) == D["moving"]).tolist() == [23, 34]
    (r,) = f1.objects[f1.objects["track_id"] == 7]
    assert (r["state"], r["age_frames"], r["cell_count"]) == (MOVING, 5, 2)
    np.testing.assert_allclose(r["velocity_m_per_s"], [1.0, 0.0])
    assert f0.added == f2.added == []
    assert f1.added_by == {23: "gap", 34: "gap"} and f0.added_by is f2.added_by is None


def test_a_gap_between_two_candidates_is_bridged_when_they_are_filled() -> None:
    """Lag 4: track 7 a candidate in frames 0 and 2 (window cells (2, 2) and (2, 4)), not
    associated in frame 1, reported moving in frame 3: frames 0 and 2 are filled, then the
    gap between them bridged on frame 1's occupied cell at the predicted (2, 3)."""
    backfill = Backfill(4, bridge_reach=0)
    frames = [_frame({7: ([[102, 202]], 1)}), _frame({}), _frame({7: ([[102, 204]], 2)}),
              _frame({}, objects=_record(7, velocity=(1.0, 0.0)),
                     cells=np.array([25], np.uint32))]
    for k, f in enumerate(frames):
        f.stamp_ns = k * 500_000_000
        f.occupied = np.zeros(W.shape, np.bool_)
        f.occupied.reshape(-1)[[22 + k, 33]] = True  # (3, 3): off the prediction
        backfill.push(f)
    assert [f.added for f in frames] == [[7], [7], [7], []]
    assert frames[1].object_cells.tolist() == [23]
    assert frames[1].objects["age_frames"].tolist() == [1]  # the record before the gap


def test_a_bridged_record_takes_the_predicted_cells_its_scan_is_silent_about() -> None:
    """Track 7 on window cells (2, 2), (3, 2) before the gap and (2, 4), (3, 4) after it:
    predicted (2, 3), (3, 3) in the gap frame. (2, 3) is occupied there; (3, 3) joins the
    record when the scan is silent about it, not when it was seen free; with no occupied
    cell near the prediction nothing is bridged, silent or not."""
    def run(occupied: list[int], free: list[int]) -> HeldFrame:
        backfill = Backfill(3, bridge_reach=0)
        f0 = _frame({}, objects=_record(7, cells=2, velocity=(1.0, 0.0)),
                    cells=np.array([22, 32], np.uint32))
        f1 = _frame({})
        f2 = _frame({}, objects=_record(7, cells=2, velocity=(1.0, 0.0)),
                    cells=np.array([24, 34], np.uint32))
        for k, f in enumerate((f0, f1, f2)):
            f.stamp_ns = k * 500_000_000
            f.occupied = np.zeros(W.shape, np.bool_)
            f.speaks = np.zeros(W.shape, np.bool_)
        f1.occupied.reshape(-1)[occupied] = True
        f1.speaks.reshape(-1)[occupied + free] = True
        for f in (f0, f1, f2):
            backfill.push(f)
        return f1

    assert run([23], []).object_cells.tolist() == [23, 33]
    assert run([23], [33]).object_cells.tolist() == [23]
    gap = run([], [])
    assert gap.added == [] and not (gap.decision == D["moving"]).any()


def _lead_frames(occupied: list[list[int]], lead: int = 6, reach: int = 1,
                 trace: bool = False, moving_before: tuple[int, ...] = ()
                 ) -> list[HeldFrame]:
    """Lag 4, track 7 moving +x at 1 m/s (a cell every 0.5 s): a candidate in frame 2 on
    window cell (2, 4), reported moving in frame 3 on (2, 5); frames 0 and 1 hold the
    occupied cells ``occupied[0]``, ``occupied[1]`` (flat) and no candidate of it; frame 1
    decides the flat cells ``moving_before`` moving before any fill; pushed (``trace``:
    :attr:`Backfill.trace`)."""
    backfill = Backfill(4, bridge_reach=0, lead_frames=lead, lead_reach=reach, trace=trace)
    frames = [_frame({}), _frame({}), _frame({7: ([[102, 204]], 2)}),
              _frame({}, objects=_record(7, velocity=(1.0, 0.0)),
                     cells=np.array([25], np.uint32))]
    frames[1].decision.reshape(-1)[list(moving_before)] = D["moving"]
    for k, f in enumerate(frames):
        f.stamp_ns = k * 500_000_000
        f.occupied = np.zeros(W.shape, np.bool_)
        f.occupied.reshape(-1)[occupied[k] if k < 2 else [24 + k - 2]] = True
    for f in frames:
        backfill.push(f)
    return frames


def test_a_track_is_led_back_before_its_first_association() -> None:
    """Track 7's first association is frame 2's candidate (2, 4): frame 1 gets the occupied
    cells within one cell of (2, 3), its velocity run back (23 and 33, not 53), frame 0
    those within one cell of frame 1's record run back one more cell ((2, 2), (3, 2):
    22 and 41, not 55); age 0, the report's velocity, decided moving. With lead_frames 1
    only frame 1; 0 none; reach 0 the predicted cell alone (23, then 22)."""
    f0, f1, f2, _ = _lead_frames([[22, 41, 55], [23, 33, 53]])
    assert [f0.added, f1.added, f2.added] == [[7], [7], [7]]
    assert f1.object_cells.tolist() == [23, 33] and f0.object_cells.tolist() == [22, 41]
    for f in (f0, f1):
        (r,) = f.objects
        assert (r["track_id"], r["state"], r["age_frames"]) == (7, MOVING, 0)
        np.testing.assert_allclose(r["velocity_m_per_s"], [1.0, 0.0])
    assert np.flatnonzero(f0.decision.reshape(-1) == D["moving"]).tolist() == [22, 41]
    f0, f1, _, _ = _lead_frames([[22, 41, 55], [23, 33, 53]], lead=1)
    assert f0.added == [] and f1.object_cells.tolist() == [23, 33]
    f0, f1, _, _ = _lead_frames([[22, 41, 55], [23, 33, 53]], lead=0)
    assert f0.added == f1.added == []
    f0, f1, _, _ = _lead_frames([[22, 41, 55], [23, 33, 53]], reach=0)
    assert f1.object_cells.tolist() == [23] and f0.object_cells.tolist() == [22]


def test_a_lead_stops_at_the_first_frame_with_nothing_there() -> None:
    """Frame 1 has no occupied cell within one cell of (2, 3): nothing is led into it, nor
    into frame 0 beyond it, whose cells sit where the track would have been."""
    f0, f1, f2, _ = _lead_frames([[22, 23], [55]])
    assert f0.added == f1.added == [] and f2.added == [7]
    assert not (f0.decision == D["moving"]).any()


def test_a_traced_backfill_notes_the_step_that_decided_each_cell() -> None:
    """With ``trace`` each held frame's ``added_by`` names the step that decided a cell
    moving (scripts/trace_false_moving.py reads it): frame 2's candidate cell 24 was filled
    ("candidate"), frames 1 and 0 were led into (cells 23, 33 and 22, 41: "lead"; the same
    cells as test_a_track_is_led_back_before_its_first_association). A cell already decided
    moving before the fill (33 in frame 1) is not the backfill's and is not noted; the
    records and decisions are those of the untraced backfill, whose frames note nothing."""
    f0, f1, f2, f3 = _lead_frames([[22, 41, 55], [23, 33, 53]], trace=True, moving_before=(33,))
    assert f2.added_by == {24: "candidate"}
    assert f1.added_by == {23: "lead"} and f0.added_by == {22: "lead", 41: "lead"}
    assert f3.added_by is None  # the reporting frame: nothing added to it
    plain = _lead_frames([[22, 41, 55], [23, 33, 53]], moving_before=(33,))
    for traced, untraced in zip((f0, f1, f2, f3), plain, strict=True):
        assert untraced.added_by is None
        np.testing.assert_array_equal(traced.decision, untraced.decision)
        assert traced.object_cells.tolist() == untraced.object_cells.tolist()
    assert f1.object_cells.tolist() == [23, 33]


def _bridge_reference(held: HeldFrame, velocity: np.ndarray, known: tuple, reach: int
                      ) -> list[tuple[int, int]]:
    """bridge_cells by the module docstring's words, cell by cell with Python sets."""
    w = held.window
    predicted = set()
    for cells, stamp in known:
        shift = [round(float(x)) for x in  # half to even, as np.rint
                 (np.asarray(velocity, np.float64)[::-1] * (held.stamp_ns - stamp) * 1e-9
                  / w.resolution_m)]
        predicted |= {(int(r) + shift[0], int(c) + shift[1]) for r, c in cells}
    records = {divmod(int(f), w.cols) for f in held.object_cells}
    records = {(r + w.row0, c + w.col0) for r, c in records}

    def inside(r: int, c: int) -> bool:
        return 0 <= r - w.row0 < w.rows and 0 <= c - w.col0 < w.cols

    near = {(r + a, c + b) for r, c in predicted for a in range(-reach, reach + 1)
            for b in range(-reach, reach + 1)}
    found = {(r, c) for r, c in near if inside(r, c) and (r, c) not in records
             and held.occupied[r - w.row0, c - w.col0]}
    if found and held.speaks is not None:
        found |= {(r, c) for r, c in predicted if inside(r, c) and (r, c) not in records
                  and not held.speaks[r - w.row0, c - w.col0]}
    return sorted(found)


def test_bridge_cells_match_a_cell_by_cell_reference() -> None:
    """The compiled bridge_cells against :func:`_bridge_reference` on random frames: one or
    two known ends (some cells carried out of the window), reach 0-2, random occupied,
    spoken and record cells, with and without the scan's layer; and the cases are not
    vacuous (most calls find cells, some find none)."""
    rng = np.random.default_rng(7)
    found = empty = 0
    for trial in range(300):
        w = Window(0.5, int(rng.integers(3, 12)), int(rng.integers(3, 12)), 100, 200)
        decision = np.zeros(w.shape, np.uint8)
        cells = np.flatnonzero(rng.random(w.rows * w.cols) < 0.1).astype(np.uint32)
        held = HeldFrame(w, decision, np.zeros(w.shape, np.uint8), empty_objects(), cells,
                         stamp_ns=1_000_000_000,
                         occupied=rng.random(w.shape) < rng.uniform(0.05, 0.5),
                         speaks=(rng.random(w.shape) < 0.5) if trial % 3 else None)
        known = tuple(
            (np.stack([rng.integers(98, 102 + w.rows, size=n),
                       rng.integers(198, 202 + w.cols, size=n)], axis=1),
             int(rng.integers(0, 2_000_000_000)))
            for n in rng.integers(1, 6, size=int(rng.integers(1, 3))))
        velocity = rng.uniform(-2.0, 2.0, size=2)
        reach = int(rng.integers(0, 3))
        got = bridge_cells(held, velocity, known, reach)
        want = _bridge_reference(held, velocity, known, reach)
        assert [tuple(x) for x in got.tolist()] == want, trial
        found += bool(want)
        empty += not want
    assert found > 150 and empty > 10


def test_gaps_not_bounded_by_a_moving_record_are_not_bridged() -> None:
    """Nothing is bridged when the record before the gap is stopped, when the bridge is off
    (reach -1), when the record before the gap was released already (lag 1), or into a
    frame whose occupied cells are unknown; reach 0 keeps the predicted cell only."""
    for state, reach in ((OBJECT_STATES["stopped"], 1), (MOVING, -1)):
        backfill, frames = _gap_frames(state, reach)
        for f in frames:
            backfill.push(f)
        assert frames[1].added == [] and not (frames[1].decision == D["moving"]).any()
    backfill, frames = _gap_frames()
    backfill.frames = 1
    for f in frames:
        backfill.push(f)
    assert frames[1].added == []
    backfill, frames = _gap_frames()
    frames[1].occupied = None
    for f in frames:
        backfill.push(f)
    assert frames[1].added == []
    backfill, frames = _gap_frames(reach=0)
    for f in frames:
        backfill.push(f)
    assert frames[1].object_cells.tolist() == [23, 12]


def test_a_fragment_beside_a_moving_record_joins_it() -> None:
    """Gap 2 cells, extent 3 m: track 5's cells two cells from track 3's moving record join
    it (track 3's id, age and velocity kept, its geometry recomputed over the union); a
    candidate three cells away, or one whose joined box would pass 3 m, is a record of its
    own."""
    existing = _record(3, cells=2, velocity=(2.0, 0.0))
    existing["age_frames"] = 9
    existing["bbox_m"] = [100.5, 50.5, 101.5, 51.0]  # its cells (101, 201), (101, 202)
    backfill = Backfill(1, gap_cells=2, extent_m=3.0)
    f0 = _frame({5: ([[101, 204]], 1), 6: ([[105, 205]], 1)}, objects=existing,
                cells=np.array([11, 12], np.uint32))  # (1, 1), (1, 2) of the window
    backfill.push(f0)
    backfill.push(_frame({}, objects=np.concatenate([_record(5), _record(6)]),
                         cells=np.array([1, 2], np.uint32)))
    assert f0.objects["track_id"].tolist() == [3, 6] and f0.added == [6]
    joined = f0.objects[0]
    assert (joined["cell_count"], joined["age_frames"]) == (3, 9)
    np.testing.assert_allclose(joined["velocity_m_per_s"], [2.0, 0.0])
    assert f0.object_cells[:3].tolist() == [11, 12, 14]
    # cells (1, 1), (1, 2), (1, 4): x = 200 + cols + 0.5, mean col 2.333
    np.testing.assert_allclose(joined["centroid_m"], [(200 + 7 / 3 + 0.5) * 0.5, 50.75])
    np.testing.assert_allclose(joined["bbox_m"], [100.5, 50.5, 102.5, 51.0])
    assert np.flatnonzero(f0.decision.reshape(-1) == D["moving"]).tolist() == [14, 55]
    far = Backfill(1, gap_cells=2, extent_m=3.0)
    f1 = _frame({5: ([[101, 205]], 1)}, objects=existing.copy(),  # three cells away
                cells=np.array([11, 12], np.uint32))
    far.push(f1)
    far.push(_frame({}, objects=_record(5), cells=np.array([1], np.uint32)))
    assert f1.objects["track_id"].tolist() == [3, 5]
    long = Backfill(1, gap_cells=2, extent_m=1.5)  # joined box 2 m > 1.5 m
    f2 = _frame({5: ([[101, 204]], 1)}, objects=existing.copy(),
                cells=np.array([11, 12], np.uint32))
    long.push(f2)
    long.push(_frame({}, objects=_record(5), cells=np.array([1], np.uint32)))
    assert f2.objects["track_id"].tolist() == [3, 5]


def test_stopped_reports_and_frames_beyond_the_lag_are_not_filled() -> None:
    """A track reported ``stopped`` fills nothing; a frame already released (older than the
    lag) is not filled by a later report."""
    backfill = Backfill(1)
    f0 = _frame({4: ([[102, 202]], 1)})
    f1 = _frame({4: ([[102, 203]], 2)})
    backfill.push(f0)
    assert backfill.push(f1) == [f0]
    stopped = _frame({}, objects=_record(4, state=OBJECT_STATES["stopped"]),
                     cells=np.array([1], np.uint32))
    assert backfill.push(stopped) == [f1]
    assert len(f1.objects) == 0 and not (f1.decision == D["moving"]).any()
    moving = _frame({}, objects=_record(4), cells=np.array([2], np.uint32))
    backfill.push(moving)  # fills `stopped` (no candidate there), not f0 / f1
    assert len(f0.objects) == len(f1.objects) == 0


def test_candidates_are_the_associated_unreported_tracks() -> None:
    """Rows with ``missed == 0`` (associated in this frame) and cells, not in the records;
    their cells are their slice of the pooled ``fp``."""
    state = TrackerState()
    state.id = np.array([3, 4, 5, 6])
    state.missed = np.array([0, 0, 1, 0])
    state.hits = np.array([2, 5, 4, 1])
    state.fp_n = np.array([2, 1, 3, 0])
    state.fp = np.arange(12, dtype=np.int64).reshape(6, 2)
    got = candidates(state, _record(4))
    assert got.ids.tolist() == [3] and 3 in got and 4 not in got and 5 not in got
    cells, age = got.pop(3)
    assert cells.tolist() == [[0, 1], [2, 3]] and age == 2
    assert got.pop(3) is None and 3 not in got  # taken once
    assert len(candidates(TrackerState(), empty_objects()).ids) == 0


def test_candidates_match_numpy_on_random_tracks() -> None:
    """The compiled pass against the numpy expressions it replaced (kept here as the
    oracle): random tracker states and record id sets, ids ascending on both sides."""
    rng = np.random.default_rng(21)
    for _ in range(200):
        n = int(rng.integers(0, 12))
        state = TrackerState()
        state.id = np.sort(rng.choice(40, n, replace=False)).astype(np.int64) + 1
        state.missed = rng.integers(0, 3, n).astype(np.int64)
        state.hits = rng.integers(1, 30, n).astype(np.int64)
        state.fp_n = rng.integers(0, 4, n).astype(np.int64)
        state.fp = rng.integers(-50, 50, (int(state.fp_n.sum()), 2)).astype(np.int64)
        reported = np.sort(rng.choice(45, int(rng.integers(0, 8)), replace=False)) + 1
        records = np.zeros(len(reported), OBJECT_DTYPE)
        records["track_id"] = reported
        keep = (state.missed == 0) & (state.fp_n > 0) & ~np.isin(state.id, reported)
        starts = np.cumsum(state.fp_n) - state.fp_n
        got = candidates(state, records)
        np.testing.assert_array_equal(got.ids, state.id[keep])
        np.testing.assert_array_equal(got.starts, starts[keep])
        np.testing.assert_array_equal(got.counts, state.fp_n[keep])
        np.testing.assert_array_equal(got.ages, state.hits[keep])
        assert got.cells is state.fp


def test_the_key_is_off_without_objects_and_checked(tmp_path: Path) -> None:
    assert backfill_frames(load_config()) == 6  # the default (docs/method.md §8 step 8)
    assert backfill_frames(load_config(overrides={"objects.backfill_frames": 0})) == 0
    assert backfill_frames(load_config(overrides={"objects.backfill_frames": 6})) == 6
    assert backfill_frames(load_config(overrides={"objects.enabled": False,
                                                  "objects.backfill_frames": 6})) == 0
    with pytest.raises(ConfigError, match="backfill_frames"):
        load_config(overrides={"objects.backfill_frames": -1})
    # the gaps: on with reach 0 by default (docs/method.md §8 step 8, "Gaps"), off is -1
    assert Backfill.from_config(load_config()).bridge_reach == 0
    assert Backfill.from_config(load_config(overrides={"objects.bridge_gaps": False})
                                ).bridge_reach == -1
    assert Backfill.from_config(load_config(overrides={"objects.bridge_reach_cells": 2})
                                ).bridge_reach == 2
    with pytest.raises(ConfigError, match="bridge_reach_cells"):
        load_config(overrides={"objects.bridge_reach_cells": -1})
    # the lead: 6 frames, reach 1 by default (docs/method.md §8 step 8, "Lead")
    led = Backfill.from_config(load_config())
    assert (led.lead_frames, led.lead_reach) == (6, 1)
    assert Backfill.from_config(load_config(overrides={"objects.lead_frames": 0})
                                ).lead_frames == 0
    with pytest.raises(ConfigError, match="lead_reach_cells"):
        load_config(overrides={"objects.lead_reach_cells": -1})
    bad = tmp_path / "bad.toml"  # a user's file: typed (overrides are the tests' own)
    bad.write_text("[objects]\nbridge_gaps = 1\n")
    with pytest.raises(ConfigError, match="bridge_gaps must be bool"):
        load_config(bad)


@pytest.fixture(scope="module")
def sample_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[int | str, list]:
    """The sample drive (8 s, with its map) causal and with lags 3 and 6; chunks of 7
    frames, a checkpoint at each chunk end (the backfill's snapshots taken); -6: lag 6 with
    the chunks stored uncompressed (the writer cannot hold slots: the held frames' own
    buffers are copied into its slot); "no_lead": lag 6 without objects.lead_frames;
    "no_bridge": lag 6 without objects.bridge_gaps nor the lead. Without the small groups'
    support (objects.small_support_frames), which reads as many frames ahead as the lag
    allows (tests/objects/test_support.py): here the lag changes the records only."""
    root = Path(__file__).resolve().parents[2] / "sample_data"
    tmp = tmp_path_factory.mktemp("backfill")
    frames: dict[int | str, list] = {}
    for lag, compress in ((0, True), (3, True), (6, True), (-6, False), ("no_bridge", True),
                          ("no_lead", True)):
        config = load_config(overrides={"objects.backfill_frames": 6 if isinstance(lag, str)
                                        else abs(lag),
                                        "objects.bridge_gaps": lag != "no_bridge",
                                        "objects.lead_frames": 0 if isinstance(lag, str) else 6,
                                        "output.chunk_frames": 7,
                                        "output.checkpoint_frames": 1,
                                        "output.compress": compress,
                                        "objects.small_support_frames": 0})
        out = tmp / f"lag{lag}"
        run(RunRequest(log_path=root / "drive.mcap", out_dir=out, config=config,
                       map_path=root / "map.geojson", end_s=8.0), progress=False)
        frames[lag] = list(evperc.load(out).frames)
    return frames


def _moving_ids(frames: list) -> list[set[int]]:
    """The track ids each frame reports moving."""
    return [set(f.objects["track_id"][f.objects["state"] == MOVING].tolist()) for f in frames]


def _records_kept(a, b) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frame ``b`` against ``a`` (the same scan, fewer records filled in): the layers other
    than the decision are equal and every record of ``a`` is in ``b`` (same track, state,
    age, velocity) on a superset of its cells. Returns both frames' object labels and the
    records ``b`` adds."""
    for layer in ("masses", "betp", "conflict", "zeta"):
        np.testing.assert_array_equal(getattr(a, layer), getattr(b, layer))
    la, lb = a.object_labels(), b.object_labels()
    kept = np.isin(b.objects["track_id"], a.objects["track_id"])
    assert kept.sum() == len(a.objects)
    for ra, rb in zip(a.objects, b.objects[kept], strict=True):
        for name in ("track_id", "state", "age_frames", "velocity_m_per_s"):
            np.testing.assert_array_equal(ra[name], rb[name])
        assert (lb[la == ra["track_id"]] == ra["track_id"]).all()  # cells kept
    return la, lb, b.objects[~kept]


@pytest.mark.parametrize("lag", [3, 6])
def test_a_run_with_the_backfill_adds_only_what_the_rule_allows(
        sample_runs: dict[int | str, list], lag: int) -> None:
    """Against the causal run, frame by frame: the layers other than the decision are equal;
    every record of the causal frame is kept (same track, state, age, velocity) on a
    superset of its cells (a fragment joined); each added record is a track absent from
    the causal frame and reported moving by the causal run in one of the next ``lag``
    frames; the decision differs only on cells the lagged frame's moving records hold and
    the causal one's do not, now ``moving``; and the backfill added something (the sample
    drive's agents are confirmed over 3+ frames)."""
    causal, lagged = sample_runs[0], sample_runs[lag]
    assert len(causal) == len(lagged) > 50
    moving_ids = _moving_ids(causal)
    added_total = 0
    for k, (a, b) in enumerate(zip(causal, lagged, strict=True)):
        la, lb, added = _records_kept(a, b)
        later = set().union(*moving_ids[k + 1:k + 1 + lag])
        assert set(added["track_id"].tolist()) <= later
        assert (added["state"] == MOVING).all()
        moving_b = np.isin(lb, b.objects["track_id"][b.objects["state"] == MOVING]) & (lb > 0)
        new_cells = moving_b & (la == 0)
        changed = a.decision != b.decision
        assert not (changed & ~new_cells).any()
        assert (b.decision[new_cells] == D["moving"]).all()
        assert (lb[(la == 0) & (lb > 0)] > 0).all()
        assert not ((la == 0) & (lb > 0) & ~moving_b).any()  # only moving records grow
        for r in b.objects:
            assert (lb == r["track_id"]).sum() == r["cell_count"] > 0
        added_total += len(added)
    assert added_total > 0
    counts_a = sum(np.bincount(f.decision.ravel(), minlength=8) for f in causal)
    counts_b = sum(np.bincount(f.decision.ravel(), minlength=8) for f in lagged)
    assert counts_b[D["moving"]] > counts_a[D["moving"]]


def test_the_bridged_gaps_of_a_run_are_bounded_by_moving_records(
        sample_runs: dict[int | str, list]) -> None:
    """Lag 6 with and without objects.bridge_gaps (both without the lead: a frame before
    a track's first record that the lead fills may lie in a gap once the gaps are
    bridged), frame by frame: the layers other than the
    decision are equal; every record without the bridge is kept (same track, state, age,
    velocity, cells a superset: a bridged fragment may join it); each added record is a
    moving track absent from that frame without the bridge and holding a moving record in
    an earlier and in a later frame within the lag (the gap between them); the decision
    changes only on the added moving cells, to moving; and the sample drive has such gaps."""
    plain, bridged = sample_runs["no_bridge"], sample_runs["no_lead"]
    assert len(plain) == len(bridged) > 50
    moving_ids = _moving_ids(plain)
    added_total = 0
    for k, (a, b) in enumerate(zip(plain, bridged, strict=True)):
        la, lb, added = _records_kept(a, b)
        assert (added["state"] == MOVING).all()
        before = set().union(*moving_ids[max(k - 6, 0):k])
        after = set().union(*moving_ids[k + 1:k + 7])
        assert set(added["track_id"].tolist()) <= before & after
        new_cells = (la == 0) & (lb > 0)
        assert not ((a.decision != b.decision) & ~new_cells).any()
        assert (b.decision[new_cells] == D["moving"]).all()
        added_total += len(added)
    assert added_total > 0


def test_the_leads_of_a_run_come_before_the_tracks_first_association(
        sample_runs: dict[int | str, list]) -> None:
    """Lag 6 with and without objects.lead_frames, frame by frame: the layers other than the
    decision are equal; every record without the lead is kept; each added record is a
    moving track with no record in this frame or any before it without the lead, whose
    first record comes within the next 6 frames and which is reported moving in one of
    them; the decision changes only on the added moving cells, to moving; and the sample
    drive has such leads."""
    plain, led = sample_runs["no_lead"], sample_runs[6]
    assert len(plain) == len(led) > 50
    moving_ids = _moving_ids(plain)
    recorded = [set(f.objects["track_id"].tolist()) for f in plain]
    first = {}
    for k, ids in enumerate(recorded):
        for t in ids:
            first.setdefault(t, k)
    added_total = 0
    for k, (a, b) in enumerate(zip(plain, led, strict=True)):
        la, lb, added = _records_kept(a, b)
        assert (added["state"] == MOVING).all()
        for t in added["track_id"].tolist():
            assert k < first[t] <= k + 6
            assert t in set().union(*moving_ids[k + 1:k + 7])
        new_cells = (la == 0) & (lb > 0)
        assert not ((a.decision != b.decision) & ~new_cells).any()
        assert (b.decision[new_cells] == D["moving"]).all()
        added_total += len(added)
    assert added_total > 0


def test_the_writer_holds_frames_and_commits_them_in_order(tmp_path: Path) -> None:
    """RunWriter.hold(): a fused frame's decision and betP(M) copied out (the ring slot is
    refilled by the next frames before the held ones are committed: the ring has 4 slots,
    6 frames are held here), its other layers deflated at once; the decision changed while
    held is the one stored, every other layer the slot's at hold time, and frames committed
    plainly after held ones keep their order. Read back with numpy alone (np.load)."""
    from evperc.output.writer import RING_SLOTS, RunWriter

    config = load_config(overrides={"output.chunk_frames": 4})
    meta = {"rows": 4, "cols": 5, "decision_codes": D}
    writer = RunWriter(tmp_path / "w", config, meta)
    if not writer.can_hold:
        pytest.skip("this zipfile cannot deflate frame by frame (chunks deflated whole)")
    rng = np.random.default_rng(7)
    expected, held = [], []
    n_held = RING_SLOTS + 2
    for k in range(n_held + 3):
        slot = writer.frame_slot()
        runs = rng.integers(0, 256, 3 + k, dtype=np.uint8)
        slot.mass_runs[:runs.size] = runs
        slot.mass_length[0] = runs.size
        slot.tile_masks[...] = rng.integers(0, 2**32, slot.tile_masks.shape, dtype=np.uint32)
        for layer in (slot.betp, slot.conflict, slot.zeta):
            layer[...] = rng.integers(0, 256, layer.shape, dtype=np.uint8)
        slot.decision[...] = rng.integers(0, len(D), slot.decision.shape, dtype=np.uint8)
        frame = {"runs": runs.copy(), **{name: getattr(slot, name).copy() for name in
                                        ("tile_masks", "betp", "conflict", "zeta", "decision")}}
        if k < n_held:
            h = writer.hold()
            np.testing.assert_array_equal(h.betp_moving, frame["betp"][4])
            np.testing.assert_array_equal(h.decision, frame["decision"])
            changed = (h.decision[0, 0] + 1) % len(D)  # changed while held (the fills)
            h.decision[0, 0] = changed
            frame["decision"][0, 0] = changed
            held.append(h)
        else:
            if held:  # the held frames first, oldest first
                for k_held, h in enumerate(held):
                    writer.commit_frame(stamp_ns=k_held, pose=np.zeros(3), origin=(0, 0),
                                        held=h)
                held = []
            writer.commit_frame(stamp_ns=k, pose=np.zeros(3), origin=(0, 0))
        expected.append(frame)
    writer.close({"frames": len(expected)})
    chunks = [np.load(p) for p in sorted((tmp_path / "w" / "frames").glob("chunk_*.npz"))]
    assert np.concatenate([c["stamp_ns"] for c in chunks]).tolist() == list(range(len(expected)))
    runs = np.concatenate([c["mass_runs"] for c in chunks])
    np.testing.assert_array_equal(runs, np.concatenate([f["runs"] for f in expected]))
    assert np.concatenate([c["mass_bytes"] for c in chunks]).tolist() == [
        f["runs"].size for f in expected]
    assert not any("betp" in c.files for c in chunks)  # a reader derives it from the masses
    for name in ("tile_masks", "conflict", "zeta", "decision"):
        stored = np.concatenate([c[name] for c in chunks])
        np.testing.assert_array_equal(stored, np.stack([f[name] for f in expected]), name)
    counts = np.concatenate([c["decision_counts"] for c in chunks])
    for f, count in zip(expected, counts, strict=True):
        assert count.tolist() == np.bincount(f["decision"].ravel(),
                                             minlength=counts.shape[1]).tolist()


def test_held_in_the_writer_or_copied_the_frames_are_the_same(
        sample_runs: dict[int | str, list]) -> None:
    held, copied = sample_runs[6], sample_runs[-6]
    assert len(held) == len(copied)
    for a, b in zip(held, copied, strict=True):
        for layer in ("masses", "betp", "conflict", "zeta", "decision"):
            np.testing.assert_array_equal(getattr(a, layer), getattr(b, layer))
        assert a.objects.tobytes() == b.objects.tobytes()
        np.testing.assert_array_equal(a.object_cells, b.object_cells)


def test_a_filled_vehicle_gets_its_box_when_the_frame_leaves() -> None:
    """Lag 1, vehicle boxes on (evperc/objects/boxes.py): track 7 is a candidate in frame 0
    with a car's rear face (window rows 13-16 at column 20: centres x 10.25, y 6.75-8.25),
    reported moving at (5, 0) m/s in frame 1. Frame 0 leaves with its record completed to
    the box: along u = x from 10.25 to 10.25 + 4.4 = 14.65 (columns 20-28; the sensor,
    the window's centre (7.75, 7.75), lies behind the face); across, the face's 1.5 m grows
    to 1.8 m away from the sensor (y ≥ 6.45: rows 13-16 still). Without boxes: the face.
    Traced, the face's cells are the candidate's and the rest of the box the box's."""
    from evperc.objects.boxes import BoxParams
    window = Window(0.5, 30, 30, 0, 0)
    silent = (np.zeros(window.shape, np.float32), np.zeros(window.shape, np.float32))
    face = [[r, 20] for r in range(13, 17)]
    got = {}
    for name, boxes in (("boxes", BoxParams(4.4, 1.8, 3.0, 1.0)), ("none", None)):
        backfill = Backfill(1, boxes=boxes, trace=True)
        f0 = HeldFrame(window, np.full(window.shape, D["free"], np.uint8),
                       np.zeros(window.shape, np.uint8), empty_objects(),
                       np.zeros(0, np.uint32),
                       Candidates.from_dict({7: (np.array(face, np.int64), 3)}),
                       speaks=silent)
        f1 = HeldFrame(window, np.full(window.shape, D["free"], np.uint8),
                       np.zeros(window.shape, np.uint8),
                       _record(7, cells=1, velocity=(5.0, 0.0)),
                       np.array([13 * 30 + 21], np.uint32), speaks=silent)
        assert backfill.push(f0) == []
        assert backfill.push(f1) == [f0]
        (record,) = f0.objects
        cells = {divmod(int(c), 30) for c in f0.object_cells}
        assert record["cell_count"] == len(cells)
        assert {divmod(int(c), 30) for c in np.flatnonzero(
            f0.decision.reshape(-1) == D["moving"])} == cells
        got[name] = cells
        assert {divmod(q, 30): step for q, step in f0.added_by.items()} == {
            cell: "candidate" if cell[1] == 20 else "box" for cell in cells}
    assert got["none"] == {(r, 20) for r in range(13, 17)}
    assert got["boxes"] == {(r, c) for r in range(13, 17) for c in range(20, 29)}
