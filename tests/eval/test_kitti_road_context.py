"""scripts/kitti_road_context.py: a SemanticKITTI slice's road cells, placed by a second route
(cam0's poses and the calibration, in plain numpy, not evperc's KITTI reader), and the window
context they make."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from evperc.geo.prior import CONTEXT_ROAD
from evperc.geo.window import Window

REPO = Path(__file__).resolve().parents[2]
SMALL = REPO / "tests" / "data" / "semantickitti05"
sys.path.insert(0, str(REPO / "scripts"))
import kitti_road_context as road  # noqa: E402


def _tr(calib: Path) -> np.ndarray:
    for line in calib.read_text().splitlines():
        if line.startswith("Tr:"):
            return np.vstack([np.array(line.split()[1:], float).reshape(3, 4), [0, 0, 0, 1]])
    raise AssertionError("no Tr line")


def expected_cells(seq: Path, res: float = 0.5) -> set[tuple[int, int]]:
    """The road points' cells in the first scan's lidar frame: P_world_lidar = P_cam0 · Tr."""
    tr = _tr(seq / "calib.txt")
    poses = np.loadtxt(seq / "poses.txt").reshape(-1, 3, 4)
    cells = set()
    first = None
    for scan in sorted((seq / "velodyne").glob("*.bin")):
        k = int(scan.stem)
        lidar = np.vstack([poses[k], [0, 0, 0, 1]]) @ tr
        first = lidar if first is None else first
        xyz = np.fromfile(scan, "<f4").reshape(-1, 4)[:, :3].astype(float)
        cls = np.fromfile(seq / "labels" / f"{scan.stem}.label", "<u4") & 0xFFFF
        pts = xyz[np.isin(cls, (40, 44, 60))]
        rel = np.linalg.inv(first) @ lidar
        world = pts @ rel[:3, :3].T + rel[:3, 3]
        for x, y in world[:, :2]:
            cells.add((int(np.floor(y / res)), int(np.floor(x / res))))
    return cells


def test_road_cells_are_the_road_points_cells() -> None:
    want = expected_cells(SMALL)
    got = road.road_cells(SMALL)
    assert len(want) > 100   # the slice's road is in it
    assert {tuple(c) for c in got.tolist()} == want


def test_grown_road_cells_are_the_neighbourhoods() -> None:
    base = {tuple(c) for c in road.road_cells(SMALL).tolist()}
    grown = {tuple(c) for c in road.road_cells(SMALL, grow=2).tolist()}
    want = {(r + dr, c + dc) for r, c in base for dr in range(-2, 3) for dc in range(-2, 3)}
    assert grown == want


def test_context_marks_the_cells_inside_the_window() -> None:
    window = Window(rows=4, cols=5, row0=10, col0=-2, resolution_m=0.5)
    cells = np.array([[10, -2], [13, 2], [12, 0], [9, 0], [11, 3]])   # two outside
    context = road.context_of(cells, window)
    want = np.zeros((4, 5), np.uint8)
    want[0, 0] = want[3, 4] = want[2, 2] = CONTEXT_ROAD
    np.testing.assert_array_equal(context, want)
