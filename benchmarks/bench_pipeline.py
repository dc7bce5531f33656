"""Fusion step + decision on a 160,000-cell window (400 × 400 at 0.5 m), against the
per-cell plain-Python reference of SPEC §5 (tests/pipeline/reference.py) timed on a subset
of cells and scaled to the window."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from evperc.config import load_config  # noqa: E402
from evperc.pipeline import FusionParams, decide, fusion_step, scaled_rate, sensor_masses, vacuous  # noqa: E402
from tests.pipeline import reference as ref  # noqa: E402

SIDE = 400


def _inputs(rng: np.random.Generator):
    shape = (SIDE, SIDE)
    kind = rng.integers(0, 3, shape)
    free = np.where(kind == 1, 0.7, 0.0).astype(np.float32)
    occ = np.where(kind == 2, 0.8, 0.0).astype(np.float32)
    prior = vacuous(shape)
    prior[..., 31] = 0.1
    prior[..., 0b11001] = 0.9  # road {F,S,M}
    return free, occ, prior, kind > 0


def best_of(fn, repeats: int = 3) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def run() -> list[dict]:
    rng = np.random.default_rng(0)
    params = FusionParams.from_config(load_config())
    free, occ, prior, observed = _inputs(rng)
    pg, zeta = vacuous((SIDE, SIDE)), np.zeros((SIDE, SIDE), np.float32)
    sg = sensor_masses(free, occ)
    for _ in range(3):  # warm the state up so it holds many focal sets
        pg, zeta, _ = fusion_step(pg, zeta, sg, prior, observed, 0.1, params)
    step_s = best_of(lambda: fusion_step(pg, zeta, sg, prior, observed, 0.1, params))
    decide_s = best_of(lambda: decide(pg, params))

    n_ref = 300
    rates = scaled_rate(params.discount_rates, 0.1, 0.1).tolist()
    p = {"prior_where": params.prior_where, "discount": params.discount, "classical_rate": 0.1,
         "residual": params.residual_conflict, "gamma_o": params.gamma_occupied,
         "gamma_c": params.gamma_conflict, "inc": params.zeta_increment,
         "dec": params.zeta_decrement, "stopped_target": params.stopped_target}
    flat = pg.reshape(-1, 32)
    prior_cell = ref.from_vector(prior[0, 0])
    cells = [(ref.from_vector(flat[i]), float(zeta.flat[i]), float(free.flat[i]),
              float(occ.flat[i]), bool(observed.flat[i])) for i in range(n_ref)]
    t0 = time.perf_counter()
    for m, z, f, o, obs in cells:
        ref.step(m, z, f, o, prior_cell, obs, rates, p)
    ref_s = (time.perf_counter() - t0) * SIDE * SIDE / n_ref
    return [
        {"stage": "fusion step (numpy, dense 32)", "cells": SIDE * SIDE, "ms": step_s * 1e3,
         "frames/s": 1 / step_s, "vs reference": f"{ref_s / step_s:.0f}x"},
        {"stage": "decision (betP + codes)", "cells": SIDE * SIDE, "ms": decide_s * 1e3,
         "frames/s": 1 / decide_s, "vs reference": ""},
        {"stage": f"reference per-cell Python (timed on {n_ref} cells, scaled)",
         "cells": SIDE * SIDE, "ms": ref_s * 1e3, "frames/s": 1 / ref_s, "vs reference": "1x"},
    ]


if __name__ == "__main__":
    from run import print_table

    print_table("pipeline", run())
