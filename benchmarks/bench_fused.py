"""The fused numba step (evperc.fusion.fused) against numpy fusion_step + decide and the per-cell
plain-Python reference (tests/fusion/reference.py), on 160,000 cells (400 × 400) and 40,000
cells (200 × 200, the default 100 m window at 0.5 m), after ~20 frames of a plausible scene.

The scene: a street grid (roads, pavements, buildings) seen by a ray-cast sensor driving
along the main road, with cars moving on it and cars parked at its edge; rays stop at the
first building cell (m({O}) = 0.8 there, m({F}) = 0.7 before it) and see over cars
(occupied where they cross one). Frames are timed
best-of-N with time.perf_counter. Also measured: numba compile time of the first call (fresh
cache and loaded cache, in subprocesses) and the copy time of a 20 MB float32 array, the
bandwidth bound of reading and writing the state once per frame.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from timing import best_of  # noqa: E402  (benchmarks/ is on sys.path)

from evperc.config import load_config  # noqa: E402
from evperc.fusion.fused import FusedOutputs, StoredOutputs, focal_sets, fused_step  # noqa: E402
from evperc.fusion.twin import (  # noqa: E402
    FusionParams,
    decide,
    fusion_step,
    scaled_rate,
    sensor_masses,
    vacuous,
)
from evperc.geo.prior import prior_masses  # noqa: E402
from tests.fusion import reference as ref  # noqa: E402

WARM_FRAMES = 20
REPEATS = 5
MU_FREE, MU_OCC = 0.7, 0.8


def scene_labels(side: int) -> np.ndarray:
    """Context labels: one east–west main road, two north–south roads, 6-cell pavements,
    square buildings (28 %
    of the blocks) in open ground."""
    labels = np.zeros((side, side), np.uint8)
    rows, cols = np.mgrid[0:side, 0:side]
    road = (np.abs(rows - side // 2) < 10) | (np.abs(cols - side // 4) < 7) \
        | (np.abs(cols - 3 * side // 4) < 7)
    near_road = (np.abs(rows - side // 2) < 16) | (np.abs(cols - side // 4) < 13) \
        | (np.abs(cols - 3 * side // 4) < 13)
    building = ~near_road & (rows % 50 < 14) & (cols % 50 < 14)
    labels[road] = 1
    labels[building] = 2
    return labels


def scene_scan(labels: np.ndarray, frame: int) -> tuple[np.ndarray, np.ndarray]:
    """m({F}), m({O}) of one ray-cast scan at ``frame`` (10 Hz)."""
    side = labels.shape[0]
    wall = labels == 2
    car = np.zeros_like(wall)
    centre = side // 2
    for k in range(6):  # moving cars, 4 × 9 cells, 1.5 m per frame eastwards
        c0 = (k * side // 6 + 3 * frame) % side
        car[centre - 7:centre - 3, c0:min(c0 + 9, side)] = True
    for k in range(8):  # parked cars at the southern kerb
        c0 = 12 + k * side // 8
        car[centre + 5:centre + 9, c0:c0 + 8] = True
    ego_col = side // 2 - 30 + 2 * frame
    car[centre - 2:centre + 2, ego_col - 4:ego_col + 5] = False
    azimuth = np.linspace(0, 2 * np.pi, 8 * side, endpoint=False)[:, None]
    ranges = np.arange(4, int(0.75 * side), 0.5)[None, :]
    r = np.floor(centre + ranges * np.sin(azimuth)).astype(int)
    c = np.floor(ego_col + ranges * np.cos(azimuth)).astype(int)
    inside = (r >= 0) & (r < side) & (c >= 0) & (c < side)
    hit_wall = np.zeros(r.shape, bool)
    hit_wall[inside] = wall[r[inside], c[inside]]
    hit_car = np.zeros(r.shape, bool)
    hit_car[inside] = car[r[inside], c[inside]]
    first = np.where(hit_wall.any(1), hit_wall.argmax(1), r.shape[1])[:, None]
    index = np.arange(r.shape[1])[None, :]
    free = np.zeros((side, side), np.float32)
    occ = np.zeros((side, side), np.float32)
    # a roof-mounted lidar sees over cars (occupied where hit) but not through buildings
    seen = inside & (index < first)
    free[r[seen & ~hit_car], c[seen & ~hit_car]] = MU_FREE
    hit = inside & ((index == first) | (seen & hit_car))
    occ[r[hit], c[hit]] = MU_OCC
    free[occ > 0] = 0
    return free, occ




def copy_time(nbytes: int) -> float:
    src = np.ones(nbytes // 4, np.float32)
    dst = np.empty_like(src)
    return best_of(lambda: np.copyto(dst, src), 10)


_COMPILE_PROBE = """
import time
t0 = time.perf_counter()
import numpy as np
from evperc.fusion.fused import fused_step
from evperc.fusion.twin import FusionParams
t1 = time.perf_counter()
pg = np.zeros((32, 4, 4), np.float32); pg[31] = 1
z = np.zeros((4, 4), np.float32); f = np.zeros((4, 4), np.float32)
fused_step(pg, z, f, f, np.zeros((4, 4), np.uint8), (0.9, 0.9, 0.8), 0.1, FusionParams())
t2 = time.perf_counter()
fused_step(pg, z, f, f, np.zeros((4, 4), np.uint8), (0.9, 0.9, 0.8), 0.1, FusionParams())
t3 = time.perf_counter()
print(t1 - t0, (t2 - t1) - (t3 - t2))
"""


def compile_times() -> tuple[float, float, float]:
    """(import s, first call with an empty cache s, first call with the cache filled s)."""
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache, "PYTHONPATH": str(ROOT)}
        runs = []
        for _ in range(2):
            done = subprocess.run([sys.executable, "-c", _COMPILE_PROBE], env=env, check=True,
                                  capture_output=True, text=True)
            runs.append([float(x) for x in done.stdout.split()])
    return runs[1][0], runs[0][1], runs[1][1]


def open_gate(shape: tuple[int, int], params: FusionParams) -> np.ndarray | None:
    """A motion-gate layer open everywhere when the options have the gate on (the kernel's
    work is the gated rule's; which cells the gate opens does not change its cost)."""
    return np.ones(shape, np.uint8) if params.gated else None


def warmed_state(labels, params, betas):
    """Planar state after WARM_FRAMES frames."""
    side = labels.shape[0]
    pg = np.ascontiguousarray(np.moveaxis(vacuous((side, side)), -1, 0))
    zeta = np.zeros((side, side), np.float32)
    out = FusedOutputs.empty((side, side))
    for frame in range(WARM_FRAMES):
        free, occ = scene_scan(labels, frame)
        fused_step(pg, zeta, free, occ, labels, betas, 0.1, params, out=out,
                   gate=open_gate((side, side), params))
    return pg, zeta


def bench_side(side: int, params: FusionParams, betas, n_ref: int) -> list[dict]:
    labels = scene_labels(side)
    planar, zeta = warmed_state(labels, params, betas)
    pg = np.ascontiguousarray(np.moveaxis(planar, 0, -1))  # numpy's layout
    scans = [scene_scan(labels, WARM_FRAMES + k) for k in range(REPEATS)]
    observed = np.mean([(f > 0) | (o > 0) for f, o in scans])
    focal = float((pg > 0).sum(-1).mean())
    cells = side * side

    prior = prior_masses(labels, *betas)
    free, occ = scans[0]
    sg = sensor_masses(free, occ)

    def numpy_frame() -> None:
        new_pg, _, _ = fusion_step(pg, zeta, sg, prior, (free > 0) | (occ > 0), 0.1, params,
                                   gate=open_gate((side, side), params))
        decide(new_pg, params)

    def numpy_frame_with_inputs() -> None:
        pr = prior_masses(labels, *betas)
        new_pg, _, _ = fusion_step(pg, zeta, sensor_masses(free, occ), pr,
                                   (free > 0) | (occ > 0), 0.1, params,
                                   gate=open_gate((side, side), params))
        decide(new_pg, params)

    numpy_s = best_of(numpy_frame, 3)
    numpy_inputs_s = best_of(numpy_frame_with_inputs, 3)

    def fused_timing(out) -> float:
        """best of REPEATS frames, the window moving by one cell each frame (circular
        buffer, as in the runner)."""
        state = (planar.copy(), zeta.copy(), None)
        flags = np.zeros((side, side), np.uint8)
        focal = focal_sets(state[0])
        frames = iter(scans * 2)
        offset = [0, 0]

        def fused_frame() -> None:
            f, o = next(frames)
            offset[1] = (offset[1] + 1) % side
            fused_step(state[0], state[1], f, o, labels, betas, 0.1, params, out=out,
                       flags=flags, focal=focal, offset=tuple(offset), shift=(0, 1),
                       gate=open_gate((side, side), params))

        return best_of(fused_frame, REPEATS)

    fused_s = fused_timing(FusedOutputs.empty((side, side)))
    stored_s = fused_timing(StoredOutputs.empty((side, side)))

    rates = scaled_rate(params.discount_rates, 0.1, params.discount_period_s).tolist()
    p = {"prior_where": params.prior_where, "discount": params.discount,
         "classical_rate": float(scaled_rate(params.discount_classical, 0.1,
                                             params.discount_period_s)),
         "residual": params.residual_conflict, "gamma_o": params.gamma_occupied,
         "gamma_c": params.gamma_conflict, "inc": params.zeta_increment,
         "dec": params.zeta_decrement, "stopped_target": params.stopped_target}
    flat = pg.reshape(-1, 32)
    idx = np.random.default_rng(0).choice(cells, n_ref, replace=False)
    priors = [ref.from_vector(prior.reshape(-1, 32)[i]) for i in idx]
    args = [(ref.from_vector(flat[i]), float(zeta.flat[i]), float(free.flat[i]),
             float(occ.flat[i]), pr, bool(free.flat[i] > 0 or occ.flat[i] > 0))
            for i, pr in zip(idx, priors, strict=True)]
    t0 = time.perf_counter()
    for m, z, f, o, pr, obs in args:
        new, _, _ = ref.step(m, z, f, o, pr, obs, rates, p)
        ref.betp(new)
    ref_s = (time.perf_counter() - t0) * cells / n_ref

    scene = f"{side}x{side}, {observed:.0%} observed, {focal:.1f} focal sets/cell"
    return [
        {"cells": cells, "stage": "numpy fusion_step + decide", "ms": numpy_s * 1e3,
         "frames/s": 1 / numpy_s, "fused is x faster": numpy_s / fused_s, "scene": scene},
        {"cells": cells, "stage": "numpy incl. sensor_masses + prior_masses",
         "ms": numpy_inputs_s * 1e3, "frames/s": 1 / numpy_inputs_s,
         "fused is x faster": numpy_inputs_s / fused_s},
        {"cells": cells, "stage": "fused_step, float outputs (moving window)",
         "ms": fused_s * 1e3, "frames/s": 1 / fused_s, "fused is x faster": 1.0},
        {"cells": cells, "stage": "fused_step, uint8 outputs as stored (the runner's)",
         "ms": stored_s * 1e3, "frames/s": 1 / stored_s,
         "fused is x faster": fused_s / stored_s},
        {"cells": cells, "stage": f"reference per-cell Python ({n_ref} cells, scaled)",
         "ms": ref_s * 1e3, "frames/s": 1 / ref_s, "fused is x faster": ref_s / fused_s},
    ]


def run() -> list[dict]:
    config = load_config()
    params = FusionParams.from_config(config)
    betas = (config["map"]["beta_building"], config["map"]["beta_road"],
             config["map"]["beta_other"])
    rows = bench_side(400, params, betas, 400) + bench_side(200, params, betas, 200)
    import_s, cold_s, cached_s = compile_times()
    rows.append({"stage": "import evperc.fusion.fused (numba)", "ms": import_s * 1e3})
    rows.append({"stage": "first call, empty numba cache (compile)", "ms": cold_s * 1e3})
    rows.append({"stage": "first call, numba cache filled (load)", "ms": cached_s * 1e3})
    state_bytes = 160_000 * 32 * 4
    for nbytes, label in ((state_bytes, "20 MB"), (256 << 20, "256 MB")):
        t = copy_time(nbytes)
        rows.append({"cells": 160_000 if nbytes == state_bytes else "",
                     "stage": f"numpy copy of {label} float32 (read + write)", "ms": t * 1e3,
                     "frames/s": 1 / t if nbytes == state_bytes else "",
                     "scene": f"{2 * nbytes / t / 1e9:.1f} GB/s moved"})
    return rows


if __name__ == "__main__":
    from run import print_table

    print_table("fused", run())
