"""Cross-check of `evperc evaluate --semantickitti`: label every point of a KITTI run by a plain
cell look-up (no ground split), with the poses computed here from the files (tests.mcap_writers),
and score it with numpy written here. Reproduces the issue-19 "starting line" scorer's rule
("each point takes its cell's decision").

    PYTHONPATH=$PWD python scripts/kitti_cell_lookup.py RUN SEQ_DIR [--first 1]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import evperc  # noqa: E402
from tests.mcap_writers import kitti_lidar_poses, read_kitti_odometry  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run")
    ap.add_argument("seq")
    ap.add_argument("--first", type=int, default=1, help="first scan scored")
    ap.add_argument("--keep-ground", action="store_true",
                    help="use the run's own labels for ground points (9) instead of the look-up")
    args = ap.parse_args()
    run = evperc.load(args.run)
    n = len(run)
    poses = kitti_lidar_poses(args.seq, n)
    bins = read_kitti_odometry(args.seq, n)["bins"]
    moving_code = run.manifest["decision_codes"]["moving"]
    tp = fp = fn = tn = 0
    for i, frame in enumerate(run.frames):
        if i < args.first:
            continue
        pts = np.fromfile(bins[i], "<f4").reshape(-1, 4)[:, :3].astype(np.float64)
        world = pts @ poses[i][:3, :3].T + poses[i][:3, 3]
        res = frame.window.resolution_m
        row = np.floor(world[:, 1] / res).astype(int) - frame.origin[0]
        col = np.floor(world[:, 0] / res).astype(int) - frame.origin[1]
        inside = (row >= 0) & (row < frame.decision.shape[0]) & (col >= 0) & (
            col < frame.decision.shape[1])
        said = np.zeros(len(pts), bool)
        said[inside] = frame.decision[row[inside], col[inside]] == moving_code
        if args.keep_ground:
            own = np.fromfile(Path(args.run) / "labels" / f"{i:06d}.label", "<u4")
            said &= own != 9  # ground (and static obstacle) points as the run says
        gt = np.fromfile(Path(args.seq) / "labels" / f"{i:06d}.label", "<u4") & 0xFFFF
        labelled = gt > 1
        moving = (gt >= 252) & (gt <= 259)
        tp += int((said & moving).sum())
        fp += int((said & labelled & ~moving).sum())
        fn += int((~said & moving).sum())
        tn += int((~said & labelled & ~moving).sum())
    iou = tp / max(tp + fp + fn, 1)
    print(f"{Path(args.seq).name}: scans {args.first}-{n - 1}: TP {tp} FP {fp} FN {fn} "
          f"IoU {iou:.3f} static->moving {100 * fp / max(fp + tn, 1):.2f}%")


if __name__ == "__main__":
    main()
