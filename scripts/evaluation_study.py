#!/usr/bin/env python3
"""The evaluation study of docs/evaluation.md: every number of that page, from one command.

Report mode (default) — for every profile and seed: ``evperc simulate`` (cached in the work
directory), ``evperc run`` with the map and with ``--no-map`` (optionally with ``--config``),
``evperc evaluate --cells observed|visible --json``; then the JSON files are aggregated into
markdown tables (mean ± sample standard deviation over the seeds):

    .venv/bin/python scripts/evaluation_study.py --work /tmp/evstudy  # test seeds 11-16

Tune mode (``--tune``) — a grid search of the ``[fusion]`` / ``[decision]`` parameters on the
tuning seeds, with the map, in process: the sensor grids and map labels of every scan are
computed once per drive (they do not depend on the tuned keys), then each candidate replays the
fusion (:func:`evperc.fusion.fused.fused_step`, the runner's kernel) and is scored with
:func:`evperc.eval.metrics.evaluate`, exactly as `evperc run` + `evperc evaluate` would score it:

    .venv/bin/python scripts/evaluation_study.py --tune --work /tmp/evstudy  # tuning seeds 1,2

Everything of docs/evaluation.md (tuning, then the report with the defaults, the SPEC values and
the tuned config side by side, paired per seed):

    .venv/bin/python scripts/evaluation_study.py --all --work /tmp/evstudy --out study.md

Objective J (higher is better), per drive and cell set, averaged over the tuning drives and
over both cell sets (observed, visible):
J = mean(F1 moving, F1 stopped, coarse F1 static, coarse precision free).

The grid is searched in three stages (each keeps the best of the previous one): ζ accumulator
(δ_inc, δ_dec, γ_O, γ_∅), discount rates (α_F, α_M, α_S, α_U), decision thresholds.
A stage's winner is adopted only if it beats the previous values by more than MIN_GAIN in J;
finally each changed key is put back to its SPEC value, one at a time, when that costs at most
MIN_GAIN (fewest changes for the same score).
The best candidate is written to WORK/tune/best.toml (a `--config` file).
"""

from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import logging
import os
import shlex
import subprocess
import sys
import time
import types
from collections.abc import Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

log = logging.getLogger("evaluation_study")

REPO = Path(__file__).resolve().parents[1]
DEFAULT_MAP = REPO / "tests" / "data" / "osm" / "helsinki_buildings.geojson"
DEFAULT_ROADS = REPO / "tests" / "data" / "osm" / "helsinki_roads.geojson"
#: the city of the study's drives (:func:`use_map`)
MAP: Path = DEFAULT_MAP
ROADS: Path | None = DEFAULT_ROADS
EVPERC = [sys.executable, "-m", "evperc", "-q"]

DEFAULT_SECONDS = {"ibeo4": 20.0, "hdl64": 10.0, "vlp16": 10.0, "hdl32": 10.0, "scan2d": 20.0}
FINE = ("free", "infrastructure", "unmapped", "stopped", "moving")
COARSE = ("free", "static", "moving")
DECISIONS = ("unknown", "free", "moving", "static", "stopped", "infrastructure", "unmapped")
CELL_SETS = ("observed", "visible")

#: test seeds of docs/evaluation.md
TEST_SEEDS = "11,12,13,14,15,16"
TUNING_SEEDS = "1,2"

#: untuned values of the tuned keys (the shipped defaults before the tuning of
#: docs/evaluation.md was adopted); the start and the parsimony target of ``--tune``
SPEC_VALUES: dict[str, dict[str, float]] = {
    "fusion": {"zeta_increment": 0.1, "zeta_decrement": 0.5, "gamma_occupied": 0.6,
               "gamma_conflict": 0.2, "discount_free": 0.1, "discount_moving": 0.1,
               "discount_stopped": 0.02, "discount_unmapped": 0.01},
    "decision": {"min_betp": 0.5, "max_ignorance": 0.5},
}

#: SPEC values of fusion keys that are not tuned, written with SPEC_VALUES by ``--config spec``
SPEC_FIXED: dict[str, dict[str, float]] = {"fusion": {"discount_infrastructure": 0.0}}

