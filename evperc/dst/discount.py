"""Discounting (method.md §2, §5.3): classical and contextual (Mercier, Quost, Denœux 2008).

Rates broadcast over the leading axes of the mass array: a scalar, or one rate per cell.
Rates are not range-checked here (they come validated from the configuration); they must
lie in [0, 1].
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from evperc.dst.transforms import (
    Kernel,
    apply_matrix,
    float_dtype,
    frame_bits,
    transform_matrix,
    use_matrix,
)


def discount(m: np.ndarray, alpha: ArrayLike) -> np.ndarray:
    """Classical discounting: ^α m(A) = (1 − α) m(A) for A ≠ Ω, ^α m(Ω) = (1 − α) m(Ω) + α.

    ``alpha`` is a scalar or an array broadcasting against ``m.shape[:-1]``.
    """
    m = np.asarray(m)
    frame_bits(m)
    dtype = float_dtype(m)
    a = np.asarray(alpha, dtype=dtype)[..., None]
    out = m.astype(dtype) * (1 - a)
    out[..., -1:] += a
    return out


def contextual_discount_matrix(alphas: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """T with ``m @ T`` = contextual discount of m for fixed rates ``alphas`` (n,).

    T = B · diag(b_α) · B⁻¹, B the implicability transform and
    b_α(A) = Π_{θ ∉ A} (1 − α_θ) the implicability of m_θ1 ∪ … ∪ m_θn.
    """
    n = alphas.shape[0]
    subsets = np.arange(1 << n)[:, None]
    outside = (subsets >> np.arange(n)[None, :] & 1) == 0
    b_alpha = np.prod(np.where(outside, 1.0 - alphas.astype(np.float64), 1.0), axis=1)
    forward = transform_matrix(n, "down", False, np.dtype(np.float64))
    inverse = transform_matrix(n, "down", True, np.dtype(np.float64))
    return ((forward * b_alpha[None, :]) @ inverse).astype(dtype)


def contextual_discount(m: np.ndarray, alphas: ArrayLike, kernel: Kernel = "auto"
                        ) -> np.ndarray:
    """Contextual discounting ^α m = m ∪ m_θ1 ∪ … ∪ m_θn, one rate α_θ per class.

    m_θ(∅) = 1 − α_θ, m_θ({θ}) = α_θ (Mercier et al. 2008). Combining with one m_θ is one
    butterfly over the bit of θ: for A ∌ θ, the result at A is (1 − α_θ) m(A) and at
    A ∪ {θ} it is m(A ∪ {θ}) + α_θ m(A). Equivalently b'(A) = b(A) Π_{θ ∉ A} (1 − α_θ).

    ``alphas`` has shape ``(n,)`` (same rates everywhere) or ``(..., n)`` broadcasting
    against ``m.shape[:-1]`` (per-cell rates); class ``k`` is bit ``k`` of the frame.
    Rates shared by all cells on a small frame (``kernel="auto"``) use one product with
    the precomputed matrix of :func:`contextual_discount_matrix` instead; the result is
    then clipped to [0, 1] against round-off.
    """
    m = np.asarray(m)
    n = frame_bits(m)
    dtype = float_dtype(m)
    a = np.asarray(alphas, dtype=dtype)
    if a.shape[-1:] != (n,):
        raise ValueError(f"alphas must have last axis {n} (one rate per class), got {a.shape}")
    if a.ndim == 1 and kernel != "butterfly" and use_matrix(n, kernel):
        out = apply_matrix(m.astype(dtype, copy=False), contextual_discount_matrix(a, dtype))
        return np.clip(out, 0.0, 1.0, out=out)
    lead = np.broadcast_shapes(m.shape[:-1], a.shape[:-1])
    out = np.array(np.broadcast_to(m, (*lead, m.shape[-1])), dtype=dtype, order="C", copy=True)
    for k in range(n):
        rate = a[..., k]
        if a.ndim == 1 and rate == 0:
            continue
        rate = rate[..., None, None]
        v = out.reshape(*lead, 1 << (n - 1 - k), 2, 1 << k)
        lo, hi = v[..., 0, :], v[..., 1, :]
        hi += rate * lo
        lo *= 1 - rate
    return out
