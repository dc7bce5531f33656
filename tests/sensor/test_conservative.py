"""Conservative free space (evperc.sensor.conservative, docs/method.md): hand-made sensor grids
with the expected cells worked out by hand, and a grazing wall seen by a 2-D scanner."""

from __future__ import annotations

import math

import numpy as np
import pytest

from evperc.geo.window import Window
from evperc.sensor import SensorParams, sensor_grid
from evperc.sensor.conservative import conservative_free, disc_offsets
from evperc.sensor.evidence import FREE, OCCUPIED, UNKNOWN
from tests.sensor.scenes import pose

RES = 0.5
F, O, U = int(FREE), int(OCCUPIED), int(UNKNOWN)


def grid(rows: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """States from strings ('F', 'O', 'U' per cell) and the free masses they give (μ_F 0.7)."""
    code = {"F": F, "O": O, "U": U}
    state = np.array([[code[c] for c in row] for row in rows], np.uint8)
    return state, np.where(state == F, np.float32(0.7), np.float32(0.0))


def freed(free: np.ndarray) -> list[str]:
    """The free mask back as strings: '1' free, '.' not."""
    return ["".join("1" if v > 0 else "." for v in row) for row in free]


def test_disc_offsets_count_by_hand() -> None:
    # 0.5 m cells: radius 0.5 → the 4 edge neighbours (distance 0.5); 0.75 → also the 4
    # diagonals (0.707); 1.0 → also (±2, 0), (0, ±2) at 1.0 but not (±2, ±1) at 1.118
    assert len(disc_offsets(0.5, RES)) == 4
    assert len(disc_offsets(0.75, RES)) == 8
    assert sorted(map(tuple, disc_offsets(1.0, RES))) == sorted(
        [(-2, 0), (2, 0), (0, -2), (0, 2), (-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1),
         (1, -1), (1, 0), (1, 1)])
    assert len(disc_offsets(0.49, RES)) == 0 and len(disc_offsets(0.0, RES)) == 0


def test_margin_around_a_return() -> None:
    # d_s = 0.5 m: the 4 edge neighbours of the occupied cell (1, 3) lose their free mass;
    # 0.75 m: the 8 neighbours. The unknown cell (3, 6) plays no part without erosion.
    rows = ["FFFFFFF",
            "FFFOFFF",
            "FFFFFFF",
            "FFFFFFU",
            "FFFFFFF"]
    state, free = grid(rows)
    assert conservative_free(state, free, RES, 0.5, 0.0) == 4
    assert freed(free) == ["111.111",
                           "11...11",
                           "111.111",
                           "111111.",
                           "1111111"]
    state, free = grid(rows)
    assert conservative_free(state, free, RES, 0.75, 0.0) == 8
    assert freed(free) == ["11...11",
                           "11...11",
                           "11...11",
                           "111111.",
                           "1111111"]


def test_erosion_from_unknown_does_not_cascade() -> None:
    # d_p = 0.5 m: only the free cells next to an unknown cell lose their free mass: (2, 6),
    # (4, 6), (3, 5) next to (3, 6), and the whole row 0 next to the unknown row above? No:
    # cells outside the window are not unknown, so row 0 keeps its mass. The cells freed of
    # their mass do not erode their own neighbours (the test reads the projected states).
    rows = ["FFFFFFF",
            "FFFOFFF",
            "FFFFFFF",
            "FFFFFFU",
            "FFFFFFF"]
    state, free = grid(rows)
    assert conservative_free(state, free, RES, 0.0, 0.5) == 3
    assert freed(free) == ["1111111",
                           "111.111",
                           "111111.",
                           "11111..",
                           "111111."]
    # both margins: the union of the two sets (4 + 3 cells)
    state, free = grid(rows)
    assert conservative_free(state, free, RES, 0.5, 0.5) == 7
    assert freed(free) == ["111.111",
                           "11...11",
                           "111.11.",
                           "11111..",
                           "111111."]


def test_erosion_of_a_free_strip_between_unknown_rays() -> None:
    # a 3-cell free strip between unknown columns: d_p 0.5 m leaves its middle column;
    # 0.75 m (diagonals too) the same; 1.0 m (two cells) nothing
    rows = ["UFFFU"] * 4
    for erosion, expected in ((0.5, ".F."), (0.75, ".F."), (1.0, "...")):
        state, free = grid(rows)
        conservative_free(state, free, RES, 0.0, erosion)
        assert freed(free) == ["." + expected.replace("F", "1") + "."] * 4


def test_margins_below_a_cell_change_nothing() -> None:
    state, free = grid(["FOF", "FUF"])
    before = free.copy()
    assert conservative_free(state, free, RES, 0.2, 0.4) == 0
    np.testing.assert_array_equal(free, before)


def test_shape_mismatch_is_an_error() -> None:
    state, _ = grid(["FF"])
    with pytest.raises(ValueError, match="shape"):
        conservative_free(state, np.zeros((2, 2), np.float32), RES, 0.5, 0.0)


def wall_scan(wall_y: float, x_max: float, step_deg: float) -> np.ndarray:
    """2-D returns of a straight wall ``y = wall_y`` (x in [0, x_max]) seen from the origin by
    beams every ``step_deg`` (on the polar bin centres) below 90°: the points
    ``(wall_y / tan θ, wall_y)``."""
    theta = np.radians(np.arange(step_deg, 90.0, step_deg))
    x = wall_y / np.tan(theta)
    keep = x <= x_max
    return np.stack([x[keep], np.full(keep.sum(), wall_y), np.zeros(keep.sum())],
                    axis=1).astype(np.float32)


def test_grazing_rays_no_longer_free_the_wall_face() -> None:
    # A wall at y = 5.2 m, the sensor at the origin looking east: cell row 10 holds y in
    # [5.0, 5.5), the wall's face. Beams at θ ≈ 6° stay in row 10 for 0.2 m / tan θ ≈ 1.9 m
    # before they reach the wall, while their hits lie ~4 m apart along it: the paper's model
    # marks wall-face cells free between the hits. Beyond the wall (row 11 and up) no ray
    # passes: unknown. So d_p = 0.5 m takes the free mass of every wall-face cell (row 11 is
    # its edge neighbour); d_s alone only takes the face cells next to a hit.
    window = Window(RES, 40, 200, -20, -100)  # rows: y in [-10, 10); cols: x in [-50, 50)
    points = wall_scan(5.2, 45.0, 0.5)
    t = pose(0.0, 0.0, 1.0)
    wall_row = 10 - window.row0
    face = slice(20 - window.col0, 90 - window.col0)  # x in [10, 45): grazing angles < 27°

    def face_free(**margins: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        params = SensorParams(range_bin_m=RES, **margins)
        free, occ = sensor_grid(points, True, t, window, params)
        return free[wall_row, face] > 0, occ[wall_row, face] > 0, free

    carved, hits, plain = face_free()
    # (about 20 face cells beyond x = 21 m are carved free with this beam pattern)
    assert carved.sum() >= 10, "the scene no longer shows the grazing-ray carving"
    assert hits.sum() >= 5
    eroded, _, free_dp = face_free(free_erosion_m=0.5)
    assert eroded.sum() == 0
    margin, _, _ = face_free(free_margin_m=0.5)
    next_to_hit = np.zeros_like(hits)
    next_to_hit[1:] |= hits[:-1]
    next_to_hit[:-1] |= hits[1:]
    assert not (margin & next_to_hit).any()
    assert margin.sum() < carved.sum()
    # the road in front of the wall keeps its free mass: rows 3..7 (y in [1.5, 4)), x in
    # [2, 12) m lie inside the fan of beams that reach the wall (θ ≥ atan(5.2 / 45) = 6.6°,
    # whose edge crosses y = 1.5 m at x = 13 m) and away from the min-range disc: no cell
    # there has an unknown neighbour
    road = (slice(3 - window.row0, 8 - window.row0), slice(4 - window.col0, 24 - window.col0))
    assert (plain[road] > 0).all() and (free_dp[road] > 0).all()


def test_sensor_grid_with_zero_margins_is_the_papers_model() -> None:
    # the same wall through SensorParams() with margins 0 and with margins left out: equal
    window = Window(RES, 40, 200, -20, -100)
    points = wall_scan(5.2, 45.0, 0.5)
    a = sensor_grid(points, True, pose(0.0, 0.0, 1.0), window, SensorParams(range_bin_m=RES))
    b = sensor_grid(points, True, pose(0.0, 0.0, 1.0), window,
                    SensorParams(range_bin_m=RES, free_margin_m=0.0, free_erosion_m=0.0))
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    assert math.isclose(float(a[0].max()), 0.7, rel_tol=1e-6)
