"""The object list's fixed-lag backfill (``objects.backfill_frames`` = L; docs/method.md §8
step 8): a frame is handed to the output L frames after it was fused, and a track reported
``moving`` now is also reported ``moving`` in the held frames in which it was associated with
a cluster but not yet reported — the frames it spent being confirmed (``confirm_frames``),
passing the velocity test and gathering the grid's motion evidence.

Why: a track is reported only after ``confirm_frames`` associations, a velocity fit over
them and ``motion_evidence_frames`` frames of evidence, so the first frames of every moving
object are missed by construction (on the tuning drives, 557 of hdl64's 843 missed
agent-frames and 179 of ibeo4's 582: ``scripts/trace_missed.py``). A log is processed after
the fact: what is known at frame t + L about frame t may be written into frame t, as a
fixed-lag smoother does. The output of frame t then depends on the scans up to t + L (0: the
causal output, each frame from the scans up to itself).

Per held frame, the candidates are the tracks associated in it and not reported in it
(their cells: the tracker's footprint of that association, :attr:`TrackerState.fp`). When a
later frame (within L) reports a candidate ``moving``, the held frame gets a record for it —
its cells there, their centroid, box and mean betP(M), its age then, and the velocity of the
report — and its cells are decided ``moving`` (a decision, like the fill: the masses are not
changed). A candidate is filled once; a track reported ``stopped`` in the held frame is not
a candidate (it moved before and stood there). With the vehicle boxes on
(``objects.box_length_m``, :mod:`evperc.objects.boxes`), a frame leaving the backfill gets
the boxes of the records added to it, as its own moving records got theirs when it was
fused (the added records' velocity is the later report's).

**Gaps** (``objects.bridge_gaps``, reach ``objects.bridge_reach_cells`` = ρ; ours): a track
reported moving now that was not reported moving in the frame before may have gone without a
cluster for a few frames in between (the tracker coasts through up to
``max_missed_frames``): its cluster fell under the minimum size, or merged with a neighbour's.
Walking the held frames from the newest, each run of frames without a record of the track
between two frames that hold a ``moving`` record of it (reported then, or filled just now;
the newest end may be the report itself) is a gap, and each of its frames k gets the
track's cells predicted there from both ends at constant velocity v (the report's),

    P_k = { c + ⌊v (t_k − t_q) / r⌉ : c ∈ C_q } ∪ { c + ⌊v (t_k − t_p) / r⌉ : c ∈ C_p },

with p < k < q the gap's two ends, and its record is the cells *occupied now* in frame k
(holding a return of its scan, the clusters' input) within Chebyshev distance ρ of P_k and,
if there are any, the cells of P_k its scan is silent about (neither seen free nor holding a
return: occluded, as the footprint completion fills them), none in another record of frame
k; they are decided ``moving`` as a fill's. A gap that reaches past the held frames, or
ends at a ``stopped`` record, is not bridged; a frame with no occupied cell near P_k gets
nothing (nothing says the object is there).

**Lead** (``objects.lead_frames`` = N, reach ``objects.lead_reach_cells`` = ρ_l; ours): the
held frames before the newly reported track's first association (its oldest record there,
reported or filled, in frame q) are walked back from q, at most N of them: each frame k gets
the cells predicted from the next newer frame that holds the track's record,

    P_k = { c + ⌊v (t_k − t_q) / r⌉ : c ∈ C_q },

its record as a gap frame's (the cells occupied now within ρ_l of P_k, with the silent
predicted cells if any; age 0: the track did not exist yet), and that record is the next
frame's C_q. The walk stops at the first frame with no occupied cell near P_k and at the
held frames' end. Why: a person's first steps
are clusters of one or two cells, under the clusters' minimum size, so the track starts
late and its candidates begin there; its cells before are where its velocity, run back,
puts it (docs/method.md §8 step 8).

**Candidate window** (``objects.backfill_candidate_frames`` = K; ours, -1 = L): a report fills
its track's candidates only in the K held frames just before it; the gaps and the lead reach
all L. With a longer lag the lead goes further back on a person's velocity while a track's
older candidates — associated long before it moved, or before a false report — stay unfilled
(docs/evaluation.md § Since 2026-12-06, sixth session)."""

from __future__ import annotations

import bisect
import itertools
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np