#: tune mode: a stage's winner replaces the previous values only if J improves by more than this
MIN_GAIN = 0.001

#: tune mode: the stages of the grid search, ``(section, key) -> values``
TUNING_STAGES: tuple[dict[tuple[str, str], tuple[float, ...]], ...] = (
    {("fusion", "zeta_increment"): (0.05, 0.1, 0.2, 0.34),
     ("fusion", "zeta_decrement"): (0.25, 0.5, 1.0),
     ("fusion", "gamma_occupied"): (0.5, 0.6, 0.7),
     ("fusion", "gamma_conflict"): (0.1, 0.2, 0.3)},
    {("fusion", "discount_free"): (0.05, 0.1, 0.2),
     ("fusion", "discount_moving"): (0.05, 0.1, 0.2),
     ("fusion", "discount_stopped"): (0.01, 0.02, 0.05),
     ("fusion", "discount_unmapped"): (0.005, 0.01, 0.02)},
    {("decision", "min_betp"): (0.4, 0.5, 0.6),
     ("decision", "max_ignorance"): (0.4, 0.5, 0.6)},
)


# ---------------------------------------------------------------------------------------------
# drives, runs, evaluations (report mode)

@dataclass(frozen=True)
class Drive:
    """One simulated drive of the study."""

    profile: str
    seed: int
    seconds: float

    @property
    def name(self) -> str:
        return f"{self.profile}-s{self.seed}-{self.seconds:g}s"


def drive_dir(work: Path, drive: Drive) -> Path:
    return work / "drives" / drive.name


def simulate_command(work: Path, drive: Drive) -> list[str]:
    roads = ["--roads", str(ROADS)] if ROADS is not None else []
    return [*EVPERC, "simulate", "--map", str(MAP), *roads,
            "--profile", drive.profile, "--seconds", f"{drive.seconds:g}",
            "--seed", str(drive.seed), "--out", str(drive_dir(work, drive)), "--overwrite"]


def run_dir(work: Path, tag: str, drive: Drive, with_map: bool) -> Path:
    return work / "runs" / tag / f"{drive.name}-{'map' if with_map else 'nomap'}"


def run_command(work: Path, tag: str, config: Path | None, drive: Drive,
                with_map: bool) -> list[str]:
    d = drive_dir(work, drive)
    where = ["--map", str(d / "map.geojson")] if with_map else ["--no-map"]
    cfg = ["--config", str(config)] if config is not None else []
    return [*EVPERC, "run", str(d / "drive.mcap"), *where, *cfg,
            "--out", str(run_dir(work, tag, drive, with_map)), "--overwrite"]


def eval_path(work: Path, tag: str, drive: Drive, cells: str) -> Path:
    return work / "eval" / tag / f"{drive.name}-{cells}.json"


def evaluate_command(work: Path, tag: str, drive: Drive, cells: str) -> list[str]:
    return [*EVPERC, "evaluate", str(run_dir(work, tag, drive, True)),
            "--truth", str(drive_dir(work, drive) / "truth"),
            "--compare", str(run_dir(work, tag, drive, False)),
            "--cells", cells, "--json", str(eval_path(work, tag, drive, cells))]


def _complete(manifest: Path) -> bool:
    try:
        return bool(json.loads(manifest.read_text()).get("complete"))
    except (OSError, json.JSONDecodeError):
        return False


def _execute(command: list[str]) -> float:
    """Run one evperc command (output discarded unless it fails); returns its wall time."""
    t0 = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"command failed ({done.returncode}): {shlex.join(command)}\n"
                           f"{done.stderr.strip()}")
    return time.perf_counter() - t0


def _run_all(commands: Sequence[list[str]], workers: int) -> list[float]:
    if not commands:
        return []
    with ProcessPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(_execute, commands))


def config_tag(config: Path | None) -> str:
    """Cache key of a config: its name and a hash of configs/default.toml and the file (a
    user file overrides the defaults, so a run depends on both)."""
    digest = hashlib.sha1((REPO / "configs" / "default.toml").read_bytes())
    if config is not None:
        digest.update(config.read_bytes())
    return f"{config.stem if config is not None else 'default'}-{digest.hexdigest()[:8]}"


