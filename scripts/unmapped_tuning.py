#!/usr/bin/env python3
"""The unmapped cue's tuning table (docs/method.md, "Unmapped infrastructure"): the pass of
``evperc.objects.unmapped`` replayed on the stored decisions of runs made *without* it, for
a grid of ``(objects.unmapped_max_width_m, objects.unmapped_min_age_s)``, each scored with
``evperc.eval.metrics.evaluate`` on the visible cells against the drive's truth.

    evperc simulate --map tests/data/osm/helsinki_buildings.geojson \\
        --roads tests/data/osm/helsinki_roads.geojson --profile ibeo4 --seconds 20 \\
        --seed 1 --out D
    printf '[objects]\\nunmapped_cue = false\\n' > nocue.toml
    evperc run D/drive.mcap --map D/map.geojson --config nocue.toml --out R
    .venv/bin/python scripts/unmapped_tuning.py R:D [R2:D2 ...]

The replay gives the decisions `evperc run` would store with the cue: the pass reads only a
frame's decision, window, map labels and moving objects (all in the run's output or its
map), and nothing downstream of it feeds back into the fusion.
"""

from __future__ import annotations

import argparse
import itertools
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pyproj import CRS

from evperc.eval.metrics import evaluate
from evperc.geo.maps import load_map
from evperc.geo.prior import PriorRasteriser
from evperc.geo.window import Window
from evperc.objects.unmapped import (
    UnmappedCue,
    UnmappedParams,
    UnmappedState,
)
from evperc.output.objects import moving_object_cells
from evperc.sim.truth import load_truth

WIDTHS_M = (0.55, 0.65, 1.0)
AGES_S = (0.0, 0.1, 0.3, 1.0, 2.0)


@dataclass(frozen=True)
class ReplayFrame:
    """What :func:`evaluate` reads of a frame (no object list: not what is tuned)."""

    stamp_ns: int
    pose: np.ndarray
    origin: tuple[int, int]
    decision: np.ndarray
    objects: None = None


@dataclass(frozen=True)
class ReplayRun:
    decision_codes: dict[str, int]
    resolution_m: float
    crs: str
    frames: list[ReplayFrame]


def read_run(run_dir: Path, map_path: Path) -> dict[str, Any]:
    """The run's frames (decision, window, pose, moving objects' cells) and the map labels
    of each frame's window."""
    man = json.loads((run_dir / "manifest.json").read_text())
    if man["config"]["objects"].get("unmapped_cue", False):
        raise SystemExit(f"{run_dir}: made with the unmapped cue on; run it with "
                         "objects.unmapped_cue = false")
    res, shape = man["resolution_m"], (man["rows"], man["cols"])
    data = load_map(map_path, None, config_map=man["config"]["map"]).to_crs(
        CRS.from_user_input(man["crs"]))
    rasteriser = PriorRasteriser(data, res, man["config"]["map"]["tile_size_cells"])
    frames = []
    for chunk in man["chunks"]:
        with np.load(run_dir / chunk["file"]) as npz:
            a = {k: npz[k] for k in npz.files if k in (
                "stamp_ns", "pose", "origin", "decision", "objects", "object_cells",
                "object_counts")}
        ends = np.cumsum(a.get("object_counts", np.zeros(len(a["stamp_ns"]), np.int64)))
        cell_ends = (np.concatenate([[0], np.cumsum(a["objects"]["cell_count"].astype(
            np.int64))]) if "objects" in a else None)
        for k in range(len(a["stamp_ns"])):
            window = Window(res, *shape, int(a["origin"][k][0]), int(a["origin"][k][1]))
            moving = None
            if "objects" in a:
                first = 0 if k == 0 else int(ends[k - 1])
                records = a["objects"][first:int(ends[k])]
                cells = a["object_cells"][cell_ends[first]:cell_ends[int(ends[k])]]
                moving = moving_object_cells(records, cells)
            frames.append({"stamp_ns": int(a["stamp_ns"][k]), "pose": a["pose"][k],
                           "window": window, "decision": a["decision"][k],
                           "labels": rasteriser.labels(window), "moving": moving})
    return {"manifest": man, "shape": shape, "resolution_m": res, "frames": frames}


def replay(run: dict[str, Any], params: UnmappedParams) -> ReplayRun:
    """The run's frames with the pass applied (the runner's circular-buffer offsets)."""
    shape = run["shape"]
    cue = UnmappedCue(params, shape, run["resolution_m"])
    state = UnmappedState.fresh(shape)
    prev_window, prev_ns, offset = None, None, (0, 0)
    out = []
    for f in run["frames"]:
        window, shift = f["window"], (0, 0)
        if prev_window is not None and window != prev_window:
            shift = (window.row0 - prev_window.row0, window.col0 - prev_window.col0)
            offset = ((offset[0] + shift[0]) % shape[0], (offset[1] + shift[1]) % shape[1])
        dt_s = 0.0 if prev_ns is None else (f["stamp_ns"] - prev_ns) * 1e-9
        prev_window, prev_ns = window, f["stamp_ns"]
        decision = f["decision"].copy()
        cue.step(state, decision, f["labels"], dt_s, moving_cells=f["moving"],
                 offset=offset, shift=shift)
        out.append(ReplayFrame(f["stamp_ns"], f["pose"], (window.row0, window.col0),
                               decision))
    man = run["manifest"]
    return ReplayRun(man["decision_codes"], run["resolution_m"], man["crs"], out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("pairs", nargs="+", metavar="RUN:DRIVE",
                        help="a run made without the cue and the simulated drive it is of")
    args = parser.parse_args()
    runs, truths, stopped_f1 = [], [], []
    for pair in args.pairs:
        run_dir, drive = (Path(p) for p in pair.split(":"))
        run = read_run(run_dir, drive / "map.geojson")
        runs.append(run)
        truths.append(load_truth(drive / "truth"))
        as_stored = ReplayRun(run["manifest"]["decision_codes"], run["resolution_m"],
                              run["manifest"]["crs"],
                              [ReplayFrame(f["stamp_ns"], f["pose"],
                                           (f["window"].row0, f["window"].col0), f["decision"])
                               for f in run["frames"]])
        stopped_f1.append(evaluate(as_stored, truths[-1], "visible")["per_class"]["stopped"]["f1"]
                          or 0.0)
    print("| unmapped_max_width_m | unmapped_min_age_s | unmapped P | R | F1 "
          "| Δ stopped F1 (per run) |")
    print("|---|---|---|---|---|---|")
    for width, age in itertools.product(WIDTHS_M, AGES_S):
        params = UnmappedParams(max_width_m=width, min_age_s=age)
        scores, delta = [], []
        for run, truth, before in zip(runs, truths, stopped_f1, strict=True):
            after = evaluate(replay(run, params), truth, "visible")
            scores.append(after["per_class"]["unmapped"])
            delta.append((after["per_class"]["stopped"]["f1"] or 0.0) - before)
        mean = {k: float(np.mean([s[k] or 0.0 for s in scores]))
                for k in ("precision", "recall", "f1")}
        print(f"| {width} | {age} | {mean['precision']:.3f} | {mean['recall']:.3f} "
              f"| {mean['f1']:.3f} | {min(delta):+.4f} … {max(delta):+.4f} |", flush=True)


if __name__ == "__main__":
    main()
