"""Colour maths against hand-worked values (method.md §6)."""

from __future__ import annotations

import numpy as np

from evperc.render import colours as c
from tests.render.conftest import CODES


def test_pignistic_colour_hand_worked() -> None:
    betp = np.array([
        [1, 0, 0, 0, 0],            # all free: green
        [0, 0, 0, 0, 1],            # all moving: red
        [0.5, 0, 0, 0, 0.5],        # half free half moving: (127.5, 127.5, 0)
        [0, 0.25, 0.25, 0.25, 0.25],  # I, U, S, M: R .25·(255+255), G .25·255, B .25·(128+255)
        [0, 1, 0, 0, 0],            # infrastructure: dark blue
        [0, 0, 1, 0, 0],            # unmapped: yellow
    ], dtype=np.float32)
    expected = [(0, 255, 0), (255, 0, 0), (128, 128, 0), (128, 64, 96), (0, 0, 128),
                (255, 255, 0)]
    np.testing.assert_array_equal(c.pignistic_colour(betp), np.array(expected, np.uint8))


def test_four_colour_decision_groups_static_classes() -> None:
    lut = c.decision_lut(CODES, c.DECISION4_COLOURS, c.DECISION4_OF_CODE)
    codes = np.array([[0, 1, 2, 3, 4, 5, 6]], np.uint8)
    got = c.apply_lut(codes, lut)[0]
    blue = (0, 0, 255)
    assert [tuple(v) for v in got] == [(0, 0, 0), (0, 255, 0), (255, 0, 0), blue, blue, blue,
                                       blue]


def test_six_class_decision_distinguishes_static_kinds() -> None:
    lut = c.decision_lut(CODES, c.DECISION6_COLOURS)
    got = [tuple(v) for v in c.apply_lut(np.arange(7, dtype=np.uint8), lut)]
    assert len(set(got)) == 7
    assert got[CODES["stopped"]] == (0, 0, 255)
    assert got[CODES["infrastructure"]] == (0, 0, 128)
    assert got[CODES["unmapped"]] == (255, 255, 0)


def test_zeta_ramp_ends_and_clipping() -> None:
    lut = c.ramp_lut()
    got = c.ramp_colour(np.array([0.0, 1.0, -3.0, 7.0, np.nan]), lut)
    assert tuple(got[0]) == (0, 0, 0)
    assert tuple(got[1]) == (252, 255, 164)
    assert tuple(got[2]) == (0, 0, 0) and tuple(got[3]) == (252, 255, 164)
    assert tuple(got[4]) == (0, 0, 0)


def test_conflict_channels() -> None:
    got = c.conflict_colour(np.array([[1.0, 0.0, 0.5]], np.float32))
    assert tuple(got[0]) == (255, 0, 128)


def test_trace_colour_dims_base_and_marks_trace() -> None:
    base = np.array([[[0, 255, 0], [255, 0, 0]]], np.uint8)
    got = c.trace_colour(base, np.array([[False, True]]))
    assert tuple(got[0, 1]) == (255, 0, 0)
    assert got[0, 0, 0] == 0 and 70 <= got[0, 0, 1] <= 80  # 0.3 × 255 ≈ 76
