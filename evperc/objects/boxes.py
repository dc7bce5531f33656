"""Vehicle boxes: a moving vehicle's footprint completed to a car-sized box on its far side
(docs/method.md §8, "Vehicle boxes"; issue 21).

A lidar sees a car's near faces — the rear or front, one side — and nothing of the cells
under the rest of it: its own body hides them. The footprint completion
(:mod:`evperc.objects.footprint`) brings back the parts the car showed in earlier frames, but
a car driving ahead of the sensor or passing beside it never shows its far half. So a moving
object that is a vehicle gets the rest of an oriented box of a vehicle's size:

- *orientation*: its velocity (a car drives along its length): unit vectors u = v / |v|
  and w ⊥ u;
- *vehicle*: a moving record whose cell centres span at least ``box_min_length_m`` along u
  (a car's side) or ``box_min_width_m`` across it (its rear or front): a person is a cell or
  two, a cyclist seen from the side 2 m long and one cell wide;
- *box*: the record's cell centres projected on u and w give the observed spans
  [u₀, u₁], [w₀, w₁]; a span shorter than the vehicle's (``box_length_m`` along u,
  ``box_width_m`` along w) is extended **away from the sensor** — the side the sensor sees is
  the observed face, the hidden part lies beyond it:

      u₁ = u₀ + L  if the sensor's projection s_u ≤ (u₀ + u₁) / 2,  else  u₀ = u₁ − L,

  and the same along w with W (s the sensor position, the centre of the window's centre
  cell);
- *cells*: those whose centres lie in the box, not decided ``static``, ``stopped``,
  ``unmapped`` or ``infrastructure`` (a wall or a parked car the grid remembers there is not
  the car's hidden half: its near face is in front of it), that the scan of this frame is
  silent about
  (neither seen free nor holding a return — any obstacle return of the scan, not only the
  first one of its azimuth bin that the sensor model marks occupied: something seen
  beyond the car's near face is not the car's hidden half — so the box never contradicts
  the scan, as the footprint completion) and that no other record holds.

The added cells join the record (its ``cell_count``, centroid, bbox and extent are those of
the completed footprint, its velocity the tracker's) and, with ``objects.fill_moving``,
are decided ``moving``: a decision, not evidence (the masses are not changed).

Implementation: one compiled pass over the records (:func:`_boxes`), equal to the per-record
numpy version it was first written as (tests/objects/reference_boxes.py): the same cells
in the same order, the geometry within rounding (a sequential sum for the centroid).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np

from evperc.fusion.twin import DECISION_CODES
from evperc.geo.window import Window
from evperc.objects.footprint import _geometry, _set_geometry
from evperc.objects.tracking import ego_cell_centre
from evperc.output.objects import OBJECT_DTYPE, OBJECT_STATES

_MOVING = OBJECT_STATES["moving"]


@dataclass(frozen=True)
class BoxParams:
    """The ``[objects]`` keys of the vehicle boxes (configs/default.toml)."""

    #: objects.box_length_m: a vehicle's length along its velocity (0: no boxes)
    length_m: float = 0.0
    #: objects.box_width_m: its width across
    width_m: float = 0.0
    #: objects.box_min_length_m: a moving record whose cell centres span at least this along
    #: its velocity is a vehicle (a car's side) ...
    min_length_m: float = 3.0
    #: objects.box_min_width_m: ... or at least this across it (a car's rear or front)
    min_width_m: float = 1.0

    @staticmethod
    def from_config(config: dict[str, Any]) -> BoxParams:
        o = config.get("objects", {})
        return BoxParams(float(o.get("box_length_m", 0.0)), float(o.get("box_width_m", 0.0)),
                         float(o.get("box_min_length_m", 3.0)),
                         float(o.get("box_min_width_m", 1.0)))

    @property
    def enabled(self) -> bool:
        return self.length_m > 0 and self.width_m > 0


def complete_boxes(objects: np.ndarray, cells: np.ndarray, window: Window,
                   scan_speaks: tuple[np.ndarray, np.ndarray] | np.ndarray,
                   decision: np.ndarray, params: BoxParams, scratch: np.ndarray | None = None,
                   returns: np.ndarray | None = None, only: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The frame's object list with each moving vehicle's footprint completed to its box
    (module docstring). ``objects``, ``cells``: records and their flat window cells, in
    record order; ``scan_speaks``: (rows, cols) bool, the cells seen free or holding a
    return in this scan, or the sensor grid's (m({F}), m({O})) layers (a cell speaks where
    either is > 0, read only at the cells a box covers); ``decision``: the frame's decided
    cells (uint8 codes, (rows, cols)); ``scratch``: a zeroed uint8 layer
    of the window's size to mark the records' cells in (zeroed again on return; None: one
    is made); ``returns``: (rows, cols), > 0 where the cell holds any obstacle return of
    the scan, not only a first one (the sensor grid's ``heights_out`` layer; None: the first
    returns only); ``only``: bool per record, the records to complete (None: all; the others'
    cells are kept from the boxes all the same). Returns new records and cells (the inputs
    unchanged); the inputs themselves when boxes are off or no box adds a cell."""
    if not params.enabled or len(objects) == 0:
        return objects, cells
    if isinstance(scan_speaks, tuple):
        speaks_a, speaks_b = (flat_layer(layer) for layer in scan_speaks)
    else:
        speaks_a = speaks_b = flat_layer(scan_speaks)
    if scratch is None:
        scratch = np.zeros(window.rows * window.cols, np.uint8)
    # without returns: a dummy of the speaks layers' dtype (one compiled variant per dtype)
    held_returns = (flat_layer(returns) if returns is not None
                    else np.zeros(1, speaks_a.dtype))
    moving = objects["state"] == _MOVING
    if only is not None:
        moving &= np.asarray(only, np.bool_)
    count = objects["cell_count"].astype(np.int64)
    velocity = np.ascontiguousarray(objects["velocity_m_per_s"], np.float64)
    own = np.ascontiguousarray(np.asarray(cells, np.int64)[:int(count.sum())])
    sx, sy = ego_cell_centre(window)
    full, full_n, changed, centroid, bbox, extent = _boxes(
        moving, count, velocity, own, int(window.rows), int(window.cols), int(window.row0),
        int(window.col0), float(window.resolution_m), sx, sy, speaks_a, speaks_b,
        held_returns, returns is not None, np.ascontiguousarray(decision).reshape(-1),
        _STATIC_CODES, float(params.length_m), float(params.width_m),
        float(params.min_length_m), float(params.min_width_m), scratch.reshape(-1))
    if not changed.any():
        return objects, cells
    out = objects.copy()
    _set_geometry(out, changed, full_n, centroid, bbox, extent)
    return out, full.astype(np.uint32)


