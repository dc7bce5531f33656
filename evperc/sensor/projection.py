"""Visiting world cells: the polar grid mapped onto the window (method.md §3, polar → world).

Three passes fill a uint8 state per window cell (UNKNOWN 0 < FREE 1 < OCCUPIED 2) so that
occupied wins over free over unknown wherever several polar cells meet one world cell: the
state is the maximum of what the passes give the cell. On a state of zeros:

1. :func:`scatter_free_polar_cells` — the centre ``((k + ½)·c, a·Δ)`` of every free polar
   cell within ``[min_range_m, max_range_m)`` marks the world cell it falls in free. Near
   the sensor a world cell spans several azimuth bins (at 0.5°/0.5 m, up to ~57 m), so this
   keeps free rays that pass between cell centres.
2. :func:`scatter_hits` — the world cell holding each obstacle *point* that lies in its
   bin's occupied polar cell is occupied. This keeps thin obstacles (a pole seen by one
   azimuth bin) that no cell centre samples. The points themselves are used rather than the
   occupied polar cells' centres: a polar cell centre can lie up to half a range bin from
   the return and fall in the neighbouring world cell.
3. :func:`rasterise` — every world cell whose centre lies within
   ``[min_range_m, max_range_m)`` of the sensor (only the bounding box of that disc is
   visited) takes the maximum of its state and that of the polar cell holding its centre
   ``(r, θ)``; in the same pass over all cells the state becomes the masses m({F}), m({O}).

Passes 1 and 2 store their value without reading the cell (a read-modify-write per polar
cell would chain through memory): in this order, that is the maximum.

Cell centres are offsets ``(dx, dy)`` from the sensor in float32, in range if
``dx² + dy²`` is in ``[min², max²)``; their polar coordinates ``√(dx² + dy²)`` and
``atan2(dy, dx) − ψ`` are binned as the points are (:mod:`.beams`). World coordinates
(polar cell centres, points) are float64, the cell holding ``(x, y)`` is
``(⌊y/r⌋ − row0, ⌊x/r⌋ − col0)`` as in :meth:`Window.index_of`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from evperc.geo.window import Window
from evperc.sensor.beams import PolarLayout
from evperc.sensor.evidence import FREE, OCCUPIED, UNKNOWN
from evperc.sensor.ground import OBSTACLE

# The kernels below call only jitted helpers of this module: numba's cache checks the source
# file of a kernel, not of the functions it inlines from elsewhere. The imported constants are
# frozen into the cached code too (clear __pycache__ after changing them).


def scatter_free_polar_cells(state: np.ndarray, window: Window, sensor_xy: tuple[float, float],
                             heading_rad: float, layout: PolarLayout,
                             free_end: np.ndarray) -> None:
    """Pass 1: set FREE every world cell holding the centre of a free polar cell."""
    angle = np.arange(layout.n_az) * layout.az_step_rad + heading_rad
    _scatter_free(state, float(window.resolution_m), window.row0, window.col0, sensor_xy[0],
                  sensor_xy[1], np.cos(angle), np.sin(angle), layout.range_bin_m,
                  layout.min_range_m, layout.max_range_m, free_end)


def scatter_hits(state: np.ndarray, window: Window, sensor_xy: tuple[float, float],
                 x: np.ndarray, y: np.ndarray, az_bin: np.ndarray, range_bin: np.ndarray,
                 kind: np.ndarray, obstacle_bin: np.ndarray) -> None:
    """Pass 2: set OCCUPIED the world cells holding the OBSTACLE points (level offsets
    ``x``, ``y`` from the sensor) whose range bin is their azimuth bin's ``obstacle_bin``."""
    _scatter_hits(state, float(window.resolution_m), window.row0, window.col0, sensor_xy[0],
                  sensor_xy[1], x, y, az_bin, range_bin, kind, obstacle_bin)


def scatter_all_hits(mask: np.ndarray, window: Window, sensor_xy: tuple[float, float],
                     x: np.ndarray, y: np.ndarray, kind: np.ndarray) -> None:
    """Set True in ``mask`` (bool ``window.shape``, not cleared here) every world cell
    holding an OBSTACLE point — every return, not only the first of its azimuth bin (the
    object stage's ``objects.cluster_on = "all_returns"``). Not part of the sensor grid."""
    _scatter_all_hits(mask.view(np.uint8), float(window.resolution_m), window.row0,
                      window.col0, sensor_xy[0], sensor_xy[1], x, y, kind)