from evperc.fusion.twin import DECISION_CODES
from evperc.geo.window import Window
from evperc.gil_kept import in_sorted, sorted_copy, sorted_unique
from evperc.objects.boxes import BoxParams, VehicleBoxes, flat_layer
from evperc.objects.stage import fills_decision, objects_enabled
from evperc.objects.tracking import TrackerState, window_indices
from evperc.output.objects import OBJECT_DTYPE, OBJECT_STATES

MOVING = DECISION_CODES["moving"]
_STATE_MOVING = OBJECT_STATES["moving"]


def backfill_frames(config: dict[str, Any]) -> int:
    """``objects.backfill_frames`` (0: off, and without the object stage)."""
    if not objects_enabled(config):
        return 0
    return int(config["objects"].get("backfill_frames", 0))


@dataclass
class HeldFrame:
    """A fused frame not yet handed to the output. ``decision`` (uint8 codes) and
    ``betp_moving`` (uint8, ×255) are the frame's own arrays (the decision is changed in
    place); ``objects`` / ``object_cells`` are replaced when a record is added; ``payload``
    is whatever the caller hands on at release."""

    window: Window
    decision: np.ndarray
    betp_moving: np.ndarray
    objects: np.ndarray
    object_cells: np.ndarray
    #: the tracks it may get (:func:`candidates`), each taken once
    candidates: Candidates = field(default_factory=lambda: Candidates.from_dict({}))
    payload: Any = None
    #: the track ids the backfill added, in the order added
    added: list[int] = field(default_factory=list)
    #: the frame's time (ns) and its cells occupied now (window-shaped, nonzero: the
    #: clusters' input), for the gaps (module docstring); None: no gap is bridged into it
    stamp_ns: int = 0
    occupied: np.ndarray | None = None
    #: the cells its scan speaks of (seen free or holding a return): a bool layer (the
    #: runner's, :func:`evperc.objects.stage.scan_cells`) or the sensor grid's (m({F}),
    #: m({O})); None: a gap's record is its occupied cells only
    speaks: np.ndarray | tuple[np.ndarray, np.ndarray] | None = None
    #: > 0 (or True) where the cell holds any obstacle return of its scan (the runner's: a
    #: bool layer, the sensor grid's heights > 0), for the vehicle boxes of the added
    #: records; None: the first returns only
    returns: np.ndarray | None = None
    #: with :attr:`Backfill.trace`: which of the backfill's steps decided each cell
    #: ``moving`` that was not before (flat window cell -> "candidate", "gap", "lead" or
    #: "box"; the first step wins), for scripts/trace_false_moving.py; None: not kept
    added_by: dict[int, str] | None = None


class Candidates:
    """A held frame's candidates: tracks (ids ascending) with their cells of the frame's
    association (global lattice (iy, ix)) and age; each may be taken once (:meth:`pop`)."""

    def __init__(self, ids: np.ndarray, starts: np.ndarray, counts: np.ndarray,
                 cells: np.ndarray, ages: np.ndarray) -> None:
        self.ids, self.starts, self.counts = ids, starts, counts
        self.cells, self.ages = cells, ages
        self.taken = np.zeros(len(ids), np.bool_)

    def _find(self, track: int) -> int:
        k = bisect.bisect_left(self.ids, track)  # not np.searchsorted: keeps the GIL
        return k if k < len(self.ids) and self.ids[k] == track and not self.taken[k] else -1

    def __contains__(self, track: int) -> bool:
        return self._find(track) >= 0

    @staticmethod
    def from_dict(tracks: dict[int, tuple[np.ndarray, int]]) -> Candidates:
        """From track id -> (cells (n, 2), age)."""
        ids = sorted(tracks)
        counts = np.array([len(tracks[t][0]) for t in ids], np.int64)
        cells = (np.concatenate([np.asarray(tracks[t][0], np.int64).reshape(-1, 2)
                                 for t in ids]) if ids else np.zeros((0, 2), np.int64))
        return Candidates(np.array(ids, np.int64), np.cumsum(counts) - counts, counts, cells,
                          np.array([tracks[t][1] for t in ids], np.int64))

    def matching(self, tracks: np.ndarray) -> np.ndarray:
        """The indices of the candidates not yet taken whose ids are in ``tracks``
        (ascending: a frame's record ids)."""
        return np.flatnonzero(_in_sorted(self.ids, tracks) & ~self.taken)

    def pop(self, track: int, default: Any = None) -> Any:
        """(cells, age) of ``track``, taken (``default`` if not a candidate or taken)."""
        k = self._find(track)
        if k < 0:
            return default
        self.taken[k] = True
        a = int(self.starts[k])
        return self.cells[a:a + int(self.counts[k])], int(self.ages[k])


