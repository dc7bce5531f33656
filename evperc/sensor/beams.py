"""Beam geometry: lidar points in the sensor's horizontal frame and on its polar grid (SPEC §3).

The *horizontal sensor frame* has its origin at the sensor, z vertical (the CRS up axis) and
x along the sensor's heading ψ, the CRS azimuth of the sensor's x axis projected on the
horizontal plane. Points are rotated by the full attitude ``R`` of ``T_crs_sensor`` into
CRS-aligned offsets ``(x, y, z) = R·p`` (which removes roll and pitch); their azimuth in the
horizontal sensor frame is ``atan2(y, x) − ψ``. Keeping the azimuth relative to ψ keeps the
polar bins fixed to the scanner's own beam directions, so a 2-D scanner whose beam step
equals the bin width does not alias into alternately empty bins as the vehicle turns.

Polar grid: ``n_az = round(360° / azimuth_resolution_deg)`` azimuth bins of width
``Δ = 2π / n_az``, bin ``a`` centred on azimuth ``a·Δ`` (bin 0 straight ahead); range bins
of depth ``c`` (the cell size), bin ``k`` covering horizontal range ``[k·c, (k+1)·c)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PolarLayout:
    """The polar grid: ``n_az`` azimuth bins of ``az_step_rad``, ``n_range`` range bins of
    ``range_bin_m`` (enough to hold every range below ``max_range_m``)."""

    n_az: int
    az_step_rad: float
    n_range: int
    range_bin_m: float
    min_range_m: float
    max_range_m: float

    @staticmethod
    def build(azimuth_resolution_deg: float, range_bin_m: float, min_range_m: float,
              max_range_m: float) -> PolarLayout:
        n_az = max(1, int(round(360.0 / azimuth_resolution_deg)))
        n_range = int(max_range_m // range_bin_m) + 2
        return PolarLayout(n_az, 2.0 * math.pi / n_az, n_range, float(range_bin_m),
                           float(min_range_m), float(max_range_m))

    def azimuth_bin(self, azimuth_rad: np.ndarray) -> np.ndarray:
        """Bin index ``round(θ / Δ) mod n_az`` of azimuths relative to the heading (int32)."""
        scaled = np.rint(azimuth_rad * np.float32(1.0 / self.az_step_rad))
        return scaled.astype(np.int32) % np.int32(self.n_az)

    def range_bin(self, range_m: np.ndarray) -> np.ndarray:
        """Bin index ``⌊r / c⌋`` of non-negative horizontal ranges (int32)."""
        return (range_m * np.float32(1.0 / self.range_bin_m)).astype(np.int32)


def sensor_heading(t_crs_sensor: np.ndarray) -> float:
    """ψ: CRS azimuth (radians, counter-clockwise from east) of the sensor's x axis projected
    on the horizontal plane."""
    return math.atan2(t_crs_sensor[1, 0], t_crs_sensor[0, 0])


def as_pose(t_crs_sensor: np.ndarray) -> np.ndarray:
    """The pose as a float64 (4, 4) array; ValueError for any other shape."""
    t = np.asarray(t_crs_sensor, dtype=np.float64)
    if t.shape != (4, 4):
        raise ValueError(f"T_crs_sensor must have shape (4, 4), got {t.shape}")
    return t


def level_points(points: np.ndarray, t_crs_sensor: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CRS-aligned offsets ``(x, y, z) = R·p`` (float32, 1-D) of the finite ``points`` (N, 3),
    sensor at the origin; NaN/inf rows are dropped."""
    pts = np.asarray(points, dtype=np.float32)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {pts.shape}")
    t = as_pose(t_crs_sensor)
    if not np.isfinite(pts.sum()):
        pts = pts[np.isfinite(pts).all(axis=1)]
    r = t[:3, :3].astype(np.float32)
    px, py, pz = pts[:, 0], pts[:, 1], pts[:, 2]
    # written out rather than pts @ r.T: a (N, 3) matmul goes through threaded BLAS, which
    # stalls when the cores are shared
    return (r[0, 0] * px + r[0, 1] * py + r[0, 2] * pz,
            r[1, 0] * px + r[1, 1] * py + r[1, 2] * pz,
            r[2, 0] * px + r[2, 1] * py + r[2, 2] * pz)


def polar_coordinates(x: np.ndarray, y: np.ndarray, heading_rad: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal range ``√(x² + y²)`` and azimuth ``atan2(y, x) − ψ`` (not wrapped), float32."""
    range_m = np.sqrt(x * x + y * y)
    azimuth = np.arctan2(y, x) - np.float32(heading_rad)
    return range_m, azimuth
