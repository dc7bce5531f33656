#!/usr/bin/env python3
"""Replay the object stage on recorded fusion outputs, to compare ``[objects]`` settings on
simulated drives in seconds (issue 21).

The object stage (clusters, tracks, fill; docs/method.md §8) reads only the fusion's outputs
of the frame — the decision before the fill, betP(M), ∅_FO, the cells holding a return — and
writes nothing back into the fusion state, so those inputs, recorded once per drive by a run
with a hook (:func:`record`), replay the stage exactly under any ``[objects]`` values
(:func:`replay`). The replayed frames are scored by :func:`evperc.eval.metrics.evaluate` as a
run would be. The footprint completion (:mod:`evperc.objects.footprint`) is replayed too (the scan's
cells seen free or holding a return are recorded). The unmapped cue, which never touches a
moving cell, is not replayed: the
cells it relabelled in the recorded run keep that label unless the replay decides them
moving (moving scores, latency and object scores are exact; stopped / unmapped approximate).

    PYTHONPATH=$PWD .venv/bin/python scripts/object_replay.py --work /tmp/objstudy \\
        --seeds 1,2 --set "" --set "confirm_frames=2" --set "min_cluster_cells=2"
"""

from __future__ import annotations

import argparse
import copy
import logging
import subprocess
import sys
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import evaluation_study as study  # noqa: E402

from evperc import runner as runner_mod  # noqa: E402
from evperc.eval.metrics import evaluate  # noqa: E402
from evperc.fusion.twin import DECISION_CODES  # noqa: E402
from evperc.geo.prior import CONTEXT_BUILDING  # noqa: E402
from evperc.geo.window import Window  # noqa: E402
from evperc.objects import stage as stage_mod  # noqa: E402
from evperc.objects.backfill import Backfill, HeldFrame, candidates  # noqa: E402
from evperc.objects.boxes import BoxParams, complete_boxes  # noqa: E402
from evperc.objects.footprint import FootprintParams, FootprintState, complete_footprints  # noqa: E402,E501
from evperc.objects.stage import ObjectStage, fill_moving, unfill_small  # noqa: E402
from evperc.objects.support import SmallGroupSupport, SupportParams  # noqa: E402
from evperc.objects.tracking import TrackerState  # noqa: E402
from evperc.output.objects import moving_object_cells, object_labels  # noqa: E402

log = logging.getLogger("object_replay")
OSM = REPO / "tests" / "data" / "osm"
#: each profile's drive length (s), as scripts/evaluation_study.py simulates it
SECONDS = {p: int(s) for p, s in study.DEFAULT_SECONDS.items()}
INPUTS = "object_inputs.npz"
_UNMAPPED = DECISION_CODES["unmapped"]
_MOVING = DECISION_CODES["moving"]


def simulated_drive(work: Path, profile: str, seed: str) -> Path:
    """The drive of scripts/evaluation_study.py in the same work directory if it is there
    (WORK/drives/PROFILE-sSEED-LENs, simulated in whatever city the study's ``--map``
    named: a replay of a study's drives, e.g. Prague's); else WORK/drives/PROFILE-sSEED,
    simulated in the Helsinki extract if absent."""
    study_drive = study.drive_dir(work, study.Drive(profile, int(seed), SECONDS[profile]))
    if (study_drive / "truth" / "manifest.json").exists():
        return study_drive
    drive = work / "drives" / f"{profile}-s{seed}"
    if not (drive / "truth" / "manifest.json").exists():
        subprocess.run([sys.executable, "-m", "evperc", "-q", "simulate", "--map",
                        str(OSM / "helsinki_buildings.geojson"), "--roads",
                        str(OSM / "helsinki_roads.geojson"), "--profile", profile,
                        "--seconds", str(SECONDS[profile]), "--seed", seed, "--out",
                        str(drive), "--overwrite"], check=True, cwd=REPO)
    return drive


