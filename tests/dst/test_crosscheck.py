"""Cross-checks against two independent libraries on random mass functions, n = 2…5.

- py-dempster-shafer (``pyds.MassFunction``): focal-set dictionaries, pair loops.
- evtools-dst (``evtools``): ``DSVector`` with its own sparse pair loops (``method="sparse"``,
  the default, so its fast Möbius code is not what we compare against), ``betp``,
  ``mtobel``/``mtopl``, and discounting in ``evtools.corrections``.

Conventions that differ, and what is done about them:
- pyds has no discounting at all: classical and contextual discounting are checked against
  evtools and the naive reference (``evperc.dst.reference``) only.
- evtools writes discounting with the *reliability* β = 1 − α (``discount(m, beta)``,
  ``contextual_discount(m, {{θ}: β_θ})``).
- Both libraries raise (evtools) or divide by zero (pyds) on total conflict, where ours
  reports K = 1: the Dempster checks draw only pairs with K < 0.999 (total conflict is
  tested in test_operators.py).
- pyds's ``q(∅)`` is hard-wired to 1 and its ``bel``/``pl`` ignore ∅; inputs sum to 1, so
  they agree with ours, and belief/plausibility are compared on non-normal inputs too.
All comparisons are in float64 to 1e-9.
"""

from __future__ import annotations

import numpy as np
import pytest
from evtools import combinations as ev_comb
from evtools import conversions as ev_conv
from evtools import corrections as ev_corr
from evtools.dsvector import DSVector
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from pyds import MassFunction

from evperc.dst import (
    belief,
    conjunctive,
    contextual_discount,
    dempster,
    discount,
    disjunctive,
    pignistic,
    plausibility,
)
from evperc.dst import reference as ref

from .strategies import masses, names

TOL = 1e-9
SETTINGS = settings(max_examples=60, deadline=None)


@st.composite
def pair(draw, normal: bool = False) -> tuple[int, np.ndarray, np.ndarray]:
    n = draw(st.integers(2, 5))
    return n, draw(masses(n, normal=normal)), draw(masses(n, normal=normal))


def to_pyds(m: np.ndarray, n: int) -> MassFunction:
    return MassFunction.from_array(m, names(n))


def from_pyds(mf: MassFunction, n: int) -> np.ndarray:
    return mf.to_array(names(n))


def to_ev(m: np.ndarray, n: int) -> DSVector:
    return DSVector.from_dense(names(n), m)


def from_ev(v: DSVector, n: int) -> np.ndarray:
    out = np.zeros(1 << n)
    for subset, value in v.sparse.items():
        out[sum(1 << int(name[1:]) for name in subset)] += value
    return out


@SETTINGS
@given(pair())
def test_conjunctive(args) -> None:
    n, m1, m2 = args
    ours = conjunctive(m1, m2)
    pyds_c = from_pyds(to_pyds(m1, n).combine_conjunctive(to_pyds(m2, n), normalization=False), n)
    np.testing.assert_allclose(ours, pyds_c, atol=TOL)
    np.testing.assert_allclose(ours, from_ev(ev_comb.crc(to_ev(m1, n), to_ev(m2, n)), n),
                               atol=TOL)


@SETTINGS
@given(pair())
def test_dempster(args) -> None:
    n, m1, m2 = args
    k_ref = ref.conjunctive(m1, m2)[0]
    assume(k_ref < 0.999)
    ours, k = dempster(m1, m2)
    assert k == pytest.approx(k_ref, abs=TOL)
    pyds_d = from_pyds(to_pyds(m1, n).combine_conjunctive(to_pyds(m2, n)), n)
    np.testing.assert_allclose(ours, pyds_d, atol=TOL)
    np.testing.assert_allclose(ours, from_ev(ev_comb.dempster(to_ev(m1, n), to_ev(m2, n)), n),
                               atol=TOL)


@SETTINGS
@given(pair())
def test_disjunctive(args) -> None:
    n, m1, m2 = args
    ours = disjunctive(m1, m2)
    np.testing.assert_allclose(
        ours, from_pyds(to_pyds(m1, n).combine_disjunctive(to_pyds(m2, n)), n), atol=TOL)
    np.testing.assert_allclose(ours, from_ev(ev_comb.drc(to_ev(m1, n), to_ev(m2, n)), n),
                               atol=TOL)


@SETTINGS
@given(st.integers(2, 5).flatmap(lambda n: st.tuples(st.just(n), masses(n))))
def test_pignistic(args) -> None:
    n, m = args
    assume(m[0] < 0.999)
    ours = pignistic(m)
    p = to_pyds(m, n).pignistic()
    np.testing.assert_allclose(ours, [p[(f"c{k}",)] for k in range(n)], atol=TOL)
    np.testing.assert_allclose(ours, ev_conv.betp(m), atol=TOL)


@SETTINGS
@given(st.integers(2, 5).flatmap(lambda n: st.tuples(st.just(n), masses(n))))
def test_belief_plausibility(args) -> None:
    n, m = args
    bel, pl = belief(m), plausibility(m)
    mf = to_pyds(m, n)
    for a in range(1 << n):
        hyp = [f"c{k}" for k in range(n) if a >> k & 1]
        assert bel[a] == pytest.approx(mf.bel(hyp), abs=TOL)
        assert pl[a] == pytest.approx(mf.pl(hyp), abs=TOL)
    np.testing.assert_allclose(bel, ev_conv.mtobel(m), atol=TOL)
    np.testing.assert_allclose(pl, ev_conv.mtopl(m), atol=TOL)


@SETTINGS
@given(st.integers(2, 5).flatmap(lambda n: st.tuples(st.just(n), masses(n, normal=True))),
       st.floats(0.0, 1.0))
def test_classical_discount(args, alpha: float) -> None:
    """pyds has no discounting: evtools (β = 1 − α) and the textbook formula."""
    n, m = args
    ours = discount(m, alpha)
    np.testing.assert_allclose(ours, from_ev(ev_corr.discount(to_ev(m, n), 1.0 - alpha), n),
                               atol=TOL)
    want = (1 - alpha) * m
    want[-1] += alpha
    np.testing.assert_allclose(ours, want, atol=TOL)


@SETTINGS
@given(st.integers(2, 5).flatmap(
    lambda n: st.tuples(st.just(n), masses(n, normal=True),
                        st.lists(st.floats(0.0, 1.0), min_size=n, max_size=n))))
def test_contextual_discount(args) -> None:
    """pyds has no discounting: evtools (β_θ = 1 − α_θ) and the naive pair-loop reference."""
    n, m, alphas = args
    ours = contextual_discount(m, alphas)
    betas = {frozenset({f"c{k}"}): 1.0 - a for k, a in enumerate(alphas)}
    np.testing.assert_allclose(
        ours, from_ev(ev_corr.contextual_discount(to_ev(m, n), betas), n), atol=TOL)
    np.testing.assert_allclose(ours, ref.contextual_discount(m, np.array(alphas)), atol=TOL)
