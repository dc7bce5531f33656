"""The object stages of one frame in a row (docs/method.md, "Objects"): clusters
(:mod:`evperc.objects.clusters`) of the cells seen occupied now (or seeded by the frame's
moving cells and the footprints of the tracks that moved), the split of the clusters shared
by tracks that move apart (:mod:`evperc.objects.split`), then the tracker
(:mod:`evperc.objects.tracking`), then :func:`fill_moving`, which decides the cells of the
moving objects ``moving``.

Inputs are a frame's stored outputs (decision, betP(M) and ∅_FO as uint8 ×255, the window,
the stamp) and the cells holding a return of the scan: the stage does not depend on how the
fusion decided them."""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

from evperc.fusion.twin import DECISION_CODES
from evperc.geo.window import Window
from evperc.objects.clusters import (
    BYTE_ONES,
    Clusterer,
    ClusterParams,
    block_max_at,
    with_return_centroids,
    zero_bytes,
)
from evperc.objects.split import SplitParams, Splitter
from evperc.objects.tracking import TrackerState, TrackingParams, footprint_seeds, track_step

MOVING = DECISION_CODES["moving"]
STATIC = DECISION_CODES["static"]


def objects_enabled(config: dict[str, Any]) -> bool:
    """Whether a run with ``config`` computes objects (a config written before the
    ``[objects]`` table existed, e.g. an old run's manifest on resume: no)."""
    return bool(config.get("objects", {}).get("enabled", False))


def moving_min_cluster_cells(config: dict[str, Any]) -> int:
    """``objects.moving_min_cluster_cells`` (0: off, and without the object stage)."""
    if not objects_enabled(config):
        return 0
    return int(config["objects"].get("moving_min_cluster_cells", 0))


def moving_min_height_m(config: dict[str, Any]) -> float:
    """``objects.moving_min_height_m`` (0: off, and without the small-group rule)."""
    if moving_min_cluster_cells(config) <= 0:
        return 0.0
    return float(config["objects"].get("moving_min_height_m", 0.0))


def moving_needs_object(config: dict[str, Any]) -> bool:
    """Whether a cell stays ``moving`` only in a moving object (``objects.moving_needs_object``;
    no: without the object stage)."""
    return objects_enabled(config) and bool(config["objects"]["moving_needs_object"])


def fills_decision(config: dict[str, Any]) -> bool:
    """Whether the moving objects' cells are decided ``moving`` (``objects.fill_moving``)."""
    return objects_enabled(config) and bool(config["objects"].get("fill_moving", False))


