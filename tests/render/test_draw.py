"""Raster primitives: segment clipping and drawing."""

from __future__ import annotations

import numpy as np

from evperc.render.draw import clip_segments, draw_segments, upscale


def test_clip_segments_hand_cases() -> None:
    seg = np.array([
        [-5, 5, 15, 5],      # crosses the box horizontally → 0..10
        [2, 2, 4, 4],        # inside
        [20, 20, 30, 30],    # outside
        [-1, 11, 11, -1],    # diagonal through the box
    ], float)
    got = clip_segments(seg, 0, 0, 10, 10)
    np.testing.assert_allclose(got, [[0, 5, 10, 5], [2, 2, 4, 4], [0, 10, 10, 0]])


def test_draw_segments_horizontal_and_clipped() -> None:
    img = np.zeros((10, 20, 3), np.uint8)
    draw_segments(img, np.array([[-5.0, 3.5, 30.0, 3.5]]), (9, 8, 7), box=(2, 0, 12, 10))
    hit = np.all(img == (9, 8, 7), axis=-1)
    assert hit.sum() == 10 and hit[3, 2:12].all()


def test_upscale_repeats_cells() -> None:
    rgb = np.arange(12, dtype=np.uint8).reshape(2, 2, 3)
    big = upscale(rgb, 3)
    assert big.shape == (6, 6, 3)
    np.testing.assert_array_equal(big[4, 1], rgb[1, 0])
