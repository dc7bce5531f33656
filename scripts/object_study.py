#!/usr/bin/env python3
"""Object-level scores of the default config on simulated drives (issue 21): per profile and
seed, ``evperc simulate`` (cached in WORK), ``evperc run`` with the map, then
:func:`evperc.eval.metrics.evaluate` on the visible cells; prints a markdown table of the
object list's moving precision / recall and track switches, with the cell-level moving F1
beside it.

    .venv/bin/python scripts/object_study.py --work /tmp/objstudy --seeds 11,12,13
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import evaluation_study as study  # noqa: E402

from evperc import load  # noqa: E402
from evperc.eval.metrics import evaluate  # noqa: E402
from evperc.sim.truth import load_truth  # noqa: E402

OSM = REPO / "tests" / "data" / "osm"
#: each profile's drive length (s), as scripts/evaluation_study.py simulates it
SECONDS = {p: int(s) for p, s in study.DEFAULT_SECONDS.items()}
EVPERC = [sys.executable, "-m", "evperc", "-q"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--seeds", default="11,12,13,14,15,16")
    parser.add_argument("--profiles", default="ibeo4,hdl64")
    parser.add_argument("--config", type=Path, help="a --config file for the runs")
    args = parser.parse_args()
    rows = []
    for profile in args.profiles.split(","):
        for seed in args.seeds.split(","):
            drive = args.work / "drives" / f"{profile}-s{seed}"
            if not (drive / "truth" / "manifest.json").exists():
                subprocess.run([*EVPERC, "simulate", "--map",
                                str(OSM / "helsinki_buildings.geojson"), "--roads",
                                str(OSM / "helsinki_roads.geojson"), "--profile",
                                profile, "--seconds", str(SECONDS[profile]), "--seed", seed,
                                "--out", str(drive), "--overwrite"], check=True, cwd=REPO)
            out = args.work / "runs" / f"{profile}-s{seed}"
            cmd = [*EVPERC, "run", str(drive / "drive.mcap"), "--map",
                   str(drive / "map.geojson"), "--out", str(out), "--overwrite"]
            if args.config:
                cmd += ["--config", str(args.config)]
            subprocess.run(cmd, check=True, cwd=REPO)
            m = evaluate(load(out), load_truth(drive / "truth"), cells="visible")
            o = m["objects"]
            rows.append((profile, seed, o, m["per_class"]["moving"]["f1"]))
            print(profile, seed, o, flush=True)
    print("\n| profile | seed | moving objects reported | matched | precision | true moving "
          "(visible) | found | recall | track switches | cell moving F1 (visible) |")
    print("|---|---|---|---|---|---|---|---|---|---|")

    def f(v: float | None) -> str:
        return "–" if v is None else f"{v:.2f}"

    for profile, seed, o, f1 in rows:
        print(f"| {profile} | {seed} | {o['moving_reported']} | {o['moving_matched']} | "
              f"{f(o['precision'])} | {o['moving_truth']} | {o['moving_found']} | "
              f"{f(o['recall'])} | {o['track_switches']} | {f(f1)} |")


if __name__ == "__main__":
    main()