def candidates(state: TrackerState, objects: np.ndarray) -> Candidates:
    """The tracks of ``state`` (just stepped) associated in this frame and absent from its
    reported ``objects``, with their cells of this association (global lattice) and age."""
    ids, starts, counts, ages = _candidate_rows(
        state.id, state.missed, state.fp_n, state.hits,
        objects["track_id"].astype(np.int64))  # records: id order
    # the tracker replaces its arrays at each step, never writes into them: no copy
    return Candidates(ids, starts, counts, state.fp, ages)


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _candidate_rows(ids, missed, fp_n, hits, reported):  # pragma: no cover - compiled
    """:func:`candidates`' rows in one pass over the tracks (ids ascending, as ``reported``):
    each kept track's id, the start of its cells in the tracker's ``fp`` (the running sum
    of ``fp_n``), their count and its hits — where numpy took ~15 calls (0.04 ms a frame of
    workload (a))."""
    rows = np.empty((4, ids.shape[0]), np.int64)  # id, start, count, hits of the kept
    start, r, k = 0, 0, 0
    for i in range(ids.shape[0]):
        while r < reported.shape[0] and reported[r] < ids[i]:
            r += 1
        if missed[i] == 0 and fp_n[i] > 0 and not (r < reported.shape[0]
                                                   and reported[r] == ids[i]):
            rows[0, k], rows[1, k], rows[2, k], rows[3, k] = ids[i], start, fp_n[i], hits[i]
            k += 1
        start += fp_n[i]
    return rows[0, :k].copy(), rows[1, :k].copy(), rows[2, :k].copy(), rows[3, :k].copy()


def _in_sorted(values: np.ndarray, ascending: np.ndarray) -> np.ndarray:
    """Which of ``values`` are in ``ascending`` (sorted; :func:`evperc.gil_kept.in_sorted`,
    which keeps the GIL)."""
    return in_sorted(np.ascontiguousarray(values, np.int64),
                     np.ascontiguousarray(ascending, np.int64))


