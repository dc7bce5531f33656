"""Small moving groups need company in space and time (docs/method.md §8 step 9,
"Support"; ``objects.small_support_frames``, ``small_support_reach_cells``,
``small_support_min_frames``; ours).

A group of the frame's decided-``moving`` cells too small to be tracked (fewer than
``moving_min_cluster_cells`` cells, :func:`evperc.objects.stage.small_moving_cells`) is
exempt from "moving needs an object": no track can confirm it. It is a pedestrian's one or
two cells — or a pole's, a bollard's: a sparse scanner's beams pass beside a thin obstacle
at 20–50 m for many scans (its cell seen free, its neighbours too, so the motion gate is
open) and hit it in one, an "object appeared" conflict. What tells them apart is what
follows and precedes: a walking person leaves a chain of moving cells — each cell it
enters is a new conflict, and it is tracked once its cluster grows —, a pole hit stays
alone. For frame k, with M_j the *motion cells* of frame j (its small moving groups and
its moving records' cells, global lattice, as they stood when the frame was pushed), a
small group G of frame k keeps its cells ``moving`` only if

    #{ j : 0 < |j − k| ≤ L, ∃ g ∈ G, m ∈ M_j with ‖g − m‖_∞ ≤ ρ } ≥ n

(L = ``small_support_frames``, ρ = ``small_support_reach_cells``, n =
``small_support_min_frames``); else its cells fall to the step-9 rule (``static``). The
frames after k are the backfill's held frames (``objects.backfill_frames``): the rule
reads at most that many of them, so with the backfill off it reads the past only, and the
log's last frames have fewer.

Decision-level only, like the rest of step 9: the masses, betP and ζ are the fusion's."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np

from evperc.objects.backfill import backfill_frames

#: no cell (an empty group list)
_NO_CELLS = np.empty(0, np.int64)


@dataclass(frozen=True)
class SupportParams:
    """``[objects]`` keys of the rule (module docstring)."""

    frames: int = 0          # L; 0 = off
    reach_cells: int = 3     # ρ
    min_frames: int = 3      # n
    ahead: int = 0           # the frames after k it may read: min(L, objects.backfill_frames)

    @property
    def enabled(self) -> bool:
        return self.frames > 0

    @staticmethod
    def from_config(config: dict[str, Any]) -> SupportParams:
        objects = config.get("objects", {})
        frames = int(objects.get("small_support_frames", 0))
        return SupportParams(frames, int(objects.get("small_support_reach_cells", 3)),
                             int(objects.get("small_support_min_frames", 3)),
                             min(frames, backfill_frames(config)))


class SmallGroupSupport:
    """The motion cells of the last frames (module docstring), pushed in frame order, and
    the judgement of a frame's small groups against them, in the same order."""

    def __init__(self) -> None:
        #: (frame number, rows, cols) of the frames that can still support a judgement
        self._motion: deque[tuple[int, np.ndarray, np.ndarray]] = deque()

    def push(self, number: int, row0: int, col0: int, cols: int, motion_cells: np.ndarray
             ) -> None:
        """Record the motion cells of frame ``number`` (flat cells of its window at global
        (row0, col0), ``cols`` wide); frames are pushed in increasing number."""
        flat = np.asarray(motion_cells, np.int64)
        self._motion.append((int(number), flat // cols + row0, flat % cols + col0))

    def copy(self) -> SmallGroupSupport:
        """A copy later pushes and judgements do not change (the arrays are never written)."""
        twin = SmallGroupSupport()
        twin._motion = deque(self._motion)
        return twin

    def to_arrays(self, prefix: str = "support_") -> dict[str, np.ndarray]:
        """Flat arrays for the checkpoint (:meth:`from_arrays` reads them back exactly)."""
        motion = list(self._motion)
        return {f"{prefix}number": np.array([m[0] for m in motion], np.int64),
                f"{prefix}count": np.array([m[1].size for m in motion], np.int64),
                f"{prefix}rows": np.concatenate([m[1] for m in motion] or [_NO_CELLS]),
                f"{prefix}cols": np.concatenate([m[2] for m in motion] or [_NO_CELLS])}

    @staticmethod
    def from_arrays(arrays: Any, prefix: str = "support_") -> SmallGroupSupport | None:
        """The state saved by :meth:`to_arrays`, or None if ``arrays`` holds none."""
        if f"{prefix}number" not in arrays:
            return None
        support = SmallGroupSupport()
        counts = np.array(arrays[f"{prefix}count"], np.int64)
        rows = np.array(arrays[f"{prefix}rows"], np.int64)
        cols = np.array(arrays[f"{prefix}cols"], np.int64)
        for number, end, count in zip(np.array(arrays[f"{prefix}number"], np.int64),
                                      np.cumsum(counts), counts, strict=True):
            support._motion.append((int(number), rows[end - count:end], cols[end - count:end]))
        return support

    def judge(self, params: SupportParams, number: int, row0: int, col0: int, cols: int,
              small_cells: np.ndarray, group_of: np.ndarray) -> np.ndarray:
        """The cells of ``small_cells`` (flat cells of frame ``number``'s window at global
        (row0, col0), ``cols`` wide, in groups: ``group_of[i]`` the group of cell i) whose
        group has the support (module docstring); forgets the frames too old for it (and
        so for the next ones). Frames are judged in increasing number."""
        while self._motion and self._motion[0][0] < number - params.frames:
            self._motion.popleft()
        small = np.asarray(small_cells, np.int64)
        if small.size == 0:
            return small
        near = [(r, c) for j, r, c in self._motion
                if j != number and -params.frames <= j - number <= params.ahead]
        if not near:
            return small[:0]
        keep = _supported(small // cols + row0, small % cols + col0,
                          np.asarray(group_of, np.int64), np.concatenate([r for r, _ in near]),
                          np.concatenate([c for _, c in near]),
                          np.array([r.size for r, _ in near], np.int64), params.reach_cells,
                          params.min_frames)
        return small[keep]


@numba.njit(cache=True)  # keeps the GIL: a short pass over a few cells
def _supported(rows, cols, groups, near_rows, near_cols, counts, reach, need
               ):  # pragma: no cover - compiled
    """Whether each cell (``rows[i]``, ``cols[i]``) is in a supported group (``groups[i]``):
    one whose cells have, in at least ``need`` frames (the runs of ``counts`` cells of
    ``near_rows`` / ``near_cols``), a cell within Chebyshev ``reach`` of one of them."""
    n = rows.shape[0]
    frames = counts.shape[0]
    hit = np.zeros((groups.max() + 1, frames), np.bool_)  # group × frame: a cell within reach
    for i in range(n):
        start = 0
        for f in range(frames):
            if not hit[groups[i], f]:
                for k in range(start, start + counts[f]):
                    if (abs(near_rows[k] - rows[i]) <= reach
                            and abs(near_cols[k] - cols[i]) <= reach):
                        hit[groups[i], f] = True
                        break
            start += counts[f]
    keep = np.empty(n, np.bool_)
    for i in range(n):
        keep[i] = hit[groups[i]].sum() >= need
    return keep


def warm_up() -> None:
    """Load the compiled pass (from numba's cache), before the first frame."""
    one = np.zeros(1, np.int64)
    _supported(one, one, one, one, one, one, 1, 1)
