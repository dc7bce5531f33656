"""The clustering and the unmapped cue against the versions they replaced
(tests/objects/reference_clusters.py, reference_unmapped.py: per-cell loops, numpy
summaries; the cells left out near buildings by numpy masks) on random windows: every
output array equal to the bit (same operations per cell, so no tolerance)."""

from __future__ import annotations

import numpy as np
import pytest

from evperc.fusion.twin import DECISION_CODES as D
from evperc.geo.window import Window
from evperc.objects.clusters import Clusterer, ClusterParams
from evperc.objects.unmapped import UnmappedCue, UnmappedParams, UnmappedState
from tests.objects import reference_clusters as ref_clusters
from tests.objects import reference_unmapped as ref_unmapped

CODES = np.array(sorted(D.values()), np.uint8)


def _decision(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """Blobs of occupied decisions on free / unknown, with noise (a code per cell drawn
    with weights; then squares of one code)."""
    p = rng.dirichlet(np.ones(len(CODES)))
    dec = rng.choice(CODES, shape, p=p).astype(np.uint8)
    for _ in range(int(rng.integers(0, 30))):
        r, c = rng.integers(0, shape[0]), rng.integers(0, shape[1])
        h, w = rng.integers(1, 6, 2)
        dec[r:r + h, c:c + w] = rng.choice(CODES)
    return dec


@pytest.mark.parametrize("seed", range(10))
def test_clusters_equal_the_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(1, 90)), int(rng.integers(1, 90)))
    for seeds_mode in ("occupied", "moving"):
        params = ClusterParams(min_cells=int(rng.integers(1, 5)),
                               max_extent_m=float(rng.choice([1.0, 3.0, 20.0])),
                               seed_conflict_fo=float(rng.choice([0.0, 0.3, 0.8])),
                               seeds=seeds_mode,
                               keep_tracked_small=bool(rng.random() < 0.5),
                               isolated_min_cells=int(rng.choice([0, 1, 2, 3])),
                               isolated_clearance_m=float(rng.choice([0.3, 0.5, 1.0, 2.0])),
                               small_conflict_min_cells=int(rng.choice([0, 1, 2, 3])),
                               isolated_min_height_m=float(rng.choice([0.0, 0.4, 1.5])),
                               off_buildings=bool(rng.random() < 0.7),
                               off_buildings_small_m=float(rng.choice([0.0, 0.5, 1.0, 2.0])),
                               off_buildings_max_height_m=float(rng.choice([0.0, 1.0, 2.2])))
        new = Clusterer(params, shape)
        old = ref_clusters.Clusterer(ref_clusters.ClusterParams(**params.__dict__), shape)
        for _ in range(5):
            dec = _decision(rng, shape)
            betp = rng.integers(0, 256, shape).astype(np.uint8)
            fo = rng.integers(0, 256, shape).astype(np.uint8)
            now = rng.random(shape) < rng.random()
            extra = rng.integers(-5, shape[0] * shape[1] + 5, int(rng.integers(0, 40)))
            window = Window(float(rng.choice([0.2, 0.5, 1.0])), *shape,
                            int(rng.integers(-1000, 1000)), int(rng.integers(-1000, 1000)))
            # the widened buildings: none, scattered cells or blocks (a façade's strip)
            near = (None if rng.random() < 0.2 else rng.random(shape) < rng.random() * 0.6)
            if near is not None and rng.random() < 0.5:
                near[:, :int(rng.integers(0, shape[1] + 1))] = True
            # each cell's highest return above the ground (0: none), or no layer
            heights = (None if rng.random() < 0.2 else
                       (rng.random(shape) * 3.0 * (rng.random(shape) < 0.7)).astype(np.float32))
            a = new.clusters(dec, betp, fo, window, extra, now, heights, near_building=near)
            b = old.clusters(dec, betp, fo, window, extra, now, heights, near_building=near)
            for name in ("cells", "offsets", "centroid_m", "bbox_m", "seeds",
                         "mean_betp_moving"):
                x, y = getattr(a, name), getattr(b, name)
                assert x.dtype == y.dtype and x.shape == y.shape, name
                assert x.tobytes() == y.tobytes(), name


