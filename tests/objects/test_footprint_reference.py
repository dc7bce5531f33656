"""The compiled footprint completion and fragment merge (evperc.objects.footprint) against
the per-object numpy version they replaced (tests/objects/reference_footprint.py) on
randomised multi-frame object lists: records, cells (values and order) and the checkpoint
arrays equal to the byte after every frame (same floating-point operations in the same
order, so no tolerance)."""

from __future__ import annotations

import numpy as np
import pytest

from evperc.geo.window import Window
from evperc.objects import footprint as fast
from evperc.output.objects import OBJECT_DTYPE, OBJECT_STATES
from tests.objects import reference_footprint as ref


def _frame(rng: np.random.Generator, shape: tuple[int, int], tracks: dict[int, list]
           ) -> tuple[np.ndarray, np.ndarray]:
    """An object list: each live track a rectangle of cells moving with its velocity (with
    jitter), clusters disjoint (a cell goes to the first object drawing it), some near one
    another (fragments), some touching the window's edge, some with no cell."""
    rows, cols = shape
    used = np.zeros(rows * cols, bool)
    recs, cells = [], []
    for tid, tr in tracks.items():
        tr[0] += tr[2] + rng.normal(0, 0.5)
        tr[1] += tr[3] + rng.normal(0, 0.5)
        r0, c0 = int(tr[0]) % rows, int(tr[1]) % cols
        h, w = rng.integers(1, 6, 2)
        rr, cc = np.meshgrid(np.arange(r0, min(rows, r0 + h)), np.arange(c0, min(cols, c0 + w)),
                             indexing="ij")
        flat = (rr * cols + cc).reshape(-1)
        flat = flat[rng.random(len(flat)) < 0.85]
        rng.shuffle(flat)
        flat = flat[~used[flat]]
        if rng.random() < 0.05:
            flat = flat[:0]
        used[flat] = True
        rec = np.zeros(1, OBJECT_DTYPE)
        rec["track_id"] = tid
        rec["state"] = OBJECT_STATES["moving"] if rng.random() < 0.8 else OBJECT_STATES["stopped"]
        rec["cell_count"] = len(flat)
        rec["age_frames"] = rng.integers(1, 6)
        rec["velocity_m_per_s"] = (tr[3] + rng.normal(0, 1), tr[2] + rng.normal(0, 1))
        rec["centroid_m"] = rng.normal(0, 10, 2)
        rec["bbox_m"] = rng.normal(0, 10, 4)
        rec["mean_betp_moving"] = rng.random()
        recs.append(rec)
        cells.append(flat)
    order = rng.permutation(len(recs))
    objects = (np.concatenate([recs[k] for k in order]) if recs
               else np.zeros(0, OBJECT_DTYPE))
    flat = (np.concatenate([cells[k] for k in order]).astype(np.uint32) if cells
            else np.zeros(0, np.uint32))
    return objects, flat