def recorded(work: Path, profile: str, seed: str, config: Path | None = None,
             with_map: bool = True) -> tuple[Path, Path]:
    """(drive, run dir) of a tuning drive in ``work``: simulated (:func:`simulated_drive`)
    and recorded (:func:`record`; ``with_map`` False: a ``--no-map`` run, kept apart) unless
    already there."""
    drive = simulated_drive(work, profile, seed)
    out = work / ("replay_runs" if with_map else "replay_runs_nomap") / f"{profile}-s{seed}"
    if not (out / INPUTS).exists():
        record(drive, out, config, with_map)
    return drive, out


def record(drive: Path, out: Path, config: Path | None = None, with_map: bool = True
           ) -> Path:
    """``evperc run`` of ``drive`` (with its map, or ``--no-map``) into ``out``, in this
    process, saving the object stage's inputs of every frame to ``out/object_inputs.npz``."""
    from evperc.cli import cli
    frames: list[tuple[Any, ...]] = []
    original = stage_mod.ObjectStage.step
    original_pipeline = runner_mod.Pipeline.sensor_grid
    speaks: dict[int, np.ndarray] = {}  # per stamp, the cells seen free or holding a return

    def pipeline_hooked(self: Any, inputs: Any) -> Any:
        done = original_pipeline(self, inputs)  # in the decode thread or the step's
        if done.free is not None:
            speaks[int(done.stamp_ns)] = (done.free > 0) | (done.occupied > 0)
        return done

    def hooked(self: Any, state: Any, decision: np.ndarray, betp_moving: np.ndarray,
               conflict_fo: np.ndarray, window: Window, stamp_ns: int,
               occupied_now: np.ndarray | None = None, heights: np.ndarray | None = None,
               near_building: np.ndarray | None = None,
               return_sums: np.ndarray | None = None,
               sensor_xy: tuple[float, float] | None = None) -> Any:
        if decision.shape[0] >= 20:  # not the runner's warm-up on a tiny window
            frames.append((int(stamp_ns), window.row0, window.col0, decision.copy(),
                           betp_moving.copy(), conflict_fo.copy(),
                           np.packbits(np.asarray(occupied_now, bool).reshape(-1)),
                           np.packbits(speaks.pop(int(stamp_ns)).reshape(-1)),
                           np.zeros(decision.shape, np.float16) if heights is None
                           else heights.astype(np.float16),
                           np.zeros((*decision.shape, 3), np.float32) if return_sums is None
                           else return_sums.copy()))
        return original(self, state, decision, betp_moving, conflict_fo, window, stamp_ns,
                        occupied_now, heights, near_building, return_sums, sensor_xy)

    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    original_needs = stage_mod.ObjectStage.needs_return_sums
    stage_mod.ObjectStage.step = hooked  # type: ignore[method-assign]
    runner_mod.Pipeline.sensor_grid = pipeline_hooked  # type: ignore[method-assign]
    # the returns' sums recorded whatever the run's objects.centroid (the replay chooses);
    # the object stage writes nothing back into the fusion, so the recorded inputs are the
    # same either way
    stage_mod.ObjectStage.needs_return_sums = property(  # type: ignore[method-assign]
        lambda self: True)
    try:
        args = ["-q", "run", str(drive / "drive.mcap"),
                *(["--map", str(drive / "map.geojson")] if with_map else ["--no-map"]),
                "--out", str(out), "--overwrite"]
        if config is not None:
            args += ["--config", str(config)]
        cli(args, standalone_mode=False)
    finally:
        stage_mod.ObjectStage.step = original  # type: ignore[method-assign]
        runner_mod.Pipeline.sensor_grid = original_pipeline  # type: ignore[method-assign]
        stage_mod.ObjectStage.needs_return_sums = original_needs  # type: ignore[method-assign]
        # the CLI set up its own logging (its filter drops this script's INFO lines)
        root.handlers[:], root.level = handlers, level
    path = out / INPUTS
    np.savez_compressed(
        path, stamp_ns=np.array([f[0] for f in frames], np.int64),
        origin=np.array([(f[1], f[2]) for f in frames], np.int64),
        decision=np.stack([f[3] for f in frames]), betp_moving=np.stack([f[4] for f in frames]),
        conflict_fo=np.stack([f[5] for f in frames]),
        occupied=np.stack([f[6] for f in frames]), speaks=np.stack([f[7] for f in frames]),
        heights=np.stack([f[8] for f in frames]), return_sums=np.stack([f[9] for f in frames]))
    return path


