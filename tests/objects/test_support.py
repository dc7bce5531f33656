"""objects.small_support_frames (evperc.objects.support): a small moving group stays moving
only with motion cells near it in enough frames before and after — hand-worked sequences,
a plain set-based reference on random ones, the checkpoint round trip, and whole runs of
the sample drive with the rule off and on compared frame by frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import evperc
from evperc.config import ConfigError, load_config
from evperc.fusion.twin import DECISION_CODES as D
from evperc.geo.window import Window
from evperc.objects.support import SmallGroupSupport, SupportParams
from evperc.runner import FusionState, RunRequest, run
from tests.objects.unheld import unheld_static

COLS = 20  # every hand-worked window is 20 cells wide


def flat(row: int, col: int, row0: int = 0, col0: int = 0) -> int:
    """The flat cell of global (row, col) in a window at (row0, col0), COLS wide."""
    return (row - row0) * COLS + (col - col0)


def judged(params: SupportParams, motion: dict[int, list[tuple[int, int]]], number: int,
           small: list[tuple[int, int]], groups: list[int] | None = None) -> list[int]:
    """Push ``motion`` (frame -> global cells; window at the origin) in frame order, judge
    frame ``number``'s ``small`` cells; returns the flat cells kept."""
    support = SmallGroupSupport()
    for k in sorted(motion):
        support.push(k, 0, 0, COLS, np.array([flat(*c) for c in motion[k]], np.int64))
    cells = np.array([flat(*c) for c in small], np.int64)
    group_of = np.array(groups if groups is not None else range(len(small)), np.int64)
    return support.judge(params, number, 0, 0, COLS, cells, group_of).tolist()


def test_a_chain_of_moving_cells_supports_a_small_group() -> None:
    # a person walking east one cell a frame: frame 5's cell (10, 5) has motion within one
    # cell in frames 4 (10, 4) and 6 (10, 6); the cells two frames away are 2 cells off
    walk = {k: [(10, k)] for k in range(3, 8)}
    p = SupportParams(frames=2, reach_cells=1, min_frames=2, ahead=2)
    assert judged(p, walk, 5, [(10, 5)]) == [flat(10, 5)]
    # three frames needed: frames 3 and 7 are two cells away, beyond reach 1
    assert judged(SupportParams(2, 1, 3, 2), walk, 5, [(10, 5)]) == []
    # reach 2 takes them: four frames within reach
    assert judged(SupportParams(2, 2, 4, 2), walk, 5, [(10, 5)]) == [flat(10, 5)]
    # reach 0: no other frame holds (10, 5) itself
    assert judged(SupportParams(2, 0, 1, 2), walk, 5, [(10, 5)]) == []


def test_a_lone_hit_is_not_supported_by_its_own_frame() -> None:
    # a pole hit once: motion in frame 5 only (its own group and a cell beside it)
    lone = {5: [(10, 5), (10, 6)]}
    assert judged(SupportParams(6, 3, 1, 6), lone, 5, [(10, 5)]) == []
    # the same cells a frame later and a frame earlier: two frames
    again = {4: [(10, 5)], 5: [(10, 5)], 6: [(10, 5)]}
    assert judged(SupportParams(6, 3, 2, 6), again, 5, [(10, 5)]) == [flat(10, 5)]
    assert judged(SupportParams(6, 3, 3, 6), again, 5, [(10, 5)]) == []


def test_the_frames_read_are_bounded_before_and_after() -> None:
    motion = {1: [(10, 5)], 2: [(10, 5)], 8: [(10, 5)], 9: [(10, 5)]}
    # frame 5, L = 3: frames 2..8 — frames 2 and 8 count, 1 and 9 do not
    assert judged(SupportParams(3, 0, 2, 3), motion, 5, [(10, 5)]) == [flat(10, 5)]
    assert judged(SupportParams(3, 0, 3, 3), motion, 5, [(10, 5)]) == []
    # ahead 2 (the backfill's lag): frame 8 is three frames after, not read
    assert judged(SupportParams(3, 0, 2, 2), motion, 5, [(10, 5)]) == []
    assert judged(SupportParams(4, 0, 4, 4), motion, 5, [(10, 5)]) == [flat(10, 5)]


def test_a_group_is_kept_whole_on_its_best_cells_support() -> None:
    # a two-cell group (10, 5)-(10, 6): only (10, 6) has motion within reach 0 in two frames
    motion = {4: [(10, 6)], 6: [(10, 6)]}
    p = SupportParams(2, 0, 2, 2)
    assert judged(p, motion, 5, [(10, 5), (10, 6)], [0, 0]) == [flat(10, 5), flat(10, 6)]
    # as two groups, only the supported one
    assert judged(p, motion, 5, [(10, 5), (10, 6)], [0, 1]) == [flat(10, 6)]


