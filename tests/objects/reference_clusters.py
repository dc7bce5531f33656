"""The clusters pass as it was before the compiled rewrite (evperc main d379f5e), kept as the
reference the pipeline's pass is tested against (tests/objects/test_tracking_reference.py,
test_passes_reference.py), like tests/fusion/reference.py is for the fusion. Not used by
the pipeline. Original docstring:

Clusters of one frame: cells seen moving, grown through the cells occupied now
(docs/method.md, "Objects"; after Dynablox's clustering, Schmid et al. RA-L 2023).

Seeds are the cells decided ``moving`` this frame (and, optionally, the cells whose
conflict ∅_FO — free before, occupied now — reaches ``seed_conflict_fo``, and the cells an
existing track held in the previous frame). From each seed a cluster grows 8-connected
through the cells decided occupied: ``moving``, ``static``, ``stopped`` and ``unmapped``,
whatever their history: the far side of a car, never seen free, joins the cells whose
conflict revealed it.

With ``seeds = "occupied"`` (the default) the growth is limited to what the scan sees now
— a cell decided ``moving``, or decided occupied and holding a return of this scan
(``occupied_now``, the sensor grid's m({O}) > 0) — and every such cell seeds: each connected
group of them is a cluster, whether or not any of its cells conflicts. A car driving ahead
of the ego enters cells that were inside it a scan before and never gives the ∅_FO
conflict; as a cluster it is tracked, and the tracker's motion evidence
(:mod:`evperc.objects.tracking`) decides whether it moves. Cells the grid still remembers
occupied but no return hits now (the trail a car leaves until rays carve it free) stay out,
so a cluster is the object where it is now (Dynablox grows through the voxels occupied in the
current scan). ``infrastructure`` cells do not take part: the map says
a building stands there, it cannot move, and a car at a façade would otherwise grow into
the whole building. A cluster is kept if it has at least ``min_cells`` cells and its
bounding box is at most ``max_extent_m`` on each side (a false seed at a wall grows along
the wall, far beyond any vehicle); with ``keep_tracked_small``, a cluster grown from a cell
that a track which has moved held in the previous frame is kept whatever its size (the
track has shown it is an object: a car seen through a gap, a pedestrian of one cell).

The growth is one compiled pass (numba): a scan of the window for seeds, then a flood fill
from each seed not yet in a cluster, touching only the clusters' cells and their
neighbours; the scratch marks are cleared cell by cell afterwards."""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from evperc.fusion.twin import DECISION_CODES
from evperc.geo.window import Window
from evperc.objects.clusters import ClusterParams  # the same parameters

#: decisions a cluster grows through (the cells occupied now, except mapped buildings)
GROWS_THROUGH = ("moving", "static", "stopped", "unmapped")


@dataclass(frozen=True)
class Clusters:
    """The kept clusters of a frame, ``n`` of them, in the order their first seed was
    found (row-major scan, extra seeds first)."""

    cells: np.ndarray       # int64: flat window indices (row · cols + col), cluster by cluster
    offsets: np.ndarray     # int64 (n + 1,): cluster k's cells are cells[offsets[k]:offsets[k+1]]
    centroid_m: np.ndarray  # (n, 2) float64: mean cell centre x, y (working CRS)
    bbox_m: np.ndarray      # (n, 4) float64: xmin, ymin, xmax, ymax of the outer cell edges
    seeds: np.ndarray       # (n,) int64: seed cells in the cluster
    mean_betp_moving: np.ndarray  # (n,) float32

    def __len__(self) -> int:
        return len(self.seeds)

    def cells_of(self, k: int) -> np.ndarray:
        return self.cells[self.offsets[k]:self.offsets[k + 1]]


def _grow_lut() -> np.ndarray:
    lut = np.zeros(256, np.bool_)
    lut[[DECISION_CODES[n] for n in GROWS_THROUGH]] = True
    return lut


_GROWS = _grow_lut()
_MOVING = DECISION_CODES["moving"]


