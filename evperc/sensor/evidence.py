"""Evidence per beam: the state of every polar cell of one azimuth bin (method.md §3, Moras 2011).

Per azimuth bin ``a``, with ``k_o`` the range bin of its nearest obstacle point and ``k_g``
the range bin of its furthest ground point:

- obstacle present: bins ``k < k_o`` free (m(F) = μ_F), bin ``k_o`` occupied (m(O) = μ_O),
  bins beyond unknown;
- ground only: bins ``k ≤ k_g`` free, beyond unknown (the ground return itself is a free
  surface; ground returns beyond an obstacle add nothing);
- no return: every bin unknown (never free).

A beam is summarised by two integers: ``obstacle_bin[a]`` (``n_range`` when none) and
``free_end[a]``: bins ``k < free_end[a]`` are free. The state of the polar cell ``(a, k)``
is FREE if ``k < free_end[a]``, OCCUPIED if ``k = obstacle_bin[a]``, UNKNOWN otherwise
(:mod:`.projection` reads it so).
"""

from __future__ import annotations

import numba
import numpy as np

from evperc.sensor.ground import GROUND, OBSTACLE

UNKNOWN = np.uint8(0)
FREE = np.uint8(1)
OCCUPIED = np.uint8(2)


@numba.njit(cache=True, nogil=True)
def beam_extents(az_bin: np.ndarray, range_bin: np.ndarray, kind: np.ndarray, n_range: int,
                 obstacle_bin: np.ndarray, free_end: np.ndarray) -> None:
    """Fill ``obstacle_bin`` (``k_o``, ``n_range`` where the bin has no obstacle point) and
    ``free_end`` (``k_o`` where there is an obstacle, else ``k_g + 1``, 0 without any
    return), both int32 (n_az,), from the points' bins and GROUND / OBSTACLE kinds."""
    n_az = obstacle_bin.shape[0]
    furthest = np.full(n_az, -1, dtype=np.int32)
    obstacle_bin[:] = n_range
    for i in range(az_bin.shape[0]):
        a = az_bin[i]
        if kind[i] == OBSTACLE:
            obstacle_bin[a] = min(obstacle_bin[a], range_bin[i])
        elif kind[i] == GROUND:
            furthest[a] = max(furthest[a], range_bin[i])
    for a in range(n_az):
        free_end[a] = obstacle_bin[a] if obstacle_bin[a] < n_range else furthest[a] + 1

