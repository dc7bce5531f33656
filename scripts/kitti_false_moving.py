#!/usr/bin/env python3
"""What the static points decided moving are, on a SemanticKITTI slice (issue 20).

For a run made with ``evperc run SEQ --no-map --point-labels`` and its sequence folder:
every point that the run labels moving and SemanticKITTI labels static — the false
positives exactly as ``evperc.eval.semantickitti.confusion`` counts them —, from scan
``--warmup`` on (the scans ``evperc evaluate --semantickitti`` scores), counted by its
SemanticKITTI class, with the quartiles of its horizontal range and of its height in the
lidar frame (the sensor is about 1.73 m above the road). Then the run's decided-``moving``
cells of those scans, and how many of them a reported moving object holds (the rest the
fusion decided moving with no object).

    python scripts/kitti_false_moving.py RUN ../shared/data/semantickitti/09
"""

from __future__ import annotations

import argparse
import collections
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import evperc  # noqa: E402
from evperc.eval.semantickitti import point_masks, read_label_file  # noqa: E402
from evperc.fusion.twin import DECISION_CODES  # noqa: E402
from evperc.output.objects import moving_object_cells  # noqa: E402

#: SemanticKITTI's class names (semantic-kitti.yaml) of the static classes that occur
CLASSES = {10: "car", 11: "bicycle", 13: "bus", 15: "motorcycle", 16: "on-rails", 18: "truck",
           20: "other-vehicle", 30: "person", 31: "bicyclist", 32: "motorcyclist", 40: "road",
           44: "parking", 48: "sidewalk", 49: "other-ground", 50: "building", 51: "fence",
           52: "other-structure", 60: "lane-marking", 70: "vegetation", 71: "trunk",
           72: "terrain", 80: "pole", 81: "traffic-sign", 99: "other-object"}


def false_points(run: Path, seq: Path, warmup: int) -> tuple[collections.Counter, np.ndarray]:
    """The false moving points' classes and their (range, z) rows."""
    classes: collections.Counter = collections.Counter()
    rows = []
    for path in sorted((run / "labels").glob("*.label"))[warmup:]:
        predicted = read_label_file(path) & 0xFFFF
        truth = read_label_file(seq / "labels" / path.name) & 0xFFFF
        points = np.fromfile(seq / "velodyne" / (path.stem + ".bin"), np.float32).reshape(-1, 4)
        # the scorer's own reading (evperc.eval.semantickitti.confusion): said moving,
        # labelled, not moving
        said, labelled, moving = point_masks(predicted, truth)
        false = said & labelled & ~moving
        for c, n in zip(*np.unique(truth[false], return_counts=True), strict=True):
            classes[CLASSES.get(int(c), str(int(c)))] += int(n)
        p = points[false]
        rows.append(np.column_stack([np.hypot(p[:, 0], p[:, 1]), p[:, 2]]))
    return classes, (np.concatenate(rows) if rows else np.zeros((0, 2), np.float32))


def moving_cells(run: Path, warmup: int) -> tuple[int, int]:
    """Decided-moving cell-frames from scan ``warmup`` on, and those a moving object holds."""
    total = held = 0
    for frame in evperc.load(run).frames:
        if frame.index < warmup:
            continue
        cells = np.flatnonzero(frame.decision.reshape(-1) == DECISION_CODES["moving"])
        total += cells.size
        if frame.objects is not None:
            held += int(np.isin(cells, moving_object_cells(frame.objects,
                                                           frame.object_cells)).sum())
    return total, held


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("sequence", type=Path)
    parser.add_argument("--warmup", type=int, default=2)
    args = parser.parse_args(argv)
    classes, rz = false_points(args.run, args.sequence, args.warmup)
    total = sum(classes.values())
    print(f"static points decided moving: {total}")
    for name, n in classes.most_common():
        print(f"  {name:16s} {n:6d}  {100 * n / total:5.1f} %")
    if total:
        q = np.percentile(rz, [25, 50, 75], axis=0)
        print(f"  range m (quartiles) {q[0, 0]:.1f} {q[1, 0]:.1f} {q[2, 0]:.1f}; "
              f"lidar z m {q[0, 1]:.2f} {q[1, 1]:.2f} {q[2, 1]:.2f}")
    cells, held = moving_cells(args.run, args.warmup)
    print(f"decided-moving cell-frames: {cells}, held by a moving object: {held}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
