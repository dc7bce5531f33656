"""The unmapped cue on hand-made decision grids (evperc.objects.unmapped): expected relabels
worked out by hand in the comments; on random shifting windows, against a plain reference
(a dict of world cells for the state, scipy's 8-connected labelling for the components)."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from evperc.config import load_config
from evperc.errors import ConfigError
from evperc.fusion.twin import DECISION_CODES as D
from evperc.geo.prior import CONTEXT_BUILDING, CONTEXT_OTHER, CONTEXT_ROAD
from evperc.geo.window import Window
from evperc.objects.unmapped import (
    UnmappedCue,
    UnmappedParams,
    UnmappedState,
    unmapped_enabled,
)
from evperc.output.objects import OBJECT_DTYPE, OBJECT_STATES, moving_object_cells
from tests.objects.unmapped_grids import DT, RES, SHAPE, free_window, run_cue, street_labels

PARAMS = UnmappedParams(max_width_m=0.55, min_age_s=0.1)


def _frames(decisions: list[np.ndarray], labels: np.ndarray | None, params=PARAMS,
            moving_cells=None) -> list[np.ndarray]:
    """Each decision after the cue, the window fixed; ``moving_cells``: per frame or None."""
    return run_cue(decisions, labels, params, moving_cells)[0]


def test_pole_and_fence_become_unmapped_once_old_enough() -> None:
    dec = free_window()
    dec[8, 3] = D["static"]                  # a pole: one cell, width 1 / 1 cell = 0.5 m
    fence = [(6 + k, 8 + k) for k in range(6)]
    for r, c in fence:
        dec[r, c] = D["stopped"]
    # length along 45°: centres 5·√2 apart, + 1 cell = 8.07 cells; width 6 / 8.07 = 0.74
    # cell = 0.37 m <= 0.55
    first, second = _frames([dec, dec], street_labels())
    np.testing.assert_array_equal(first, dec)            # age 0 < 0.1 s: not yet
    want = dec.copy()
    want[8, 3] = D["unmapped"]
    for r, c in fence:
        want[r, c] = D["unmapped"]
    np.testing.assert_array_equal(second, want)          # age 0.1 s: relabelled


def test_straight_fence_width_is_one_cell() -> None:
    dec = free_window()
    dec[9, 2:14] = D["static"]               # 12 cells in a row: 12 / (11 + 1) = 1 cell
    cue = UnmappedCue(PARAMS, SHAPE, RES)
    state = UnmappedState.fresh(SHAPE)
    cue.step(state, dec.copy(), street_labels(), DT)
    n = cue.step(state, dec, street_labels(), DT)
    assert n == 12 and (dec[9, 2:14] == D["unmapped"]).all()
    (row,) = cue.stats
    assert row[0] == 12 and row[4] == pytest.approx(0.5) and row[5] == pytest.approx(6.0)



@pytest.mark.parametrize("seed", range(4))
def test_width_and_length_of_random_blobs_from_every_cell(seed: int) -> None:
    """Each component's width and length (stats) against the shape test on every one of its
    cells (scipy's 8-connected labels, numpy's projections) — filled rectangles, diagonal
    bands and discs, not only the one-cell-thick lines and small blocks of the tests above."""
    rng = np.random.default_rng(seed)
    shape = (48, 48)
    dec = np.full(shape, D["free"], np.uint8)
    rr, cc = np.mgrid[0:shape[0], 0:shape[1]]
    for _ in range(6):  # filled rectangles, diagonal bands and discs of 1-6 cells across
        r, c = (int(v) for v in rng.integers(1, shape[0] - 1, size=2))
        h, w = (int(v) for v in rng.integers(1, 7, size=2))
        kind = seed % 3 if _ % 2 else int(rng.integers(0, 3))
        blob = ((np.abs(rr - r) < h) & (np.abs(cc - c) < w) if kind == 0
                else (np.abs((rr - r) - (cc - c)) < h) & (np.abs(rr - r) < w + 2) if kind == 1
                else (rr - r) ** 2 + (cc - c) ** 2 <= h * w)
        dec[blob] = D["static"] if rng.random() < 0.5 else D["stopped"]
    labels = np.full(shape, CONTEXT_OTHER, np.uint8)
    cue = UnmappedCue(PARAMS, shape, RES)
    cue.step(UnmappedState.fresh(shape), dec.copy(), labels, DT)
    comp, n = ndimage.label(np.isin(dec, [D["static"], D["stopped"]]),
                            structure=np.ones((3, 3)))
    assert cue.components == n and n >= 2
    theta = np.arange(16) * (math.pi / 16)
    wide = 0
    # the components in the order the pass finds them: row-major by their first cell
    firsts = sorted((int(np.flatnonzero(comp.reshape(-1) == k)[0]), k) for k in range(1, n + 1))
    for row, (_, k) in zip(cue.stats, firsts, strict=True):
        rr, cc = np.nonzero(comp == k)
        p = cc[:, None] * np.cos(theta) + rr[:, None] * np.sin(theta)
        extent = p.max(axis=0) - p.min(axis=0)
        thin = int(np.flatnonzero(extent < extent.min() + 1e-9)[0])
        length = extent[(thin + 8) % 16] + 1.0
        assert row[0] == len(rr)
        assert row[5] == pytest.approx(length * RES, abs=1e-9)
        assert row[4] == pytest.approx(len(rr) / length * RES, abs=1e-9)
        wide += int(np.ptp(cc) >= 2 and len(rr) > np.ptp(cc) + 1)
    assert wide >= 1  # a blob with cells inside its rows: filled, not only outlines

def test_parked_car_block_tree_blob_and_l_stay() -> None:
    dec = free_window()
    dec[6:10, 2:11] = D["stopped"]           # a parked car, 4 x 9 cells (2 m x 4.5 m) on the
    # pavement: width 36 / 9 = 4 cells = 2 m
    dec[7:9, 14:16] = D["static"]            # a 2 x 2 blob: width 4 / 2 = 2 cells = 1 m
    dec[12, 2] = D["static"]                 # an L of three cells: thinnest across 135°
    dec[12, 3] = D["static"]                 # (extent 0.71 cell), length along 45°
    dec[13, 3] = D["static"]                 # 1.41 + 1 = 2.41 cells: width 3 / 2.41 = 0.62 m
    final = _frames([dec] * 3, street_labels())[-1]
    np.testing.assert_array_equal(final, dec)
    # a wider limit admits the L (0.62 m) but not the blob (1 m)
    wide = _frames([dec] * 3, street_labels(), UnmappedParams(max_width_m=0.7, min_age_s=0.1))[-1]
    want = dec.copy()
    want[12, 2] = want[12, 3] = want[13, 3] = D["unmapped"]
    np.testing.assert_array_equal(wide, want)


def test_road_cells_and_components_touching_the_road_stay() -> None:
    dec = free_window()
    dec[3, 4] = D["stopped"]                 # a pole-sized thing on the road
    dec[4:8, 10] = D["static"]               # a thin strip across the kerb (rows 4-5 road):
    # one component with road cells: none of it is relabelled, not even rows 6-7
    final = _frames([dec] * 3, street_labels())[-1]
    np.testing.assert_array_equal(final, dec)


def test_facade_returns_next_to_a_building_stay() -> None:
    dec = free_window()
    dec[10, 15] = D["static"]                # 8-next to the building cell (11, 16)
    dec[8, 15] = D["static"]                 # two cells from it: furniture
    final = _frames([dec] * 3, street_labels())[-1]
    want = dec.copy()
    want[8, 15] = D["unmapped"]
    np.testing.assert_array_equal(final, want)


def test_a_cell_once_moving_stays() -> None:
    moving, still = free_window(), free_window()
    moving[8, 3] = D["moving"]               # seen moving at frame 0 (a pedestrian) ...
    still[8, 3] = D["static"]                # ... then standing
    still[8, 9] = D["static"]                # a pole nearby, never moving
    final = _frames([moving, still, still, still], street_labels())[-1]
    want = still.copy()
    want[8, 9] = D["unmapped"]
    np.testing.assert_array_equal(final, want)
    # with the object list: the cell was decided moving but was in no moving object (a pole
    # flagged at first sight): relabelled; a cell of a moving object is not
    no_objects = [np.zeros(0, np.int64)] * 4
    final = _frames([moving, still, still, still], street_labels(), moving_cells=no_objects)[-1]
    want[8, 3] = D["unmapped"]
    np.testing.assert_array_equal(final, want)
    in_object = [np.array([8 * SHAPE[1] + 9])] + no_objects[1:]
    final = _frames([still] * 4, street_labels(), moving_cells=in_object)[-1]
    want = still.copy()
    want[8, 3] = D["unmapped"]               # (8, 9) was in a moving object at frame 0
    np.testing.assert_array_equal(final, want)


def test_component_with_a_cell_once_moving_stays_whole() -> None:
    first, later = free_window(), free_window()
    first[8, 3] = D["moving"]
    later[8, 3:6] = D["static"]              # the moving cell's component: all of it stays
    final = _frames([first, later, later], street_labels())[-1]
    np.testing.assert_array_equal(final, later)


def test_age_pauses_on_unknown_and_restarts_on_free() -> None:
    static, unknown, free = free_window(), free_window(), free_window()
    static[8, 3] = D["static"]
    unknown[8, 3] = D["unknown"]
    # static (age 0), unknown (holds 0), static (0.1): relabelled at the third frame
    assert _frames([static, unknown, static], street_labels())[-1][8, 3] == D["unmapped"]
    # static (0), free (reset), static (0 again): not yet
    assert _frames([static, free, static], street_labels())[-1][8, 3] == D["static"]
    # a longer minimum age: 0, 0.1, 0.2, 0.3 -> relabelled at the fourth frame only
    slow = UnmappedParams(max_width_m=0.55, min_age_s=0.3)
    got = [f[8, 3] for f in _frames([static] * 4, street_labels(), slow)]
    assert got == [D["static"]] * 3 + [D["unmapped"]]


def test_without_a_map_nothing_changes() -> None:
    dec = free_window()
    dec[8, 3] = D["static"]
    dec[9, 2:14] = D["stopped"]
    final = _frames([dec] * 3, None)[-1]
    np.testing.assert_array_equal(final, dec)


def test_state_follows_the_window_and_resets_entering_cells() -> None:
    """A pole at world cell (lattice) (20, 33): window A at (12, 30), then B shifted by
    (1, 2): the pole is at window (8, 3) then (7, 1); its age carries over the move."""
    cue = UnmappedCue(PARAMS, SHAPE, RES)
    state = UnmappedState.fresh(SHAPE)
    labels = np.full(SHAPE, CONTEXT_OTHER, np.uint8)
    a = free_window()
    a[8, 3] = D["static"]
    cue.step(state, a.copy(), labels, DT, offset=(0, 0), shift=(0, 0))
    b = free_window()
    b[7, 1] = D["static"]
    offset = (1, 2)  # FusionState.move_to: (0 + 1) % 14, (0 + 2) % 20
    cue.step(state, b, labels, DT, offset=offset, shift=(1, 2))
    assert b[7, 1] == D["unmapped"]
    # the window moves back west by 19 columns: every column enters, the state is reset
    c = free_window()
    c[7, 1] = D["static"]
    cue.step(state, c, labels, DT, offset=(1, (2 - 19) % 20), shift=(0, -19))
    assert c[7, 1] == D["static"]


def _reference(seq, params, res, ages=None):
    """Plain reference over (window, decision, labels, moving mask) frames: ages and moved
    flags in a dict of lattice cells (a cell leaving the window forgets its state),
    components by scipy.ndimage.label, the width by numpy over the same 16 orientations.
    ``ages``: a list that receives each frame's ages (window order, −1 where none)."""
    age: dict[tuple[int, int], float] = {}
    moved: set[tuple[int, int]] = set()
    theta = np.arange(16) * (math.pi / 16)
    outs = []
    for win, dec, labels, mov in seq:
        inside = {(win.row0 + r, win.col0 + c) for r in range(win.rows) for c in range(win.cols)}
        age = {k: v for k, v in age.items() if k in inside}
        moved &= inside
        for r in range(win.rows):
            for c in range(win.cols):
                key = (win.row0 + r, win.col0 + c)
                d = dec[r, c]
                if d in (D["moving"], D["static"], D["stopped"], D["unmapped"]):
                    age[key] = 0.0 if age.get(key, -1.0) < 0 else np.float32(
                        np.float32(age[key]) + np.float32(DT))
                elif d == D["free"]:
                    age[key] = -1.0
                if mov[r, c]:
                    moved.add(key)
        if ages is not None:
            ages.append(np.array([[age.get((win.row0 + r, win.col0 + c), -1.0)
                                   for c in range(win.cols)] for r in range(win.rows)],
                                 np.float32))
        out = dec.copy()
        cand = np.isin(dec, [D["static"], D["stopped"], D["unmapped"]])
        comp, n = ndimage.label(cand, structure=np.ones((3, 3)))
        building = ndimage.binary_dilation(labels == CONTEXT_BUILDING,
                                           structure=np.ones((3, 3)))
        for k in range(1, n + 1):
            rr, cc = np.nonzero(comp == k)
            p = cc[:, None] * np.cos(theta) + rr[:, None] * np.sin(theta)
            extent = p.max(axis=0) - p.min(axis=0)
            thin = int(np.flatnonzero(extent < extent.min() + 1e-9)[0])
            width = len(rr) / (extent[(thin + 8) % 16] + 1.0)
            keys = [(win.row0 + r, win.col0 + c) for r, c in zip(rr, cc, strict=True)]
            if (width <= params.max_width_m / res + 1e-9
                    and not (labels[rr, cc] == CONTEXT_ROAD).any()
                    and not building[rr, cc].any() and not any(key in moved for key in keys)):
                for r, c in zip(rr, cc, strict=True):
                    if (labels[r, c] == CONTEXT_OTHER
                            and age[(win.row0 + r, win.col0 + c)] >= params.min_age_s - 1e-3):
                        out[r, c] = D["unmapped"]
            # step 4: stopped needs the road or motion; step 5: a façade is not stopped
            never_moved = not any(key in moved for key in keys)
            if ((params.stopped_needs_road and not (labels[rr, cc] == CONTEXT_ROAD).any()
                 and never_moved)
                    or (params.stopped_off_facades and building[rr, cc].any() and never_moved
                        and width <= params.max_width_m / res + 1e-9)):
                left = out[rr, cc] == D["stopped"]
                out[rr[left], cc[left]] = D["static"]
        outs.append(out)
    return outs


