"""The motion gate: where an "object appeared" conflict (∅_FO) may count as motion.

A separate pass before the fused step (docs/method.md, "The motion gate"), after Dynablox's
ever-free voxels (Schmid et al., RA-L 2023), in the belief-function frame's sensor terms.
Per cell, in a circular buffer like ζ (:mod:`evperc.fusion.fused`: window cell ``(r, c)`` is buffer
cell ``((r + offset[0]) % rows, (c + offset[1]) % cols)``; cells entering the window start
reset), four numbers:

- ``free_s``: time of the cell's current run of free observations — m_SG({F}) ≥
  ``gate_min_free`` with m_SG({O}) = 0 — counting dt at each free scan after the run's
  first (a scan that does not observe the cell neither adds nor breaks); −1: no run. A
  return (m_SG({O}) > 0) ends the run.
- ``occ_s``: length of the current run of occupied scans (m_SG({O}) > 0), gaps up to
  ``gate_gap_s`` without a return tolerated (lidar sparsity).
- ``quiet_s``: time since the cell's last return.
- ``ever``: the cell is *ever-free*.

Per scan, with R(x) = [free_s(x) ≥ gate_free_s] after this scan's update and
V(x) = [x's return this scan ends an occupied run of occ_s ≥ gate_revoke_s, or comes back
after a gap: more than ``gate_gap_s`` and at most ``gate_rehit_s`` since x's previous
return (a thin object seen through beam gaps; 0 = off)]:

    ever(x) ← 0                 if V(y) for some y in the 3 × 3 block around x
    ever(x) ← 1                 elif R(y) for every y in the 3 × 3 block around x
    ever(x) unchanged           otherwise

(neighbours outside the window count as not free and not revoking). The gate layer of the
scan is ``ever`` in window order: 1 where ∅_FO may go to {M}.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from evperc.fusion.twin import FusionParams

#: planes of the gate state
FREE_S, OCC_S, QUIET_S = 0, 1, 2
#: ``quiet_s`` of a cell never seen occupied (any value above every gap)
NEVER = np.float32(1e9)
#: seconds of slack on the time comparisons (scan intervals jitter by a few ms)
SLACK = np.float32(1e-3)


@dataclass
class GateState:
    """The motion gate's per-cell state, circular buffers of the fusion state's shape:
    ``times`` float32 ``(3, rows, cols)`` (``free_s``, ``occ_s``, ``quiet_s``) and
    ``ever`` uint8 ``(rows, cols)``."""

    times: np.ndarray
    ever: np.ndarray

    @staticmethod
    def fresh(shape: tuple[int, int]) -> GateState:
        times = np.empty((3, *shape), np.float32)
        times[FREE_S] = -1.0
        times[OCC_S] = 0.0
        times[QUIET_S] = NEVER
        return GateState(times, np.zeros(shape, np.uint8))

    def copy(self) -> GateState:
        return GateState(self.times.copy(), self.ever.copy())


def gate_step(state: GateState, free: np.ndarray, occupied: np.ndarray, dt_s: float,
              params: FusionParams, *, offset: tuple[int, int] = (0, 0),
              shift: tuple[int, int] = (0, 0), out: np.ndarray | None = None,
              closed: np.ndarray | None = None) -> np.ndarray:
    """Update ``state`` in place with this scan's sensor grid (m({F}), m({O}), window
    order) and return the gate layer (uint8 window order, 1 = ∅_FO may go to {M}).

    ``offset``, ``shift``: as :func:`evperc.fusion.fused.fused_step` (the same values, the state
    shares the fusion state's circular buffer); cells entering the window are reset.
    ``closed``: bool (window order), cells whose gate stays shut whatever their history —
    the cells within ``map.building_margin_m`` of a mapped building (docs/method.md §4a): a
    conflict there is the building's face seen from a new angle, not motion. The state is
    updated as elsewhere."""
    shape = state.ever.shape
    if state.times.shape != (3, *shape) or state.times.dtype != np.float32:
        raise ValueError(f"gate times must be float32 (3, {shape[0]}, {shape[1]})")
    free32 = np.ascontiguousarray(free, np.float32)
    occ32 = np.ascontiguousarray(occupied, np.float32)
    if free32.shape != shape or occ32.shape != shape:
        raise ValueError(f"sensor grid of shape {free32.shape}, the gate state is {shape}")
    if out is None:
        out = np.empty(shape, np.uint8)
    marks = np.empty(shape, np.uint8)
    _gate_pass(state.times, state.ever, int(offset[0]) % shape[0] if shape[0] else 0,
               int(offset[1]) % shape[1] if shape[1] else 0, int(shift[0]), int(shift[1]),
               free32, occ32, np.float32(max(dt_s, 0.0)), np.float32(params.gate_min_free),
               np.float32(params.gate_free_s), np.float32(params.gate_revoke_s),
               np.float32(params.gate_gap_s), np.float32(params.gate_rehit_s), marks, out)
    if closed is not None:
        if closed.shape != shape:
            raise ValueError(f"closed mask of shape {closed.shape}, the gate state is {shape}")
        out[closed] = 0
    return out


@numba.njit(cache=True, nogil=True)
def _gate_pass(times, ever, off_r, off_c, dr, dc, free, occ, dt, min_free, t_free,
               t_revoke, t_gap, t_rehit, marks, gate):  # pragma: no cover - compiled
    """Pass 1: each cell's times (reset where it entered the window) and its marks (bit 0:
    R, free long enough; bit 1: V, revoking); pass 2: the 3 × 3 AND of R and OR of V,
    separably (a row pass into ``gate``, then a column pass), ``ever`` and the gate layer.
    Branch-free inner loops over the two parts of a window row that are contiguous in the
    circular buffer (LLVM vectorises them)."""
    rows, cols = ever.shape
    free_s, occ_s, quiet_s = times[0], times[1], times[2]
    zero, minus = np.float32(0.0), np.float32(-1.0)
    lo = min(max(-dc, 0), cols)  # window columns [lo, hi) were in the previous window
    hi = max(min(cols - dc, cols), lo)
    for r in range(rows):
        br = r + off_r
        br = br - rows if br >= rows else br
        row_lo, row_hi = (lo, hi) if 0 <= r + dr < rows else (0, 0)
        for seg in range(2):
            a0 = 0 if seg == 0 else cols - off_c
            a1 = cols - off_c if seg == 0 else cols
            shift_c = off_c if seg == 0 else off_c - cols
            for c in range(a0, a1):  # entered the window: reset
                if c < row_lo or c >= row_hi:
                    bc = c + shift_c
                    free_s[br, bc] = minus
                    occ_s[br, bc] = zero
                    quiet_s[br, bc] = NEVER
                    ever[br, bc] = 0
            for c in range(a0, a1):
                bc = c + shift_c
                o = occ[r, c] > zero
                fr = free[r, c] >= min_free
                fs = free_s[br, bc]
                qs = quiet_s[br, bc] + dt
                run = (occ_s[br, bc] + qs) if qs <= t_gap + SLACK else zero
                run = run if o else occ_s[br, bc]
                grown = zero if fs < zero else fs + dt
                fs = minus if o else (grown if fr else fs)
                qs = qs if qs < NEVER else NEVER
                occ_s[br, bc] = run
                free_s[br, bc] = fs
                quiet_s[br, bc] = zero if o else qs
                back = (qs > t_gap + SLACK) & (qs <= t_rehit + SLACK)
                marks[r, c] = (np.uint8(2) if (o & ((run >= t_revoke - SLACK) | back))
                               else np.uint8(0)) \
                    | (np.uint8(1) if fs >= t_free - SLACK else np.uint8(0))
    # row pass: bit 0 the AND of R over (c − 1, c, c + 1), bit 1 the OR of V; outside the
    # window R is false
    for r in range(rows):
        for c in range(1, cols - 1):
            a, b, d = marks[r, c - 1], marks[r, c], marks[r, c + 1]
            gate[r, c] = (a & b & d & np.uint8(1)) | ((a | b | d) & np.uint8(2))
        if cols > 1:
            gate[r, 0] = (marks[r, 0] | marks[r, 1]) & np.uint8(2)
            gate[r, cols - 1] = (marks[r, cols - 2] | marks[r, cols - 1]) & np.uint8(2)
        elif cols == 1:
            gate[r, 0] = marks[r, 0] & np.uint8(2)
    # column pass into marks (R and V of the 3 × 3 block), then ever and the gate
    for r in range(rows):
        up = max(r - 1, 0)
        down = min(r + 1, rows - 1)
        inner = np.uint8(1) if (0 < r < rows - 1) else np.uint8(0)
        for c in range(cols):
            a, b, d = gate[up, c], gate[r, c], gate[down, c]
            marks[r, c] = (a & b & d & inner) | ((a | b | d) & np.uint8(2))
    for r in range(rows):
        br = r + off_r
        br = br - rows if br >= rows else br
        for seg in range(2):
            a0 = 0 if seg == 0 else cols - off_c
            a1 = cols - off_c if seg == 0 else cols
            shift_c = off_c if seg == 0 else off_c - cols
            for c in range(a0, a1):
                bc = c + shift_c
                m = marks[r, c]
                e = ever[br, bc]
                e = np.uint8(0) if m & np.uint8(2) else (np.uint8(1) if m & np.uint8(1) else e)
                ever[br, bc] = e
                gate[r, c] = e