@pytest.mark.parametrize("seed", range(10))
def test_unmapped_cue_equals_the_reference(seed: int) -> None:
    """Several frames with the window shifting (cells entering reset, the circular
    buffer's offset wrapping), with and without labels and the object list's cells."""
    rng = np.random.default_rng(100 + seed)
    shape = (int(rng.integers(1, 70)), int(rng.integers(1, 70)))
    rows, cols = shape
    params = UnmappedParams(max_width_m=float(rng.choice([0.3, 0.55, 1.2])),
                            min_age_s=float(rng.choice([0.0, 0.1, 0.3])),
                            unmapped=bool(rng.random() < 0.8),
                            stopped_needs_road=bool(rng.random() < 0.5))
    res = 0.5
    new = UnmappedCue(params, shape, res)
    old = ref_unmapped.UnmappedCue(ref_unmapped.UnmappedParams(**params.__dict__), shape, res)
    s_new = UnmappedState.fresh(shape)
    s_old = ref_unmapped.UnmappedState.fresh(shape)
    offset = (int(rng.integers(0, rows)), int(rng.integers(0, cols)))
    labels = rng.choice([0, 1, 2], shape, p=[0.7, 0.2, 0.1]).astype(np.uint8)
    with_labels = rng.random() < 0.8
    for _ in range(8):
        shift = (int(rng.integers(-3, 4)), int(rng.integers(-3, 4)))
        if rng.random() < 0.1:
            shift = (int(rng.integers(-rows - 2, rows + 2)), int(rng.integers(-cols - 2, cols + 2)))
        offset = ((offset[0] + shift[0]) % rows, (offset[1] + shift[1]) % cols)
        dec = _decision(rng, shape)
        moving = (rng.integers(0, rows * cols, int(rng.integers(0, 20)))
                  if rng.random() < 0.5 else None)
        dt = float(rng.choice([0.0, 0.1, 0.099, 0.25]))
        lab = labels if with_labels else None
        d_new, d_old = dec.copy(), dec.copy()
        n_new = new.step(s_new, d_new, lab, dt, moving_cells=moving, offset=offset, shift=shift)
        n_old = old.step(s_old, d_old, lab, dt, moving_cells=moving, offset=offset, shift=shift)
        assert n_new == n_old
        assert d_new.tobytes() == d_old.tobytes()
        assert s_new.age_s.tobytes() == s_old.age_s.tobytes()
        assert s_new.moved.tobytes() == s_old.moved.tobytes()
        assert new.stats.tobytes() == old.stats.tobytes()


def test_unaligned_decision_views_give_the_same_clusters_and_cue() -> None:
    """The scans read the decision 8 cells a word: a window that is a view at an odd
    byte offset of a larger buffer (a chunk's frame) gives what an aligned copy gives."""
    rng = np.random.default_rng(7)
    shape = (21, 37)
    buf = np.empty(1 + shape[0] * shape[1], np.uint8)
    dec = buf[1:].reshape(shape)
    dec[:] = _decision(rng, shape)
    assert dec.ctypes.data % 8 != 0
    betp = rng.integers(0, 256, shape).astype(np.uint8)
    now = rng.random(shape) < 0.7
    window = Window(0.5, *shape, 3, -4)
    clusterer = Clusterer(ClusterParams(seeds="occupied"), shape)
    a = clusterer.clusters(dec, betp, betp, window, None, now)
    b = clusterer.clusters(dec.copy(), betp, betp, window, None, now)
    assert len(a) > 0 and a.cells.tobytes() == b.cells.tobytes()
    labels = np.zeros(shape, np.uint8)
    cue = UnmappedCue(UnmappedParams(min_age_s=0.0), shape, 0.5)
    aligned = dec.copy()
    na = cue.step(UnmappedState.fresh(shape), dec, labels, 0.1)
    nb = cue.step(UnmappedState.fresh(shape), aligned, labels, 0.1)
    assert na == nb > 0 and dec.tobytes() == aligned.tobytes()
