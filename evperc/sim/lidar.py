"""Vectorised lidar ray casting against the 2.5-D scene.

The lidar is level (no roll/pitch) at height ``z0`` above the flat ground ``z = 0``. A beam
with azimuth ``a`` (world) and elevation ``e`` travels the horizontal distance ``s`` along
``(cos a, sin a)`` at height ``z(s) = z0 + s·tan e`` and has range ``s / cos e``.

1. Per azimuth (2-D): each solid's horizontal entry/exit ``[s_in, s_out]`` (slab test for
   oriented boxes, the quadratic for cylinders; walls are segments with ``s_in = s_out``).
   Only the ``k`` nearest candidates per azimuth are kept.
2. Per beam (3-D): a candidate is hit at ``s_in`` if ``0 ≤ z(s_in) ≤ h``; a descending beam
   above it at ``s_in`` hits its roof at ``s = (z0 − h)/(−tan e)`` if that is ``≤ s_out``.
   The ground is hit at ``s = z0 / (−tan e)`` for descending beams. The nearest hit wins.
3. Range noise (Gaussian), dropouts (Bernoulli) and no-returns beyond the maximum range.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evperc.sim.scene import BOX, INFRASTRUCTURE, Solids

GROUND = 0  # label of ground returns in :class:`Hits`


@dataclass(frozen=True)
class LidarProfile:
    """Beam pattern and noise of one sensor model; angles in radians, sensor frame."""

    name: str
    azimuths: np.ndarray      # (A,) relative to the sensor's x axis (forward), CCW
    elevations: np.ndarray    # (L,)
    max_range_m: float
    min_range_m: float
    range_noise_m: float
    dropout: float
    mount_xyz_m: tuple[float, float, float]   # lidar in base_link: forward, left, up
    planar: bool = False
    candidates: int = 8


def make_profile(name: str, range_noise_m: float | None = None, dropout: float | None = None
                 ) -> LidarProfile:
    """``ibeo4`` (IBEO Alaska XT-like: 4 layers ±1.2°, 150° in front, 200 beams a layer),
    ``hdl64`` (Velodyne HDL-64E-like: 64 layers −24.8°..+2°, 360° in 2,000 steps),
    ``vlp16`` (Velodyne VLP-16-like: 16 layers −15°..+15° 2° apart, 360° in 1,800 steps, 100 m,
    on the roof at 1.8 m; a geometry no default was tuned on), ``hdl32`` (Velodyne
    HDL-32E-like: 32 layers −30.67°..+10.67° 1.33° apart, 360° in 1,800 steps, 100 m, on the
    roof at 1.9 m) or ``scan2d`` (a planar 270° LaserScan at 0.5°)."""
    deg = np.deg2rad
    if name == "ibeo4":
        prof = LidarProfile(name, deg(np.linspace(-75.0, 75.0, 200)),
                            deg(np.array([-1.2, -0.4, 0.4, 1.2])), 80.0, 0.3, 0.03, 0.01,
                            (3.7, 0.0, 0.5))
    elif name == "hdl64":
        prof = LidarProfile(name, deg(np.arange(2000) * 0.18 - 180.0),
                            deg(np.linspace(-24.8, 2.0, 64)), 80.0, 1.0, 0.02, 0.01,
                            (1.5, 0.0, 1.9), candidates=16)
    elif name == "vlp16":
        prof = LidarProfile(name, deg(np.arange(1800) * 0.2 - 180.0),
                            deg(np.arange(-15.0, 16.0, 2.0)), 100.0, 0.5, 0.03, 0.01,
                            (1.5, 0.0, 1.8), candidates=16)
    elif name == "hdl32":
        prof = LidarProfile(name, deg(np.arange(1800) * 0.2 - 180.0),
                            deg(np.linspace(-30.67, 10.67, 32)), 100.0, 1.0, 0.02, 0.01,
                            (1.5, 0.0, 1.9), candidates=16)
    elif name == "scan2d":
        prof = LidarProfile(name, deg(np.linspace(-135.0, 135.0, 541)), np.zeros(1), 40.0, 0.1,
                            0.02, 0.01, (1.0, 0.0, 0.5), planar=True)
    else:
        raise ValueError(f"unknown lidar profile {name!r}")
    changes = {}
    if range_noise_m is not None:
        changes["range_noise_m"] = range_noise_m
    if dropout is not None:
        changes["dropout"] = dropout
    return LidarProfile(**{**prof.__dict__, **changes})


@dataclass(frozen=True)
class Hits:
    """One scan. ``range_m`` (L, A) is NaN where there is no return; ``label`` (L, A) the
    truth class of what was hit (``GROUND`` for the ground); ``horizontal_m`` = range·cos e."""

    range_m: np.ndarray
    horizontal_m: np.ndarray
    label: np.ndarray
    azimuths: np.ndarray
    elevations: np.ndarray

    def points(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Returns as ``(N, 3)`` float32 sensor-frame points, ``(N,)`` float32 intensity and
        ``(N,)`` uint16 layer index (0 = the lowest elevation: the ``ring`` a driver writes),
        in row-major (layer, azimuth) order."""
        ok = np.isfinite(self.range_m)
        e = np.broadcast_to(self.elevations[:, None], ok.shape)[ok]
        a = np.broadcast_to(self.azimuths[None, :], ok.shape)[ok]
        r = self.range_m[ok]
        pts = np.column_stack([r * np.cos(e) * np.cos(a), r * np.cos(e) * np.sin(a),
                               r * np.sin(e)]).astype(np.float32)
        intensity = np.where(self.label[ok] == GROUND, 0.1, 0.2 + 0.1 * self.label[ok])
        ring = np.broadcast_to(np.argsort(np.argsort(self.elevations))[:, None], ok.shape)[ok]
        return pts, intensity.astype(np.float32), ring.astype(np.uint16)


