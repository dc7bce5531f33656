"""The object reach of the per-point labels (evperc.objects.point_labels, "Object reach"):
returns of a moving object that fall in cells with no occupied decision of their own take the
object's label, by hand on small windows, and through a run on the KITTI copy in tests/data."""

from __future__ import annotations

import numpy as np

from evperc.fusion.twin import DECISION_CODES as D
from evperc.geo.window import Window
from evperc.objects.point_labels import object_reach, point_cells, point_labels
from evperc.sensor.ground import GROUND, OBSTACLE

IDENTITY = np.eye(4)


def _window() -> Window:
    # 1 m cells, 5 x 7, rows 0-4 and cols 0-6 of the lattice: a point (x, y) of an identity
    # pose lies in cell (floor(y), floor(x))
    return Window(1.0, 5, 7, 0, 0)


def _at(cells_xy: list[tuple[float, float, float]]) -> np.ndarray:
    return np.array(cells_xy, np.float32)


def test_reach_takes_free_and_unknown_neighbours_at_the_objects_height_only() -> None:
    window = _window()
    decision = np.full(window.shape, D["free"], np.uint8)
    decision[2, 2] = decision[2, 3] = D["moving"]   # the moving object: cells (2, 2), (2, 3)
    decision[1, 4] = D["static"]                    # a parked car beside it
    decision[3, 4] = D["unknown"]
    points = _at([
        (2.5, 2.5, 0.2),   # 0 object cell (2, 2), z 0.2                   -> 251 (its cell)
        (3.5, 2.5, 1.0),   # 1 object cell (2, 3), z 1.0: heights [0.2, 1.0] -> 251
        (4.5, 2.5, 0.6),   # 2 free cell (2, 4), next to (2, 3), z in range  -> 251 (reach)
        (4.5, 3.5, 1.2),   # 3 unknown cell (3, 4), z 1.2 = 1.0 + 0.2 margin -> 251 (reach)
        (4.5, 1.5, 0.6),   # 4 static cell (1, 4): its own occupied decision -> 9
        (5.5, 2.5, 0.6),   # 5 free cell (2, 5): two cells from the object    -> 9
        (1.5, 2.5, 1.5),   # 6 free cell (2, 1), next to it but 0.5 m above   -> 9
        (1.5, 1.5, -0.1),  # 7 free cell (1, 1), diagonal neighbour, z 0.3 below lo -> 9
        (1.5, 1.5, 0.05),  # 8 the same cell, within the margin below          -> 251
        (2.5, 3.5, 0.5),   # 9 ground point in a reached cell: ground stays   -> 9
    ])
    kinds = np.full(len(points), OBSTACLE, np.uint8)
    kinds[9] = GROUND
    own = [np.array([2 * 7 + 2, 2 * 7 + 3])]
    plain = point_labels(points, kinds, IDENTITY, window, decision)
    # without the reach: each point its cell's decision (unknown -> 0)
    assert plain.tolist() == [251, 251, 9, 0, 9, 9, 9, 9, 9, 9]
    reached = point_labels(points, kinds, IDENTITY, window, decision, moving_objects=own,
                           reach_cells=1, height_margin_m=0.2)
    assert reached.tolist() == [251, 251, 251, 251, 9, 9, 9, 9, 251, 9]
    # reach 2 also takes cell (2, 5); a zero reach is the plain rule
    two = point_labels(points, kinds, IDENTITY, window, decision, moving_objects=own,
                       reach_cells=2, height_margin_m=0.2)
    assert two[5] == 251 and two[4] == 9
    zero = point_labels(points, kinds, IDENTITY, window, decision, moving_objects=own,
                        reach_cells=0, height_margin_m=0.2)
    assert zero.tolist() == plain.tolist()


