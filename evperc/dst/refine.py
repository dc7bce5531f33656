"""Vacuous extension of a mass function to a refined frame (method.md §2, §5.1).

A refining maps each coarse class to a non-empty set of fine classes, the images being
disjoint and covering the fine frame, e.g. Ω_SG → Ω: {F} → {F}, {O} → {I, U, S, M}.
The mass of a coarse set A moves unchanged to the union of the images of its classes.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

from evperc.dst.frame import Frame
from evperc.dst.transforms import float_dtype, frame_bits


def refining_index(mapping: Mapping[str, Iterable[str] | str], fine_frame: Frame,
                   coarse_frame: Frame | None = None) -> np.ndarray:
    """For each coarse mask, the fine mask of its image: int array ``(2**n_coarse,)``."""
    coarse = coarse_frame if coarse_frame is not None else Frame(tuple(mapping))
    if set(mapping) != set(coarse.names):
        raise ValueError(f"refining must map every class of {coarse.names!r} exactly, "
                         f"got {tuple(mapping)!r}")
    images = [fine_frame.mask(mapping[name]) for name in coarse.names]
    covered = 0
    for name, image in zip(coarse.names, images, strict=True):
        if image == 0 or image & covered:
            raise ValueError(f"refining of {name!r} is empty or overlaps another class")
        covered |= image
    if covered != fine_frame.omega:
        raise ValueError(f"refining images do not cover frame {fine_frame.names!r}")
    index = np.zeros(coarse.size, dtype=np.intp)
    for k, image in enumerate(images):
        with_k = (np.arange(coarse.size) >> k & 1).astype(bool)
        index[with_k] |= image
    return index


def refine(m_coarse: np.ndarray, mapping: Mapping[str, Iterable[str] | str],
           fine_frame: Frame, coarse_frame: Frame | None = None) -> np.ndarray:
    """Vacuous extension: m_fine(ρ(A)) = m_coarse(A), zero elsewhere.

    ``mapping`` gives, per coarse class name, its fine class names. The coarse frame is
    ``coarse_frame`` if given, else ``Frame(tuple(mapping))`` (keys in bit order).
    Result: ``(..., 2**fine_frame.n)`` of the input's float dtype.
    """
    m_coarse = np.asarray(m_coarse)
    n = frame_bits(m_coarse)
    index = refining_index(mapping, fine_frame, coarse_frame)
    if index.size != 1 << n:
        raise ValueError(f"mass array has {1 << n} subsets, the coarse frame has {index.size}")
    out = np.zeros((*m_coarse.shape[:-1], fine_frame.size), dtype=float_dtype(m_coarse))
    out[..., index] = m_coarse
    return out
