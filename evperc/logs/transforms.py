"""Rigid transforms: quaternions (x, y, z, w), 4×4 matrices, and pose interpolation.

A transform ``T_a_b`` maps points from frame b into frame a (docs/conventions.md). Poses are
interpolated linearly in position and by spherical linear interpolation (slerp) in orientation:

    p(α) = (1 − α)·p0 + α·p1
    q(α) = sin((1 − α)θ)/sin θ · q0 + sin(αθ)/sin θ · q1,   cos θ = |q0 · q1|

with q1 negated first when q0 · q1 < 0 (the shorter arc).
"""

from __future__ import annotations

import numpy as np

#: below this angle between two quaternions slerp falls back to normalised lerp
_SLERP_LINEAR_BELOW_RAD = 1e-6


def normalise_quaternion(q: np.ndarray) -> np.ndarray:
    """``q / |q|`` along the last axis; a zero quaternion becomes the identity (0, 0, 0, 1)."""
    q = np.asarray(q, dtype=np.float64)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    identity = np.zeros_like(q)
    identity[..., 3] = 1.0
    return np.where(norm > 0.0, q / np.where(norm > 0.0, norm, 1.0), identity)


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix (..., 3, 3) of the unit quaternion(s) ``q`` = (x, y, z, w) (normalised)."""
    x, y, z, w = np.moveaxis(normalise_quaternion(q), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def pose_matrix(translation: np.ndarray, quaternion: np.ndarray) -> np.ndarray:
    """4×4 homogeneous matrix [R(q) | t; 0 0 0 1] (float64)."""
    T = np.eye(4)
    T[:3, :3] = quaternion_to_matrix(quaternion)
    T[:3, 3] = np.asarray(translation, dtype=np.float64)
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4×4 transform: [Rᵀ | −Rᵀt]."""
    out = np.eye(4)
    R = T[:3, :3]
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def slerp(q0: np.ndarray, q1: np.ndarray, alpha: float) -> np.ndarray:
    """Spherical linear interpolation from ``q0`` (α = 0) to ``q1`` (α = 1) on the shorter arc."""
    q0 = normalise_quaternion(q0)
    q1 = normalise_quaternion(q1)
    dot = float(np.dot(q0, q1))
    if dot < 0.0:
        q1, dot = -q1, -dot
    theta = np.arccos(min(dot, 1.0))
    if theta < _SLERP_LINEAR_BELOW_RAD:
        return normalise_quaternion((1.0 - alpha) * q0 + alpha * q1)
    s = np.sin(theta)
    return (np.sin((1.0 - alpha) * theta) / s) * q0 + (np.sin(alpha * theta) / s) * q1


def interpolate_pose(t0: np.ndarray, q0: np.ndarray, t1: np.ndarray, q1: np.ndarray,
                     alpha: float) -> np.ndarray:
    """4×4 pose between (t0, q0) and (t1, q1): lerp of the translation, slerp of the rotation."""
    t = (1.0 - alpha) * np.asarray(t0, dtype=np.float64) + alpha * np.asarray(t1, np.float64)
    return pose_matrix(t, slerp(q0, q1, alpha))


def extrinsic_matrix(x_m: float = 0.0, y_m: float = 0.0, z_m: float = 0.0,
                     roll_deg: float = 0.0, pitch_deg: float = 0.0,
                     yaw_deg: float = 0.0) -> np.ndarray:
    """4×4 from config ``input.extrinsic``: R = Rz(yaw)·Ry(pitch)·Rx(roll), then translation."""
    r, p, y = np.radians([roll_deg, pitch_deg, yaw_deg])
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = Rz @ Ry @ Rx
    T[:3, 3] = (x_m, y_m, z_m)
    return T
