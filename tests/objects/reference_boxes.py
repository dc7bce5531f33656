"""Reference: evperc/objects/boxes.py as first written (a numpy pass per moving record), kept
to test the compiled version against (test_boxes.py). Not used by evperc."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from evperc.fusion.twin import DECISION_CODES
from evperc.geo.window import Window
from evperc.objects.boxes import BoxParams  # the same parameters
from evperc.objects.tracking import ego_cell_centre
from evperc.output.objects import OBJECT_STATES

_MOVING = OBJECT_STATES["moving"]
_REMEMBERED = [DECISION_CODES[n] for n in ("static", "stopped", "unmapped", "infrastructure")]


def complete_boxes(objects: np.ndarray, cells: np.ndarray, window: Window,
                   scan_speaks: tuple[np.ndarray, np.ndarray] | np.ndarray,
                   decision: np.ndarray, params: BoxParams,
                   returns: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The frame's object list with each moving vehicle's footprint completed to its box
    (module docstring). ``objects``, ``cells``: records and their flat window cells, in
    record order; ``scan_speaks``: (rows, cols) bool, the cells seen free or holding a
    return in this scan, or the sensor grid's (m({F}), m({O})) layers (a cell speaks where
    either is > 0). Returns new records and cells (the inputs unchanged); the inputs
    themselves when boxes are off or no record is a moving vehicle."""
    if not params.enabled or len(objects) == 0:
        return objects, cells
    counts = objects["cell_count"].astype(np.int64)
    ends = np.cumsum(counts)
    flat_cells = np.asarray(cells, np.int64)
    held = np.zeros(window.rows * window.cols, np.bool_)
    held[flat_cells[:int(ends[-1])]] = True
    res = float(window.resolution_m)
    sx, sy = ego_cell_centre(window)
    pieces, out, changed = [], objects.copy(), False
    for k, record in enumerate(objects):
        own = flat_cells[ends[k] - counts[k]:ends[k]]
        added = _box_cells(record, own, window, res, (sx, sy), scan_speaks, held, params,
                           returns, decision)
        if added.size:
            held[added] = True
            own = np.concatenate([own, added])
            _set_geometry(out[k:k + 1], own, window)
            changed = True
        pieces.append(own)
    if not changed:
        return objects, cells
    return out, np.concatenate(pieces).astype(np.uint32)


def _box_cells(record: np.ndarray, own: np.ndarray, window: Window, res: float,
               sensor: tuple[float, float], scan_speaks: Any, held: np.ndarray,
               params: BoxParams, returns: np.ndarray | None = None,
               decision: np.ndarray | None = None) -> np.ndarray:
    """The flat window cells a moving vehicle's box adds (none for any other record)."""
    vx, vy = (float(v) for v in record["velocity_m_per_s"])
    speed = math.hypot(vx, vy)
    if record["state"] != _MOVING or own.size == 0 or speed == 0.0:
        return np.zeros(0, np.int64)
    x, y = _centres(own, window, res)
    ux, uy = vx / speed, vy / speed
    pu, pw = x * ux + y * uy, -x * uy + y * ux
    if (np.ptp(pu) + 1e-9 < params.min_length_m
            and np.ptp(pw) + 1e-9 < params.min_width_m):
        return np.zeros(0, np.int64)  # no vehicle
    su, sw = sensor[0] * ux + sensor[1] * uy, -sensor[0] * uy + sensor[1] * ux
    u0, u1 = _extend(float(pu.min()), float(pu.max()), su, params.length_m)
    w0, w1 = _extend(float(pw.min()), float(pw.max()), sw, params.width_m)
    # the cells of the box's bounding rectangle on the lattice, then the box test
    corners_x = np.array([u0 * ux - w0 * uy, u0 * ux - w1 * uy, u1 * ux - w0 * uy,
                          u1 * ux - w1 * uy])
    corners_y = np.array([u0 * uy + w0 * ux, u0 * uy + w1 * ux, u1 * uy + w0 * ux,
                          u1 * uy + w1 * ux])
    c_lo = max(int(math.floor(corners_x.min() / res)) - window.col0, 0)
    c_hi = min(int(math.floor(corners_x.max() / res)) - window.col0, window.cols - 1)
    r_lo = max(int(math.floor(corners_y.min() / res)) - window.row0, 0)
    r_hi = min(int(math.floor(corners_y.max() / res)) - window.row0, window.rows - 1)
    if c_lo > c_hi or r_lo > r_hi:
        return np.zeros(0, np.int64)
    rr, cc = np.mgrid[r_lo:r_hi + 1, c_lo:c_hi + 1]
    flat = (rr * window.cols + cc).reshape(-1)
    bx, by = _centres(flat, window, res)
    bu, bw = bx * ux + by * uy, -bx * uy + by * ux
    eps = 1e-6
    inside = (bu >= u0 - eps) & (bu <= u1 + eps) & (bw >= w0 - eps) & (bw <= w1 + eps)
    flat = flat[inside]
    silent = ~_speaks(scan_speaks, flat)
    if decision is not None:  # remembered obstacles are not the car's hidden half
        silent &= ~np.isin(decision.reshape(-1)[flat], _REMEMBERED)
    if returns is not None:
        silent &= returns.reshape(-1)[flat] <= 0
    return flat[~held[flat] & silent]


def _extend(lo: float, hi: float, sensor: float, size: float) -> tuple[float, float]:
    """The span [lo, hi] grown to ``size`` away from ``sensor`` (unchanged if longer)."""
    if hi - lo >= size:
        return lo, hi
    if sensor <= (lo + hi) / 2:
        return lo, lo + size
    return hi - size, hi


def _centres(flat: np.ndarray, window: Window, res: float) -> tuple[np.ndarray, np.ndarray]:
    """Cell centres (x, y) m of flat window cells."""
    r, c = np.divmod(np.asarray(flat, np.int64), window.cols)
    return (c + window.col0 + 0.5) * res, (r + window.row0 + 0.5) * res


def _speaks(scan_speaks: Any, flat: np.ndarray) -> np.ndarray:
    if isinstance(scan_speaks, tuple):
        return ((scan_speaks[0].reshape(-1)[flat] > 0)
                | (scan_speaks[1].reshape(-1)[flat] > 0))
    return np.asarray(scan_speaks).reshape(-1)[flat].astype(bool)


def _set_geometry(record: np.ndarray, own: np.ndarray, window: Window) -> None:
    """A record's cell count, centroid, bbox and extent from its cells ``own`` (flat)."""
    res = float(window.resolution_m)
    x, y = _centres(own, window, res)
    record["cell_count"] = len(own)
    record["centroid_m"] = (x.mean(), y.mean())
    record["bbox_m"] = (x.min() - res / 2, y.min() - res / 2, x.max() + res / 2,
                        y.max() + res / 2)
    record["extent_m"] = (x.max() - x.min() + res, y.max() - y.min() + res)
