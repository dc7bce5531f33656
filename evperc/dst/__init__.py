"""Belief functions over grids: dense (..., 2**n) mass arrays, subsets as bitmasks."""

from evperc.dst.combine import (
    conjunctive,
    dempster,
    disjunctive,
    total_conflict_tolerance,
    yager,
)
from evperc.dst.conflict import belief_of, conflict_parts
from evperc.dst.discount import contextual_discount, discount
from evperc.dst.frame import FRAME, SENSOR_FRAME, Frame
from evperc.dst.pignistic import pignistic
from evperc.dst.refine import refine
from evperc.dst.specialise import specialise_by_zeta
from evperc.dst.transforms import (
    belief,
    commonality_to_mass,
    implicability_to_mass,
    mass_to_commonality,
    mass_to_implicability,
    plausibility,
)

__all__ = [
    "FRAME",
    "SENSOR_FRAME",
    "Frame",
    "belief",
    "belief_of",
    "commonality_to_mass",
    "conflict_parts",
    "conjunctive",
    "contextual_discount",
    "dempster",
    "discount",
    "disjunctive",
    "implicability_to_mass",
    "mass_to_commonality",
    "mass_to_implicability",
    "pignistic",
    "plausibility",
    "refine",
    "specialise_by_zeta",
    "total_conflict_tolerance",
    "yager",
]
