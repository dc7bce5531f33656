#!/usr/bin/env python3
"""The headline, ablation and object tables of docs/evaluation.md, from the evaluations that
``scripts/evaluation_study.py`` cached in its work directory (run that first, with the same
``--work`` and the configs named here):

    .venv/bin/python scripts/evaluation_study.py --work W --config default \\
        --config kurdej2013 --config configs/ablation/free_margin.toml \\
        --config configs/ablation/no_gate.toml --config configs/ablation/no_building_margin.toml \\
        --config configs/ablation/no_objects.toml --config configs/ablation/no_unmapped_cue.toml \\
        --config configs/ablation/no_stopped_needs_road.toml \\
        --config configs/ablation/no_footprint_completion.toml \\
        --config configs/ablation/no_arrival_evidence.toml --config configs/ibeo4.toml \\
        --config configs/ablation/ground_prior.toml --config configs/ablation/no_rehit.toml \\
        --config configs/ablation/rehit_any_gap.toml --config configs/ablation/speed_1.toml \\
        --config configs/ablation/no_low_groups.toml --config configs/ablation/no_isolated.toml \\
        --config configs/ablation/no_backfill.toml --config configs/ablation/no_bridge.toml \\
        --config configs/ablation/no_needs_object.toml \\
        --config configs/ablation/arrival_any_count.toml \\
        --config configs/ablation/no_ego_clearance.toml \\
        --config configs/ablation/no_vehicle_boxes.toml \\
        --config configs/ablation/no_stopped_off_facades.toml \\
        --config configs/ablation/no_evidence_expiry.toml \\
        --config configs/ablation/rehit_1_5.toml \\
        --config configs/ablation/clusters_on_buildings.toml \\
        --config configs/ablation/facade_fragments_any_height.toml \\
        --config configs/ablation/faded_free_paper.toml \\
        --config configs/ablation/no_split.toml --config configs/ablation/no_lead.toml \\
        --config configs/ablation/no_support.toml --config configs/ablation/no_facade_speed.toml \\
        --config configs/ablation/no_small_conflict.toml \\
        --config configs/ablation/rehit_recent_returns.toml --config configs/hdl64.toml \\
        --config configs/ablation/no_growth.toml
    .venv/bin/python scripts/report_tables.py --work W

Figures are means ± sample sd over the test seeds of the per-drive scores (as the study's
tables), except the missed episodes and the object counts, which are pooled over the seeds.
Moving cells are scored strictly (the truth's centre-in convention, docs/truth-format.md) and
within one cell (``moving_within_one_cell`` of evperc.eval.metrics: the 8-neighbourhood);
objects and missed episodes as well (``objects.within_one_cell``,
``latency_frames_within_one_cell``: a record's cells or an agent's widened by one cell).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import evaluation_study as study  # noqa: E402

from evperc.eval.metrics import VISIBLE_FRAME_BUCKETS  # noqa: E402

ABLATIONS = (("paper's method (`--preset kurdej2013`)", "kurdej2013"),
             ("**defaults**", "default"),
             ("with the free margin (d_s 0.5 m)", "configs/ablation/free_margin.toml"),
             ("no motion gate", "configs/ablation/no_gate.toml"),
             ("no building margin", "configs/ablation/no_building_margin.toml"),
             ("no object stage (no fill, no object list)", "configs/ablation/no_objects.toml"),
             ("no unmapped cue", "configs/ablation/no_unmapped_cue.toml"),
             ("stopped without the road rule", "configs/ablation/no_stopped_needs_road.toml"),
             ("no footprint completion", "configs/ablation/no_footprint_completion.toml"),
             ("no arrival evidence", "configs/ablation/no_arrival_evidence.toml"),
             ("configs/ibeo4.toml (small moving groups static)", "configs/ibeo4.toml"),
             ("configs/hdl64.toml (recent re-hits, small clusters' returns' centroids)",
              "configs/hdl64.toml"),
             ("ground fallback on the prior plane", "configs/ablation/ground_prior.toml"),
             ("no re-hit revocation, 3 free scans", "configs/ablation/no_rehit.toml"),
             ("re-hit after any gap, 1.0 s", "configs/ablation/rehit_any_gap.toml"),
             ("tracker speed floor 1.0 m/s", "configs/ablation/speed_1.toml"),
             ("no low-group rule (small moving groups kept)",
              "configs/ablation/no_low_groups.toml"),
             ("no isolated small clusters", "configs/ablation/no_isolated.toml"),
             ("no backfill (the causal output)", "configs/ablation/no_backfill.toml"),
             ("no bridged gaps", "configs/ablation/no_bridge.toml"),
             ("moving cells without an object kept", "configs/ablation/no_needs_object.toml"),
             ("an arrival from any count of moving cells",
              "configs/ablation/arrival_any_count.toml"),
             ("no ego clearance", "configs/ablation/no_ego_clearance.toml"),
             ("no vehicle boxes", "configs/ablation/no_vehicle_boxes.toml"),
             ("no façade rule for stopped", "configs/ablation/no_stopped_off_facades.toml"),
             ("motion evidence never expires", "configs/ablation/no_evidence_expiry.toml"),
             ("re-hit window 1.5 s", "configs/ablation/rehit_1_5.toml"),
             ("clusters through the façades' static cells",
              "configs/ablation/clusters_on_buildings.toml"),
             ("a small group keeps façade cells of any height",
              "configs/ablation/facade_fragments_any_height.toml"),
             ("faded free space: the paper's product under a closed gate",
              "configs/ablation/faded_free_paper.toml"),
             ("no split of shared clusters", "configs/ablation/no_split.toml"),
             ("no lead before a track's first association", "configs/ablation/no_lead.toml"),
             ("small moving groups kept without support", "configs/ablation/no_support.toml"),
             ("a re-hit revokes only its block's recently hit cells (an option)",
              "configs/ablation/rehit_recent_returns.toml"),
             ("no small clusters that conflict", "configs/ablation/no_small_conflict.toml"),
             ("no speed bound on clusters wholly at a façade",
              "configs/ablation/no_facade_speed.toml"),
             ("no growth rule (a cluster that only grew shows motion evidence)",
              "configs/ablation/no_growth.toml"))


#: the scores of the headline and ablation rows, in column order
SCORE_KEYS = (("per_class", "moving", "precision"), ("per_class", "moving", "recall"),
              ("per_class", "moving", "f1"), ("coarse", "free", "precision"),
              ("per_class", "stopped", "f1"), ("per_class", "unmapped", "f1"),
              ("moving_within_one_cell", "precision"), ("moving_within_one_cell", "recall"),
              ("stopped_within_one_cell", "f1"))
#: their column headers
SCORE_HEADS = ("moving P", "moving R", "moving F1", "free P", "stopped F1", "unmapped F1",
               "moving P ±1 cell", "moving R ±1 cell", "stopped F1 ±1 cell")


#: the cell sets the study evaluates every run on
CELLS = ("visible", "observed")


def _get(m: dict[str, Any], *path: str) -> float | None:
    for p in path:
        m = m[p]
    return m  # type: ignore[return-value]


def _missed(ms: list[dict[str, Any]]) -> str:
    eps = sum(m["latency_frames"]["episodes"] for m in ms)
    missed = sum(m["latency_frames"]["missed"] for m in ms)
    near = sum(m["latency_frames_within_one_cell"]["missed"] for m in ms)
    return f"{missed} of {eps} ({near} within one cell)"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--seeds", default=study.TEST_SEEDS)
    parser.add_argument("--profiles", default="ibeo4,hdl64")
    parser.add_argument("--extra", action="append", default=[],
                        help="a further --config of the study (a TOML file): one more row of "
                             "the ablation table, labelled with its file name (repeatable); "
                             "configs the study has not evaluated on every drive are left out")
    parser.add_argument("--kitti", type=Path,
                        help="instead: the SemanticKITTI table from the DIR/{default,kurdej2013}-"
                             "SEQ.json files of `evperc evaluate --semantickitti --json`")
    args = parser.parse_args()
    if args.kitti is not None:
        return kitti_table(args.kitti)
    profiles = args.profiles.split(",")
    drives = [study.Drive(p, int(s), study.DEFAULT_SECONDS[p]) for p in profiles
              for s in args.seeds.split(",")]
    ablations = [*ABLATIONS, *((f"`{Path(e).name}`", e) for e in args.extra)]
    tags = {name: study.config_tag(study.resolve_config(name, args.work))
            for _, name in ablations}
    ms_ = study._mean_sd

    def runs(profile: str, name: str, cells: str) -> tuple[list, list]:
        ds = [d for d in drives if d.profile == profile]
        return study.load_metrics(args.work, tags[name], ds, cells)

    def evaluated(profile: str, name: str) -> bool:
        """Whether the study evaluated this config on every drive of the profile."""
        return all(study.eval_path(args.work, tags[name], d, cells).is_file()
                   for d in drives if d.profile == profile for cells in CELLS)

    def scores(ms: list, with_map: str) -> str:
        """SCORE_KEYS and infrastructure precision (with the map only; mean ± sd over the
        seeds), as table cells"""
        infra = (ms_(_get(m, "per_class", "infrastructure", "precision") for m in ms)
                 if with_map == "with" else "–")
        return " | ".join([*(ms_(_get(m, *key) for m in ms) for key in SCORE_KEYS), infra])

    print("### Headline\n")
    heads = " | ".join(SCORE_HEADS)
    print(f"| profile | method | map | cells | {heads} | infrastructure P | missed moving "
          "episodes |")
    print("|" + "---|" * (len(SCORE_HEADS) + 6))
    for profile in profiles:
        for label, name in ABLATIONS[:2]:
            if not evaluated(profile, name):
                continue
            for k, with_map in ((0, "with"), (1, "without")):
                for cells in ("visible", "observed"):
                    ms = runs(profile, name, cells)[k]
                    obs = runs(profile, name, "observed")[k]
                    print(f"| {profile} | {label} | {with_map} | {cells} | "
                          f"{scores(ms, with_map)} | "
                          f"{_missed(obs) if cells == 'observed' else '–'} |")

    print("\n### Ablation (visible cells; missed episodes on observed cells)\n")
    print(f"| profile | config | map | {heads} | infrastructure P | missed moving episodes | "
          "object P / R (mean of drives) |")
    print("|" + "---|" * (len(SCORE_HEADS) + 6))
    for profile in profiles:
        for k, with_map in ((0, "with"), (1, "without")):
            for label, name in ablations:
                if not evaluated(profile, name):
                    continue   # a config the study was not asked for
                ms = runs(profile, name, "visible")[k]
                obs = runs(profile, name, "observed")[k]
                objects = [m["objects"] for m in ms]
                pr = ("–" if any(o is None for o in objects) else
                      f"{ms_(o['precision'] for o in objects)} / "
                      f"{ms_(o['recall'] for o in objects)}")
                print(f"| {profile} | {label} | {with_map} | {scores(ms, with_map)} | "
                      f"{_missed(obs)} | {pr} |")

    print("\n### Missed episodes by frames visible (observed cells, with the map, pooled)\n")
    buckets = list(VISIBLE_FRAME_BUCKETS)
    print("| profile | method | " + " | ".join(f"visible in {b} frames" for b in buckets)
          + " |")
    print("|" + "---|" * (len(buckets) + 2))
    for profile in profiles:
        for label, name in ABLATIONS[:2]:
            if not evaluated(profile, name):
                continue
            obs = runs(profile, name, "observed")[0]
            cells = []
            for b in buckets:
                missed = sum(m["latency_frames"]["by_visible_frames"][b]["missed"] for m in obs)
                eps = sum(m["latency_frames"]["by_visible_frames"][b]["episodes"] for m in obs)
                cells.append(f"{missed} of {eps}")
            print(f"| {profile} | {label} | " + " | ".join(cells) + " |")

    print("\n### Objects (defaults, visible cells, pooled over the seeds)\n")
    print("| profile | map | moving objects reported | matched | precision | true moving "
          "(agent-frames) | found | recall | track switches | identity switches | agent-frames "
          "matched twice or more | P / R within one cell |")
    print("|" + "---|" * 12)
    for profile in profiles:
        if not evaluated(profile, "default"):
            continue
        for k, with_map in ((0, "with"), (1, "without")):
            obj = [m["objects"] for m in runs(profile, "default", "visible")[k]]
            if any(o is None for o in obj):
                continue
            rep = sum(o["moving_reported"] for o in obj)
            mat = sum(o["moving_matched"] for o in obj)
            tru = sum(o["moving_truth"] for o in obj)
            fnd = sum(o["moving_found"] for o in obj)
            sw = sum(o["track_switches"] for o in obj)
            # evaluations made before the identity switches (2026-12-06) lack them
            ids = ("– | –" if any("identity_switches" not in o for o in obj) else
                   f"{sum(o['identity_switches'] for o in obj)} | "
                   f"{sum(o['duplicate_matches'] for o in obj)}")
            p = f"{mat / rep:.3f}" if rep else "–"
            r = f"{fnd / tru:.3f}" if tru else "–"
            near_p = (f"{sum(o['within_one_cell']['moving_matched'] for o in obj) / rep:.3f}"
                      if rep else "–")
            near_r = (f"{sum(o['within_one_cell']['moving_found'] for o in obj) / tru:.3f}"
                      if tru else "–")
            print(f"| {profile} | {with_map} | {rep:,} | {mat:,} | {p} | {tru:,} | {fnd:,} | "
                  f"{r} | {sw} | {ids} | {near_p} / {near_r} |")
    return 0


KITTI_CONFIGS = (("**defaults**", "default"), ("paper's method", "kurdej2013"),
                 ("no motion gate", "no_gate"), ("with the free margin", "free_margin"),
                 ("no object stage", "no_objects"),
                 ("configs/semantickitti.toml before 2026-12-03 (all returns only)",
                  "semantickitti_before"),
                 ("**configs/semantickitti.toml** (all returns + small moving groups static)",
                  "semantickitti"))


def kitti_table(folder: Path) -> int:
    """Scans from the third on (`--warmup 2`): moving IoU, P, R and the static points decided
    moving (% of the scored points) per slice and config; a config whose DIR/CONFIG-SEQ.json
    is missing is left out."""
    tuning = {"00", "09"}
    print("| seq | used for | moving points | config | IoU | P | R | static→moving |")
    print("|" + "---|" * 8)

    def f(v: float | None) -> str:
        return "–" if v is None else f"{v:.3f}"

    for seq in ("00", "01", "05", "07", "09", "10"):
        use = "tuning" if seq in tuning else "held out"
        for label, config in KITTI_CONFIGS:
            path = folder / f"{config}-{seq}.json"
            if not path.is_file():
                continue
            o = json.loads(path.read_text())["overall"]
            truth = o["moving_truth"]
            iou = f(o["iou"]) if truth else f"– ({o['fp']:,} FP)"
            print(f"| {seq} | {use} | {truth:,} | {label} | {iou} | {f(o['precision'])} | "
                  f"{f(o['recall']) if truth else '–'} | {100 * o['static_as_moving']:.2f} % |")
    print("\n| config | mean moving IoU, 00 01 05 07 10 |\n|---|---|")
    for label, config in KITTI_CONFIGS:
        paths = [folder / f"{config}-{seq}.json" for seq in ("00", "01", "05", "07", "10")]
        if all(p.is_file() for p in paths):
            ious = [json.loads(p.read_text())["overall"]["iou"] or 0.0 for p in paths]
            print(f"| {label} | {sum(ious) / len(ious):.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