def resolve_config(name: str, work: Path) -> Path | None:
    """``default`` → no file; ``spec`` → the untuned values of the tuned keys, written to WORK;
    ``kurdej2013`` → the shipped preset (the paper's method: its values and the margins and
    the motion gate off); else a path."""
    if name == "default":
        return None
    if name == "kurdej2013":
        return REPO / "configs" / "kurdej2013.toml"
    if name == "spec":
        values = {s: {**SPEC_FIXED.get(s, {}), **keys} for s, keys in SPEC_VALUES.items()}
        return write_config(work / "configs" / "spec.toml", values)
    path = Path(name)
    if not path.is_file():
        raise SystemExit(f"--config {name}: no such file (or use 'default' / 'spec' / "
                         "'kurdej2013')")
    return path.resolve()


def write_config(path: Path, values: dict[str, dict[str, float]]) -> Path:
    lines = []
    for section, keys in values.items():
        lines.append(f"[{section}]")
        lines += [f"{k} = {float(v)!r}" for k, v in keys.items()]
        lines.append("")
    path.parent.mkdir(parents=True, exist_ok=True)
    text = "\n".join(lines)
    if not path.is_file() or path.read_text() != text:
        path.write_text(text)
    return path


def prepare(work: Path, drives: Sequence[Drive], configs: Sequence[Path | None],
            workers: int, commands_log: list[str]) -> dict[str, float]:
    """Simulate, run and evaluate what is not cached yet; returns wall seconds per stage."""
    times: dict[str, float] = {}
    sims = [simulate_command(work, d) for d in drives]
    commands_log += [shlex.join(c) for c in sims]
    todo = [c for c, d in zip(sims, drives, strict=True)
            if not _complete(drive_dir(work, d) / "truth" / "manifest.json")]
    t0 = time.perf_counter()
    _run_all(todo, workers)
    times["simulate"] = time.perf_counter() - t0
    runs, evals = [], []
    for config in configs:
        tag = config_tag(config)
        for d in drives:
            for with_map in (True, False):
                cmd = run_command(work, tag, config, d, with_map)
                commands_log.append(shlex.join(cmd))
                if not _complete(run_dir(work, tag, d, with_map) / "manifest.json"):
                    runs.append(cmd)
            for cells in CELL_SETS:
                cmd = evaluate_command(work, tag, d, cells)
                commands_log.append(shlex.join(cmd))
                path = eval_path(work, tag, d, cells)
                path.parent.mkdir(parents=True, exist_ok=True)
                evals.append((cmd, path))
    t0 = time.perf_counter()
    _run_all(runs, workers)
    times["run"] = time.perf_counter() - t0
    # an evaluation is redone when missing or older than one of its runs
    evals = [(c, p) for c, p in evals
             if not p.is_file() or any(
                 p.stat().st_mtime < (Path(c[c.index(flag) + 1]) / "manifest.json").stat().st_mtime
                 for flag in ("evaluate", "--compare"))]
    t0 = time.perf_counter()
    _run_all([c for c, _ in evals], workers)
    times["evaluate"] = time.perf_counter() - t0
    return times


# ---------------------------------------------------------------------------------------------
# aggregation into markdown

def _mean_sd(values: Iterable[float | None]) -> str:
    v = np.array([x for x in values if x is not None], dtype=float)
    if len(v) == 0:
        return "–"
    if len(v) == 1:
        return f"{v[0]:.3f}"
    return f"{v.mean():.3f} ± {v.std(ddof=1):.3f}"


def load_metrics(work: Path, tag: str, drives: Sequence[Drive], cells: str
                 ) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """(with map, without map) metrics of every drive."""
    with_map, without = [], []
    for d in drives:
        doc = json.loads(eval_path(work, tag, d, cells).read_text())
        with_map.append(doc)
        without.append(doc["compare"])
    return with_map, without


def class_table(runs: tuple[list[dict[str, Any]], list[dict[str, Any]]], table: str,
                names: Sequence[str]) -> list[str]:
    head = ("| class | support (cells) | map P | map R | map F1 | no-map P | no-map R "
            "| no-map F1 |")
    lines = [head, "|" + "---|" * 8]
    for name in names:
        support = sum(m[table][name]["support"] for m in runs[0])
        row = f"| {name} | {support:,} |"
        for ms in runs:
            for score in ("precision", "recall", "f1"):
                row += f" {_mean_sd(m[table][name][score] for m in ms)} |"
        lines.append(row)
    return lines