def solid_intervals(sx: float, sy: float, az: np.ndarray, solids: Solids
                    ) -> tuple[np.ndarray, np.ndarray]:
    """(A, N) horizontal entry and exit distances of the beams at world azimuths ``az`` into
    each solid (inf where missed)."""
    ux, uy = np.cos(az)[:, None], np.sin(az)[:, None]
    dx, dy = (sx - solids.x)[None, :], (sy - solids.y)[None, :]
    # cylinders: |o + s·u − c|² = r²
    b = ux * dx + uy * dy
    cc = dx * dx + dy * dy - (solids.length / 2)[None, :] ** 2
    disc = b * b - cc
    root = np.sqrt(np.maximum(disc, 0.0))
    cyl_in, cyl_out = -b - root, -b + root
    cyl_ok = disc >= 0
    # boxes: slab test in the box frame
    c, s = np.cos(solids.heading)[None, :], np.sin(solids.heading)[None, :]
    ox, oy = c * dx + s * dy, -s * dx + c * dy
    vx, vy = c * ux + s * uy, -s * ux + c * uy
    vx = np.where(np.abs(vx) < 1e-12, 1e-12, vx)
    vy = np.where(np.abs(vy) < 1e-12, 1e-12, vy)
    hx, hy = (solids.length / 2)[None, :], (solids.width / 2)[None, :]
    tx1, tx2 = (-hx - ox) / vx, (hx - ox) / vx
    ty1, ty2 = (-hy - oy) / vy, (hy - oy) / vy
    box_in = np.maximum(np.minimum(tx1, tx2), np.minimum(ty1, ty2))
    box_out = np.minimum(np.maximum(tx1, tx2), np.maximum(ty1, ty2))
    box_ok = box_out >= box_in
    is_box = (solids.kind == BOX)[None, :]
    s_in = np.where(is_box, box_in, cyl_in)
    s_out = np.where(is_box, box_out, cyl_out)
    ok = np.where(is_box, box_ok, cyl_ok) & (s_in > 0.05)
    return np.where(ok, s_in, np.inf), np.where(ok, s_out, np.inf)


def wall_intervals(sx: float, sy: float, az: np.ndarray, walls: np.ndarray) -> np.ndarray:
    """(A, W) horizontal distance at which each beam crosses each wall segment (inf if not)."""
    ux, uy = np.cos(az)[:, None], np.sin(az)[:, None]
    ddx, ddy = (walls[:, 2] - walls[:, 0])[None, :], (walls[:, 3] - walls[:, 1])[None, :]
    wx, wy = (walls[:, 0] - sx)[None, :], (walls[:, 1] - sy)[None, :]
    denom = ux * ddy - uy * ddx
    safe = np.where(np.abs(denom) < 1e-12, np.nan, denom)
    s = (wx * ddy - wy * ddx) / safe
    t = (wx * uy - wy * ux) / safe
    ok = (s > 0.05) & (t >= 0.0) & (t <= 1.0)
    return np.where(ok, s, np.inf)


