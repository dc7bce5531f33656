"""Frames, refinement, specialisation by ζ, conflict parts, and total-conflict handling."""

from __future__ import annotations

import numpy as np
import pytest

from evperc.dst import (
    FRAME,
    SENSOR_FRAME,
    Frame,
    conflict_parts,
    conjunctive,
    dempster,
    pignistic,
    refine,
    specialise_by_zeta,
    yager,
)
from evperc.dst import reference as ref

SG_TO_OMEGA = {"F": {"F"}, "O": {"I", "U", "S", "M"}}


# Frames

def test_standard_frames_follow_the_conventions() -> None:
    assert FRAME.names == ("F", "I", "U", "S", "M")
    assert [FRAME.mask(c) for c in "FIUSM"] == [1, 2, 4, 8, 16]
    assert FRAME.mask({"S", "M"}) == 24 and FRAME.names_of(24) == {"S", "M"}
    assert (FRAME.n, FRAME.size, FRAME.omega) == (5, 32, 31)
    assert FRAME.names_of(0) == frozenset()
    assert SENSOR_FRAME.mask("O") == 2 and SENSOR_FRAME.omega == 3


def test_frame_round_trip_every_mask() -> None:
    for mask in range(FRAME.size):
        assert FRAME.mask(FRAME.names_of(mask)) == mask


@pytest.mark.parametrize("names", [(), ("a", "a"), tuple("abcdefghi"), ("a", "")])
def test_bad_frames_are_refused(names: tuple[str, ...]) -> None:
    with pytest.raises(ValueError):
        Frame(names)


def test_unknown_class_and_bad_mask_are_refused() -> None:
    with pytest.raises(ValueError, match="'X'"):
        FRAME.mask({"X"})
    with pytest.raises(ValueError):
        FRAME.names_of(32)


def test_vacuous() -> None:
    v = FRAME.vacuous((2, 3))
    assert v.shape == (2, 3, 32) and v.dtype == np.float32
    assert np.all(v[..., 31] == 1) and v.sum() == 6


# Refinement Ω_SG → Ω

def test_refine_sensor_to_perception_frame() -> None:
    sg = np.array([[0.0, 0.7, 0.0, 0.3], [0.0, 0.0, 0.8, 0.2]], dtype=np.float32)
    out = refine(sg, SG_TO_OMEGA, FRAME)
    assert out.shape == (2, 32) and out.dtype == np.float32
    want = np.zeros((2, 32), dtype=np.float32)
    want[0, 0b00001], want[0, 31] = 0.7, 0.3
    want[1, 0b11110], want[1, 31] = 0.8, 0.2
    np.testing.assert_array_equal(out, want)


def test_refine_keeps_empty_set_and_uses_given_coarse_frame() -> None:
    sg = np.array([0.1, 0.2, 0.3, 0.4])
    out = refine(sg, {"O": tuple("IUSM"), "F": "F"}, FRAME, coarse_frame=SENSOR_FRAME)
    assert (out[0], out[1], out[30], out[31]) == (0.1, 0.2, 0.3, 0.4)
    assert out.sum() == pytest.approx(1.0)


@pytest.mark.parametrize("mapping", [
    {"F": {"F"}, "O": {"F", "I", "U", "S", "M"}},   # overlap
    {"F": {"F"}, "O": {"I", "U", "S"}},              # does not cover M
    {"F": set(), "O": {"F", "I", "U", "S", "M"}},    # empty image
])
def test_refine_refuses_non_refinings(mapping) -> None:
    with pytest.raises(ValueError):
        refine(np.array([0, 0, 0, 1.0]), mapping, FRAME)


# Specialisation by ζ (method.md §5.7)

def _m(focal: dict[str, float]) -> np.ndarray:
    return FRAME.vector({tuple(k): v for k, v in focal.items()})


@pytest.mark.parametrize("target, where", [("stopped", "S"), ("empty", "")])
def test_specialise_hand_worked(target: str, where: str) -> None:
    # {M .5, SM .2, Ω .3}, ζ = .4: M keeps .3 and gives .2 to S (or ∅); SM keeps .12 and
    # gives .08 to S; Ω keeps .18 and gives .12 to FIUS.
    m = _m({"M": 0.5, "SM": 0.2, "FIUSM": 0.3})
    out = specialise_by_zeta(m, 0.4, FRAME, stopped_target=target)
    want = {"M": 0.3, "SM": 0.12, "S": 0.08, "FIUSM": 0.18, "FIUS": 0.12}
    want[where] = want.get(where, 0.0) + 0.2
    np.testing.assert_allclose(out, _m(want), atol=1e-12)