def test_global_cells_follow_each_frames_window() -> None:
    # the window moves: frame 4 at origin (2, 3), frame 5 at (0, 0), frame 6 at (5, 1);
    # the motion of frames 4 and 6 is at global (10, 6), the small cell of frame 5 too
    support = SmallGroupSupport()
    support.push(4, 2, 3, COLS, np.array([flat(10, 6, 2, 3)], np.int64))
    support.push(5, 0, 0, COLS, np.array([flat(10, 6)], np.int64))
    support.push(6, 5, 1, COLS, np.array([flat(10, 6, 5, 1)], np.int64))
    kept = support.judge(SupportParams(1, 0, 2, 1), 5, 0, 0, COLS,
                         np.array([flat(10, 6)], np.int64), np.zeros(1, np.int64))
    assert kept.tolist() == [flat(10, 6)]
    # judged in a window at (1, 2): the same global cell is another flat cell
    support = SmallGroupSupport()
    support.push(4, 0, 0, COLS, np.array([flat(10, 6)], np.int64))
    support.push(6, 0, 0, COLS, np.array([flat(10, 6)], np.int64))
    kept = support.judge(SupportParams(1, 0, 2, 1), 5, 1, 2, COLS,
                         np.array([flat(10, 6, 1, 2), flat(10, 9, 1, 2)], np.int64),
                         np.array([0, 1], np.int64))
    assert kept.tolist() == [flat(10, 6, 1, 2)]


def reference(motion: dict[int, set[tuple[int, int]]], number: int,
              small: list[tuple[int, int]], groups: list[int], p: SupportParams
              ) -> list[int]:
    """The rule as written in the module docstring, with Python sets: the indices of the
    small cells kept."""
    frames_near: dict[int, set[int]] = {}
    for i, (r, c) in enumerate(small):
        for j, cells in motion.items():
            if j == number or not -p.frames <= j - number <= p.ahead:
                continue
            if any(max(abs(r - mr), abs(c - mc)) <= p.reach_cells for mr, mc in cells):
                frames_near.setdefault(groups[i], set()).add(j)
    return [i for i in range(len(small)) if len(frames_near.get(groups[i], ())) >= p.min_frames]


def test_judgements_match_the_set_reference_on_random_sequences() -> None:
    rng = np.random.default_rng(7)
    checked = kept_some = dropped_some = 0
    for _ in range(150):
        p = SupportParams(int(rng.integers(1, 7)), int(rng.integers(0, 4)),
                          int(rng.integers(1, 5)), 0)
        p = SupportParams(p.frames, p.reach_cells, p.min_frames, int(rng.integers(0, p.frames + 1)))
        n_frames = 14
        motion = {k: {(int(r), int(c)) for r, c in rng.integers(0, 12, (rng.integers(0, 5), 2))}
                  for k in range(n_frames)}
        origins = rng.integers(-6, 1, (n_frames, 2))  # every cell 0..11 in the window
        support = SmallGroupSupport()
        for k in range(n_frames):  # each frame in its own window, COLS wide
            r0, c0 = (int(v) for v in origins[k])
            cells = [flat(r, c, r0, c0) for r, c in sorted(motion[k])]
            support.push(k, r0, c0, COLS, np.array(cells, np.int64))
        for k in range(n_frames):  # judged in order, as the runner does
            small = [(int(r), int(c)) for r, c in rng.integers(0, 12, (rng.integers(0, 4), 2))]
            groups = [int(g) for g in rng.integers(0, 2, len(small))]
            r0, c0 = (int(v) for v in origins[k])
            cells = np.array([flat(r, c, r0, c0) for r, c in small], np.int64)
            got = support.judge(p, k, r0, c0, COLS, cells, np.array(groups, np.int64))
            want = cells[reference(motion, k, small, groups, p)]
            np.testing.assert_array_equal(got, want)
            checked += len(small)
            kept_some += len(want) > 0
            dropped_some += len(want) < len(small)
    assert checked > 500 and kept_some > 50 and dropped_some > 50


