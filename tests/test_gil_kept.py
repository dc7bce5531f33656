"""The frame loop's GIL-keeping array operations (evperc.gil_kept): each equal to the numpy
operation it replaces (numpy the oracle, on random arrays), and compiled without ``nogil``
(keeping the GIL is their reason to exist: docs/performance.md § "The GIL's hand-overs")."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from evperc import gil_kept
from evperc.gil_kept import copy_layer, in_sorted, positive, sorted_copy, sorted_unique

ints = arrays(np.int64, st.integers(0, 60), elements=st.integers(-50, 50))


@settings(max_examples=200, deadline=None)
@given(ints, ints)
def test_in_sorted_is_numpy_isin(values: np.ndarray, pool: np.ndarray) -> None:
    ascending = np.sort(pool)
    assert np.array_equal(in_sorted(values, ascending), np.isin(values, pool))


@settings(max_examples=200, deadline=None)
@given(ints)
def test_sorted_copy_and_sorted_unique_are_numpy_sort_and_unique(values: np.ndarray) -> None:
    before = values.copy()
    assert np.array_equal(sorted_copy(values), np.sort(values))
    unique = sorted_unique(values)
    assert unique.dtype == np.int64 and np.array_equal(unique, np.unique(values))
    assert np.array_equal(values, before)  # new arrays, the input untouched


@settings(max_examples=50, deadline=None)
@given(arrays(np.float32, st.tuples(st.integers(1, 9), st.integers(1, 9)),
              elements=st.floats(-1, 1, width=32)))
def test_positive_and_copy_layer_are_numpy_compare_and_copy(layer: np.ndarray) -> None:
    assert np.array_equal(positive(layer), layer > 0) and positive(layer).dtype == np.bool_
    codes = (layer * 100).astype(np.uint8)
    copied = copy_layer(codes)
    assert np.array_equal(copied, codes) and not np.shares_memory(copied, codes)


@pytest.mark.parametrize("name", ["sorted_copy", "sorted_unique", "in_sorted", "copy_layer",
                                  "positive"])
def test_they_keep_the_gil(name: str) -> None:
    assert not getattr(gil_kept, name).targetoptions.get("nogil", False)
