"""Algebraic properties of the rules and transforms, on random mass functions (hypothesis)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from evperc.dst import (
    commonality_to_mass,
    conjunctive,
    contextual_discount,
    dempster,
    discount,
    disjunctive,
    implicability_to_mass,
    mass_to_commonality,
    mass_to_implicability,
    plausibility,
    yager,
)
from evperc.dst import reference as ref

from .strategies import masses

SETTINGS = settings(max_examples=50, deadline=None)
KERNELS = ("butterfly", "matrix")


def frame_and(k: int, *, lo: int = 2, hi: int = 5, cells: tuple[int, ...] = (),
              normal: bool = False, dtype: type = np.float64):
    """(n, m_1, …, m_k) with n drawn in lo…hi."""
    return st.integers(lo, hi).flatmap(lambda n: st.tuples(
        st.just(n), *[masses(n, cells=cells, normal=normal, dtype=dtype) for _ in range(k)]))


@SETTINGS
@given(frame_and(3, cells=(3,)), st.sampled_from(KERNELS))
def test_commutative_and_associative(args, kernel: str) -> None:
    _, a, b, c = args
    for rule in (conjunctive, disjunctive):
        np.testing.assert_allclose(rule(a, b, kernel), rule(b, a, kernel), atol=1e-12)
        np.testing.assert_allclose(rule(rule(a, b, kernel), c, kernel),
                                   rule(a, rule(b, c, kernel), kernel), atol=1e-12)


@SETTINGS
@given(frame_and(1, cells=(4,)), st.sampled_from(KERNELS))
def test_neutral_and_absorbing_elements(args, kernel: str) -> None:
    """Vacuous (m(Ω) = 1) is neutral for ∩ and absorbing for ∪; m(∅) = 1 is neutral for ∪
    and absorbing for ∩."""
    n, m = args
    vacuous = np.zeros(1 << n)
    vacuous[-1] = 1
    empty = np.zeros(1 << n)
    empty[0] = 1
    np.testing.assert_allclose(conjunctive(m, vacuous, kernel), m, atol=1e-12)
    np.testing.assert_allclose(disjunctive(m, vacuous, kernel), np.broadcast_to(vacuous, m.shape),
                               atol=1e-12)
    np.testing.assert_allclose(disjunctive(m, empty, kernel), m, atol=1e-12)
    np.testing.assert_allclose(conjunctive(m, empty, kernel), np.broadcast_to(empty, m.shape),
                               atol=1e-12)


@SETTINGS
@given(frame_and(2, lo=2, hi=8, cells=(5,)), st.sampled_from([np.float32, np.float64]),
       st.sampled_from(KERNELS))
def test_results_are_mass_functions(args, dtype: type, kernel: str) -> None:
    """Every rule keeps the dtype and gives masses in [0, 1] summing to 1 (float32: 1e-5)."""
    n, a, b = args
    a, b = a.astype(dtype), b.astype(dtype)
    tol = 1e-5 if dtype == np.float32 else 1e-12
    alphas = np.linspace(0.05, 0.9, n)
    results = [conjunctive(a, b, kernel), disjunctive(a, b, kernel), yager(a, b, kernel),
               discount(a, 0.3), contextual_discount(a, alphas)]
    m, k = dempster(a, b, kernel)
    results.append(m[k < 1])
    for r in results:
        assert r.dtype == dtype
        assert r.min() >= 0 and r.max() <= 1
        np.testing.assert_allclose(r.sum(axis=-1), 1.0, atol=tol)
    # float32 results stay close to the float64 reference: through commonalities each mass
    # is a signed sum of up to 2^n products, so its round-off grows like 2^n float32 ulps
    # (seen: 1.1e-5 at n = 8 with 256 equal masses)
    atol = 2.0 ** n * 4 * np.finfo(np.float32).eps if dtype == np.float32 else 1e-12
    np.testing.assert_allclose(results[0], ref.conjunctive(a, b), atol=max(atol, 1e-5))


@SETTINGS
@given(frame_and(1, lo=1, hi=8, cells=(3,)), st.sampled_from(KERNELS))
def test_moebius_round_trips_and_definitions(args, kernel: str) -> None:
    n, m = args
    q = mass_to_commonality(m, kernel)
    b = mass_to_implicability(m, kernel)
    np.testing.assert_allclose(commonality_to_mass(q, kernel), m, atol=1e-12)
    np.testing.assert_allclose(implicability_to_mass(b, kernel), m, atol=1e-12)
    if n <= 5:
        np.testing.assert_allclose(q, ref.commonality(m), atol=1e-12)
        np.testing.assert_allclose(b, ref.implicability(m), atol=1e-12)
        np.testing.assert_allclose(plausibility(m, kernel), ref.plausibility(m), atol=1e-12)


@SETTINGS
@given(frame_and(2, lo=2, hi=6, cells=(2, 3)))
def test_kernels_agree_with_pair_loop(args) -> None:
    _, a, b = args
    for kernel in KERNELS:
        np.testing.assert_allclose(conjunctive(a, b, kernel), ref.conjunctive(a, b), atol=1e-12)
        np.testing.assert_allclose(disjunctive(a, b, kernel), ref.disjunctive(a, b), atol=1e-12)


# Contextual discounting: the relations of Mercier, Quost & Denœux (2008)

def _alphas(n: int):
    return st.lists(st.floats(0.0, 1.0), min_size=n, max_size=n).map(np.array)


@SETTINGS
@given(st.integers(2, 5).flatmap(lambda n: st.tuples(st.just(n), masses(n), _alphas(n))),
       st.sampled_from(KERNELS))
def test_contextual_implicability_relation(args, kernel: str) -> None:
    """b'(A) = b(A) · Π_{θ ∉ A} (1 − α_θ) (the disjunctive rule multiplies implicabilities)."""
    n, m, alphas = args
    b_new = mass_to_implicability(contextual_discount(m, alphas, kernel=kernel))
    b = mass_to_implicability(m)
    for a in range(1 << n):
        factor = np.prod([1 - alphas[k] for k in range(n) if not a >> k & 1])
        assert b_new[a] == pytest.approx(b[a] * factor, abs=1e-12)