class Backfill:
    """Holds the last ``frames`` frames (:meth:`push`) and fills them (module docstring)."""

    def __init__(self, frames: int, gap_cells: int = 0, extent_m: float = np.inf,
                 fill_decision: bool = True, bridge_reach: int = -1,
                 boxes: BoxParams | None = None, lead_frames: int = 0,
                 lead_reach: int = 0, candidate_frames: int = -1, trace: bool = False) -> None:
        self.frames = int(frames)
        #: objects.backfill_candidate_frames: a report fills its track's candidates in at
        #: most this many held frames before it (-1: every held frame)
        self.candidate_frames = self.frames if candidate_frames < 0 else int(candidate_frames)
        #: objects.lead_frames, objects.lead_reach_cells (module docstring, "Lead"); 0: off
        self.lead_frames = int(lead_frames)
        self.lead_reach = int(lead_reach)
        #: objects.box_length_m ...: the added moving vehicles get their boxes at release
        #: (:mod:`evperc.objects.boxes`), as the frame's own did
        self.boxes = VehicleBoxes(boxes) if boxes is not None and boxes.enabled else None
        #: objects.bridge_reach_cells with objects.bridge_gaps (module docstring); -1: off
        self.bridge_reach = int(bridge_reach)
        #: objects.fill_moving: the added records' cells are decided moving
        self.fill_decision = bool(fill_decision)
        #: objects.fragment_gap_cells: a candidate this close to a moving record joins it ...
        self.gap_cells = int(gap_cells)
        #: objects.fragment_extent_m: ... unless their joined box is longer along x or y
        self.extent_m = float(extent_m)
        self.held: deque[HeldFrame] = deque()
        #: note in each held frame's ``added_by`` which step decided its cells moving
        #: (diagnostics: scripts/trace_false_moving.py); off in a run
        self.trace = bool(trace)
        #: the track ids reported moving by the last frame pushed (their candidates in the
        #: frames held before it were taken then, and it has none: nothing left to fill)
        self.last_moving = np.zeros(0, np.int64)

    @staticmethod
    def from_config(config: dict[str, Any]) -> Backfill:
        o = config["objects"]
        reach = int(o.get("bridge_reach_cells", 0)) if o.get("bridge_gaps", False) else -1
        return Backfill(backfill_frames(config), int(o.get("fragment_gap_cells", 0)),
                        float(o.get("fragment_extent_m", np.inf)), fills_decision(config),
                        reach, BoxParams.from_config(config), int(o.get("lead_frames", 0)),
                        int(o.get("lead_reach_cells", 0)),
                        int(o.get("backfill_candidate_frames", -1)))

    def push(self, frame: HeldFrame) -> list[HeldFrame]:
        """Fill the held frames from ``frame``'s moving records, hold ``frame``; returns the
        frames now older than the lag, oldest first (to hand to the output)."""
        moving = frame.objects[frame.objects["state"] == _STATE_MOVING]
        ids = moving["track_id"].astype(np.int64)
        new = ids[~_in_sorted(ids, self.last_moving)]
        self.last_moving = ids
        if len(new) and self.held:
            newest = len(self.held) - min(self.candidate_frames, len(self.held))
            for held in itertools.islice(self.held, newest, None):
                for k in held.candidates.matching(new):
                    track = int(held.candidates.ids[k])
                    cells, age = held.candidates.pop(track)
                    self._note(held, cells, "candidate")
                    fill(held, track, cells, age, moving[bisect.bisect_left(ids, track)],
                         self.gap_cells, self.extent_m, self.fill_decision)
            if self.bridge_reach >= 0 or self.lead_frames > 0:
                reported = frame.objects["track_id"].astype(np.int64)
                for k in np.flatnonzero((frame.objects["state"] == _STATE_MOVING)
                                        & _in_sorted(reported, new)):
                    self._bridge(frame, int(k))
        self.held.append(frame)
        released = []
        while len(self.held) > self.frames:
            released.append(self._box_added(self.held.popleft()))
        return released

    def _bridge(self, frame: HeldFrame, k: int) -> None:
        """Bridge the gaps of the track of record ``k`` of ``frame`` (newly reported moving)
        in the held frames, newest first, each between two of its moving records, then lead
        it back into the held frames before its first association (module docstring, "Gaps"
        and "Lead")."""
        report = frame.objects[k]
        track = int(report["track_id"])
        newer = (_record_lattice(frame, k), frame.stamp_ns)
        gap: list[HeldFrame] = []
        for held in reversed(self.held):
            b = _first(np.ascontiguousarray(held.objects["track_id"]), track)
            if b < 0:
                if held.occupied is None:
                    return
                gap.append(held)
                continue
            if held.objects["state"][b] != _STATE_MOVING:
                return
            older = (_record_lattice(held, b), held.stamp_ns)
            for g in gap if self.bridge_reach >= 0 else ():
                cells = bridge_cells(g, report["velocity_m_per_s"], (newer, older),
                                     self.bridge_reach)
                if len(cells):
                    self._note(g, cells, "gap")
                    fill(g, track, cells, int(held.objects["age_frames"][b]), report,
                         self.gap_cells, self.extent_m, self.fill_decision)
            newer, gap = older, []
        for g in gap[:self.lead_frames]:  # before the track's first association
            cells = bridge_cells(g, report["velocity_m_per_s"], (newer,), self.lead_reach)
            if not len(cells):
                return
            self._note(g, cells, "lead")
            fill(g, track, cells, 0, report, self.gap_cells, self.extent_m, self.fill_decision)
            newer = (cells, g.stamp_ns)

    def _note(self, held: HeldFrame, lattice: np.ndarray, step: str) -> None:
        """With :attr:`trace` (and the fill deciding cells), note ``step`` for ``lattice``'s
        cells in ``held.added_by`` before they are filled."""
        if self.trace and self.fill_decision:
            _note(held, lattice, step)

    def flush(self) -> list[HeldFrame]:
        """Every held frame, oldest first (the log's end)."""
        released = [self._box_added(held) for held in self.held]
        self.held.clear()
        return released

    def _box_added(self, held: HeldFrame) -> HeldFrame:
        """``held``, leaving the backfill, with the vehicle boxes of the records added to it
        (their cells decided ``moving`` with the fill): its own records got theirs when it
        was fused."""
        if self.boxes is None or not held.added or held.speaks is None:
            return held
        only = _in_sorted(held.objects["track_id"], np.array(sorted(held.added), np.int64))
        objects, cells = self.boxes.complete(held.objects, held.object_cells, held.window,
                                             held.speaks, held.decision,
                                             returns=held.returns, only=only)
        if objects is not held.objects:
            held.objects, held.object_cells = objects, cells
            if self.fill_decision:
                counts = objects["cell_count"].astype(np.int64)
                ends = np.cumsum(counts)
                flat = held.decision.reshape(-1)
                # int64 indices: numpy's assignment through a uint32 index array (the
                # records' cells) takes its general path, which releases the GIL
                cells64 = np.asarray(cells, np.int64)
                for k in np.flatnonzero(only):
                    box = cells64[ends[k] - counts[k]:ends[k]]
                    if self.trace:
                        _note_flat(held, box, "box")
                    flat[box] = MOVING
        return held