def _scrolled(params: UnmappedParams, shape: tuple[int, int], origin: tuple[int, int],
              frames: int, shift_at, frame_at):
    """The cue over a window scrolled from ``origin`` (row0, col0) by ``shift_at(k)`` before
    frame k, whose decision and labels are ``frame_at(k, window)``: the frames as
    :func:`_reference` reads them, the relabelled decisions, and the ages in window order
    after each frame."""
    cue = UnmappedCue(params, shape, RES)
    state = UnmappedState.fresh(shape)
    win = Window(RES, *shape, *origin)
    offset = (0, 0)
    seq, got, got_ages = [], [], []
    for k in range(frames):
        shift = shift_at(k)
        win = Window(RES, *shape, win.row0 + shift[0], win.col0 + shift[1])
        offset = ((offset[0] + shift[0]) % shape[0], (offset[1] + shift[1]) % shape[1])
        dec, labels = frame_at(k, win)
        seq.append((win, dec.copy(), labels, dec == D["moving"]))
        cue.step(state, dec, labels, DT, offset=offset, shift=shift)
        got.append(dec)
        rows_at = (np.arange(shape[0]) + offset[0]) % shape[0]
        cols_at = (np.arange(shape[1]) + offset[1]) % shape[1]
        got_ages.append(state.age_s[np.ix_(rows_at, cols_at)].copy())  # window order
    return seq, got, got_ages