def cast(profile: LidarProfile, x: float, y: float, yaw: float, walls: np.ndarray,
         wall_height: np.ndarray, solids: Solids, rng: np.random.Generator) -> Hits:
    """Cast every beam of ``profile`` from the lidar at ``(x, y)`` (height ``mount z``),
    heading ``yaw``, against building walls (class I) and ``solids``; then add noise."""
    z0 = profile.mount_xyz_m[2]
    az = profile.azimuths + yaw
    reach = profile.max_range_m + 1.0
    near = _walls_near(walls, x, y, reach)
    wall_s = wall_intervals(x, y, az, walls[near])
    solid_near = np.hypot(solids.x - x, solids.y - y) < reach + solids.length
    sub = Solids(*(getattr(solids, f)[solid_near] for f in Solids.__dataclass_fields__))
    box_in, box_out = solid_intervals(x, y, az, sub)
    s_in = np.concatenate([wall_s, box_in], axis=1)
    s_out = np.concatenate([wall_s, box_out], axis=1)
    height = np.concatenate([wall_height[near], sub.height])
    label = np.concatenate([np.full(near.sum(), INFRASTRUCTURE, dtype=np.uint8), sub.label])
    k = min(profile.candidates, s_in.shape[1])
    if k == 0:
        s_in = np.full((len(az), 1), np.inf)
        s_out, height, label, k = s_in, np.zeros(1), np.zeros(1, dtype=np.uint8), 1
    elif k < s_in.shape[1]:
        pick = np.argpartition(s_in, k - 1, axis=1)[:, :k]
        s_in = np.take_along_axis(s_in, pick, 1)
        s_out = np.take_along_axis(s_out, pick, 1)
        height, label = height[pick], label[pick]
    else:
        height = np.broadcast_to(height, s_in.shape)
        label = np.broadcast_to(label, s_in.shape)
    tan_e = np.tan(profile.elevations)[:, None, None]
    finite = np.isfinite(s_in)[None]
    z_in = z0 + np.where(finite, s_in[None], 0.0) * tan_e
    front = finite & (z_in >= 0.0) & (z_in <= height[None])
    s_roof = np.where(tan_e < 0, (z0 - height[None]) / np.where(tan_e < 0, -tan_e, 1.0), np.inf)
    roof = finite & (z_in > height[None]) & (tan_e < 0) & (s_roof <= s_out[None])
    s_hit = np.where(front, s_in[None], np.where(roof, s_roof, np.inf))
    best = np.argmin(s_hit, axis=2)
    s_obj = np.take_along_axis(s_hit, best[..., None], 2)[..., 0]
    lab_obj = np.broadcast_to(label[None], s_hit.shape)
    lab_obj = np.take_along_axis(lab_obj, best[..., None], 2)[..., 0]
    tan2 = tan_e[:, :, 0]
    s_ground = np.where(tan2 < 0, z0 / np.where(tan2 < 0, -tan2, 1.0), np.inf)
    s_ground = np.broadcast_to(s_ground, s_obj.shape)
    hit_ground = s_ground < s_obj
    s_final = np.where(hit_ground, s_ground, s_obj)
    lab = np.where(hit_ground, GROUND, lab_obj).astype(np.uint8)
    cos_e = np.cos(profile.elevations)[:, None]
    rng_m = s_final / cos_e
    rng_m = rng_m + rng.normal(0.0, profile.range_noise_m, size=rng_m.shape)
    lost = rng.random(rng_m.shape) < profile.dropout
    valid = (rng_m <= profile.max_range_m) & (rng_m >= profile.min_range_m) & ~lost
    rng_m = np.where(valid, rng_m, np.nan)
    return Hits(rng_m, rng_m * cos_e, lab, profile.azimuths, profile.elevations)


def _walls_near(walls: np.ndarray, x: float, y: float, reach: float) -> np.ndarray:
    """Walls with a point within ``reach`` of (x, y) (bounding-box test)."""
    lo_x = np.minimum(walls[:, 0], walls[:, 2])
    hi_x = np.maximum(walls[:, 0], walls[:, 2])
    lo_y = np.minimum(walls[:, 1], walls[:, 3])
    hi_y = np.maximum(walls[:, 1], walls[:, 3])
    gap_x = np.maximum(0.0, np.maximum(lo_x - x, x - hi_x))
    gap_y = np.maximum(0.0, np.maximum(lo_y - y, y - hi_y))
    return np.hypot(gap_x, gap_y) <= reach