def fill(held: HeldFrame, track: int, lattice: np.ndarray, age: int,
         report: np.ndarray, gap_cells: int = 0, extent_m: float = np.inf,
         fill_decision: bool = True) -> None:
    """Add ``track`` to ``held`` as ``moving`` on its cells ``lattice`` (global (iy, ix)),
    with the velocity of ``report`` (its record in the frame that reported it moving), and
    decide those cells ``moving``. Records stay in track id order. With ``gap_cells`` > 0,
    cells within that many cells (Chebyshev) of a moving record of the frame join that
    record instead (a fragment of an object already reported there, as the fragment merge
    joins them, :func:`evperc.objects.footprint.complete_footprints`), unless the joined cells'
    box is longer than ``extent_m`` along x or y. ``fill_decision`` false
    (``objects.fill_moving = false``): the record only, the decision as it was."""
    w = held.window
    objects = held.objects
    old_cells = np.asarray(held.object_cells)
    span = int(np.floor(extent_m / w.resolution_m + 1e-9)) if gap_cells > 0 else 0
    cells, into, lo, hi = _fill_pass(
        np.asarray(lattice, np.int64), w.row0, w.col0, w.rows, w.cols, w.resolution_m,
        held.decision.reshape(-1), fill_decision, *_fields(objects), old_cells.astype(np.int64),
        track, gap_cells, span)
    if cells.size == 0:
        return
    dtype = old_cells.dtype if old_cells.size else np.uint32
    if into >= 0:  # a fragment: its cells join the record beside it, old_cells[lo:hi]
        joined = sorted_unique(np.concatenate([old_cells[lo:hi].astype(np.int64), cells]))
        record = objects[into:into + 1].copy()
        _set_geometry(record, held, joined)
        objects = objects.copy()
        objects[into] = record[0]
        held.objects = objects
        held.object_cells = np.concatenate([old_cells[:lo], joined.astype(dtype),
                                            old_cells[hi:]])
        return
    at, offset = lo, hi  # the new record's place (records stay in id order), its cells'
    grown = np.empty(len(objects) + 1, OBJECT_DTYPE)  # (concatenating records is slow)
    grown[:at], grown[at + 1:] = objects[:at], objects[at:]
    centroid, box, extent, mean_betp = _geometry_fields(held, cells)
    grown[at] = (track, _STATE_MOVING, cells.size, age, centroid, box, extent,
                 report["velocity_m_per_s"], report["speed_sigma_m_per_s"], mean_betp)
    held.objects = grown
    held.object_cells = np.concatenate([old_cells[:offset], cells.astype(dtype),
                                        old_cells[offset:]])
    held.added.append(track)


def _note(held: HeldFrame, lattice: np.ndarray, step: str) -> None:
    """Note ``step`` in ``held.added_by`` for the cells of ``lattice`` (global (iy, ix))
    in its window not yet decided ``moving`` (:attr:`HeldFrame.added_by`)."""
    _note_flat(held, window_indices(np.asarray(lattice, np.int64).reshape(-1, 2), held.window),
               step)


def _note_flat(held: HeldFrame, flat: np.ndarray, step: str) -> None:
    """:func:`_note` on flat window cells."""
    if held.added_by is None:
        held.added_by = {}
    decision = held.decision.reshape(-1)
    for q in np.asarray(flat, np.int64).tolist():
        if decision[q] != MOVING:
            held.added_by.setdefault(q, step)