def test_specialise_per_cell_zeta_and_extremes() -> None:
    rng = np.random.default_rng(3)
    m = rng.dirichlet(np.ones(32), size=(4,)).astype(np.float32)
    zeta = np.array([0.0, 1.0, 0.5, 0.25], dtype=np.float32)
    out = specialise_by_zeta(m, zeta, FRAME)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out[0], m[0], atol=1e-7)                # ζ = 0: unchanged
    with_m = [a for a in range(32) if a & 16]
    np.testing.assert_allclose(out[1, with_m], 0.0, atol=1e-7)          # ζ = 1: nothing on ∋M
    np.testing.assert_allclose(out.sum(-1), 1.0, atol=1e-6)
    np.testing.assert_allclose(out[2], specialise_by_zeta(m[2], 0.5, FRAME), atol=1e-7)
    # the set {M} never keeps mass a ζ = 1 moved, and with "stopped" ∅ gets nothing
    assert out[1, 0] == pytest.approx(m[1, 0])
    assert out[1, 8] == pytest.approx(m[1, 8] + m[1, 16] + m[1, 24], abs=1e-7)


# Conflict parts (method.md §5.4)

def test_conflict_parts_hand_worked() -> None:
    prev = np.stack([
        _m({"F": 0.6, "FIUSM": 0.4}),          # free before
        _m({"S": 0.5, "F": 0.3, "FIUSM": 0.2}),
        _m({"I": 0.5, "FIUSM": 0.5}),
    ])
    sensor = np.stack([
        _m({"IUSM": 0.8, "FIUSM": 0.2}),       # an object appears
        _m({"F": 0.7, "IUSM": 0.1, "FIUSM": 0.2}),
        _m({"S": 0.4, "FIUSM": 0.6}),          # I vs S: conflict that is neither
    ])
    fo, of, other = conflict_parts(prev, sensor, FRAME)
    # row 0: .6·.8 = .48; row 1: FO = .3·.1, OF = .5·.7; row 2: I∩S = .5·.4 = .2
    np.testing.assert_allclose(fo, [0.48, 0.03, 0.0], atol=1e-12)
    np.testing.assert_allclose(of, [0.0, 0.35, 0.0], atol=1e-12)
    np.testing.assert_allclose(other, [0.0, 0.0, 0.2], atol=1e-12)
    np.testing.assert_allclose(fo + of + other, ref.conjunctive(prev, sensor)[:, 0], atol=1e-12)


def test_conflict_parts_with_precomputed_empty_mass() -> None:
    rng = np.random.default_rng(5)
    prev, sensor = rng.dirichlet(np.ones(32), size=(2, 10))
    c = conjunctive(prev, sensor)
    a = conflict_parts(prev, sensor, FRAME)
    b = conflict_parts(prev, sensor, FRAME, empty_mass=c[..., 0])
    for x, y in zip(a, b, strict=True):
        np.testing.assert_allclose(x, y, atol=1e-12)
    assert np.all(a[2] >= 0)


# Total conflict: reported, never NaN, never raised

@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_dempster_total_conflict_is_reported(dtype: type) -> None:
    ab = Frame(("a", "b"))
    m1 = np.stack([ab.vector({"a": 1.0}), ab.vector({"a": 0.5, ("a", "b"): 0.5})]).astype(dtype)
    m2 = np.stack([ab.vector({"b": 1.0}), ab.vector({"b": 0.5, ("a", "b"): 0.5})]).astype(dtype)
    m, k = dempster(m1, m2)
    assert m.dtype == dtype and k.dtype == dtype
    assert k[0] == 1.0 and np.all(m[0] == 0)
    assert k[1] == pytest.approx(0.25)
    np.testing.assert_allclose(m[1], [0, 0.25 / 0.75, 0.25 / 0.75, 0.25 / 0.75], atol=1e-6)
    assert np.isfinite(m).all()
    np.testing.assert_allclose(yager(m1, m2)[0], [0, 0, 0, 1], atol=1e-7)


def test_pignistic_of_total_conflict_is_zero() -> None:
    m = np.zeros((2, 8), dtype=np.float32)
    m[0, 0] = 1.0
    m[1, 0], m[1, 7] = 0.5, 0.5
    p = pignistic(m)
    assert p.dtype == np.float32 and p.shape == (2, 3)
    np.testing.assert_array_equal(p[0], 0.0)
    np.testing.assert_allclose(p[1], [1 / 3] * 3, atol=1e-7)


def test_shape_errors() -> None:
    with pytest.raises(ValueError):
        conjunctive(np.ones(3), np.ones(3))
    with pytest.raises(ValueError):
        conjunctive(np.ones(4), np.ones(8))
    with pytest.raises(ValueError):
        conjunctive(np.ones(4), np.ones(4), kernel="fft")
