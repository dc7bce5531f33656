"""The tracking pass as it was before the compiled rewrite (evperc main d379f5e), kept as the
reference the pipeline's pass is tested against (tests/objects/test_tracking_reference.py,
test_passes_reference.py), like tests/fusion/reference.py is for the fusion. Not used by
the pipeline. Original docstring:

Tracks of clusters from frame to frame, and the motion test per object (docs/method.md,
"Objects"; association after Dynablox, the motion test after DOGMa, Nuss et al. IJRR 2018).

Association: each track predicts its centroid at the new stamp, ``c + v·Δt`` (``v`` its
last velocity, 0 before it has one); track–cluster pairs whose distance is at most
``gate_m`` are taken greedily, nearest first (ties: lower track index, then lower cluster
index), each track and cluster at most once. A cluster left over starts a new track (new
id: ids count up from 1 and are never reused). A track without a cluster is kept for
``max_missed_frames`` frames, then dropped.

Motion: over the track's last ``history_frames`` centroids ``(tᵢ, pᵢ)`` (associated frames
only, ``tᵢ`` the stamps), the least-squares constant-velocity fit per axis,

    v = Σ (tᵢ − t̄)(pᵢ − p̄) / S,   S = Σ (tᵢ − t̄)²,

with the centroid noise σ² = max(σ₀², RSS / (2(n − 2))) (σ₀ = ``centroid_sigma_m``; the
residuals of both axes pooled, 2(n − 2) degrees of freedom, when n > 2), so each velocity
component has variance s² = σ² / S and Σ = s² I. The object moves if its speed passes both
``|v| ≥ moving_speed_m_per_s`` and the Mahalanobis test ``vᵀ Σ⁻¹ v = |v|² / s² ≥
motion_test`` (DOGMa's 4: two standard deviations), and the grid has shown motion evidence of
one kind (below) in at least ``motion_evidence_frames`` of the frames in which the velocity
passed the test (counted per kind over the track's life). A centroid alone is no proof: the
cluster of a parked car grows as the ego drives past and more of it comes into view, and its
centroid then drifts at a walking pace. Evidence of a frame, from the grid:

- *conflict*: the cluster holds at least ``conflict_cells`` cells decided ``moving`` (the
  fusion's ∅_FO, through the motion gate: free before, occupied now);
- *vacated*: of the cells the track held ``vacated_frames`` associations ago, a share of at
  least ``vacated_share`` is decided ``free`` now (occupied then, seen free now: the object
  left them). A static object's cells stay occupied; a car driving ahead of the ego, which
  never conflicts, frees the road behind it at every scan.

A track is reported once it has been
associated in ``confirm_frames`` frames, and in a frame in which it is associated: as
``moving`` while the test passes, as ``stopped`` once it has moved and the test fails.
Tracks that never moved are not reported (a false seed at a wall grows a cluster that
stays put). A track that has moved seeds the next frame's clusters with its cells
(:func:`footprint_seeds`): a stopped car, no longer decided moving, keeps its cluster
while its cells stay occupied."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from evperc.fusion.twin import DECISION_CODES
from evperc.geo.window import Window
from evperc.objects.clusters import Clusters
from evperc.objects.tracking import TrackingParams  # noqa: F401 - the same parameters
from evperc.output.objects import OBJECT_DTYPE, OBJECT_STATES

_FREE = DECISION_CODES["free"]


@dataclass
class Track:
    """One tracked object."""

    track_id: int
    hits: int = 0                # frames associated with a cluster
    missed: int = 0              # consecutive frames without one
    ever_moving: bool = False
    t_ns: list[int] = field(default_factory=list)          # recent associated stamps
    xy: list[tuple[float, float]] = field(default_factory=list)  # their centroids
    velocity: tuple[float, float] = (0.0, 0.0)
    sigma: float = math.inf      # standard deviation of each velocity component
    moving: bool = False         # the motion test passed at the last association
    #: global lattice (iy, ix) of the cells of the last associated cluster (int64 (m, 2))
    footprint: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    conflict_evidence: int = 0   # frames with conflict evidence (module docstring)
    vacated_evidence: int = 0    # frames with vacated evidence
    #: the footprints of the previous associations, oldest first (at most vacated_frames)
    past: list[np.ndarray] = field(default_factory=list)
    #: associated at least once with a cluster at least ego_clearance_m from the sensor
    ever_far: bool = True


def velocity_fit(t_s: Sequence[float], xy: Sequence[Sequence[float]], sigma0: float
                 ) -> tuple[tuple[float, float], float]:
    """Least-squares constant velocity of centroids ``xy`` (n pairs) at times ``t_s`` (n)
    and the standard deviation of each component (module docstring); ``inf`` for n < 2.
    Plain floats: n is at most ``history_frames``, and numpy's per-call cost would be
    most of the tracker's time with tens of tracks."""
    n = len(t_s)
    if n < 2:
        return (0.0, 0.0), math.inf
    tm = sum(t_s) / n
    xm = sum(p[0] for p in xy) / n
    ym = sum(p[1] for p in xy) / n
    s = stx = sty = 0.0
    for t, (x, y) in zip(t_s, xy, strict=True):
        dt = t - tm
        s += dt * dt
        stx += dt * (x - xm)
        sty += dt * (y - ym)
    if s <= 0.0:
        return (0.0, 0.0), math.inf
    vx, vy = stx / s, sty / s
    var = sigma0 * sigma0
    if n > 2:
        rss = 0.0
        for t, (x, y) in zip(t_s, xy, strict=True):
            dt = t - tm
            ex = x - xm - vx * dt
            ey = y - ym - vy * dt
            rss += ex * ex + ey * ey
        var = max(var, rss / (2 * (n - 2)))
    return (vx, vy), math.sqrt(var / s)


