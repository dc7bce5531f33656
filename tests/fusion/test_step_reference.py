"""The vectorised fusion step against the per-cell plain-Python reference of method.md §5."""

from __future__ import annotations

import numpy as np
import pytest

from evperc.fusion.twin import FusionParams, decide, fusion_step, scaled_rate, sensor_masses

from . import reference as ref

PRIORS = {
    "building": {frozenset("I"): 0.9, ref.OMEGA: 0.1},
    "road": {frozenset("FSM"): 0.85, ref.OMEGA: 0.15},
    "other": {frozenset("FUSM"): 0.8, ref.OMEGA: 0.2},
    "none": {ref.OMEGA: 1.0},
}


def random_mass(rng: np.random.Generator, n_focal: int) -> np.ndarray:
    vec = np.zeros(32)
    masks = rng.choice(np.arange(1, 32), size=n_focal, replace=False)
    vec[masks] = rng.dirichlet(np.ones(n_focal))
    return vec


@pytest.mark.parametrize("seed", range(12))
@pytest.mark.parametrize("gated", [False, True])
def test_step_matches_reference(seed: int, gated: bool) -> None:
    """Every option; ``gated``: with the motion gate, a random gate layer and random
    building cells (the paper's rule otherwise)."""
    rng = np.random.default_rng(seed + 1000 * gated)
    gate_options = {"motion_gate": "ever_free",
                    "gate_closed_target": str(rng.choice(["occupied", "static"])),
                    "building_conflict": str(rng.choice(["infrastructure", "moving"]))
                    } if gated else {}
    params = FusionParams(**gate_options,
        prior_where=rng.choice(["observed", "everywhere"]),
        discount=rng.choice(["contextual", "classical"]),
        residual_conflict=rng.choice(["omega", "empty", "normalise"]),
        stopped_target=rng.choice(["stopped", "empty"]),
        discount_rates=tuple(rng.uniform(0, 0.3, 5)),
        discount_classical=float(rng.uniform(0, 0.3)),
        zeta_increment=float(rng.uniform(0.05, 0.3)), zeta_decrement=float(rng.uniform(0.1, 0.6)),
        gamma_occupied=float(rng.uniform(0.2, 0.7)), gamma_conflict=float(rng.uniform(0.05, 0.4)))
    rows, cols = 6, 7
    pg = np.stack([random_mass(rng, int(rng.integers(1, 8))) for _ in range(rows * cols)])
    pg = pg.reshape(rows, cols, 32)
    zeta = rng.uniform(0, 1, (rows, cols))
    kind = rng.integers(0, 3, (rows, cols))  # 0 unseen, 1 free, 2 occupied
    free = np.where(kind == 1, 0.7, 0.0)
    occ = np.where(kind == 2, 0.8, 0.0)
    prior_kind = rng.choice(list(PRIORS), size=(rows, cols))
    prior = np.zeros((rows, cols, 32))
    for r in range(rows):
        for c in range(cols):
            prior[r, c] = ref.to_vector(PRIORS[prior_kind[r, c]])
    observed = kind > 0
    dt = float(rng.uniform(0.05, 0.2))
    gate = rng.random((rows, cols)) < 0.5
    building = prior_kind == "building"
    got_pg, got_zeta, got_conflict = fusion_step(
        pg, zeta, sensor_masses(free, occ).astype(np.float64), prior, observed, dt, params,
        gate=gate if gated else None, building=building)

    if params.discount == "contextual":
        rates = scaled_rate(params.discount_rates, dt, params.discount_period_s).tolist()
    else:
        rates = None
    classical = float(scaled_rate(params.discount_classical, dt, params.discount_period_s))
    p = {"prior_where": params.prior_where, "discount": params.discount,
         "classical_rate": classical, "residual": params.residual_conflict,
         "gamma_o": params.gamma_occupied, "gamma_c": params.gamma_conflict,
         "inc": params.zeta_increment, "dec": params.zeta_decrement,
         "stopped_target": params.stopped_target, "motion_gate": params.motion_gate,
         "closed_target": params.gate_closed_target,
         "building_conflict": params.building_conflict}
    for r in range(rows):
        for c in range(cols):
            want_pg, want_zeta, want_conf = ref.step(
                ref.from_vector(pg[r, c]), zeta[r, c], free[r, c], occ[r, c],
                PRIORS[prior_kind[r, c]], observed[r, c], rates or [0] * 5, p,
                gate_open=bool(gate[r, c]), building=bool(building[r, c]))
            np.testing.assert_allclose(got_pg[r, c], ref.to_vector(want_pg), atol=1e-9,
                                       err_msg=f"cell {r},{c} params {params}")
            assert got_zeta[r, c] == pytest.approx(want_zeta, abs=1e-12)
            np.testing.assert_allclose(got_conflict[r, c], want_conf, atol=1e-9)
            betp, _ = decide(got_pg[r:r + 1, c:c + 1], params)
            np.testing.assert_allclose(betp[0, 0], ref.betp(want_pg), atol=1e-6)
