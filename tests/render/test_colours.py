"""Colour maths against hand-worked values (method.md §6)."""

from __future__ import annotations

import numpy as np

from evperc.render import colours as c
from tests.render.conftest import CODES


def test_pignistic_colour_hand_worked() -> None:
    betp = np.array([
        [1, 0, 0, 0, 0],            # all free: green
        [0, 0, 0, 0, 1],            # all moving: red
        [0.5, 0, 0, 0, 0.5],        # fading free {F, M}: (127.5, 127.5, 0), olive
        [0, 0.25, 0.25, 0.25, 0.25],  # I, U, S, M: R .25·(255+255+255), G .25·160,
        #                               B .25·(255+255)
        [0, 1, 0, 0, 0],            # infrastructure: blue
        [0, 0, 1, 0, 0],            # unmapped: magenta
    ], dtype=np.float32)
    expected = [(0, 255, 0), (255, 0, 0), (128, 128, 0), (191, 40, 128), (0, 0, 255),
                (255, 0, 255)]
    np.testing.assert_array_equal(c.pignistic_colour(betp), np.array(expected, np.uint8))


def test_no_class_colour_is_a_mixture_the_picture_shows() -> None:
    """Issue 22: a fading free cell ({F, M}) rendered olive looked like the old "unmapped"
    yellow. No class colour is within 60 (per channel) of a 50/50 or 4-way mixture, and the
    legend's fading swatches are the mixtures' colours."""
    classes = list(c.CLASS_COLOURS.values())
    mixtures = [c.pignistic_colour(np.array(b, np.float32)) for b in
                ([0.5, 0, 0, 0, 0.5], [0.25, 0, 0.25, 0.25, 0.25], [0.5, 0, 0, 0.5, 0])]
    for mixture in mixtures:
        for colour in classes:
            assert np.abs(mixture.astype(int) - colour).max() > 60, (mixture, colour)
    assert tuple(mixtures[0]) == c.FADING_COLOURS["free, fading"]
    assert tuple(mixtures[1]) == c.FADING_COLOURS["free, faded"]


def test_unknown_is_black_in_the_pignistic_panel() -> None:
    betp = np.full((2, 5), 0.2, np.float32)
    got = c.pignistic_colour_known(betp, np.array([1.0, 0.5], np.float32))
    assert tuple(got[0]) == (0, 0, 0)
    assert tuple(got[1]) == tuple(np.round(np.array([153, 83, 102]) * 0.5 + 1e-9).astype(int))


def test_four_colour_decision_groups_static_classes() -> None:
    lut = c.decision_lut(CODES, c.DECISION4_COLOURS, c.DECISION4_OF_CODE)
    codes = np.array([[0, 1, 2, 3, 4, 5, 6]], np.uint8)
    got = c.apply_lut(codes, lut)[0]
    static = c.STATIC_COLOUR
    assert [tuple(v) for v in got] == [(0, 0, 0), (0, 255, 0), (255, 0, 0), static, static,
                                       static, static]
    # the same colour never means two things across panels: static is no class's colour
    assert static not in c.CLASS_COLOURS.values()


def test_six_class_decision_distinguishes_static_kinds() -> None:
    lut = c.decision_lut(CODES, c.DECISION6_COLOURS)
    got = [tuple(v) for v in c.apply_lut(np.arange(7, dtype=np.uint8), lut)]
    assert len(set(got)) == 7
    assert got[CODES["stopped"]] == c.CLASS_COLOURS["S"] == (255, 160, 0)
    assert got[CODES["infrastructure"]] == c.CLASS_COLOURS["I"] == (0, 0, 255)
    assert got[CODES["unmapped"]] == c.CLASS_COLOURS["U"] == (255, 0, 255)


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
