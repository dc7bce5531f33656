#!/usr/bin/env python3
"""Stopped / moving / unmapped scores of a set of runs on simulated drives, per run and pooled
(issue 21's before/after table): :func:`evperc.eval.metrics.evaluate` on each RUN:DRIVE pair,
both cell sets; prints a markdown table (P / R / F1 of `stopped`, `unmapped`, `moving`,
moving within one cell, and `stopped` within one cell: a cell decided `stopped` is correct if
it or an 8-neighbour is truth S, a truth S cell found if it or an 8-neighbour is decided
`stopped` — the tolerance evperc.eval.metrics applies to `moving`, computed here only).

    python scripts/stopped_scores.py RUN:DRIVE [RUN:DRIVE ...] [--label before]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from evperc import load  # noqa: E402
from evperc.eval.metrics import FINE, dilate_one_cell, evaluate  # noqa: E402
from evperc.geo.window import Window, overlap  # noqa: E402
from evperc.sim.truth import load_truth  # noqa: E402


def _tol(c: np.ndarray) -> tuple[float, float, float]:
    p, r = c[0] / max(c[1], 1), c[2] / max(c[3], 1)
    return p, r, (2 * p * r / (p + r) if p + r > 0 else float("nan"))


def prf(conf: np.ndarray, decisions: list[str], cls: str) -> tuple[float, float, float]:
    i = FINE.index(cls)
    j = decisions.index(cls)
    tp = conf[i, j]
    p = tp / conf[:, j].sum() if conf[:, j].sum() else float("nan")
    r = tp / conf[i].sum() if conf[i].sum() else float("nan")
    f = 2 * p * r / (p + r) if p + r > 0 else float("nan")
    return p, r, f


def stopped_within_one_cell(run_dir: str, drive: str, cells: str) -> np.ndarray:
    """(correct, decided stopped, found, truth S) with one cell of tolerance (docstring)."""
    run, truth = load(run_dir), load_truth(Path(drive) / "truth")
    stop = run.decision_codes["stopped"]
    s_code = truth.class_codes["stopped"]
    out = np.zeros(4, np.int64)
    frames = {f.stamp_ns: f for f in truth.frames}
    for f in run.frames:
        t = frames.get(f.stamp_ns)
        if t is None:
            continue
        dec = np.asarray(f.decision)
        win = Window(truth.resolution_m, *dec.shape, int(f.origin[0]), int(f.origin[1]))
        ov = overlap(win, t.window)
        if ov is None:
            continue
        (rr, rc), (tr, tc) = ov
        ok = (t.visible if cells == "visible" else t.observed)[tr, tc]
        ds, ts = (dec == stop), (t.classes == s_code)
        d, tt = ds[rr, rc] & ok, ts[tr, tc] & ok
        out += (int((d & dilate_one_cell(ts)[tr, tc]).sum()), int(d.sum()),
                int((tt & dilate_one_cell(ds)[rr, rc]).sum()), int(tt.sum()))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("pairs", nargs="+")
    parser.add_argument("--label", default="run")
    args = parser.parse_args()
    print(f"| {args.label} | cells | stopped P | R | F1 | unmapped P | R | F1 | moving P | R | "
          "moving ±1 P | ±1 R | stopped ±1 P | ±1 R | ±1 F1 |")
    print("|---" * 15 + "|")
    for cells in ("visible", "observed"):
        pooled = None
        tol = np.zeros(4)
        stol = np.zeros(4)
        for pair in args.pairs:
            run_dir, drive = pair.split(":")
            m = evaluate(load(run_dir), load_truth(Path(drive) / "truth"), cells=cells)
            conf = np.array(m["confusion"]["counts"])
            decisions = m["confusion"]["decision"]
            pooled = conf if pooled is None else pooled + conf
            t = m["moving_within_one_cell"]
            tol += (t["correct"], t["decided"], t["found"], t["support"])
            st = stopped_within_one_cell(run_dir, drive, cells)
            stol += st
            row = [*prf(conf, decisions, "stopped"), *prf(conf, decisions, "unmapped"),
                   *prf(conf, decisions, "moving")[:2], t["precision"] or 0, t["recall"] or 0,
                   *_tol(st)]
            print(f"| {Path(run_dir).name} | {cells} | " + " | ".join(f"{v:.3f}" for v in row)
                  + " |", flush=True)
        row = [*prf(pooled, decisions, "stopped"), *prf(pooled, decisions, "unmapped"),
               *prf(pooled, decisions, "moving")[:2], tol[0] / tol[1], tol[2] / tol[3],
               *_tol(stol)]
        print(f"| **pooled** | {cells} | " + " | ".join(f"{v:.3f}" for v in row) + " |")


if __name__ == "__main__":
    main()
