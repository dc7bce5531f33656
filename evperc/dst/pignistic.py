"""Pignistic probability (method.md §2, §6)."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from evperc.dst.combine import total_conflict_tolerance
from evperc.dst.transforms import float_dtype, frame_bits


@lru_cache(maxsize=16)
def _share_matrix(n: int, dtype: np.dtype) -> np.ndarray:
    """W[A, θ] = 1/|A| if θ ∈ A else 0 (row ∅ is zero)."""
    subsets = np.arange(1 << n)[:, None]
    member = (subsets >> np.arange(n)[None, :] & 1).astype(np.float64)
    size = member.sum(axis=1, keepdims=True)
    w = np.divide(member, size, out=np.zeros_like(member), where=size > 0).astype(dtype)
    w.setflags(write=False)
    return w


def pignistic(m: np.ndarray) -> np.ndarray:
    """betP(θ) = Σ_{A ∋ θ} m(A) / (|A| (1 − m(∅))), shape ``(..., n)``; class k is bit k.

    The normaliser is computed as Σ_{A ≠ ∅} m(A), which equals 1 − m(∅) for a mass
    function summing to 1 and keeps Σ_θ betP(θ) = 1 under float round-off. Cells with
    m(∅) = 1 (normaliser ≤ the total-conflict tolerance) give all zeros, never NaN.
    """
    m = np.asarray(m)
    n = frame_bits(m)
    dtype = float_dtype(m)
    m = m.astype(dtype, copy=False)
    shares = np.matmul(m, _share_matrix(n, dtype))
    norm = m[..., 1:].sum(axis=-1, keepdims=True)
    ok = norm > total_conflict_tolerance(n, dtype)
    return np.divide(shares, norm, out=np.zeros_like(shares), where=ok)
