"""Shared pieces for the log-reading tests: stamps, an independent pose interpolation."""

from __future__ import annotations

import numpy as np

S0 = 1_700_000_000_000_000_000  # a stamp base in 2023, ns


def rodrigues(axis_angle: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (Rodrigues' formula)."""
    theta = float(np.linalg.norm(axis_angle))
    if theta < 1e-15:
        return np.eye(3)
    k = axis_angle / theta
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * K @ K


def log_rotation(R: np.ndarray) -> np.ndarray:
    """Rotation vector of R (angle below pi)."""
    theta = np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))
    if theta < 1e-15:
        return np.zeros(3)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return theta * w / (2 * np.sin(theta))


def geodesic_interpolation(T0: np.ndarray, T1: np.ndarray, alpha: float) -> np.ndarray:
    """Independent reference: R0·exp(α·log(R0ᵀR1)) and linear translation."""
    T = np.eye(4)
    T[:3, :3] = T0[:3, :3] @ rodrigues(alpha * log_rotation(T0[:3, :3].T @ T1[:3, :3]))
    T[:3, 3] = (1 - alpha) * T0[:3, 3] + alpha * T1[:3, 3]
    return T
