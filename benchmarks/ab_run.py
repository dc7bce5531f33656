"""Whole `evperc run`s of workload (a) from several source trees, interleaved (issue 20's
speed target: the run's frames/s against those of an older commit, measured in one run).

    git worktree add /tmp/wt-old e996c3d    # a detached tree per commit to compare
    python benchmarks/ab_run.py 14 old=/tmp/wt-old new=.

Each round runs every tree once (``python -m evperc -q run`` on bench_run's (a) log, 200 m
window, ``PYTHONPATH`` = the tree), in the order given and reversed every other round; the
trees' numba caches are kept apart (``NUMBA_CACHE_DIR`` per tree, under bench-out/, so the
first round also compiles: run one round first to warm them). It prints each run's
frames/s and CPU ms per frame of each thread (the manifest summary, as bench_run reads it),
then per tree the median and range, and for every pair of trees the median and range of
the per-round ratios — on a shared machine the only figure that means something, since
the host's speed changes from minute to minute. Raw summaries go to
``bench-out/ab_run.json``.

``--seconds 60`` (before the rounds) runs a 60 s drive of the same profile instead (600
scans, simulated once into bench-out/sim-hdl64-60s): the frames' steady state, with the
run's set-up and its first touch of fresh memory spread over six times more frames
(docs/performance.md § "The main thread against e996c3d").

``--warm N`` (before the rounds): N more rounds first, run and not counted — a new tree's
first run compiles its kernels into its numba cache.

Beside the frames/s ratio, every pair gets the ratio of the CPU time a frame of all the
run's threads (the older tree's over the newer's: above 1 when the newer spends less): on
two cores kept ~80 % busy it follows the throughput, with less of the host's noise.

``name=TREE@FILE.toml``: that tree's runs take FILE's keys on top of the 200 m window (a
stage switched off, to measure what it costs in the same rounds), e.g.
``python benchmarks/ab_run.py 8 e99=/tmp/wt-old new=. noobj=.@configs/ablation/no_objects.toml``
(docs/performance.md § "The object part on the fusion thread: measured").
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import bench_run  # noqa: E402  (benchmarks/ is on sys.path)

from evperc.vector_width import environ_as_given  # noqa: E402


def run_tree(tree: Path, name: str, sim: Path, config: Path) -> dict:
    """The manifest summary of one run of ``sim`` with the code of ``tree``."""
    out = bench_run.CACHE / "runs" / f"ab-{name}"
    # each tree picks numba's vector width itself (an older one: LLVM's; evperc.vector_width)
    env = {**environ_as_given(), "PYTHONPATH": str(tree),
           "NUMBA_CACHE_DIR": str(bench_run.CACHE / "numba" / name)}
    subprocess.run([sys.executable, "-m", "evperc", "-q", "run", str(sim / "drive.mcap"),
                    "--map", str(sim / "map.geojson"), "--config", str(config), "--out",
                    str(out), "--overwrite"], env=env, check=True, cwd=tree,
                   stdout=subprocess.DEVNULL)
    return json.loads((out / "manifest.json").read_text())["summary"]


OBJECT_STAGES = ("objects", "unmapped")


def object_share(summary: dict) -> tuple[float, float] | None:
    """The object stages' (``OBJECT_STAGES``) share of a frame: their main-thread CPU time
    over the CPU time of every thread, and their wall time (the stage timer) over the frame's
    (1 / frames/s); None for a tree whose summary has no stage CPU times (before 2026-12-04)."""
    stage_cpu = summary.get("stage_cpu_ms_per_frame")
    if stage_cpu is None:
        return None
    cpu = sum(stage_cpu.get(k, 0.0) for k in OBJECT_STAGES)
    wall = sum(summary["stage_ms_per_frame"].get(k, 0.0) for k in OBJECT_STAGES)
    return (cpu / sum(summary["cpu_ms_per_frame"].values()),
            wall * summary["frames_per_s"] / 1e3)


def frame_cpu_ms(summary: dict) -> float:
    """CPU ms a frame of all the run's threads (main, decode, writer, other)."""
    return sum(summary["cpu_ms_per_frame"].values())


