"""objects.moving_min_cluster_cells (evperc.objects.stage.small_moving_cells / unfill_small):
the fusion's moving cells of a cluster too small to be an object are decided static, unless
a moving object holds them; on hand-made frames whose outcome is worked out in the comments."""

from __future__ import annotations

import numpy as np

from evperc.config import load_config
from evperc.fusion.twin import DECISION_CODES as D
from evperc.geo.window import Window
from evperc.objects.stage import ObjectStage, block_max_at, small_moving_cells, unfill_small
from evperc.objects.tracking import TrackerState

SHAPE = (20, 30)
WIN = Window(0.5, *SHAPE, 0, 0)
Z = np.zeros(SHAPE, np.uint8)
T0 = 1_700_000_000_000_000_000


def _frame() -> tuple[np.ndarray, np.ndarray]:
    """A pole (one moving cell with a return), a pair (a moving cell and a static one, both
    with a return: a cluster of 2), a car face (a 2 x 3 block, one cell moving)."""
    dec = np.full(SHAPE, D["free"], np.uint8)
    now = np.zeros(SHAPE, bool)
    dec[2, 2] = D["moving"]
    now[2, 2] = True
    dec[5, 10] = D["moving"]
    dec[5, 11] = D["static"]
    now[5, 10:12] = True
    dec[10:12, 20:23] = D["static"]
    dec[10, 20] = D["moving"]
    now[10:12, 20:23] = True
    return dec, now


def _stage(min_cells: int) -> ObjectStage:
    config = load_config(overrides={"objects.moving_min_cluster_cells": min_cells})
    return ObjectStage(config, SHAPE)


def test_small_clusters_moving_cells_by_size() -> None:
    dec, now = _frame()
    for min_cells, expected in ((2, [2 * 30 + 2]), (3, [2 * 30 + 2, 5 * 30 + 10]),
                                (7, [2 * 30 + 2, 5 * 30 + 10, 10 * 30 + 20])):
        stage = _stage(min_cells)
        stage.step(TrackerState(), dec, Z, Z, WIN, T0, occupied_now=now)
        # the clusters are of 1, 2 and 6 cells: those below min_cells give their moving cell
        assert sorted(stage.small_moving.tolist()) == expected


def test_off_computes_nothing_and_the_static_cell_is_never_listed() -> None:
    dec, now = _frame()
    stage = _stage(0)
    assert stage.moving_min_cells == 0
    stage.step(TrackerState(), dec, Z, Z, WIN, T0, occupied_now=now)
    assert stage.small_moving.size == 0
    on = _stage(3)
    on.step(TrackerState(), dec, Z, Z, WIN, T0, occupied_now=now)
    cells, sizes = on.clusterer.groups()
    assert sorted(sizes.tolist()) == [1, 2, 6]  # every group, the 1- and 2-cell ones too
    # (5, 11) is in the pair's cluster but decided static: not a moving cell to change
    assert 5 * 30 + 11 in cells.tolist()
    assert 5 * 30 + 11 not in small_moving_cells(cells, sizes, dec, 3).tolist()


def test_unfill_small_spares_the_moving_objects_cells() -> None:
    dec, _ = _frame()
    before = dec.copy()
    small = np.array([2 * 30 + 2, 5 * 30 + 10], np.int64)
    held = np.array([5 * 30 + 10, 10 * 30 + 20], np.int64)  # a moving object holds (5, 10)
    assert unfill_small(dec, small, held) == 1
    expected = before.copy()
    expected[2, 2] = D["static"]
    np.testing.assert_array_equal(dec, expected)
    assert unfill_small(dec, np.zeros(0, np.int64), None) == 0
    assert unfill_small(dec, small, None) == 1  # (5, 10) now, (2, 2) was static already
    assert dec[5, 10] == D["static"]


def test_the_key_is_shipped_and_needs_the_object_stage() -> None:
    config = load_config()
    assert isinstance(config["objects"]["moving_min_cluster_cells"], int)
    # with the object stage off (e.g. --preset kurdej2013) nothing is computed or changed
    config["objects"]["moving_min_cluster_cells"] = 3
    assert ObjectStage({"objects": {**config["objects"], "enabled": False}},
                       SHAPE).moving_min_cells == 0


