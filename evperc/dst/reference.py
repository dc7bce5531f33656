"""Naive definitions, for tests and benchmarks only: the 4ⁿ pair loops and direct sums.

Each function follows its textbook definition over all pairs of subsets, vectorised over
the cells only. Nothing in the pipeline should call these.
"""

from __future__ import annotations

import numpy as np


def _n(m: np.ndarray) -> int:
    return m.shape[-1].bit_length() - 1


def conjunctive(m1: np.ndarray, m2: np.ndarray) -> np.ndarray:
    """(m1 ∩ m2)(A) = Σ_{B∩C=A} m1(B) m2(C)."""
    m1, m2 = np.broadcast_arrays(np.asarray(m1, float), np.asarray(m2, float))
    out = np.zeros(m1.shape)
    size = m1.shape[-1]
    for b in range(size):
        for c in range(size):
            out[..., b & c] += m1[..., b] * m2[..., c]
    return out


def disjunctive(m1: np.ndarray, m2: np.ndarray) -> np.ndarray:
    """(m1 ∪ m2)(A) = Σ_{B∪C=A} m1(B) m2(C)."""
    m1, m2 = np.broadcast_arrays(np.asarray(m1, float), np.asarray(m2, float))
    out = np.zeros(m1.shape)
    size = m1.shape[-1]
    for b in range(size):
        for c in range(size):
            out[..., b | c] += m1[..., b] * m2[..., c]
    return out


def commonality(m: np.ndarray) -> np.ndarray:
    """q(A) = Σ_{B ⊇ A} m(B)."""
    m = np.asarray(m, float)
    size = m.shape[-1]
    return np.stack([sum(m[..., b] for b in range(size) if b & a == a)
                     for a in range(size)], axis=-1)


def implicability(m: np.ndarray) -> np.ndarray:
    """b(A) = Σ_{B ⊆ A} m(B)."""
    m = np.asarray(m, float)
    size = m.shape[-1]
    return np.stack([sum(m[..., b] for b in range(size) if b & a == b)
                     for a in range(size)], axis=-1)


def plausibility(m: np.ndarray) -> np.ndarray:
    """pl(A) = Σ_{B ∩ A ≠ ∅} m(B)."""
    m = np.asarray(m, float)
    size = m.shape[-1]
    return np.stack([sum((m[..., b] for b in range(size) if b & a), np.zeros(m.shape[:-1]))
                     for a in range(size)], axis=-1)


def pignistic(m: np.ndarray) -> np.ndarray:
    """betP(θ) = Σ_{A ∋ θ} m(A) / (|A| (1 − m(∅)))."""
    m = np.asarray(m, float)
    n = _n(m)
    out = np.zeros((*m.shape[:-1], n))
    for a in range(1, 1 << n):
        members = [k for k in range(n) if a >> k & 1]
        for k in members:
            out[..., k] += m[..., a] / len(members)
    return out / (1.0 - m[..., :1])


def contextual_discount(m: np.ndarray, alphas: np.ndarray) -> np.ndarray:
    """m ∪ m_θ1 ∪ … ∪ m_θn with m_θ(∅) = 1 − α_θ, m_θ({θ}) = α_θ, by the pair loop."""
    m = np.asarray(m, float)
    alphas = np.asarray(alphas, float)
    out = m
    for k in range(_n(m)):
        m_theta = np.zeros((*alphas.shape[:-1], m.shape[-1]))
        m_theta[..., 0] = 1.0 - alphas[..., k]
        m_theta[..., 1 << k] = alphas[..., k]
        out = disjunctive(out, m_theta)
    return out
