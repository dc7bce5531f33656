"""Unmapped infrastructure from the decision grid: thin static things off the road
(docs/method.md, "Objects", "Unmapped infrastructure").

The evidence cannot separate U from S: the map prior gives road cells {F, S, M} and other
cells {F, U, S, M}, so an occupied cell off the road ends as {U, S} or {U, S, M} and is
decided ``static`` or ``stopped``, never ``unmapped``. This pass uses what a cell's masses
do not hold — the shape of the static thing the cell belongs to, and whether it ever
moved — and relabels the decision, after the object stage.

Per frame, with ``dt`` the time since the previous frame:

1. Per-cell state (circular buffers like the fusion state's, the same offset and shift;
   cells entering the window start reset):

   - ``age_s``: the time the cell has been decided occupied (``moving``, ``static``,
     ``stopped``, ``unmapped``) since it was last decided ``free``: 0 at the first such
     frame, + dt at each next one; a frame decided ``unknown`` or ``infrastructure``
     neither adds nor resets; −1 after ``free`` (and at the start).
   - ``moved``: set once the cell is *seen moving* — in a moving object of the frame's
     object list (``moving_cells``; with the object list off, decided ``moving``) — and
     kept while the cell stays in the window.

2. Components: the 8-connected components of the cells decided ``static``, ``stopped`` or
   ``unmapped`` this frame, whatever their map context (a parked car that crosses the
   road's edge is one component). Its *length* is the extent of its cells' centres, plus
   one cell, at right angles to the direction (of :data:`ANGLES`, every 180° / 16) in
   which that extent is least; its *width* is its area over its length: the shorter side
   of a filled rectangle, a cell or less for a one-cell-thick line at any angle (a fence),
   one cell for a lone cell (a pole).
3. A component is *unmapped-like* if its width is at most ``max_width_m``, none of its
   cells is on the road (map context road), none is in or 8-next to a building cell (the
   returns of a façade that fall just outside the mapped outline), and none was ever seen
   moving. Its cells of context other whose ``age_s`` is at least ``min_age_s`` become
   ``unmapped``.

4. ``stopped`` needs the road or motion (``stopped_needs_road``, the same components): a
   component with no cell on the road and none ever seen moving keeps no cell ``stopped``:
   its ``stopped`` cells (those left after step 3) become ``static``. Off the road the prior
   allows U and S alike ({F, U, S, M}), and what tips such a cell to S is not the map but
   the fusion's moving mass: a cell seen free fades through {F, M} (α_M), an occupied return
   there intersects it to {M} (no conflict, so the motion gate does not see it), and ζ then
   moves that {M} to {S}. On the simulated tuning drives that is a façade's returns just
   outside the building's outline (94 % of the off-road cells decided ``stopped``, truth
   free, 8-next to a building cell); a parked car at the kerb has cells on the road and
   stays ``stopped``, a car that drove off the road and stopped was seen moving.

5. A façade is not ``stopped`` (``stopped_off_facades``, the same components): a component
   as thin as furniture (width at most ``max_width_m``), in or 8-next to a building cell
   and never seen moving keeps no cell ``stopped``: they become ``static``. It is the
   returns of a mapped building's face that fall in the cells just outside its outline,
   on the road's side (road prior {F, S, M}: occupied there is {S, M}, and ζ makes it S);
   a car parked against the wall makes the component wider than a strip, and keeps it.

Without a map the pass changes nothing (the state is still kept): the road's edge is what
tells a kerb-side car's face — a strip one cell thick, as thin as a fence — from the
pavement's furniture, and without it every thin static strip would be called unmapped.

One compiled pass (numba): the state update over the window, then a flood fill from every
candidate cell not yet in a component, touching only the components' cells and their
neighbours; the scratch marks are cleared cell by cell afterwards."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np

from evperc.fusion.twin import DECISION_CODES
from evperc.geo.prior import CONTEXT_BUILDING, CONTEXT_OTHER, CONTEXT_ROAD
from evperc.objects.clusters import BYTE_ONES, zero_bytes

#: orientations of the shape test (every 180° / ANGLES; even, so that each has its normal)
ANGLES = 16
#: ``age_s`` of a cell not decided occupied since it was last free
NOT_OCCUPIED = np.float32(-1.0)
#: seconds of slack on the age comparison (scan intervals jitter by a few ms)
SLACK = np.float32(1e-3)
#: columns of :attr:`UnmappedCue.stats`
STAT_CELLS, STAT_ROAD, STAT_NEAR_BUILDING, STAT_MOVED, STAT_WIDTH_M, STAT_LENGTH_M, \
    STAT_RELABELLED, STAT_UNSTOPPED = range(8)

_FREE = DECISION_CODES["free"]
_MOVING = DECISION_CODES["moving"]
_STATIC = DECISION_CODES["static"]
_STOPPED = DECISION_CODES["stopped"]
_UNMAPPED = DECISION_CODES["unmapped"]
#: a word of 8 bytes each the code (zero-byte tests: :func:`zero_bytes`)
_STATIC_BYTES = np.uint64(_STATIC) * BYTE_ONES
_STOPPED_BYTES = np.uint64(_STOPPED) * BYTE_ONES
_UNMAPPED_BYTES = np.uint64(_UNMAPPED) * BYTE_ONES
#: the bits of a word's bytes above code 1: zero iff its 8 cells are decided unknown (0) or
#: free (1), the codes of most of the window
_ABOVE_FREE = np.uint64(0xFEFEFEFEFEFEFEFE)


def unmapped_enabled(config: dict[str, Any]) -> bool:
    """Whether a run with ``config`` runs the pass: the unmapped cue or the stopped-needs-road
    rule on (a config written before the keys existed, e.g. an old run's manifest on
    resume: no)."""
    o = config.get("objects", {})
    return (bool(o.get("unmapped_cue", False)) or bool(o.get("stopped_needs_road", False))
            or bool(o.get("stopped_off_facades", False)))


@dataclass(frozen=True)
class UnmappedParams:
    """The ``[objects]`` keys of the unmapped cue (configs/default.toml)."""

    #: objects.unmapped_max_width_m: the widest component (area / length) that may be
    #: furniture. The simulator's poles (0.24 m), trunks (0.6 m), bollards (0.2 m) and
    #: fences (0.1 m × 4-12 m) are one cell across at 0.5 m (a line: ≤ 0.5 m at any angle);
    #: a parked car is 1.7-2.0 m wide; an L of three cells is 0.62 m, a 2 × 2 block 1.0 m
    max_width_m: float = 0.55
    #: objects.unmapped_min_age_s: a cell is relabelled once decided occupied this long
    #: (0.1 s: in two decisions at 10 Hz)
    min_age_s: float = 0.1
    #: objects.unmapped_cue: relabel the unmapped-like components (steps 1-3)
    unmapped: bool = True
    #: objects.stopped_needs_road: step 4 (off here, the fusion's decision; on in
    #: configs/default.toml)
    stopped_needs_road: bool = False
    #: objects.stopped_off_facades: step 5 (off here; on in configs/default.toml)
    stopped_off_facades: bool = False

    @staticmethod
    def from_config(config: dict[str, Any]) -> UnmappedParams:
        o = config["objects"]
        return UnmappedParams(max_width_m=float(o["unmapped_max_width_m"]),
                              min_age_s=float(o["unmapped_min_age_s"]),
                              unmapped=bool(o.get("unmapped_cue", False)),
                              stopped_needs_road=bool(o.get("stopped_needs_road", False)),
                              stopped_off_facades=bool(o.get("stopped_off_facades", False)))


@dataclass
class UnmappedState:
    """The pass's per-cell state, circular buffers of the fusion state's shape (module
    docstring): ``age_s`` float32 and ``moved`` uint8, ``(rows, cols)``."""

    age_s: np.ndarray
    moved: np.ndarray

    @staticmethod
    def fresh(shape: tuple[int, int]) -> UnmappedState:
        return UnmappedState(np.full(shape, NOT_OCCUPIED, np.float32), np.zeros(shape, np.uint8))

    def copy(self) -> UnmappedState:
        return UnmappedState(self.age_s.copy(), self.moved.copy())

    def to_arrays(self, prefix: str = "unmapped_") -> dict[str, np.ndarray]:
        """The arrays of the checkpoint (:meth:`from_arrays` reads them back exactly)."""
        return {f"{prefix}age_s": self.age_s, f"{prefix}moved": self.moved}

    @staticmethod
    def from_arrays(arrays: Any, prefix: str = "unmapped_") -> UnmappedState | None:
        """The state saved by :meth:`to_arrays`, or None if ``arrays`` holds none."""
        if f"{prefix}age_s" not in arrays:
            return None
        return UnmappedState(np.array(arrays[f"{prefix}age_s"], np.float32),
                             np.array(arrays[f"{prefix}moved"], np.uint8))


class UnmappedCue:
    """Scratch buffers for :meth:`step` over windows of one shape."""

    def __init__(self, params: UnmappedParams, shape: tuple[int, int], resolution_m: float
                 ) -> None:
        self.params = params
        self.shape = shape
        self.resolution_m = float(resolution_m)
        n = shape[0] * shape[1]
        self._mark = np.zeros(n, np.uint8)
        self._cells = np.empty(n, np.int64)
        self._stats = np.empty((n, 8), np.float64)
        theta = np.arange(ANGLES) * (math.pi / ANGLES)
        self._cos = np.cos(theta)
        self._sin = np.sin(theta)
        self._no_labels = np.zeros((0, 0), np.uint8)
        self._no_cells = np.zeros(0, np.int64)
        self.components = 0  # components of the last step (``stats[:components]``)

    def step(self, state: UnmappedState, decision: np.ndarray, labels: np.ndarray | None,
             dt_s: float, *, moving_cells: np.ndarray | None = None,
             offset: tuple[int, int] = (0, 0), shift: tuple[int, int] = (0, 0)) -> int:
        """Update ``state`` with the frame's ``decision`` (uint8 codes, window order,
        :data:`evperc.fusion.twin.DECISION_CODES`) and relabel its unmapped-like cells
        ``unmapped`` in place (module docstring), and, with ``stopped_needs_road``, the
        ``stopped`` cells of off-road components never seen moving ``static`` (with
        ``stopped_off_facades``, those of a façade's strip too); returns the
        number of cells relabelled ``unmapped`` (:attr:`stats` counts both per component).

        ``labels``: the window's map context (:mod:`evperc.geo.prior`), None without a map
        (nothing is relabelled). ``moving_cells``: flat window indices of the cells seen
        moving this frame (:func:`evperc.output.objects.moving_object_cells`); None: the
        cells decided ``moving``. ``offset``, ``shift``: as
        :func:`evperc.fusion.fused.fused_step` (the state shares the fusion state's circular
        buffer)."""
        rows, cols = self.shape
        if decision.shape != self.shape or state.age_s.shape != self.shape:
            raise ValueError(f"decision {decision.shape} / state {state.age_s.shape}, the "
                             f"cue's window is {self.shape}")
        if decision.dtype != np.uint8 or not decision.flags.c_contiguous:
            raise ValueError("decision must be C-contiguous uint8 (it is relabelled in place)")
        has_labels = labels is not None
        if has_labels and labels.shape != self.shape:
            raise ValueError(f"labels {labels.shape}, the cue's window is {self.shape}")
        # seen moving: the listed cells (set in ``moved`` after the update), else the cells
        # decided moving (read in the update); no window-sized layer of them
        from_decision = moving_cells is None
        seen = self._no_cells if from_decision else np.ascontiguousarray(moving_cells,
                                                                         np.int64).reshape(-1)
        p = self.params
        res = self.resolution_m
        flat = decision.reshape(-1)
        n, relabelled = _unmapped_pass(
            decision, labels if has_labels else self._no_labels, has_labels, from_decision,
            seen, state.age_s, state.moved, int(offset[0]) % rows if rows else 0,
            int(offset[1]) % cols if cols else 0, int(shift[0]), int(shift[1]),
            np.float32(max(dt_s, 0.0)), p.max_width_m / res, np.float32(p.min_age_s),
            p.unmapped, p.stopped_needs_road, p.stopped_off_facades, self._cos, self._sin,
            self._mark, self._cells,
            self._stats, flat[:flat.size - flat.size % 8].view(np.uint64), res)
        if n < 0:  # checked before any state was changed
            raise ValueError(f"moving_cells outside the {rows} x {cols} window")
        self.components = n
        return relabelled

    @property
    def stats(self) -> np.ndarray:
        """``(components, 8)`` float64 of the last step, one row a component in the order
        found (row-major scan; columns ``STAT_*``): cells, road cells, in or next to a
        building (0/1), seen moving (0/1), width and length (m), cells relabelled
        ``unmapped``, cells turned from ``stopped`` to ``static`` (steps 4 and 5)."""
        return self._stats[:self.components]


@numba.njit(cache=True, nogil=True, inline="always")
def _update_kept(dec, from_decision, age, moved, dt):  # pragma: no cover - compiled
    """The per-cell state update (module docstring, 1.) of a run of cells that were in the
    previous window (1-d views of one row: window order for ``dec``, buffer order for
    ``age`` and ``moved``); with ``from_decision``, the cells decided moving are seen moving
    (else :func:`_unmapped_pass` sets the listed ones after the update). Selects, not
    branches, so that it vectorises."""
    for k in range(dec.shape[0]):
        a = age[k]
        d = dec[k]
        occ = (d == _MOVING) | (d == _STATIC) | (d == _STOPPED) | (d == _UNMAPPED)
        grown = np.float32(0.0) if a < 0 else a + dt
        age[k] = grown if occ else (NOT_OCCUPIED if d == _FREE else a)
    if from_decision:  # else ``moved`` is left as it is here (neither read nor written)
        for k in range(dec.shape[0]):
            moved[k] = np.uint8(1) if dec[k] == _MOVING else moved[k]


@numba.njit(cache=True, nogil=True, inline="always")
def _update_entered(dec, from_decision, age, moved):  # pragma: no cover - compiled
    """:func:`_update_kept` of cells that entered the window (their state starts reset:
    ``age_s`` −1, so 0 if occupied now, else −1; ``moved`` 0)."""
    for k in range(dec.shape[0]):
        d = dec[k]
        occ = (d == _MOVING) | (d == _STATIC) | (d == _STOPPED) | (d == _UNMAPPED)
        age[k] = np.float32(0.0) if occ else NOT_OCCUPIED
        moved[k] = np.uint8(1) if (from_decision and d == _MOVING) else np.uint8(0)


@numba.njit(cache=True, nogil=True, inline="always")
def _update_columns(decision, from_decision, age_s, moved, r, br, c0, c1, off_c, kept, dt
                    ):  # pragma: no cover - compiled
    """The state update of window columns [c0, c1) of window row ``r`` (buffer row
    ``br``): split where the circular buffer wraps (window column c is buffer column
    c + off_c, less cols from ``cols - off_c`` on)."""
    cols = decision.shape[1]
    wrap = cols - off_c
    for a0, a1, delta in ((c0, min(c1, wrap), off_c), (max(c0, wrap), c1, off_c - cols)):
        if a0 >= a1:
            continue
        dec = decision[r, a0:a1]
        age = age_s[br, a0 + delta:a1 + delta]
        mv = moved[br, a0 + delta:a1 + delta]
        if kept:
            _update_kept(dec, from_decision, age, mv, dt)
        else:
            _update_entered(dec, from_decision, age, mv)


@numba.njit(cache=True)  # keeps the GIL: a short pass (docs/performance.md, "GIL")
def _unmapped_pass(decision, labels, has_labels, from_decision, seen_cells, age_s, moved,
                   off_r, off_c, dr, dc, dt, max_width, min_age, relabel_unmapped,
                   stopped_needs_road, off_facades, cos, sin, mark, cells, stats, dec_words,
                   res
                   ):  # pragma: no cover - compiled
    """The state update, then the components (module docstring). ``max_width`` in cells.
    Seen moving: with ``from_decision`` the cells decided moving, else the flat window
    cells ``seen_cells`` (their ``moved`` set after the update, which resets it where a
    cell entered the window). Returns (−1, 0), changing nothing, if a seen cell is outside
    the window. The stats' width and length are stored in metres (× ``res``).
    ``dec_words``: the first cells of ``decision`` as uint64 words (8 cells each; the
    scan for components skips the words without a cell decided static, stopped or
    unmapped). Returns (components, cells relabelled)."""
    rows, cols = decision.shape
    for q in range(seen_cells.shape[0]):
        if seen_cells[q] < 0 or seen_cells[q] >= rows * cols:
            return -1, 0
    lo = min(max(-dc, 0), cols)  # window columns [lo, hi) were in the previous window
    hi = max(min(cols - dc, cols), lo)
    for r in range(rows):
        br = r + off_r
        br = br - rows if br >= rows else br
        row_lo, row_hi = (lo, hi) if 0 <= r + dr < rows else (0, 0)
        if row_lo > 0:
            _update_columns(decision, from_decision, age_s, moved, r, br, 0, row_lo, off_c,
                            False, dt)
        if row_hi > row_lo:
            _update_columns(decision, from_decision, age_s, moved, r, br, row_lo, row_hi,
                            off_c, True, dt)
        if cols > row_hi:
            _update_columns(decision, from_decision, age_s, moved, r, br, max(row_hi, row_lo),
                            cols, off_c, False, dt)
    for q in range(seen_cells.shape[0]):
        i = seen_cells[q]
        r = i // cols
        br = r + off_r
        br = br - rows if br >= rows else br
        bc = i - r * cols + off_c
        bc = bc - cols if bc >= cols else bc
        moved[br, bc] = 1
    flat = decision.reshape(-1)
    n_comp = 0
    n_cells = 0
    relabelled = 0
    n_angles = cos.shape[0]
    lo_p = np.empty(n_angles)
    hi_p = np.empty(n_angles)
    n_words = dec_words.shape[0]
    total = rows * cols
    w = 0
    while w <= n_words:
        if w < n_words:  # 8 cells at once: the words without a candidate are skipped
            while w < n_words:
                x = dec_words[w]
                if x & _ABOVE_FREE == 0:  # unknown and free cells only (most words)
                    w += 1
                    continue
                a = x ^ _STATIC_BYTES  # a zero byte where decided static, ...
                b = x ^ _STOPPED_BYTES
                e = x ^ _UNMAPPED_BYTES
                hit = zero_bytes(a) | zero_bytes(b) | zero_bytes(e)
                if hit != 0:
                    break
                w += 1
            if w == n_words:
                continue
            at = 8 * w
            stop = at + 8
            w += 1
        else:  # the cells after the last whole word
            at = 8 * n_words
            stop = total
            w += 1
        for start in range(at, stop):
            if mark[start]:
                continue
            d0 = flat[start]
            if not (d0 == _STATIC or d0 == _STOPPED or d0 == _UNMAPPED):
                continue
            mark[start] = 1
            first = n_cells
            cells[n_cells] = start
            n_cells += 1
            head = first
            road = 0
            near_building = False
            any_moved = False
            for k in range(n_angles):
                lo_p[k] = np.inf
                hi_p[k] = -np.inf
            while head < n_cells:  # the component's cells double as the queue (breadth first)
                i = cells[head]
                head += 1
                r = i // cols
                c = i - r * cols
                br = r + off_r
                br = br - rows if br >= rows else br
                bc = c + off_c
                bc = bc - cols if bc >= cols else bc
                if moved[br, bc]:
                    any_moved = True
                for k in range(n_angles):
                    p = c * cos[k] + r * sin[k]
                    lo_p[k] = min(lo_p[k], p)
                    hi_p[k] = max(hi_p[k], p)
                for ddr in range(-1, 2):
                    rr = r + ddr
                    if rr < 0 or rr >= rows:
                        continue
                    for ddc in range(-1, 2):
                        cc = c + ddc
                        if cc < 0 or cc >= cols:
                            continue
                        if has_labels:
                            lab = labels[rr, cc]
                            if lab == CONTEXT_BUILDING:
                                near_building = True
                            elif ddr == 0 and ddc == 0 and lab == CONTEXT_ROAD:
                                road += 1
                        j = rr * cols + cc
                        if mark[j]:
                            continue
                        dj = flat[j]
                        if dj == _STATIC or dj == _STOPPED or dj == _UNMAPPED:
                            mark[j] = 1
                            cells[n_cells] = j
                            n_cells += 1
            count = n_cells - first
            thinnest = 0
            for k in range(1, n_angles):
                if hi_p[k] - lo_p[k] < hi_p[thinnest] - lo_p[thinnest] - 1e-9:
                    thinnest = k
            along = (thinnest + n_angles // 2) % n_angles
            length = hi_p[along] - lo_p[along] + 1.0
            width = count / length
            eligible = (relabel_unmapped and has_labels and width <= max_width + 1e-9
                        and road == 0 and not near_building and not any_moved)
            changed = 0
            if eligible:
                for q in range(first, n_cells):
                    i = cells[q]
                    r = i // cols
                    c = i - r * cols
                    if labels[r, c] != CONTEXT_OTHER:
                        continue
                    br = r + off_r
                    br = br - rows if br >= rows else br
                    bc = c + off_c
                    bc = bc - cols if bc >= cols else bc
                    if age_s[br, bc] >= min_age - SLACK:
                        flat[i] = _UNMAPPED
                        changed += 1
            stats[n_comp, 0] = count
            stats[n_comp, 1] = road
            stats[n_comp, 2] = 1.0 if near_building else 0.0
            stats[n_comp, 3] = 1.0 if any_moved else 0.0
            stats[n_comp, 4] = width * res
            stats[n_comp, 5] = length * res
            unstopped = 0
            facade = (off_facades and has_labels and near_building and not any_moved
                      and width <= max_width + 1e-9)
            if (stopped_needs_road and has_labels and road == 0 and not any_moved) or facade:
                for q in range(first, n_cells):  # steps 4 and 5: what step 3 left stopped
                    i = cells[q]
                    if flat[i] == _STOPPED:
                        flat[i] = _STATIC
                        unstopped += 1
            stats[n_comp, 6] = changed
            stats[n_comp, 7] = unstopped
            relabelled += changed
            n_comp += 1
    for q in range(n_cells):
        mark[cells[q]] = 0
    return n_comp, relabelled
