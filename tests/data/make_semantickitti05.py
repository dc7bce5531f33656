"""Write tests/data/semantickitti05/ from the shared SemanticKITTI slice (run from the repo
root: ``python tests/data/make_semantickitti05.py``; see tests/data/README.md).

Scans 0, 3, 6 and 9 of sequence 05, points within 20 m (horizontal) of the lidar, every 12th
of them plus every point labelled moving; labels cut the same way; poses.txt, times.txt and
calib.txt unchanged (10 lines: the file numbers keep pointing at their lines).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

SOURCE = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "semantickitti" / "05"
DEST = Path(__file__).resolve().parent / "semantickitti05"
SCANS = (0, 3, 6, 9)
RADIUS_M = 20.0
STRIDE = 12


def main() -> None:
    (DEST / "velodyne").mkdir(parents=True, exist_ok=True)
    (DEST / "labels").mkdir(exist_ok=True)
    for name in ("poses.txt", "times.txt", "calib.txt"):
        shutil.copyfile(SOURCE / name, DEST / name)
    for i in SCANS:
        points = np.fromfile(SOURCE / "velodyne" / f"{i:06d}.bin", "<f4").reshape(-1, 4)
        labels = np.fromfile(SOURCE / "labels" / f"{i:06d}.label", "<u4")
        near = np.flatnonzero(np.hypot(points[:, 0], points[:, 1]) < RADIUS_M)
        moving = near[(labels[near] & 0xFFFF) >= 252]
        keep = np.union1d(near[::STRIDE], moving)  # sorted: the scan's point order
        points[keep].tofile(DEST / "velodyne" / f"{i:06d}.bin")
        labels[keep].tofile(DEST / "labels" / f"{i:06d}.label")


if __name__ == "__main__":
    main()
