"""Frames of discernment: class names ↔ subset bitmasks (docs/conventions.md).

A subset of a frame of ``n`` classes is the integer whose bit ``i`` is set when class ``i``
belongs to it; mass arrays are indexed by that integer on their last axis, of length
``2**n``. Index 0 is ∅ and ``2**n - 1`` is Ω.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

MAX_CLASSES = 8


@dataclass(frozen=True)
class Frame:
    """An ordered frame of discernment; class ``names[i]`` is bit ``i``."""

    names: tuple[str, ...]
    _bits: dict[str, int] = field(init=False, repr=False, compare=False, hash=False)

    def __post_init__(self) -> None:
        names = tuple(self.names)
        if not 1 <= len(names) <= MAX_CLASSES:
            raise ValueError(f"a frame needs 1 to {MAX_CLASSES} classes, got {names!r}")
        if len(set(names)) != len(names) or not all(isinstance(s, str) and s for s in names):
            raise ValueError(f"frame class names must be distinct non-empty strings: {names!r}")
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "_bits", {s: i for i, s in enumerate(names)})

    @property
    def n(self) -> int:
        """Number of classes."""
        return len(self.names)

    @property
    def size(self) -> int:
        """Number of subsets, ``2**n``: the length of a mass vector."""
        return 1 << self.n

    @property
    def omega(self) -> int:
        """The mask of Ω, ``2**n - 1``."""
        return self.size - 1

    def bit(self, name: str) -> int:
        """The mask of the singleton ``{name}``."""
        try:
            return 1 << self._bits[name]
        except KeyError:
            raise ValueError(f"class {name!r} is not in frame {self.names!r}") from None

    def mask(self, names: Iterable[str] | str) -> int:
        """The mask of a set of class names; a bare string is one class name."""
        if isinstance(names, str):
            return self.bit(names)
        out = 0
        for name in names:
            out |= self.bit(name)
        return out

    def names_of(self, mask: int) -> frozenset[str]:
        """The class names of a subset mask (inverse of :meth:`mask`)."""
        mask = int(mask)
        if not 0 <= mask <= self.omega:
            raise ValueError(f"mask {mask} is outside 0..{self.omega} for frame {self.names!r}")
        return frozenset(s for i, s in enumerate(self.names) if mask >> i & 1)

    def vacuous(self, shape: tuple[int, ...] = (), dtype: np.dtype | type = np.float32
                ) -> np.ndarray:
        """Vacuous mass functions ``m(Ω) = 1`` of the given leading shape."""
        m = np.zeros((*shape, self.size), dtype=dtype)
        m[..., self.omega] = 1
        return m

    def vector(self, focal: Mapping[Iterable[str] | str, float],
               dtype: np.dtype | type = np.float64) -> np.ndarray:
        """A dense mass vector from ``{set of names: mass}``; masses of equal sets add up."""
        m = np.zeros(self.size, dtype=dtype)
        for names, value in focal.items():
            m[self.mask(names)] += value
        return m


#: The perception/map frame Ω = {F, I, U, S, M} (method.md §1): bit0 F … bit4 M.
FRAME = Frame(("F", "I", "U", "S", "M"))
#: The sensor frame Ω_SG = {F, O} (method.md §1, §3).
SENSOR_FRAME = Frame(("F", "O"))
