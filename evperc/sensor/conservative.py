"""Conservative free space: two neighbourhood passes on one scan's sensor grid (docs/method.md,
"Conservative free space"; after DUFOMap's d_s and d_p, Duberg et al. RA-L 2024).

The paper's sensor model (method.md §3) gives m({F}) = μ_F to every world cell a ray passes. At
0.5 m cells that carves the faces of walls and car sides seen at grazing angles (a ray that
passes a wall within a few centimetres marks the wall's cell free), and a later return in such a
cell is then an "object appeared" conflict ∅_FO, i.e. false motion. Two margins withhold the
free evidence where it is least trustworthy. On the scan's cell states (UNKNOWN / FREE /
OCCUPIED after the polar → world projection) a FREE cell ``c`` keeps m({F}) = μ_F only if

- **d_s** (``free_margin_m``): no OCCUPIED cell ``o`` of this scan lies within it,
  ``‖centre(o) − centre(c)‖ > free_margin_m``;
- **d_p** (``free_erosion_m``): no UNKNOWN cell ``u`` of this scan lies within it,
  ``‖centre(u) − centre(c)‖ > free_erosion_m``

(centre-to-centre Euclidean distances; with 0.5 m cells, 0.5 m means the 4 edge neighbours and
0.75 m the 8 neighbours). A cell that fails either test becomes vacuous (m(Ω_SG) = 1): the
scan says nothing about it. Both tests read the states as projected, never the result of the
pass, so the erosion does not feed on itself. Cells outside the window count as neither
occupied nor unknown. Occupied masses are never changed.

d_s differs from DUFOMap's in its shape: DUFOMap marks the last d_s of each ray before its hit
as a hit; here the whole disc around every occupied cell is withheld, which also covers cells
lateral to a return — where another beam's grazing ray passes a wall.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from evperc.sensor.evidence import FREE, OCCUPIED, UNKNOWN

#: tolerance of the distance comparison, metres: a neighbour at exactly the margin is inside
_EPS_M = 1e-6


def disc_offsets(radius_m: float, resolution_m: float) -> np.ndarray:
    """``(K, 2)`` int64 ``(drow, dcol)`` of the cells whose centres lie within ``radius_m`` of
    a cell's centre, the cell itself excluded: ``0 < (drow² + dcol²)·r² ≤ radius²``. Empty for a
    radius below one cell."""
    if radius_m <= 0:
        return np.zeros((0, 2), np.int64)
    reach = int(math.floor(radius_m / resolution_m + 1e-9))
    d = np.arange(-reach, reach + 1)
    dr, dc = np.meshgrid(d, d, indexing="ij")
    dist2 = (dr * dr + dc * dc) * resolution_m * resolution_m
    keep = (dist2 > 0) & (dist2 <= (radius_m + _EPS_M) ** 2)
    return np.stack([dr[keep], dc[keep]], axis=1).astype(np.int64)


def conservative_free(state: np.ndarray, free: np.ndarray, resolution_m: float,
                      free_margin_m: float, free_erosion_m: float) -> int:
    """Zero ``free`` (float32, the scan's m({F}), changed in place) at the FREE cells of
    ``state`` (uint8, the projected cell states, same shape) that fail the d_s or d_p test of
    the module docstring; returns the number of cells whose free mass was withheld. With both
    margins below one cell this changes nothing."""
    margin = disc_offsets(free_margin_m, resolution_m)
    erosion = disc_offsets(free_erosion_m, resolution_m)
    if len(margin) == 0 and len(erosion) == 0:
        return 0
    if state.shape != free.shape:
        raise ValueError(f"state {state.shape} and free {free.shape} differ in shape")
    return int(_withhold(state, free, margin, erosion))


@numba.njit(cache=True, nogil=True)
def _withhold(state: np.ndarray, free: np.ndarray, margin: np.ndarray,
              erosion: np.ndarray) -> int:
    """See :func:`conservative_free`. A FREE cell is withheld when a margin offset reaches an
    OCCUPIED cell or an erosion offset reaches an UNKNOWN one (inside the window)."""
    rows, cols = state.shape
    withheld = 0
    zero = np.float32(0.0)
    for i in range(rows):
        for j in range(cols):
            if state[i, j] != FREE:
                continue
            hit = False
            for k in range(margin.shape[0]):
                r = i + margin[k, 0]
                c = j + margin[k, 1]
                if 0 <= r < rows and 0 <= c < cols and state[r, c] == OCCUPIED:
                    hit = True
                    break
            if not hit:
                for k in range(erosion.shape[0]):
                    r = i + erosion[k, 0]
                    c = j + erosion[k, 1]
                    if 0 <= r < rows and 0 <= c < cols and state[r, c] == UNKNOWN:
                        hit = True
                        break
            if hit:
                free[i, j] = zero
                withheld += 1
    return withheld
