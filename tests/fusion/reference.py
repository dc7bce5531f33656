"""method.md §5–§6 written out per cell in plain Python (dicts of frozensets, no numpy).

An oracle for :mod:`evperc.fusion.twin`: it shares no code with evperc.dst or the pipeline.
"""

from __future__ import annotations

from collections import defaultdict

EMPTY = frozenset()
CLASSES = "FIUSM"
OMEGA = frozenset(CLASSES)
OCC = frozenset("IUSM")


def from_vector(vec) -> dict[frozenset, float]:
    return {frozenset(c for b, c in enumerate(CLASSES) if mask >> b & 1): float(v)
            for mask, v in enumerate(vec) if v != 0}


def to_vector(m: dict[frozenset, float]) -> list[float]:
    out = [0.0] * 32
    for a, v in m.items():
        out[sum(1 << CLASSES.index(c) for c in a)] += v
    return out


def conjunctive(m1, m2):
    out = defaultdict(float)
    for a, x in m1.items():
        for b, y in m2.items():
            out[a & b] += x * y
    return dict(out)


def disjunctive(m1, m2):
    out = defaultdict(float)
    for a, x in m1.items():
        for b, y in m2.items():
            out[a | b] += x * y
    return dict(out)


def dempster(m1, m2):
    c = conjunctive(m1, m2)
    k = c.pop(EMPTY, 0.0)
    return {a: v / (1 - k) for a, v in c.items()}


def bel_occupied(m):
    return sum(v for a, v in m.items() if a and a <= OCC)


def discount(m, rates, kind, classical_rate):
    if kind == "classical":
        out = {a: (1 - classical_rate) * v for a, v in m.items()}
        out[OMEGA] = out.get(OMEGA, 0.0) + classical_rate
        return out
    for cls, rate in zip(CLASSES, rates, strict=True):
        m = disjunctive(m, {EMPTY: 1 - rate, frozenset(cls): rate})
    return m


def step(pg, zeta, sg_free, sg_occ, prior, observed, rates, p, gate_open=True,
         building=False):
    """One cell; ``rates`` already scaled to dt. Returns (pg, zeta, (fo, of, other)).

    The motion gate (docs/method.md): ``p.get("motion_gate", "none")`` other than "none"
    sends ∅_FO to {M} only if ``gate_open``, else to O (``p["closed_target"]`` "occupied")
    or {I,U,S} ("static"); with ``p["building_conflict"]`` "infrastructure" a ``building``
    cell sends it to {I}; ζ counts ∅_FO as conflict only where it went to {M}."""
    sg = {frozenset("F"): sg_free, OCC: sg_occ, OMEGA: 1 - sg_free - sg_occ}
    sg = {a: v for a, v in sg.items() if v}
    sg_prime = dempster(sg, prior) if (observed or p["prior_where"] == "everywhere") else sg
    pgd = discount(pg, rates, p["discount"], p["classical_rate"])
    c = conjunctive(pgd, sg_prime)
    of = bel_occupied(pgd) * sg_prime.get(frozenset("F"), 0.0)
    fo = pgd.get(frozenset("F"), 0.0) * bel_occupied(sg_prime)
    other = max(c.pop(EMPTY, 0.0) - fo - of, 0.0)
    if building and p.get("building_conflict", "moving") == "infrastructure":
        target = frozenset("I")
    elif gate_open or p.get("motion_gate", "none") == "none":
        target = frozenset("M")
    elif p["closed_target"] == "occupied":
        target = OCC
    else:
        target = frozenset("IUS")
    c[target] = c.get(target, 0.0) + fo
    moved = fo if target == frozenset("M") else 0.0
    c[OMEGA] = c.get(OMEGA, 0.0) + of
    if p["residual"] == "omega":
        c[OMEGA] += other
    elif p["residual"] == "empty":
        c[EMPTY] = other
    else:
        c = {a: v / (1 - other) for a, v in c.items()}
    if bel_occupied(c) >= p["gamma_o"] and moved + of <= p["gamma_c"]:
        zeta = min(1.0, zeta + p["inc"])
    elif moved + of > p["gamma_c"]:
        zeta = max(0.0, zeta - p["dec"])
    out = defaultdict(float)
    for a, v in c.items():
        if "M" in a:
            target = a - {"M"}
            if not target and p["stopped_target"] == "stopped":
                target = frozenset("S")
            out[target] += zeta * v
            out[a] += (1 - zeta) * v
        else:
            out[a] += v
    return dict(out), zeta, (fo, of, other)


def betp(m):
    empty = m.get(EMPTY, 0.0)
    if empty >= 1:
        return [0.0] * 5
    return [sum(v / len(a) for a, v in m.items() if c in a) / (1 - empty) for c in CLASSES]
