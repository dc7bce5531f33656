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

Input is the object list of the frame (records and cells, :mod:`evperc.output.objects`),
so this does not depend on the tracker's internals."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from evperc.geo.window import Window
from evperc.output.objects import OBJECT_STATES

_MOVING = OBJECT_STATES["moving"]


@dataclass(frozen=True)
class FootprintParams:
    """The ``[objects]`` key of the completion (configs/default.toml)."""

    #: objects.footprint_frames: past moving frames whose cluster cells, carried forward by
    #: the velocity, complete the footprint (0: off)
    frames: int = 0  # configs/default.toml: tuned value

    @staticmethod
    def from_config(config: dict[str, Any]) -> FootprintParams:
        return FootprintParams(frames=int(config.get("objects", {}).get("footprint_frames", 0)))


@dataclass
class FootprintState:
    """Per track id, its last moving frames: (stamp_ns, cell centres (m, 2) x, y metres)."""

    history: dict[int, list[tuple[int, np.ndarray]]] = field(default_factory=dict)

    def copy(self) -> FootprintState:
        return FootprintState({k: [(t, xy.copy()) for t, xy in v]
                               for k, v in self.history.items()})

    def to_arrays(self, prefix: str = "footprint_") -> dict[str, np.ndarray]:
        """Flat arrays for the checkpoint (:meth:`from_arrays` reads them back exactly)."""
        ids, stamps, counts, xys = [], [], [], []
        for tid, frames in self.history.items():
            for t, xy in frames:
                ids.append(tid)
                stamps.append(t)
                counts.append(len(xy))
                xys.append(xy)
        return {f"{prefix}id": np.array(ids, np.int64),
                f"{prefix}stamp": np.array(stamps, np.int64),
                f"{prefix}n": np.array(counts, np.int64),
                f"{prefix}xy": (np.concatenate(xys) if xys else np.zeros((0, 2), np.float64))}

    @staticmethod
    def from_arrays(arrays: Any, prefix: str = "footprint_") -> FootprintState | None:
        """The state saved by :meth:`to_arrays`, or None if ``arrays`` holds none."""
        if f"{prefix}id" not in arrays:
            return None
        state = FootprintState()
        xy = np.asarray(arrays[f"{prefix}xy"], np.float64)
        at = 0
        for tid, t, n in zip(arrays[f"{prefix}id"], arrays[f"{prefix}stamp"],
                             arrays[f"{prefix}n"], strict=True):
            state.history.setdefault(int(tid), []).append(
                (int(t), xy[at:at + int(n)].copy()))
            at += int(n)
        return state


def cell_centres(cells: np.ndarray, window: Window) -> np.ndarray:
    """(m, 2) x, y (metres, working CRS) of the centres of flat window cells."""
    r, c = np.divmod(np.asarray(cells, np.int64), window.cols)
    res = window.resolution_m
    return np.stack([(c + window.col0 + 0.5) * res, (r + window.row0 + 0.5) * res], axis=1)


def _cells_at(xy: np.ndarray, window: Window) -> np.ndarray:
    """Flat window indices of the cells holding points ``xy``; points outside dropped."""
    res = window.resolution_m
    col = np.floor(xy[:, 0] / res).astype(np.int64) - window.col0
    row = np.floor(xy[:, 1] / res).astype(np.int64) - window.row0
    inside = (row >= 0) & (row < window.rows) & (col >= 0) & (col < window.cols)
    return row[inside] * window.cols + col[inside]


def complete_footprints(state: FootprintState, objects: np.ndarray, cells: np.ndarray,
                        window: Window, stamp_ns: int, scan_speaks: np.ndarray,
                        params: FootprintParams) -> tuple[np.ndarray, np.ndarray]:
    """The frame's object list with each moving object's footprint completed (module
    docstring); ``state`` updated in place. ``objects``, ``cells``: the tracker's records
    and their flat window cells, in record order; ``scan_speaks``: (rows, cols) bool, the
    cells seen free or holding a return in this scan. Returns new records and cells (the
    inputs unchanged); with ``params.frames == 0``, the inputs themselves."""
    if params.frames <= 0:
        return objects, cells
    speaks = np.asarray(scan_speaks, bool).reshape(-1)
    out = objects.copy()
    pieces = []
    at = 0
    seen: set[int] = set()
    res = window.resolution_m
    for k, rec in enumerate(objects):
        n = int(rec["cell_count"])
        own = np.asarray(cells[at:at + n], np.int64)
        at += n
        tid = int(rec["track_id"])
        seen.add(tid)
        if rec["state"] != _MOVING:
            state.history.pop(tid, None)
            pieces.append(own)
            continue
        past = state.history.get(tid, [])
        v = np.asarray(rec["velocity_m_per_s"], np.float64)
        extra = [_cells_at(xy + v * ((stamp_ns - t) * 1e-9), window) for t, xy in past]
        if extra:
            add = np.unique(np.concatenate(extra))
            add = add[~speaks[add]]
            add = add[~np.isin(add, own)]
            full = np.concatenate([own, add])
        else:
            full = own
        past.append((int(stamp_ns), cell_centres(own, window)))
        state.history[tid] = past[-params.frames:]
        pieces.append(full)
        if len(full) != n:
            xy = cell_centres(full, window)
            out[k]["cell_count"] = len(full)
            out[k]["centroid_m"] = xy.mean(axis=0)
            lo, hi = xy.min(axis=0) - res / 2, xy.max(axis=0) + res / 2
            out[k]["bbox_m"] = (lo[0], lo[1], hi[0], hi[1])
            out[k]["extent_m"] = hi - lo
    for tid in [t for t in state.history if t not in seen]:  # tracks not reported now
        del state.history[tid]
    new_cells = (np.concatenate(pieces).astype(np.uint32) if pieces
                 else np.zeros(0, np.uint32))
    return out, new_cells
