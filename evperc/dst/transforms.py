"""Fast Möbius transforms between masses m, commonalities q and implicabilities b.

    q(A) = Σ_{B ⊇ A} m(B)        b(A) = Σ_{B ⊆ A} m(B)  (b includes m(∅))
    bel(A) = b(A) − m(∅)         pl(A) = b(Ω) − b(Ā)

Each transform is a product of ``n`` commuting 2×2 butterflies, one per class bit: for bit
``k`` the entry at ``A`` (without ``k``) and at ``A ∪ {k}`` are updated as a pair, giving
O(n·2ⁿ) operations per cell (Kennes 1992; Smets 2002). Arrays are ``(..., 2**n)``, any
leading shape; the dtype of the input is kept for float32/float64 (other dtypes become
float64). Inputs are never modified.

Two equivalent kernels compute the same linear maps:
- ``butterfly``: the n stages on a subset-major copy ``(2**n, cells)``, so each stage adds
  two contiguous blocks;
- ``matrix``: one product with the dense 0/±1 transform matrix. For small frames this is
  faster in practice (one BLAS call against n strided passes; see benchmarks/bench_dst.py)
  although it does O(4ⁿ) work per cell, so it is only used up to :data:`MATRIX_MAX_N`.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Literal

import numpy as np

from evperc.dst.frame import MAX_CLASSES

Kernel = Literal["auto", "butterfly", "matrix"]

#: Frames up to this many classes use the dense-matrix kernel under ``kernel="auto"``.
#: 0: ``auto`` always takes the butterflies. The matrix kernel is ~1.5× faster on an idle
#: machine, but multi-threaded BLAS made it 5–14× slower whenever the other core was busy
#: (measured: 6,400 cells, 0.8 ms single-threaded vs 11 ms with 2 BLAS threads under load),
#: which is the normal state of a batch run. Pass ``kernel="matrix"`` to force it.
MATRIX_MAX_N = 0

# A transform: (which pair member receives, sign): "up" sums over supersets (q),
# "down" over subsets (b).
_Direction = Literal["up", "down"]


def frame_bits(m: np.ndarray) -> int:
    """The number of classes ``n`` of a mass array ``(..., 2**n)``; ValueError otherwise."""
    size = m.shape[-1] if m.ndim else 0
    n = size.bit_length() - 1
    if size < 2 or size != 1 << n or n > MAX_CLASSES:
        raise ValueError(
            f"last axis must have length 2**n with 1 <= n <= {MAX_CLASSES}, got shape {m.shape}")
    return n


def float_dtype(*arrays: np.ndarray) -> np.dtype:
    """float32 if every array is float32, else float64 (integers and mixtures promote)."""
    dt = np.result_type(*arrays)
    return np.dtype(np.float32) if dt == np.float32 else np.dtype(np.float64)


@lru_cache(maxsize=64)
def transform_matrix(n: int, direction: _Direction, inverse: bool, dtype: np.dtype
                     ) -> np.ndarray:
    """Dense transform matrix T with ``out = x @ T`` (T[B, A] is the weight of x(B) in A)."""
    idx = np.arange(1 << n)
    b, a = idx[:, None], idx[None, :]
    related = (b & a) == a if direction == "up" else (b & a) == b
    t = related.astype(np.float64)
    if inverse:
        diff = np.bitwise_xor(b, a)
        popcount = np.zeros_like(diff)
        for k in range(n):
            popcount += diff >> k & 1
        t *= np.where(popcount % 2 == 0, 1.0, -1.0)
    out = t.astype(dtype)
    out.setflags(write=False)
    return out


def apply_matrix(x: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """``x @ matrix`` on the last axis, as one 2-D BLAS call (faster than a batched matmul)."""
    flat = x.reshape(-1, x.shape[-1]).astype(matrix.dtype, copy=False)
    return np.matmul(flat, matrix).reshape(*x.shape[:-1], matrix.shape[-1])


def to_subset_major(m: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """A fresh C-contiguous ``(2**n, cells)`` copy of ``m`` (last axis moved first)."""
    size = m.shape[-1]
    return np.array(np.moveaxis(m, -1, 0), dtype=dtype, order="C", copy=True).reshape(size, -1)


def from_subset_major(x: np.ndarray, lead_shape: tuple[int, ...]) -> np.ndarray:
    """Inverse of :func:`to_subset_major`: back to a C-contiguous ``(*lead_shape, 2**n)``."""
    return np.ascontiguousarray(np.moveaxis(x.reshape(x.shape[0], *lead_shape), 0, -1))


def butterflies_inplace(x: np.ndarray, n: int, direction: _Direction, inverse: bool) -> None:
    """Apply the n butterfly stages in place to a subset-major array ``(2**n, cells)``."""
    for k in range(n):
        v = x.reshape(1 << (n - 1 - k), 2, 1 << k, x.shape[-1])
        lo, hi = v[:, 0], v[:, 1]
        dst, src = (lo, hi) if direction == "up" else (hi, lo)
        if inverse:
            dst -= src
        else:
            dst += src


def use_matrix(n: int, kernel: Kernel) -> bool:
    if kernel not in ("auto", "butterfly", "matrix"):
        raise ValueError(f"kernel must be 'auto', 'butterfly' or 'matrix', got {kernel!r}")
    return kernel == "matrix" or (kernel == "auto" and n <= MATRIX_MAX_N)


def transform(m: np.ndarray, direction: _Direction, inverse: bool,
              kernel: Kernel = "auto") -> np.ndarray:
    """One zeta (``inverse=False``) or Möbius (``inverse=True``) transform on the last axis."""
    m = np.asarray(m)
    n = frame_bits(m)
    dtype = float_dtype(m)
    if use_matrix(n, kernel):
        return apply_matrix(m, transform_matrix(n, direction, inverse, dtype))
    x = to_subset_major(m, dtype)
    butterflies_inplace(x, n, direction, inverse)
    return from_subset_major(x, m.shape[:-1])


def mass_to_commonality(m: np.ndarray, kernel: Kernel = "auto") -> np.ndarray:
    """q(A) = Σ_{B ⊇ A} m(B); q(∅) = Σ_B m(B)."""
    return transform(m, "up", inverse=False, kernel=kernel)


def commonality_to_mass(q: np.ndarray, kernel: Kernel = "auto") -> np.ndarray:
    """m(A) = Σ_{B ⊇ A} (−1)^{|B∖A|} q(B) (inverse of :func:`mass_to_commonality`)."""
    return transform(q, "up", inverse=True, kernel=kernel)


def mass_to_implicability(m: np.ndarray, kernel: Kernel = "auto") -> np.ndarray:
    """b(A) = Σ_{B ⊆ A} m(B), including m(∅); b(∅) = m(∅)."""
    return transform(m, "down", inverse=False, kernel=kernel)


def implicability_to_mass(b: np.ndarray, kernel: Kernel = "auto") -> np.ndarray:
    """m(A) = Σ_{B ⊆ A} (−1)^{|A∖B|} b(B) (inverse of :func:`mass_to_implicability`)."""
    return transform(b, "down", inverse=True, kernel=kernel)


def belief(m: np.ndarray, kernel: Kernel = "auto") -> np.ndarray:
    """bel(A) = Σ_{∅ ≠ B ⊆ A} m(B) = b(A) − m(∅); bel(∅) = 0."""
    b = mass_to_implicability(m, kernel)
    return b - b[..., :1]


def plausibility(m: np.ndarray, kernel: Kernel = "auto") -> np.ndarray:
    """pl(A) = Σ_{B ∩ A ≠ ∅} m(B) = b(Ω) − b(Ā); pl(∅) = 0.

    ``b(Ω)`` is the total mass, so this holds for unnormalised and subnormal inputs too.
    """
    b = mass_to_implicability(m, kernel)
    # Ā has mask Ω − A, i.e. the reversed index order.
    return b[..., -1:] - b[..., ::-1]