class ObjectStage:
    """Clusters and tracks over windows of one shape."""

    def __init__(self, config: dict[str, Any], shape: tuple[int, int]) -> None:
        self.cluster_params = ClusterParams.from_config(config)
        self.tracking_params = TrackingParams.from_config(config)
        self.clusterer = Clusterer(self.cluster_params, shape)
        self.splitter = Splitter(SplitParams.from_config(config), shape, self.clusterer.fo_q)
        #: objects.moving_min_cluster_cells: the fusion's moving cells of smaller clusters
        #: are decided static (:func:`unfill_small`); 0 = off
        self.moving_min_cells = moving_min_cluster_cells(config)
        #: flat window cells decided moving whose cluster is smaller than moving_min_cells,
        #: of the last :meth:`step` (empty when off)
        self.small_moving = np.zeros(0, np.int64)
        #: objects.moving_min_height_m: only the small groups whose highest return of the
        #: scan is lower than this above the local ground are listed; 0 = every small group
        self.moving_min_height = moving_min_height_m(config)
        #: objects.isolated_min_height_m, where a rule reads it — the isolated clusters' or
        #: the small conflicting clusters' (docs/method.md §8 step 1) — else 0
        p = self.cluster_params
        self.isolated_min_height = (p.isolated_min_height_m
                                    if p.isolated_min_cells > 0 or p.small_conflict_min_cells > 0
                                    else 0.0)

    @property
    def needs_heights(self) -> bool:
        """Whether :meth:`step` uses the cells' highest returns (``heights``)."""
        p = self.cluster_params
        return (self.moving_min_height > 0 or self.isolated_min_height > 0
                or (p.off_buildings and p.off_buildings_max_height_m > 0))

    @property
    def needs_return_sums(self) -> bool:
        """Whether :meth:`step` uses the cells' return sums (``objects.centroid =
        "returns"``)."""
        return self.cluster_params.centroid == "returns"

    def step(self, state: TrackerState, decision: np.ndarray, betp_moving: np.ndarray,
             conflict_fo: np.ndarray, window: Window, stamp_ns: int,
             occupied_now: np.ndarray | None = None, heights: np.ndarray | None = None,
             near_building: np.ndarray | None = None, return_sums: np.ndarray | None = None,
             sensor_xy: tuple[float, float] | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
        """The frame's reported objects and their cells (:func:`track_step`); ``state``
        is updated in place. ``occupied_now``: (rows, cols) bool, the cells holding a
        return of this scan; ``heights``: (rows, cols) float32, each cell's highest return
        above the local ground (``sensor_grid(heights_out=)``), for
        ``objects.moving_min_height_m`` and ``isolated_min_height_m`` (None: no height
        condition); ``near_building``: (rows, cols) bool, the cells within
        ``map.building_margin_m`` of a mapped building, for
        ``objects.clusters_off_buildings`` (None: no map); ``return_sums``: (rows, cols, 3)
        float32, each cell's returns' offset sums and count (``sensor_grid(sums_out=)``), for
        ``objects.centroid = "returns"`` (None: the cell centres' mean); read only where
        ``heights`` > 0 when ``heights`` is given (the sensor grid writes the two in one pass
        and leaves the other cells' sums as they were); ``sensor_xy``: the scan's sensor
        position (working CRS, m), the line of sight of ``objects.centroid_depth_m`` (None:
        the window's centre cell)."""
        seeds = footprint_seeds(state, window)
        clusters = self.clusterer.clusters(decision, betp_moving, conflict_fo, window, seeds,
                                           occupied_now, heights, near_building)
        self.list_small_moving(decision, heights)
        clusters = self.splitter.split(clusters, state, window, stamp_ns, decision,
                                       betp_moving, conflict_fo)
        if return_sums is not None and self.needs_return_sums:
            p = self.cluster_params
            clusters = with_return_centroids(clusters, return_sums, window,
                                             p.centroid_max_cells, p.centroid_min_returns,
                                             heights, sensor_xy, p.centroid_depth_m)
        return track_step(state, clusters, window, stamp_ns, self.tracking_params, decision,
                          near_building)

    def list_small_moving(self, decision: np.ndarray, heights: np.ndarray | None) -> None:
        """:attr:`small_moving` of the frame whose clusters were just made (every group of
        the same flood fill, unfiltered; nothing when the rule is off)."""
        if self.moving_min_cells > 0:
            self.small_moving = small_moving_cells(
                *self.clusterer.groups(), decision, self.moving_min_cells,
                heights if self.moving_min_height > 0 else None, self.moving_min_height)

    def history(self) -> int:
        return self.tracking_params.history_frames


def scan_cells(free: np.ndarray, occupied: np.ndarray, heights: np.ndarray | None
               ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """The scan's cells as the object stage, the footprint completion, the vehicle boxes and
    the backfill's held frames read them: bool layers of the cells the scan speaks of
    (m({F}) > 0 or m({O}) > 0), of those holding an obstacle return (``heights`` > 0; None
    without ``heights``) and of those the sensor model marks occupied (m({O}) > 0: the
    clusters' ``occupied_now``) — an eighth of the bytes of the float32 layers they are made
    from, for the passes that read them at scattered cells and the frames held in flight.
    One compiled pass that releases the GIL (the runner makes them beside the sensor grid,
    in the decode thread, while the grid is in that core's cache)."""
    speaks = np.empty(free.shape, np.bool_)
    occupied_now = np.empty(free.shape, np.bool_)
    returns = None if heights is None else np.empty(free.shape, np.bool_)
    _scan_cells(np.ascontiguousarray(free, np.float32).reshape(-1),
                np.ascontiguousarray(occupied, np.float32).reshape(-1),
                _NO_LAYER if heights is None
                else np.ascontiguousarray(heights, np.float32).reshape(-1),
                heights is not None, speaks.reshape(-1), occupied_now.reshape(-1),
                _NO_FLAGS if returns is None else returns.reshape(-1))
    return speaks, returns, occupied_now


_NO_LAYER = np.zeros(0, np.float32)
_NO_FLAGS = np.zeros(0, np.bool_)


@numba.njit(cache=True, nogil=True)
def _scan_cells(free, occupied, heights, has_heights, speaks, occupied_now, returns
                ):  # pragma: no cover - compiled
    zero = np.float32(0.0)
    for i in range(free.shape[0]):
        o = occupied[i] > zero
        occupied_now[i] = o
        speaks[i] = (free[i] > zero) | o
    if has_heights:
        for i in range(free.shape[0]):
            returns[i] = heights[i] > zero


def fill_moving(decision: np.ndarray, moving_cells: np.ndarray) -> int:
    """Decide ``moving`` the cells of the frame's moving objects (``decision``, a frame's
    uint8 codes, changed in place; ``moving_cells``: their flat window indices,
    :func:`evperc.output.objects.moving_object_cells`); returns the cells changed. The masses
    are not changed (docs/method.md §8: why the object decision is a decision, not
    evidence)."""
    flat = decision.reshape(-1)
    changed = int(np.count_nonzero(flat[moving_cells] != MOVING))
    flat[moving_cells] = MOVING
    return changed


def small_moving_cells(group_cells: np.ndarray, sizes: np.ndarray, decision: np.ndarray,
                       min_cells: int, heights: np.ndarray | None = None,
                       min_height: float = 0.0, with_groups: bool = False
                       ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """The flat window cells decided ``moving`` in the groups of fewer than ``min_cells``
    cells (``group_cells``, ``sizes``: every group of the frame, no size or extent filter,
    :meth:`evperc.objects.clusters.Clusterer.groups`). With ``heights`` (each cell's highest
    return above the local ground), only the groups whose highest return within one cell of
    their cells (:func:`block_max_at`) is lower than ``min_height``: a ground point the ground
    split called an obstacle, not a person. ``with_groups``: also each cell's group (the
    index in ``sizes``), for :mod:`evperc.objects.support`."""
    use_heights = heights is not None
    top = heights if use_heights else _NO_HEIGHTS
    # contiguous whatever the group count (a column of the clusterer's stats is contiguous
    # only for 0 or 1 group): one compiled signature, loaded by the warm-up, not frame 1
    cells, groups = _small_moving(group_cells, np.ascontiguousarray(sizes),
                                  decision.reshape(-1), int(min_cells),
                                  np.ascontiguousarray(top, np.float32), use_heights,
                                  np.float32(min_height), MOVING)
    return (cells, groups) if with_groups else cells


_NO_HEIGHTS = np.zeros((1, 1), np.float32)


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _small_moving(group_cells, sizes, decision, min_cells, heights, use_heights, min_height,
                  moving):  # pragma: no cover - compiled
    """:func:`small_moving_cells` in one pass over the groups (numpy's per-call cost was
    0.1 ms a frame of workload (a) for a few hundred cells)."""
    out = np.empty(group_cells.shape[0], np.int64)
    group_of = np.empty(group_cells.shape[0], np.int64)
    n = 0
    start = 0
    for g in range(sizes.shape[0]):
        size = sizes[g]
        if size < min_cells:
            low = True
            if use_heights:
                top = block_max_at(heights, group_cells[start:start + size])
                low = top.max() < min_height
            if low:
                for k in range(start, start + size):
                    if decision[group_cells[k]] == moving:
                        out[n] = group_cells[k]
                        group_of[n] = g
                        n += 1
        start += size
    return out[:n].copy(), group_of[:n].copy()


def unfill_small(decision: np.ndarray, small_cells: np.ndarray,
                 moving_cells: np.ndarray | None) -> int:
    """Decide ``static`` the cells ``small_cells`` (:func:`small_moving_cells`: the fusion
    decided them moving, their cluster is smaller than ``objects.moving_min_cluster_cells``)
    that no moving object holds (``moving_cells``, flat; a completed footprint may cover
    them); ``decision`` changed in place, returns the cells changed.

    Why (docs/notes, issue "ibeofp"): on ibeo4 most false moving cells are one or two cells
    of a pole, bollard or trunk at 20-50 m, or a lone cell in the open, that a beam passed
    beside (the cell seen free) and hit a scan later: the conflict through the motion gate,
    in a group too small to be an object. ``static``: the cell holds a return; which static
    class, the decision does not say (the masses are not changed, as for the fill)."""
    if small_cells.size == 0:
        return 0
    held = _NO_CELLS if moving_cells is None else np.asarray(moving_cells, np.int64)
    return int(_unfill(decision.reshape(-1), np.asarray(small_cells, np.int64), held,
                       STATIC, MOVING))


_NO_CELLS = np.zeros(0, np.int64)


def unfill_unconfirmed(decision: np.ndarray, moving_cells: np.ndarray | None,
                       small_moving: np.ndarray | None = None) -> int:
    """``objects.moving_needs_object``: decide ``static`` every cell decided ``moving`` that
    no moving object holds (``moving_cells``, flat) and that is not in ``small_moving`` (the
    moving cells of the groups under ``moving_min_cluster_cells``, which their own rule,
    :func:`unfill_small`, judged: too small to be tracked, so no object can confirm them);
    ``decision`` changed in place, returns the cells changed. Run on the frame's final
    object list (after the backfill, when on).

    Why (docs/method.md §8 step 9): the fusion's moving cells outside any moving object are
    a conflict no track confirms — on SemanticKITTI 09, where nothing moves, 194 of 277
    static points decided moving; a moving object's own frames before its report are the
    backfill's to fill. ``static``: the cell holds a return (as :func:`unfill_small`)."""
    held = _NO_CELLS if moving_cells is None else np.asarray(moving_cells, np.int64)
    if small_moving is not None and small_moving.size:
        held = np.concatenate([held, np.asarray(small_moving, np.int64)])
    flat = decision.reshape(-1)
    words = flat[:flat.size - flat.size % 8].view(np.uint64)
    return int(_unfill_unheld(flat, words, held, STATIC, MOVING))


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _unfill_unheld(flat, words, held, static, moving):  # pragma: no cover - compiled
    """:func:`unfill_unconfirmed`: every cell of ``flat`` decided ``moving`` and not in
    ``held`` decided ``static``; returns how many. One scan of the window (``flat ==
    MOVING`` and ``np.flatnonzero`` in numpy released the GIL twice a frame) that skips the
    8 cells of a word of ``words`` (the whole words of ``flat``) none of which is decided
    moving, as the clusters' flood fill does."""
    order = np.sort(held)
    moving_bytes = np.uint64(moving) * BYTE_ONES
    changed = 0
    for w in range(words.shape[0] + 1):
        if w < words.shape[0]:
            x = words[w] ^ moving_bytes  # a zero byte where decided moving
            if zero_bytes(x) == 0:
                continue
            first, last = 8 * w, 8 * w + 8
        else:  # the cells after the last whole word
            first, last = 8 * words.shape[0], flat.shape[0]
        for c in range(first, last):
            if flat[c] != moving:
                continue
            at = np.searchsorted(order, c)
            if at < order.shape[0] and order[at] == c:
                continue
            flat[c] = static
            changed += 1
    return changed


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _unfill(flat, cells, held, static, moving):  # pragma: no cover - compiled
    """:func:`unfill_small`: ``cells`` not in ``held`` decided ``static``; returns how many
    of them were ``moving`` (a binary search in the sorted ``held``: np.isin cost up to
    1 ms on some frames)."""
    order = np.sort(held)
    changed = 0
    for c in cells:
        at = np.searchsorted(order, c)
        if at < order.shape[0] and order[at] == c:
            continue
        if flat[c] == moving:
            changed += 1
        flat[c] = static
    return changed