@dataclass
class ReplayFrame:
    """The parts of :class:`evperc.output.reader.Frame` that evaluate reads."""

    index: int
    stamp_ns: int
    pose: Any
    origin: tuple[int, int]
    decision: np.ndarray
    objects: np.ndarray
    object_cells: np.ndarray
    #: the backfill's step behind each cell it decided moving (:attr:`HeldFrame.added_by`;
    #: replay(trace_backfill=True)), else None
    added_by: dict[int, str] | None = None

    def object_labels(self) -> np.ndarray:
        return object_labels(self.objects, self.object_cells, self.decision.shape)


class ReplayRun:
    """A run's frames with the replayed decisions and objects (for evaluate)."""

    def __init__(self, run: Any, frames: list[ReplayFrame]) -> None:
        self.decision_codes = run.decision_codes
        self.resolution_m = run.resolution_m
        self.crs = getattr(run, "crs", None)
        self.frames = frames


StepFn = Callable[[ObjectStage, TrackerState, np.ndarray, np.ndarray, np.ndarray, Window, int,
                   np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None,
                   tuple[float, float] | None],
                  tuple[np.ndarray, np.ndarray]]


def replay(out: Path, config: dict[str, Any], step: StepFn | None = None,
           trace_backfill: bool = False) -> ReplayRun:
    """The recorded run ``out`` with its object stage replayed under ``config``. ``step``:
    replaces :meth:`ObjectStage.step` (same signature), e.g. to trace it;
    ``trace_backfill``: each frame's ``added_by`` says which of the backfill's steps decided
    its cells moving (:attr:`evperc.objects.backfill.HeldFrame.added_by`)."""
    from evperc import load
    run = load(out)
    data = np.load(out / INPUTS)
    stamps, origins = data["stamp_ns"], data["origin"]
    if "speaks" not in data.files or "heights" not in data.files:
        raise SystemExit(f"{out / INPUTS}: recorded before the scan's cells or heights; "
                         "delete it")
    if stage_mod.ObjectStage(config, (1, 1)).needs_return_sums and \
            "return_sums" not in data.files:
        raise SystemExit(f"{out / INPUTS}: recorded before the returns' sums "
                         "(objects.centroid = \"returns\"); delete it")
    sums = data["return_sums"] if "return_sums" in data.files else None
    decisions, betps, conflicts, occs = (data["decision"], data["betp_moving"],
                                         data["conflict_fo"], data["occupied"])
    shape = decisions.shape[1:]
    res = run.resolution_m
    stage = ObjectStage(config, shape)
    near_building = near_building_layer(run, config)
    state = TrackerState()
    fp_params, fp_state = FootprintParams.from_config(config), FootprintState()
    box_params = BoxParams.from_config(config)
    stored = {f.stamp_ns: f for f in run.frames}
    frames = []
    fill = stage_mod.fills_decision(config)
    backfill = Backfill.from_config(config)
    backfill.trace = trace_backfill
    small_groups: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    support, support_params = SmallGroupSupport(), SupportParams.from_config(config)
    for k in range(len(stamps)):
        window = Window(res, shape[0], shape[1], int(origins[k, 0]), int(origins[k, 1]))
        decision = decisions[k].copy()
        occ = np.unpackbits(occs[k])[:shape[0] * shape[1]].reshape(shape).astype(bool)
        # heights as float16 (the bound is 0.4 m: 1e-3 m steps there); None when the
        # recorded run did not compute them (all zero: no return is that low)
        top = data["heights"][k].astype(np.float32)
        f = stored.get(int(stamps[k]))
        args = (state, decision, betps[k], conflicts[k], window, int(stamps[k]), occ,
                top if top.any() else None, near_building(window),
                None if sums is None else sums[k],
                None if f is None else (float(f.pose[0]), float(f.pose[1])))
        objects, cells = step(stage, *args) if step is not None else stage.step(*args)
        speaks = np.unpackbits(data["speaks"][k])[:occ.size].reshape(shape).astype(bool)
        if fp_params.frames > 0:
            objects, cells = complete_footprints(fp_state, objects, cells, window,
                                                 int(stamps[k]), speaks, fp_params)
        if box_params.enabled:
            objects, cells = complete_boxes(objects, cells, window, speaks, decision,
                                            box_params, returns=top)
        moving = moving_object_cells(objects, cells)
        if fill:
            fill_moving(decision, moving)
        if stage.moving_min_cells > 0:
            unfill_small(decision, stage.small_moving, moving)
            # the small groups left moving: moving_needs_object leaves them to that rule
            small_groups[k] = stage_mod.small_moving_cells(
                *stage.clusterer.groups(), decision, stage.moving_min_cells, with_groups=True)
            if support_params.enabled:  # the runner's push (evperc/objects/support.py)
                small = small_groups[k][0]
                support.push(k, window.row0, window.col0, window.cols,
                             small if moving is None else np.concatenate([small, moving]))
        if f is not None:  # the unmapped cue's cells, where the replay did not decide moving
            relabel = (np.asarray(f.decision) == _UNMAPPED) & (decision != _MOVING)
            decision[relabel] = _UNMAPPED
        frame = ReplayFrame(k, int(stamps[k]), None if f is None else f.pose,
                            (int(origins[k, 0]), int(origins[k, 1])), decision, objects, cells)
        if backfill.frames > 0:  # the frames L behind, with the moving tracks filled in
            frames.extend(_released(backfill.push(HeldFrame(
                window, decision, betps[k], objects, cells, candidates(state, objects),
                payload=frame, stamp_ns=int(stamps[k]), occupied=occ, speaks=speaks,
                returns=top))))
        else:
            frames.append(frame)
    frames.extend(_released(backfill.flush()))
    if config["objects"].get("moving_needs_object", False):  # on the final object lists
        for frame in frames:
            small, group_of = small_groups.get(frame.index, (None, None))
            if support_params.enabled and small is not None:
                small = support.judge(support_params, frame.index, *frame.origin,
                                      frame.decision.shape[1], small, group_of)
            stage_mod.unfill_unconfirmed(
                frame.decision, moving_object_cells(frame.objects, frame.object_cells), small)
    return ReplayRun(run, frames)