def tree_spec(arg: str) -> tuple[str, Path, Path]:
    """``name=TREE`` or ``name=TREE@FILE.toml`` → (name, tree, the run's config file: the
    200 m window, then FILE's keys)."""
    name, rest = arg.split("=", 1)
    tree, _, extra = rest.partition("@")
    text = bench_run.WINDOW_200 + (Path(extra).read_text() if extra else "")
    config = bench_run.config_file(f"window200-{name}" if extra else "window200", text)
    return name, Path(tree).resolve(), config


def main(argv: list[str]) -> None:
    seconds = 10  # workload (a)
    warm = 0
    while argv[:1] in (["--seconds"], ["--warm"]):
        if argv[0] == "--seconds":
            seconds = int(argv[1])
        else:
            warm = int(argv[1])
        argv = argv[2:]
    rounds = int(argv[0])
    sim = bench_run.simulate(f"sim-hdl64-{seconds}s", "hdl64", seconds)
    trees = [tree_spec(a) for a in argv[1:]]
    runs: dict[str, list[dict]] = {name: [] for name, _, _ in trees}
    print("load average before", os.getloadavg(), flush=True)
    for _ in range(warm):  # compiled and cached, not counted
        for name, tree, config in trees:
            run_tree(tree, name, sim, config)
    for k in range(rounds):
        for name, tree, config in trees if k % 2 == 0 else trees[::-1]:
            summary = run_tree(tree, name, sim, config)
            runs[name].append(summary)
            cpu = summary["cpu_ms_per_frame"]
            print(k, name, f"{summary['frames_per_s']:.1f} frames/s, CPU ms/frame main / "
                  f"decode / writer {cpu['main']:.2f} / {cpu['decode']:.2f} / "
                  f"{cpu['writer']:.2f}", flush=True)
    print("load average after", os.getloadavg())
    for name, summaries in runs.items():
        fps = [s["frames_per_s"] for s in summaries]
        cpu = {t: statistics.median(s["cpu_ms_per_frame"][t] for s in summaries)
               for t in ("main", "decode", "writer")}
        print(f"{name}: median {statistics.median(fps):.1f} frames/s ({min(fps):.1f}-"
              f"{max(fps):.1f}); CPU ms/frame main / decode / writer {cpu['main']:.2f} / "
              f"{cpu['decode']:.2f} / {cpu['writer']:.2f}")
        shares = [object_share(s) for s in summaries]
        if None not in shares:
            cpu_share = [c for c, _ in shares]
            wall_share = statistics.median(w for _, w in shares)
            print(f"{name}: object stages' share of a frame, median (range): CPU "
                  f"{statistics.median(cpu_share):.1%} ({min(cpu_share):.1%}-"
                  f"{max(cpu_share):.1%}), wall {wall_share:.1%}")
    names = list(runs)
    for i, a in enumerate(names):
        for b in names[:i]:
            ratios = [x["frames_per_s"] / y["frames_per_s"]
                      for x, y in zip(runs[a], runs[b], strict=True)]
            print(f"{a} / {b}: per-round ratio median {statistics.median(ratios):.3f} "
                  f"({min(ratios):.3f}-{max(ratios):.3f}, {len(ratios)} rounds)")
            cpu = [frame_cpu_ms(y) / frame_cpu_ms(x)
                   for x, y in zip(runs[a], runs[b], strict=True)]
            print(f"{a} / {b}: CPU a frame, {b}'s over {a}'s, median "
                  f"{statistics.median(cpu):.3f} ({min(cpu):.3f}-{max(cpu):.3f})")
    (bench_run.CACHE / "ab_run.json").write_text(json.dumps(runs))


if __name__ == "__main__":
    main(sys.argv[1:])
