"""scripts/kitti_mover_motion.py: how far SemanticKITTI's labelled movers move in a slice.

The oracle is a second route from the same files that shares no code with the script or with
evperc's KITTI reader: the labelled points placed in cam0's world frame (poses.txt · Tr), whose
horizontal plane is x–z (camera axes: x right, y down, z forward). The lidar frame of the first
scan, the script's frame, is within a degree of it (``Tr``'s rotation is an axis permutation up
to < 1°), so horizontal distances agree to millimetres on displacements of a metre or two with
a few centimetres of height change; 0.02 m is the tolerance.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
SMALL = REPO / "tests" / "data" / "semantickitti05"
SHARED = REPO.parent / "shared" / "data" / "semantickitti"
sys.path.insert(0, str(REPO / "scripts"))
import kitti_mover_motion as motion  # noqa: E402

needs_shared = pytest.mark.skipif(not (SHARED / "07" / "poses.txt").exists(),
                                  reason="../shared/data/semantickitti (the six slices) absent")


def _cam_world_centroids(seq: Path, instance: int) -> list[np.ndarray]:
    """The instance's labelled-moving points' centroid in cam0's world frame, per scan."""
    rows = {line.split(":")[0]: line.split(":", 1)[1] for line in
            (seq / "calib.txt").read_text().splitlines() if ":" in line}
    tr = np.eye(4)
    tr[:3] = np.array(rows["Tr"].split(), float).reshape(3, 4)
    poses = np.loadtxt(seq / "poses.txt").reshape(-1, 3, 4)
    out = []
    for scan in sorted((seq / "velodyne").glob("*.bin")):
        xyz = np.fromfile(scan, "<f4").reshape(-1, 4)[:, :3].astype(np.float64)
        lab = np.fromfile(seq / "labels" / f"{scan.stem}.label", "<u4")
        mine = ((lab & 0xFFFF) >= 252) & ((lab & 0xFFFF) <= 259) & ((lab >> 16) == instance)
        pose = np.eye(4)
        pose[:3] = poses[int(scan.stem)]
        world = (pose @ tr)[:3]
        out.append((xyz[mine] @ world[:, :3].T + world[:, 3]).mean(axis=0))
    return out


def test_the_walker_of_the_small_05_copy_moves_as_a_second_route_says() -> None:
    records = motion.mover_motion(SMALL)
    assert [r["instance"] for r in records] == [1]
    walker = records[0]
    assert walker["scans"] == 4 and walker["class"] == 254  # moving-person
    c = _cam_world_centroids(SMALL, 1)
    net_cam = float(np.hypot(c[-1][0] - c[0][0], c[-1][2] - c[0][2]))
    assert walker["net_m"] == pytest.approx(net_cam, abs=0.02)
    # a person walking: between 0.8 and 2 m/s (the dataset: "a person walking")
    assert 0.8 < walker["speed_mps"] < 2.0


@needs_shared
def test_the_people_of_07_walk() -> None:
    """07's recall is 0 (docs/evaluation.md § Where the method fails): not because its
    labelled movers stand still in the slice — both walk faster than 1 m/s."""
    records = motion.mover_motion(SHARED / "07")
    assert len(records) == 2
    for r in records:
        c = _cam_world_centroids(SHARED / "07", r["instance"])
        net_cam = float(np.hypot(c[-1][0] - c[0][0], c[-1][2] - c[0][2]))
        assert r["net_m"] == pytest.approx(net_cam, abs=0.02)
        assert r["speed_mps"] > 1.0 and r["net_m"] > 0.9
