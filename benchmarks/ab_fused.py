"""The fused step of two commits, timed in alternating rounds on the same state.

Host speed on a shared machine drifts by tens of percent between minutes, so a kernel change
is judged by timing the old and the new kernel in the same run, alternating: each round
runs ``--frames`` frames of one kernel in a fresh process (its own numba cache), then of the
other. The state is workload (a) of ``bench_run.py`` after 10 scans (160,000 cells), saved
once to ``bench-out/ab-state.npz``; every frame moves the window by one cell, as when
driving. The old kernel is ``git archive REV evperc configs`` unpacked into a temporary
folder.

``--replay`` times the step over (a)'s own frames 10–99 instead, back to back with every
scan's inputs prepared first (as ``bench_run.replay``; the window moving with the vehicle,
a new scan each frame). With the motion gate on (the defaults), the state is saved with the
next scan's gate layer, and ``--replay`` runs the gate pass before each timed step, untimed,
as ``Pipeline.step`` does; an older tree gets only the parameters its ``FusionParams`` has.

``python benchmarks/ab_fused.py [--base REV] [--rounds 6] [--frames 40] [--stored]
[--replay]`` (default base: f17e282, the kernel before the compact focal-set layout).
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import statistics
import subprocess
import sys
import tarfile
import tempfile
from io import BytesIO
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
HERE = Path(__file__).resolve().parent
STATE = ROOT / "bench-out" / "ab-state.npz"
SCANS = 10

#: the timing loop, run in a child process with the kernel under test first on sys.path
CHILD = r"""
import inspect, json, sys, time
import numpy as np
from pathlib import Path
import evperc
# by the tree's files, not by trying the import: the editable install's finder would serve
# evperc.fusion from this repository to a tree without it
if (Path(evperc.__file__).parent / "fusion").is_dir():
    from evperc.fusion.fused import FusedOutputs, StoredOutputs, fused_step
    from evperc.fusion.twin import FusionParams
else:  # a commit before the evperc/fusion/ layout
    from evperc.fused import FusedOutputs, StoredOutputs, fused_step
    from evperc.pipeline import FusionParams
with np.load(sys.argv[1]) as npz:
    z = {name: npz[name] for name in npz.files}
pg, zeta, flags = z["pg"].copy(), z["zeta"].copy(), z["flags"].copy()
kwargs = {}
if "focal" in inspect.signature(fused_step).parameters:
    focal_sets = sys.modules[fused_step.__module__].focal_sets
    kwargs["focal"] = focal_sets(pg)
shape = flags.shape
out = (StoredOutputs if sys.argv[3] == "stored" else FusedOutputs).empty(shape)
# the keys this tree's FusionParams knows (an older tree lacks the newer options: it runs
# its own step, which is what the A/B times)
known = set(inspect.signature(FusionParams).parameters)
params = FusionParams(**{k: tuple(v) if isinstance(v, list) else v
                          for k, v in json.loads(str(z["params"])).items() if k in known})
if "gate" in inspect.signature(fused_step).parameters and "gate" in z:
    kwargs["gate"] = z["gate"]  # the motion gate's layer of the scan (the runner's)
offset = [int(v) for v in z["offset"]]
times = []
for frame in range(int(sys.argv[2]) + 2):  # two to warm up
    offset[1] = (offset[1] + 1) % shape[1]
    t0 = time.perf_counter()
    fused_step(pg, zeta, z["free"], z["occupied"], z["labels"], tuple(z["betas"]), 0.1,
               params, out=out, flags=flags, offset=tuple(offset), shift=(0, 1), **kwargs)
    times.append(time.perf_counter() - t0)
print(json.dumps(times[2:]))
"""


#: ``--replay``: the step over (a)'s frames back to back (inputs prepared first), as
#: bench_run.replay; times of frames 10 on. argv: simulated log folder, config, frames, kind
REPLAY_CHILD = r"""
import json, sys, time
from pathlib import Path
import evperc
from evperc.config import load_config
if (Path(evperc.__file__).parent / "fusion").is_dir():  # by the files, as CHILD
    from evperc.fusion.fused import FusedOutputs, StoredOutputs, fused_step
else:  # a commit before the evperc/fusion/ layout
    from evperc.fused import FusedOutputs, StoredOutputs, fused_step
from evperc.runner import FusionState, Pipeline, RunRequest
sim = Path(sys.argv[1])
pipeline = Pipeline(RunRequest(log_path=sim / "drive.mcap", out_dir=sim / "unused",
                               config=load_config(sys.argv[2]), map_path=sim / "map.geojson"))
inputs = [prepared for _, prepared in pipeline.inputs(-1)]
out = (StoredOutputs if sys.argv[4] == "stored" else FusedOutputs).empty(inputs[0].free.shape)
state, times = FusionState(), []
gated = getattr(pipeline.params, "gated", False)
if gated:  # the motion gate's pass, untimed, as Pipeline.step makes it
    from evperc.fusion.gate import GateState, gate_step
for frame in inputs[:10 + int(sys.argv[3])]:
    shift = state.move_to(frame.window)
    kwargs = {}
    if gated:
        if state.gate is None:
            state.gate = GateState.fresh(frame.window.shape)
        kwargs["gate"] = gate_step(state.gate, frame.free, frame.occupied, 0.1,
                                   pipeline.params, offset=state.offset, shift=shift,
                                   closed=getattr(frame, "near_building", None))
    t0 = time.perf_counter()
    fused_step(state.pg, state.zeta, frame.free, frame.occupied, frame.labels, pipeline.betas,
               0.1, pipeline.params, out=out, flags=state.flags, focal=state.focal,
               offset=state.offset, shift=shift, **kwargs)
    times.append(time.perf_counter() - t0)