@numba.njit(cache=True, nogil=True)
def _flood(decision: np.ndarray, conflict_fo: np.ndarray, now: np.ndarray, seed_all: bool,
           cols: int, fo_q: int, moving: int, grows: np.ndarray, extra: np.ndarray,
           mark: np.ndarray, cells: np.ndarray, stats: np.ndarray) -> tuple[int, int]:
    """Flood fill from every seed; returns (clusters, cells). ``stats[k]``: count, seeds,
    Σrow, Σcol, min row, max row, min col, max col. ``decision``, ``conflict_fo``, ``now``
    (1: a cell a cluster may hold unless decided moving): the window's cells, flat
    (row-major, ``cols`` a row). ``seed_all``: every cell a cluster may hold seeds."""
    total = decision.shape[0]
    rows = total // cols
    n_clusters = 0
    n_cells = 0
    n_extra = extra.shape[0]
    for s in range(n_extra + total):
        if s < n_extra:
            start = extra[s]
            if (start < 0 or start >= total or mark[start] or not grows[decision[start]]
                    or not (now[start] or decision[start] == moving)):
                continue
        else:
            start = s - n_extra
            if mark[start]:
                continue
            d = decision[start]
            if seed_all:
                if not (d == moving or (grows[d] and now[start])):
                    continue
            elif d != moving and not (fo_q > 0 and conflict_fo[start] >= fo_q):
                continue
        k = n_clusters
        n_clusters += 1
        first = n_cells
        mark[start] = 1
        cells[n_cells] = start
        n_cells += 1
        head = first
        count = 0
        seeds = 0
        sr = 0
        sc = 0
        r0 = rows
        r1 = -1
        c0 = cols
        c1 = -1
        while head < n_cells:  # the cluster's cells double as the queue (breadth first)
            i = cells[head]
            head += 1
            r = i // cols
            c = i - r * cols
            count += 1
            if decision[i] == moving or (fo_q > 0 and conflict_fo[i] >= fo_q):
                seeds += 1
            sr += r
            sc += c
            r0 = min(r0, r)
            r1 = max(r1, r)
            c0 = min(c0, c)
            c1 = max(c1, c)
            for dr in range(-1, 2):
                rr = r + dr
                if rr < 0 or rr >= rows:
                    continue
                for dc in range(-1, 2):
                    cc = c + dc
                    if cc < 0 or cc >= cols or (dr == 0 and dc == 0):
                        continue
                    j = rr * cols + cc
                    if mark[j]:
                        continue
                    dj = decision[j]
                    if ((grows[dj] and (now[j] or dj == moving))
                            or (fo_q > 0 and conflict_fo[j] >= fo_q)):
                        mark[j] = 1
                        cells[n_cells] = j
                        n_cells += 1
        stats[k, 0] = count
        stats[k, 1] = seeds
        stats[k, 2] = sr
        stats[k, 3] = sc
        stats[k, 4] = r0
        stats[k, 5] = r1
        stats[k, 6] = c0
        stats[k, 7] = c1
    for m in range(n_cells):
        mark[cells[m]] = 0
    return n_clusters, n_cells


def tracked_clusters(first_cells: np.ndarray, extra_seeds: np.ndarray) -> np.ndarray:
    """(n,) bool: the clusters grown from an extra seed. The extra seeds are grown first, so
    a cluster holds a (growable) extra seed exactly when its first cell is one."""
    return np.isin(first_cells, extra_seeds)