def scatter_top_heights(top: np.ndarray, window: Window, sensor_xy: tuple[float, float],
                        x: np.ndarray, y: np.ndarray, kind: np.ndarray,
                        height: np.ndarray) -> None:
    """Raise each cell of ``top`` (float32 ``window.shape``, not cleared here) to the height
    above the local ground of the highest OBSTACLE point in it (``height``:
    :func:`evperc.sensor.ground.classify_points`' per-point ``d``) — every return, not only
    the first of its azimuth bin —, and at least to the smallest positive float32
    (:data:`TOP_FLOOR`: a return at exactly the threshold of a 0 m ``ground_threshold_m``
    still marks its cell). Not part of the sensor grid."""
    _scatter_top_heights(top, float(window.resolution_m), window.row0, window.col0,
                         sensor_xy[0], sensor_xy[1], x, y, kind, height)


def scatter_top_heights_and_sums(top: np.ndarray, sums: np.ndarray, window: Window,
                                 sensor_xy: tuple[float, float], x: np.ndarray, y: np.ndarray,
                                 kind: np.ndarray, height: np.ndarray) -> None:
    """:func:`scatter_top_heights` and :func:`scatter_return_sums` in one pass over the
    points, with the sums *written*, not added: a cell's three sums are set to zero at its
    first OBSTACLE point of the scan — the point that finds its ``top`` still 0 —, so that
    ``sums`` needs no clearing and holds this scan's sums exactly where ``top`` > 0 after the
    pass (elsewhere whatever it held: read it only there). ``top`` must be 0 in every cell
    (the sensor grid fills it) and every OBSTACLE point raises its cell to at least the
    smallest positive float32 (:func:`scatter_top_heights`), so ``top`` > 0 marks the cells
    holding one. The same cells, heights and sums as the two passes on a zeroed ``sums``
    (tested)."""
    _scatter_top_heights_and_sums(top, sums, float(window.resolution_m), window.row0,
                                  window.col0, sensor_xy[0], sensor_xy[1], x, y, kind, height)


def scatter_return_sums(sums: np.ndarray, window: Window, sensor_xy: tuple[float, float],
                        x: np.ndarray, y: np.ndarray, kind: np.ndarray) -> None:
    """Add to each cell of ``sums`` (float32 ``(*window.shape, 3)``, not cleared here) the
    offsets of its OBSTACLE points from the cell's centre, ``Σ (xᵢ − x_c)``, ``Σ (yᵢ − y_c)``
    (m), and their count — every return, not only the first of its azimuth bin — so that a
    group of cells has the mean of its returns for a centroid, not of its cell centres
    (``objects.centroid = "returns"``). Not part of the sensor grid."""
    _scatter_return_sums(sums, float(window.resolution_m), window.row0, window.col0,
                         sensor_xy[0], sensor_xy[1], x, y, kind)