@pytest.mark.parametrize(("stopped_needs_road", "stopped_off_facades", "unknown_margins"),
                         [(False, False, False), (True, False, False), (False, True, False),
                          (True, True, False), (False, False, True), (True, True, True)])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_shifting_windows_match_the_reference(seed: int, stopped_needs_road: bool,
                                                     stopped_off_facades: bool,
                                                     unknown_margins: bool) -> None:
    """The relabelled decisions and the ages (the state, cell by cell) against the plain
    reference. ``unknown_margins``: each row's first and last 0-3 cells decided unknown in
    every frame (the window's edges beyond the sensor's range), where a cell's age must
    pause."""
    rng = np.random.default_rng(seed)
    shape = (12, 15)
    codes = np.array([D["free"], D["unknown"], D["static"], D["stopped"], D["moving"],
                      D["infrastructure"]])
    # the decisions of a world of 200 x 200 cells, each frame 10 % of them drawn anew
    # (mostly free, so that components stay small and varied, and old enough to be relabelled)
    p = [0.6, 0.12, 0.12, 0.08, 0.03, 0.05]
    world = rng.choice(np.array([CONTEXT_OTHER, CONTEXT_ROAD, CONTEXT_BUILDING], np.uint8),
                       size=(200, 200), p=[0.8, 0.15, 0.05])
    world_dec = rng.choice(codes, size=(200, 200), p=p).astype(np.uint8)
    params = UnmappedParams(max_width_m=0.8, min_age_s=0.2,
                            stopped_needs_road=stopped_needs_road,
                            stopped_off_facades=stopped_off_facades)

    def shift_at(k: int) -> tuple[int, int]:
        if k == 12:
            rng.integers(-2, 3, size=2)  # drawn as every frame's, then replaced
            return (0, 20)  # a jump: every cell enters
        return (0, 0) if k == 0 else tuple(int(v) for v in rng.integers(-2, 3, size=2))

    def frame_at(k: int, win: Window) -> tuple[np.ndarray, np.ndarray]:
        redraw = rng.random(world_dec.shape) < 0.1
        world_dec[redraw] = rng.choice(codes, size=int(redraw.sum()), p=p)
        at = (slice(win.row0, win.row0 + shape[0]), slice(win.col0, win.col0 + shape[1]))
        dec, labels = world_dec[at].copy(), world[at].copy()
        if unknown_margins:
            for r in range(shape[0]):
                lo, hi = (int(v) for v in rng.integers(0, 4, size=2))
                dec[r, :lo] = D["unknown"]
                dec[r, shape[1] - hi:] = D["unknown"]
        return dec, labels

    seq, got, got_ages = _scrolled(params, shape, (80, 80), 30, shift_at, frame_at)
    want_ages: list[np.ndarray] = []
    want = _reference(seq, params, RES, want_ages)
    for k, (g, w) in enumerate(zip(got_ages, want_ages, strict=True)):  # the state, exactly
        np.testing.assert_array_equal(g, w, err_msg=f"ages, frame {k}")
    relabelled = unstopped = 0
    for k, ((_, dec, _, _), g, w) in enumerate(zip(seq, got, want, strict=True)):
        np.testing.assert_array_equal(g, w, err_msg=f"frame {k}")
        relabelled += int((w == D["unmapped"]).sum())
        unstopped += int(((dec == D["stopped"]) & (w == D["static"])).sum())
    assert relabelled > 50  # the test exercises the relabelling (97-167 cells on seeds 0-2)
    # ... and steps 4 and 5 when on (they turn stopped cells static), never when off
    assert (unstopped > 50) if stopped_needs_road else (unstopped > 0) == stopped_off_facades
    if stopped_off_facades:  # step 5 changes cells that step 4 alone leaves stopped
        without = _reference(seq, replace(params, stopped_off_facades=False), RES)
        assert sum(int((w != v).sum()) for w, v in zip(want, without, strict=True)) > 10


