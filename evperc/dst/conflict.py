"""The parts of the conflict of one fusion step (method.md §5.4)."""

from __future__ import annotations

import numpy as np

from evperc.dst.combine import conjunctive
from evperc.dst.frame import Frame
from evperc.dst.transforms import frame_bits


def belief_of(m: np.ndarray, mask: int) -> np.ndarray:
    """Bel(A) = Σ_{∅ ≠ B ⊆ A} m(B) for one fixed set ``mask``, shape ``(...)``."""
    subsets = [b for b in range(1, m.shape[-1]) if b & ~mask == 0]
    return m[..., subsets].sum(axis=-1)


def conflict_parts(m_prev: np.ndarray, m_sensor: np.ndarray, frame: Frame, free: str = "F",
                   empty_mass: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(fo, of, other)``: the conflict c(∅) of c = m_prev ∩ m_sensor split in three.

        ∅_FO = m_prev({F}) · Bel_sensor(O)     (an object appeared)
        ∅_OF = Bel_prev(O) · m_sensor({F})     (an object left)
        ∅_other = c(∅) − ∅_FO − ∅_OF

    with O = Ω ∖ {F} and Bel(O) the sum of the masses of the non-empty subsets of O.
    ``empty_mass`` is c(∅) when the caller has already combined (saves a combination);
    otherwise it is computed. ``other`` is clipped at 0 against round-off.
    """
    m_prev, m_sensor = np.asarray(m_prev), np.asarray(m_sensor)
    if frame_bits(m_prev) != frame.n or frame_bits(m_sensor) != frame.n:
        raise ValueError(f"mass arrays {m_prev.shape}, {m_sensor.shape} are not on frame "
                         f"{frame.names!r}")
    f = frame.bit(free)
    objects = frame.omega & ~f
    fo = m_prev[..., f] * belief_of(m_sensor, objects)
    of = belief_of(m_prev, objects) * m_sensor[..., f]
    if empty_mass is None:
        empty_mass = conjunctive(m_prev, m_sensor)[..., 0]
    other = np.maximum(np.asarray(empty_mass) - fo - of, 0)
    return fo, of, other.astype(fo.dtype, copy=False)