def _state_equal(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> None:
    assert a.keys() == b.keys()
    for key in a:
        assert a[key].dtype == b[key].dtype and a[key].shape == b[key].shape, key
        assert a[key].tobytes() == b[key].tobytes(), key


@pytest.mark.parametrize("seed", range(16))
def test_footprints_equal_the_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(8, 60)), int(rng.integers(8, 60)))
    res = float(rng.choice([0.2, 0.3, 0.5]))
    frames = int(rng.integers(1, 10))
    gap = int(rng.choice([0, 1, 2, 3]))
    extent = float(rng.choice([1.0, 2.0, 6.0, 20.0]))
    p_fast = fast.FootprintParams(frames=frames, fragment_gap_cells=gap, fragment_extent_m=extent)
    p_ref = ref.FootprintParams(frames=frames, fragment_gap_cells=gap, fragment_extent_m=extent)
    s_fast, s_ref = fast.FootprintState(), ref.FootprintState()
    tracks: dict[int, list] = {}
    next_id = 1
    row0, col0 = int(rng.integers(-500, 500)), int(rng.integers(-500, 500))
    stamp = int(rng.integers(0, 10**12))
    merges = grown = 0
    for k in range(60):
        for tid in [t for t in tracks if rng.random() < 0.08]:  # tracks end
            del tracks[tid]
        for _ in range(int(rng.poisson(0.8 if len(tracks) < 8 else 0.1))):  # tracks begin
            tracks[next_id] = [rng.uniform(0, shape[0]), rng.uniform(0, shape[1]),
                               rng.normal(0, 1.5), rng.normal(0, 1.5)]
            next_id += 1
        if rng.random() < 0.3:  # the window drifts
            row0 += int(rng.integers(-3, 4))
            col0 += int(rng.integers(-3, 4))
        stamp += int(rng.choice([0, 50_000_000, 100_000_000, 100_000_001, 300_000_000]))
        window = Window(res, shape[0], shape[1], row0, col0)
        objects, cells = _frame(rng, shape, tracks)
        speaks = rng.random(shape) < rng.choice([0.0, 0.3, 0.7])
        # the runner's form: the sensor grid's m(F), m(O) layers, speaking where either > 0
        free = (rng.random(shape) * (speaks & (rng.random(shape) < 0.5))).astype(np.float32)
        occupied = np.where(speaks & (free == 0), np.float32(0.25), np.float32(0.0))
        layers = (free, occupied) if k % 2 else speaks
        if k == 30:  # a checkpoint round trip mid-drive
            s_fast = fast.FootprintState.from_arrays(s_fast.to_arrays())
            s_ref = ref.FootprintState.from_arrays(s_ref.to_arrays())
        before = (objects.tobytes(), cells.tobytes())
        r_ref, c_ref = ref.complete_footprints(s_ref, objects, cells, window, stamp, speaks, p_ref)
        r_fast, c_fast = fast.complete_footprints(s_fast, objects, cells, window, stamp, layers,
                                                  p_fast)
        assert (objects.tobytes(), cells.tobytes()) == before  # inputs unchanged
        assert r_fast.dtype == r_ref.dtype and r_fast.shape == r_ref.shape, k
        assert r_fast.tobytes() == r_ref.tobytes(), k
        assert c_fast.dtype == c_ref.dtype and c_fast.tobytes() == c_ref.tobytes(), k
        _state_equal(s_fast.to_arrays(), s_ref.to_arrays())
        assert s_fast.history.keys() == s_ref.history.keys()
        merges += len(r_ref) < len(objects)
        grown += len(c_ref) > len(cells)
    # the drive exercised the completion (and, with a gap, usually the merge)
    assert grown > 0


def test_the_random_drives_merge_fragments() -> None:
    """Not a vacuous comparison: over the seeds, fragments are merged in some frames."""
    merged = 0
    for seed in range(16):
        rng = np.random.default_rng(1000 + seed)
        shape = (30, 30)
        window = Window(0.5, *shape, 0, 0)
        p = ref.FootprintParams(frames=4, fragment_gap_cells=2, fragment_extent_m=6.0)
        state = ref.FootprintState()
        tracks = {t: [rng.uniform(0, 30), rng.uniform(0, 30), 0.5, 0.5] for t in range(1, 9)}
        for k in range(10):
            objects, cells = _frame(rng, shape, tracks)
            out, _ = ref.complete_footprints(state, objects, cells, window,
                                             k * 100_000_000, np.zeros(shape, bool), p)
            merged += len(out) < len(objects)
    assert merged > 0


def test_from_arrays_reads_ungrouped_entries_as_the_reference() -> None:
    """A checkpoint whose entries are not grouped by track (not written by to_arrays, but
    readable by the old from_arrays): the same history and the same arrays back."""
    arrays = {"footprint_id": np.array([5, 3, 5, 3, 9], np.int64),
              "footprint_stamp": np.array([1, 2, 3, 4, 5], np.int64),
              "footprint_n": np.array([2, 1, 0, 3, 1], np.int64),
              "footprint_xy": np.arange(14, dtype=np.float64).reshape(7, 2)}
    a, b = fast.FootprintState.from_arrays(arrays), ref.FootprintState.from_arrays(arrays)
    assert a is not None and b is not None
    _state_equal(a.to_arrays(), b.to_arrays())
    assert list(a.history) == list(b.history) == [5, 3, 9]
    for tid in b.history:
        for (t1, x1), (t2, x2) in zip(a.history[tid], b.history[tid], strict=True):
            assert t1 == t2 and x1.tobytes() == x2.tobytes() and x1.shape == x2.shape
