#!/usr/bin/env python3
"""How far SemanticKITTI's labelled movers move within a slice (issues 20 and 21).

SemanticKITTI labels a whole track moving (classes 252–259) when the object moves at some
time of the recording, so a labelled mover may stand still for the scans a slice holds.
This script measures, from the labels and the poses alone (no evperc run, no decision),
what each labelled moving instance does in the slice: per scan the centroid of its points in
the first scan's lidar frame (the sequence's poses and ``Tr``, as evperc's KITTI reader
places them), then

    speed      the least-squares slope of the centroid against the scan times, |(vx, vy)|
               in m/s (horizontal; the centroid of the points seen, so it also moves with
               the part of the object the scan sees)
    net        the straight-line distance from the first scan's centroid to the last's, m
    range      the mean horizontal range of its points from the lidar, m

An instance seen in fewer than ``--min-scans`` scans (3) has no speed. evperc's tracker calls
nothing slower than ``objects.moving_speed_m_per_s`` (0.5 m/s) moving.

    python scripts/kitti_mover_motion.py ../shared/data/semantickitti/07 [--json F]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from evperc.eval.semantickitti import MOVING_CLASSES, read_label_file  # noqa: E402
from evperc.logs.kitti import KittiLog  # noqa: E402


def mover_motion(seq_dir: str | Path, min_scans: int = 3) -> list[dict[str, Any]]:
    """One record per labelled moving instance of the slice: its class, scans, points per
    scan, mean range (m), fitted horizontal speed (m/s; None below ``min_scans`` scans) and
    net centroid displacement (m) over the slice."""
    log = KittiLog(seq_dir)
    if log.labels_dir is None:
        raise SystemExit(f"{seq_dir}: no labels/ folder; give a SemanticKITTI sequence")
    tracks: dict[int, list[tuple[float, float, float, int, float, int]]] = {}
    for scan in log.scans():
        labels = read_label_file(log.labels_dir / f"{scan.number:06d}.label")
        if scan.source_index is not None:
            labels = labels[scan.source_index]
        semantic = labels & 0xFFFF
        instance = labels >> 16
        moving = np.isin(semantic, MOVING_CLASSES)
        world = scan.points.astype(np.float64) @ scan.T_world_sensor[:3, :3].T \
            + scan.T_world_sensor[:3, 3]
        for k in np.unique(instance[moving]):
            mine = moving & (instance == k)
            xy = world[mine, :2].mean(axis=0)
            rng = float(np.hypot(scan.points[mine, 0], scan.points[mine, 1]).mean())
            cls = int(np.bincount(semantic[mine]).argmax())
            tracks.setdefault(int(k), []).append((scan.stamp_ns * 1e-9, xy[0], xy[1],
                                                  int(mine.sum()), rng, cls))
    out = []
    for k, rows in sorted(tracks.items()):
        a = np.array(rows)
        t, x, y = a[:, 0], a[:, 1], a[:, 2]
        speed = None
        if len(a) >= min_scans:
            vx = np.polyfit(t - t[0], x, 1)[0]
            vy = np.polyfit(t - t[0], y, 1)[0]
            speed = float(np.hypot(vx, vy))
        out.append({"instance": k, "class": int(np.bincount(a[:, 5].astype(int)).argmax()),
                    "scans": len(a), "points_min": int(a[:, 3].min()),
                    "points_max": int(a[:, 3].max()), "range_m": float(a[:, 4].mean()),
                    "speed_mps": speed, "net_m": float(np.hypot(x[-1] - x[0], y[-1] - y[0])),
                    "span_s": float(t[-1] - t[0])})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("seq", type=Path, help="SemanticKITTI sequence folder")
    ap.add_argument("--min-scans", type=int, default=3)
    ap.add_argument("--json", type=Path, help="write the records here too")
    args = ap.parse_args()
    records = mover_motion(args.seq, args.min_scans)
    print(f"{args.seq}: {len(records)} labelled moving instance(s)")
    print(f"{'inst':>5} {'class':>5} {'scans':>5} {'points':>9} {'range m':>8} "
          f"{'speed m/s':>9} {'net m':>6} {'span s':>6}")
    for r in records:
        speed = "-" if r["speed_mps"] is None else f"{r['speed_mps']:.2f}"
        print(f"{r['instance']:>5} {r['class']:>5} {r['scans']:>5} "
              f"{r['points_min']:>4}-{r['points_max']:<4} {r['range_m']:>8.1f} {speed:>9} "
              f"{r['net_m']:>6.2f} {r['span_s']:>6.2f}")
    if args.json:
        args.json.write_text(json.dumps(records, indent=1))


if __name__ == "__main__":
    main()