def near_building_layer(run: Any, config: dict[str, Any]
                        ) -> Callable[[Window], np.ndarray | None]:
    """The runner's ``near_building`` layer of a window (the buildings widened by
    ``map.building_margin_m``), made from the recorded run's log and map as
    :class:`evperc.runner.Pipeline` makes it; None for every window when the run had no map
    or the margin is 0."""
    request = run.manifest["request"]
    if request.get("map_path") is None:
        return lambda window: None
    pipeline = runner_mod.Pipeline(runner_mod.RunRequest(
        log_path=Path(request["log_path"]), out_dir=Path(run.out_dir), config=config,
        map_path=Path(request["map_path"]),
        roads_path=None if request.get("roads_path") is None else Path(request["roads_path"])))
    rasteriser = pipeline.near_rasteriser
    if rasteriser is None:
        return lambda window: None
    return lambda window: rasteriser.labels(window) == CONTEXT_BUILDING


def _released(held: list[HeldFrame]) -> list[ReplayFrame]:
    """The replayed frames of ``held`` with the backfill's objects (the decision is the
    frame's own array, filled in place)."""
    for h in held:
        h.payload.objects, h.payload.object_cells = h.objects, h.object_cells
        h.payload.added_by = h.added_by
    return [h.payload for h in held]


def parse_set(text: str) -> dict[str, Any]:
    """``"a=1,b=x"`` → overrides of ``[objects]`` (TOML values)."""
    if not text.strip():
        return {}
    return tomllib.loads("\n".join(p.strip() for p in text.split(";") if p.strip()))