def test_with_a_height_bound_only_the_low_small_groups_are_listed() -> None:
    # objects.moving_min_height_m: the pole's cell reaches 1.5 m above the ground (a person,
    # a pole: kept moving), the pair's highest return is 0.4 m (a ground point the ground
    # split called an obstacle: static), the car face is large (never listed)
    dec, now = _frame()
    top = np.zeros(SHAPE, np.float32)
    top[2, 2] = 1.5
    top[5, 10], top[5, 11] = 0.35, 0.4
    top[10:12, 20:23] = 0.3
    config = load_config(overrides={"objects.moving_min_cluster_cells": 3,
                                    "objects.moving_min_height_m": 0.5})
    stage = ObjectStage(config, SHAPE)
    assert stage.moving_min_height == 0.5
    stage.step(TrackerState(), dec, Z, Z, WIN, T0, occupied_now=now, heights=top)
    assert stage.small_moving.tolist() == [5 * 30 + 10]
    # the group's highest cell decides, not the moving cell's own: the pair's static cell
    # at 0.6 m makes the pair tall
    top[5, 11] = 0.6
    stage.step(TrackerState(), dec, Z, Z, WIN, T0, occupied_now=now, heights=top)
    assert stage.small_moving.size == 0
    # without the layer (a run that did not ask for it) or with the bound at 0: every small
    # group, as before
    stage.step(TrackerState(), dec, Z, Z, WIN, T0, occupied_now=now)
    assert sorted(stage.small_moving.tolist()) == [2 * 30 + 2, 5 * 30 + 10]
    off = ObjectStage(load_config(overrides={"objects.moving_min_cluster_cells": 3,
                                             "objects.moving_min_height_m": 0.0}), SHAPE)
    assert off.moving_min_height == 0.0
    off.step(TrackerState(), dec, Z, Z, WIN, T0, occupied_now=now, heights=top)
    assert sorted(off.small_moving.tolist()) == [2 * 30 + 2, 5 * 30 + 10]
    # the bound needs the small-group rule: alone it does nothing
    alone = ObjectStage(load_config(overrides={"objects.moving_min_cluster_cells": 0,
                                               "objects.moving_min_height_m": 0.5}), SHAPE)
    assert alone.moving_min_height == 0.0 and alone.moving_min_cells == 0


def test_block_max_at_is_the_largest_of_each_cells_3x3_block() -> None:
    # against a plain loop over the block, on random layers and cells (edges and corners too)
    rng = np.random.default_rng(7)
    for shape in ((1, 1), (1, 5), (4, 1), (6, 9)):
        layer = rng.random(shape).astype(np.float32)
        cells = np.arange(layer.size)
        got = block_max_at(layer, cells)
        for k in cells:
            r, c = divmod(int(k), shape[1])
            block = layer[max(r - 1, 0):r + 2, max(c - 1, 0):c + 2]
            assert got[k] == block.max()
    assert block_max_at(layer, np.zeros(0, np.int64)).size == 0


def test_the_stage_asks_for_heights_for_any_height_bound():
    """The run computes each cell's highest return (``sensor_grid(heights_out=)``) when
    the small-group rule, the isolated-cluster rule, the small conflicting clusters' rule
    (the same ``isolated_min_height_m``) or the façade rule's small groups
    (``off_buildings_max_height_m``) has a height bound, not otherwise."""
    def needs(**overrides):
        keys = {f"objects.{k}": v for k, v in overrides.items()}
        return ObjectStage(load_config(overrides=keys), (4, 4)).needs_heights
    no_facade = {"off_buildings_max_height_m": 0.0}
    no_small = {"isolated_min_cells": 0, "small_conflict_min_cells": 0}
    assert needs()                                                      # the defaults: all
    assert needs(moving_min_cluster_cells=0, small_conflict_min_cells=0,
                 **no_facade)                                           # isolated only
    assert needs(moving_min_cluster_cells=0, isolated_min_cells=0,
                 **no_facade)                                           # small conflicting only
    assert needs(isolated_min_cells=0, small_conflict_min_cells=0,
                 **no_facade)                                           # small groups only
    assert needs(moving_min_cluster_cells=0, **no_small)                # the façade rule only
    assert not needs(moving_min_cluster_cells=0, clusters_off_buildings=False, **no_small)
    assert not needs(moving_min_cluster_cells=0, isolated_min_height_m=0.0, **no_facade)
    assert not needs(moving_min_cluster_cells=0, **no_small, **no_facade)