def _fields(objects: np.ndarray) -> tuple[np.ndarray, ...]:
    """The records' track ids, states, cell counts and boxes as contiguous arrays: the
    views of a record array's fields are strided and, but for one record, unaligned — a
    compiled pass would compile one version per case."""
    return tuple(np.ascontiguousarray(objects[name])
                 for name in ("track_id", "state", "cell_count", "bbox_m"))


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _fill_pass(lattice, row0, col0, rows, cols, res, decision, fill_decision, ids, states,
               counts, bbox, old_cells, track, gap, span):  # pragma: no cover - compiled
    """:func:`fill`'s arithmetic in one pass: the flat window cells of ``lattice`` (global
    (iy, ix) rows; those outside the window dropped, the rest in their order), decided
    ``moving`` with ``fill_decision``; then, if there are any, ``(cells, into, a, b)`` with
    ``into`` the record they join (:func:`_touching_pass`, with ``gap`` > 0) and its cells
    ``old_cells[a:b]``, or ``(cells, -1, at, offset)``: the new record's index in the
    records (by ``ids``, ascending) and its cells' offset."""
    out = np.empty(lattice.shape[0], np.int64)
    n = 0
    for i in range(lattice.shape[0]):
        r = lattice[i, 0] - row0
        c = lattice[i, 1] - col0
        if 0 <= r < rows and 0 <= c < cols:
            out[n] = r * cols + c
            n += 1
    cells = out[:n]
    if n == 0:
        return cells, -1, 0, 0
    if fill_decision:
        for q in cells:
            decision[q] = MOVING
    ends = np.cumsum(counts.astype(np.int64))
    if gap > 0 and ids.shape[0] > 0:
        box = np.empty((ids.shape[0], 4), np.int64)  # outer edges, cells, inclusive, window
        for k in range(ids.shape[0]):
            box[k, 0] = np.int64(np.rint(bbox[k, 0] / res)) - col0
            box[k, 1] = np.int64(np.rint(bbox[k, 1] / res)) - row0
            box[k, 2] = np.int64(np.rint(bbox[k, 2] / res)) - (col0 + 1)
            box[k, 3] = np.int64(np.rint(bbox[k, 3] / res)) - (row0 + 1)
        into = _touching_pass(box, states == _STATE_MOVING, old_cells, ends,
                              counts.astype(np.int64), cells // cols, cells % cols, gap, span,
                              cols)
        if into >= 0:
            return cells, into, ends[into] - counts[into], ends[into]
    at = 0
    while at < ids.shape[0] and ids[at] < track:
        at += 1
    return cells, -1, at, ends[at - 1] if at else 0


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _touching_pass(box, moving, cells, ends, counts, r, c, gap, span,
                   cols):  # pragma: no cover - compiled
    """The first moving record (in record order) with a cell within ``gap`` cells
    (Chebyshev) of a cell (``r``, ``c``) and whose cells joined with those span at most
    ``span`` cells along rows and columns, or -1. Records whose window boxes ``box`` (n, 4:
    first col, first row, last col, last row, inclusive) are farther than ``gap`` from those
    cells' box are passed over without looking at their flat ``cells``."""
    r_lo, r_hi, c_lo, c_hi = r.min(), r.max(), c.min(), c.max()
    for k in range(box.shape[0]):
        if (not moving[k] or counts[k] == 0 or box[k, 1] - r_hi > gap or r_lo - box[k, 3] > gap
                or box[k, 0] - c_hi > gap or c_lo - box[k, 2] > gap):
            continue
        near = False
        rows_lo, rows_hi, cols_lo, cols_hi = r_lo, r_hi, c_lo, c_hi
        for q in range(ends[k] - counts[k], ends[k]):
            rq = cells[q] // cols
            cq = cells[q] - rq * cols
            rows_lo, rows_hi = min(rows_lo, rq), max(rows_hi, rq)
            cols_lo, cols_hi = min(cols_lo, cq), max(cols_hi, cq)
            if not near:
                for i in range(r.shape[0]):
                    if max(abs(rq - r[i]), abs(cq - c[i])) <= gap:
                        near = True
                        break
        if near and rows_hi - rows_lo + 1 <= span and cols_hi - cols_lo + 1 <= span:
            return k
    return -1


