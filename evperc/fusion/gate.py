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
return (a thin object seen through beam gaps; 0 = off), with ``gate_rehit_gap`` "seen_free"
only if x was seen free in that gap (free_s ≥ 0 before this scan's update)]:

    ever(x) ← 0                 if V(y) for some y in the 3 × 3 block around x
    ever(x) ← 1                 elif R(y) for every y in the 3 × 3 block around x
    ever(x) unchanged           otherwise

(neighbours outside the window count as not free and not revoking). The gate layer of the
scan is ``ever`` in window order: 1 where ∅_FO may go to {M}.

With ``gate_rehit_revokes`` "recent_returns" (an option; "block", the rule above, is the
default) a re-hit revokes only the cells of its block that held a return within
``gate_rehit_s`` (quiet_s ≤ gate_rehit_s after this scan, so every cell hit now): a long
occupancy still revokes the whole block. A pole's or a fence's cells around a flickering one
were hit a moment ago and close with it; the pavement ahead of a walker, whose own returns
flicker between two cells, was not, and stays open for the walker's next step.
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
#: the ``closed`` argument of :func:`_gate_pass` when no cell is held shut
_NO_CLOSED = np.zeros((0, 0), np.uint8)


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
    elif out.shape != shape or out.dtype != np.uint8 or not out.flags.c_contiguous:
        raise ValueError(f"out must be C-contiguous uint8 {shape}")
    if not (state.times.flags.c_contiguous and state.ever.flags.c_contiguous):
        raise ValueError("gate state arrays must be C-contiguous")
    if closed is not None and closed.shape != shape:
        raise ValueError(f"closed mask of shape {closed.shape}, the gate state is {shape}")
    shut = (_NO_CLOSED if closed is None
            else np.ascontiguousarray(closed, np.bool_).view(np.uint8))  # 0/1 bytes, no copy
    _gate_pass(state.times, state.ever, int(offset[0]) % shape[0] if shape[0] else 0,
               int(offset[1]) % shape[1] if shape[1] else 0, int(shift[0]), int(shift[1]),
               free32, occ32, np.float32(max(dt_s, 0.0)), np.float32(params.gate_min_free),
               np.float32(params.gate_free_s), np.float32(params.gate_revoke_s),
               np.float32(params.gate_gap_s), np.float32(params.gate_rehit_s),
               params.gate_rehit_gap == "seen_free",
               params.gate_rehit_revokes == "recent_returns", shut, closed is not None, out)
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def _update_run(times, n, b0, w0, count, free, occ, dt, min_free, t_free, t_revoke, t_gap,
                t_rehit, rehit_free, rehit_recent, marks, m0):  # pragma: no cover - compiled
    """Pass 1 of ``count`` cells that are contiguous in the circular buffer (flat buffer
    index ``b0 + k``, window index ``w0 + k``, row mark ``m0 + k``; flat arrays, unsigned
    indices, no views): each cell's times and its marks (bit 0: R, free long enough; bit 1:
    V, revoking its block; with ``rehit_recent`` a re-hit is bit 2 instead, revoking the
    cells of its block that have bit 3: a return within ``t_rehit``). Selects, not
    branches, so that it vectorises."""
    zero, minus = np.float32(0.0), np.float32(-1.0)
    any_gap = not rehit_free
    for k in range(count):
        b = np.uint64(b0 + k)
        w = np.uint64(w0 + k)
        o = occ[w] > zero
        fr = free[w] >= min_free
        fs = times[b]
        free_s_before = fs
        occ_s = times[np.uint64(n) + b]
        qs = times[np.uint64(2 * n) + b] + dt
        run = (occ_s + qs) if qs <= t_gap + SLACK else zero
        run = run if o else occ_s
        grown = zero if fs < zero else fs + dt
        fs = minus if o else (grown if fr else fs)
        qs = qs if qs < NEVER else NEVER
        times[np.uint64(n) + b] = run
        times[b] = fs
        times[np.uint64(2 * n) + b] = zero if o else qs
        back = (qs > t_gap + SLACK) & (qs <= t_rehit + SLACK)  # a re-hit after a gap
        back = back & ((free_s_before >= zero) | any_gap)  # ... seen free in it
        long_run = run >= t_revoke - SLACK
        recent = (zero if o else qs) <= t_rehit + SLACK
        marks[np.uint64(m0 + k)] = (
            (np.uint8(2) if (o & (long_run | (back & (not rehit_recent)))) else np.uint8(0))
            | (np.uint8(4) if (o & back & rehit_recent) else np.uint8(0))
            | (np.uint8(8) if (recent & rehit_recent) else np.uint8(0))
            | (np.uint8(1) if fs >= t_free - SLACK else np.uint8(0)))


@numba.njit(cache=True, nogil=True, inline="always")
def _reset_run(times, ever, n, b0, count):  # pragma: no cover - compiled
    """Cells that entered the window start reset (``count`` cells from flat buffer index
    ``b0``)."""
    for k in range(count):
        b = np.uint64(b0 + k)
        times[b] = np.float32(-1.0)
        times[np.uint64(n) + b] = np.float32(0.0)
        times[np.uint64(2 * n) + b] = NEVER
        ever[b] = 0


@numba.njit(cache=True, nogil=True, inline="always")
def _times_row(times, ever, n, cols, free, occ, r, br, row_lo, row_hi, off_c, dt,
               min_free, t_free, t_revoke, t_gap, t_rehit, rehit_free, rehit_recent, marks
               ):  # pragma: no cover - compiled
    """Pass 1 of window row ``r`` (buffer row ``br``): the cells that entered the window
    (window columns outside [row_lo, row_hi)) reset, then every cell's times and marks
    (:func:`_update_run`) into ``marks`` (one row, window order), over the two parts of
    the row that are contiguous in the circular buffer (window column c is buffer column
    c + off_c, less cols from ``cols - off_c`` on)."""
    for seg in range(2):
        a0 = 0 if seg == 0 else cols - off_c
        a1 = cols - off_c if seg == 0 else cols
        delta = off_c if seg == 0 else off_c - cols
        base = br * cols + delta
        for e0, e1 in ((a0, min(a1, row_lo)), (max(a0, row_hi), a1)):  # entered: reset
            if e0 < e1:
                _reset_run(times, ever, n, base + e0, e1 - e0)
        if a0 < a1:
            _update_run(times, n, base + a0, r * cols + a0, a1 - a0, free, occ, dt, min_free,
                        t_free, t_revoke, t_gap, t_rehit, rehit_free, rehit_recent, marks, a0)


@numba.njit(cache=True, nogil=True, inline="always")
def _row_block(marks, h):  # pragma: no cover - compiled
    """One row of the separable 3 × 3 block: ``h[c]`` bit 0 the AND of R over
    (c − 1, c, c + 1), bits 1 and 2 the OR of the two revocations, bit 3 the cell's own
    recent return; outside the window R is false."""
    cols = marks.shape[0]
    for c in range(1, cols - 1):
        a, b, d = marks[c - 1], marks[c], marks[c + 1]
        h[c] = (a & b & d & np.uint8(1)) | ((a | b | d) & np.uint8(6)) | (b & np.uint8(8))
    if cols > 1:
        h[0] = ((marks[0] | marks[1]) & np.uint8(6)) | (marks[0] & np.uint8(8))
        h[cols - 1] = (((marks[cols - 2] | marks[cols - 1]) & np.uint8(6))
                       | (marks[cols - 1] & np.uint8(8)))
    elif cols == 1:
        h[0] = marks[0] & np.uint8(14)


@numba.njit(cache=True, nogil=True, inline="always")
def _ever_run(ever, b0, ring, u0, m0, d0, c0, inner, gate, w0, shut, has_shut, count
              ):  # pragma: no cover - compiled
    """The column pass of ``count`` cells contiguous in the buffer (the 3 × 3 block's R and
    V from the row results at ``ring[u0 + c]``, ``ring[m0 + c]``, ``ring[d0 + c]``, column
    ``c = c0 + k``; bit 0 only for an ``inner`` row), then ``ever`` (flat buffer index
    ``b0 + k``) and the gate layer (window index ``w0 + k``), 0 where ``shut`` (with
    ``has_shut``)."""
    for k in range(count):
        c = np.uint64(c0 + k)
        a, b, d = ring[np.uint64(u0) + c], ring[np.uint64(m0) + c], ring[np.uint64(d0) + c]
        m = (a & b & d & inner) | ((a | b | d) & np.uint8(6)) | (b & np.uint8(8))
        i = np.uint64(b0 + k)
        e = ever[i]
        # bit 1, or bit 2 with bit 3 (a re-hit in the block, a recent return here)
        revoke = (m | ((m >> np.uint8(1)) & (m >> np.uint8(2)))) & np.uint8(2)
        e = np.uint8(0) if revoke else (np.uint8(1) if m & np.uint8(1) else e)
        ever[i] = e
        w = np.uint64(w0 + k)
        gate[w] = (e & (shut[w] ^ np.uint8(1))) if has_shut else e


@numba.njit(cache=True, nogil=True, inline="always")
def _ever_row(ever, ring, u, m, d, inner, r, br, cols, off_c, shut, has_shut, gate
              ):  # pragma: no cover - compiled
    """Window row ``r`` (buffer row ``br``) of the column pass, its ``ever`` and its gate
    layer (:func:`_ever_run`; outside the window R is false: ``inner`` 0 on the first and
    last rows), 0 where ``shut`` (with ``has_shut``)."""
    for seg in range(2):
        a0 = 0 if seg == 0 else cols - off_c
        a1 = cols - off_c if seg == 0 else cols
        delta = off_c if seg == 0 else off_c - cols
        if a0 < a1:
            _ever_run(ever, br * cols + delta + a0, ring, u * cols, m * cols, d * cols, a0,
                      inner, gate, r * cols + a0, shut, has_shut, a1 - a0)


@numba.njit(cache=True, nogil=True)
def _gate_pass(times, ever, off_r, off_c, dr, dc, free, occ, dt, min_free, t_free,
               t_revoke, t_gap, t_rehit, rehit_free, rehit_recent, shut, has_shut, gate
               ):  # pragma: no cover - compiled
    """One sweep down the window: pass 1 of row r (:func:`_times_row`), its row of the
    separable 3 × 3 block (:func:`_row_block`) into a ring of three row buffers, then the
    column pass, ``ever`` and the gate layer of row r − 1 (:func:`_ever_row`), which needs
    the row results of r − 2, r − 1 and r; the last row after the sweep. Each window row's
    cells are read and written once, on flat arrays with unsigned indices (no array views
    a row: no reference counts, no negative-index fix-ups); the same operations per cell,
    so the same bits. ``shut``: uint8 window order, the cells whose gate layer is 0
    (``has_shut``)."""
    rows, cols = ever.shape
    if rows == 0 or cols == 0:
        return
    n = rows * cols
    flat_times = times.reshape(3 * n)
    flat_ever = ever.reshape(n)
    flat_free = free.reshape(n)
    flat_occ = occ.reshape(n)
    flat_gate = gate.reshape(n)
    flat_shut = shut.reshape(n) if has_shut else shut.reshape(shut.size)
    lo = min(max(-dc, 0), cols)  # window columns [lo, hi) were in the previous window
    hi = max(min(cols - dc, cols), lo)
    marks = np.empty(cols, np.uint8)
    ring = np.empty(3 * cols, np.uint8)
    for r in range(rows):
        br = r + off_r
        br = br - rows if br >= rows else br
        row_lo, row_hi = (lo, hi) if 0 <= r + dr < rows else (0, 0)
        _times_row(flat_times, flat_ever, n, cols, flat_free, flat_occ, r, br, row_lo,
                   row_hi, off_c, dt, min_free, t_free, t_revoke, t_gap, t_rehit, rehit_free,
                   rehit_recent, marks)
        _row_block(marks, ring[(r % 3) * cols:(r % 3 + 1) * cols])
        if r >= 1:  # row r − 1 has both neighbours' row results now
            q = r - 1
            bq = q + off_r
            bq = bq - rows if bq >= rows else bq
            inner = np.uint8(1) if q > 0 else np.uint8(0)  # q < rows − 1 here
            _ever_row(flat_ever, ring, max(q - 1, 0) % 3, q % 3, r % 3, inner, q, bq, cols,
                      off_c, flat_shut, has_shut, flat_gate)
    q = rows - 1  # the last row: below it is outside the window (clamped, as R is masked)
    bq = q + off_r
    bq = bq - rows if bq >= rows else bq
    _ever_row(flat_ever, ring, max(q - 1, 0) % 3, q % 3, q % 3, np.uint8(0), q, bq, cols,
              off_c, flat_shut, has_shut, flat_gate)
