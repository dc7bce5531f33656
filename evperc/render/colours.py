"""Colour maths for grid layers (SPEC §6): whole-array numpy, one call per layer.

Every function maps ``(rows, cols, ...)`` arrays to ``(rows, cols, 3)`` uint8 RGB in the
grid's own row order (row 0 = south); flipping for display is the compositor's job.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

RGB = tuple[int, int, int]

#: Decision codes of format_version 1 (docs/output-format.md), for frames without a run.
DEFAULT_DECISION_CODES: dict[str, int] = {
    "unknown": 0, "free": 1, "moving": 2, "static": 3, "stopped": 4, "infrastructure": 5,
    "unmapped": 6}

#: Pignistic colour of each class, in the class order F, I, U, S, M (SPEC §6).
CLASS_COLOURS: dict[str, RGB] = {
    "F": (0, 255, 0),      # free: green
    "I": (0, 0, 128),      # mapped infrastructure: dark blue
    "U": (255, 255, 0),    # unmapped infrastructure: yellow
    "S": (0, 0, 255),      # stopped: blue
    "M": (255, 0, 0),      # moving: red
}
CLASS_NAMES = {"F": "free", "I": "infrastructure", "U": "unmapped", "S": "stopped",
               "M": "moving"}
_CLASS_MATRIX = np.array(list(CLASS_COLOURS.values()), dtype=np.float32)  # (5, 3)

#: The paper's 4-colour decision view: static covers I, U, S and undecided `static`.
DECISION4_COLOURS: dict[str, RGB] = {
    "free": (0, 255, 0), "moving": (255, 0, 0), "static": (0, 0, 255), "unknown": (0, 0, 0)}
DECISION4_OF_CODE = {"unknown": "unknown", "free": "free", "moving": "moving",
                     "static": "static", "stopped": "static", "infrastructure": "static",
                     "unmapped": "static"}

#: Fine decision view: one colour per decision code (same hues as the pignistic colours).
DECISION6_COLOURS: dict[str, RGB] = {
    "free": (0, 255, 0), "moving": (255, 0, 0), "stopped": (0, 0, 255),
    "infrastructure": (0, 0, 128), "unmapped": (255, 255, 0), "static": (100, 150, 255),
    "unknown": (0, 0, 0)}

#: Outlines, ids and velocity arrows of the run's object list (docs/output-format.md).
OBJECT_COLOURS: dict[str, RGB] = {"moving": (0, 255, 255), "stopped": (255, 140, 0)}

#: Trace of moving objects over a dimmed 4-colour decision map.
TRACE_COLOUR: RGB = (255, 0, 0)
TRACE_DIM = 0.3

#: ζ ramp anchors (value, colour): black → purple → orange → pale yellow.
ZETA_ANCHORS: tuple[tuple[float, RGB], ...] = (
    (0.0, (0, 0, 0)), (0.35, (120, 28, 109)), (0.7, (237, 105, 37)), (1.0, (252, 255, 164)))

#: Conflict parts ∅_FO, ∅_OF, ∅_other drawn into the red, green and blue channels.
CONFLICT_COLOURS: dict[str, RGB] = {"free-occ": (255, 0, 0), "occ-free": (0, 255, 0),
                                    "other": (0, 0, 255)}


def pignistic_colour(betp: np.ndarray) -> np.ndarray:
    """Σ_θ betP(θ)·colour_θ over θ ∈ {F, I, U, S, M} (SPEC §6); ``betp`` is (..., 5)."""
    rgb = np.asarray(betp, dtype=np.float32) @ _CLASS_MATRIX
    return np.clip(rgb + 0.5, 0, 255).astype(np.uint8)


def decision_lut(decision_codes: Mapping[str, int], colours: Mapping[str, RGB],
                 name_of: Mapping[str, str] | None = None) -> np.ndarray:
    """A (256, 3) uint8 look-up table code → colour; codes not named are magenta."""
    lut = np.zeros((256, 3), dtype=np.uint8)
    lut[:] = (255, 0, 255)
    for name, code in decision_codes.items():
        key = name_of.get(name, name) if name_of is not None else name
        if key in colours:
            lut[int(code)] = colours[key]
    return lut


def apply_lut(codes: np.ndarray, lut: np.ndarray) -> np.ndarray:
    """``lut[codes]``: (rows, cols) uint8 codes → (rows, cols, 3) colours."""
    return lut[np.asarray(codes, dtype=np.uint8)]


def ramp_lut(anchors: tuple[tuple[float, RGB], ...] = ZETA_ANCHORS) -> np.ndarray:
    """A (256, 3) uint8 piecewise-linear colour ramp through ``anchors`` over [0, 1]."""
    t = np.linspace(0.0, 1.0, 256)
    xs = [a[0] for a in anchors]
    channels = [np.interp(t, xs, [a[1][c] for a in anchors]) for c in range(3)]
    return np.clip(np.stack(channels, axis=-1) + 0.5, 0, 255).astype(np.uint8)


def ramp_colour(values: np.ndarray, lut: np.ndarray) -> np.ndarray:
    """Values in [0, 1] (clipped; NaN → 0) through a 256-entry ramp."""
    v = np.nan_to_num(np.asarray(values, dtype=np.float32), nan=0.0)
    index = np.clip(v * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return lut[index]


def conflict_colour(conflict: np.ndarray) -> np.ndarray:
    """(..., 3) conflict parts ∅_FO, ∅_OF, ∅_other in [0, 1] → red, green, blue."""
    c = np.nan_to_num(np.asarray(conflict, dtype=np.float32), nan=0.0)
    return np.clip(c * 255.0 + 0.5, 0, 255).astype(np.uint8)


def trace_colour(base: np.ndarray, trace: np.ndarray) -> np.ndarray:
    """``base`` RGB dimmed to ``TRACE_DIM``, with cells of ``trace`` (bool) in TRACE_COLOUR."""
    out = (base.astype(np.uint16) * int(TRACE_DIM * 256) >> 8).astype(np.uint8)
    out[trace] = TRACE_COLOUR
    return out