def flat_layer(layer: np.ndarray) -> np.ndarray:
    """A layer read as ``> 0``, flat and without a copy: a bool one as its 0/1 bytes (the
    runner's, :func:`evperc.objects.stage.scan_cells`), any other as float32 (the sensor
    grid's). Read by the boxes and the backfill's :func:`~evperc.objects.backfill.bridge_cells`."""
    layer = np.asarray(layer)
    if layer.dtype == np.bool_ or layer.dtype == np.uint8:
        return np.ascontiguousarray(layer).reshape(-1).view(np.uint8)
    return np.ascontiguousarray(layer, np.float32).reshape(-1)


class VehicleBoxes:
    """:func:`complete_boxes` with ``params`` and a zeroed scratch layer of its own, kept
    from call to call and sized to the window (one per caller: the runner's frames, the
    backfill's)."""

    def __init__(self, params: BoxParams) -> None:
        self.params = params
        self._marks = np.zeros(0, np.uint8)

    @property
    def enabled(self) -> bool:
        return self.params.enabled

    def complete(self, objects: np.ndarray, cells: np.ndarray, window: Window,
                 scan_speaks: tuple[np.ndarray, np.ndarray] | np.ndarray,
                 decision: np.ndarray, returns: np.ndarray | None = None,
                 only: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """:func:`complete_boxes` of these arguments."""
        size = window.rows * window.cols
        if self._marks.size != size:
            self._marks = np.zeros(size, np.uint8)
        return complete_boxes(objects, cells, window, scan_speaks, decision, self.params,
                              scratch=self._marks, returns=returns, only=only)


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _boxes(moving, count, velocity, own, rows, cols, row0, col0, res, sx, sy, speaks_a,
           speaks_b, returns, has_returns, decision, static, length, width, min_length,
           min_width, marks):  # pragma: no cover - compiled
    """:func:`complete_boxes` on the records' fields: returns the completed cells (record
    order, each record's own cells first, then its box's in row-major order), their counts,
    which records changed, and the changed records' centroid, bbox and extent."""
    n = count.shape[0]
    for q in range(own.shape[0]):
        marks[own[q]] = 1
    add_n = np.zeros(n, np.int64)
    boxes = []
    at = 0
    for k in range(n):
        a, b = at, at + count[k]
        at = b
        box = np.empty(0, np.int64)
        vx, vy = velocity[k, 0], velocity[k, 1]
        speed = math.hypot(vx, vy)
        if moving[k] and b > a and speed != 0.0:
            box = _box(own[a:b], vx / speed, vy / speed, rows, cols, row0, col0, res, sx, sy,
                       speaks_a, speaks_b, returns, has_returns, decision, static, length,
                       width, min_length, min_width, marks)
        boxes.append(box)
        add_n[k] = box.shape[0]
    total = own.shape[0] + add_n.sum()
    full = np.empty(total, np.int64)
    full_n = count + add_n
    changed = add_n > 0
    centroid = np.zeros((n, 2))
    bbox = np.zeros((n, 4))
    extent = np.zeros((n, 2))
    at = 0
    out = 0
    for k in range(n):
        for q in range(at, at + count[k]):
            full[out] = own[q]
            out += 1
        at += count[k]
        for q in range(add_n[k]):
            full[out] = boxes[k][q]
            out += 1
        if changed[k]:
            _geometry(full[out - full_n[k]:out], cols, row0, col0, res, centroid[k], bbox[k],
                      extent[k])
    for q in range(full.shape[0]):  # the marks back to zero
        marks[full[q]] = 0
    return full, full_n, changed, centroid, bbox, extent


@numba.njit(cache=True)
def _box(own, ux, uy, rows, cols, row0, col0, res, sx, sy, speaks_a, speaks_b, returns,
         has_returns, decision, static, length, width, min_length, min_width, marks
         ):  # pragma: no cover - compiled
    """The cells one moving record's box adds (module docstring), marked in ``marks``;
    none if it is no vehicle."""
    u0, u1, w0, w1 = np.inf, -np.inf, np.inf, -np.inf
    for q in range(own.shape[0]):
        r = own[q] // cols
        x = (own[q] - r * cols + col0 + 0.5) * res
        y = (r + row0 + 0.5) * res
        pu, pw = x * ux + y * uy, -x * uy + y * ux
        u0, u1 = min(u0, pu), max(u1, pu)
        w0, w1 = min(w0, pw), max(w1, pw)
    if u1 - u0 + 1e-9 < min_length and w1 - w0 + 1e-9 < min_width:
        return np.empty(0, np.int64)  # no vehicle
    u0, u1 = _extend(u0, u1, sx * ux + sy * uy, length)
    w0, w1 = _extend(w0, w1, -sx * uy + sy * ux, width)
    xs = (u0 * ux - w0 * uy, u0 * ux - w1 * uy, u1 * ux - w0 * uy, u1 * ux - w1 * uy)
    ys = (u0 * uy + w0 * ux, u0 * uy + w1 * ux, u1 * uy + w0 * ux, u1 * uy + w1 * ux)
    c_lo = max(int(math.floor(min(xs) / res)) - col0, 0)
    c_hi = min(int(math.floor(max(xs) / res)) - col0, cols - 1)
    r_lo = max(int(math.floor(min(ys) / res)) - row0, 0)
    r_hi = min(int(math.floor(max(ys) / res)) - row0, rows - 1)
    if c_lo > c_hi or r_lo > r_hi:
        return np.empty(0, np.int64)
    out = np.empty((r_hi - r_lo + 1) * (c_hi - c_lo + 1), np.int64)
    n = 0
    eps = 1e-6
    for r in range(r_lo, r_hi + 1):
        by = (r + row0 + 0.5) * res
        for c in range(c_lo, c_hi + 1):
            bx = (c + col0 + 0.5) * res
            bu, bw = bx * ux + by * uy, -bx * uy + by * ux
            if not (u0 - eps <= bu <= u1 + eps and w0 - eps <= bw <= w1 + eps):
                continue
            f = r * cols + c
            if marks[f] or static[decision[f]] or speaks_a[f] > 0 or speaks_b[f] > 0 or (
                    has_returns and returns[f] > 0):
                continue
            marks[f] = 1
            out[n] = f
            n += 1
    return out[:n].copy()


@numba.njit(cache=True)
def _extend(lo, hi, sensor, size):  # pragma: no cover - compiled
    """The span [lo, hi] grown to ``size`` away from ``sensor`` (unchanged if longer)."""
    if hi - lo >= size:
        return lo, hi
    if sensor <= (lo + hi) / 2:
        return lo, lo + size
    return hi - size, hi


#: by decision code: the decisions a box does not take (the grid remembers an obstacle)
_STATIC_CODES = np.zeros(256, np.bool_)
_STATIC_CODES[[DECISION_CODES[n] for n in ("static", "stopped", "unmapped",
                                           "infrastructure")]] = True


def warm_up(params: BoxParams) -> None:
    """Load (or compile) the compiled passes for the runner's argument types (the scan's
    bool layers, :func:`evperc.objects.stage.scan_cells`) on a made-up moving vehicle: the
    first real frame is not charged a cache load. Changes nothing."""
    if not params.enabled:
        return
    window = Window(0.5, 8, 8, 0, 0)
    record = np.zeros(1, OBJECT_DTYPE)
    record["state"] = _MOVING
    record["cell_count"] = 4
    record["velocity_m_per_s"] = (1.0, 0.0)
    layer = np.zeros(window.shape, np.bool_)
    complete_boxes(record, np.array([1, 9, 17, 25], np.uint32), window, layer,
                   np.zeros(window.shape, np.uint8), params, returns=layer)