def bridge_cells(held: HeldFrame, velocity_m_per_s: np.ndarray,
                 known: tuple[tuple[np.ndarray, int], ...], reach: int) -> np.ndarray:
    """The cells (global lattice (iy, ix), ascending) of a track in ``held``, a frame of
    a gap (module docstring, "Gaps") or of its lead ("Lead"), none of them in a record of
    ``held``: its cells ``known`` elsewhere ((cells (n, 2), stamp_ns) pairs) carried to
    ``held.stamp_ns`` at ``velocity_m_per_s`` (x, y) predict where it is; the cells occupied
    now within Chebyshev distance ``reach`` of the prediction are its, and if there are any,
    so are the predicted cells its scan is silent about (``held.speaks``). No cell at all if
    none near the prediction is occupied now (nothing says the object is there). One
    compiled pass over the predicted cells (:func:`_bridge_pass`)."""
    w = held.window
    vx, vy = (float(x) for x in velocity_m_per_s)
    cells = (np.asarray(known[0][0], np.int64).reshape(-1, 2) if len(known) == 1 else
             np.concatenate([np.asarray(c, np.int64).reshape(-1, 2) for c, _ in known]))
    counts = np.array([len(c) for c, _ in known], np.int64)
    ago_ns = np.array([held.stamp_ns - stamp for _, stamp in known], np.int64)
    speaks = held.speaks
    if isinstance(speaks, tuple):  # the sensor grid's layers (tests, callers of their own)
        speaks = (speaks[0] > 0) | (speaks[1] > 0)
    spoken = _NO_BYTES if speaks is None else flat_layer(speaks)
    return _bridge_pass(cells, counts, ago_ns, vx, vy, w.resolution_m, w.row0, w.col0,
                        w.rows, w.cols, int(reach), flat_layer(held.occupied),
                        np.asarray(held.object_cells, np.int64), spoken, speaks is not None)


_NO_BYTES = np.zeros(0, np.uint8)


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _bridge_pass(cells, counts, ago_ns, vx, vy, res, row0, col0, rows, cols, reach, occupied,
                 records, spoken, has_spoken):  # pragma: no cover - compiled
    """:func:`bridge_cells` on the known ``cells`` (global lattice, ``counts`` per end, each
    end's rows carried ``ago_ns`` forward at (``vx``, ``vy``) m/s, rounded to cells of
    ``res`` m): the window cells within ``reach`` of a
    predicted one that are ``occupied`` and in no record (``records``: flat), and if there
    are any, with the predicted cells in no record that the scan does not speak of
    (``spoken``, with ``has_spoken``); global lattice rows, ascending, unique."""
    side = 2 * reach + 1
    n = cells.shape[0]
    near = np.empty(n * side * side, np.int64)
    silent = np.empty(n, np.int64)
    n_near = 0
    n_silent = 0
    start = 0
    for e in range(counts.shape[0]):
        shift_r = np.int64(np.rint(vy * ago_ns[e] * 1e-9 / res))
        shift_c = np.int64(np.rint(vx * ago_ns[e] * 1e-9 / res))
        for i in range(start, start + counts[e]):
            r = cells[i, 0] + shift_r - row0
            c = cells[i, 1] + shift_c - col0
            for a in range(max(r - reach, 0), min(r + reach + 1, rows)):
                for b in range(max(c - reach, 0), min(c + reach + 1, cols)):
                    if occupied[a * cols + b] > 0:
                        near[n_near] = a * cols + b
                        n_near += 1
            if has_spoken and 0 <= r < rows and 0 <= c < cols and spoken[r * cols + c] == 0:
                silent[n_silent] = r * cols + c
                n_silent += 1
        start += counts[e]
    held = sorted_copy(records)
    near = near[:n_near][~in_sorted(near[:n_near], held)]
    if near.shape[0] == 0:
        return np.zeros((0, 2), np.int64)
    silent = silent[:n_silent][~in_sorted(silent[:n_silent], held)]
    flat = sorted_unique(np.concatenate((near, silent)))
    out = np.empty((flat.shape[0], 2), np.int64)
    for k in range(flat.shape[0]):
        out[k, 0] = flat[k] // cols + row0
        out[k, 1] = flat[k] % cols + col0
    return out


