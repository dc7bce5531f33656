"""Belief-function core timings on a 400 × 400 grid (160,000 cells) on Ω = {F, I, U, S, M}.

``run()`` returns one dict per table row; ``python benchmarks/bench_dst.py`` prints the table.
Times are the best of several repeats (time.perf_counter). The naive pair-loop reference
(evperc.dst.reference: 4ⁿ = 1024 vectorised pair updates, always float64) is timed on a
tenth of the cells and scaled ×10, as its cost is linear in the number of cells.
"""

from __future__ import annotations

import numpy as np
from timing import best_of  # noqa: E402  (benchmarks/ is on sys.path)

from evperc.dst import FRAME, conjunctive, contextual_discount, dempster, disjunctive
from evperc.dst import reference as ref

SHAPE = (400, 400)
NAIVE_FRACTION = 10
RATES = np.array([0.1, 0.0, 0.01, 0.02, 0.1])  # method.md §5.3 defaults, bit order F I U S M




def random_grid(rng: np.random.Generator, dtype: type) -> np.ndarray:
    """Dense random mass functions (all 32 sets focal): the worst case for any layout."""
    return rng.dirichlet(np.ones(FRAME.size), size=SHAPE).astype(dtype)


def rows_for(dtype: type, rng: np.random.Generator, repeats: int) -> list[dict]:
    """All rows for one dtype."""
    cells = SHAPE[0] * SHAPE[1]
    m1, m2 = random_grid(rng, dtype), random_grid(rng, dtype)
    sub = slice(0, SHAPE[0] // NAIVE_FRACTION)
    naive_s = best_of(lambda: ref.conjunctive(m1[sub], m2[sub]), 2) * NAIVE_FRACTION
    per_cell_rates = rng.uniform(0, 0.2, size=(*SHAPE, FRAME.n)).astype(dtype)
    cases = [
        ("conjunctive", "matrix (BLAS)", lambda: conjunctive(m1, m2, kernel="matrix")),
        ("conjunctive", "butterfly (default)", lambda: conjunctive(m1, m2, kernel="butterfly")),
        ("dempster", "butterfly (default)", lambda: dempster(m1, m2)),
        ("disjunctive", "matrix (BLAS)", lambda: disjunctive(m1, m2, kernel="matrix")),
        ("disjunctive", "butterfly (default)",
         lambda: disjunctive(m1, m2, kernel="butterfly")),
        ("contextual_discount", "rates (5,)", lambda: contextual_discount(m1, RATES)),
        ("contextual_discount", "(5,) butterfly",
         lambda: contextual_discount(m1, RATES, kernel="butterfly")),
        ("contextual_discount", "rates per cell", lambda: contextual_discount(m1, per_cell_rates)),
    ]
    rows = []
    for op, kernel, fn in cases:
        seconds = best_of(fn, repeats)
        rows.append({
            "op": op, "dtype": np.dtype(dtype).name, "kernel": kernel, "cells": cells,
            "ms": seconds * 1e3, "cells_per_s": cells / seconds,
            "speedup_vs_naive": naive_s / seconds if op == "conjunctive" else None, "note": "",
        })
    rows.append({
        "op": "conjunctive", "dtype": np.dtype(dtype).name, "kernel": "naive pair loop",
        "cells": cells, "ms": naive_s * 1e3, "cells_per_s": cells / naive_s,
        "speedup_vs_naive": 1.0,
        "note": f"timed on 1/{NAIVE_FRACTION} of the cells, scaled; computes in float64",
    })
    return rows


def run(repeats: int = 5) -> list[dict]:
    """Rows for float32 then float64 grids of 160,000 cells, n = 5."""
    rng = np.random.default_rng(0)
    return [row for dtype in (np.float32, np.float64) for row in rows_for(dtype, rng, repeats)]


def format_table(rows: list[dict]) -> str:
    header = (f"{'op':<20} {'dtype':<8} {'kernel':<16} {'cells':>8} {'ms':>9} "
              f"{'cells/s':>10} {'× naive':>8}  note")
    lines = [header, "-" * len(header)]
    for r in rows:
        speed = "" if r["speedup_vs_naive"] is None else f"{r['speedup_vs_naive']:.1f}"
        lines.append(f"{r['op']:<20} {r['dtype']:<8} {r['kernel']:<16} {r['cells']:>8} "
                     f"{r['ms']:>9.1f} {r['cells_per_s']:>10.3g} {speed:>8}  {r['note']}")
    return "\n".join(lines)


if __name__ == "__main__":
    print(format_table(run()))
