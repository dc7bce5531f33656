"""objects.moving_needs_object (evperc.objects.stage.unfill_unconfirmed): a cell stays decided
moving only in a moving object's cells, on the frame's final object list — hand-made grids
worked out in the comments, and whole runs of the sample drive with the option off and on
compared frame by frame (the rule checked on the outputs alone)."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import evperc
from evperc.config import load_config
from evperc.fusion.twin import DECISION_CODES as D
from evperc.objects.stage import unfill_unconfirmed
from evperc.runner import RunRequest, run
from tests.objects.unheld import unheld_static


def test_moving_cells_outside_the_moving_objects_are_decided_static() -> None:
    dec = np.full((4, 5), D["free"], np.uint8)
    dec[0, 0:2] = D["moving"]        # flat 0, 1: a moving object's cells
    dec[2, 3] = D["moving"]          # flat 13: no object holds it
    dec[3, 4] = D["moving"]          # flat 19: nor this one
    dec[1, 1] = D["stopped"]         # flat 6: not moving, untouched
    expected = dec.copy()
    expected[2, 3] = expected[3, 4] = D["static"]
    assert unfill_unconfirmed(dec, np.array([1, 0, 6], np.int64)) == 2
    np.testing.assert_array_equal(dec, expected)
    assert unfill_unconfirmed(dec, np.array([1, 0], np.int64)) == 0  # nothing left
    dec[0, 0] = D["moving"]
    assert unfill_unconfirmed(dec, None) == 2  # no object list: no cell keeps moving
    assert not (dec == D["moving"]).any()


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 4), st.integers(1, 40), st.data())
def test_the_compiled_scan_is_the_rule_on_random_grids(rows: int, cols: int,
                                                        data: st.DataObject) -> None:
    """Random grids of every width (whole 8-cell words, a tail after them, moving cells
    in any byte of a word), against the rule in numpy (np.isin the oracle)."""
    codes = st.sampled_from([D["free"], D["moving"], D["static"], D["unknown"]])
    dec = data.draw(arrays(np.uint8, (rows, cols), elements=codes))
    held = data.draw(arrays(np.int64, st.integers(0, 12),
                            elements=st.integers(0, rows * cols - 1)))
    expected = dec.copy().reshape(-1)
    moving = np.flatnonzero(expected == D["moving"])
    unheld = moving[~np.isin(moving, held)]
    expected[unheld] = D["static"]
    assert unfill_unconfirmed(dec, held) == len(unheld)
    np.testing.assert_array_equal(dec.reshape(-1), expected)


def test_a_small_groups_cells_are_left_to_their_own_rule() -> None:
    dec = np.full((4, 5), D["free"], np.uint8)
    dec[0, 0] = dec[2, 3] = dec[3, 4] = D["moving"]  # flat 0, 13, 19
    # 0: an object's; 13: a small group's (kept); 19: neither (static)
    assert unfill_unconfirmed(dec, np.array([0], np.int64), np.array([13], np.int64)) == 1
    assert np.flatnonzero(dec == D["moving"]).tolist() == [0, 13]
    assert dec[3, 4] == D["static"]


@pytest.fixture(scope="module")
def sample_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[tuple, list]:
    """The sample drive (8 s, with its map), option off and on, causal and with lag 6, with
    the small-group rule (3 cells, the default) and without it (0: no group is exempt)."""
    root = Path(__file__).resolve().parents[2] / "sample_data"
    tmp = tmp_path_factory.mktemp("needs_object")
    frames = {}
    for needs, lag, small in itertools.product((False, True), (0, 6), (0, 3)):
        config = load_config(overrides={"objects.moving_needs_object": needs,
                                        "objects.backfill_frames": lag,
                                        "objects.moving_min_cluster_cells": small})
        out = tmp / f"{needs}-{lag}-{small}"
        run(RunRequest(log_path=root / "drive.mcap", out_dir=out, config=config,
                       map_path=root / "map.geojson", end_s=8.0), progress=False)
        frames[needs, lag, small] = list(evperc.load(out).frames)
    return frames


@pytest.mark.parametrize("lag", [0, 6])
@pytest.mark.parametrize("small", [0, 3])
def test_only_the_moving_objects_cells_stay_moving(sample_runs: dict, lag: int,
                                                   small: int) -> None:
    """Against the run without the option: masses, objects equal; the decision differs only
    on cells decided moving there that no moving record of the frame holds, now ``static``
    — without the small-group rule on every such cell (no group is exempt), with it on a
    part (the small groups' cells keep their decision); the stored per-frame counts are
    those of the stored decision; and the option removed some cells (the sample drive has
    conflict no track confirms)."""
    off, on = sample_runs[False, lag, small], sample_runs[True, lag, small]
    assert len(off) == len(on) > 50
    removed = kept = 0
    for a, b in zip(off, on, strict=True):
        unheld, changed = unheld_static(a, b)
        db = np.asarray(b.decision)
        if small == 0:
            assert (changed == unheld).all()
        kept += int((unheld & ~changed).sum())
        np.testing.assert_array_equal(
            b.decision_counts, np.bincount(db.ravel(), minlength=len(b.decision_counts)))
        removed += int(changed.sum())
    assert removed > 0
    if small:
        assert kept > 0  # the sample drive has small moving groups the rule keeps