@pytest.mark.parametrize("seed", [0, 1])
def test_sparse_windows_skipped_word_by_word_match_the_reference(seed: int) -> None:
    """A window like a drive's: nine in ten of its 8-cell words decided only unknown or free,
    which the components' scan skips on one test of the word, with a few static, stopped
    and unmapped cells between them (a pole, a car's face, a cell at a word's edge) — the
    relabels and the ages against the plain reference, on a scrolling window."""
    rng = np.random.default_rng(100 + seed)
    shape = (10, 64)
    codes = np.array([D["free"], D["unknown"], D["static"], D["stopped"], D["unmapped"],
                      D["moving"]])
    p = [0.6, 0.385, 0.006, 0.004, 0.003, 0.002]
    world = rng.choice(np.array([CONTEXT_OTHER, CONTEXT_ROAD, CONTEXT_BUILDING], np.uint8),
                       size=(100, 200), p=[0.85, 0.13, 0.02])
    world_dec = rng.choice(codes, size=world.shape, p=p).astype(np.uint8)
    params = UnmappedParams(max_width_m=0.8, min_age_s=0.2, stopped_needs_road=True,
                            stopped_off_facades=True)
    low_words: list[float] = []

    def frame_at(k: int, win: Window) -> tuple[np.ndarray, np.ndarray]:
        at = (slice(win.row0, win.row0 + shape[0]), slice(win.col0, win.col0 + shape[1]))
        dec = world_dec[at].copy()
        low_words.append(float((dec.reshape(-1, 8) <= D["free"]).all(axis=1).mean()))
        return dec, world[at].copy()

    seq, got, got_ages = _scrolled(
        params, shape, (40, 60), 25,
        lambda k: (0, 0) if k == 0 else tuple(int(v) for v in rng.integers(-1, 2, size=2)),
        frame_at)
    assert min(low_words) > 0.8  # the skipped words are most of the window
    want_ages: list[np.ndarray] = []
    want = _reference(seq, params, RES, want_ages)
    for k, (g, w) in enumerate(zip(got_ages, want_ages, strict=True)):
        np.testing.assert_array_equal(g, w, err_msg=f"ages, frame {k}")
    changed = 0
    for k, ((_, dec, _, _), g, w) in enumerate(zip(seq, got, want, strict=True)):
        np.testing.assert_array_equal(g, w, err_msg=f"frame {k}")
        changed += int((w != dec).sum())
    assert changed > 20  # relabels and stopped cells turned static happen between the skips


