"""Clusters of one frame: cells seen moving, grown through the cells occupied now
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
With ``off_buildings`` (and a map), a cluster keeps none of the cells within
``map.building_margin_m`` of a mapped building (the runner's ``near_building`` layer) that
are decided ``static``, ``stopped`` or ``unmapped``: a façade's returns fall a cell or two
outside its outline, and a person standing against the wall, whose group takes them in,
would otherwise grow along the wall and be tracked on the façade's evidence. A group whose
bounding box is at most ``off_buildings_small_m`` on each side keeps them (a person walking
along a wall: the motion gate is closed there, so its cells are decided static, and the
tracker alone tells that it moves) — with ``off_buildings_max_height_m`` > 0, only if none of
its cells holds a return that high above the local ground (a person is lower; a fragment of
the façade, hit up its height, is not). The flood fill is unchanged — the group still grows
through those cells, so the small-group rules read the same groups — and the cells are
dropped from the cluster before the size and extent filters (a group that keeps none is no
cluster).
With ``isolated_min_cells`` > 0, a cluster of at least that many cells but fewer than
``min_cells`` is kept too when it is *isolated*: no cell within ``isolated_clearance_m``
(Chebyshev, centre to centre) of one of its cells, outside it, is decided ``static``,
``stopped``, ``unmapped`` or ``infrastructure``. A walking person is 1–3 cells off every
remembered obstacle; a small group at the edge of a remembered one is its spill (a return
of a façade, a parked car or a pole in the cell beside the ones it usually hits).
With ``small_conflict_min_cells`` > 0, a cluster of at least that many cells but fewer than
``min_cells`` is kept too when one of its cells is decided ``moving`` (the fusion's
conflict through the motion gate: a person of one or two cells stepping into cells seen
free, beside a parked car or a fence, where the isolation test fails) and its highest
return within one cell is at least ``isolated_min_height_m`` above the ground (the
isolated clusters' bound: a ground point the ground split called an obstacle is no person);
the tracker's motion test and evidence still decide whether it is reported
(docs/method.md §8 step 1).

The growth is one compiled pass (numba): a scan of the window for seeds, then a flood fill
from each seed not yet in a cluster, touching only the clusters' cells and their
neighbours; the scratch marks are cleared cell by cell afterwards."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numba
import numpy as np

from evperc.fusion.twin import DECISION_CODES
from evperc.geo.window import Window

#: decisions a cluster grows through (the cells occupied now, except mapped buildings)
GROWS_THROUGH = ("moving", "static", "stopped", "unmapped")


@dataclass(frozen=True)
class ClusterParams:
    """The ``[objects]`` keys of the clustering (configs/default.toml)."""

    #: objects.min_cluster_cells: smaller clusters are dropped (a car's near face at
    #: 0.5 m cells is 4-10 cells; a lone cell is noise)
    min_cells: int = 3
    #: objects.max_cluster_extent_m: a cluster whose bounding box is longer than this along
    #: x or y is no object (a bus is 12 m; a wall reached from a false seed is longer)
    max_extent_m: float = 20.0
    #: objects.seed_conflict_fo: cells with ∅_FO at least this seed a cluster too, even if
    #: not decided moving; 0 = off (only decided-moving cells seed)
    seed_conflict_fo: float = 0.0
    #: objects.seeds: "moving" (decided-moving cells seed, growth through every occupied
    #: decision) or "occupied" (every cell seen occupied now seeds; module docstring)
    seeds: str = "moving"  # configs/default.toml: "occupied"
    #: objects.keep_tracked_small: a cluster grown from an extra seed (a cell a track that
    #: has moved held in the previous frame) is kept whatever its size
    keep_tracked_small: bool = False
    #: objects.isolated_min_cells: a cluster of at least this many cells but fewer than
    #: min_cells is kept when isolated (module docstring); 0 = off
    isolated_min_cells: int = 0
    #: objects.isolated_clearance_m: how far (m, Chebyshev, cell centre to centre) from an
    #: isolated cluster's cells no cell may be decided static, stopped, unmapped or
    #: infrastructure
    isolated_clearance_m: float = 1.0
    #: objects.isolated_min_height_m: ... and whose highest return within one cell is at
    #: least this high above the local ground (a ground point the ground split called an
    #: obstacle is no person); 0 = no height condition
    isolated_min_height_m: float = 0.0
    #: objects.small_conflict_min_cells: a cluster of at least this many cells but fewer than
    #: min_cells is kept when it holds a cell decided moving (or, with seed_conflict_fo, a
    #: conflict seed) and its highest return within one cell reaches isolated_min_height_m
    #: (module docstring); 0 = off
    small_conflict_min_cells: int = 0
    #: objects.clusters_off_buildings: clusters keep none of the cells near a mapped
    #: building decided static, stopped or unmapped (module docstring)
    off_buildings: bool = False
    #: objects.off_buildings_small_m: ... except in a group whose bounding box is at most
    #: this on each side (m), kept whole (module docstring)
    off_buildings_small_m: float = 0.0
    #: objects.off_buildings_max_height_m: ... and none of whose cells holds a return at
    #: least this high above the local ground (m); 0 = no height condition
    off_buildings_max_height_m: float = 0.0
    #: objects.centroid: "cells" (a cluster's centroid is the mean of its cell centres) or
    #: "returns" (the mean of the obstacle returns of the scan in its cells, where it holds
    #: one: :func:`with_return_centroids`)
    centroid: str = "cells"
    #: objects.centroid_max_cells: with centroid = "returns", only clusters of at most this
    #: many cells take their returns' mean (0: every cluster)
    centroid_max_cells: int = 0
    #: objects.centroid_min_returns: ... and holding at least this many returns (0: one)
    centroid_min_returns: int = 0
    #: objects.centroid_depth_m: a returns' mean is moved this far from the sensor along the
    #: line of sight (m; :func:`with_return_centroids`); 0: as it is
    centroid_depth_m: float = 0.0

    @staticmethod
    def from_config(config: dict[str, Any]) -> ClusterParams:
        o = config["objects"]
        return ClusterParams(min_cells=int(o["min_cluster_cells"]),
                             max_extent_m=float(o["max_cluster_extent_m"]),
                             seed_conflict_fo=float(o["seed_conflict_fo"]),
                             seeds=str(o["seeds"]),
                             keep_tracked_small=bool(o.get("keep_tracked_small", False)),
                             isolated_min_cells=int(o.get("isolated_min_cells", 0)),
                             isolated_clearance_m=float(o.get("isolated_clearance_m", 1.0)),
                             isolated_min_height_m=float(o.get("isolated_min_height_m", 0.0)),
                             small_conflict_min_cells=int(o.get("small_conflict_min_cells", 0)),
                             off_buildings=bool(o.get("clusters_off_buildings", False)),
                             off_buildings_small_m=float(o.get("off_buildings_small_m", 0.0)),
                             off_buildings_max_height_m=float(
                                 o.get("off_buildings_max_height_m", 0.0)),
                             centroid=str(o.get("centroid", "cells")),
                             centroid_max_cells=int(o.get("centroid_max_cells", 0)),
                             centroid_min_returns=int(o.get("centroid_min_returns", 0)),
                             centroid_depth_m=float(o.get("centroid_depth_m", 0.0)))


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
    #: (n,) bool: the centroid is the mean of the cluster's returns
    #: (:func:`with_return_centroids`); None: every centroid is its cells' mean
    from_returns: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.seeds)

    def cells_of(self, k: int) -> np.ndarray:
        return self.cells[self.offsets[k]:self.offsets[k + 1]]


def _grow_lut() -> np.ndarray:
    lut = np.zeros(256, np.bool_)
    lut[[DECISION_CODES[n] for n in GROWS_THROUGH]] = True
    return lut


_GROWS = _grow_lut()
#: decisions that make a small cluster next to them spill, not an isolated object
STILL = ("static", "stopped", "unmapped", "infrastructure")
_STILL = np.zeros(256, np.bool_)
_STILL[[DECISION_CODES[n] for n in STILL]] = True
#: decisions a cluster leaves out near a mapped building (``off_buildings``)
OFF_BUILDINGS = ("static", "stopped", "unmapped")
_OFF_BUILDINGS = np.zeros(256, np.bool_)
_OFF_BUILDINGS[[DECISION_CODES[n] for n in OFF_BUILDINGS]] = True
_NO_HEIGHTS = np.zeros((0, 0), np.float32)
_NO_FLAT_HEIGHTS = np.zeros(0, np.float32)
_NO_FLAT_DECISION = np.zeros(0, np.uint8)
_MOVING = DECISION_CODES["moving"]
_UNKNOWN = DECISION_CODES["unknown"]
#: ``now`` value of a cell holding only returns behind the first one of their azimuth bin
#: (objects.cluster_on = "all_returns_join"): decided unknown (the grid has no occupied
#: evidence there), it joins a cluster growing next to it as a leaf — it seeds none (except
#: as a track's previous cell) and grows the cluster no further. Hit-only cells decided
#: free are not taken: on the simulated hdl64 drives they cost object precision (they
#: are later counted as vacated cells), notes/hits.md
JOINS_ANY = 2


@numba.njit(cache=True, nogil=True, inline="always")
def _grow(start, k, n_cells, decision, conflict_fo, now, cols, rows, fo_q, moving, unknown,
          grows, mark, cells, stats):  # pragma: no cover - compiled
    """Flood fill of cluster ``k`` from ``start`` (not yet marked); its cells are appended
    to ``cells`` from ``n_cells`` on, its ``stats[k]`` by :func:`group_stats`; returns the
    new ``n_cells``."""
    first = n_cells
    mark[start] = 1
    cells[n_cells] = start
    n_cells += 1
    head = first
    while head < n_cells:  # the cluster's cells double as the queue (breadth first)
        i = cells[head]
        head += 1
        r = i // cols
        c = i - r * cols
        if now[i] == JOINS_ANY:  # a hit-only cell joins but does not grow the cluster
            continue
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
                        or (now[j] == JOINS_ANY and dj == unknown)
                        or (fo_q > 0 and conflict_fo[j] >= fo_q)):
                    mark[j] = 1
                    cells[n_cells] = j
                    n_cells += 1
    group_stats(cells, first, n_cells, decision, conflict_fo, fo_q, moving, cols, stats, k)
    return n_cells


#: a word of 8 bytes each 1 / each with its high bit (the zero-byte test, :func:`zero_bytes`;
#: ``np.uint64(code) * BYTE_ONES``: a word of 8 bytes each ``code``)
BYTE_ONES = np.uint64(0x0101010101010101)
BYTE_HIGHS = np.uint64(0x8080808080808080)


@numba.njit(cache=True, inline="always")
def zero_bytes(x):  # pragma: no cover - compiled
    """The high bit of each zero byte of the uint64 word ``x`` (and perhaps of a 0x01 byte
    above a zero byte): non-zero iff ``x`` has a zero byte — the word-at-a-time scans of the
    object stages, 8 cells at once."""
    return (x - BYTE_ONES) & ~x & BYTE_HIGHS


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _flood(decision: np.ndarray, conflict_fo: np.ndarray, now: np.ndarray, seed_all: bool,
           cols: int, fo_q: int, moving: int, unknown: int, grows: np.ndarray,
           extra: np.ndarray,
           mark: np.ndarray, cells: np.ndarray, stats: np.ndarray, dec_words: np.ndarray,
           now_words: np.ndarray) -> tuple[int, int]:  # pragma: no cover - compiled
    """Flood fill from every seed; returns (clusters, cells). ``stats[k]``: count, seeds,
    Σrow, Σcol, min row, max row, min col, max col. ``decision``, ``conflict_fo``, ``now``
    (1: a cell a cluster may hold unless decided moving; :data:`JOINS_ANY`: a leaf cell a
    growing cluster takes if decided ``unknown``): the window's cells, flat
    (row-major, ``cols`` a row). ``seed_all``: every cell a cluster may hold seeds.
    ``dec_words``, ``now_words``: the first cells of ``decision`` and ``now`` as uint64
    words (8 cells each; empty: no skipping): the scan skips the 8 cells of a word
    in which no cell is decided moving (and, with ``seed_all``, none occupied now) — they
    hold no seed — and tests the others one by one as before."""
    total = decision.shape[0]
    rows = total // cols
    n_clusters = 0
    n_cells = 0
    for s in range(extra.shape[0]):
        start = extra[s]
        if (start < 0 or start >= total or mark[start] or not grows[decision[start]]
                or not (now[start] or decision[start] == moving)):
            continue
        n_cells = _grow(start, n_clusters, n_cells, decision, conflict_fo, now, cols, rows,
                        fo_q, moving, unknown, grows, mark, cells, stats)
        n_clusters += 1
    w_end = 8 * dec_words.shape[0]
    moving_bytes = np.uint64(moving) * BYTE_ONES
    n_words = dec_words.shape[0]
    w = 0
    while w <= n_words:
        if w < n_words:  # 8 cells at once: the words in which none may seed are skipped
            while w < n_words:
                x = dec_words[w] ^ moving_bytes  # a zero byte where decided moving
                hit = zero_bytes(x)
                if seed_all:
                    hit |= now_words[w]
                if hit != 0:
                    break
                w += 1
            if w == n_words:
                continue
            at = 8 * w
            stop = at + 8
            w += 1
        else:  # the cells after the last whole word
            at = w_end
            stop = total
            w += 1
        for start in range(at, stop):
            if mark[start]:
                continue
            d = decision[start]
            if seed_all:
                if not (d == moving or (grows[d] and now[start] == 1)):
                    continue
            elif d != moving and not (fo_q > 0 and conflict_fo[start] >= fo_q):
                continue
            n_cells = _grow(start, n_clusters, n_cells, decision, conflict_fo, now, cols,
                            rows, fo_q, moving, unknown, grows, mark, cells, stats)
            n_clusters += 1
    for m in range(n_cells):
        mark[cells[m]] = 0
    return n_clusters, n_cells


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def block_max_at(layer: np.ndarray, cells: np.ndarray) -> np.ndarray:  # pragma: no cover
    """The largest value of the 3 × 3 block of each of ``cells`` (flat indices of
    ``layer``; neighbours outside the grid left out): a cell the sensor model marks
    occupied holds the return that made it or lies next to it (a polar cell spans about a
    window cell). Compiled: a few hundred cells a frame, where numpy's per-call cost
    dominated (0.37 ms a frame of workload (a))."""
    rows, cols = layer.shape
    out = np.empty(cells.shape[0], np.float32)
    for k in range(cells.shape[0]):
        r, c = divmod(cells[k], cols)
        top = -np.inf
        for rr in range(max(r - 1, 0), min(r + 2, rows)):
            for cc in range(max(c - 1, 0), min(c + 2, cols)):
                top = max(top, layer[rr, cc])
        out[k] = top
    return out


@numba.njit(cache=True, inline="always")
def group_stats(cells, first, end, decision, conflict_fo, fo_q, moving, cols, stats, k
                ):  # pragma: no cover - compiled
    """``stats[k]`` of the group ``cells[first:end]`` (flat window cells, ``cols`` a row;
    the flood fill's clusters, :func:`_grow`, and the split's parts): count, seeds
    (decided ``moving``, or ∅_FO ≥ ``fo_q`` > 0), Σrow, Σcol, min row, max row, min col,
    max col."""
    seeds = 0
    sr = 0
    sc = 0
    r0 = 1 << 62
    r1 = -1
    c0 = 1 << 62
    c1 = -1
    for q in range(first, end):
        i = cells[q]
        r = i // cols
        c = i - r * cols
        if decision[i] == moving or (fo_q > 0 and conflict_fo[i] >= fo_q):
            seeds += 1
        sr += r
        sc += c
        r0 = min(r0, r)
        r1 = max(r1, r)
        c0 = min(c0, c)
        c1 = max(c1, c)
    stats[k, 0] = end - first
    stats[k, 1] = seeds
    stats[k, 2] = sr
    stats[k, 3] = sc
    stats[k, 4] = r0
    stats[k, 5] = r1
    stats[k, 6] = c0
    stats[k, 7] = c1


def summarise_groups(cells: np.ndarray, stats: np.ndarray, betp_moving: np.ndarray,
                     window: Window) -> Clusters:
    """Every group of ``cells`` / ``stats`` (:func:`group_stats`) as :class:`Clusters`, by
    the clustering's own formulas (:func:`_summarise` with no size or extent filter)."""
    n = stats.shape[0]
    return Clusters(*_summarise(cells, stats, n, betp_moving.reshape(-1), window.row0,
                                window.col0, float(window.resolution_m), 0, np.inf,
                                np.zeros(0, np.bool_), 0, _NO_FLAT_DECISION, window.cols, 0,
                                _STILL, _NO_HEIGHTS, np.float32(0.0), 0))


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _off_buildings(all_cells, stats, n, near, decision, leaves, conflict_fo, fo_q, moving,
                   cols, small, heights, max_height):  # pragma: no cover - compiled
    """:func:`_flood`'s ``n`` groups (``all_cells``, ``stats``) without their cells marked in
    ``near`` (flat window bytes) whose decision ``leaves`` marks, except the groups whose
    bounding box is at most ``small`` cells on each side and (``heights`` not empty: flat,
    each cell's highest return above the ground) none of whose cells is ``max_height`` or
    higher (kept whole): new (cells, stats),
    the stats of a group that lost a cell counted again (count, seeds, sums, bounds; a
    group with no cell left has count 0), the others copied."""
    used = 0
    for k in range(n):
        used += stats[k, 0]
    out_cells = np.empty(used, np.int64)
    out_stats = np.zeros((n, 8), np.int64)
    at = 0
    w = 0
    for k in range(n):
        count = stats[k, 0]
        whole = max(stats[k, 5] - stats[k, 4], stats[k, 7] - stats[k, 6]) < small
        if whole and heights.size > 0:
            # the heights are read only for a group that has cells to lose (a few a frame)
            loses = False
            for q in range(at, at + count):
                i = all_cells[q]
                if near[i] and leaves[decision[i]]:
                    loses = True
                    break
            if loses:
                for q in range(at, at + count):
                    if heights[all_cells[q]] >= max_height:
                        whole = False
                        break
        first = w
        for q in range(at, at + count):
            i = all_cells[q]
            if whole or not (near[i] and leaves[decision[i]]):
                out_cells[w] = i
                w += 1
        at += count
        kept = w - first
        if kept == count:
            out_stats[k, :] = stats[k, :]
            continue
        out_stats[k, 0] = kept
        if kept == 0:
            continue
        group_stats(out_cells, first, w, decision, conflict_fo, fo_q, moving, cols, out_stats, k)
    return out_cells, out_stats


