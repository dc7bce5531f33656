"""Colour maths for grid layers (method.md §6): whole-array numpy, one call per layer.

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

#: Pignistic colour of each class, in the class order F, I, U, S, M (method.md §6). One hue
#: per class, the same in every panel, and none of them a mixture of two others: a fading free
#: cell ({F, M}: betP F = M = 0.5) is olive, which is no class's colour (issue 22).
CLASS_COLOURS: dict[str, RGB] = {
    "F": (0, 255, 0),      # free: green
    "I": (0, 0, 255),      # mapped infrastructure: blue
    "U": (255, 0, 255),    # unmapped infrastructure: magenta
    "S": (255, 160, 0),    # stopped: orange
    "M": (255, 0, 0),      # moving: red
}
CLASS_NAMES = {"F": "free", "I": "infrastructure", "U": "unmapped", "S": "stopped",
               "M": "moving"}
_CLASS_MATRIX = np.array(list(CLASS_COLOURS.values()), dtype=np.float32)  # (5, 3)
#: undecided among I, U, S (the decision ``static``): a colour of its own, lighter than I's
STATIC_COLOUR: RGB = (150, 150, 255)
#: a free cell no longer seen fades through {F, M} (betP F = M = 0.5: olive), then {F, S, M}
#: and {F, U, S, M} (each 0.25: brown), before it is unknown (method.md §5.3)
FADING_COLOURS: dict[str, RGB] = {"free, fading": (128, 128, 0),
                                  "free, faded": (191, 104, 64)}

#: The paper's 4-colour decision view: static covers I, U, S and undecided `static`.
DECISION4_COLOURS: dict[str, RGB] = {
    "free": CLASS_COLOURS["F"], "moving": CLASS_COLOURS["M"], "static": STATIC_COLOUR,
    "unknown": (0, 0, 0)}
DECISION4_OF_CODE = {"unknown": "unknown", "free": "free", "moving": "moving",
                     "static": "static", "stopped": "static", "infrastructure": "static",
                     "unmapped": "static"}

#: Fine decision view: one colour per decision code, the pignistic colours of the classes.
DECISION6_COLOURS: dict[str, RGB] = {
    "free": CLASS_COLOURS["F"], "moving": CLASS_COLOURS["M"], "stopped": CLASS_COLOURS["S"],
    "infrastructure": CLASS_COLOURS["I"], "unmapped": CLASS_COLOURS["U"],
    "static": STATIC_COLOUR, "unknown": (0, 0, 0)}

#: a decision code the run names but the palette does not (a newer output format)
UNNAMED_COLOUR: RGB = (255, 255, 128)

#: Outlines, ids and velocity arrows of the run's object list (docs/output-format.md).
#: (yellow and pink: no class, decision, ego or map-outline colour, so an outline shows over
#: the cells it surrounds)
OBJECT_COLOURS: dict[str, RGB] = {"moving": (255, 255, 0), "stopped": (255, 105, 180)}

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
    """Σ_θ betP(θ)·colour_θ over θ ∈ {F, I, U, S, M} (method.md §6); ``betp`` is (..., 5)."""
    rgb = np.asarray(betp, dtype=np.float32) @ _CLASS_MATRIX
    return np.clip(rgb + 0.5, 0, 255).astype(np.uint8)


def pignistic_colour_known(betp: np.ndarray, m_omega: np.ndarray) -> np.ndarray:
    """:func:`pignistic_colour` dimmed by the ignorance: × (1 − m(Ω)), so that unknown cells
    are black as in the decision panels (a vacuous cell's betP is uniform, which would
    otherwise paint it a mixture of all five colours)."""
    rgb = np.asarray(betp, dtype=np.float32) @ _CLASS_MATRIX
    known = 1.0 - np.clip(np.asarray(m_omega, dtype=np.float32), 0.0, 1.0)
    return np.clip(rgb * known[..., None] + 0.5, 0, 255).astype(np.uint8)


def decision_lut(decision_codes: Mapping[str, int], colours: Mapping[str, RGB],
                 name_of: Mapping[str, str] | None = None) -> np.ndarray:
    """A (256, 3) uint8 look-up table code → colour; codes not named are
    :data:`UNNAMED_COLOUR`."""
    lut = np.zeros((256, 3), dtype=np.uint8)
    lut[:] = UNNAMED_COLOUR
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