def velocity_fits(t_s: np.ndarray, xy: np.ndarray, count: np.ndarray,
                  sigma0: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`velocity_fit` of many tracks at once: ``t_s`` (n, H) and ``xy`` (n, H, 2), of
    which the first ``count[i]`` columns of row i are the track's (the rest ignored);
    returns v (n, 2) and the standard deviation (n,), ``inf`` (and v = 0) where count < 2 or
    the stamps do not differ. Equal to :func:`velocity_fit` row by row up to round-off (the
    sums are taken in another order; tests/objects/test_tracking.py)."""
    n, h = t_s.shape
    valid = np.arange(h)[None, :] < count[:, None]
    k = np.maximum(count, 1).astype(np.float64)
    t = np.where(valid, t_s, 0.0)
    x = np.where(valid, xy[..., 0], 0.0)
    y = np.where(valid, xy[..., 1], 0.0)
    dt = np.where(valid, t - (t.sum(axis=1) / k)[:, None], 0.0)
    dx = np.where(valid, x - (x.sum(axis=1) / k)[:, None], 0.0)
    dy = np.where(valid, y - (y.sum(axis=1) / k)[:, None], 0.0)
    s = (dt * dt).sum(axis=1)
    ok = (count >= 2) & (s > 0.0)
    s_safe = np.where(ok, s, 1.0)
    vx = np.where(ok, (dt * dx).sum(axis=1) / s_safe, 0.0)
    vy = np.where(ok, (dt * dy).sum(axis=1) / s_safe, 0.0)
    ex = dx - vx[:, None] * dt
    ey = dy - vy[:, None] * dt
    rss = np.where(valid, ex * ex + ey * ey, 0.0).sum(axis=1)
    dof = np.maximum(2 * (count - 2), 1)
    var = np.where(count > 2, np.maximum(sigma0 * sigma0, rss / dof), sigma0 * sigma0)
    sigma = np.where(ok, np.sqrt(var / s_safe), np.inf)
    return np.stack([vx, vy], axis=1), sigma


def is_moving(v: Sequence[float], sigma: float, params: TrackingParams) -> bool:
    """Speed threshold and Mahalanobis test ``|v|² / s² ≥ motion_test``."""
    speed2 = v[0] * v[0] + v[1] * v[1]
    if not math.isfinite(sigma) or speed2 < params.moving_speed_m_per_s ** 2:
        return False
    return sigma == 0.0 or speed2 / (sigma * sigma) >= params.motion_test


class TrackerState:
    """The tracks and the next id; part of the run's checkpointed state."""

    def __init__(self) -> None:
        self.next_id = 1
        self.tracks: list[Track] = []
        self.prev_ns: int | None = None

    def copy(self) -> TrackerState:
        other = TrackerState()
        other.next_id, other.prev_ns = self.next_id, self.prev_ns
        other.tracks = [Track(t.track_id, t.hits, t.missed, t.ever_moving, list(t.t_ns),
                              list(t.xy), t.velocity, t.sigma, t.moving, t.footprint.copy(),
                              t.conflict_evidence, t.vacated_evidence,
                              [f.copy() for f in t.past], t.ever_far)
                        for t in self.tracks]
        return other

    def to_arrays(self, prefix: str = "objects_") -> dict[str, np.ndarray]:
        """Flat arrays for the checkpoint (:meth:`from_arrays` reads them back exactly)."""
        n = len(self.tracks)
        history = max([len(t.t_ns) for t in self.tracks], default=0)
        hist_t = np.zeros((n, history), np.int64)
        hist_xy = np.zeros((n, history, 2), np.float64)
        hist_n = np.zeros(n, np.int64)
        for i, t in enumerate(self.tracks):
            k = len(t.t_ns)
            hist_n[i] = k
            hist_t[i, :k] = t.t_ns
            hist_xy[i, :k] = t.xy
        fps = [t.footprint for t in self.tracks]
        depth = max([len(t.past) for t in self.tracks], default=0)
        past_n = np.full((n, depth), -1, np.int64)  # cells of each past footprint, -1: none
        pasts = []
        for i, t in enumerate(self.tracks):
            for k, f in enumerate(t.past):
                past_n[i, k] = len(f)
                pasts.append(f)
        return {f"{prefix}next_id": np.int64(self.next_id),
                f"{prefix}prev_ns": np.int64(-1 if self.prev_ns is None else self.prev_ns),
                f"{prefix}id": np.array([t.track_id for t in self.tracks], np.int64),
                f"{prefix}hits": np.array([t.hits for t in self.tracks], np.int64),
                f"{prefix}missed": np.array([t.missed for t in self.tracks], np.int64),
                f"{prefix}flags": np.array([[t.ever_moving, t.moving, t.ever_far]
                                            for t in self.tracks], np.uint8).reshape(n, 3),
                f"{prefix}hist_n": hist_n, f"{prefix}hist_t": hist_t,
                f"{prefix}hist_xy": hist_xy,
                f"{prefix}velocity": np.array([t.velocity for t in self.tracks],
                                              np.float64).reshape(n, 2),
                f"{prefix}sigma": np.array([t.sigma for t in self.tracks], np.float64),
                f"{prefix}fp_n": np.array([len(f) for f in fps], np.int64),
                f"{prefix}fp": (np.concatenate(fps) if fps else np.zeros((0, 2), np.int64)),
                f"{prefix}evidence": np.array([(t.conflict_evidence, t.vacated_evidence)
                                               for t in self.tracks], np.int64).reshape(n, 2),
                f"{prefix}past_n": past_n,
                f"{prefix}past": (np.concatenate(pasts) if pasts
                                  else np.zeros((0, 2), np.int64))}

    @staticmethod
    def from_arrays(arrays: Any, prefix: str = "objects_") -> TrackerState | None:
        """The state saved by :meth:`to_arrays`, or None if ``arrays`` holds none."""
        if f"{prefix}next_id" not in arrays:
            return None
        state = TrackerState()
        state.next_id = int(arrays[f"{prefix}next_id"])
        prev = int(arrays[f"{prefix}prev_ns"])
        state.prev_ns = None if prev < 0 else prev
        fp = arrays[f"{prefix}fp"]
        ends = np.cumsum(arrays[f"{prefix}fp_n"])
        has_past = f"{prefix}past_n" in arrays  # checkpoints written before motion evidence
        past_n = arrays[f"{prefix}past_n"] if has_past else None
        past = arrays[f"{prefix}past"] if has_past else None
        past_at = 0
        for i, tid in enumerate(arrays[f"{prefix}id"]):
            k = int(arrays[f"{prefix}hist_n"][i])
            ever, moving, *far = (bool(v) for v in arrays[f"{prefix}flags"][i])
            vx, vy = (float(v) for v in arrays[f"{prefix}velocity"][i])
            state.tracks.append(Track(
                int(tid), int(arrays[f"{prefix}hits"][i]), int(arrays[f"{prefix}missed"][i]),
                ever, [int(v) for v in arrays[f"{prefix}hist_t"][i, :k]],
                [(float(x), float(y)) for x, y in arrays[f"{prefix}hist_xy"][i, :k]],
                (vx, vy), float(arrays[f"{prefix}sigma"][i]), moving,
                np.array(fp[ends[i] - arrays[f"{prefix}fp_n"][i]:ends[i]], np.int64),
                ever_far=far[0] if far else True))
            if has_past:
                t = state.tracks[-1]
                t.conflict_evidence, t.vacated_evidence = (
                    int(v) for v in arrays[f"{prefix}evidence"][i])
                for m in past_n[i]:
                    if m < 0:
                        break
                    t.past.append(np.array(past[past_at:past_at + m], np.int64))
                    past_at += int(m)
        return state


def footprint_seeds(state: TrackerState, window: Window) -> np.ndarray:
    """Flat window indices of the cells held in their last frame by the tracks that have
    moved (extra seeds for :meth:`evperc.objects.clusters.Clusterer.clusters`)."""
    parts = [t.footprint for t in state.tracks if t.ever_moving and len(t.footprint)]
    if not parts:
        return np.zeros(0, np.int64)
    return window_indices(np.concatenate(parts), window)


def window_indices(lattice: np.ndarray, window: Window) -> np.ndarray:
    """Flat window indices (row · cols + col) of the global lattice cells (iy, ix) that lie
    in ``window``; the others are left out."""
    r = lattice[:, 0] - window.row0
    c = lattice[:, 1] - window.col0
    inside = (r >= 0) & (r < window.rows) & (c >= 0) & (c < window.cols)
    return r[inside] * window.cols + c[inside]


def _associate(predicted: np.ndarray, centroids: np.ndarray, gate_m: float
               ) -> list[tuple[int, int]]:
    """Greedy nearest-first pairs (track, cluster) within the gate."""
    if len(predicted) == 0 or len(centroids) == 0:
        return []
    d = np.hypot(predicted[:, None, 0] - centroids[None, :, 0],
                 predicted[:, None, 1] - centroids[None, :, 1])
    ti, ci = np.nonzero(d <= gate_m)
    order = np.lexsort((ci, ti, d[ti, ci]))
    used_t: set[int] = set()
    used_c: set[int] = set()
    pairs = []
    for k in order:
        t, c = int(ti[k]), int(ci[k])
        if t in used_t or c in used_c:
            continue
        used_t.add(t)
        used_c.add(c)
        pairs.append((t, c))
    return pairs


def vacated_share(footprint: np.ndarray, decision: np.ndarray, window: Window) -> float:
    """Share of ``footprint``'s cells (global lattice (iy, ix)) decided ``free`` now; cells
    outside the window count as not free."""
    if len(footprint) == 0:
        return 0.0
    cells = window_indices(footprint, window)
    free = int(np.count_nonzero(decision.reshape(-1)[cells] == _FREE))
    return free / len(footprint)


def expire_evidence(count: int, need: int, still: bool) -> int:
    """``objects.evidence_expires``: a count kept at most ``need``, one less in an
    association whose fitted speed is under the speed floor (``still``), never below 0."""
    kept = min(count, need)
    return max(kept - 1, 0) if still else kept


def frame_evidence(t: Track, clusters: Clusters, c: int, decision: np.ndarray | None,
                   window: Window, params: TrackingParams) -> tuple[int, int]:
    """The motion evidence (conflict, vacated) that track ``t``'s association with cluster
    ``c`` adds this frame (module docstring), counted in the frames whose velocity passes
    the test (or, with ``evidence_every_frame``, in every associated frame). Arrival: with
    ``arrival_share`` > 0, a cluster of which at least that share of the cells is decided
    moving (free before, occupied now: the object arrived in cells seen free), and at least
    ``arrival_min_cells`` of them, counts ``motion_evidence_frames`` frames of conflict
    evidence at once. A cluster of at most ``single_conflict_max_cells`` cells (added after
    the compiled rewrite) needs one cell decided moving, not ``conflict_cells``. Growth (added
    after the compiled rewrite, ``growth_kept_share`` > 0): a cluster of at least
    ``growth_min_cells`` cells that keeps that share of ``t.past[0]``'s cells (a cell kept
    when the cluster holds one within ``growth_reach_cells``) and holds ``growth_more_cells``
    more adds nothing; with ``growth_early``, also before ``t.past`` is full."""
    seeds = int(clusters.seeds[c])
    size = int(clusters.offsets[c + 1] - clusters.offsets[c])
    full = len(t.past) == params.vacated_frames
    if (params.growth_kept_share > 0 and size >= params.growth_min_cells
            and (full or (params.growth_early and len(t.past) > 0))):
        old = t.past[0]
        r, col = np.divmod(clusters.cells_of(c), window.cols)
        held = set(zip((r + window.row0).tolist(), (col + window.col0).tolist(), strict=True))
        reach = range(-params.growth_reach_cells, params.growth_reach_cells + 1)
        kept = sum(any((int(iy) + dy, int(ix) + dx) in held for dy in reach for dx in reach)
                   for iy, ix in old)
        if (kept >= params.growth_kept_share * len(old)
                and size >= len(old) + params.growth_more_cells):
            return 0, 0
    least = 1 if size <= params.single_conflict_max_cells else params.conflict_cells
    conflict = int(seeds >= least)
    if conflict and params.arrival_share > 0:
        if seeds >= params.arrival_min_cells and seeds >= params.arrival_share * size:
            conflict = max(1, params.motion_evidence_frames)
    vacated = int(decision is not None and len(t.past) == params.vacated_frames
                  and vacated_share(t.past[0], decision, window) >= params.vacated_share)
    return conflict, vacated


def track_step(state: TrackerState, clusters: Clusters, window: Window, stamp_ns: int,
               params: TrackingParams, decision: np.ndarray | None = None,
               near_building: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Associate this frame's ``clusters`` with ``state``'s tracks (updated in place);
    returns the frame's reported objects (records of
    :data:`evperc.output.objects.OBJECT_DTYPE`, by track id) and their cells (flat window
    indices, concatenated in record order). ``decision``: the frame's decided cells, for
    the vacated evidence (None: no vacated evidence). ``near_building`` (added with
    ``facade_max_speed_m_per_s``, after the compiled rewrite): the widened buildings' cells;
    an association with a cluster all of whose cells are there passes no motion test
    faster than that speed."""
    dt_s = 0.0 if state.prev_ns is None else (stamp_ns - state.prev_ns) * 1e-9
    state.prev_ns = stamp_ns
    tracks = state.tracks
    predicted = np.array([(t.xy[-1][0] + t.velocity[0] * dt_s,
                           t.xy[-1][1] + t.velocity[1] * dt_s) for t in tracks],
                         np.float64).reshape(len(tracks), 2)
    pairs = _associate(predicted, clusters.centroid_m, params.gate_m)
    of_track = dict(pairs)
    taken = {c for _, c in pairs}
    for c in range(len(clusters)):
        if c not in taken:
            tracks.append(Track(state.next_id))
            state.next_id += 1
            of_track[len(tracks) - 1] = c
    # global lattice (iy, ix) of every cluster cell, once for the frame
    r, col = np.divmod(clusters.cells, window.cols)
    lattice = np.stack([r + window.row0, col + window.col0], axis=1)
    reported: list[tuple[int, int]] = []  # (track index, cluster index)
    survivors: list[Track] = []
    associated = [(i, t, c) for i, t in enumerate(tracks)
                  if (c := of_track.get(i)) is not None]
    history = params.history_frames
    hist_t = np.zeros((len(associated), history))
    hist_xy = np.zeros((len(associated), history, 2))
    count = np.zeros(len(associated), np.int64)
    for k, (_, t, c) in enumerate(associated):
        t.t_ns.append(int(stamp_ns))
        t.xy.append((float(clusters.centroid_m[c, 0]), float(clusters.centroid_m[c, 1])))
        del t.t_ns[:-history], t.xy[:-history]
        m = count[k] = len(t.t_ns)
        hist_t[k, :m] = [(ns - stamp_ns) * 1e-9 for ns in t.t_ns]
        hist_xy[k, :m] = t.xy
    # one vectorised fit for the frame's tracks (velocity_fit is its per-track reference)
    sigma0 = params.centroid_sigma_m
    returns_floor = (params.centroid_returns_sigma_m > 0
                     and getattr(clusters, "from_returns", None) is not None)
    if returns_floor:  # a centroid that is its returns' mean has a floor of its own
        sigma0 = np.array([params.centroid_returns_sigma_m if clusters.from_returns[c]
                           else params.centroid_sigma_m for _, _, c in associated], np.float64)
    if params.centroid_sigma_per_m > 0:  # the noise floor grows with the range from the ego
        # np.hypot is libm's, as numba's math.hypot (Python's own math.hypot rounds otherwise)
        ex = (window.col0 + window.cols // 2 + 0.5) * window.resolution_m
        ey = (window.row0 + window.rows // 2 + 0.5) * window.resolution_m
        sigma0 = np.array([
            max(float(sigma0[k]) if returns_floor else params.centroid_sigma_m,
                params.centroid_sigma_per_m * np.hypot(
                    float(clusters.centroid_m[c, 0]) - ex, float(clusters.centroid_m[c, 1]) - ey))
            for k, (_, _, c) in enumerate(associated)], np.float64)
    fit_v, fit_sigma = velocity_fits(hist_t, hist_xy, count, sigma0)
    fit_of = {i: k for k, (i, _, _) in enumerate(associated)}
    for i, t in enumerate(tracks):
        c = of_track.get(i)
        if c is None:
            t.missed += 1
            if t.missed <= params.max_missed_frames:
                survivors.append(t)
            continue
        t.missed = 0
        t.hits += 1
        k = fit_of[i]
        v = (float(fit_v[k, 0]), float(fit_v[k, 1]))
        sigma = float(fit_sigma[k])
        t.velocity, t.sigma = v, sigma
        if len(t.footprint):  # the previous association's cells join the past
            t.past.append(t.footprint)
            del t.past[:-params.vacated_frames]
        fast = is_moving(v, sigma, params)
        ex = (window.col0 + window.cols // 2 + 0.5) * window.resolution_m
        ey = (window.row0 + window.rows // 2 + 0.5) * window.resolution_m
        dx = float(clusters.centroid_m[c, 0]) - ex
        dy = float(clusters.centroid_m[c, 1]) - ey
        if t.hits == 1:  # a new track: far or not by its first cluster alone
            t.ever_far = False
        t.ever_far = t.ever_far or dx * dx + dy * dy >= params.ego_clearance_m ** 2
        fast = fast and t.ever_far  # never away from the sensor: the ego's own returns
        if (near_building is not None and params.facade_max_speed_m_per_s > 0
                and v[0] * v[0] + v[1] * v[1] > params.facade_max_speed_m_per_s ** 2):
            cells = clusters.cells[clusters.offsets[c]:clusters.offsets[c + 1]]
            if near_building.reshape(-1)[cells].all():  # a façade's spot, not a walker
                fast = False
        if fast or params.evidence_every_frame:
            conflict, vacated = frame_evidence(t, clusters, c, decision, window, params)
            t.conflict_evidence += conflict
            t.vacated_evidence += vacated
        need = params.motion_evidence_frames
        if params.evidence_expires:
            still = v[0] * v[0] + v[1] * v[1] < params.moving_speed_m_per_s ** 2
            t.conflict_evidence = expire_evidence(t.conflict_evidence, need, still)
            t.vacated_evidence = expire_evidence(t.vacated_evidence, need, still)
        t.moving = fast and max(t.conflict_evidence, t.vacated_evidence) >= need
        if t.moving and t.hits >= params.confirm_frames:
            t.ever_moving = True
        t.footprint = lattice[clusters.offsets[c]:clusters.offsets[c + 1]]  # a view
        if t.hits >= params.confirm_frames and (t.moving or t.ever_moving):
            reported.append((len(survivors), c))
        survivors.append(t)
    state.tracks = survivors
    reported.sort(key=lambda p: survivors[p[0]].track_id)
    records = np.zeros(len(reported), OBJECT_DTYPE)
    pieces = []
    for k, (i, c) in enumerate(reported):
        t = survivors[i]
        cells = clusters.cells_of(c)
        pieces.append(cells)
        rec = records[k]
        rec["track_id"] = t.track_id
        rec["state"] = OBJECT_STATES["moving" if t.moving else "stopped"]
        rec["cell_count"] = len(cells)
        rec["age_frames"] = t.hits
        rec["centroid_m"] = clusters.centroid_m[c]
        rec["bbox_m"] = clusters.bbox_m[c]
        rec["extent_m"] = clusters.bbox_m[c, 2:] - clusters.bbox_m[c, :2]
        rec["velocity_m_per_s"] = t.velocity
        rec["speed_sigma_m_per_s"] = t.sigma
        rec["mean_betp_moving"] = clusters.mean_betp_moving[c]
    cells_out = (np.concatenate(pieces).astype(np.uint32) if pieces
                 else np.zeros(0, np.uint32))
    return records, cells_out
