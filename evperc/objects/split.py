"""Clusters shared by tracks that move apart, split between them (docs/method.md §8, "Shared
clusters"; the split of a merged measurement among the tracks that claim it, as a
multi-object tracker does before association).

A car passing a parked car, a person walking past a pole: for a frame or several the two are
one 8-connected group of occupied cells, so one cluster. The tracker associates each cluster
with one track (:mod:`evperc.objects.tracking`), so one of the two tracks loses its object,
and the other takes a centroid pulled half-way to the other object: a jump the velocity fit
reads as motion, and the moving one's conflict cells as its evidence — the parked car is
reported moving while the passing car is lost.

This pass runs between the clustering and the tracker. Each track associated in the previous
frame (``missed`` 0) paints its footprint of that frame, carried by its velocity over the
frame's Δt (the shift ``round(v·Δt / resolution)`` cells per axis), into the window. A
cluster is *shared* when at least two tracks each paint at least ``split_min_overlap_cells``
of its cells and two of those tracks, both with a fitted velocity (two associations or more:
a track one frame old has none, and its 0 would set any moving track apart from it) and one
of them moving (its motion test passed at its last association), differ in velocity by at
least ``split_speed_difference_m_per_s`` (|v_a − v_b|; fragments of one car move alike and
are left as one cluster, as before; two tracks of still things — a parked car and the hedge
beside it, whose fitted velocities wander with their growing views — are left too). A shared
cluster is replaced by one part per such track: the painted cells of each track seed a
breadth-first growth, 8-connected, through the cluster's cells, all tracks' fronts advancing
together (a cell painted by two tracks, or by a track that does not take part, is grown into
like an unpainted one; a cell is taken by the first front to reach it — the front of the
lower track row on a tie: the queue holds each distance's cells part by part); a cell no
front reaches (the cluster's off-building cells can leave it in pieces) joins the largest
part. The parts, in track row order, take the cluster's place in the list; each part's
statistics are the clustering's own (:func:`evperc.objects.clusters.summarise_groups`) over
its cells. A part may be smaller than ``min_cluster_cells``: it is a tracked object's
visible share."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numba
import numpy as np

from evperc.fusion.twin import DECISION_CODES
from evperc.geo.window import Window
from evperc.objects.clusters import Clusters, group_stats, summarise_groups
from evperc.objects.tracking import TrackerState

_MOVING = DECISION_CODES["moving"]
#: ``part`` marks of the scratch layer (:func:`_split`): no cluster cell / a cell of the
#: cluster being split that no front has reached; parts are numbered from 0
_OUTSIDE = -1
_UNREACHED = -2
#: ``label`` marks of the painted footprints: no track / more than one track
_NO_TRACK = -1
_TWO_TRACKS = -2


@dataclass(frozen=True)
class SplitParams:
    """The ``[objects]`` keys of the split (configs/default.toml)."""

    #: objects.split_shared_clusters: split a cluster shared by tracks that move apart
    enabled: bool = False
    #: objects.split_min_overlap_cells: cells of the cluster a track's carried footprint
    #: must cover to claim a part
    min_overlap_cells: int = 2
    #: objects.split_speed_difference_m_per_s: least |v_a − v_b| of two claiming tracks
    speed_difference_m_per_s: float = 1.0

    @staticmethod
    def from_config(config: dict[str, Any]) -> SplitParams:
        o = config["objects"]
        return SplitParams(
            enabled=bool(o.get("split_shared_clusters", False)),
            min_overlap_cells=int(o.get("split_min_overlap_cells", 2)),
            speed_difference_m_per_s=float(o.get("split_speed_difference_m_per_s", 1.0)))


@numba.njit(cache=True, inline="always")
def _meet(a, b):  # pragma: no cover - compiled
    """Whether the boxes ``a`` and ``b`` (row min, row max, col min, col max; cells,
    inclusive) share a cell."""
    return a[0] <= b[1] and b[0] <= a[1] and a[2] <= b[3] and b[2] <= a[3]


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _split(cells, offsets, fp, fp_n, missed, moving, fitted, velocity, dt, row0, col0, rows,
           cols, res, min_overlap, dv2_min, label, part, decision, fo_q, conflict_fo,
           moving_code):  # pragma: no cover - compiled
    """The module docstring's split: returns (split count, cells, stats) — the clusters'
    cells, part after part in place of each shared cluster, and each group's
    :func:`~evperc.objects.clusters.group_stats` — or split count 0 and empty arrays when
    no cluster is shared. ``label`` and ``part`` (int32) are flat window scratch
    layers, all −1 on entry and on return.

    Only what can be shared is painted: a shared cluster holds cells of a moving track's
    carried footprint, so the candidates are the clusters whose bounding box meets such a
    footprint's, and only the tracks whose carried footprint's box meets a candidate's are
    painted (every such track, moving or not: the counts and the cells of two tracks in a
    candidate are then those of painting them all). The scratch layers are touched at a
    few objects' cells, not at every track's (a window's layers do not stay in cache)."""
    n_tr = fp_n.shape[0]
    n_cl = offsets.shape[0] - 1
    none = (0, cells[:0], np.empty((0, 8), np.int64))
    # each fresh track's shift and carried box (window rows / cols)
    shift = np.zeros((n_tr, 2), np.int64)
    box = np.empty((n_tr, 4), np.int64)  # row min, row max, col min, col max
    fresh = np.zeros(n_tr, np.bool_)
    start = np.empty(n_tr + 1, np.int64)
    start[0] = 0
    any_moving = False
    for i in range(n_tr):
        start[i + 1] = start[i] + fp_n[i]
        if missed[i] != 0 or fp_n[i] == 0:
            continue
        fresh[i] = True
        dr = int(np.round(velocity[i, 1] * dt / res))
        dc = int(np.round(velocity[i, 0] * dt / res))
        shift[i, 0] = dr - row0
        shift[i, 1] = dc - col0
        r0 = c0 = 1 << 62
        r1 = c1 = -(1 << 62)
        for q in range(start[i], start[i + 1]):
            r0 = min(r0, fp[q, 0])
            r1 = max(r1, fp[q, 0])
            c0 = min(c0, fp[q, 1])
            c1 = max(c1, fp[q, 1])
        box[i, 0] = r0 + shift[i, 0]
        box[i, 1] = r1 + shift[i, 0]
        box[i, 2] = c0 + shift[i, 1]
        box[i, 3] = c1 + shift[i, 1]
        if moving[i] != 0 and fitted[i]:
            any_moving = True
    if not any_moving:
        return none
    # the candidate clusters: their box meets a fresh, fitted, moving track's
    candidate = np.zeros(n_cl, np.bool_)
    cbox = np.empty((n_cl, 4), np.int64)
    n_candidates = 0
    for k in range(n_cl):
        r0 = c0 = 1 << 62
        r1 = c1 = -(1 << 62)
        for q in range(offsets[k], offsets[k + 1]):
            r = cells[q] // cols
            c = cells[q] - r * cols
            r0 = min(r0, r)
            r1 = max(r1, r)
            c0 = min(c0, c)
            c1 = max(c1, c)
        cbox[k, 0] = r0
        cbox[k, 1] = r1
        cbox[k, 2] = c0
        cbox[k, 3] = c1
        for i in range(n_tr):
            if fresh[i] and moving[i] != 0 and fitted[i] and _meet(box[i], cbox[k]):
                candidate[k] = True
                n_candidates += 1
                break
    if n_candidates == 0:
        return none
    painted = np.empty(fp.shape[0], np.int64)
    n_painted = 0
    for i in range(n_tr):
        if not fresh[i]:
            continue
        meets = False
        for k in range(n_cl):
            if candidate[k] and _meet(box[i], cbox[k]):
                meets = True
                break
        if not meets:
            continue
        for q in range(start[i], start[i + 1]):
            r = fp[q, 0] + shift[i, 0]
            c = fp[q, 1] + shift[i, 1]
            if 0 <= r < rows and 0 <= c < cols:
                j = r * cols + c
                if label[j] == _NO_TRACK:
                    label[j] = i
                    painted[n_painted] = j
                    n_painted += 1
                elif label[j] != i:
                    label[j] = _TWO_TRACKS
    hit = np.zeros(n_tr, np.int64)
    claim = np.full(n_tr, -1, np.int64)  # track row -> its part in the cluster being split
    takers = np.empty(n_tr, np.int64)
    shared = np.zeros(n_cl, np.int64)  # parts of each cluster (0: kept whole)
    n_split = 0
    for k in range(n_cl):
        if not candidate[k]:
            continue
        n_takers = 0
        for q in range(offsets[k], offsets[k + 1]):
            t = label[cells[q]]
            if t >= 0:
                hit[t] += 1
                if hit[t] == min_overlap:
                    takers[n_takers] = t
                    n_takers += 1
        for q in range(offsets[k], offsets[k + 1]):
            t = label[cells[q]]
            if t >= 0:
                hit[t] = 0
        apart = False
        for a in range(n_takers):
            for b in range(a + 1, n_takers):
                if moving[takers[a]] == 0 and moving[takers[b]] == 0:
                    continue
                if not (fitted[takers[a]] and fitted[takers[b]]):
                    continue
                dx = velocity[takers[a], 0] - velocity[takers[b], 0]
                dy = velocity[takers[a], 1] - velocity[takers[b], 1]
                if dx * dx + dy * dy >= dv2_min:
                    apart = True
        if apart:
            shared[k] = n_takers
            n_split += 1
    if n_split == 0:
        for q in range(n_painted):
            label[painted[q]] = _NO_TRACK
        return none
    n_out = 0
    for k in range(n_cl):
        n_out += max(shared[k], 1)
    n_cells = offsets[n_cl]
    out_cells = np.empty(n_cells, np.int64)
    stats = np.empty((n_out, 8), np.int64)
    queue = np.empty(n_cells, np.int64)
    sizes = np.empty(n_tr, np.int64)
    w = 0
    j = 0
    for k in range(n_cl):
        a = offsets[k]
        b = offsets[k + 1]
        n_parts = max(shared[k], 1)
        if shared[k] > 0:
            # the claiming tracks in row order: part p is the p-th of them
            n_takers = 0
            for q in range(a, b):
                t = label[cells[q]]
                if t >= 0:
                    hit[t] += 1
            for t in range(n_tr):
                if hit[t] >= min_overlap:
                    claim[t] = n_takers
                    n_takers += 1
            for q in range(a, b):
                part[cells[q]] = _UNREACHED
            head = 0
            tail = 0
            for p in range(n_takers):  # the fronts start from the painted cells, by part
                for q in range(a, b):
                    i = cells[q]
                    t = label[i]
                    if t >= 0 and claim[t] == p:
                        part[i] = p
                        queue[tail] = i
                        tail += 1
            while head < tail:
                i = queue[head]
                head += 1
                r = i // cols
                c = i - r * cols
                for dr in range(-1, 2):
                    rr = r + dr
                    if rr < 0 or rr >= rows:
                        continue
                    for dc in range(-1, 2):
                        cc = c + dc
                        if cc < 0 or cc >= cols or (dr == 0 and dc == 0):
                            continue
                        n = rr * cols + cc
                        if part[n] == _UNREACHED:
                            part[n] = part[i]
                            queue[tail] = n
                            tail += 1
            for p in range(n_parts):
                sizes[p] = 0
            for q in range(a, b):
                if part[cells[q]] >= 0:
                    sizes[part[cells[q]]] += 1
            largest = 0
            for p in range(1, n_parts):
                if sizes[p] > sizes[largest]:
                    largest = p
            for q in range(a, b):
                if part[cells[q]] == _UNREACHED:
                    part[cells[q]] = largest
            for q in range(a, b):
                t = label[cells[q]]
                if t >= 0:
                    hit[t] = 0
            for t in range(n_tr):
                claim[t] = -1
        for p in range(n_parts):
            first = w
            for q in range(a, b):
                i = cells[q]
                if shared[k] == 0 or part[i] == p:
                    out_cells[w] = i
                    w += 1
            group_stats(out_cells, first, w, decision, conflict_fo, fo_q, moving_code, cols,
                        stats, j)
            j += 1
        if shared[k] > 0:
            for q in range(a, b):
                part[cells[q]] = _OUTSIDE
    for q in range(n_painted):
        label[painted[q]] = _NO_TRACK
    return n_split, out_cells, stats


class Splitter:
    """Scratch layers for :meth:`split` over windows of one shape."""

    def __init__(self, params: SplitParams, shape: tuple[int, int], fo_q: int = 0) -> None:
        self.params = params
        self.shape = shape
        n = shape[0] * shape[1]
        self._label = np.full(n, _NO_TRACK, np.int32)
        self._part = np.full(n, _OUTSIDE, np.int32)
        #: ∅_FO threshold of the clusters' seeds as stored (×255; 0: decided moving only)
        self.fo_q = fo_q
        #: clusters split in the last :meth:`split`
        self.last_split = 0

    def split(self, clusters: Clusters, state: TrackerState, window: Window, stamp_ns: int,
              decision: np.ndarray, betp_moving: np.ndarray, conflict_fo: np.ndarray
              ) -> Clusters:
        """``clusters`` with each shared cluster replaced by its parts (the module
        docstring); ``clusters`` itself when none is shared or the split is off. Call it
        before :func:`~evperc.objects.tracking.track_step` updates ``state`` (``stamp_ns``
        the frame's: Δt from the state's previous stamp)."""
        self.last_split = 0
        if (not self.params.enabled or len(clusters) == 0 or len(state) < 2
                or state.prev_ns is None):
            return clusters
        dt_s = (stamp_ns - state.prev_ns) * 1e-9
        dv = self.params.speed_difference_m_per_s
        out = _split(clusters.cells, clusters.offsets, state.fp, state.fp_n, state.missed,
                     np.ascontiguousarray(state.flags[:, 1]), np.isfinite(state.sigma),
                     state.velocity, float(dt_s),
                     window.row0, window.col0, window.rows, window.cols,
                     float(window.resolution_m),
                     max(int(self.params.min_overlap_cells), 1), float(dv * dv), self._label,
                     self._part, decision.reshape(-1), self.fo_q,
                     conflict_fo.reshape(-1), _MOVING)
        self.last_split = int(out[0])
        if self.last_split == 0:
            return clusters
        return summarise_groups(out[1], out[2], betp_moving, window)


def warm_up(params: SplitParams) -> int:
    """Load (or compile) :func:`_split` and the summary of its parts for the runner's
    argument types on two made-up tracks sharing a cluster (a parked car and one passing
    it): the first real frame is not charged a cache load. Changes nothing; returns the
    clusters split (1; 0 when the split is off)."""
    if not params.enabled:
        return 0
    window = Window(0.5, 8, 8, 0, 0)
    cells = np.array([9, 10, 11, 12, 13], np.int64)
    clusters = Clusters(cells, np.array([0, 5], np.int64), np.zeros((1, 2)), np.zeros((1, 4)),
                        np.zeros(1, np.int64), np.zeros(1, np.float32))
    state = TrackerState()
    state.prev_ns = 0
    state.id = np.array([1, 2], np.int64)
    state.hits = np.array([3, 3], np.int64)
    state.missed = np.zeros(2, np.int64)
    state.flags = np.array([[0, 0, 1], [1, 1, 1]], np.uint8)
    state.velocity = np.array([[0.0, 0.0], [5.0, 0.0]])
    state.sigma = np.array([0.1, 0.1])
    state.fp_n = np.array([2, 2], np.int64)
    state.fp = np.array([[1, 1], [1, 2], [1, 3], [1, 4]], np.int64)  # the second one cell on
    layer = np.zeros(window.shape, np.uint8)
    splitter = Splitter(SplitParams(True, 2, 1.0), window.shape)
    splitter.split(clusters, state, window, 100_000_000, layer, layer, layer)
    return splitter.last_split