@numba.njit(cache=True, inline="always")
def _isolated(cells, decision, cols, reach, still, heights, min_height
              ):  # pragma: no cover - compiled
    """Whether no cell within ``reach`` cells (Chebyshev) of one of ``cells`` (a small
    cluster's flat window cells), other than ``cells`` themselves, is decided ``still``,
    and (``heights`` not empty) the highest return within one cell of them
    (:func:`block_max_at`) is at least ``min_height`` above the ground."""
    if not _tall(cells, heights, min_height):
        return False
    rows = decision.shape[0] // cols
    for i in cells:
        r = i // cols
        c = i - r * cols
        for rr in range(max(r - reach, 0), min(r + reach + 1, rows)):
            for cc in range(max(c - reach, 0), min(c + reach + 1, cols)):
                j = rr * cols + cc
                if still[decision[j]] and not (cells == j).any():
                    return False
    return True


@numba.njit(cache=True, inline="always")
def _tall(cells, heights, min_height):  # pragma: no cover - compiled
    """Whether the highest return within one cell of ``cells`` (:func:`block_max_at`) is at
    least ``min_height`` above the ground (no condition with ``heights`` empty)."""
    return heights.size == 0 or block_max_at(heights, cells).max() >= min_height


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _summarise(all_cells, stats, n, betp_flat, row0, col0, res, min_cells, max_extent,
               tracked, iso_min, decision, cols, reach, still, heights, min_height,
               conflict_min):  # pragma: no cover - compiled
    """The kept clusters of :func:`_flood`'s ``n`` (:class:`Clusters`' arrays, the
    formulas of :meth:`Clusterer.clusters` op for op): at least ``min_cells`` cells (or
    ``tracked[k]``, if ``tracked`` is not empty, or at least ``conflict_min`` > 0 cells of
    which one is decided moving — ``stats[k, 1]``, the group's seeds — and :func:`_tall`
    by ``min_height``, or at least ``iso_min`` > 0 cells and :func:`_isolated` within
    ``reach`` cells of ``decision``) and a bounding box at most ``max_extent`` (m, slack
    included) on each side."""
    keep = np.zeros(n, np.bool_)
    n_kept = 0
    n_cells = 0
    first = 0
    for k in range(n):
        count = stats[k, 0]
        span_r = (stats[k, 5] - stats[k, 4] + 1) * res
        span_c = (stats[k, 7] - stats[k, 6] + 1) * res
        big_enough = count > 0 and (count >= min_cells
                                    or (tracked.shape[0] > 0 and tracked[k])
                                    or (0 < conflict_min <= count and stats[k, 1] > 0
                                        and _tall(all_cells[first:first + count], heights,
                                                  min_height)))
        if not big_enough and count > 0 and 0 < iso_min <= count:
            big_enough = _isolated(all_cells[first:first + count], decision, cols, reach,
                                   still, heights, min_height)
        first += count
        if big_enough and span_r <= max_extent and span_c <= max_extent:
            keep[k] = True
            n_kept += 1
            n_cells += count
    cells = np.empty(n_cells, np.int64)
    offsets = np.zeros(n_kept + 1, np.int64)
    centroid = np.empty((n_kept, 2))
    bbox = np.empty((n_kept, 4))
    seeds = np.empty(n_kept, np.int64)
    mean_m = np.empty(n_kept, np.float32)
    at = 0
    j = 0
    out = 0
    for k in range(n):
        count = stats[k, 0]
        if keep[k]:
            total = 0
            for q in range(at, at + count):
                cells[out] = all_cells[q]
                total += np.int64(betp_flat[all_cells[q]])
                out += 1
            offsets[j + 1] = out
            cnt = float(max(count, 1))
            centroid[j, 0] = (col0 + stats[k, 3] / cnt + 0.5) * res
            centroid[j, 1] = (row0 + stats[k, 2] / cnt + 0.5) * res
            bbox[j, 0] = (col0 + stats[k, 6]) * res
            bbox[j, 1] = (row0 + stats[k, 4]) * res
            bbox[j, 2] = (col0 + stats[k, 7] + 1) * res
            bbox[j, 3] = (row0 + stats[k, 5] + 1) * res
            seeds[j] = stats[k, 1]
            mean_m[j] = np.float32(total / cnt / 255.0)
            j += 1
        at += count
    return cells, offsets, centroid, bbox, seeds, mean_m


