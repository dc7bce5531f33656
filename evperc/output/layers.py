"""The uint8 layers of one frame as the output format stores them (docs/output-format.md),
written by the fused step (:func:`evperc.fusion.fused.fused_step`) straight into the
writer's chunk buffer. Defined here, with the output format, so that the writer needs
nothing of the fusion."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from evperc.output import mass_tiles

#: cells per tile of the stored masses' block-sparse layout (the generated kernel's TILE)
MASS_TILE = 64


@dataclass(frozen=True)
class StoredOutputs:
    """uint8 outputs of :func:`fused_step` as the output format stores them
    (``round(255 · x)``, docs/output-format.md): the new masses in the block-sparse layout
    of :mod:`evperc.output.mass_tiles` (tiles of :data:`MASS_TILE` cells: ``mass_runs`` from
    its start, ``tile_masks``, and ``mass_length[0]`` the bytes of runs written), betP,
    conflict parts, ζ and the decision, planar. Usually views into the writer's chunk
    buffer. betP is for the frame's own passes (the objects' betP(M), ``on_frame``): since
    format_version 4 it is not stored, a reader derives it from the masses."""

    mass_runs: np.ndarray  # uint8 (32 · rows · cols,): room for every plane of every cell
    tile_masks: np.ndarray  # uint32 (rows, tiles per row)
    mass_length: np.ndarray  # int64 (1,)
    betp: np.ndarray  # uint8 (5, rows, cols)
    conflict: np.ndarray  # uint8 (3, rows, cols)
    zeta: np.ndarray  # uint8 (rows, cols)
    decision: np.ndarray  # uint8 (rows, cols)

    @staticmethod
    def empty(shape: tuple[int, int], fill: Callable[..., np.ndarray] | None = None
              ) -> StoredOutputs:
        """Layers for a frame of ``shape``, made by ``fill`` (``np.zeros``: every cell
        decided ``unknown``, code 0; None: ``np.empty``, whatever bytes the allocator had,
        for buffers a fused step writes whole before anything reads them)."""
        make = np.empty if fill is None else fill
        return StoredOutputs(*(make(s, d) for s, d in StoredOutputs.layout(shape)))

    @staticmethod
    def layout(shape: tuple[int, int]) -> list[tuple[tuple[int, ...], type]]:
        """Shape and dtype of each array, in field order."""
        rows, cols = shape
        return [((32 * rows * cols,), np.uint8),
                ((rows, mass_tiles.tiles_per_row(cols, MASS_TILE)), np.uint32),
                ((1,), np.int64), ((5, rows, cols), np.uint8), ((3, rows, cols), np.uint8),
                ((rows, cols), np.uint8), ((rows, cols), np.uint8)]

    def arrays(self) -> tuple[np.ndarray, ...]:
        return (self.mass_runs, self.tile_masks, self.mass_length, self.betp, self.conflict,
                self.zeta, self.decision)

    def copy_to(self, other: StoredOutputs) -> None:
        """Copy these layers into ``other`` (same window shape; the mass runs only as far
        as written)."""
        used = int(self.mass_length[0])
        other.mass_runs[:used] = self.mass_runs[:used]
        for name in ("tile_masks", "mass_length", "betp", "conflict", "zeta", "decision"):
            np.copyto(getattr(other, name), getattr(self, name))

    def masses(self) -> np.ndarray:
        """The masses as dense uint8 planes ``(32, rows, cols)``."""
        runs = self.mass_runs[:int(self.mass_length[0])]
        return mass_tiles.decode(runs, self.tile_masks, self.decision.shape, MASS_TILE)
