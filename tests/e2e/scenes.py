"""Small synthetic 2-D drives written as ROS 2 MCAP (LaserScan + Odometry + tf_static), for
end-to-end tests of `evperc run`: a closed straight street (walls at y = ±6 m, ends at
x = −50 and 60 m), the ego driving along
it, optionally a car crossing ahead. Ranges come from exact ray/segment intersection."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tests.mcap_writers import transform, write_ros2_mcap

BASE_NS = 1_700_000_000_000_000_000


def _segments(t: float, with_car: bool) -> np.ndarray:
    """(K, 4) segments x0, y0, x1, y1 of the scene at time t (s)."""
    walls = [(-50, 6, 60, 6), (-50, -6, 60, -6), (60, -6, 60, 6), (-50, -6, -50, 6)]
    segs = list(walls)
    if with_car:
        cx, cy = 25.0, -5.0 + 2.0 * t   # crossing north at 2 m/s
        h = 1.0
        segs += [(cx - h, cy - h, cx + h, cy - h), (cx + h, cy - h, cx + h, cy + h),
                 (cx + h, cy + h, cx - h, cy + h), (cx - h, cy + h, cx - h, cy - h)]
    return np.array(segs, dtype=np.float64)


def cast(origin: np.ndarray, angles: np.ndarray, segs: np.ndarray, max_range: float
         ) -> np.ndarray:
    """Range of each ray from ``origin`` at world ``angles`` to the nearest segment (inf if
    none within ``max_range``)."""
    d = np.stack([np.cos(angles), np.sin(angles)], axis=1)[:, None, :]
    p0, p1 = segs[None, :, :2], segs[None, :, 2:]
    e = p1 - p0
    w = p0 - origin[None, None, :]
    denom = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * e[..., 1] - w[..., 1] * e[..., 0]) / denom
        u = (w[..., 0] * d[..., 1] - w[..., 1] * d[..., 0]) / denom
    hit = (np.abs(denom) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
    r = np.where(hit, t, np.inf).min(axis=1)
    return np.where(r <= max_range, r, np.inf)


def write_street_drive(path: Path, n_scans: int = 40, speed_mps: float = 5.0,
                       with_car: bool = True, beams: int = 720,
                       chunk_size: int = 1024 * 1024, poses_first: bool = False) -> Path:
    """The street drive as ROS 2 MCAP: /scan LaserScan in ``laser`` at 10 Hz, /odom
    map→base_link, /tf_static base_link→laser (0.5 m forward)."""
    angles = -np.pi + np.arange(beams) * (2 * np.pi / beams)
    scans, odom = [], []
    for k in range(n_scans):
        t = 0.1 * k
        ns = BASE_NS + int(round(t * 1e9))
        x = speed_mps * t
        ranges = cast(np.array([x + 0.5, 0.0]), angles, _segments(t, with_car), 75.0)
        scans.append((ns, ranges, float(angles[0]), float(2 * np.pi / beams), "laser"))
        odom.append((ns, transform(x=x)))
    odom.append((BASE_NS + int(round(0.1 * n_scans * 1e9)), transform(x=speed_mps * 0.1
                                                                          * n_scans)))
    return write_ros2_mcap(path, laserscans=scans, scan_range=(0.1, 75.0), odometry=odom,
                           tf_static=[("base_link", "laser", transform(x=0.5))],
                           chunk_size=chunk_size, poses_first=poses_first)