def test_each_object_uses_its_own_heights_and_an_empty_object_reaches_nothing() -> None:
    window = _window()
    decision = np.full(window.shape, D["unknown"], np.uint8)
    decision[0, 0] = decision[4, 6] = D["moving"]
    points = _at([
        (0.5, 0.5, 0.0),   # object A's own point, heights [0, 0]
        (6.5, 4.5, 2.0),   # object B's own point, heights [2, 2]
        (1.5, 0.5, 0.1),   # next to A at A's height                 -> moving
        (5.5, 4.5, 0.1),   # next to B at A's height, not B's        -> unknown (0)
        (5.5, 3.5, 1.95),  # next to B at B's height                 -> moving
    ])
    kinds = np.full(len(points), OBSTACLE, np.uint8)
    labels = point_labels(points, kinds, IDENTITY, window, decision,
                          moving_objects=[np.array([0]), np.array([4 * 7 + 6]),
                                          np.array([2 * 7 + 3])],  # the third holds no point
                          reach_cells=1, height_margin_m=0.1)
    assert labels.tolist() == [251, 251, 251, 0, 251]


def test_object_reach_matches_a_brute_force_count_on_random_scenes() -> None:
    """Independent check: per point, a loop over the objects and their cells."""
    rng = np.random.default_rng(5)
    window = Window(0.5, 12, 15, 3, -4)
    for _ in range(20):
        decision = rng.choice([D["free"], D["unknown"], D["static"], D["moving"]],
                              size=window.shape).astype(np.uint8)
        n = 300
        xy = np.stack([rng.uniform(-2.5, 6.0, n), rng.uniform(1.0, 8.0, n)], axis=1)
        points = np.column_stack([xy, rng.uniform(-1, 2, n)]).astype(np.float32)
        row, col, inside, z = point_cells(points, IDENTITY, window, with_height=True)
        cells = (row * window.cols + col)[inside]
        z = z[inside]
        # disjoint, as the clusters of a frame are
        drawn = rng.permutation(window.rows * window.cols)
        sizes = rng.integers(0, 6, size=3)
        objects = [drawn[sizes[:i].sum():sizes[:i + 1].sum()] for i in range(3)]
        k, margin = int(rng.integers(1, 3)), float(rng.uniform(0, 0.5))
        got = object_reach(cells, z, decision, window.cols, objects, k, margin)
        want = np.zeros(len(cells), bool)
        flat = decision.reshape(-1)
        for i, cell in enumerate(cells):
            if flat[cell] not in (D["free"], D["unknown"]):
                continue
            r, c = divmod(int(cell), window.cols)
            for own in objects:
                heights = [z[j] for j in range(len(cells)) if cells[j] in set(own.tolist())]
                if not heights:
                    continue
                near = any(max(abs(r - o // window.cols), abs(c - o % window.cols)) <= k
                           for o in own.tolist())
                if near and min(heights) - margin <= z[i] <= max(heights) + margin:
                    want[i] = True
        assert got.tolist() == want.tolist()


def test_the_runner_hands_only_the_moving_objects_cells_to_the_labels() -> None:
    """Pipeline._object_reach on a frame's object list: records in track order, cells
    concatenated in record order; stopped objects reach nothing; the reach off (0) or the
    fill off gives the plain labels."""
    from types import SimpleNamespace

    from evperc.config import load_config
    from evperc.output.objects import OBJECT_DTYPE, OBJECT_STATES
    from evperc.runner import Pipeline

    objects = np.zeros(3, OBJECT_DTYPE)
    objects["state"] = [OBJECT_STATES["moving"], OBJECT_STATES["stopped"],
                        OBJECT_STATES["moving"]]
    objects["cell_count"] = [2, 3, 1]
    frame = {"objects": objects, "object_cells": np.array([5, 6, 10, 11, 12, 40], np.uint32)}
    config = load_config(overrides={"objects.point_reach_cells": 2,
                                    "objects.point_height_margin_m": 0.4})
    fake = SimpleNamespace(request=SimpleNamespace(config=config), fill_moving=True)
    got = Pipeline._object_reach(fake, frame)
    assert [c.tolist() for c in got["moving_objects"]] == [[5, 6], [40]]
    assert got["reach_cells"] == 2 and got["height_margin_m"] == 0.4
    off = SimpleNamespace(request=SimpleNamespace(config=load_config(
        overrides={"objects.point_reach_cells": 0})), fill_moving=True)
    assert Pipeline._object_reach(off, frame) == {}
    assert Pipeline._object_reach(SimpleNamespace(request=fake.request, fill_moving=False),
                                  frame) == {}
    assert Pipeline._object_reach(fake, {}) == {}
