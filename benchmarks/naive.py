"""The naive dense reference of `benchmarks/bench_run.py`: what evperc would cost written
straight from the textbook definitions (issue 7).

- Fusion (method.md §5 steps 2–8) and decision (method.md §6) over the dense 32-entry mass vectors,
  every combination by the 32 × 32 pair loop of :mod:`evperc.dst.reference` (vectorised over
  cells only): SG ⊕ GG (one pair loop), contextual discounting (one disjunctive pair loop per
  class, five), PG ∩ SG' (one pair loop), the conflict parts, ⊛, ζ, the specialisation and
  betP by direct sums; float64 throughout. The decision rule on betP is
  :func:`evperc.fusion.twin.decide` (whole-array numpy, negligible next to the pair loops).
- Sensor grid (method.md §3): the per-point / per-cell plain-Python oracle
  ``tests/sensor/reference.py`` (one Python iteration per point, per cell, per polar cell).

Benchmarks only; nothing in evperc calls this.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from evperc.dst import reference as pairs  # noqa: E402
from evperc.fusion.twin import (  # noqa: E402
    DECISION_CODES,
    OCCUPIED,
    OMEGA,
    FusionParams,
    decide,
    scaled_rate,
)
from tests.sensor.reference import reference_grid  # noqa: E402

F, M, S = 1, 16, 8
_OCC_SUBSETS = [a for a in range(1, 32) if a & ~OCCUPIED == 0]


def dense_step(pg: np.ndarray, zeta: np.ndarray, free: np.ndarray, occupied: np.ndarray,
               prior: np.ndarray, observed: np.ndarray, dt_s: float, params: FusionParams
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One fusion step + decision on ``n`` cells: ``pg`` (n, 32), ``zeta`` (n,), ``free``,
    ``occupied``, ``observed`` (n,), ``prior`` GG (n, 32). Returns ``(pg, zeta, betp,
    decision)``. Same maths as :func:`evperc.fusion.twin.fusion_step` + ``decide``."""
    n = len(pg)
    sg = np.zeros((n, 32))
    sg[:, F] = free
    sg[:, OCCUPIED] = occupied
    sg[:, OMEGA] = 1.0 - free - occupied
    # 2. SG' = SG ⊕ GG (Dempster: pair loop, then normalise)
    c = pairs.conjunctive(sg, prior)
    k = c[:, 0]
    use = k < 1.0
    if params.prior_where == "observed":
        use &= observed
    sgp = c / np.where(use, 1.0 - k, 1.0)[:, None]
    sgp[:, 0] = 0.0
    sgp = np.where(use[:, None], sgp, sg)
    # 3. discounting
    if params.discount == "contextual":
        alphas = scaled_rate(params.discount_rates, dt_s, params.discount_period_s)
        pgd = pairs.contextual_discount(pg, np.broadcast_to(alphas, (n, 5)))
    else:
        alpha = float(scaled_rate(params.discount_classical, dt_s, params.discount_period_s))
        pgd = (1.0 - alpha) * np.asarray(pg, float)
        pgd[:, OMEGA] += alpha
    # 4. PG ∩ SG' and its conflict parts (direct sums)
    fused = pairs.conjunctive(pgd, sgp)
    fo = pgd[:, F] * sgp[:, _OCC_SUBSETS].sum(axis=1)
    of = pgd[:, _OCC_SUBSETS].sum(axis=1) * sgp[:, F]
    other = np.maximum(fused[:, 0] - fo - of, 0.0)
    # 5. rule ⊛
    fused[:, 0] = 0.0
    fused[:, M] += fo
    fused[:, OMEGA] += of
    if params.residual_conflict == "omega":
        fused[:, OMEGA] += other
    elif params.residual_conflict == "empty":
        fused[:, 0] = other
    else:
        fused /= np.maximum(1.0 - other, np.finfo(float).tiny)[:, None]
    # 6. ζ
    dynamic = fo + of
    bel_o = fused[:, _OCC_SUBSETS].sum(axis=1)
    grow = (bel_o >= params.gamma_occupied) & (dynamic <= params.gamma_conflict)
    shrink = dynamic > params.gamma_conflict
    zeta = np.where(grow, np.minimum(1.0, zeta + params.zeta_increment),
                    np.where(shrink, np.maximum(0.0, zeta - params.zeta_decrement), zeta))
    # 7. specialisation by ζ, set by set
    out = fused.copy()
    for a in range(32):
        if a & M:
            given = zeta * fused[:, a]
            out[:, a] -= given
            target = a & ~M
            if target == 0 and params.stopped_target == "stopped":
                target = S
            out[:, target] += given
    # method.md §6: betP by direct sums, then the decision rule
    betp = pairs.pignistic(out) if (out[:, 0] < 1).all() else np.zeros((n, 5))
    _, decision = decide(out.astype(np.float32)[None], params)
    return out, zeta, betp, decision[0]


def sensor_grid(points, planar, t_crs_sensor, window, params):  # noqa: ANN001, ANN201
    """``(free, occupied)`` of one scan, per point and per cell in plain Python."""
    return reference_grid(points, planar, t_crs_sensor, window, params)


__all__ = ["DECISION_CODES", "dense_step", "sensor_grid"]
