"""Evidence per beam: the state of every polar cell of one azimuth bin (SPEC §3, Moras 2011).

Per azimuth bin ``a``, with ``k_o`` the range bin of its nearest obstacle point and ``k_g``
the range bin of its furthest ground point:

- obstacle present: bins ``k < k_o`` free (m(F) = μ_F), bin ``k_o`` occupied (m(O) = μ_O),
  bins beyond unknown;
- ground only: bins ``k ≤ k_g`` free, beyond unknown (the ground return itself is a free
  surface; ground returns beyond an obstacle add nothing);
- no return: every bin unknown (never free).

A beam is summarised by two integers: ``obstacle_bin[a]`` (``n_range`` when none) and
``free_end[a]``: bins ``k < free_end[a]`` are free.
"""

from __future__ import annotations

import numpy as np

UNKNOWN = np.uint8(0)
FREE = np.uint8(1)
OCCUPIED = np.uint8(2)


def nearest_obstacle_bin(az_bin: np.ndarray, range_bin: np.ndarray, n_az: int,
                         n_range: int) -> np.ndarray:
    """``k_o`` per azimuth bin: the smallest range bin of the obstacle points, ``n_range``
    where the bin has none (int32, shape (n_az,))."""
    nearest = np.full(n_az, n_range, dtype=np.int32)
    np.minimum.at(nearest, az_bin, range_bin)
    return nearest


def furthest_ground_bin(az_bin: np.ndarray, range_bin: np.ndarray, n_az: int) -> np.ndarray:
    """``k_g`` per azimuth bin: the largest range bin of the ground points, −1 where none."""
    furthest = np.full(n_az, -1, dtype=np.int32)
    np.maximum.at(furthest, az_bin, range_bin)
    return furthest


def free_extent(obstacle_bin: np.ndarray, ground_bin: np.ndarray, n_range: int) -> np.ndarray:
    """``free_end`` per azimuth bin: ``k_o`` where there is an obstacle, else ``k_g + 1``
    (0 without any return)."""
    return np.where(obstacle_bin < n_range, obstacle_bin, ground_bin + 1).astype(np.int32)


def polar_state(obstacle_bin: np.ndarray, free_end: np.ndarray, az_bin: np.ndarray,
                range_bin: np.ndarray) -> np.ndarray:
    """State (UNKNOWN / FREE / OCCUPIED, uint8) of the polar cells ``(az_bin, range_bin)``
    (arrays of any matching shape)."""
    state = (range_bin < free_end[az_bin]).view(np.uint8)
    state |= (range_bin == obstacle_bin[az_bin]).view(np.uint8) << 1
    return state
