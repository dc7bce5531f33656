#!/usr/bin/env python3
"""A sparse-lidar copy of a SemanticKITTI slice: real scans as a 16-layer scanner would see them.

evperc's 16-layer settings (configs/vlp16.toml, taken by a run of a 12–24-layer log) were
chosen on simulated drives; no real 16-layer log with moving labels is shipped. This script
makes one from a SemanticKITTI slice: it keeps, in every scan, the points whose elevation
atan2(z, √(x² + y²)) lies within ``--half-width`` (0.2°) of one of ``--layers`` (16)
elevations ``--spacing`` (1.6°) apart from ``--lowest`` (−24°) up — the HDL-64E's lines are
about 0.4° apart, so each kept elevation holds about one of its 64 lines, 22 % of the points —
and the labels of the points kept, in the same order; calib.txt, poses.txt and times.txt are
copied. The copy is a KITTI folder like the source (``evperc run COPY --no-map
--point-labels``, ``evperc evaluate RUN --semantickitti COPY``); evperc reads it as an
HDL-64E's, so name the preset (``--preset vlp16``, or ``--preset none``).

    python scripts/kitti_sparse_copy.py ../shared/data/semantickitti/05 /tmp/sk16/05
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import numpy as np


def layer_elevations(layers: int = 16, lowest_deg: float = -24.0,
                     spacing_deg: float = 1.6) -> np.ndarray:
    """The kept elevations, degrees, lowest first."""
    return lowest_deg + spacing_deg * np.arange(layers)


def keep_mask(xyz: np.ndarray, elevations_deg: np.ndarray, half_width_deg: float = 0.2
              ) -> np.ndarray:
    """Whether each point's elevation lies within ``half_width_deg`` of a kept elevation."""
    elevation = np.degrees(np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1])))
    nearest = np.abs(elevation[:, None] - elevations_deg[None, :]).min(axis=1)
    return nearest <= half_width_deg


def sparse_copy(src: Path, dst: Path, elevations_deg: np.ndarray,
                half_width_deg: float = 0.2) -> tuple[int, int]:
    """Write the copy of ``src`` into ``dst`` (replaced); returns (points kept, points).
    Exits with a one-line message if ``src`` is no SemanticKITTI slice."""
    for need in ("velodyne", "labels", "calib.txt", "poses.txt", "times.txt"):
        if not (src / need).exists():
            raise SystemExit(f"{src}: no {need}: give a SemanticKITTI sequence folder "
                             "(velodyne/, labels/, calib.txt, poses.txt, times.txt)")
    if dst.resolve() == src.resolve():
        raise SystemExit(f"{dst}: the copy would replace its source: give another folder")
    if dst.exists():
        shutil.rmtree(dst)
    (dst / "velodyne").mkdir(parents=True)
    (dst / "labels").mkdir()
    for name in ("calib.txt", "poses.txt", "times.txt"):
        shutil.copy(src / name, dst / name)
    kept = total = 0
    for scan in sorted((src / "velodyne").glob("*.bin")):
        points = np.fromfile(scan, "<f4").reshape(-1, 4)
        label_file = src / "labels" / f"{scan.stem}.label"
        if not label_file.exists():
            raise SystemExit(f"{label_file}: missing: every scan needs its labels")
        labels = np.fromfile(label_file, "<u4")
        if len(labels) != len(points):
            raise SystemExit(f"{scan}: {len(points)} points but {len(labels)} labels")
        keep = keep_mask(points[:, :3], elevations_deg, half_width_deg)
        points[keep].tofile(dst / "velodyne" / scan.name)
        labels[keep].tofile(dst / "labels" / f"{scan.stem}.label")
        kept += int(keep.sum())
        total += len(points)
    return kept, total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("src", type=Path, help="a SemanticKITTI slice (velodyne/, labels/)")
    parser.add_argument("dst", type=Path, help="the copy (replaced if it exists)")
    parser.add_argument("--layers", type=int, default=16)
    parser.add_argument("--lowest", type=float, default=-24.0, help="degrees")
    parser.add_argument("--spacing", type=float, default=1.6, help="degrees")
    parser.add_argument("--half-width", type=float, default=0.2, help="degrees")
    args = parser.parse_args()
    kept, total = sparse_copy(args.src, args.dst,
                              layer_elevations(args.layers, args.lowest, args.spacing),
                              args.half_width)
    print(f"{args.dst}: {kept} of {total} points kept ({kept / max(total, 1):.1%})")


if __name__ == "__main__":
    main()
