"""Tracks of clusters from frame to frame, and the motion test per object (docs/method.md,
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

with the centroid noise σ² = max(σ₀², RSS / (2(n − 2))) (σ₀ = ``centroid_sigma_m``, or
``centroid_returns_sigma_m`` when the track's cluster of this frame takes its returns' mean
(:func:`evperc.objects.clusters.with_return_centroids`: many returns, no cell staircase in
it); the residuals of both axes pooled, 2(n − 2) degrees of freedom, when n > 2), so each velocity
component has variance s² = σ² / S and Σ = s² I. The object moves if its speed passes both
``|v| ≥ moving_speed_m_per_s`` and the Mahalanobis test ``vᵀ Σ⁻¹ v = |v|² / s² ≥
motion_test`` (DOGMa's 4: two standard deviations), and the grid has shown motion evidence of
one kind (below) in at least ``motion_evidence_frames`` of the frames in which the velocity
passed the test (counted per kind over the track's life). A centroid alone is no proof: the
cluster of a parked car grows as the ego drives past and more of it comes into view, and its
centroid then drifts at a walking pace. Evidence of a frame, from the grid:

- *conflict*: the cluster holds at least ``conflict_cells`` cells decided ``moving`` (the
  fusion's ∅_FO, through the motion gate: free before, occupied now) — one, if it has at
  most ``single_conflict_max_cells`` cells (a person of one to three cells steps into one
  cell seen free at a time);
- *vacated*: of the cells the track held ``vacated_frames`` associations ago, a share of at
  least ``vacated_share`` is decided ``free`` now (occupied then, seen free now: the object
  left them). A static object's cells stay occupied; a car driving ahead of the ego, which
  never conflicts, frees the road behind it at every scan.

A frame of *growth* adds no evidence of either kind: the cluster, of at least
``growth_min_cells`` cells (more than a person's footprint), still holds at least
``growth_kept_share`` of the cells the track held ``vacated_frames`` associations ago and at
least ``growth_more_cells`` cells more than then (a cell held then counts as kept when the
cluster holds a cell within ``growth_reach_cells`` of it, Chebyshev; with ``growth_early``,
a track with fewer associations behind it is compared with the oldest it has). Its centroid
moved because more of the
object came into view (a fence or a parked car along which a sparse scanner's layer sweeps
as the ego drives by, its new cells seen free before: conflict), not because it moved; a
moving object leaves cells behind (a car drives out of its old footprint within a few scans,
and the cells behind a car coming closer are hidden, not held).

Two exceptions pass no velocity test: a track never associated with a cluster at least
``ego_clearance_m`` from the sensor (the recording vehicle's own returns), and an
association with a cluster all of whose cells lie in the widened buildings at a speed above
``facade_max_speed_m_per_s`` (a façade's return spot sliding with the ego).

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

import numba
import numpy as np

from evperc.fusion.twin import DECISION_CODES
from evperc.geo.window import Window
from evperc.objects.clusters import Clusters, ego_cell_centre
from evperc.output.objects import OBJECT_DTYPE, OBJECT_STATES

_FREE = DECISION_CODES["free"]
_STATE_MOVING = OBJECT_STATES["moving"]
_STATE_STOPPED = OBJECT_STATES["stopped"]


@dataclass(frozen=True)
class TrackingParams:
    """The ``[objects]`` keys of the tracker (configs/default.toml)."""

    #: objects.gate_m: largest distance between a track's predicted centroid and a cluster
    #: centroid that may be associated (Dynablox: 1 m; a cluster's centroid also moves as
    #: more of a car comes into view)
    gate_m: float = 2.0
    #: objects.confirm_frames: associated frames before a track is reported
    confirm_frames: int = 3
    #: objects.max_missed_frames: frames a track survives without a cluster
    max_missed_frames: int = 3
    #: objects.history_frames: centroids the velocity fit uses (10 = 1 s at 10 Hz)
    history_frames: int = 10
    #: objects.moving_speed_m_per_s: slower objects are not moving
    moving_speed_m_per_s: float = 1.0
    #: objects.motion_test: vᵀ Σ⁻¹ v at least this is motion (DOGMa: 4)
    motion_test: float = 4.0
    #: objects.centroid_sigma_m: least standard deviation of a cluster centroid per axis
    centroid_sigma_m: float = 0.25
    #: objects.centroid_returns_sigma_m: ... of a centroid that is the mean of the cluster's
    #: returns (``Clusters.from_returns``); 0 = ``centroid_sigma_m`` for every centroid
    centroid_returns_sigma_m: float = 0.0
    #: objects.motion_evidence_frames: frames with conflict evidence, or frames with vacated
    #: evidence, among those whose velocity passed, before the object moves (0: the
    #: velocity test alone)
    motion_evidence_frames: int = 0  # configs/default.toml: 3
    #: objects.conflict_cells: decided-moving cells a cluster needs for conflict evidence
    conflict_cells: int = 2
    #: objects.single_conflict_max_cells: a cluster of at most this many cells needs one
    #: (a person's one step into cells seen free is all the conflict it gives); 0 = off
    single_conflict_max_cells: int = 0
    #: objects.vacated_frames: the footprint compared is the one this many associations ago
    vacated_frames: int = 3
    #: objects.vacated_share: share of that footprint decided free now for vacated evidence
    vacated_share: float = 0.3
    #: objects.evidence_every_frame: count the evidence of every associated frame, not only
    #: of the frames whose velocity passed (:func:`track_step`)
    evidence_every_frame: bool = False
    #: objects.arrival_share: a frame in which at least this share of the cluster's cells is
    #: decided moving is the whole evidence at once (0: off; :func:`track_step`)
    arrival_share: float = 0.0
    #: objects.arrival_min_cells: ... and that share holds at least this many cells decided
    #: moving (below ``conflict_cells``: ``conflict_cells``)
    arrival_min_cells: int = 0
    #: objects.centroid_sigma_per_m: the centroid noise floor grows with the object's range r
    #: from the ego (the window's centre cell): σ₀ = max(centroid_sigma_m, this · r); 0 = off
    centroid_sigma_per_m: float = 0.0
    #: objects.ego_clearance_m: a track never associated with a cluster whose centroid lay at
    #: least this far from the sensor passes no motion test (the recording vehicle's own
    #: returns ride along with it); 0 = off
    ego_clearance_m: float = 0.0
    #: objects.evidence_expires: the motion evidence counts are kept at most
    #: ``motion_evidence_frames``, and each association whose fitted speed is under
    #: ``moving_speed_m_per_s`` takes one frame off each: a track that stood still that long
    #: shows fresh evidence before it is reported moving again (:func:`track_step`); False =
    #: the counts only grow
    evidence_expires: bool = False
    #: objects.facade_max_speed_m_per_s: with the map, an association with a cluster whose
    #: cells all lie in the widened buildings (``near_building``) passes no motion test at a
    #: speed above this (a façade's return spot sliding along the wall with the ego; a
    #: person walking along it is slower); 0 = off
    facade_max_speed_m_per_s: float = 0.0
    #: objects.growth_kept_share: an association whose cluster keeps at least this share of
    #: the track's cells of ``vacated_frames`` associations ago ... (0: off)
    growth_kept_share: float = 0.0
    #: objects.growth_more_cells: ... and holds at least this many cells more than then ...
    growth_more_cells: int = 0
    #: objects.growth_min_cells: ... and at least this many cells is growth: no motion
    #: evidence (module docstring)
    growth_min_cells: int = 0
    #: objects.growth_reach_cells: a cell of that footprint is kept if the cluster holds a
    #: cell within this many cells of it (Chebyshev; 0: the cell itself)
    growth_reach_cells: int = 0
    #: objects.growth_early: a track with fewer than ``vacated_frames`` associations behind
    #: it (but one) is compared with its oldest footprint (False: not tested)
    growth_early: bool = False

    @staticmethod
    def from_config(config: dict[str, Any]) -> TrackingParams:
        o = config["objects"]
        return TrackingParams(
            gate_m=float(o["gate_m"]), confirm_frames=int(o["confirm_frames"]),
            max_missed_frames=int(o["max_missed_frames"]),
            history_frames=int(o["history_frames"]),
            moving_speed_m_per_s=float(o["moving_speed_m_per_s"]),
            motion_test=float(o["motion_test"]),
            centroid_sigma_m=float(o["centroid_sigma_m"]),
            centroid_returns_sigma_m=float(o.get("centroid_returns_sigma_m", 0.0)),
            motion_evidence_frames=int(o["motion_evidence_frames"]),
            conflict_cells=int(o["conflict_cells"]),
            single_conflict_max_cells=int(o.get("single_conflict_max_cells", 0)),
            vacated_frames=int(o["vacated_frames"]),
            vacated_share=float(o["vacated_share"]),
            evidence_every_frame=bool(o.get("evidence_every_frame", False)),
            arrival_share=float(o.get("arrival_share", 0.0)),
            arrival_min_cells=int(o.get("arrival_min_cells", 0)),
            centroid_sigma_per_m=float(o.get("centroid_sigma_per_m", 0.0)),
            ego_clearance_m=float(o.get("ego_clearance_m", 0.0)),
            evidence_expires=bool(o.get("evidence_expires", False)),
            facade_max_speed_m_per_s=float(o.get("facade_max_speed_m_per_s", 0.0)),
            growth_kept_share=float(o.get("growth_kept_share", 0.0)),
            growth_more_cells=int(o.get("growth_more_cells", 0)),
            growth_min_cells=int(o.get("growth_min_cells", 0)),
            growth_reach_cells=int(o.get("growth_reach_cells", 0)),
            growth_early=bool(o.get("growth_early", False)))


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


def velocity_fits(t_s: np.ndarray, xy: np.ndarray, count: np.ndarray, sigma0: float
                  ) -> tuple[np.ndarray, np.ndarray]:
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
    """The tracks and the next id; part of the run's checkpointed state.

    Struct of arrays, one row a track (in id order), laid out as the checkpoint stores them
    (:meth:`to_arrays`): ``id``, ``hits``, ``missed`` (n,) int64; ``flags`` (n, 3) uint8
    (ever moving, moving, ever far: see ``objects.ego_clearance_m``); ``hist_n`` (n,) int64
    and ``hist_t`` (n, W) int64 / ``hist_xy`` (n, W, 2) float64, the recent associated
    stamps and centroids, oldest first in the first ``hist_n`` columns, 0 after;
    ``velocity`` (n, 2), ``sigma`` (n,) float64; ``fp_n`` (n,) int64 and ``fp`` (Σ fp_n, 2)
    int64, the global lattice (iy, ix) of each track's cells of its last association, track
    by track; ``evidence`` (n, 2) int64 (conflict, vacated); ``past_n`` (n, D) int64, the
    cells of each previous footprint, oldest first, −1 after, and ``past`` their cells,
    track by track. W and D may exceed what the tracks use."""

    def __init__(self) -> None:
        self.next_id = 1
        self.prev_ns: int | None = None
        self.id = np.zeros(0, np.int64)
        self.hits = np.zeros(0, np.int64)
        self.missed = np.zeros(0, np.int64)
        self.flags = np.zeros((0, 3), np.uint8)
        self.hist_n = np.zeros(0, np.int64)
        self.hist_t = np.zeros((0, 0), np.int64)
        self.hist_xy = np.zeros((0, 0, 2), np.float64)
        self.velocity = np.zeros((0, 2), np.float64)
        self.sigma = np.zeros(0, np.float64)
        self.fp_n = np.zeros(0, np.int64)
        self.fp = np.zeros((0, 2), np.int64)
        self.evidence = np.zeros((0, 2), np.int64)
        self.past_n = np.zeros((0, 0), np.int64)
        self.past = np.zeros((0, 2), np.int64)

    _ARRAYS = ("id", "hits", "missed", "flags", "hist_n", "hist_t", "hist_xy", "velocity",
               "sigma", "fp_n", "fp", "evidence", "past_n", "past")

    def __len__(self) -> int:
        return len(self.id)

    def copy(self) -> TrackerState:
        other = TrackerState()
        other.next_id, other.prev_ns = self.next_id, self.prev_ns
        for name in self._ARRAYS:
            setattr(other, name, getattr(self, name).copy())
        return other

    @property
    def tracks(self) -> list[Track]:
        """The tracks as :class:`Track` objects (a copy, for inspection)."""
        fp_end = np.cumsum(self.fp_n)
        past_at = 0
        out = []
        for i in range(len(self.id)):
            k = int(self.hist_n[i])
            past = []
            for m in self.past_n[i]:
                if m < 0:
                    break
                past.append(self.past[past_at:past_at + m].copy())
                past_at += int(m)
            out.append(Track(
                int(self.id[i]), int(self.hits[i]), int(self.missed[i]), bool(self.flags[i, 0]),
                [int(v) for v in self.hist_t[i, :k]],
                [(float(x), float(y)) for x, y in self.hist_xy[i, :k]],
                (float(self.velocity[i, 0]), float(self.velocity[i, 1])), float(self.sigma[i]),
                bool(self.flags[i, 1]), self.fp[fp_end[i] - self.fp_n[i]:fp_end[i]].copy(),
                int(self.evidence[i, 0]), int(self.evidence[i, 1]), past,
                bool(self.flags[i, 2])))
        return out

    def to_arrays(self, prefix: str = "objects_") -> dict[str, np.ndarray]:
        """Flat arrays for the checkpoint (:meth:`from_arrays` reads them back exactly);
        the history and the past footprints as wide as the tracks use."""
        n = len(self.id)
        history = int(self.hist_n.max()) if n else 0
        depth = int((self.past_n >= 0).sum(axis=1).max()) if n and self.past_n.size else 0
        arrays = {name: getattr(self, name).copy() for name in self._ARRAYS}
        arrays["hist_t"] = np.ascontiguousarray(self.hist_t[:, :history])
        arrays["hist_xy"] = np.ascontiguousarray(self.hist_xy[:, :history])
        arrays["past_n"] = np.ascontiguousarray(self.past_n[:, :depth])
        out = {f"{prefix}next_id": np.int64(self.next_id),
               f"{prefix}prev_ns": np.int64(-1 if self.prev_ns is None else self.prev_ns)}
        out.update({f"{prefix}{name}": arrays[name] for name in self._ARRAYS})
        return out

    @staticmethod
    def from_arrays(arrays: Any, prefix: str = "objects_") -> TrackerState | None:
        """The state saved by :meth:`to_arrays`, or None if ``arrays`` holds none."""
        if f"{prefix}next_id" not in arrays:
            return None
        state = TrackerState()
        state.next_id = int(arrays[f"{prefix}next_id"])
        prev = int(arrays[f"{prefix}prev_ns"])
        state.prev_ns = None if prev < 0 else prev
        dtypes = {"flags": np.uint8, "hist_xy": np.float64, "velocity": np.float64,
                  "sigma": np.float64}
        n = len(arrays[f"{prefix}id"])
        for name in state._ARRAYS:
            key = f"{prefix}{name}"
            if key in arrays:
                value = np.array(arrays[key], dtypes.get(name, np.int64))
            elif name == "evidence":  # checkpoints written before motion evidence
                value = np.zeros((n, 2), np.int64)
            elif name == "past_n":
                value = np.zeros((n, 0), np.int64)
            elif name == "past":
                value = np.zeros((0, 2), np.int64)
            else:
                raise KeyError(key)
            setattr(state, name, value)
        if state.flags.size == 2 * n:  # checkpoints written before the ever-far flag
            state.flags = np.column_stack([state.flags.reshape(n, 2), np.ones(n, np.uint8)])
        state.flags = state.flags.reshape(n, 3)
        state.velocity = state.velocity.reshape(n, 2)
        state.evidence = state.evidence.reshape(n, 2)
        state.hist_t = state.hist_t.reshape(n, -1) if n else np.zeros((0, 0), np.int64)
        state.hist_xy = state.hist_xy.reshape(n, state.hist_t.shape[1], 2)
        state.past_n = state.past_n.reshape(n, -1) if n else np.zeros((0, 0), np.int64)
        state.fp = state.fp.reshape(-1, 2)
        state.past = state.past.reshape(-1, 2)
        return state


def footprint_seeds(state: TrackerState, window: Window) -> np.ndarray:
    """Flat window indices of the cells held in their last frame by the tracks that have
    moved (extra seeds for :meth:`evperc.objects.clusters.Clusterer.clusters`), track by
    track."""
    return _seed_cells(state.fp, state.fp_n, state.flags, window.row0, window.col0,
                       window.rows, window.cols)


def window_indices(lattice: np.ndarray, window: Window) -> np.ndarray:
    """Flat window indices (row · cols + col) of the global lattice cells (iy, ix) that lie
    in ``window``; the others are left out."""
    r = lattice[:, 0] - window.row0
    c = lattice[:, 1] - window.col0
    inside = (r >= 0) & (r < window.rows) & (c >= 0) & (c < window.cols)
    return r[inside] * window.cols + c[inside]


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _seed_cells(fp, fp_n, flags, row0, col0, rows, cols):  # pragma: no cover - compiled
    """:func:`footprint_seeds`: the window cells of the footprints of tracks that moved."""
    out = np.empty(fp.shape[0], np.int64)
    m = 0
    at = 0
    for i in range(fp_n.shape[0]):
        end = at + fp_n[i]
        if flags[i, 0]:
            for q in range(at, end):
                r = fp[q, 0] - row0
                c = fp[q, 1] - col0
                if 0 <= r < rows and 0 <= c < cols:
                    out[m] = r * cols + c
                    m += 1
        at = end
    return out[:m].copy()


@numba.njit(cache=True, nogil=True)
def _block_sum(a, start, n):  # pragma: no cover - compiled
    """numpy's pairwise summation of ``a[start:start + n]``, n ≤ 128 (one block: 8
    accumulators, then the rest in order; below 8 terms in order)."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[start + i]
        return res
    r0 = a[start]
    r1 = a[start + 1]
    r2 = a[start + 2]
    r3 = a[start + 3]
    r4 = a[start + 4]
    r5 = a[start + 5]
    r6 = a[start + 6]
    r7 = a[start + 7]
    i = 8
    while i < n - n % 8:
        r0 += a[start + i]
        r1 += a[start + i + 1]
        r2 += a[start + i + 2]
        r3 += a[start + i + 3]
        r4 += a[start + i + 4]
        r5 += a[start + i + 5]
        r6 += a[start + i + 6]
        r7 += a[start + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[start + i]
        i += 1
    return res


@numba.njit(cache=True, nogil=True)
def _pairwise_sum(a, start, n):  # pragma: no cover - compiled
    """numpy's pairwise summation of ``a[start:start + n]`` (float64; the order of
    ``np.add.reduce`` along a contiguous axis: blocks of up to 128 terms, above that the
    sum of the halves, the first half's length a multiple of 8), so that the compiled fit
    equals :func:`velocity_fits` to the bit. numpy recurses; this walks the same tree with
    a stack (a recursive function loaded from numba's cache crashes)."""
    if n <= 128:
        return _block_sum(a, start, n)
    st_start = np.empty(64, np.int64)
    st_n = np.empty(64, np.int64)
    st_stage = np.empty(64, np.int64)
    vals = np.empty(64)
    top = 1
    st_start[0] = start
    st_n[0] = n
    st_stage[0] = 0
    nv = 0
    while top > 0:
        s = st_start[top - 1]
        m = st_n[top - 1]
        if m <= 128:
            vals[nv] = _block_sum(a, s, m)
            nv += 1
            top -= 1
            continue
        n2 = m // 2
        n2 -= n2 % 8
        stage = st_stage[top - 1]
        if stage == 0:  # the first half
            st_stage[top - 1] = 1
            st_start[top] = s
            st_n[top] = n2
            st_stage[top] = 0
            top += 1
        elif stage == 1:  # the second half
            st_stage[top - 1] = 2
            st_start[top] = s + n2
            st_n[top] = m - n2
            st_stage[top] = 0
            top += 1
        else:  # both done: their sum
            vals[nv - 2] = vals[nv - 2] + vals[nv - 1]
            nv -= 1
            top -= 1
    return vals[0]


@numba.njit(cache=True, nogil=True)
def _row_sum(a):  # pragma: no cover - compiled
    """``a.sum()`` of a 1-d float64 row as numpy reduces it (identity 0, then pairwise)."""
    return 0.0 + _pairwise_sum(a, 0, a.shape[0])


@numba.njit(cache=True, nogil=True)
def _fit(t, x, y, m, sigma0, scratch):  # pragma: no cover - compiled
    """One row of :func:`velocity_fits` (``t``, ``x``, ``y``: the row's H columns, the first
    ``m`` the track's, zeros after), op for op; returns (vx, vy, sigma)."""
    h = t.shape[0]
    k = float(max(m, 1))
    dt = scratch[0]
    dx = scratch[1]
    dy = scratch[2]
    w = scratch[3]
    tm = _row_sum(t) / k
    xm = _row_sum(x) / k
    ym = _row_sum(y) / k
    for j in range(h):
        if j < m:
            dt[j] = t[j] - tm
            dx[j] = x[j] - xm
            dy[j] = y[j] - ym
        else:
            dt[j] = 0.0
            dx[j] = 0.0
            dy[j] = 0.0
    for j in range(h):
        w[j] = dt[j] * dt[j]
    s = _row_sum(w)
    ok = m >= 2 and s > 0.0
    s_safe = s if ok else 1.0
    vx = 0.0
    vy = 0.0
    if ok:
        for j in range(h):
            w[j] = dt[j] * dx[j]
        vx = _row_sum(w) / s_safe
        for j in range(h):
            w[j] = dt[j] * dy[j]
        vy = _row_sum(w) / s_safe
    for j in range(h):
        if j < m:
            ex = dx[j] - vx * dt[j]
            ey = dy[j] - vy * dt[j]
            w[j] = ex * ex + ey * ey
        else:
            w[j] = 0.0
    rss = _row_sum(w)
    var0 = sigma0 * sigma0
    var = var0
    if m > 2:
        q = rss / max(2 * (m - 2), 1)
        var = q if q > var0 else var0
    sigma = math.sqrt(var / s_safe) if ok else np.inf
    return vx, vy, sigma


@numba.njit(cache=True, nogil=True)
def _fits(t_s, xy, count, sigma0):  # pragma: no cover - compiled
    """:func:`velocity_fits` compiled, row by row (the tracker's fit; tested equal)."""
    n, h = t_s.shape
    v = np.zeros((n, 2))
    sigma = np.empty(n)
    scratch = np.empty((4, h))
    t = np.empty(h)
    x = np.empty(h)
    y = np.empty(h)
    for i in range(n):
        m = count[i]
        for j in range(h):
            valid = j < m
            t[j] = t_s[i, j] if valid else 0.0
            x[j] = xy[i, j, 0] if valid else 0.0
            y[j] = xy[i, j, 1] if valid else 0.0
        v[i, 0], v[i, 1], sigma[i] = _fit(t, x, y, m, sigma0, scratch)
    return v, sigma


@numba.njit(cache=True, nogil=True)
def _distances(hist_xy, hist_n, velocity, dt, centroid, gate):  # pragma: no cover - compiled
    """(tracks, clusters) float64: each track's centroid predicted by its velocity, ``last
    + v · dt``, to each cluster centroid, ``hypot(px − cx, py − cy)`` — numpy's formulas
    op for op (``hist_xy[i, hist_n[i] − 1]``, numpy's wrap of −1 kept; ``math.hypot`` and
    ``np.hypot`` are both libm's ``hypot``; no fastmath, so no contraction into an FMA) —
    where it may be within ``gate``: a pair with |px − cx| or |py − cy| above the gate is
    farther (hypot(a, b) ≥ max(|a|, |b|), rounding included) and gets +inf."""
    n = hist_n.shape[0]
    m = centroid.shape[0]
    dist = np.empty((n, m), np.float64)
    for i in range(n):
        j = hist_n[i] - 1
        j = j + hist_xy.shape[1] if j < 0 else j
        px = hist_xy[i, j, 0] + velocity[i, 0] * dt
        py = hist_xy[i, j, 1] + velocity[i, 1] * dt
        for c in range(m):
            dx = px - centroid[c, 0]
            dy = py - centroid[c, 1]
            dist[i, c] = (np.inf if abs(dx) > gate or abs(dy) > gate
                          else math.hypot(dx, dy))
    return dist


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _track_kernel(ids, hits, missed, flags, hist_n, hist_t, hist_xy, velocity, sigma, fp_n,
                  fp, evidence, past_n, past, dt, cells, offsets, centroid, seeds, row0,
                  col0, rows, cols, decision, has_decision, stamp_ns, next_id, gate,
                  history, confirm, max_missed, speed2_min, motion_test, sigma0, sigma_c, need,
                  conflict_cells, vacated_frames, share_min, every_frame, arrival_share,
                  arrival_cells, sigma_per_m, clearance2, centre_x, centre_y, expires,
                  near, facade_speed2, single_max, kept_share, growth_more,
                  growth_least, growth_reach, growth_early):  # pragma: no cover - compiled
    """One frame of the tracker (:func:`track_step`, the module docstring) on the state's
    arrays; returns the new arrays, the next id, and the reported (track row, cluster)."""
    n_old = ids.shape[0]
    n_cl = offsets.shape[0] - 1
    mark = np.zeros(rows * cols if kept_share > 0 else 1, np.uint8)  # a cluster's cells
    if n_old > 0 and n_cl > 0:  # read only within the gate
        dist = _distances(hist_xy, hist_n, velocity, dt, centroid, gate)
    else:
        dist = np.zeros((n_old, n_cl), np.float64)
    # association: pairs within the gate, nearest first (ties: track, then cluster)
    of_track = np.full(n_old + n_cl, -1, np.int64)
    taken = np.zeros(n_cl, np.bool_)
    if n_old > 0 and n_cl > 0:
        n_pairs = 0
        for t in range(n_old):
            for c in range(n_cl):
                if dist[t, c] <= gate:
                    n_pairs += 1
        pt = np.empty(n_pairs, np.int64)
        pc = np.empty(n_pairs, np.int64)
        pd = np.empty(n_pairs, np.float64)
        k = 0
        for t in range(n_old):  # row-major, as np.nonzero
            for c in range(n_cl):
                if dist[t, c] <= gate:
                    pt[k] = t
                    pc[k] = c
                    pd[k] = dist[t, c]
                    k += 1
        used = np.zeros(n_old, np.bool_)
        for k in np.argsort(pd, kind="mergesort"):  # stable: ties keep (track, cluster)
            t = pt[k]
            c = pc[k]
            if used[t] or taken[c]:
                continue
            used[t] = True
            taken[c] = True
            of_track[t] = c
    n_all = n_old
    for c in range(n_cl):  # clusters left over start tracks
        if not taken[c]:
            of_track[n_all] = c
            n_all += 1
    # the old pools' offsets per track
    fp_at = np.zeros(n_old + 1, np.int64)
    past_at = np.zeros(n_old + 1, np.int64)
    depth_old = past_n.shape[1]
    for i in range(n_old):
        fp_at[i + 1] = fp_at[i] + fp_n[i]
        m = 0
        for q in range(depth_old):
            if past_n[i, q] < 0:
                break
            m += past_n[i, q]
        past_at[i + 1] = past_at[i] + m
    width = max(hist_t.shape[1], history)
    depth = max(depth_old, vacated_frames)
    n_cells = offsets[n_cl]
    # the new state (rows: survivors in order), pools at their largest
    o_ids = np.empty(n_all, np.int64)
    o_hits = np.empty(n_all, np.int64)
    o_missed = np.empty(n_all, np.int64)
    o_flags = np.zeros((n_all, 3), np.uint8)
    o_hist_n = np.zeros(n_all, np.int64)
    o_hist_t = np.zeros((n_all, width), np.int64)
    o_hist_xy = np.zeros((n_all, width, 2), np.float64)
    o_velocity = np.zeros((n_all, 2), np.float64)
    o_sigma = np.empty(n_all, np.float64)
    o_fp_n = np.zeros(n_all, np.int64)
    o_fp = np.empty((fp.shape[0] + n_cells, 2), np.int64)
    o_evidence = np.zeros((n_all, 2), np.int64)
    o_past_n = np.full((n_all, depth), -1, np.int64)
    o_past = np.empty((past.shape[0] + fp.shape[0], 2), np.int64)
    rep_row = np.empty(n_all, np.int64)
    rep_cl = np.empty(n_all, np.int64)
    n_rep = 0
    t_row = np.zeros(history)
    x_row = np.zeros(history)
    y_row = np.zeros(history)
    scratch = np.empty((4, history))
    lens = np.empty(depth + 1, np.int64)  # cells of the kept past footprints
    starts = np.empty(depth + 1, np.int64)
    from_new = np.empty(depth + 1, np.bool_)  # that footprint is the old fp (else old past)
    n_out = 0
    fp_out = 0
    past_out = 0
    for i in range(n_all):
        c = of_track[i]
        old = i < n_old
        if c < 0:  # not associated (an old track): kept as it is while it may come back
            if missed[i] + 1 > max_missed:
                continue
        j = n_out
        n_out += 1
        if old:
            o_ids[j] = ids[i]
            o_hits[j] = hits[i]
            o_missed[j] = missed[i]
            o_flags[j, 0] = flags[i, 0]
            o_flags[j, 1] = flags[i, 1]
            o_flags[j, 2] = flags[i, 2]
            o_velocity[j, 0] = velocity[i, 0]
            o_velocity[j, 1] = velocity[i, 1]
            o_sigma[j] = sigma[i]
            o_evidence[j, 0] = evidence[i, 0]
            o_evidence[j, 1] = evidence[i, 1]
            kh = hist_n[i]
        else:
            o_ids[j] = next_id
            next_id += 1
            o_hits[j] = 0
            o_missed[j] = 0
            o_sigma[j] = np.inf
            kh = 0
        # the past footprints it keeps (before this frame's change): old past entries
        n_past = 0
        if old:
            at = past_at[i]
            for q in range(depth_old):
                m = past_n[i, q]
                if m < 0:
                    break
                lens[n_past] = m
                starts[n_past] = at
                from_new[n_past] = False
                n_past += 1
                at += m
        cur_fp_start = fp_at[i] if old else 0
        cur_fp_n = fp_n[i] if old else 0
        if c < 0:
            o_missed[j] += 1
            o_hist_n[j] = kh
            for q in range(kh):
                o_hist_t[j, q] = hist_t[i, q]
                o_hist_xy[j, q, 0] = hist_xy[i, q, 0]
                o_hist_xy[j, q, 1] = hist_xy[i, q, 1]
            o_fp_n[j] = cur_fp_n
            for q in range(cur_fp_n):
                o_fp[fp_out + q, 0] = fp[cur_fp_start + q, 0]
                o_fp[fp_out + q, 1] = fp[cur_fp_start + q, 1]
            fp_out += cur_fp_n
        else:
            o_missed[j] = 0
            o_hits[j] += 1
            # the history: the old one and this frame's centroid, the last `history` kept
            drop = max(kh + 1 - history, 0)
            m_new = kh + 1 - drop
            for q in range(drop, kh):
                o_hist_t[j, q - drop] = hist_t[i, q]
                o_hist_xy[j, q - drop, 0] = hist_xy[i, q, 0]
                o_hist_xy[j, q - drop, 1] = hist_xy[i, q, 1]
            o_hist_t[j, m_new - 1] = stamp_ns
            o_hist_xy[j, m_new - 1, 0] = centroid[c, 0]
            o_hist_xy[j, m_new - 1, 1] = centroid[c, 1]
            o_hist_n[j] = m_new
            for q in range(history):
                if q < m_new:
                    t_row[q] = (o_hist_t[j, q] - stamp_ns) * 1e-9
                    x_row[q] = o_hist_xy[j, q, 0]
                    y_row[q] = o_hist_xy[j, q, 1]
                else:
                    t_row[q] = 0.0
                    x_row[q] = 0.0
                    y_row[q] = 0.0
            s0 = sigma_c[c] if sigma_c.shape[0] > 0 else sigma0
            if sigma_per_m > 0:
                s0 = max(s0, sigma_per_m * math.hypot(centroid[c, 0] - centre_x,
                                                      centroid[c, 1] - centre_y))
            vx, vy, sg = _fit(t_row, x_row, y_row, m_new, s0, scratch)
            o_velocity[j, 0] = vx
            o_velocity[j, 1] = vy
            o_sigma[j] = sg
            if cur_fp_n > 0:  # the previous association's cells join the past
                lens[n_past] = cur_fp_n
                starts[n_past] = cur_fp_start
                from_new[n_past] = True
                n_past += 1
                if n_past > vacated_frames:  # the oldest beyond vacated_frames are dropped
                    cut = n_past - vacated_frames
                    for q in range(vacated_frames):
                        lens[q] = lens[q + cut]
                        starts[q] = starts[q + cut]
                        from_new[q] = from_new[q + cut]
                    n_past = vacated_frames
            speed2 = vx * vx + vy * vy
            fast = False
            if math.isfinite(sg) and not speed2 < speed2_min:
                fast = sg == 0.0 or speed2 / (sg * sg) >= motion_test
            ex = centroid[c, 0] - centre_x
            ey = centroid[c, 1] - centre_y
            if ex * ex + ey * ey >= clearance2:
                o_flags[j, 2] = 1
            if o_flags[j, 2] == 0:  # never away from the sensor: the ego's own returns
                fast = False
            if fast and facade_speed2 > 0 and speed2 > facade_speed2:
                inside = True  # every cell in the widened buildings: a façade's spot
                for q in range(offsets[c], offsets[c + 1]):
                    if not near[cells[q]]:
                        inside = False
                        break
                if inside:
                    fast = False
            size = offsets[c + 1] - offsets[c]
            grown = False  # (reference: frame_evidence)
            if ((fast or every_frame) and kept_share > 0 and size >= growth_least
                    and (n_past == vacated_frames or (growth_early and n_past > 0))):
                for q in range(offsets[c], offsets[c + 1]):
                    mark[cells[q]] = 1
                kept = 0
                src = fp if from_new[0] else past
                for q in range(starts[0], starts[0] + lens[0]):
                    r = src[q, 0] - row0
                    cc = src[q, 1] - col0
                    near_cell = False
                    for r2 in range(max(r - growth_reach, 0), min(r + growth_reach + 1, rows)):
                        for c2 in range(max(cc - growth_reach, 0),
                                        min(cc + growth_reach + 1, cols)):
                            if mark[r2 * cols + c2]:
                                near_cell = True
                    if near_cell:
                        kept += 1
                for q in range(offsets[c], offsets[c + 1]):
                    mark[cells[q]] = 0
                grown = kept >= kept_share * lens[0] and size >= lens[0] + growth_more
            if (fast or every_frame) and not grown:  # the frame's evidence
                least = 1 if size <= single_max else conflict_cells
                conflict = 1 if seeds[c] >= least else 0
                if conflict and arrival_share > 0:  # arrival: the whole evidence at once
                    if seeds[c] >= arrival_cells and seeds[c] >= arrival_share * size:
                        conflict = max(1, need)
                o_evidence[j, 0] += conflict
                if has_decision and n_past == vacated_frames:
                    free = 0
                    src = fp if from_new[0] else past
                    for q in range(starts[0], starts[0] + lens[0]):
                        r = src[q, 0] - row0
                        cc = src[q, 1] - col0
                        if (0 <= r < rows and 0 <= cc < cols
                                and decision[r * cols + cc] == _FREE):
                            free += 1
                    if free / lens[0] >= share_min:
                        o_evidence[j, 1] += 1
            if expires:  # (reference: expire_evidence)
                still = speed2 < speed2_min
                for e in range(2):
                    kept = min(o_evidence[j, e], need)
                    o_evidence[j, e] = max(kept - 1, 0) if still else kept
            moving = fast and max(o_evidence[j, 0], o_evidence[j, 1]) >= need
            o_flags[j, 1] = 1 if moving else 0
            if moving and o_hits[j] >= confirm:
                o_flags[j, 0] = 1
            a = offsets[c]
            b = offsets[c + 1]
            o_fp_n[j] = b - a
            for q in range(a, b):
                rr = cells[q] // cols
                o_fp[fp_out, 0] = rr + row0
                o_fp[fp_out, 1] = cells[q] - rr * cols + col0
                fp_out += 1
            if o_hits[j] >= confirm and (moving or o_flags[j, 0]):
                rep_row[n_rep] = j
                rep_cl[n_rep] = c
                n_rep += 1
        for q in range(n_past):
            src = fp if from_new[q] else past
            o_past_n[j, q] = lens[q]
            for e in range(starts[q], starts[q] + lens[q]):
                o_past[past_out, 0] = src[e, 0]
                o_past[past_out, 1] = src[e, 1]
                past_out += 1
    return (o_ids[:n_out].copy(), o_hits[:n_out].copy(), o_missed[:n_out].copy(),
            o_flags[:n_out].copy(), o_hist_n[:n_out].copy(), o_hist_t[:n_out].copy(),
            o_hist_xy[:n_out].copy(), o_velocity[:n_out].copy(), o_sigma[:n_out].copy(),
            o_fp_n[:n_out].copy(), o_fp[:fp_out].copy(), o_evidence[:n_out].copy(),
            o_past_n[:n_out].copy(), o_past[:past_out].copy(), next_id,
            rep_row[:n_rep].copy(), rep_cl[:n_rep].copy())


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _fill_records(rows, cl, ids, flags, hits, velocity, sigma, cells, offsets, centroid, bbox,
                  mean_m, records):  # pragma: no cover - compiled
    """The reported objects, in track id order, written into ``records``
    (:data:`~evperc.output.objects.OBJECT_DTYPE`, one per reported row; each field takes
    the cast numpy's assignment of its value makes), and their cells (uint32, in record
    order)."""
    n = rows.shape[0]
    order = np.argsort(ids[rows], kind="mergesort")  # by id (rows are in id order already)
    total = 0
    for k in range(n):
        c = cl[k]
        total += offsets[c + 1] - offsets[c]
    out = np.empty(total, np.uint32)
    at = 0
    for k in range(n):
        i = rows[order[k]]
        c = cl[order[k]]
        a = offsets[c]
        b = offsets[c + 1]
        rec = records[k]
        rec.track_id = ids[i]
        rec.state = _STATE_MOVING if flags[i, 1] != 0 else _STATE_STOPPED
        rec.cell_count = b - a
        rec.age_frames = hits[i]
        for q in range(2):
            rec.centroid_m[q] = centroid[c, q]
            rec.extent_m[q] = bbox[c, 2 + q] - bbox[c, q]
            rec.velocity_m_per_s[q] = velocity[i, q]
        for q in range(4):
            rec.bbox_m[q] = bbox[c, q]
        rec.speed_sigma_m_per_s = sigma[i]
        rec.mean_betp_moving = mean_m[c]
        for q in range(a, b):
            out[at] = cells[q]
            at += 1
    return out


_NO_NEAR = np.zeros(1, np.bool_)
_NO_DECISION = np.zeros(0, np.uint8)


_NO_SIGMAS = np.zeros(0, np.float64)


def cluster_sigmas(clusters: Clusters, params: TrackingParams) -> np.ndarray:
    """Each cluster's centroid noise floor σ₀ (m): ``centroid_returns_sigma_m`` where its
    centroid is its returns' mean (``clusters.from_returns``), ``centroid_sigma_m``
    elsewhere; empty (every floor ``centroid_sigma_m``) with the key 0 or no such
    clusters' flags."""
    if params.centroid_returns_sigma_m <= 0 or clusters.from_returns is None:
        return _NO_SIGMAS
    return np.where(clusters.from_returns, float(params.centroid_returns_sigma_m),
                    float(params.centroid_sigma_m))


def track_step(state: TrackerState, clusters: Clusters, window: Window, stamp_ns: int,
               params: TrackingParams, decision: np.ndarray | None = None,
               near_building: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Associate this frame's ``clusters`` with ``state``'s tracks (updated in place);
    returns the frame's reported objects (records of
    :data:`evperc.output.objects.OBJECT_DTYPE`, by track id) and their cells (flat window
    indices, concatenated in record order). ``decision``: the frame's decided cells, for
    the vacated evidence (None: no vacated evidence). ``near_building``: (rows, cols) bool,
    the cells of the widened buildings, for ``facade_max_speed_m_per_s`` (None: no map,
    the rule off).

    The evidence a track's association with cluster ``c`` adds (module docstring) is
    counted in the frames whose velocity passes the test (or, with
    ``evidence_every_frame``, in every associated frame). Arrival: with ``arrival_share``
    > 0, a cluster of which at least that share of the cells is decided moving (free
    before, occupied now: the object arrived in cells seen free), and at least
    ``arrival_min_cells`` of them, counts ``motion_evidence_frames`` frames of conflict
    evidence at once. With ``evidence_expires`` each count is then kept at most
    ``motion_evidence_frames`` N, and lowered by one in an association whose fitted speed
    is under ``moving_speed_m_per_s`` v₀ (the track stands): e ← min(e + Δe, N) if
    |v| ≥ v₀, else max(min(e + Δe, N) − 1, 0).

    One compiled pass over the tracks (``_track_kernel``); the predicted centroids and
    their distances to the clusters (``_distances``) are numpy's formulas op for op, so the
    association is the per-track tracker's (tests/objects/reference_tracking.py) to the
    bit."""
    dt_s = 0.0 if state.prev_ns is None else (stamp_ns - state.prev_ns) * 1e-9
    state.prev_ns = stamp_ns
    centroids = clusters.centroid_m
    has_decision = decision is not None
    flat = (np.ascontiguousarray(decision).reshape(-1) if has_decision else _NO_DECISION)
    has_near = near_building is not None and params.facade_max_speed_m_per_s > 0
    near = (np.ascontiguousarray(near_building, np.bool_).reshape(-1) if has_near
            else _NO_NEAR)
    out = _track_kernel(
        state.id, state.hits, state.missed, state.flags, state.hist_n, state.hist_t,
        state.hist_xy, state.velocity, state.sigma, state.fp_n, state.fp, state.evidence,
        state.past_n, state.past, float(dt_s), clusters.cells, clusters.offsets,
        np.ascontiguousarray(centroids, np.float64), clusters.seeds, window.row0, window.col0,
        window.rows, window.cols, flat, has_decision, int(stamp_ns), state.next_id,
        float(params.gate_m), int(params.history_frames), int(params.confirm_frames),
        int(params.max_missed_frames), float(params.moving_speed_m_per_s ** 2),
        float(params.motion_test), float(params.centroid_sigma_m),
        cluster_sigmas(clusters, params), int(params.motion_evidence_frames),
        int(params.conflict_cells),
        int(params.vacated_frames), float(params.vacated_share),
        bool(params.evidence_every_frame), float(params.arrival_share),
        int(params.arrival_min_cells),
        float(params.centroid_sigma_per_m), float(params.ego_clearance_m) ** 2,
        *ego_cell_centre(window), bool(params.evidence_expires), near,
        float(params.facade_max_speed_m_per_s) ** 2 if has_near else 0.0,
        int(params.single_conflict_max_cells), float(params.growth_kept_share),
        int(params.growth_more_cells), int(params.growth_min_cells),
        int(params.growth_reach_cells), bool(params.growth_early))
    (state.id, state.hits, state.missed, state.flags, state.hist_n, state.hist_t,
     state.hist_xy, state.velocity, state.sigma, state.fp_n, state.fp, state.evidence,
     state.past_n, state.past, state.next_id, rows, cl) = out
    state.next_id = int(state.next_id)
    records = np.zeros(len(rows), OBJECT_DTYPE)
    cells_out = _fill_records(
        rows, cl, state.id, state.flags, state.hits, state.velocity, state.sigma,
        clusters.cells, clusters.offsets, clusters.centroid_m, clusters.bbox_m,
        clusters.mean_betp_moving, records)
    return records, cells_out
