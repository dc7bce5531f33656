"""betP of stored masses (format_version 4 derives it on reading): the compiled pass over the
uint8 planes against evperc.dst.pignistic on the dequantised masses, the tested reference."""

from __future__ import annotations

import numpy as np
import pytest

from evperc.dst.pignistic import pignistic
from evperc.output.quantise import dequantise_planar, pignistic_of_planes


def random_planes(rng: np.random.Generator, rows: int, cols: int) -> np.ndarray:
    """Stored masses of random cells: a few focal sets each, rounded to ×255 steps (their
    sum then differs from 255 by a few steps, as stored masses do)."""
    masses = np.zeros((rows, cols, 32))
    for r in range(rows):
        for c in range(cols):
            sets = rng.choice(32, size=int(rng.integers(1, 9)), replace=False)
            masses[r, c, sets] = rng.dirichlet(np.ones(len(sets)))
    return np.round(np.moveaxis(masses, -1, 0) * 255).astype(np.uint8)


def test_matches_the_reference_on_random_masses() -> None:
    rng = np.random.default_rng(5)
    planes = random_planes(rng, 17, 23)
    planes[:, 0, 0] = 0          # nothing stored: no belief at all
    planes[:, 0, 1] = 0
    planes[0, 0, 1] = 255        # all on the empty set (m(∅) = 1)
    planes[:, 0, 2] = 0
    planes[31, 0, 2] = 255       # vacuous: 0.2 each
    got = pignistic_of_planes(planes)
    want = pignistic(dequantise_planar(planes).astype(np.float64))
    assert got.shape == (17, 23, 5) and got.dtype == np.float32
    # float32 sums of at most 31 terms of ≤ 255 against float64: a few ulps of 1
    np.testing.assert_allclose(got, want, atol=1e-6)
    np.testing.assert_array_equal(got[0, 0], 0.0)
    np.testing.assert_array_equal(got[0, 1], 0.0)
    np.testing.assert_allclose(got[0, 2], 0.2, atol=1e-7)
    ok = planes[1:].sum(axis=0) > 0
    np.testing.assert_allclose(got.sum(axis=-1)[ok], 1.0, atol=1e-6)


def test_worked_by_hand() -> None:
    """m({F}) = 0.4, m({S, M}) = 0.4, m(Ω) = 0.2 (×255: 102, 102, 51): betP = (0.44, 0.04,
    0.04, 0.24, 0.24)."""
    planes = np.zeros((32, 1, 1), np.uint8)
    planes[0b00001, 0, 0] = 102
    planes[0b11000, 0, 0] = 102
    planes[0b11111, 0, 0] = 51
    np.testing.assert_allclose(pignistic_of_planes(planes)[0, 0],
                               [0.44, 0.04, 0.04, 0.24, 0.24], atol=1e-6)


def test_the_planes_must_be_32() -> None:
    with pytest.raises(ValueError, match=r"\(32, rows, cols\)"):
        pignistic_of_planes(np.zeros((5, 2, 2), np.uint8))
