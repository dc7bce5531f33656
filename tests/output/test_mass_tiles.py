"""The block-sparse layout of stored masses (evperc.output.mass_tiles; docs/output-format.md),
against a plain-Python reading of its definition."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from evperc.output import mass_tiles


def naive_runs(masses: np.ndarray, tile_masks: np.ndarray, tile: int) -> bytes:
    """The definition, cell by cell: tiles row by row, left to right; in each, the planes of
    its mask in increasing subset order; in each plane, the tile's cells left to right."""
    _, rows, cols = masses.shape
    out = bytearray()
    for r in range(rows):
        for t, j0 in enumerate(range(0, cols, tile)):
            for a in range(32):
                if int(tile_masks[r, t]) >> a & 1:
                    out += bytes(int(v) for v in masses[a, r, j0:min(j0 + tile, cols)])
    return bytes(out)


@st.composite
def sparse_frames(draw):
    rows = draw(st.integers(1, 4))
    cols = draw(st.integers(1, 140))
    tile = draw(st.sampled_from([1, 3, 16, 64, 256]))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    n_tiles = -(-cols // tile)
    # each tile uses a few planes; its cells hold values (some zero) on them only
    masks = np.zeros((rows, n_tiles), np.uint32)
    masses = np.zeros((32, rows, cols), np.uint8)
    for r in range(rows):
        for t in range(n_tiles):
            planes = rng.choice(32, size=int(rng.integers(0, 6)), replace=False)
            for a in planes:
                masks[r, t] |= np.uint32(1 << int(a))
                cells = slice(t * tile, min((t + 1) * tile, cols))
                masses[a, r, cells] = rng.integers(0, 256, masses[a, r, cells].shape)
    return masses, masks, tile


@settings(max_examples=60, deadline=None)
@given(sparse_frames())
def test_encode_is_the_definition_and_decode_inverts_it(frame) -> None:
    masses, masks, tile = frame
    runs = mass_tiles.encode(masses, masks, tile)
    assert runs.tobytes() == naive_runs(masses, masks, tile)
    assert mass_tiles.run_bytes(masks, masses.shape[2], tile) == runs.size
    np.testing.assert_array_equal(mass_tiles.decode(runs, masks, masses.shape[1:], tile),
                                  masses)


@settings(max_examples=40, deadline=None)
@given(sparse_frames())
def test_masks_of_are_the_planes_used_in_each_tile(frame) -> None:
    masses, _, tile = frame
    masks = mass_tiles.masks_of(masses, tile)
    _, rows, cols = masses.shape
    for r in range(rows):
        for t, j0 in enumerate(range(0, cols, tile)):
            used = sum(1 << a for a in range(32) if masses[a, r, j0:j0 + tile].any())
            assert int(masks[r, t]) == used


def test_popcount_of_every_bit_pattern_kind() -> None:
    values = np.array([0, 1, 0x80000000, 0xFFFFFFFF, 0x0F0F0F0F, 2**31 - 1], np.uint32)
    np.testing.assert_array_equal(mass_tiles.popcount(values),
                                  [bin(int(v)).count("1") for v in values])


def test_encode_refuses_mass_outside_the_masks() -> None:
    masses = np.zeros((32, 1, 4), np.uint8)
    masses[3, 0, 2] = 7
    with pytest.raises(ValueError, match="outside the tile masks"):
        mass_tiles.encode(masses, np.array([[1 << 31]], np.uint32), 64)


def test_decode_refuses_runs_of_the_wrong_length_or_masks_of_the_wrong_shape() -> None:
    masks = np.array([[1 << 31 | 1, 1 << 31]], np.uint32)  # 2 planes of 64 + 1 plane of 6
    good = np.zeros(2 * 64 + 6, np.uint8)
    assert mass_tiles.decode(good, masks, (1, 70), 64).shape == (32, 1, 70)
    with pytest.raises(ValueError, match="133 bytes of mass runs, the tile masks describe 134"):
        mass_tiles.decode(good[:-1], masks, (1, 70), 64)
    with pytest.raises(ValueError, match="tile masks of shape"):
        mass_tiles.decode(good, masks, (1, 200), 64)