def objective(metrics: dict[str, Any]) -> float:
    """J = mean(F1 moving, F1 stopped, coarse F1 static, coarse precision free); None → 0."""
    parts = (metrics["per_class"]["moving"]["f1"], metrics["per_class"]["stopped"]["f1"],
             metrics["coarse"]["static"]["f1"], metrics["coarse"]["free"]["precision"])
    return float(np.mean([p if p is not None else 0.0 for p in parts]))


def latency_table(work: Path, tag: str, drives: Sequence[Drive]) -> list[str]:
    lines = ["| run | episodes | detected | missed | latency mean (frames) | median | "
             "per-seed mean |", "|" + "---|" * 7]
    runs = load_metrics(work, tag, drives, "observed")
    for label, ms in zip(("map", "no map"), runs, strict=True):
        eps = [e for m in ms for e in m["latency_frames"]["per_episode"]]
        lat = np.array([e["latency_frames"] for e in eps if e["latency_frames"] is not None])
        mean = f"{lat.mean():.2f}" if len(lat) else "–"
        median = f"{np.median(lat):.1f}" if len(lat) else "–"
        lines.append(f"| {label} | {len(eps)} | {len(lat)} | {len(eps) - len(lat)} | {mean} | "
                     f"{median} | {_mean_sd(m['latency_frames']['mean'] for m in ms)} |")
    return lines


def confusion_table(ms: list[dict[str, Any]], truth_rows: Sequence[str] = FINE) -> list[str]:
    """Pooled over seeds, % of each truth row."""
    decisions = ms[0]["confusion"]["decision"]
    counts = sum(np.array(m["confusion"]["counts"], dtype=np.int64) for m in ms)
    truth = ms[0]["confusion"]["truth"]
    lines = ["| truth \\ decision | " + " | ".join(decisions) + " | cells |",
             "|" + "---|" * (len(decisions) + 2)]
    for name in truth_rows:
        row = counts[truth.index(name)]
        total = max(int(row.sum()), 1)
        lines.append(f"| {name} | " + " | ".join(f"{100 * c / total:.1f}" for c in row)
                     + f" | {int(row.sum()):,} |")
    return lines


def stopped_moving_table(runs: tuple[list[dict[str, Any]], list[dict[str, Any]]]) -> list[str]:
    """Truth stopped / moving cells by decision, % of the truth class, pooled over seeds."""
    shown = ("moving", "stopped", "static", "unmapped", "free", "unknown")
    lines = ["| truth | run | " + " | ".join(shown) + " | cells |", "|" + "---|" * 9]
    for truth in ("stopped", "moving"):
        for label, ms in zip(("map", "no map"), runs, strict=True):
            counts = {d: sum(m["stopped_vs_moving"][truth].get(d, 0) for m in ms)
                      for d in DECISIONS}
            total = max(sum(counts.values()), 1)
            lines.append(f"| {truth} | {label} | "
                         + " | ".join(f"{100 * counts[d] / total:.1f}" for d in shown)
                         + f" | {sum(counts.values()):,} |")
    return lines


def report(work: Path, tag: str, drives: Sequence[Drive], profiles: Sequence[str]) -> str:
    out: list[str] = []
    for profile in profiles:
        ds = [d for d in drives if d.profile == profile]
        seeds = ", ".join(str(d.seed) for d in ds)
        out.append(f"## {profile}: seeds {seeds}, {ds[0].seconds:g} s each (config {tag})\n")
        for cells in CELL_SETS:
            runs = load_metrics(work, tag, ds, cells)
            out.append(f"### Fine classes, {cells} cells (mean ± sd over seeds)\n")
            out += class_table(runs, "per_class", FINE) + [""]
            out.append(f"### Coarse classes, {cells} cells\n")
            out += class_table(runs, "coarse", COARSE) + [""]
            acc = [f"{label}: accuracy {_mean_sd(m['accuracy'] for m in ms)}, coarse accuracy "
                   f"{_mean_sd(m['coarse_accuracy'] for m in ms)}, J "
                   f"{_mean_sd(objective(m) for m in ms)}"
                   for label, ms in zip(("map", "no map"), runs, strict=True)]
            out += ["; ".join(acc), ""]
            out.append(f"### Stopped vs moving, {cells} cells (% of the truth class)\n")
            out += stopped_moving_table(runs) + [""]
            for label, ms in zip(("map", "no map"), runs, strict=True):
                out.append(f"### Confusion, {cells} cells, {label} (% of truth row, pooled)\n")
                out += confusion_table(ms) + [""]
        out.append("### Moving-object detection latency (episodes pooled over seeds)\n")
        out += latency_table(work, tag, ds) + [""]
    return "\n".join(out)