print(json.dumps(times[10:]))
"""


def save_state() -> None:
    """(a)'s state after SCANS scans and the next scan's inputs (default fusion config)."""
    sys.path.insert(0, str(ROOT))
    sys.path.insert(0, str(HERE))
    import bench_run

    from evperc.config import load_config
    from evperc.fusion.fused import StoredOutputs
    from evperc.fusion.gate import gate_step
    from evperc.runner import FusionState, Pipeline, RunRequest

    sim = bench_run.simulate("sim-hdl64-10s", "hdl64", 10.0)
    config = load_config(bench_run.config_file("window200", bench_run.WINDOW_200))
    with tempfile.TemporaryDirectory() as unused:
        pipeline = Pipeline(RunRequest(log_path=sim / "drive.mcap", out_dir=Path(unused),
                                       config=config, map_path=sim / "map.geojson"))
    state, out = FusionState(), None
    scans = pipeline.scans(-1)
    for _ in range(SCANS):
        inputs = pipeline.prepare(next(scans)[1])
        out = out or StoredOutputs.empty(inputs.free.shape)
        pipeline.step(state, inputs, out)
    inputs = pipeline.prepare(next(scans)[1])
    gate = {}
    if pipeline.params.gated:  # the next scan's gate layer, on a copy of the state
        moved = copy.deepcopy(state)
        shift = moved.move_to(inputs.window)
        gate["gate"] = gate_step(moved.gate, inputs.free, inputs.occupied, 0.1,
                                 pipeline.params, offset=moved.offset, shift=shift,
                                 closed=inputs.near_building)
    np.savez(STATE, pg=state.pg, zeta=state.zeta, flags=state.flags,
             offset=np.array(state.offset), free=inputs.free, occupied=inputs.occupied,
             labels=inputs.labels, betas=np.array(pipeline.betas),
             params=np.array(json.dumps(dataclasses.asdict(pipeline.params))), **gate)


def unpack(rev: str, into: Path) -> Path:
    """``evperc/`` (and ``configs/``, which its default.toml links to) as of ``rev`` under
    ``into``."""
    tar = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "evperc", "configs"],
                         check=True, capture_output=True).stdout
    with tarfile.open(fileobj=BytesIO(tar)) as archive:
        archive.extractall(into, filter="data")
    return into


def time_kernel(path: Path, cache: Path, frames: int, kind: str, replay: bool = False
                ) -> list[float]:
    from evperc.vector_width import environ_as_given  # each tree picks its vector width

    env = {**environ_as_given(), "PYTHONPATH": str(path), "NUMBA_CACHE_DIR": str(cache)}
    if replay:
        command = [REPLAY_CHILD, str(ROOT / "bench-out" / "sim-hdl64-10s"),
                   str(ROOT / "bench-out" / "configs" / "window200.toml")]
    else:
        command = [CHILD, str(STATE)]
    done = subprocess.run([sys.executable, "-c", *command, str(frames), kind], env=env,
                          check=True, capture_output=True, text=True, cwd=path)
    return json.loads(done.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", default="f17e282", help="the older commit (default %(default)s)")
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--frames", type=int, default=None,
                        help="frames per round (default 40; 90, all of them, with --replay)")
    parser.add_argument("--stored", action="store_true",
                        help="time the kind the runner uses (uint8 layers as stored)")
    parser.add_argument("--replay", action="store_true",
                        help="time the step over (a)'s frames 10-99 back to back (inputs "
                             "prepared first) instead of repeating the state after 10 scans")
    args = parser.parse_args()
    kind = "stored" if args.stored else "float"
    frames = args.frames or (90 if args.replay else 40)
    if not STATE.exists():  # also simulates (a) and writes its config
        save_state()
    with tempfile.TemporaryDirectory() as tmp:
        kernels = {args.base: unpack(args.base, Path(tmp) / "base"),
                   "working tree": ROOT}
        caches = {name: Path(tmp) / f"numba-{k}" for k, name in enumerate(kernels)}
        for name, path in kernels.items():
            time_kernel(path, caches[name], 1, kind)  # compile its numba kernels once
        medians: dict[str, list[float]] = {name: [] for name in kernels}
        best = dict.fromkeys(kernels, float("inf"))
        for _ in range(args.rounds):
            for name, path in kernels.items():
                times = time_kernel(path, caches[name], frames, kind, args.replay)
                medians[name].append(statistics.median(times))
                best[name] = min(best[name], min(times))
    where = "over (a)'s frames 10-99" if args.replay else "on (a)'s state after 10 scans"
    print(f"fused step ({kind} outputs) {where}, {args.rounds} alternating rounds of "
          f"{frames} frames")
    print(f"{'kernel':<14} {'median of medians ms':>21} {'best frame ms':>14}  round medians")
    for name in kernels:
        print(f"{name:<14} {statistics.median(medians[name]) * 1e3:>21.2f} "
              f"{best[name] * 1e3:>14.2f}  "
              + " ".join(f"{m * 1e3:.2f}" for m in medians[name]))
    old, new = (statistics.median(medians[name]) for name in kernels)
    print(f"new / old (median of medians): {new / old:.2f}")


if __name__ == "__main__":
    main()