@SETTINGS
@given(st.integers(2, 5).flatmap(lambda n: st.tuples(st.just(n), masses(n, normal=True))),
       st.floats(0.0, 1.0))
def test_contextual_equal_rates_vs_classical(args, alpha: float) -> None:
    """With every α_θ = α, pl'(A) = 1 − (1 − pl(A))(1 − α)^|A| (Mercier et al. 2008), so the
    singleton plausibilities equal those of classical discounting at rate α — while the
    mass functions themselves differ in general (pinned below)."""
    n, m = args
    cd = contextual_discount(m, np.full(n, alpha))
    pl, pl_cd = plausibility(m), plausibility(cd)
    for a in range(1, 1 << n):
        size = bin(a).count("1")
        assert pl_cd[a] == pytest.approx(1 - (1 - pl[a]) * (1 - alpha) ** size, abs=1e-12)
    singletons = [1 << k for k in range(n)]
    np.testing.assert_allclose(pl_cd[singletons], plausibility(discount(m, alpha))[singletons],
                               atol=1e-12)


def test_contextual_equal_rates_is_not_classical() -> None:
    """{a: .5, r: .5} on {a, h, r} with all rates .4, worked by hand one class at a time
    (a set without θ keeps .6 of its mass and gives .4 to itself ∪ {θ}):
    after a: {a .5, r .3, ar .2}; after h: {a .3, r .18, ar .12, ah .2, hr .12, ahr .08};
    after r: {a .18, ah .12, r .18, hr .12, ar .24, ahr .16}.
    Classical discounting at .4 gives {a .3, r .3, ahr .4} instead."""
    m = np.zeros(8)
    m[0b001], m[0b100] = 0.5, 0.5
    cd = contextual_discount(m, [0.4, 0.4, 0.4])
    want = np.zeros(8)
    want[[0b001, 0b011, 0b100, 0b110, 0b101, 0b111]] = [0.18, 0.12, 0.18, 0.12, 0.24, 0.16]
    np.testing.assert_allclose(cd, want, atol=1e-12)
    np.testing.assert_allclose(cd, ref.contextual_discount(m, np.full(3, 0.4)), atol=1e-12)
    assert np.abs(cd - discount(m, 0.4)).max() > 0.1


@SETTINGS
@given(frame_and(1, lo=2, hi=5, cells=(2, 3)), st.data())
def test_per_cell_rates_broadcast(args, data) -> None:
    n, m = args
    alphas = data.draw(st.lists(st.floats(0, 1), min_size=6 * n, max_size=6 * n))
    alphas = np.array(alphas).reshape(2, 3, n)
    cd = contextual_discount(m, alphas)
    scalar = np.array(data.draw(st.lists(st.floats(0, 1), min_size=6, max_size=6))).reshape(2, 3)
    cl = discount(m, scalar)
    for i in range(2):
        for j in range(3):
            np.testing.assert_allclose(cd[i, j], contextual_discount(m[i, j], alphas[i, j]),
                                       atol=1e-12)
            np.testing.assert_allclose(cl[i, j], discount(m[i, j], scalar[i, j]), atol=1e-12)
    # one rate vector for the whole grid broadcasts too
    np.testing.assert_allclose(contextual_discount(m, alphas[0, 0]),
                               ref.contextual_discount(m, alphas[0, 0]), atol=1e-12)