def comparison(work: Path, tags: Sequence[str], drives: Sequence[Drive],
               profiles: Sequence[str]) -> str:
    """Key scores of several configs side by side (with the map)."""
    lines = ["| profile | cells | config | J | F1 moving | F1 stopped | F1 infra | "
             "coarse F1 static | coarse P free | coarse R free |", "|" + "---|" * 10]
    for profile, cells, tag in itertools.product(profiles, CELL_SETS, tags):
        ms = load_metrics(work, tag, [d for d in drives if d.profile == profile], cells)[0]
        lines.append(
            f"| {profile} | {cells} | {tag} | {_mean_sd(objective(m) for m in ms)} | "
            + " | ".join(_mean_sd(m[t][c][s] for m in ms) for t, c, s in (
                ("per_class", "moving", "f1"), ("per_class", "stopped", "f1"),
                ("per_class", "infrastructure", "f1"), ("coarse", "static", "f1"),
                ("coarse", "free", "precision"), ("coarse", "free", "recall"))) + " |")
    return "\n".join(lines)


def paired(work: Path, tags: Sequence[str], drives: Sequence[Drive],
           profiles: Sequence[str]) -> str:
    """The first config minus each other one, per seed (with the map): mean ± sd of the
    differences and on how many seeds the first config is ahead."""
    scores = (("J", None), ("F1 moving", ("per_class", "moving", "f1")),
              ("F1 stopped", ("per_class", "stopped", "f1")),
              ("coarse F1 static", ("coarse", "static", "f1")),
              ("coarse R free", ("coarse", "free", "recall")))
    lines = ["| profile | cells | first − | " + " | ".join(
        f"Δ {name} (first ahead on)" for name, _ in scores) + " |", "|" + "---|" * 8]

    def value(m: dict[str, Any], where: tuple[str, str, str] | None) -> float:
        if where is None:
            return objective(m)
        v = m[where[0]][where[1]][where[2]]
        return 0.0 if v is None else float(v)

    for profile, cells, tag in itertools.product(profiles, CELL_SETS, tags[1:]):
        ds = [d for d in drives if d.profile == profile]
        first = load_metrics(work, tags[0], ds, cells)[0]
        other = load_metrics(work, tag, ds, cells)[0]
        row = f"| {profile} | {cells} | {tag} |"
        for _, where in scores:
            diff = [value(a, where) - value(b, where) for a, b in zip(first, other, strict=True)]
            row += f" {_mean_sd(diff)} ({sum(x > 0 for x in diff)} of {len(diff)}) |"
        lines.append(row)
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# tune mode: replay the fusion in process on cached sensor grids

_DRIVES: list[tuple[str, Any, Any]] = []  # per worker: (name, prepared frames, truth)


def _prepare_drive(directory: Path) -> tuple[Any, Any]:
    """Sensor grids, context labels and windows of every scan, and the truth in memory."""
    from evperc.config import load_config
    from evperc.runner import Pipeline, RunRequest
    from evperc.sim.truth import load_truth

    config = load_config(None)
    pipe = Pipeline(RunRequest(log_path=directory / "drive.mcap", out_dir=directory / "unused",
                               config=config, map_path=directory / "map.geojson"))
    frames = []
    for _, inputs in pipe.inputs(-1):
        frames.append((inputs.stamp_ns, inputs.window, inputs.free, inputs.occupied,
                       inputs.labels, inputs.near_building))
    prepared = types.SimpleNamespace(frames=frames, betas=pipe.betas,
                                     resolution_m=pipe.resolution, base=config)
    truth = load_truth(directory / "truth")
    in_memory = types.SimpleNamespace(frames=list(truth.frames), class_codes=truth.class_codes,
                                      resolution_m=truth.resolution_m, agents=truth.agents)
    return prepared, in_memory


