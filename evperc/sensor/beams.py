"""Beam geometry: lidar points in the sensor's horizontal frame and on its polar grid (method §3).

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

Arithmetic is float32: levelling ``R·p``, range ``√(x² + y²)``, azimuth bin
``rint((θ − ψ)·(1/Δ)) mod n_az`` and range bin ``⌊r·(1/c)⌋``. The azimuths ``θ`` themselves
come from numpy's float32 ``arctan2`` between the two compiled per-point passes
(:func:`level_points`, :func:`polar_bins`), as do those of the cell centres in
:mod:`.projection`: numpy's vectorised arctan2 is ~20× faster than the scalar libm
``atan2f`` a numba loop would call, and the two differ in the last bit for many inputs,
which would move points lying on a bin edge.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

#: bin index of a point that is dropped (non-finite, or range outside [min, max))
DROPPED = -1
#: bound on the number of azimuth bins that keeps float32 azimuths, rounded to a bin, within
#: one turn of [0, n_az) (:func:`wrap_bin`)
MAX_AZIMUTH_BINS = 1 << 20


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
        if n_az >= MAX_AZIMUTH_BINS:
            raise ValueError(f"azimuth_resolution_deg {azimuth_resolution_deg} is too fine")
        n_range = int(max_range_m // range_bin_m) + 2
        return PolarLayout(n_az, 2.0 * math.pi / n_az, n_range, float(range_bin_m),
                           float(min_range_m), float(max_range_m))

    @property
    def inv_az_step32(self) -> np.float32:
        """1/Δ in float32, the factor of the azimuth binning."""
        return np.float32(1.0 / self.az_step_rad)

    @property
    def inv_range_bin32(self) -> np.float32:
        """1/c in float32, the factor of the range binning."""
        return np.float32(1.0 / self.range_bin_m)


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


def as_points(points: np.ndarray) -> np.ndarray:
    """The points as a C-ordered float32 (N, 3) array; ValueError for any other shape."""
    pts = np.ascontiguousarray(points, dtype=np.float32)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {pts.shape}")
    return pts


@numba.njit(cache=True, nogil=True)
def level_points(xyz: np.ndarray, rotation: np.ndarray, x: np.ndarray, y: np.ndarray,
                 z: np.ndarray, range_m: np.ndarray) -> None:
    """Write the CRS-aligned offsets ``(x, y, z) = R·p`` and the horizontal range
    ``√(x² + y²)`` (float32) of every point ``p`` into ``x``, ``y``, ``z``, ``range_m`` (N,);
    ``xyz`` holds the points as ``x0, y0, z0, x1, …`` (a C-ordered (N, 3) array, flattened),
    ``rotation`` is R as float32 (3, 3). A point with a non-finite coordinate gets
    non-finite x, y, z and range (each offset sums all three ``R_ij·p_j``, and 0·inf is
    NaN), so :func:`polar_bins` drops it by its range."""
    r00, r01, r02 = rotation[0, 0], rotation[0, 1], rotation[0, 2]
    r10, r11, r12 = rotation[1, 0], rotation[1, 1], rotation[1, 2]
    r20, r21, r22 = rotation[2, 0], rotation[2, 1], rotation[2, 2]
    for i in range(x.shape[0]):
        px, py, pz = xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]
        xi = r00 * px + r01 * py + r02 * pz
        yi = r10 * px + r11 * py + r12 * pz
        x[i] = xi
        y[i] = yi
        z[i] = r20 * px + r21 * py + r22 * pz
        range_m[i] = np.sqrt(xi * xi + yi * yi)


@numba.njit(cache=True, nogil=True)
def polar_bins(range_m: np.ndarray, azimuth: np.ndarray, heading: np.float32,
               inv_az_step: np.float32, n_az: int, min_range: np.float32,
               max_range: np.float32, inv_range_bin: np.float32, az_bin: np.ndarray,
               range_bin: np.ndarray) -> None:
    """Per point: azimuth bin ``rint((θ − ψ)/Δ) mod n_az`` into ``az_bin`` (θ = ``azimuth``
    = atan2(y, x)) and range bin ``⌊r/c⌋`` into ``range_bin`` (float32 arithmetic);
    ``az_bin`` is :data:`DROPPED` where ``r`` is not in ``[min_range, max_range)``, which
    includes NaN / inf ranges."""
    for i in range(range_m.shape[0]):
        r = range_m[i]
        kept = (r >= min_range) & (r < max_range)
        a = wrap_bin(np.int32(np.rint((azimuth[i] - heading) * inv_az_step)), n_az)
        az_bin[i] = a if kept else DROPPED
        range_bin[i] = np.int32(r * inv_range_bin) if kept else 0


@numba.njit(cache=True, nogil=True, inline="always")
def wrap_bin(v: int, n: int) -> int:
    """``v mod n`` for ``v`` in ``[−n, 2n)``, without a division or a branch. Azimuth bins
    ``rint((θ − ψ)/Δ)`` with θ, ψ in [−π, π] (float32) lie in ``[−n, n]`` for
    ``n <`` :data:`MAX_AZIMUTH_BINS`."""
    v = v + n if v < 0 else v
    return v - n if v >= n else v