def test_moving_object_cells_takes_the_moving_records_only() -> None:
    objects = np.zeros(3, OBJECT_DTYPE)
    objects["state"] = [OBJECT_STATES["moving"], OBJECT_STATES["stopped"],
                        OBJECT_STATES["moving"]]
    objects["cell_count"] = [2, 3, 1]
    cells = np.array([5, 6, 10, 11, 12, 40], np.uint32)
    np.testing.assert_array_equal(moving_object_cells(objects, cells), [5, 6, 40])
    assert moving_object_cells(None, None) is None


def test_state_round_trips_through_the_checkpoint_arrays() -> None:
    state = UnmappedState.fresh(SHAPE)
    state.age_s[3, 4] = 1.25
    state.moved[5, 6] = 1
    back = UnmappedState.from_arrays(state.to_arrays())
    np.testing.assert_array_equal(back.age_s, state.age_s)
    np.testing.assert_array_equal(back.moved, state.moved)
    assert UnmappedState.from_arrays({}) is None


def test_checkpoint_keeps_the_state(tmp_path: Path) -> None:
    from evperc.runner import FusionState

    fusion = FusionState.fresh(Window(RES, *SHAPE, 0, 0))
    fusion.prev_ns = 5
    fusion.unmapped = UnmappedState.fresh(SHAPE)
    fusion.unmapped.age_s[1, 2] = 0.7
    fusion.unmapped.moved[2, 3] = 1
    fusion.save(tmp_path / "c.npz")
    back = FusionState.load(tmp_path / "c.npz")
    np.testing.assert_array_equal(back.unmapped.age_s, fusion.unmapped.age_s)
    np.testing.assert_array_equal(back.unmapped.moved, fusion.unmapped.moved)
    snap = fusion.snapshot()
    fusion.unmapped.age_s[1, 2] = 9.0  # later frames do not change the snapshot
    assert snap.unmapped.age_s[1, 2] == np.float32(0.7)