def test_the_checkpoint_round_trip_and_copies_keep_the_judgement() -> None:
    support = SmallGroupSupport()
    for k in range(6):
        support.push(k, k, 0, COLS, np.array([flat(10, 5, k, 0), flat(11, 5, k, 0)][:k % 3],
                                             np.int64))
    p = SupportParams(3, 1, 2, 3)
    small, groups = np.array([flat(10, 5, 3, 0)], np.int64), np.zeros(1, np.int64)
    copy = support.copy()
    back = SmallGroupSupport.from_arrays(support.to_arrays())
    assert SmallGroupSupport.from_arrays({}) is None
    support.push(6, 0, 0, COLS, np.array([flat(10, 5)], np.int64))  # not in the others
    for key, value in back.to_arrays().items():
        np.testing.assert_array_equal(value, copy.to_arrays()[key])
    # frames 1, 2, 4, 5 hold motion within one cell of (10, 5); frame 6 only in `support`
    five = SupportParams(3, 1, 5, 3)
    for s in (copy, back):
        assert s.judge(five, 3, 3, 0, COLS, small, groups).size == 0
    assert support.judge(five, 3, 3, 0, COLS, small, groups).tolist() == small.tolist()
    assert back.judge(p, 3, 3, 0, COLS, small, groups).tolist() == small.tolist()


def test_the_fusion_states_checkpoint_carries_the_support(tmp_path: Path) -> None:
    """FusionState.save / load (the run's checkpoint) keep the motion cells pushed, so that
    a resumed run judges its first frames as the uninterrupted one did."""
    state = FusionState.fresh(Window(0.5, 30, COLS, 4, -2))
    state.prev_ns = 123  # as after a frame
    state.support = SmallGroupSupport()
    state.support.push(7, 4, -2, COLS, np.array([3, 25, 41], np.int64))
    state.support.push(8, 5, -2, COLS, np.array([], np.int64))
    state.save(tmp_path / "state.npz")
    back = FusionState.load(tmp_path / "state.npz").support
    assert back is not None
    for key, value in state.support.to_arrays().items():
        np.testing.assert_array_equal(back.to_arrays()[key], value)
    assert back.to_arrays()["support_number"].tolist() == [7, 8]
    state.support = None
    state.save(tmp_path / "none.npz")
    assert FusionState.load(tmp_path / "none.npz").support is None


def test_the_keys_are_checked() -> None:
    with pytest.raises(ConfigError, match="small_support_min_frames"):
        load_config(overrides={"objects.small_support_min_frames": 0})
    with pytest.raises(ConfigError, match="small_support_frames"):
        load_config(overrides={"objects.small_support_frames": -1})
    defaults = SupportParams.from_config(load_config())
    assert defaults.enabled and defaults.ahead == min(defaults.frames, 6)
    lagless = SupportParams.from_config(load_config(overrides={"objects.backfill_frames": 0}))
    assert lagless.enabled and lagless.ahead == 0  # the past frames only


@pytest.fixture(scope="module")
def sample_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[int, list]:
    """The sample drive (12 s, with its map) with the rule off (0) and on (the default)."""
    root = Path(__file__).resolve().parents[2] / "sample_data"
    tmp = tmp_path_factory.mktemp("support")
    frames = {}
    for frames_ in (0, 6):
        config = load_config(overrides={"objects.small_support_frames": frames_})
        out = tmp / str(frames_)
        run(RunRequest(log_path=root / "drive.mcap", out_dir=out, config=config,
                       map_path=root / "map.geojson", end_s=12.0), progress=False)
        frames[frames_] = list(evperc.load(out).frames)
    return frames


def test_a_run_drops_only_unsupported_small_groups(sample_runs: dict) -> None:
    """Against the run without the rule: masses and objects equal; the decision differs only
    on cells decided moving there that no moving record holds, now ``static``; every such
    cell the rule keeps has, in the run without it, moving cells within reach in at least
    n frames of the window (that run's moving cells hold the motion cells the rule read,
    and more: the backfill's later fills); the drive has both kinds."""
    off, on = sample_runs[0], sample_runs[6]
    p = SupportParams.from_config(load_config())
    assert len(off) == len(on) > 80
    moving_off = [np.argwhere(np.asarray(f.decision) == D["moving"]) + np.array(f.origin)
                  for f in off]
    removed = kept = 0
    for k, (a, b) in enumerate(zip(off, on, strict=True)):
        unheld, changed = unheld_static(a, b)
        removed += int(changed.sum())
        for cell in np.argwhere(unheld & ~changed) + np.array(a.origin):
            frames = sum(
                1 for j in range(max(0, k - p.frames), min(len(off), k + p.ahead + 1))
                if j != k and len(moving_off[j])
                and (np.abs(moving_off[j] - cell).max(axis=1) <= p.reach_cells).any())
            assert frames >= p.min_frames
            kept += 1
    assert removed > 0 and kept > 0
