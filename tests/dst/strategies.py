"""Hypothesis strategies: random mass functions as dense (…, 2**n) arrays."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

# Zeros are frequent so that sparse mass functions (a few focal sets) are drawn too.
_WEIGHTS = st.one_of(st.just(0.0), st.just(0.0), st.floats(0.001, 1.0))


@st.composite
def masses(draw, n: int, cells: tuple[int, ...] = (), normal: bool = False,
           dtype: type = np.float64) -> np.ndarray:
    """Mass functions on a frame of ``n`` classes, leading shape ``cells``, summing to 1.

    ``normal`` forces m(∅) = 0; otherwise ∅ may carry mass like any other set.
    """
    w = draw(arrays(np.float64, (*cells, 1 << n), elements=_WEIGHTS))
    if normal:
        w[..., 0] = 0.0
    # an all-zero draw becomes vacuous
    w[..., -1] += w.sum(axis=-1) == 0
    total = w.sum(axis=-1, keepdims=True)
    return (w / total).astype(dtype)


def frame_sizes(lo: int = 2, hi: int = 5) -> st.SearchStrategy[int]:
    return st.integers(lo, hi)


def names(n: int) -> list[str]:
    """Class names of a test frame of n classes, in bit order."""
    return [f"c{k}" for k in range(n)]