# --- configuration ------------------------------------------------------------------------

def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "user.toml"
    path.write_text(text)
    return path


def test_defaults_turn_the_cue_on_and_read_its_keys() -> None:
    config = load_config()
    assert unmapped_enabled(config)
    assert UnmappedParams.from_config(config) == UnmappedParams(
        0.55, 0.1, unmapped=True, stopped_needs_road=True, stopped_off_facades=True)


@pytest.mark.parametrize(("text", "message"), [
    ("unmapped_max_width_m = 0.0", r"objects.unmapped_max_width_m = 0.0 is outside \(0.0, "),
    ("unmapped_max_width_m = -1.0", r"objects.unmapped_max_width_m = -1.0 is outside"),
    ("unmapped_min_age_s = -0.1", r"objects.unmapped_min_age_s = -0.1 is outside \[0.0, "),
    ('unmapped_min_age_s = "long"', r"objects.unmapped_min_age_s must be float, got str"),
    ('unmapped_cue = "yes"', r"objects.unmapped_cue must be bool, got str"),
    ("stopped_off_facades = 1", r"objects.stopped_off_facades must be bool, got int"),
    ("unmapped_max_length_m = 3.0", r"unknown key objects.unmapped_max_length_m"),
])
def test_bad_values_are_named(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_config(_write(tmp_path, f"[objects]\n{text}\n"))


def test_paper_preset_has_no_cue(tmp_path: Path) -> None:
    assert not unmapped_enabled(load_config(preset="kurdej2013"))
    # the preset's file says so itself (not inherited from a default that may change)
    text = (Path(__file__).resolve().parents[2] / "configs" / "kurdej2013.toml").read_text()
    assert "unmapped_cue = false" in text
    # an old run's config without the key (a manifest on resume): off
    assert not unmapped_enabled({"objects": {"enabled": True}})


def test_interrupted_map_run_resumes_with_the_same_relabels(tmp_path: Path) -> None:
    """sample_data with its map (the cue relabels there): interrupted after frame 25, resumed
    from the checkpoint at frame 20, the decisions equal those of the uninterrupted run."""
    import evperc
    from evperc.runner import RunRequest, request_from_manifest, run

    sample = Path(__file__).resolve().parents[2] / "sample_data"
    config = load_config(overrides={"output.chunk_frames": 10, "output.checkpoint_frames": 10})

    def request(out: Path) -> RunRequest:
        return RunRequest(log_path=sample / "drive.mcap", map_path=sample / "map.geojson",
                          out_dir=out, config=config, end_s=4.0)

    run(request(tmp_path / "full"))
    seen: list[int] = []

    def stop(frame: dict) -> None:
        seen.append(frame["stamp_ns"])
        if len(seen) == 25:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run(request(tmp_path / "part"), on_frame=stop)
    assert json.loads((tmp_path / "part" / "manifest.json").read_text())["frame_count"] == 20
    with np.load(tmp_path / "part" / "checkpoint_000000020.npz") as npz:
        assert "unmapped_age_s" in npz.files and (npz["unmapped_age_s"] > 0).any()
    run(request_from_manifest(tmp_path / "part"), resume=True)
    full, part = evperc.load(tmp_path / "full"), evperc.load(tmp_path / "part")
    relabelled_after_resume = 0
    for a, b in zip(full.frames, part.frames, strict=True):
        np.testing.assert_array_equal(a.decision, b.decision)
        np.testing.assert_array_equal(a.decision_counts, np.bincount(
            b.decision.ravel(), minlength=len(D)))  # the counts are of the stored decision
        if a.index >= 20:
            relabelled_after_resume += int((a.decision == D["unmapped"]).sum())
    assert relabelled_after_resume > 0
