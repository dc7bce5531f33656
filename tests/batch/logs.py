"""Tiny synthetic drives for the batch tests and benchmark: a straight street between two
walls, written as ROS 2 MCAP (PointCloud2 in ``velodyne``, Odometry ``map -> base_link``,
/tf_static ``base_link -> velodyne``) with :func:`tests.mcap_writers.write_ros2_mcap`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tests.mcap_writers import transform, write_ros2_mcap

START_NS = 1_600_000_000 * 1_000_000_000
SCAN_PERIOD_NS = 100_000_000
LIDAR_HEIGHT_M = 1.73


def write_street_log(path: str | Path, n_scans: int, seed: int = 0,
                     points_per_scan: int = 1500, speed_m_per_s: float = 5.0) -> Path:
    """A drive along +x at ``speed_m_per_s`` between walls at y = ±(6 + seed/10) m, with a
    parked box and ground returns; ``seed`` also varies the points so logs differ."""
    rng = np.random.default_rng(seed)
    half_width = 6.0 + 0.1 * seed
    T_base_lidar = transform(z=LIDAR_HEIGHT_M)
    clouds, odometry = [], []
    for k in range(n_scans + 2):  # odometry brackets every scan
        ns = START_NS + k * SCAN_PERIOD_NS
        T_world_base = transform(x=speed_m_per_s * k * SCAN_PERIOD_NS * 1e-9, yaw=0.01 * k)
        odometry.append((ns - SCAN_PERIOD_NS // 2, T_world_base))
        if k >= n_scans:
            continue
        x0 = T_world_base[0, 3]
        n = points_per_scan // 3
        walls = np.column_stack([x0 + rng.uniform(-15, 15, 2 * n),
                                 np.repeat([-half_width, half_width], n),
                                 rng.uniform(0.5, 2.4, 2 * n)])
        box = np.column_stack([rng.uniform(8, 12, n // 2) + 3.0 * seed,
                               np.full(n // 2, 2.0), rng.uniform(0.4, 1.5, n // 2)])
        ground = np.column_stack([x0 + rng.uniform(-12, 12, n), rng.uniform(-5, 5, n),
                                  np.zeros(n)])
        world = np.vstack([walls, box, ground])
        T_world_lidar = T_world_base @ T_base_lidar
        homogeneous = np.column_stack([world, np.ones(len(world))])
        local = (np.linalg.inv(T_world_lidar) @ homogeneous.T).T[:, :3]
        clouds.append((ns, np.column_stack([local, np.ones(len(local))]).astype(np.float32),
                       "velodyne"))
    return write_ros2_mcap(path, clouds=clouds, cloud_topic="/velodyne_points",
                           odometry=odometry, odom_topic="/odom",
                           odom_frames=("map", "base_link"),
                           tf_static=[("base_link", "velodyne", T_base_lidar)])
