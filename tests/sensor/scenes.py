"""Synthetic lidar scenes for the sensor-grid tests and benchmark: ray casting against a flat
ground and axis-aligned boxes, plus pose helpers. Plain numpy; no evperc code."""

from __future__ import annotations

import math

import numpy as np


def pose(x: float, y: float, z: float, yaw_deg: float = 0.0, pitch_deg: float = 0.0,
         roll_deg: float = 0.0) -> np.ndarray:
    """T_crs_sensor from a position and ZYX Euler angles (yaw about z, then pitch, roll)."""
    cy, sy = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    cp, sp = math.cos(math.radians(pitch_deg)), math.sin(math.radians(pitch_deg))
    cr, sr = math.cos(math.radians(roll_deg)), math.sin(math.radians(roll_deg))
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    t = np.eye(4)
    t[:3, :3] = rz @ ry @ rx
    t[:3, 3] = (x, y, z)
    return t


def to_sensor(points_crs: np.ndarray, t_crs_sensor: np.ndarray) -> np.ndarray:
    """Points given in the CRS → sensor frame (float32), inverting the pose."""
    r, t = t_crs_sensor[:3, :3], t_crs_sensor[:3, 3]
    return ((np.asarray(points_crs, float) - t) @ r).astype(np.float32)


def ray_cast(directions: np.ndarray, height_m: float, boxes: list[tuple], max_range_m: float
             ) -> np.ndarray:
    """Returns (sensor-relative, level frame) of unit ``directions`` (M, 3) against the ground
    plane z = −height_m and boxes ``(xmin, ymin, zmin, xmax, ymax, zmax)`` in the same frame;
    rays without a hit within max_range_m are dropped."""
    d = np.asarray(directions, float)
    best = np.full(len(d), np.inf)
    down = d[:, 2] < -1e-9
    best[down] = -height_m / d[down, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        for box in boxes:
            lo, hi = np.array(box[:3]), np.array(box[3:])
            t1, t2 = lo * inv, hi * inv
            t_near = np.nanmax(np.minimum(t1, t2), axis=1)
            t_far = np.nanmin(np.maximum(t1, t2), axis=1)
            hit = (t_far >= t_near) & (t_near > 0)
            best = np.where(hit & (t_near < best), t_near, best)
    keep = best < max_range_m
    return d[keep] * best[keep, None]


def hdl64_directions(n_azimuth: int = 1875, rng: np.random.Generator | None = None
                     ) -> np.ndarray:
    """64 rings from −24.9° to +2° elevation × ``n_azimuth`` azimuth steps (HDL-64E-like)."""
    elev = np.radians(np.linspace(-24.9, 2.0, 64))
    az = np.linspace(-math.pi, math.pi, n_azimuth, endpoint=False)
    if rng is not None:
        az = az + rng.uniform(0, 2 * math.pi / n_azimuth)
    e, a = np.meshgrid(elev, az, indexing="ij")
    return np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3)


def street_boxes() -> list[tuple]:
    """Parked cars both sides, a wall each side, a pole, a truck (level frame, sensor at 0)."""
    h = -1.73
    cars = [(x0, side * 4.5 - 0.9, h, x0 + 4.2, side * 4.5 + 0.9, h + 1.5)
            for side in (-1, 1) for x0 in (-30.0, -20.0, -8.0, 6.0, 14.0, 26.0)]
    walls = [(-80.0, 12.0, h, 80.0, 12.5, h + 6.0), (-80.0, -12.5, h, 80.0, -12.0, h + 6.0)]
    pole = (20.0, 2.0, h, 20.15, 2.15, h + 4.0)
    truck = (-40.0, -2.0, h, -30.0, 1.0, h + 3.5)
    return [*cars, *walls, pole, truck]


def hdl64_scene(seed: int = 0) -> np.ndarray:
    """~120k-point synthetic HDL-64-like cloud of a street (float32, sensor frame = level)."""
    rng = np.random.default_rng(seed)
    pts = ray_cast(hdl64_directions(rng=rng), 1.73, street_boxes(), 100.0)
    pts += rng.normal(0, 0.02, pts.shape)
    return pts.astype(np.float32)


def ibeo_scene(seed: int = 0) -> np.ndarray:
    """≤800-point ibeo-like scan: 4 layers (−1.2°, −0.4°, 0.4°, 1.2° elevation) × 200 beams
    over ±50° ahead, mounted 0.5 m above the road, looking down the same street."""
    rng = np.random.default_rng(seed)
    elev = np.radians([-1.2, -0.4, 0.4, 1.2])
    az = np.radians(np.linspace(-50, 50, 200))
    e, a = np.meshgrid(elev, az, indexing="ij")
    d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3)
    boxes = [(b[0], b[1], b[2] + 1.23, b[3], b[4], b[5] + 1.23) for b in street_boxes()]
    pts = ray_cast(d, 0.5, boxes, 200.0)
    pts += rng.normal(0, 0.02, pts.shape)
    return pts.astype(np.float32)