def _init_worker(directories: Sequence[str]) -> None:
    logging.getLogger("evperc").setLevel(logging.WARNING)
    for d in directories:
        _DRIVES.append((Path(d).name, *_prepare_drive(Path(d))))


def replay(prepared: Any, overrides: dict[str, dict[str, float]], with_map: bool = True) -> Any:
    """The decisions `evperc run` would write with ``overrides``, as a run-like object."""
    from evperc.fusion.fused import fused_step
    from evperc.fusion.gate import gate_step
    from evperc.fusion.twin import DECISION_CODES, FusionParams
    from evperc.runner import FusionState

    config = {s: dict(prepared.base[s]) for s in ("fusion", "decision")}
    for section, keys in overrides.items():
        config[section].update(keys)
    params = FusionParams.from_config(config)
    prev = None
    state = FusionState()
    out = []
    for stamp, w, free, occupied, labels, near in prepared.frames:
        shift = state.move_to(w)  # the runner's circular buffer
        dt = 0.0 if prev is None else (stamp - prev) * 1e-9
        prev = stamp
        gate = (gate_step(state.gate, free, occupied, dt, params, offset=state.offset,
                          shift=shift, closed=near if with_map else None)
                if params.gated else None)
        res = fused_step(state.pg, state.zeta, free, occupied, labels if with_map else None,
                         prepared.betas, dt, params, flags=state.flags, offset=state.offset,
                         shift=shift, gate=gate)
        out.append(types.SimpleNamespace(stamp_ns=stamp, origin=(w.row0, w.col0),
                                         decision=res.decision.copy()))
    return types.SimpleNamespace(frames=out, decision_codes=DECISION_CODES,
                                 resolution_m=prepared.resolution_m)


def _score_candidate(overrides: dict[str, dict[str, float]]) -> dict[str, Any]:
    from evperc.eval.metrics import evaluate

    scores: dict[str, Any] = {}
    for name, prepared, truth in _DRIVES:
        run = replay(prepared, overrides)
        for cells in CELL_SETS:
            m = evaluate(run, truth, cells=cells)
            scores[f"{name}/{cells}"] = {
                "J": objective(m), "f1_moving": m["per_class"]["moving"]["f1"],
                "f1_stopped": m["per_class"]["stopped"]["f1"],
                "f1_static": m["coarse"]["static"]["f1"],
                "p_free": m["coarse"]["free"]["precision"],
                "r_free": m["coarse"]["free"]["recall"],
                "latency": m["latency_frames"]["mean"], "missed": m["latency_frames"]["missed"]}
    return {"overrides": overrides, "J": float(np.mean([s["J"] for s in scores.values()])),
            "scores": scores}


def _candidates(stage: dict[tuple[str, str], tuple[float, ...]],
                base: dict[str, dict[str, float]]) -> list[dict[str, dict[str, float]]]:
    keys = list(stage)
    out = []
    for values in itertools.product(*(stage[k] for k in keys)):
        c = {s: dict(v) for s, v in base.items()}
        for (section, key), value in zip(keys, values, strict=True):
            c.setdefault(section, {})[key] = value
        out.append(c)
    return out


def _flat(overrides: dict[str, dict[str, float]]) -> str:
    return ", ".join(f"{k}={v:g}" for keys in overrides.values() for k, v in keys.items())


