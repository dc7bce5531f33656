"""Visiting world cells: the polar grid mapped onto the window (SPEC §3, polar → world).

Three passes fill a uint8 state per window cell (UNKNOWN 0 < FREE 1 < OCCUPIED 2), each
keeping the maximum, so occupied wins over free over unknown wherever several polar cells
meet one world cell:

1. :func:`sample_cell_centres` — every world cell whose centre lies within
   ``[min_range_m, max_range_m)`` of the sensor (only the bounding box of that disc is
   computed) takes the state of the polar cell holding its centre ``(r, θ)``.
2. :func:`scatter_free_polar_cells` — the centre ``((k + ½)·c, a·Δ)`` of every free polar
   cell within ``[min_range_m, max_range_m)`` marks the world cell it falls in at least free.
   Near the sensor a world cell spans several azimuth bins (at 0.5°/0.5 m, up to ~57 m), so
   this keeps free rays that pass between cell centres.
3. :func:`scatter_points` (used for the obstacle points lying in their bin's occupied polar
   cell) — the world cell holding each such *point* is occupied. This keeps thin obstacles
   (a pole seen by one azimuth bin) that no cell centre samples. The points themselves are
   used rather than the occupied polar cells' centres: a polar cell centre can lie up to half
   a range bin from the return and fall in the neighbouring world cell.
"""

from __future__ import annotations

import numpy as np

from evperc.geo.window import Window
from evperc.sensor.beams import PolarLayout
from evperc.sensor.evidence import FREE, OCCUPIED, polar_state


def sample_cell_centres(state: np.ndarray, window: Window, sensor_xy: tuple[float, float],
                        heading_rad: float, layout: PolarLayout, obstacle_bin: np.ndarray,
                        free_end: np.ndarray) -> None:
    """Pass 1: write into ``state`` (rows, cols) the polar state at each cell centre."""
    xs, ys = window.cell_centres()
    sx, sy = sensor_xy
    reach = layout.max_range_m
    c0, c1 = np.searchsorted(xs, [sx - reach, sx + reach])
    r0, r1 = np.searchsorted(ys, [sy - reach, sy + reach])
    if c0 >= c1 or r0 >= r1:
        return
    dx = (xs[c0:c1] - sx).astype(np.float32)
    dy = (ys[r0:r1] - sy).astype(np.float32)[:, None]
    r2 = dy * dy + dx * dx
    in_range = (r2 >= np.float32(layout.min_range_m ** 2)) & (r2 < np.float32(reach ** 2))
    az = layout.azimuth_bin(np.arctan2(dy, dx) - np.float32(heading_rad))
    rb = np.minimum(layout.range_bin(np.sqrt(r2)), layout.n_range - 1)
    sampled = polar_state(obstacle_bin, free_end, az, rb)
    sampled *= in_range.view(np.uint8)
    np.maximum(state[r0:r1, c0:c1], sampled, out=state[r0:r1, c0:c1])


def scatter_free_polar_cells(state: np.ndarray, window: Window, sensor_xy: tuple[float, float],
                             heading_rad: float, layout: PolarLayout,
                             free_end: np.ndarray) -> None:
    """Pass 2: raise to FREE every world cell holding the centre of a free polar cell."""
    centres = (np.arange(layout.n_range) + 0.5) * layout.range_bin_m
    usable = (centres >= layout.min_range_m) & (centres < layout.max_range_m)
    free = (np.arange(layout.n_range)[None, :] < free_end[:, None]) & usable[None, :]
    a, k = np.nonzero(free)
    if a.size == 0:
        return
    angle = np.arange(layout.n_az) * layout.az_step_rad + heading_rad
    cos, sin = np.cos(angle), np.sin(angle)
    x = sensor_xy[0] + centres[k] * cos[a]
    y = sensor_xy[1] + centres[k] * sin[a]
    rows, cols = _cells_inside(window, x, y)
    flat = state.reshape(-1)
    idx = rows * window.cols + cols
    flat[idx] = np.maximum(flat[idx], FREE)


def scatter_points(state: np.ndarray, window: Window, x: np.ndarray, y: np.ndarray) -> None:
    """Pass 3: set OCCUPIED the world cells holding the points ``(x, y)`` (working CRS)."""
    rows, cols = _cells_inside(window, x, y)
    state.reshape(-1)[rows * window.cols + cols] = OCCUPIED


def _cells_inside(window: Window, x: np.ndarray, y: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = window.index_of(x, y)
    inside = window.contains(rows, cols)
    return rows[inside], cols[inside]
