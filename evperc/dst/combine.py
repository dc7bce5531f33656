"""Combination rules (method.md §2), cell-wise over ``(..., 2**n)`` mass arrays.

    conjunctive  (m1 ∩ m2)(A) = Σ_{B∩C=A} m1(B) m2(C)   computed as q12 = q1 · q2
    disjunctive  (m1 ∪ m2)(A) = Σ_{B∪C=A} m1(B) m2(C)   computed as b12 = b1 · b2
    Dempster     m1 ⊕ m2 = (m1 ∩ m2) / (1 − K) off ∅,   K = (m1 ∩ m2)(∅)
    Yager        m1 ∩ m2 with K moved to Ω

Leading axes broadcast (a grid may be combined with a single mass vector). The result is
float32 only when both inputs are float32.

Round-off: the inverse Möbius transform is an alternating sum of up to 2**n terms, so a
mass that is exactly 0 can come out as about −2ⁿ·ε (−4e-6 in float32 for n = 5). Results
of every rule here are therefore clipped to [0, 1]; the sum then stays 1 within the same
tolerance.
"""

from __future__ import annotations

import numpy as np

from evperc.dst.transforms import (
    Kernel,
    apply_matrix,
    butterflies_inplace,
    float_dtype,
    frame_bits,
    from_subset_major,
    to_subset_major,
    transform_matrix,
    use_matrix,
)


def _pair_shapes(m1: np.ndarray, m2: np.ndarray) -> int:
    n = frame_bits(m1)
    if m2.shape[-1:] != m1.shape[-1:]:
        raise ValueError(f"mass arrays on different frames: shapes {m1.shape} and {m2.shape}")
    return n


def _combine(m1: np.ndarray, m2: np.ndarray, direction: str, kernel: Kernel) -> np.ndarray:
    """Product rule in the transformed domain (q for ∩, b for ∪), clipped to [0, 1]."""
    m1, m2 = np.asarray(m1), np.asarray(m2)
    n = _pair_shapes(m1, m2)
    dtype = float_dtype(m1, m2)
    if use_matrix(n, kernel):
        forward = transform_matrix(n, direction, False, dtype)
        t1, t2 = apply_matrix(m1, forward), apply_matrix(m2, forward)
        t = np.multiply(t1, t2, out=t1 if t1.shape == np.broadcast_shapes(t1.shape, t2.shape)
                        else None)
        out = apply_matrix(t, transform_matrix(n, direction, True, dtype))
    else:
        b1, b2 = np.broadcast_arrays(m1, m2)
        x1, x2 = to_subset_major(b1, dtype), to_subset_major(b2, dtype)
        butterflies_inplace(x1, n, direction, inverse=False)
        butterflies_inplace(x2, n, direction, inverse=False)
        x1 *= x2
        butterflies_inplace(x1, n, direction, inverse=True)
        out = from_subset_major(x1, b1.shape[:-1])
    np.clip(out, 0.0, 1.0, out=out)
    return out


def conjunctive(m1: np.ndarray, m2: np.ndarray, kernel: Kernel = "auto") -> np.ndarray:
    """Unnormalised conjunctive rule m1 ∩ m2 (mass on ∅ is the conflict K)."""
    return _combine(m1, m2, "up", kernel)


def disjunctive(m1: np.ndarray, m2: np.ndarray, kernel: Kernel = "auto") -> np.ndarray:
    """Disjunctive rule m1 ∪ m2."""
    return _combine(m1, m2, "down", kernel)


def total_conflict_tolerance(n: int, dtype: np.dtype) -> float:
    """Cells whose non-conflicting mass 1 − K is at most this are totally conflicting.

    It bounds the round-off of one conjunctive combination (2**n-term sums), below which
    a normalisation by 1 − K would only amplify noise.
    """
    return 4.0 * (1 << n) * float(np.finfo(dtype).eps)


def dempster(m1: np.ndarray, m2: np.ndarray, kernel: Kernel = "auto"
             ) -> tuple[np.ndarray, np.ndarray]:
    """Dempster's rule: ``(m, K)`` with m = (m1 ∩ m2)/(1 − K) off ∅, m(∅) = 0.

    ``K`` (shape ``(...)``) is the conflict per cell. The normaliser is computed as
    Σ_{A≠∅} (m1 ∩ m2)(A) (= 1 − K for inputs summing to 1), so the result sums to 1 even
    in float32 near total conflict. Total conflict is reported, not raised: where that
    normaliser is ≤ :func:`total_conflict_tolerance` the returned ``K`` is exactly 1 and
    the returned masses are all zero (not a mass function: the caller decides what
    such a cell becomes, e.g. ``np.where(K[..., None] == 1, vacuous, m)``). Never NaN.
    """
    c = conjunctive(m1, m2, kernel)
    n = frame_bits(c)
    conflict = c[..., 0].copy()
    # Σ_{A≠∅} c(A) equals 1 − K for inputs summing to 1; dividing by it keeps the result
    # summing to 1 under round-off, which 1 − K alone does not when K is close to 1.
    kept = c[..., 1:].sum(axis=-1)
    total = kept <= total_conflict_tolerance(n, c.dtype)
    scale = np.where(total, 0.0, 1.0 / np.where(total, 1.0, kept)).astype(c.dtype)
    c *= scale[..., None]
    c[..., 0] = 0.0
    np.clip(c, 0.0, 1.0, out=c)
    conflict[total] = 1.0
    return c, conflict


def yager(m1: np.ndarray, m2: np.ndarray, kernel: Kernel = "auto") -> np.ndarray:
    """Yager's rule: m1 ∩ m2 with the conflict K = (m1 ∩ m2)(∅) moved to Ω."""
    c = conjunctive(m1, m2, kernel)
    c[..., -1] += c[..., 0]
    c[..., 0] = 0.0
    np.clip(c, 0.0, 1.0, out=c)
    return c