def tune(work: Path, drives: Sequence[Drive], workers: int) -> str:
    """Grid search in stages; returns the markdown summary and writes WORK/tune/best.toml."""
    directories = [str(drive_dir(work, d)) for d in drives]
    best: dict[str, dict[str, float]] = {s: dict(v) for s, v in SPEC_VALUES.items()}
    lines = [f"Tuning drives: {', '.join(d.name for d in drives)}; objective J (mean over "
             "drives and cell sets).", ""]
    results: list[dict[str, Any]] = []
    with ProcessPoolExecutor(max_workers=workers, initializer=_init_worker,
                             initargs=(directories,)) as pool:
        baseline = pool.submit(_score_candidate, best).result()
        lines += [f"SPEC values: J = {baseline['J']:.4f}", ""]
        for number, stage in enumerate(TUNING_STAGES, start=1):
            candidates = _candidates(stage, best)
            t0 = time.perf_counter()
            scored = list(pool.map(_score_candidate, candidates, chunksize=2))
            results += scored
            scored.sort(key=lambda r: -r["J"])
            previous = next(r for r in scored if r["overrides"] == best)
            if scored[0]["J"] > previous["J"] + MIN_GAIN:  # ties keep the previous values
                best = scored[0]["overrides"]
            lines += [f"### Stage {number}: {len(candidates)} candidates "
                      f"({time.perf_counter() - t0:.0f} s); top 5 and bottom 1", "",
                      "| rank | J | F1 M | F1 S | F1 static | P free | R free | candidate |",
                      "|" + "---|" * 8]
            for rank, r in list(enumerate(scored[:5], 1)) + [(len(scored), scored[-1])]:
                s = r["scores"].values()

                def avg(key: str, s: Iterable[dict[str, Any]] = s) -> str:
                    v = [x[key] for x in s if x[key] is not None]
                    return f"{np.mean(v):.3f}" if v else "–"

                lines.append(f"| {rank} | {r['J']:.4f} | {avg('f1_moving')} | "
                             f"{avg('f1_stopped')} | {avg('f1_static')} | {avg('p_free')} | "
                             f"{avg('r_free')} | {_flat(r['overrides'])} |")
            lines.append("")
        # parsimony: a changed key goes back to its SPEC value unless that costs > MIN_GAIN
        best_j = next(r["J"] for r in results if r["overrides"] == best)
        for section, key in [(s, k) for s, keys in best.items() for k in keys]:
            if best[section][key] == SPEC_VALUES[section][key]:
                continue
            trial = {s: dict(v) for s, v in best.items()}
            trial[section][key] = SPEC_VALUES[section][key]
            scored_trial = pool.submit(_score_candidate, trial).result()
            results.append(scored_trial)
            kept = scored_trial["J"] < best_j - MIN_GAIN
            lines.append(f"- {key} back to {SPEC_VALUES[section][key]:g}: J "
                         f"{scored_trial['J']:.4f} vs {best_j:.4f} -> "
                         f"{'keep ' + format(best[section][key], 'g') if kept else 'reverted'}")
            if not kept:
                best, best_j = trial, scored_trial["J"]
        lines.append("")
    gain = best_j - baseline["J"]
    path = write_config(work / "tune" / "best.toml", best)
    (work / "tune" / "results.json").write_text(json.dumps(
        {"baseline": baseline, "results": results}, indent=1))
    lines += [f"Best: {_flat(best)}; J = {baseline['J'] + gain:.4f} "
              f"(SPEC values {baseline['J']:.4f}, gain {gain:+.4f}) -> {path}", ""]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------

def use_map(work: Path, map_path: Path | None, roads: Path | None) -> None:
    """Simulate the drives on ``map_path`` (and ``roads``) instead of the Helsinki extract.

    The drives are cached by profile, seed and length only, so the work directory records its
    map (``WORK/map.txt``) and refuses another one: a study never mixes two cities' drives."""
    global MAP, ROADS
    if map_path is not None:
        MAP, ROADS = map_path.resolve(), roads.resolve() if roads is not None else None
    elif roads is not None:
        raise SystemExit("--roads needs --map (the default map has its own roads)")
    else:
        MAP, ROADS = DEFAULT_MAP, DEFAULT_ROADS
    for path in (MAP, ROADS):
        if path is not None and not path.is_file():
            raise SystemExit(f"{path}: no such map file")
    stamp = work / "map.txt"
    said = f"{MAP}\n{ROADS or ''}\n"
    if stamp.is_file() and stamp.read_text() != said:
        raise SystemExit(f"{work}: its drives were simulated on {stamp.read_text().split()[0]}; "
                         "use another --work for another map")
    work.mkdir(parents=True, exist_ok=True)
    stamp.write_text(said)