def ego_cell_centre(window: Window) -> tuple[float, float]:
    """(x, y) m of the centre of the window's centre cell, the one that holds the ego
    (:meth:`~evperc.geo.window.Window.centred_on`): the origin of the range in
    ``objects.centroid_sigma_per_m``, and the sensor position of
    :func:`with_return_centroids` when none is given."""
    return ((window.col0 + window.cols // 2 + 0.5) * window.resolution_m,
            (window.row0 + window.rows // 2 + 0.5) * window.resolution_m)


def with_return_centroids(clusters: Clusters, sums: np.ndarray, window: Window,
                          max_cells: int = 0, min_returns: int = 0,
                          heights: np.ndarray | None = None,
                          sensor_xy: tuple[float, float] | None = None,
                          depth_m: float = 0.0) -> Clusters:
    """``clusters`` with each centroid the mean of the scan's obstacle returns in its cells,

        c = Σ_cells (n_c · x_c + Σᵢ δᵢ) / Σ_cells n_c

    (``x_c`` a cell's centre, ``n_c`` its returns, ``δᵢ`` their offsets from the centre:
    ``sums`` (rows, cols, 3) float32 of :func:`evperc.sensor.sensor_grid`'s ``sums_out``),
    where its cells hold at least ``min_returns`` returns (and one) and it has at most
    ``max_cells`` cells (0: any size); a cluster holding fewer (a track's carried cells
    only, a sparse scanner's few returns), or a larger one, keeps the mean of its cell
    centres. ``heights`` ((rows, cols) float32, the same scan's ``heights_out``): the sums
    are read only where it is > 0 — a block the sensor grid wrote with the heights is valid
    only there —; None: wherever the count is > 0 (a block that was zeros). The result's
    ``from_returns`` says which clusters took the returns' mean (the tracker's noise floor,
    ``objects.centroid_returns_sigma_m``). A person is one or two 0.5 m cells: the mean of
    the cell centres moves by half a cell or not at all as the person walks a quarter cell a
    scan, the mean of the returns moves with the person (docs/method.md §8 "Centroids").

    With ``depth_m`` d > 0 each returns' mean is moved d further from the sensor along the
    line of sight, c' = c + d · (c − s) / |c − s| (``s`` = ``sensor_xy``, the scan's sensor
    position in the working CRS; None: the centre of the window's centre cell, which holds
    the sensor). The returns lie on the object's near side, so their mean sits in front of
    its centre — by πr/4 for a round object of radius r seen from afar (0.24 m for a person
    0.6 m across) — and swings round it as the sensor drives past: a standing person seems
    to move, a walking one lags (docs/method.md §8 "The near side's depth")."""
    if len(clusters) == 0:
        return replace(clusters, from_returns=np.zeros(0, np.bool_))
    flat = sums.reshape(-1, 3)
    top = _NO_FLAT_HEIGHTS if heights is None else np.ascontiguousarray(
        heights, np.float32).reshape(-1)
    if sensor_xy is None:
        sensor_xy = ego_cell_centre(window)
    centroid, from_returns = _return_centroids(
        clusters.cells, clusters.offsets, clusters.centroid_m, flat, top, window.row0,
        window.col0, window.cols, float(window.resolution_m), max_cells,
        float(max(min_returns, 1)), float(sensor_xy[0]), float(sensor_xy[1]),
        float(depth_m))
    return replace(clusters, centroid_m=centroid, from_returns=from_returns)


def warm_up_return_centroids() -> None:
    """Load (or compile) :func:`with_return_centroids`' kernel before the first frame."""
    for top in (_NO_FLAT_HEIGHTS, np.ones(1, np.float32)):
        _return_centroids(np.zeros(1, np.int64), np.array([0, 1], np.int64), np.zeros((1, 2)),
                          np.ones((1, 3), np.float32), top, 0, 0, 1, 0.5, 0, 1.0, 0.0, 0.0,
                          0.0)


@numba.njit(cache=True)  # keeps the GIL: a short pass over the clusters' cells
def _return_centroids(cells, offsets, cell_centroid, sums, top, row0, col0, cols, res,
                      max_cells, min_returns, sensor_x, sensor_y, depth
                      ):  # pragma: no cover - compiled
    """See :func:`with_return_centroids` (``top`` empty: no heights; ``depth`` 0: the
    returns' mean as it is)."""
    n = offsets.shape[0] - 1
    out = cell_centroid.copy()
    from_returns = np.zeros(n, np.bool_)
    checked = top.shape[0] > 0
    for k in range(n):
        if max_cells > 0 and offsets[k + 1] - offsets[k] > max_cells:
            continue
        sx = 0.0
        sy = 0.0
        count = 0.0
        for q in range(offsets[k], offsets[k + 1]):
            cell = cells[q]
            if checked and not top[cell] > 0:
                continue
            m = np.float64(sums[cell, 2])
            if m > 0.0:
                row = cell // cols
                col = cell - row * cols
                sx += m * ((col0 + col + 0.5) * res) + np.float64(sums[cell, 0])
                sy += m * ((row0 + row + 0.5) * res) + np.float64(sums[cell, 1])
                count += m
        if count >= min_returns:
            x = sx / count
            y = sy / count
            if depth > 0.0:
                dx = x - sensor_x
                dy = y - sensor_y
                r = math.sqrt(dx * dx + dy * dy)
                if r > 0.0:
                    x += depth * dx / r
                    y += depth * dy / r
            out[k, 0] = x
            out[k, 1] = y
            from_returns[k] = True
    return out, from_returns


def off_buildings_small(small_m: float, resolution_m: float) -> int:
    """``objects.off_buildings_small_m`` in cells: the bounding-box sides s (cells) with
    s · resolution ≤ small_m (2.0 m at 0.5 m cells: 4)."""
    return int(math.floor(small_m / resolution_m + 1e-9))


def isolated_reach(clearance_m: float, resolution_m: float) -> int:
    """``objects.isolated_clearance_m`` in cells: the Chebyshev distances d (cells, centre
    to centre) with d · resolution ≤ clearance (1.0 m at 0.5 m cells: 2)."""
    return int(math.floor(clearance_m / resolution_m + 1e-9))


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
        thr = params.seed_conflict_fo
        #: the stored ∅_FO is q / 255: q >= ceil(255 · threshold) seeds (0: no conflict
        #: seeds; read too by the passes that count a cluster's seeds again)
        self.fo_q = max(1, int(np.ceil(255.0 * thr - 1e-9))) if thr > 0 else 0
        self._everywhere = np.ones(n, np.uint8)  # ``now`` where the growth is not limited
        self._no_words = np.zeros(0, np.uint64)
        self._no_flags = np.zeros(0, np.bool_)
        self._groups = 0  # groups the last flood fill found (before the filters)
        self._group_cells = 0  # and the cells they hold

    def clusters(self, decision: np.ndarray, betp_moving: np.ndarray, conflict_fo: np.ndarray,
                 window: Window, extra_seeds: np.ndarray | None = None,
                 occupied_now: np.ndarray | None = None, heights: np.ndarray | None = None,
                 near_building: np.ndarray | None = None) -> Clusters:
        """The kept clusters of one frame. ``decision`` (rows, cols) uint8 codes;
        ``betp_moving`` and ``conflict_fo``: betP(M) and ∅_FO as stored (uint8, ×255);
        ``extra_seeds``: flat window indices that seed too if occupied now (a track's
        cells of the previous frame); ``occupied_now``: (rows, cols) bool, the cells holding
        a return of this scan (required with ``seeds = "occupied"``, unused otherwise);
        ``heights``: (rows, cols) float32, each cell's highest return above the local ground
        (``sensor_grid(heights_out=)``), for ``isolated_min_height_m`` and
        ``off_buildings_max_height_m`` (None: no height condition); ``near_building``:
        (rows, cols) bool, the cells within ``map.building_margin_m`` of a mapped building,
        for ``off_buildings`` (None: no map, no cell left out)."""
        if decision.shape != self.shape:
            raise ValueError(f"window {decision.shape}, the clusterer's is {self.shape}")
        extra = (np.zeros(0, np.int64) if extra_seeds is None
                 else np.ascontiguousarray(extra_seeds, np.int64))
        top = (_NO_HEIGHTS if heights is None or self.params.isolated_min_height_m <= 0
               else np.ascontiguousarray(heights, np.float32))
        seed_all = self.params.seeds == "occupied"
        if seed_all:
            if occupied_now is None or occupied_now.shape != self.shape:
                raise ValueError("seeds = 'occupied' needs the scan's occupied cells")
            # bool (viewed, no copy: a 0/1 byte), or uint8 with JOINS_ANY cells (the
            # runner's all_returns_join)
            now = (occupied_now.reshape(-1).view(np.uint8)
                   if occupied_now.dtype == np.bool_ and occupied_now.flags.c_contiguous
                   else np.ascontiguousarray(occupied_now, np.uint8).reshape(-1))
        else:
            now = self._everywhere
        flat = decision.reshape(-1)
        if seed_all or self.fo_q == 0:  # words of 8 cells for the scan's skip test
            whole = flat.size - flat.size % 8
            dec_words = flat[:whole].view(np.uint64)
            now_words = now[:whole].view(np.uint64) if seed_all else self._no_words
        else:  # seeds by ∅_FO: no skip test
            dec_words = now_words = self._no_words
        n, self._group_cells = _flood(
            flat, conflict_fo.reshape(-1), now, seed_all, self.shape[1], self.fo_q, _MOVING,
            _UNKNOWN, _GROWS, extra, self._mark, self._cells, self._stats, dec_words, now_words)
        self._groups = n
        tracked = self._no_flags
        if self.params.keep_tracked_small and len(extra):
            offsets = np.zeros(n + 1, np.int64)
            np.cumsum(self._stats[:n, 0], out=offsets[1:])
            tracked = tracked_clusters(self._cells[offsets[:-1]], extra)
        all_cells, stats = self._cells, self._stats
        if self.params.off_buildings and near_building is not None:
            if near_building.shape != self.shape:
                raise ValueError(f"near_building {near_building.shape}, the clusterer's "
                                 f"is {self.shape}")
            all_cells, stats = _off_buildings(
                self._cells, self._stats, n,
                np.ascontiguousarray(near_building, np.bool_).reshape(-1).view(np.uint8),
                flat, _OFF_BUILDINGS, conflict_fo.reshape(-1), self.fo_q, _MOVING,
                self.shape[1], off_buildings_small(self.params.off_buildings_small_m,
                                                   window.resolution_m),
                _NO_FLAT_HEIGHTS if heights is None or self.params.off_buildings_max_height_m <= 0
                else np.ascontiguousarray(heights, np.float32).reshape(-1),
                np.float32(self.params.off_buildings_max_height_m))
        return Clusters(*_summarise(all_cells, stats, n, betp_moving.reshape(-1),
                                    window.row0, window.col0, float(window.resolution_m),
                                    self.params.min_cells, self.params.max_extent_m + 1e-9,
                                    tracked, self.params.isolated_min_cells, flat,
                                    self.shape[1],
                                    isolated_reach(self.params.isolated_clearance_m,
                                                   window.resolution_m), _STILL, top,
                                    np.float32(self.params.isolated_min_height_m),
                                    self.params.small_conflict_min_cells))

    def groups(self) -> tuple[np.ndarray, np.ndarray]:
        """Every 8-connected group of the last :meth:`clusters` call, before the size and
        extent filters: (cells, sizes) — flat window cells, group after group, and each
        group's cell count. Views of the scratch buffers: valid until the next call."""
        return self._cells[:self._group_cells], self._stats[:self._groups, 0]
