"""Reference: evperc/objects/footprint.py as of main d27d56c (a Python loop per moving object
with np.unique / np.isin), kept to test the compiled version against (test_footprint_reference.py).
Not used by evperc."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from evperc.geo.window import Window
from evperc.objects.footprint import FootprintParams  # the same parameters
from evperc.output.objects import OBJECT_STATES

_MOVING = OBJECT_STATES["moving"]


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


def _set_geometry(rec: np.ndarray, cells: np.ndarray, window: Window) -> None:
    """``rec``'s cell_count, centroid, bbox and extent set to those of ``cells``."""
    xy = cell_centres(cells, window)
    res = window.resolution_m
    rec["cell_count"] = len(cells)
    rec["centroid_m"] = xy.mean(axis=0)
    lo, hi = xy.min(axis=0) - res / 2, xy.max(axis=0) + res / 2
    rec["bbox_m"] = (lo[0], lo[1], hi[0], hi[1])
    rec["extent_m"] = hi - lo


def _gap_cells(a: np.ndarray, b: np.ndarray, cols: int) -> int:
    """Smallest Chebyshev distance (cells) between flat cells ``a`` and ``b`` (non-empty)."""
    ra, ca = np.divmod(a, cols)
    rb, cb = np.divmod(b, cols)
    d = np.maximum(np.abs(ra[:, None] - rb[None, :]), np.abs(ca[:, None] - cb[None, :]))
    return int(d.min())


def merge_fragments(objects: np.ndarray, pieces: list[np.ndarray], observed: list[np.ndarray],
                    streak: list[int], window: Window, params: FootprintParams
                    ) -> tuple[np.ndarray, list[np.ndarray]]:
    """The moving fragments of one object joined into the oldest (module docstring,
    **Fragments**). ``pieces``: each record's (completed) cells; ``observed``: its cluster
    cells; ``streak``: its earlier moving frames held in the history (at most
    ``footprint_frames``). Returns the kept records and their cells, in record order."""
    moving = [k for k in range(len(objects)) if objects[k]["state"] == _MOVING
              and len(observed[k]) > 0]
    order = sorted(moving, key=lambda k: (-int(streak[k]), -int(objects[k]["age_frames"]),
                                          int(objects[k]["track_id"])))
    owner = {k: k for k in range(len(objects))}
    joined = {k: pieces[k] for k in range(len(objects))}
    seen_cells = {k: observed[k] for k in range(len(objects))}
    res = window.resolution_m
    for j_at, j in enumerate(order):  # each younger object, into the oldest that fits
        for i in order[:j_at]:
            if owner[i] != i:
                continue
            if _gap_cells(seen_cells[i], observed[j], window.cols) > params.fragment_gap_cells:
                continue
            both = np.union1d(seen_cells[i], observed[j])
            xy = cell_centres(both, window)
            if (xy.max(axis=0) - xy.min(axis=0) + res).max() > params.fragment_extent_m + 1e-9:
                continue
            owner[j] = i
            joined[i] = np.union1d(joined[i], joined[j])
            seen_cells[i] = both
            break
    if all(owner[k] == k for k in owner):
        return objects, pieces
    keep = [k for k in range(len(objects)) if owner[k] == k]
    out = objects[keep].copy()
    for at, k in enumerate(keep):
        if len(joined[k]) != len(pieces[k]):
            _set_geometry(out[at], joined[k], window)
    return out, [joined[k] for k in keep]


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
    observed = []
    streak = []
    at = 0
    seen: set[int] = set()
    for k, rec in enumerate(objects):
        n = int(rec["cell_count"])
        own = np.asarray(cells[at:at + n], np.int64)
        observed.append(own)
        at += n
        tid = int(rec["track_id"])
        seen.add(tid)
        if rec["state"] != _MOVING:
            state.history.pop(tid, None)
            streak.append(0)
            pieces.append(own)
            continue
        past = state.history.get(tid, [])
        streak.append(len(past))
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
            _set_geometry(out[k], full, window)
    for tid in [t for t in state.history if t not in seen]:  # tracks not reported now
        del state.history[tid]
    if params.fragment_gap_cells > 0:
        out, pieces = merge_fragments(out, pieces, observed, streak, window, params)
    new_cells = (np.concatenate(pieces).astype(np.uint32) if pieces
                 else np.zeros(0, np.uint32))
    return out, new_cells
