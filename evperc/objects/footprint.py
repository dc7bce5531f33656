"""Motion-compensated footprints of the moving objects (docs/method.md §8, issue 21).

A lidar sees a car's near face: the cells under the rest of it hold no return and, seen
free before the car arrived, stay decided ``free``. But the car has shown other parts of
itself in the last frames (its rear while it came closer, its side while it passed): in the
object's own frame, which moves with the track's velocity, those cells are still the car.
So each moving object's footprint of frame k is completed with the cells its cluster held
in the last ``footprint_frames`` frames in which it was reported moving, each carried
forward by the track's current velocity:

    F_k = C_k ∪ ( ⋃_j { ⌊(x + v_k (t_k − t_j)) / r⌋ : x ∈ centres(C_j) } \\ S_k ),
    j over the last K = ``footprint_frames`` frames in which the track was reported moving,

with C_j the object's cluster cells at frame j (the cells observed, never the completed
ones: a completion cannot feed itself), v_k its velocity now, r the cell size, and S_k the
cells the scan of frame k speaks about: seen free (a ray crossed the cell) or holding a
return (occupied now, so another cluster's, or this one's already). The completion only
adds cells where the current scan is silent — occluded by the object itself, or out of
view — so it never contradicts the scan; a track reported ``stopped`` is not completed
(and its history is dropped: it restarts when the object moves again).

The completed cells join the object's cells in the object list (the record's
``cell_count``, centroid, bbox and extent are those of the completed footprint; its
velocity is the tracker's), and with ``objects.fill_moving`` they are decided ``moving``:
a decision, not evidence (the masses are not changed, as for the fill).

**Fragments** (``objects.fragment_gap_cells`` g, ``objects.fragment_extent_m`` L; ours,
issue "switches"). One car's returns often form two clusters split by a single empty cell
(its near face and its side), and both tracks can be reported moving: two objects for one
agent. After the completion, a moving object whose observed cluster cells lie within
Chebyshev distance g (lattice cells) of an older moving object's observed cells, and whose
observed cells joined with the older one's fit in a box no longer than L along x and y, is
reported as part of the older one (its completed cells get the older track id; its record
is dropped; the older record's cells, centroid, bbox and extent are recomputed). "Older":
more earlier moving frames in the history (the track reported moving longest keeps the
agent's identity), then more ``age_frames``, then the smaller track id. Only the object
list changes: the tracker keeps both tracks, the moving cells are the same union (so cell
scores do not change), and the history stays per track id.

Input is the object list of the frame (records and cells, :mod:`evperc.output.objects`),
so this does not depend on the tracker's internals.

Implementation: one compiled pass a frame for the completion (:func:`_complete`) and one for
the fragment merge (:func:`_merge`), on the history kept as the flat arrays the checkpoint
stores; outputs, cell order and checkpoint arrays are bit-identical to the per-object numpy
version they replaced (tests/objects/reference_footprint.py; the centroid is numpy's
``mean(axis=0)``, a sequential sum over the cells, reproduced as such). Track ids are unique
within a frame's object list (the tracker's)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numba
import numpy as np

from evperc.geo.window import Window
from evperc.gil_kept import sorted_unique
from evperc.output.objects import OBJECT_DTYPE, OBJECT_STATES

_MOVING = OBJECT_STATES["moving"]


@dataclass(frozen=True)
class FootprintParams:
    """The ``[objects]`` key of the completion (configs/default.toml)."""

    #: objects.footprint_frames: past moving frames whose cluster cells, carried forward by
    #: the velocity, complete the footprint (0: off)
    frames: int = 0  # configs/default.toml: tuned value
    #: objects.fragment_gap_cells: a moving object within this Chebyshev distance (cells) of
    #: an older moving one is reported as part of it (0: off)
    fragment_gap_cells: int = 0
    #: objects.fragment_extent_m: largest side (m) of the joined footprint's box
    fragment_extent_m: float = 7.0

    @staticmethod
    def from_config(config: dict[str, Any]) -> FootprintParams:
        o = config.get("objects", {})
        return FootprintParams(frames=int(o.get("footprint_frames", 0)),
                               fragment_gap_cells=int(o.get("fragment_gap_cells", 0)),
                               fragment_extent_m=float(o.get("fragment_extent_m", 7.0)))



_EMPTY_XY = np.zeros((0, 2), np.float64)


class FootprintState:
    """Per track id, its last moving frames: (stamp_ns, cell centres (m, 2) x, y metres),
    held flat as the checkpoint stores them: one entry a (track, frame), entries grouped by
    track (tracks in first-insertion order, frames oldest first), ``n`` centres each, their
    centres concatenated in ``xy``."""

    __slots__ = ("id", "stamp", "n", "xy")

    def __init__(self, id: np.ndarray | None = None, stamp: np.ndarray | None = None,
                 n: np.ndarray | None = None, xy: np.ndarray | None = None) -> None:
        self.id = np.zeros(0, np.int64) if id is None else id
        self.stamp = np.zeros(0, np.int64) if stamp is None else stamp
        self.n = np.zeros(0, np.int64) if n is None else n
        self.xy = _EMPTY_XY if xy is None else xy

    @property
    def history(self) -> dict[int, list[tuple[int, np.ndarray]]]:
        """The entries as {track id: [(stamp_ns, centres), ...]} (copies; for reading)."""
        out: dict[int, list[tuple[int, np.ndarray]]] = {}
        at = 0
        for tid, t, n in zip(self.id.tolist(), self.stamp.tolist(), self.n.tolist(),
                             strict=True):
            out.setdefault(tid, []).append((t, self.xy[at:at + n].copy()))
            at += n
        return out

    def copy(self) -> FootprintState:
        return FootprintState(self.id.copy(), self.stamp.copy(), self.n.copy(),
                              self.xy.copy())

    def to_arrays(self, prefix: str = "footprint_") -> dict[str, np.ndarray]:
        """Flat arrays for the checkpoint (:meth:`from_arrays` reads them back exactly)."""
        return {f"{prefix}id": self.id.copy(), f"{prefix}stamp": self.stamp.copy(),
                f"{prefix}n": self.n.copy(), f"{prefix}xy": self.xy.copy()}

    @staticmethod
    def from_arrays(arrays: Any, prefix: str = "footprint_") -> FootprintState | None:
        """The state saved by :meth:`to_arrays`, or None if ``arrays`` holds none."""
        if f"{prefix}id" not in arrays:
            return None
        ids = np.array(arrays[f"{prefix}id"], np.int64).reshape(-1)
        n = np.array(arrays[f"{prefix}n"], np.int64).reshape(-1)
        xy = np.array(arrays[f"{prefix}xy"], np.float64).reshape(-1, 2)[:int(n.sum())]
        if len(ids):  # entries grouped by track id (a saved state is; regroup any other)
            first = {}
            for k, t in enumerate(ids.tolist()):
                first.setdefault(t, k)
            order = np.array(sorted(range(len(ids)), key=lambda k: first[int(ids[k])]),
                             np.int64)
            if np.any(order != np.arange(len(ids))):
                starts = np.concatenate([[0], np.cumsum(n)[:-1]])
                xy = (np.concatenate([xy[starts[k]:starts[k] + n[k]] for k in order])
                      if len(xy) else xy)
                ids, n = ids[order], n[order]
                return FootprintState(ids, np.array(arrays[f"{prefix}stamp"], np.int64)
                                      .reshape(-1)[order], n, np.ascontiguousarray(xy))
        return FootprintState(ids, np.array(arrays[f"{prefix}stamp"], np.int64).reshape(-1),
                              n, np.ascontiguousarray(xy))


def cell_centres(cells: np.ndarray, window: Window) -> np.ndarray:
    """(m, 2) x, y (metres, working CRS) of the centres of flat window cells."""
    r, c = np.divmod(np.asarray(cells, np.int64), window.cols)
    res = window.resolution_m
    return np.stack([(c + window.col0 + 0.5) * res, (r + window.row0 + 0.5) * res], axis=1)


@numba.njit(cache=True, nogil=True)
def _geometry(cells: np.ndarray, cols: int, row0: int, col0: int, res: float,
              centroid: np.ndarray, bbox: np.ndarray, extent: np.ndarray) -> None:
    """Centroid (mean of the cell centres, summed in order as numpy's ``mean(axis=0)``),
    bbox of the outer edges and extent of non-empty flat ``cells``, into the given rows."""
    sx = 0.0
    sy = 0.0
    lox = np.inf
    loy = np.inf
    hix = -np.inf
    hiy = -np.inf
    for i in range(len(cells)):
        x = ((cells[i] % cols) + col0 + 0.5) * res
        y = ((cells[i] // cols) + row0 + 0.5) * res
        sx += x
        sy += y
        lox = min(lox, x)
        loy = min(loy, y)
        hix = max(hix, x)
        hiy = max(hiy, y)
    m = len(cells)
    centroid[0] = sx / m
    centroid[1] = sy / m
    half = res / 2
    bbox[0] = lox - half
    bbox[1] = loy - half
    bbox[2] = hix + half
    bbox[3] = hiy + half
    extent[0] = bbox[2] - bbox[0]
    extent[1] = bbox[3] - bbox[1]


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _complete(tid, moving, count, vel, cells, rows, cols, row0, col0, res, stamp, speaks_a,
              speaks_b, frames, h_id, h_stamp, h_n, h_xy):
    """The completion of one frame (module docstring): per record its completed cells
    (``full``, concatenated; ``full_n`` each), its earlier moving frames (``streak``),
    whether its geometry changed and the new geometry; and the new history arrays."""
    nrec = len(tid)
    # the history's groups: track id, first entry, entries, first centre
    ng = 0
    for e in range(len(h_id)):
        if e == 0 or h_id[e] != h_id[e - 1]:
            ng += 1
    g_tid = np.empty(ng, np.int64)
    g_e0 = np.empty(ng, np.int64)
    g_ne = np.zeros(ng, np.int64)
    g_x0 = np.empty(ng, np.int64)
    g = -1
    x_at = 0
    for e in range(len(h_id)):
        if e == 0 or h_id[e] != h_id[e - 1]:
            g += 1
            g_tid[g] = h_id[e]
            g_e0[g] = e
            g_x0[g] = x_at
        g_ne[g] += 1
        x_at += h_n[e]
    e_x0 = np.empty(len(h_id), np.int64)  # first centre of each entry
    x_at = 0
    for e in range(len(h_id)):
        e_x0[e] = x_at
        x_at += h_n[e]
    rec_group = np.full(nrec, -1, np.int64)  # the record's old group, -1: none
    group_rec = np.full(ng, -1, np.int64)    # the group's moving record now, -1: dropped
    own0 = np.empty(nrec + 1, np.int64)
    own0[0] = 0
    for k in range(nrec):
        own0[k + 1] = own0[k] + count[k]
        for gg in range(ng):
            if g_tid[gg] == tid[k]:
                rec_group[k] = gg
                if moving[k]:
                    group_rec[gg] = k
                break
    streak = np.zeros(nrec, np.int64)
    full_n = np.empty(nrec, np.int64)
    changed = np.zeros(nrec, np.bool_)
    centroid = np.zeros((nrec, 2))
    bbox = np.zeros((nrec, 4))
    extent = np.zeros((nrec, 2))
    pieces = []
    for k in range(nrec):
        own = cells[own0[k]:own0[k + 1]]
        gg = rec_group[k]
        if not moving[k] or gg < 0:
            full_n[k] = len(own)
            pieces.append(own.copy())
            continue
        streak[k] = g_ne[gg]
        total = 0
        for e in range(g_e0[gg], g_e0[gg] + g_ne[gg]):
            total += h_n[e]
        buf = np.empty(total, np.int64)
        m = 0
        v0 = vel[k, 0]
        v1 = vel[k, 1]
        for e in range(g_e0[gg], g_e0[gg] + g_ne[gg]):
            dt = (stamp - h_stamp[e]) * 1e-9
            d0 = v0 * dt
            d1 = v1 * dt
            for i in range(e_x0[e], e_x0[e] + h_n[e]):
                c = np.int64(np.floor((h_xy[i, 0] + d0) / res)) - col0
                r = np.int64(np.floor((h_xy[i, 1] + d1) / res)) - row0
                if r >= 0 and r < rows and c >= 0 and c < cols:
                    buf[m] = r * cols + c
                    m += 1
        add = sorted_unique(buf[:m])
        own_sorted = np.sort(own)
        keep = np.zeros(len(add), np.bool_)
        na = 0
        for i in range(len(add)):
            a = add[i]
            if speaks_a[a] > 0 or speaks_b[a] > 0:  # seen free or holding a return now
                continue
            j = np.searchsorted(own_sorted, a)
            if j < len(own_sorted) and own_sorted[j] == a:
                continue
            keep[i] = True
            na += 1
        full = np.empty(len(own) + na, np.int64)
        full[:len(own)] = own
        full[len(own):] = add[keep]
        full_n[k] = len(full)
        pieces.append(full)
        if len(full) != len(own):
            changed[k] = True
            _geometry(full, cols, row0, col0, res, centroid[k], bbox[k], extent[k])
    # the new history: kept old tracks in their order, then new moving tracks in record order
    n_new = 0
    x_new = 0
    o_id = np.empty(0, np.int64)
    o_stamp = np.empty(0, np.int64)
    o_n = np.empty(0, np.int64)
    o_xy = np.empty((0, 2), np.float64)
    for pass_ in range(2):
        if pass_ == 1:
            o_id = np.empty(n_new, np.int64)
            o_stamp = np.empty(n_new, np.int64)
            o_n = np.empty(n_new, np.int64)
            o_xy = np.empty((x_new, 2), np.float64)
        e_at = 0
        x_at = 0
        for step in range(ng + nrec):
            if step < ng:
                k = group_rec[step]
                if k < 0:
                    continue
                gg = step
            else:
                k = step - ng
                if not moving[k] or rec_group[k] >= 0:
                    continue
                gg = -1
            old = g_ne[gg] if gg >= 0 else 0
            skip = max(0, old + 1 - frames)  # past[-frames:] of the old entries + this one
            for e in range(skip, old + 1):
                if e < old:
                    src = g_e0[gg] + e
                    cnt = h_n[src]
                    if pass_ == 1:
                        o_id[e_at] = tid[k]
                        o_stamp[e_at] = h_stamp[src]
                        o_n[e_at] = cnt
                        o_xy[x_at:x_at + cnt] = h_xy[e_x0[src]:e_x0[src] + cnt]
                else:
                    cnt = own0[k + 1] - own0[k]
                    if pass_ == 1:
                        o_id[e_at] = tid[k]
                        o_stamp[e_at] = stamp
                        o_n[e_at] = cnt
                        for i in range(cnt):
                            cell = cells[own0[k] + i]
                            o_xy[x_at + i, 0] = ((cell % cols) + col0 + 0.5) * res
                            o_xy[x_at + i, 1] = ((cell // cols) + row0 + 0.5) * res
                e_at += 1
                x_at += cnt
        n_new = e_at
        x_new = x_at
    total = 0
    for k in range(nrec):
        total += full_n[k]
    full_cells = np.empty(total, np.int64)
    at = 0
    for k in range(nrec):
        full_cells[at:at + full_n[k]] = pieces[k]
        at += full_n[k]
    return (full_cells, full_n, streak, changed, centroid, bbox, extent,
            o_id, o_stamp, o_n, o_xy)


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _merge(moving, age, tid, streak, full, full_n, cells, count, cols, row0, col0, res, gap,
           extent_m):
    """The fragment merge (module docstring, **Fragments**): whether any record joined
    another, each record's owner, the owners' joined cells (concatenated, ``out_n`` each;
    owners only), and for the owners whose cells grew, their new geometry."""
    nrec = len(tid)
    f0 = np.empty(nrec + 1, np.int64)
    o0 = np.empty(nrec + 1, np.int64)
    f0[0] = 0
    o0[0] = 0
    for k in range(nrec):
        f0[k + 1] = f0[k] + full_n[k]
        o0[k + 1] = o0[k] + count[k]
    order = np.empty(nrec, np.int64)
    no = 0
    for k in range(nrec):  # the moving records, stably sorted by (-streak, -age, id)
        if not moving[k] or count[k] == 0:
            continue
        j = no
        while j > 0:
            p = order[j - 1]
            if (streak[p] < streak[k] or (streak[p] == streak[k] and (
                    age[p] < age[k] or (age[p] == age[k] and tid[p] > tid[k])))):
                order[j] = p
                j -= 1
            else:
                break
        order[j] = k
        no += 1
    owner = np.arange(nrec)
    joined = [full[f0[k]:f0[k + 1]].copy() for k in range(nrec)]
    seen = [cells[o0[k]:o0[k + 1]].copy() for k in range(nrec)]
    merged = False
    for j_at in range(no):
        j = order[j_at]
        obs = cells[o0[j]:o0[j + 1]]
        for i_at in range(j_at):
            i = order[i_at]
            if owner[i] != i:
                continue
            si = seen[i]
            d = np.iinfo(np.int64).max
            for a in range(len(si)):
                ra = si[a] // cols
                ca = si[a] % cols
                for b in range(len(obs)):
                    d = min(d, max(abs(ra - obs[b] // cols), abs(ca - obs[b] % cols)))
            if d > gap:
                continue
            both = sorted_unique(np.concatenate((si, obs)))
            lox = np.inf
            loy = np.inf
            hix = -np.inf
            hiy = -np.inf
            for a in range(len(both)):
                x = ((both[a] % cols) + col0 + 0.5) * res
                y = ((both[a] // cols) + row0 + 0.5) * res
                lox = min(lox, x)
                hix = max(hix, x)
                loy = min(loy, y)
                hiy = max(hiy, y)
            if max(hix - lox + res, hiy - loy + res) > extent_m + 1e-9:
                continue
            owner[j] = i
            joined[i] = sorted_unique(np.concatenate((joined[i], joined[j])))
            seen[i] = both
            merged = True
            break
    total = 0
    for k in range(nrec):
        if owner[k] == k:
            total += len(joined[k])
    out = np.empty(total, np.int64)
    out_n = np.zeros(nrec, np.int64)
    grown = np.zeros(nrec, np.bool_)
    centroid = np.zeros((nrec, 2))
    bbox = np.zeros((nrec, 4))
    extent = np.zeros((nrec, 2))
    at = 0
    for k in range(nrec):
        if owner[k] == k:
            out_n[k] = len(joined[k])
            out[at:at + out_n[k]] = joined[k]
            at += out_n[k]
            if out_n[k] != full_n[k]:
                grown[k] = True
                _geometry(joined[k], cols, row0, col0, res, centroid[k], bbox[k], extent[k])
    return merged, owner, out, out_n, grown, centroid, bbox, extent


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _set_geometry(out, which, counts, centroid, bbox, extent):  # pragma: no cover - compiled
    """The records of ``out`` where ``which`` is set, given the cell counts and geometry
    computed for them (the fields' casts numpy's assignment makes: int64 → uint32,
    float64 → float32 for the extent). One pass over the records instead of four fancy
    assignments of field views."""
    for k in range(out.shape[0]):
        if not which[k]:
            continue
        out[k].cell_count = counts[k]
        for q in range(2):
            out[k].centroid_m[q] = centroid[k, q]
            out[k].extent_m[q] = extent[k, q]
        for q in range(4):
            out[k].bbox_m[q] = bbox[k, q]


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _fields(objects):  # pragma: no cover - compiled
    """The record fields the completion reads, as contiguous arrays: track id, moving,
    cell count, velocity (float64), age (one pass instead of five field copies)."""
    n = objects.shape[0]
    tid = np.empty(n, np.int64)
    moving = np.empty(n, np.bool_)
    count = np.empty(n, np.int64)
    vel = np.empty((n, 2), np.float64)
    age = np.empty(n, np.int64)
    for k in range(n):
        r = objects[k]
        tid[k] = r.track_id
        moving[k] = r.state == _MOVING
        count[k] = r.cell_count
        vel[k, 0] = r.velocity_m_per_s[0]
        vel[k, 1] = r.velocity_m_per_s[1]
        age[k] = r.age_frames
    return tid, moving, count, vel, age


def complete_footprints(state: FootprintState, objects: np.ndarray, cells: np.ndarray,
                        window: Window, stamp_ns: int,
                        scan_speaks: np.ndarray | tuple[np.ndarray, np.ndarray],
                        params: FootprintParams) -> tuple[np.ndarray, np.ndarray]:
    """The frame's object list with each moving object's footprint completed (module
    docstring); ``state`` updated in place. ``objects``, ``cells``: the tracker's records
    and their flat window cells, in record order; ``scan_speaks``: (rows, cols) bool, the
    cells seen free or holding a return in this scan, or a pair of (rows, cols) layers (the
    sensor grid's m({F}), m({O})) of which a cell speaks where either is > 0, read only at
    the cells the completion needs (saves the runner a pass over the window). Returns new
    records and cells (the inputs unchanged); with ``params.frames == 0``, the inputs
    themselves."""
    if params.frames <= 0:
        return objects, cells
    out = objects.copy()
    if len(objects) == 0:
        state.id, state.stamp, state.n, state.xy = (np.zeros(0, np.int64), np.zeros(0, np.int64),
                                                    np.zeros(0, np.int64), _EMPTY_XY)
        return out, np.zeros(0, np.uint32)
    if isinstance(scan_speaks, tuple):
        speaks_a, speaks_b = (np.ascontiguousarray(layer).reshape(-1) for layer in scan_speaks)
    else:
        speaks_a = speaks_b = np.ascontiguousarray(np.asarray(scan_speaks, bool).reshape(-1))
    tid, moving, count, vel, age = _fields(out)
    own = np.ascontiguousarray(np.asarray(cells, np.int64)[:int(count.sum())])
    res = float(window.resolution_m)
    rows, cols, row0, col0 = int(window.rows), int(window.cols), int(window.row0), int(window.col0)
    (full, full_n, streak, changed, centroid, bbox, extent,
     state.id, state.stamp, state.n, state.xy) = _complete(
        tid, moving, count, vel, own, rows, cols, row0, col0, res, int(stamp_ns), speaks_a,
        speaks_b,
        int(params.frames), state.id, state.stamp, state.n, state.xy)
    _set_geometry(out, changed, full_n, centroid, bbox, extent)
    if params.fragment_gap_cells > 0 and np.count_nonzero(moving & (count > 0)) > 1:
        merged, owner, joined, joined_n, grown, centroid, bbox, extent = _merge(
            moving, age, tid, streak,
            full, full_n, own, count, cols, row0, col0, res, int(params.fragment_gap_cells),
            float(params.fragment_extent_m))
        if merged:
            _set_geometry(out, grown, joined_n, centroid, bbox, extent)
            return out[owner == np.arange(len(owner))], joined.astype(np.uint32)
    return out, full.astype(np.uint32)


def warm_up(params: FootprintParams) -> None:
    """Load (or compile) the compiled passes for the argument types the runner gives them
    (the scan's bool layer as ``scan_speaks``, :func:`evperc.objects.stage.scan_cells`, a
    history of two frames, two moving fragments), on a tiny made-up object list: the first
    real frames are not charged a cache load (~30–40 ms each). Changes nothing."""
    if params.frames <= 0:
        return
    window = Window(1.0, 4, 4, 0, 0)
    speaks = np.zeros(window.shape, np.bool_)
    objects = np.zeros(2, OBJECT_DTYPE)
    objects["track_id"] = (1, 2)
    objects["state"] = _MOVING
    objects["cell_count"] = 1
    objects["velocity_m_per_s"] = (1.0, 0.0)
    state = FootprintState()
    for k, cells in enumerate(([0, 2], [1, 3])):
        complete_footprints(state, objects, np.array(cells, np.uint32), window,
                            k * 100_000_000, speaks, params)
