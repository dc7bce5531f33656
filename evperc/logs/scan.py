"""What every log source yields: one lidar scan with the sensor's pose at its stamp."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PosedScan:
    """One lidar scan with the sensor pose at its stamp (docs/architecture.md)."""

    stamp_ns: int
    points: np.ndarray          # (N, 3) float32, sensor frame, finite only
    planar: bool                # True for 2-D scans (LaserScan): every point is an obstacle
    T_world_sensor: np.ndarray  # (4, 4) float64: sensor pose in the log's world frame
    frame_id: str
    #: the scan's own number, if the source numbers its scans (a KITTI file number)
    number: int | None = None
    #: points in the source cloud before non-finite ones were dropped (None: len(points))
    source_count: int | None = None
    #: (N,) index in the source cloud of each row of ``points`` (None: 0..N-1)
    source_index: np.ndarray | None = None