def _record_lattice(frame: HeldFrame, k: int) -> np.ndarray:
    """The cells of record ``k`` of ``frame`` as global lattice (iy, ix) rows."""
    w = frame.window
    return _record_lattice_pass(np.ascontiguousarray(frame.objects["cell_count"]),
                                np.asarray(frame.object_cells), k, w.cols, w.row0, w.col0)


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _record_lattice_pass(counts, cells, k, cols, row0, col0):  # pragma: no cover - compiled
    """:func:`_record_lattice` on the records' ``counts`` and their flat window ``cells``."""
    start = 0
    for j in range(k):
        start += np.int64(counts[j])
    out = np.empty((np.int64(counts[k]), 2), np.int64)
    for q in range(out.shape[0]):
        flat = np.int64(cells[start + q])
        out[q, 0] = flat // cols + row0
        out[q, 1] = flat % cols + col0
    return out


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _first(ids, track):  # pragma: no cover - compiled
    """The index of the first of ``ids`` equal to ``track``, or -1."""
    for k in range(ids.shape[0]):
        if ids[k] == track:
            return k
    return -1


def _set_geometry(record: np.ndarray, held: HeldFrame, cells: np.ndarray) -> None:
    """``record``'s cell count, centroid, box, extent and mean betP(M) from its flat window
    ``cells`` in ``held`` (as the cluster summary computes them)."""
    centroid, box, extent, mean_betp = _geometry_fields(held, cells)
    record["cell_count"] = cells.size
    record["centroid_m"] = centroid
    record["bbox_m"] = box
    record["extent_m"] = extent
    record["mean_betp_moving"] = mean_betp


def _geometry_fields(held: HeldFrame, cells: np.ndarray) -> tuple[tuple[float, float],
                                                                  tuple[float, ...],
                                                                  tuple[float, float],
                                                                  np.float32]:
    """The centroid (x, y), box, extent and mean betP(M) of flat window ``cells`` in
    ``held``, as a record's fields (metres)."""
    w, res = held.window, held.window.resolution_m
    r_lo, r_hi, c_lo, c_hi, r_sum, c_sum, betp_sum = _geometry(
        np.asarray(cells, np.int64), w.cols, held.betp_moving.reshape(-1))
    n = cells.size
    box = ((w.col0 + c_lo) * res, (w.row0 + r_lo) * res,
           (w.col0 + c_hi + 1) * res, (w.row0 + r_hi + 1) * res)
    return (((w.col0 + c_sum / n + 0.5) * res, (w.row0 + r_sum / n + 0.5) * res), box,
            (box[2] - box[0], box[3] - box[1]), np.float32(betp_sum / n / 255.0))


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _geometry(cells, cols, betp):  # pragma: no cover - compiled
    """Row / column bounds, row / column sums and the betP(M) (×255) sum of flat ``cells``
    (integers: the means divided out by the caller are those of numpy)."""
    r_lo, r_hi, c_lo, c_hi = cols * cols, -1, cols * cols, -1
    r_sum, c_sum, betp_sum = 0, 0, 0
    for q in cells:
        r = q // cols
        c = q - r * cols
        r_lo, r_hi, c_lo, c_hi = min(r_lo, r), max(r_hi, r), min(c_lo, c), max(c_hi, c)
        r_sum += r
        c_sum += c
        betp_sum += np.int64(betp[q])
    return r_lo, r_hi, c_lo, c_hi, r_sum, c_sum, betp_sum


def warm_up() -> None:
    """Load the compiled passes of :func:`fill` and :func:`bridge_cells` (the run's warm-up:
    not charged to a frame)."""
    one = np.zeros(1, np.int64)
    records = np.zeros(2, OBJECT_DTYPE)
    _bridge_pass(np.zeros((1, 2), np.int64), one, one, 0.0, 0.0, 0.5, 0, 0, 1, 1, 1,
                 np.ones(1, np.uint8), np.zeros(0, np.int64), np.zeros(1, np.uint8), True)
    ids, states, counts, boxes = _fields(records)
    _record_lattice_pass(counts, np.zeros(1, np.uint32), 0, 1, 0, 0)
    _first(ids, 1)
    _fill_pass(np.zeros((1, 2), np.int64), 0, 0, 1, 1, 0.5, np.zeros(1, np.uint8), True, ids,
               states, counts, boxes, one, 1, 1, 1)
    _geometry(one, 1, np.zeros(1, np.uint8))
    _candidate_rows(one, one, one, one, one)