def with_objects(config: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    c = copy.deepcopy(config)
    c["objects"].update(overrides)
    return c


def run_config(out: Path, config_path: Path | None = None) -> dict[str, Any]:
    """The replay's base config for the run recorded in ``out`` under ``config_path``: the
    defaults under that file, with the preset the recording took for its lidar (since the
    eighth session of 2026-12-07 a 64- or 16-layer drive's run takes one — its fusion ran
    with it, so its object stage is replayed with it; a recording made before names none)."""
    from evperc.config import load_config
    from evperc.output.manifest import read_manifest

    request = read_manifest(out).get("request") or {}
    return load_config(config_path, preset=request.get("preset"))


def replay_config(out: Path, config_path: Path | None, overrides: dict[str, Any]
                  ) -> dict[str, Any]:
    """:func:`run_config` (the recording's config, with the preset its lidar took) with the
    ``[objects]`` ``overrides`` (:func:`with_objects`): what a replay of ``out`` runs."""
    return with_objects(run_config(out, config_path), overrides)


def scores(run: Any, truth: Any) -> dict[str, Any]:
    """The issue-21 scores of one run: moving P/R strict and within one cell, missed
    episodes, object P/R (visible cells), moving F1 (observed cells)."""
    v = evaluate(run, truth, cells="visible")
    o = evaluate(run, truth, cells="observed")
    mv, tol, lat, obj = (v["per_class"]["moving"], v["moving_within_one_cell"],
                         v["latency_frames"], v["objects"] or {})
    return {"P": mv["precision"], "R": mv["recall"], "tP": tol["precision"], "tR": tol["recall"],
            "tc": (tol["correct"], tol["decided"], tol["found"], tol["support"]),
            "sc": _strict_counts(v),
            "episodes": lat["episodes"], "missed": lat["missed"],
            "obs_episodes": o["latency_frames"]["episodes"],
            "obs_missed": o["latency_frames"]["missed"],
            "obs_missed_near": o["latency_frames_within_one_cell"]["missed"],
            "oc_near": (obj.get("within_one_cell", {}).get("moving_matched", 0),
                        obj.get("within_one_cell", {}).get("moving_found", 0)),
            "oP": obj.get("precision"), "oR": obj.get("recall"),
            "oc": (obj.get("moving_matched", 0), obj.get("moving_reported", 0),
                   obj.get("moving_found", 0), obj.get("moving_truth", 0)),
            "sw": (obj.get("track_switches"), obj.get("identity_switches"),
                   obj.get("duplicate_matches")),
            "obsF1": o["per_class"]["moving"]["f1"],
            "stoppedF1": v["per_class"].get("stopped", {}).get("f1")}


def _strict_counts(metrics: dict[str, Any]) -> tuple[int, int, int]:
    """(TP, decided moving, truth moving) of the confusion matrix."""
    conf = metrics["confusion"]
    counts = np.array(conf["counts"])
    i, j = conf["truth"].index("moving"), conf["decision"].index("moving")
    return int(counts[i, j]), int(counts[:, j].sum()), int(counts[i].sum())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--seeds", default="1,2")
    parser.add_argument("--profiles", default="ibeo4,hdl64")
    parser.add_argument("--config", type=Path,
                        help="the recorded runs' --config, and the replays' base (with the "
                             "preset each recording took for its lidar)")
    parser.add_argument("--no-map", action="store_true",
                        help="record and replay runs without the map (kept apart)")
    parser.add_argument("--set", action="append", default=None,
                        help="[objects] overrides, 'key=value;key=value' (repeatable)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    from evperc.sim.truth import load_truth
    sets = args.set or [""]
    table: dict[str, dict[str, dict[str, Any]]] = {s: {} for s in sets}
    for profile in args.profiles.split(","):
        for seed in args.seeds.split(","):
            drive, out = recorded(args.work, profile, seed, args.config, not args.no_map)
            truth = load_truth(drive / "truth")
            for s in sets:
                table[s][f"{profile}-s{seed}"] = r = scores(
                    replay(out, replay_config(out, args.config, parse_set(s))), truth)
                log.info("%s %s-s%s %s", s or "(defaults)", profile, seed, r)
    print_table(table)
    print_means(table)


def print_means(table: dict[str, dict[str, dict[str, Any]]]) -> None:
    """docs/evaluation.md's convention: ±1-cell P / R as the mean over the seeds, missed
    episodes pooled on the observed cells."""
    print("\n| set | profile | P ±1 cell (mean of seeds) | R ±1 cell (mean) | missed episodes "
          "(observed cells, pooled; within one cell) | (visible cells, pooled) | object P / R "
          "(pooled) | within one cell | observed F1 (mean) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for s, runs in table.items():
        for profile in sorted({n.split("-")[0] for n in runs}):
            p = pooled([r for n, r in runs.items() if n.startswith(profile)])
            print(f"| {s or 'defaults'} | {profile} | {p['tP_mean']:.3f} | {p['tR_mean']:.3f} | "
                  f"{p['obs_missed']} / {p['obs_episodes']}; {p['obs_missed_near']} | "
                  f"{p['missed']} / {p['episodes']} | {p['oP']:.3f} / {p['oR']:.3f} | "
                  f"{p['oP_near']:.3f} / {p['oR_near']:.3f} | {p['obsF1_mean']:.3f} |")


def pooled(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Pooled counts of several runs' scores."""
    tc = np.sum([r["tc"] for r in rows], axis=0)
    oc = np.sum([r["oc"] for r in rows], axis=0)

    def ratio(a: float, b: float) -> float | None:
        return float(a / b) if b else None
    sc = np.sum([r["sc"] for r in rows], axis=0)
    return {"tP": ratio(tc[0], tc[1]), "tR": ratio(tc[2], tc[3]),
            "tP_mean": float(np.mean([r["tP"] for r in rows if r["tP"] is not None])),
            "tR_mean": float(np.mean([r["tR"] for r in rows if r["tR"] is not None])),
            "obs_missed": sum(r["obs_missed"] for r in rows),
            "obs_episodes": sum(r["obs_episodes"] for r in rows),
            "P": ratio(sc[0], sc[1]), "R": ratio(sc[0], sc[2]),
            "missed": sum(r["missed"] for r in rows), "episodes": sum(r["episodes"] for r in rows),
            "oP": ratio(oc[0], oc[1]), "oR": ratio(oc[2], oc[3]),
            "oP_near": ratio(sum(r["oc_near"][0] for r in rows), oc[1]),
            "oR_near": ratio(sum(r["oc_near"][1] for r in rows), oc[3]),
            "obs_missed_near": sum(r["obs_missed_near"] for r in rows),
            "obsF1_mean": float(np.mean([r["obsF1"] for r in rows if r["obsF1"] is not None]))}


def print_table(table: dict[str, dict[str, dict[str, Any]]]) -> None:
    def f(v: Any) -> str:
        return "–" if v is None else f"{v:.3f}"
    print("\n| set | run | moving P | R | P (±1 cell) | R (±1 cell) | missed / episodes | "
          "object P | object R | observed moving F1 |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for s, runs in table.items():
        for name, r in runs.items():
            print(f"| {s or 'defaults'} | {name} | {f(r['P'])} | {f(r['R'])} | {f(r['tP'])} | "
                  f"{f(r['tR'])} | {r['missed']} / {r['episodes']} | {f(r['oP'])} | "
                  f"{f(r['oR'])} | {f(r['obsF1'])} |")
        for profile in sorted({n.split("-")[0] for n in runs}):
            p = pooled([r for n, r in runs.items() if n.startswith(profile)])
            print(f"| {s or 'defaults'} | **{profile} pooled** | {f(p['P'])} | {f(p['R'])} | "
                  f"{f(p['tP'])} | {f(p['tR'])} | {p['missed']} / {p['episodes']} | "
                  f"{f(p['oP'])} | {f(p['oR'])} | {f(p['obsF1_mean'])} (mean) |")


if __name__ == "__main__":
    main()
