"""Paper Table 1 (Kurdej et al. 2013) with the corrections of method.md §2.

m1 = {a: .2, b: .6, Ω: .2}, m2 = {a: .7, b: .1, Ω: .2} on Ω = {a, b}; vectors are
(∅, a, b, Ω). Each value below is worked by hand in the test's comment.
"""

from __future__ import annotations

import numpy as np
import pytest

from evperc.dst import Frame, conjunctive, dempster, discount, disjunctive, pignistic

AB = Frame(("a", "b"))
M1 = AB.vector({"a": 0.2, "b": 0.6, ("a", "b"): 0.2})
M2 = AB.vector({"a": 0.7, "b": 0.1, ("a", "b"): 0.2})
KERNELS = ["butterfly", "matrix"]


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_conjunctive_row(kernel: str, dtype: type) -> None:
    # ∅: .2·.1 + .6·.7 = .44; a: .2·.7 + .2·.2 + .2·.7 = .32; b: .6·.1 + .6·.2 + .2·.1 = .20
    got = conjunctive(M1.astype(dtype), M2.astype(dtype), kernel=kernel)
    assert got.dtype == dtype
    np.testing.assert_allclose(got, [0.44, 0.32, 0.20, 0.04], atol=1e-6 if dtype == np.float32
                               else 1e-12)


@pytest.mark.parametrize("kernel", KERNELS)
def test_dempster_row(kernel: str) -> None:
    m, k = dempster(M1, M2, kernel=kernel)
    assert k == pytest.approx(0.44, abs=1e-12)
    np.testing.assert_allclose(m, [0.0, 4 / 7, 5 / 14, 1 / 14], atol=1e-12)


def test_disjunctive_row() -> None:
    # a: .2·.7, b: .6·.1, Ω: the rest
    np.testing.assert_allclose(disjunctive(M1, M2), [0.0, 0.14, 0.06, 0.80], atol=1e-12)


def test_discount_row() -> None:
    np.testing.assert_allclose(discount(M1, 0.1), [0.0, 0.18, 0.54, 0.28], atol=1e-12)


def test_pignistic_row() -> None:
    np.testing.assert_allclose(pignistic(M1), [0.3, 0.7], atol=1e-12)


def test_not_the_misprinted_values() -> None:
    """The paper prints ∩ as (.44, .34, .18, .04) and ⊕ as (.61, .32, .07): misprints."""
    conj = conjunctive(M1, M2)
    assert abs(conj[1] - 0.34) > 0.01 and abs(conj[2] - 0.18) > 0.01
    m, _ = dempster(M1, M2)
    assert np.abs(m[1:] - [0.61, 0.32, 0.07]).max() > 0.01