def parse_seconds(text: str | None, profiles: Sequence[str]) -> dict[str, float]:
    """``20`` (every profile) or ``ibeo4=20,hdl64=10``."""
    seconds = {p: DEFAULT_SECONDS[p] for p in profiles}
    if text:
        if "=" not in text:
            return {p: float(text) for p in profiles}
        for item in text.split(","):
            key, value = item.split("=")
            seconds[key.strip()] = float(value)
    return seconds


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", default=TEST_SEEDS,
                        help=f"comma-separated test seeds of the report [{TEST_SEEDS}]")
    parser.add_argument("--tune-seeds", default=TUNING_SEEDS,
                        help=f"comma-separated tuning seeds of --tune / --all [{TUNING_SEEDS}]")
    parser.add_argument("--profiles", default="ibeo4,hdl64",
                        help="comma-separated lidar profiles [ibeo4,hdl64]")
    parser.add_argument("--seconds", help="drive length: N, or ibeo4=20,hdl64=10 [default]")
    parser.add_argument("--work", type=Path, default=Path("evaluation-work"),
                        help="work directory (drives, runs, evaluations are cached there)")
    parser.add_argument("--config", action="append",
                        help="report mode: 'default', 'spec' (the untuned values of the tuned "
                             "keys), 'kurdej2013' (the paper's method, configs/kurdej2013.toml) "
                             "or a TOML "
                             "file; repeat to compare configs (full tables for the first)")
    parser.add_argument("--tune", action="store_true", help="grid search on the tuning seeds")
    parser.add_argument("--all", action="store_true",
                        help="everything of docs/evaluation.md: --tune, then the report on the "
                             "test seeds with the defaults, the SPEC values and the tuned config "
                             "side by side")
    parser.add_argument("--map", type=Path,
                        help="the city the drives are simulated in: `evperc simulate --map` "
                             "[tests/data/osm/helsinki_buildings.geojson]; a work directory "
                             "holds the drives of one map")
    parser.add_argument("--roads", type=Path,
                        help="its highway lines, if not in --map [with the default map: "
                             "tests/data/osm/helsinki_roads.geojson]")
    parser.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1))
    parser.add_argument("--out", type=Path, help="also write the markdown to this file")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    profiles = [p.strip() for p in args.profiles.split(",") if p.strip()]
    seconds = parse_seconds(args.seconds, profiles)

    def drives_of(seeds: str) -> list[Drive]:
        return [Drive(p, int(s), seconds[p]) for p in profiles for s in seeds.split(",")]

    work = args.work.resolve()
    use_map(work, args.map, args.roads)
    t0 = time.perf_counter()
    commands: list[str] = []
    text = ""
    if args.tune or args.all:
        tune_drives = drives_of(args.tune_seeds)
        prepare(work, tune_drives, [], args.workers, commands)
        text += "# Tuning\n\n" + tune(work, tune_drives, args.workers) + "\n"
    if not args.tune:
        drives = drives_of(args.seeds)
        names = (args.config or (["default", "spec"] if args.all else ["default"])) + (
            [str(work / "tune" / "best.toml")] if args.all else [])
        configs = [resolve_config(c, work) for c in names]
        times = prepare(work, drives, configs, args.workers, commands)
        tags = [config_tag(c) for c in configs]
        text += "# Evaluation\n\n" + report(work, tags[0], drives, profiles)
        if len(tags) > 1:
            text += "\n## Configs compared (with the map)\n\n" + comparison(
                work, tags, drives, profiles) + "\n"
            text += ("\n## Paired per seed: the first config minus each other (with the map)"
                     "\n\n" + paired(work, tags, drives, profiles) + "\n")
        text += "\nStage wall times (s): " + ", ".join(f"{k} {v:.0f}" for k, v in times.items())
    script = shlex.join([sys.executable, str(Path(__file__).resolve()),
                         *(argv if argv is not None else sys.argv[1:])])
    text += (f"\n\nTotal wall time {time.perf_counter() - t0:.0f} s ({args.workers} workers)."
             f"\n\nReproduce: `{script}`\n\nCommands (cached results are not redone):\n\n```\n"
             + "\n".join(commands) + "\n```\n")
    print(text)
    if args.out is not None:
        args.out.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
