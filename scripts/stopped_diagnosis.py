#!/usr/bin/env python3
"""Where the `stopped` class goes wrong on simulated drives (issue 21): recall and precision
of `stopped`, traced cell by cell.

For each run (a directory written by `evperc run` on a drive of `evperc simulate`) and its
truth, over the cells the truth scores (``--cells visible|observed``, as
:func:`evperc.eval.metrics.evaluate`):

- **recall side**: every truth-S cell (class ``stopped``: an agent at ≤ 0.1 m/s,
  evperc/sim/traffic.py) is counted by the run's decision, split by *what the agent did*
  (``parked``: a parked car that has not moved yet in the drive; ``standing``: a pedestrian
  that has not moved yet; ``paused``: any agent seen in class M at this or an earlier
  frame of the drive, within the truth's window, i.e. stopped after moving) and by the
  cell's *map context* (road / other / building, the map's prior labels; all ``none`` for
  a ``--no-map`` run), plus whether the cell is in a `stopped` object of the frame's
  object list;
- **precision side**: every cell decided `stopped` is counted by its truth class; a truth-free
  one is further split by the first kind of truth cell 8-next to it, in the order S (the
  footprint's blur), M, I (a façade's return outside the building's outline), U, or none.

Each table is printed as markdown, pooled over the runs given. Usage:

    python scripts/stopped_diagnosis.py --cells visible \\
        /tmp/stopped/runs/base/ibeo4-s1-map:/tmp/stopped/drives/ibeo4-s1 ...

(RUN:DRIVE pairs; DRIVE is the `evperc simulate` output directory with ``map.geojson`` and
``truth/``). ``--json FILE`` writes the raw counts.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pyproj

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from evperc import load  # noqa: E402
from evperc.eval.metrics import dilate_one_cell  # noqa: E402
from evperc.geo.maps import load_map  # noqa: E402
from evperc.geo.prior import (  # noqa: E402
    CONTEXT_BUILDING,
    CONTEXT_OTHER,
    CONTEXT_ROAD,
    PriorRasteriser,
)
from evperc.geo.window import Window, overlap  # noqa: E402
from evperc.output.objects import OBJECT_STATES  # noqa: E402
from evperc.sim.truth import load_truth  # noqa: E402

CONTEXT_NAMES = {CONTEXT_OTHER: "other", CONTEXT_ROAD: "road", CONTEXT_BUILDING: "building"}
TRUTH_NAMES = {1: "free", 2: "moving", 4: "stopped", 5: "infrastructure", 6: "unmapped"}


def _pairs(run_frames: Any, truth_frames: Any) -> Any:
    truth_it = iter(truth_frames)
    t = next(truth_it, None)
    for f in run_frames:
        while t is not None and t.stamp_ns < f.stamp_ns:
            t = next(truth_it, None)
        if t is None:
            return
        if t.stamp_ns == f.stamp_ns:
            yield f, t


def diagnose(run_dir: Path, drive_dir: Path, cells: str = "visible") -> dict[str, Counter]:
    """Counters of one run (module docstring): ``recall`` keyed (behaviour, context,
    decision, in_stopped_object), ``precision`` keyed (truth class or "free, next to S" /
    "free, not next to S", context)."""
    run = load(run_dir)
    truth = load_truth(drive_dir / "truth")
    names = {v: k for k, v in run.decision_codes.items()}
    codes = truth.class_codes
    s_code, m_code = codes["stopped"], codes["moving"]
    roles = {a["id"]: a["role"] for a in truth.agents}
    stopped_dec = run.decision_codes["stopped"]
    rast = None
    map_path = run.manifest.get("map")
    if map_path:
        cfg = run.manifest["config"]
        data = load_map(map_path, run.manifest.get("roads"), config_map=cfg["map"])
        data = data.to_crs(pyproj.CRS.from_user_input(run.manifest["crs"]))
        rast = PriorRasteriser(data, truth.resolution_m, cfg["map"]["tile_size_cells"])
    moved: set[int] = set()   # agents seen in class M so far
    recall: Counter = Counter()
    precision: Counter = Counter()
    for f, t in _pairs(run.frames, truth.frames):
        dec = np.asarray(f.decision)
        win = Window(truth.resolution_m, dec.shape[0], dec.shape[1], int(f.origin[0]),
                     int(f.origin[1]))
        # agents in class M in this frame (anywhere in the truth window) count as moved
        # from this frame on: a paused agent is S only after its M frames
        moving_now = np.unique(t.agent[(t.classes == m_code) & (t.agent > 0)])
        moved.update(int(a) for a in moving_now)
        ov = overlap(win, t.window)
        if ov is None:
            continue
        (rr, rc), (tr, tc) = ov
        d = dec[rr, rc]
        cls = t.classes[tr, tc]
        scored = (t.visible if cells == "visible" else t.observed)[tr, tc]
        ctx = (rast.labels(win)[rr, rc] if rast is not None
               else np.full(d.shape, 255, np.uint8))
        agent = t.agent[tr, tc]
        in_obj = np.zeros(dec.size, bool)
        if f.objects is not None and len(f.objects):
            counts = f.objects["cell_count"].astype(np.int64)
            st = np.repeat(f.objects["state"] == OBJECT_STATES["stopped"], counts)
            in_obj[np.asarray(f.object_cells, np.int64)[st]] = True
        in_obj = in_obj.reshape(dec.shape)[rr, rc]
        sel = scored & (cls == s_code)
        for a, cx, dd, ob in zip(agent[sel], ctx[sel], d[sel], in_obj[sel], strict=True):
            a = int(a)
            role = roles.get(a, "?")
            beh = ("paused" if a in moved else
                   {"parked": "parked", "pedestrian": "standing"}.get(role, f"{role}-never-moved"))
            recall[(beh, CONTEXT_NAMES.get(int(cx), "none"), names[int(dd)], bool(ob))] += 1
        near = {k: dilate_one_cell(t.classes == codes[k])[tr, tc]
                for k in ("stopped", "moving", "infrastructure", "unmapped")}
        sel = scored & (d == stopped_dec)
        for i in zip(*np.nonzero(sel), strict=True):
            name = TRUTH_NAMES.get(int(cls[i]), "?")
            if name == "free":  # the first kind of truth neighbour, in this order
                name = next((f"free, next to {k[0].upper()}" for k in near if near[k][i]),
                            "free, next to none")
            precision[(name, CONTEXT_NAMES.get(int(ctx[i]), "none"))] += 1
    return {"recall": recall, "precision": precision}


def _table(counter: Counter, rows_key: Any, cols_key: Any, title: str) -> str:
    rows: Counter = Counter()
    cols: Counter = Counter()
    grid: Counter = Counter()
    for k, v in counter.items():
        r, c = rows_key(k), cols_key(k)
        rows[r] += v
        cols[c] += v
        grid[(r, c)] += v
    col_names = [c for c, _ in cols.most_common()]
    out = [f"#### {title}", "", "| | " + " | ".join(col_names) + " | cells |",
           "|---" * (len(col_names) + 2) + "|"]
    for r, n in rows.most_common():
        out.append(f"| {r} | " + " | ".join(
            f"{100 * grid[(r, c)] / n:.1f} %" for c in col_names) + f" | {n:,} |")
    total = sum(rows.values())
    out.append("| all | " + " | ".join(f"{100 * cols[c] / total:.1f} %" for c in col_names)
               + f" | {total:,} |")
    return "\n".join(out) + "\n"


def report(res: dict[str, Counter]) -> str:
    rec, prec = res["recall"], res["precision"]
    parts = [
        _table(rec, lambda k: k[0], lambda k: k[2],
               "Truth S cells by what the agent did (rows) and decision (columns)"),
        _table(rec, lambda k: f"{k[0]}, {k[1]}", lambda k: k[2],
               "Truth S cells by behaviour and map context (rows) and decision"),
        _table(rec, lambda k: f"{k[0]}, in a stopped object" if k[3] else
               f"{k[0]}, in no stopped object", lambda k: k[2],
               "Truth S cells: in a `stopped` object of the object list?"),
        _table(prec, lambda k: "decided stopped", lambda k: k[0],
               "Cells decided `stopped` by truth class (precision side)"),
        _table(prec, lambda k: k[1], lambda k: k[0],
               "Cells decided `stopped` by map context (rows) and truth class"),
    ]
    return "\n".join(parts)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("pairs", nargs="+", help="RUN:DRIVE directory pairs")
    parser.add_argument("--cells", choices=("visible", "observed"), default="visible")
    parser.add_argument("--json", type=Path, help="write the pooled counts here")
    args = parser.parse_args()
    pooled: dict[str, Counter] = {"recall": Counter(), "precision": Counter()}
    for pair in args.pairs:
        run_dir, drive_dir = pair.split(":")
        res = diagnose(Path(run_dir), Path(drive_dir), args.cells)
        for k in pooled:
            pooled[k].update(res[k])
    print(f"cells: {args.cells}; runs: {len(args.pairs)}\n")
    print(report(pooled))
    if args.json:
        args.json.write_text(json.dumps(
            {k: [[list(key), v] for key, v in c.items()] for k, c in pooled.items()}, indent=1))


if __name__ == "__main__":
    main()
