"""Every worked example of tests/data/dst-vectors.md (numbered as there)."""

from __future__ import annotations

import numpy as np
import pytest

from evperc.dst import (
    Frame,
    belief,
    conjunctive,
    contextual_discount,
    dempster,
    discount,
    disjunctive,
    mass_to_commonality,
    pignistic,
    plausibility,
    yager,
)

ABCD = Frame(("a", "b", "c", "d"))
ABC = Frame(("a", "b", "c"))
AHR = Frame(("a", "h", "r"))
C12 = Frame(("C1", "C2"))


def sets(frame: Frame, spec: dict[str, float]) -> np.ndarray:
    """{"ad": .1, "": .4} → dense vector, each letter one class of a one-letter frame."""
    return frame.vector({tuple(k): v for k, v in spec.items()})


# Example 1
E1_M1 = sets(ABCD, {"a": 0.4, "b": 0.2, "ad": 0.1, "abcd": 0.3})
E1_M2 = sets(ABCD, {"b": 0.5, "c": 0.2, "ac": 0.3})


def test_1_dempster() -> None:
    m, k = dempster(E1_M1, E1_M2)
    assert k == pytest.approx(0.45, abs=1e-12)
    want = sets(ABCD, {"a": 0.15 / 0.55, "b": 0.25 / 0.55, "c": 0.06 / 0.55, "ac": 0.09 / 0.55})
    np.testing.assert_allclose(m, want, atol=1e-12)


def test_1_disjunctive() -> None:
    want = sets(ABCD, {"ab": 0.2, "ac": 0.2, "b": 0.1, "bc": 0.04, "abc": 0.06, "abd": 0.05,
                       "acd": 0.05, "abcd": 0.3})
    np.testing.assert_allclose(disjunctive(E1_M1, E1_M2), want, atol=1e-12)


def test_1_pignistic() -> None:
    np.testing.assert_allclose(pignistic(E1_M1), [0.525, 0.275, 0.075, 0.125], atol=1e-12)


def test_1_bel_pl_q_at_a() -> None:
    a = ABCD.mask("a")
    assert belief(E1_M1)[a] == pytest.approx(0.4)
    assert plausibility(E1_M1)[a] == pytest.approx(0.8)
    assert mass_to_commonality(E1_M1)[a] == pytest.approx(0.8)


# Example 2: mass on the empty set (unnormalised conventions)
def test_2_empty_set_conventions() -> None:
    m3 = sets(ABC, {"": 0.4, "c": 0.2, "ac": 0.3, "ab": 0.1})
    assert belief(m3)[ABC.mask(tuple("abc"))] == pytest.approx(0.6)
    assert plausibility(m3)[ABC.mask("b")] == pytest.approx(0.1)
    assert mass_to_commonality(m3)[0] == pytest.approx(1.0)
    assert belief(m3)[0] == 0.0 and plausibility(m3)[0] == 0.0


# Example 3: two-class frame, vectors (∅, C1, C2, Ω)
E3 = [np.array(v) for v in ([0, 0.3, 0.7, 0], [0, 0.5, 0.4, 0.1], [0.1, 0.2, 0.7, 0])]


@pytest.mark.parametrize("kernel", ["butterfly", "matrix"])
def test_3_conjunctive(kernel: str) -> None:
    m1, m2, m3 = E3
    c12 = conjunctive(m1, m2, kernel=kernel)
    np.testing.assert_allclose(c12, [0.47, 0.18, 0.35, 0], atol=1e-12)
    np.testing.assert_allclose(conjunctive(c12, m3, kernel=kernel), [0.719, 0.036, 0.245, 0],
                               atol=1e-12)


def test_3_dempster_disjunctive_discount() -> None:
    m1, m2, m3 = E3
    m, k = dempster(m1, m2)
    np.testing.assert_allclose(m, [0, 0.18 / 0.53, 0.35 / 0.53, 0], atol=1e-12)
    assert k == pytest.approx(0.47)
    d12 = disjunctive(m1, m2)
    np.testing.assert_allclose(d12, [0, 0.15, 0.28, 0.57], atol=1e-12)
    np.testing.assert_allclose(disjunctive(d12, m3), [0, 0.045, 0.224, 0.731], atol=1e-12)
    np.testing.assert_allclose(discount(m1, 0.1), [0, 0.27, 0.63, 0.1], atol=1e-12)


# Example 4: contextual discounting (Mercier et al. 2008)
def test_4_contextual_vs_classical() -> None:
    m = sets(AHR, {"a": 0.5, "r": 0.5})
    cd = contextual_discount(m, [0.4, 0.0, 0.0])
    np.testing.assert_allclose(cd, sets(AHR, {"a": 0.5, "r": 0.3, "ar": 0.2}), atol=1e-12)
    np.testing.assert_allclose(discount(m, 0.4), sets(AHR, {"a": 0.3, "r": 0.3, "ahr": 0.4}),
                               atol=1e-12)


# Example 5: {A, B, Θ} and Zadeh's example
def test_5_two_class_dempster() -> None:
    ab = Frame(("A", "B"))
    m, k = dempster(ab.vector({"A": 0.6, ("A", "B"): 0.4}), ab.vector({"B": 0.3, ("A", "B"): 0.7}))
    np.testing.assert_allclose(m, [0, 0.42 / 0.82, 0.12 / 0.82, 0.28 / 0.82], atol=1e-12)
    assert k == pytest.approx(0.18)


def test_5_zadeh_dempster_and_yager() -> None:
    m1 = sets(ABC, {"a": 0.99, "b": 0.01})
    m2 = sets(ABC, {"c": 0.99, "b": 0.01})
    m, k = dempster(m1, m2)
    assert k == pytest.approx(0.9999)
    np.testing.assert_allclose(m, sets(ABC, {"b": 1.0}), atol=1e-9)
    np.testing.assert_allclose(yager(m1, m2), sets(ABC, {"abc": 0.9999, "b": 0.0001}),
                               atol=1e-12)