class Clusterer:
    """Reusable scratch buffers for :meth:`clusters` over windows of one shape."""

    def __init__(self, params: ClusterParams, shape: tuple[int, int]) -> None:
        self.params = params
        self.shape = shape
        n = shape[0] * shape[1]
        self._mark = np.zeros(n, np.uint8)
        self._cells = np.empty(n, np.int64)
        self._stats = np.empty((n, 8), np.int64)
        # the stored ∅_FO is q / 255: q >= ceil(255 · threshold) (0: no conflict seeds)
        thr = params.seed_conflict_fo
        self._fo_q = max(1, int(np.ceil(255.0 * thr - 1e-9))) if thr > 0 else 0
        self._everywhere = np.ones(n, np.uint8)  # ``now`` where the growth is not limited

    def clusters(self, decision: np.ndarray, betp_moving: np.ndarray, conflict_fo: np.ndarray,
                 window: Window, extra_seeds: np.ndarray | None = None,
                 occupied_now: np.ndarray | None = None, heights: np.ndarray | None = None,
                 near_building: np.ndarray | None = None) -> Clusters:
        """The kept clusters of one frame. ``decision`` (rows, cols) uint8 codes;
        ``betp_moving`` and ``conflict_fo``: betP(M) and ∅_FO as stored (uint8, ×255);
        ``extra_seeds``: flat window indices that seed too if occupied now (a track's
        cells of the previous frame); ``occupied_now``: (rows, cols) bool, the cells holding
        a return of this scan (required with ``seeds = "occupied"``, unused otherwise)."""
        if decision.shape != self.shape:
            raise ValueError(f"window {decision.shape}, the clusterer's is {self.shape}")
        extra = (np.zeros(0, np.int64) if extra_seeds is None
                 else np.ascontiguousarray(extra_seeds, np.int64))
        seed_all = self.params.seeds == "occupied"
        if seed_all:
            if occupied_now is None or occupied_now.shape != self.shape:
                raise ValueError("seeds = 'occupied' needs the scan's occupied cells")
            now = np.ascontiguousarray(occupied_now, np.uint8).reshape(-1)
        else:
            now = self._everywhere
        n, used = _flood(decision.reshape(-1), conflict_fo.reshape(-1), now, seed_all,
                         self.shape[1], self._fo_q, _MOVING, _GROWS, extra, self._mark,
                         self._cells, self._stats)
        stats = self._stats[:n]
        count = stats[:, 0]
        offsets = np.zeros(n + 1, np.int64)
        np.cumsum(count, out=offsets[1:])
        all_cells = self._cells[:used]
        tracked = (tracked_clusters(all_cells[offsets[:-1]], extra)
                   if self.params.keep_tracked_small and len(extra) else np.zeros(n, bool))
        if self.params.off_buildings and near_building is not None:
            # added with objects.clusters_off_buildings (not in d379f5e): each group's cells
            # near a building decided static / stopped / unmapped left out, its stats
            # counted again from the cells it keeps
            leaves = np.isin(decision.reshape(-1),
                             [DECISION_CODES[n] for n in ("static", "stopped", "unmapped")])
            out = near_building.reshape(-1) & leaves
            fo_q = self._fo_q
            seed = ((decision.reshape(-1) == _MOVING)
                    | ((fo_q > 0) & (conflict_fo.reshape(-1).astype(np.int64) >= fo_q)))
            groups = [all_cells[offsets[k]:offsets[k + 1]] for k in range(n)]
            # a group whose box is at most off_buildings_small_m on each side: kept whole
            side_m = np.maximum(stats[:, 5] - stats[:, 4] + 1,
                                stats[:, 7] - stats[:, 6] + 1) * window.resolution_m
            whole = side_m <= self.params.off_buildings_small_m + 1e-9
            top = self.params.off_buildings_max_height_m
            if heights is not None and top > 0:  # added with off_buildings_max_height_m:
                # ... and none of its cells holds a return that high
                flat_h = heights.reshape(-1).astype(np.float32)
                whole &= np.array([not (flat_h[g] >= np.float32(top)).any() for g in
                                   (all_cells[offsets[k]:offsets[k + 1]] for k in range(n))],
                                  bool).reshape(whole.shape)
            groups = [g if whole[k] else g[~out[g]] for k, g in enumerate(groups)]
            stats = np.zeros((n, 8), np.int64)
            for k, g in enumerate(groups):
                r, c = np.divmod(g, self.shape[1])
                stats[k, :4] = len(g), seed[g].sum(), r.sum(), c.sum()
                if len(g):
                    stats[k, 4:] = r.min(), r.max(), c.min(), c.max()
            count = stats[:, 0]
            np.cumsum(count, out=offsets[1:])
            all_cells = np.concatenate(groups) if groups else np.zeros(0, np.int64)
        res = window.resolution_m
        span_r = (stats[:, 5] - stats[:, 4] + 1) * res
        span_c = (stats[:, 7] - stats[:, 6] + 1) * res
        big_enough = (count >= self.params.min_cells) | tracked
        bound = self.params.isolated_min_height_m

        def tall(k: int) -> bool:
            """(added with isolated_min_height_m) the highest return of the 3 × 3 blocks
            of cluster k's cells reaches the bound; no condition without heights"""
            if heights is None or bound <= 0:
                return True
            padded = np.pad(heights.astype(np.float32), 1, constant_values=-np.inf)
            r, c = np.divmod(all_cells[offsets[k]:offsets[k + 1]], self.shape[1])
            top = max(padded[r + dr + 1, c + dc + 1].max() for dr in (-1, 0, 1)
                      for dc in (-1, 0, 1))
            return bool(top >= np.float32(bound))

        small_conflict = self.params.small_conflict_min_cells
        if small_conflict > 0:  # added with objects.small_conflict_min_cells (not in d379f5e):
            # a cluster holding a seed by its decision (moving) or its conflict, tall enough
            fo_q = self._fo_q
            seeded = ((decision.reshape(-1) == _MOVING)
                      | ((fo_q > 0) & (conflict_fo.reshape(-1).astype(np.int64) >= fo_q)))
            for k in range(len(count)):
                if (not big_enough[k] and count[k] >= small_conflict
                        and seeded[all_cells[offsets[k]:offsets[k + 1]]].any() and tall(k)):
                    big_enough[k] = True
        iso = self.params.isolated_min_cells
        if iso > 0:  # added with objects.isolated_min_cells (not in d379f5e): per cluster
            reach = int(np.floor(self.params.isolated_clearance_m / window.resolution_m + 1e-9))
            still = np.isin(decision, [DECISION_CODES[n] for n in
                                       ("static", "stopped", "unmapped", "infrastructure")])
            for k in np.flatnonzero(~big_enough & (count >= iso)):
                own = np.zeros(self.shape, bool).reshape(-1)
                own[all_cells[offsets[k]:offsets[k + 1]]] = True
                own = own.reshape(self.shape)
                near = np.zeros(self.shape, bool)
                for r, c in zip(*np.nonzero(own), strict=True):
                    near[max(r - reach, 0):r + reach + 1, max(c - reach, 0):c + reach + 1] = True
                big_enough[k] = not (near & still & ~own).any() and tall(int(k))
        keep = (big_enough & (count > 0) & (span_r <= self.params.max_extent_m + 1e-9)
                & (span_c <= self.params.max_extent_m + 1e-9))
        kept = np.flatnonzero(keep)
        pieces = [all_cells[offsets[k]:offsets[k + 1]] for k in kept]
        cells = np.concatenate(pieces) if pieces else np.zeros(0, np.int64)
        new_offsets = np.zeros(len(kept) + 1, np.int64)
        np.cumsum(count[kept], out=new_offsets[1:])
        st = stats[kept]
        cnt = st[:, 0].astype(np.float64)
        centroid = np.stack([(window.col0 + st[:, 3] / np.maximum(cnt, 1) + 0.5) * res,
                             (window.row0 + st[:, 2] / np.maximum(cnt, 1) + 0.5) * res],
                            axis=1) if len(kept) else np.zeros((0, 2))
        bbox = np.stack([(window.col0 + st[:, 6]) * res, (window.row0 + st[:, 4]) * res,
                         (window.col0 + st[:, 7] + 1) * res, (window.row0 + st[:, 5] + 1) * res],
                        axis=1).astype(np.float64) if len(kept) else np.zeros((0, 4))
        flat_m = betp_moving.reshape(-1)
        sums = np.add.reduceat(flat_m[cells].astype(np.int64), new_offsets[:-1]) \
            if len(kept) else np.zeros(0, np.int64)
        mean_m = (sums / np.maximum(cnt, 1) / 255.0).astype(np.float32)
        return Clusters(cells, new_offsets, centroid, bbox, st[:, 1].copy(), mean_m)
