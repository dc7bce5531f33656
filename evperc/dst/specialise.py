"""Specialisation by the accumulator ζ (method.md §5.7)."""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from evperc.dst.frame import Frame
from evperc.dst.transforms import float_dtype, frame_bits


def specialise_by_zeta(m: np.ndarray, zeta: ArrayLike, frame: Frame, moving: str = "M",
                       stopped: str = "S",
                       stopped_target: Literal["stopped", "empty"] = "stopped") -> np.ndarray:
    """Every focal set A ∋ M gives ζ·m(A) to A ∖ {M}; it keeps (1 − ζ)·m(A).

    For A = {M} the target is {S} (``stopped_target="stopped"``, the method's intent) or
    ∅ (``"empty"``, the paper's literal rule). ``zeta`` is a scalar or broadcasts against
    ``m.shape[:-1]``; it must lie in [0, 1].
    """
    m = np.asarray(m)
    n = frame_bits(m)
    if n != frame.n:
        raise ValueError(f"mass array has {n} classes, frame {frame.names!r} has {frame.n}")
    if stopped_target not in ("stopped", "empty"):
        raise ValueError(f"stopped_target must be 'stopped' or 'empty', got {stopped_target!r}")
    dtype = float_dtype(m)
    bit = frame.bit(moving)
    # every A ∋ M except {M} itself: targets A ∖ {M} are distinct and non-empty
    sources = np.array([a for a in range(frame.size) if a & bit and a != bit], dtype=np.intp)
    targets = sources & ~bit
    z = np.asarray(zeta, dtype=dtype)[..., None]
    lead = np.broadcast_shapes(m.shape[:-1], z.shape[:-1])
    out = np.array(np.broadcast_to(m, (*lead, m.shape[-1])), dtype=dtype, order="C", copy=True)
    given = out[..., sources] * z
    out[..., sources] -= given
    out[..., targets] += given
    only_m = out[..., bit] * z[..., 0]
    out[..., bit] -= only_m
    out[..., frame.bit(stopped) if stopped_target == "stopped" else 0] += only_m
    return out