def rasterise(state: np.ndarray, window: Window, sensor_xy: tuple[float, float],
              heading_rad: float, layout: PolarLayout, obstacle_bin: np.ndarray,
              free_end: np.ndarray, mu_free: float, mu_occupied: float,
              azimuth_buffer: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pass 3, then ``(free, occupied)`` float32 masses: μ_F where the state is FREE, μ_O
    where OCCUPIED, 0 elsewhere. ``azimuth_buffer``: float32 scratch of at least
    ``window.rows · window.cols`` elements (the cell-centre azimuths)."""
    xs, ys = window.cell_centres()
    sx, sy = sensor_xy
    reach = layout.max_range_m
    c0, c1 = (int(v) for v in np.searchsorted(xs, [sx - reach, sx + reach]))
    r0, r1 = (int(v) for v in np.searchsorted(ys, [sy - reach, sy + reach]))
    if c0 >= c1 or r0 >= r1:
        c0 = c1 = r0 = r1 = 0
    dx = (xs[c0:c1] - sx).astype(np.float32)
    dy = (ys[r0:r1] - sy).astype(np.float32)
    azimuth = azimuth_buffer[:dy.size * dx.size].reshape(dy.size, dx.size)
    np.arctan2(dy[:, None], dx, out=azimuth)
    # one block for both: fewer, larger allocations, which glibc then keeps on its heap
    free, occupied = np.empty((2, *window.shape), np.float32)
    _rasterise(state, r0, c0, dx, dy, azimuth, np.float32(heading_rad), layout.inv_az_step32,
               layout.n_az, layout.inv_range_bin32, layout.n_range,
               np.float32(layout.min_range_m ** 2), np.float32(reach ** 2), obstacle_bin,
               free_end, np.float32(mu_free), np.float32(mu_occupied), free, occupied)
    return free, occupied


@numba.njit(cache=True, nogil=True, inline="always")
def _mark(state: np.ndarray, res: float, row0: int, col0: int, x: float, y: float,
          value: np.uint8) -> None:
    """Set the state of the cell holding ``(x, y)`` to ``value``, if in the window (a plain
    store: no read-modify-write chain through memory)."""
    row = math.floor(y / res) - row0
    col = math.floor(x / res) - col0
    if 0 <= row < state.shape[0] and 0 <= col < state.shape[1]:
        state[row, col] = value


@numba.njit(cache=True, nogil=True)
def _scatter_hits(state, res, row0, col0, sx, sy, x, y, az_bin, range_bin, kind,
                  obstacle_bin) -> None:
    """See :func:`scatter_hits`."""
    for i in range(x.shape[0]):
        if kind[i] == OBSTACLE and range_bin[i] == obstacle_bin[az_bin[i]]:
            _mark(state, res, row0, col0, sx + np.float64(x[i]), sy + np.float64(y[i]),
                  OCCUPIED)


#: the most occupied cells in the 5 × 5 block around a foot for the object beside it to be
#: small — a person, whose shoe is a foot with the leg seen above it (method.md §3)
SMALL_OBJECT_CELLS = 4


def unfree_feet(state: np.ndarray, free: np.ndarray, window: Window,
                sensor_xy: tuple[float, float], x: np.ndarray, y: np.ndarray,
                feet: np.ndarray) -> None:
    """After pass 3: every FREE cell holding one of the ``feet`` (indices of the GROUND
    points standing ``sensor.foot_lift_m`` or more above the nearer band's ground,
    :func:`evperc.sensor.ground.classify_points`) becomes UNKNOWN and loses its free mass —
    unless a small object stands beside it: an OCCUPIED cell among its 8 neighbours and at
    most ``SMALL_OBJECT_CELLS`` in its 5 × 5 block (method.md §3 "An object's foot"). Cells
    turned UNKNOWN here are not OCCUPIED, so the order of the feet does not matter."""
    _unfree(state, free, float(window.resolution_m), window.row0, window.col0, sensor_xy[0],
            sensor_xy[1], x, y, feet)


@numba.njit(cache=True, nogil=True)
def _unfree(state, free, res, row0, col0, sx, sy, x, y, feet) -> None:
    """See :func:`unfree_feet` (cells as :func:`_mark`)."""
    rows, cols = state.shape
    for i in feet:
        r = math.floor((sy + np.float64(y[i])) / res) - row0
        c = math.floor((sx + np.float64(x[i])) / res) - col0
        if 0 <= r < rows and 0 <= c < cols and state[r, c] == FREE:
            beside = 0   # occupied cells among the 8 neighbours
            around = 0   # ... and in the 5 × 5 block
            for dr in range(max(r - 2, 0), min(r + 3, rows)):
                for dc in range(max(c - 2, 0), min(c + 3, cols)):
                    if state[dr, dc] == OCCUPIED:
                        around += 1
                        if abs(dr - r) <= 1 and abs(dc - c) <= 1:
                            beside += 1
            if beside == 0 or around > SMALL_OBJECT_CELLS:
                state[r, c] = UNKNOWN
                free[r, c] = 0.0


@numba.njit(cache=True, nogil=True)
def _scatter_all_hits(mask, res, row0, col0, sx, sy, x, y, kind) -> None:
    """See :func:`scatter_all_hits`."""
    for i in range(x.shape[0]):
        if kind[i] == OBSTACLE:
            _mark(mask, res, row0, col0, sx + np.float64(x[i]), sy + np.float64(y[i]),
                  np.uint8(1))


def points_in_context(out: np.ndarray, context: np.ndarray, value: int, window: Window,
                      sensor_xy: tuple[float, float], x: np.ndarray, y: np.ndarray) -> None:
    """Write into ``out`` (uint8, a point each) 1 for each point (level offsets ``x``, ``y``
    from the sensor) whose world cell lies in the window with ``context`` (uint8
    ``window.shape``, :mod:`evperc.geo.prior`'s map context) equal to ``value``, else 0
    (``sensor.ground_chain_gap_road_only``: the returns on a mapped road)."""
    if context.shape != window.shape:
        raise ValueError(f"context {context.shape}, the window is {window.shape}")
    _points_in_context(out, context, np.uint8(value), float(window.resolution_m), window.row0,
                       window.col0, sensor_xy[0], sensor_xy[1], x, y)


@numba.njit(cache=True, nogil=True)
def _points_in_context(out, context, value, res, row0, col0, sx, sy, x, y) -> None:
    """See :func:`points_in_context` (cells as :func:`_mark`)."""
    rows, cols = context.shape
    for i in range(x.shape[0]):
        _, _, _, _, r, c = _world_cell(res, row0, col0, sx, sy, x[i], y[i])
        out[i] = np.uint8(1) if (0 <= r < rows and 0 <= c < cols
                                 and context[r, c] == value) else np.uint8(0)


#: the least value :func:`scatter_top_heights` leaves in a cell holding an OBSTACLE point
TOP_FLOOR = np.float32(np.finfo(np.float32).tiny)


@numba.njit(cache=True, nogil=True)
def _scatter_top_heights(top, res, row0, col0, sx, sy, x, y, kind, height) -> None:
    """See :func:`scatter_top_heights` (cells as :func:`_mark`)."""
    rows, cols = top.shape
    for i in range(x.shape[0]):
        if kind[i] == OBSTACLE:
            _, _, _, _, r, c = _world_cell(res, row0, col0, sx, sy, x[i], y[i])
            if 0 <= r < rows and 0 <= c < cols:
                _raise_top(top, r, c, height[i])


@numba.njit(cache=True, nogil=True)
def _scatter_top_heights_and_sums(top, sums, res, row0, col0, sx, sy, x, y, kind, height
                                  ) -> None:
    """See :func:`scatter_top_heights_and_sums` (cells as :func:`_mark`; the sums' offsets
    as :func:`_scatter_return_sums`)."""
    rows, cols = top.shape
    for i in range(x.shape[0]):
        if kind[i] == OBSTACLE:
            wx, wy, r_abs, c_abs, r, c = _world_cell(res, row0, col0, sx, sy, x[i], y[i])
            if 0 <= r < rows and 0 <= c < cols:
                if top[r, c] == 0:  # the cell's first return of the scan
                    sums[r, c, 0] = np.float32(0.0)
                    sums[r, c, 1] = np.float32(0.0)
                    sums[r, c, 2] = np.float32(0.0)
                _raise_top(top, r, c, height[i])
                _add_return(sums, r, c, wx, wy, r_abs, c_abs, res)


@numba.njit(cache=True, nogil=True, inline="always")
def _raise_top(top, r, c, height):  # pragma: no cover - compiled
    """Raise ``top[r, c]`` to a return's height above the ground, and at least to
    :data:`TOP_FLOOR`."""
    h = max(height, TOP_FLOOR)
    if h > top[r, c]:
        top[r, c] = h


@numba.njit(cache=True, nogil=True)
def _scatter_return_sums(sums, res, row0, col0, sx, sy, x, y, kind) -> None:
    """See :func:`scatter_return_sums` (cells as :func:`_mark`)."""
    rows, cols = sums.shape[0], sums.shape[1]
    for i in range(x.shape[0]):
        if kind[i] == OBSTACLE:
            wx, wy, r_abs, c_abs, r, c = _world_cell(res, row0, col0, sx, sy, x[i], y[i])
            if 0 <= r < rows and 0 <= c < cols:
                _add_return(sums, r, c, wx, wy, r_abs, c_abs, res)


@numba.njit(cache=True, nogil=True, inline="always")
def _world_cell(res, row0, col0, sx, sy, x, y):  # pragma: no cover - compiled
    """A point's world coordinates (float64, from its float32 offsets ``x``, ``y`` from the
    sensor at ``(sx, sy)``), the lattice row and column holding it, and that cell's row and
    column in the window whose first cell is ``(row0, col0)``."""
    wx = sx + np.float64(x)
    wy = sy + np.float64(y)
    r_abs = math.floor(wy / res)
    c_abs = math.floor(wx / res)
    return wx, wy, r_abs, c_abs, r_abs - row0, c_abs - col0


@numba.njit(cache=True, nogil=True, inline="always")
def _add_return(sums, r, c, wx, wy, r_abs, c_abs, res):  # pragma: no cover - compiled
    """Add a return at ``(wx, wy)`` to window cell ``(r, c)``'s sums: its offsets from the
    centre of lattice cell ``(r_abs, c_abs)`` and a count of one."""
    sums[r, c, 0] += np.float32(wx - (c_abs + 0.5) * res)
    sums[r, c, 1] += np.float32(wy - (r_abs + 0.5) * res)
    sums[r, c, 2] += np.float32(1.0)


@numba.njit(cache=True, nogil=True)
def _scatter_free(state, res, row0, col0, sx, sy, cos, sin, range_bin_m, min_range,
                  max_range, free_end) -> None:
    """See :func:`scatter_free_polar_cells`."""
    for a in range(free_end.shape[0]):
        for k in range(free_end[a]):
            centre = (k + 0.5) * range_bin_m
            if centre >= min_range and centre < max_range:
                _mark(state, res, row0, col0, sx + centre * cos[a], sy + centre * sin[a], FREE)


@numba.njit(cache=True, nogil=True)
def _rasterise(state, r0, c0, dx, dy, azimuth, heading, inv_az_step, n_az, inv_range_bin,
               n_range, min_r2, max_r2, obstacle_bin, free_end, mu_free, mu_occupied, free,
               occupied) -> None:
    """See :func:`rasterise`: cells ``[r0, r0 + dy.size) × [c0, c0 + dx.size)`` are sampled."""
    az_bin = np.empty(dx.shape[0], np.int32)
    range_bin = np.empty(dx.shape[0], np.int32)
    for row in range(state.shape[0]):
        i = row - r0
        if 0 <= i < dy.shape[0]:
            # two loops: the first (arithmetic only) vectorises, the second looks up the beams
            _polar_cells(dx, dy[i] * dy[i], azimuth[i], heading, inv_az_step, n_az,
                         inv_range_bin, n_range, min_r2, max_r2, az_bin, range_bin)
            _sample(state[row, c0:c0 + dx.shape[0]], az_bin, range_bin, obstacle_bin,
                    free_end)
        _masses_row(state[row], mu_free, mu_occupied, free[row], occupied[row])


@numba.njit(cache=True, nogil=True, inline="always")
def _polar_cells(dx, dy2, azimuth, heading, inv_az_step, n_az, inv_range_bin, n_range,
                 min_r2, max_r2, az_bin, range_bin) -> None:
    """Polar cell ``(a, k)`` of the centres ``(dx[j], dy)`` of one row; ``k = −1`` outside
    ``[min_range, max_range)``."""
    for j in range(dx.shape[0]):
        r2 = dy2 + dx[j] * dx[j]
        az_bin[j] = _wrap_bin(np.int32(np.rint((azimuth[j] - heading) * inv_az_step)), n_az)
        k = min(np.int32(np.sqrt(r2) * inv_range_bin), n_range - 1)
        range_bin[j] = k if (r2 >= min_r2) & (r2 < max_r2) else -1


@numba.njit(cache=True, nogil=True, inline="always")
def _sample(state, az_bin, range_bin, obstacle_bin, free_end) -> None:
    """Raise ``state[j]`` to the state of the polar cell ``(az_bin[j], range_bin[j])``."""
    for j in range(state.shape[0]):
        k = range_bin[j]
        if k >= 0:
            a = az_bin[j]
            sampled = FREE if k < free_end[a] else OCCUPIED if k == obstacle_bin[a] else UNKNOWN
            state[j] = max(state[j], sampled)


@numba.njit(cache=True, nogil=True, inline="always")
def _masses_row(state, mu_free, mu_occupied, free, occupied) -> None:
    """μ_F where FREE, μ_O where OCCUPIED, 0 elsewhere."""
    zero = np.float32(0.0)
    for j in range(state.shape[0]):
        free[j] = mu_free if state[j] == FREE else zero
        occupied[j] = mu_occupied if state[j] == OCCUPIED else zero


@numba.njit(cache=True, nogil=True, inline="always")
def _wrap_bin(v: int, n: int) -> int:
    """``v mod n`` for ``v`` in ``[−n, 2n)``: :func:`evperc.sensor.beams.wrap_bin`, repeated
    here for the cache (see the note on the imports)."""
    v = v + n if v < 0 else v
    return v - n if v >= n else v
