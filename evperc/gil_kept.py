"""The frame loop's small array operations that numpy runs with the GIL released — every sort
and searchsorted, whatever its size, and a comparison or a copy of a window layer — compiled
so that they keep it (shared by the stages that run in the main thread).

The decode thread runs Python (the log's records) most of the time it holds the GIL: each
release costs the main thread a wait for it back, 0.1–2 ms beside a busy thread against 1–20
µs for the operation itself (docs/performance.md § "The GIL's hand-overs";
``python benchmarks/gil_handover.py``).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)  # keeps the GIL
def sorted_copy(values: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """``np.sort(values)`` (a new array)."""
    return np.sort(values)


@numba.njit(cache=True)  # keeps the GIL
def sorted_unique(values: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """``np.unique(values)`` of an int64 array (sorted, duplicates dropped, a new array)."""
    if len(values) == 0:
        return values.copy()
    s = np.sort(values)
    keep = np.ones(len(s), np.bool_)
    for i in range(1, len(s)):
        keep[i] = s[i] != s[i - 1]
    return s[keep]


@numba.njit(cache=True)  # keeps the GIL
def in_sorted(values: np.ndarray, ascending: np.ndarray) -> np.ndarray:  # pragma: no cover
    """Which of ``values`` are in ``ascending`` (sorted): bool per value."""
    out = np.zeros(values.shape[0], np.bool_)
    if ascending.shape[0] == 0:
        return out
    at = np.searchsorted(ascending, values)
    for i in range(values.shape[0]):
        out[i] = at[i] < ascending.shape[0] and ascending[at[i]] == values[i]
    return out


@numba.njit(cache=True)  # keeps the GIL
def copy_layer(layer: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """``layer.copy()`` (C order)."""
    return layer.copy()


@numba.njit(cache=True)  # keeps the GIL
def positive(layer: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """``layer > 0`` (bool, the layer's shape). Not in the frame loop since the clusters'
    occupied cells come from :func:`evperc.objects.stage.scan_cells` (made in the decode
    thread); kept for ``benchmarks/gil_handover.py``, which measures its hand-over."""
    return layer > 0


def warm_up_gil_kept() -> None:
    """Load (or compile) the operations above for the frame loop's argument types."""
    ints = np.arange(3, dtype=np.int64)
    sorted_copy(ints)
    sorted_unique(ints)
    in_sorted(ints, ints)
    copy_layer(np.zeros((2, 2), np.uint8))
