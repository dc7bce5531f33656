"""Speed and memory of the whole `evperc run` at scale (issue 7), against a naive dense
reference measured in the same process (benchmarks/naive.py).

Workloads, simulated once with `evperc simulate` on the Helsinki extract (tests/data/osm)
into ``bench-out/`` (git-ignored; reused when present):

- (a) hdl64, 10 s (100 scans of ~120,000 points), 200 m window at 0.5 m = 160,000 cells;
- (b) ibeo4 (~800 points per scan), 20 s (200 scans), default 100 m window (40,000 cells);
- (c) ibeo4, 100 s (1,000 scans) and the same log looped 10× (10,000 scans): peak RSS must
  not depend on the log's length. `evperc simulate --seconds 1000` is too slow here (and
  failed, see docs/performance.md), so the long log repeats the 100 s one with its stamps
  shifted by the loop's length (messages decoded and re-encoded with mcap-ros2's writer);
  the ego pose jumps back to the start at each seam (the window is then rebuilt).

Every `evperc run` is a subprocess (``python -m evperc -q run``): frames/s and the per-stage
times come from its manifest summary, the peak RSS from the child's ``VmHWM``
(/proc/PID/status, polled every 50 ms until it exits; ``os.wait4``'s ``ru_maxrss`` would
include the parent's size at fork). Numba start-up: the (b) log's first second run
with ``NUMBA_CACHE_DIR`` pointed at an empty directory (compiles) and then again (loads).

In-process, on scan 11 of (a) with the state after 10 scans: our sensor grid (best of 5)
and fused step (50 frames, the window moving one cell per frame: best and median) against
the naive per-point Python sensor model (whole scan, timed once) and the naive dense
pair-loop fusion (timed on 16,000 random cells, scaled ×10 to 160,000); the fused step
with stored outputs also with the general kernel (the default options run the lean one,
``evperc.fusion.fused._kernel``). The naive results
are compared with ours (same decisions expected). Output precision: the first 10 frames of
(a) recomputed in memory (float32) against what the run stored. The fused step over the
log's own frames (:func:`replay`): every scan's inputs prepared first, then the step on
frames 0–99 back to back, median and 90th percentile of frames 10–99, on 1 and 2 threads.

``python benchmarks/bench_run.py [--quick]`` (quick: 3× loop, one repeat per workload).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(HERE))

import naive  # noqa: E402
from timing import best_and_median, best_of  # noqa: E402  (benchmarks/ is on sys.path)

from evperc import load  # noqa: E402
from evperc.config import load_config  # noqa: E402
from evperc.fusion import fused  # noqa: E402
from evperc.fusion.fused import FusedOutputs, StoredOutputs, fused_step, window_order  # noqa: E402
from evperc.fusion.twin import decide  # noqa: E402
from evperc.geo.prior import prior_masses  # noqa: E402
from evperc.runner import FusionState, Pipeline, RunRequest  # noqa: E402
from evperc.sensor import sensor_grid  # noqa: E402

CACHE = ROOT / "bench-out"
OSM = ROOT / "tests" / "data" / "osm"
QUICK = "--quick" in sys.argv[1:] or bool(os.environ.get("EVPERC_BENCH_QUICK"))
LOOPS = 3 if QUICK else 10
REPEATS = 1 if QUICK else 3
NAIVE_CELLS = 16_000
PRECISION_FRAMES = 10
#: frames of the in-process fusion timing (best and median reported)
FUSION_FRAMES = 50
#: frames of the replay (bench_run.replay) before its timing starts
REPLAY_FROM = 10
WINDOW_200 = "[grid]\nwindow_size_m = 200.0\n"
#: the run with glibc's own malloc thresholds (evperc.plumbing.keep_freed_memory off)
GLIBC_DEFAULTS = {"EVPERC_GLIBC_MALLOC_DEFAULTS": "1"}
#: stages of the manifest summary, in pipeline order, with the issue's names
STAGES = [("read", "read + decode: wait for the decode thread"),
          ("decode", "decode thread: read + decompress + decode the scan"),
          ("geometry", "pose + window"),
          ("sensor", "sensor grid"),
          ("prior", "map prior"),
          ("fusion", "scroll + fusion + decision + quantise (one kernel)"),
          ("write", "write: hand the frame to the writer"),
          ("writer_thread", "write: deflate + file (writer thread)")]


def open_gate(shape: tuple[int, int], params) -> np.ndarray | None:
    """A motion-gate layer open everywhere when the options have the gate on (the fused
    kernel's work is the gated rule's; which cells the gate opens does not change its cost;
    the runner computes the real one with evperc.fusion.gate, timed in the runs)."""
    return np.ones(shape, np.uint8) if params.gated else None


# --- inputs ------------------------------------------------------------------------------

def simulate(name: str, profile: str, seconds: float, seed: int = 7) -> Path:
    """``bench-out/<name>/`` with drive.mcap + map.geojson, simulated once."""
    out = CACHE / name
    if (out / ".done").exists():
        return out
    subprocess.run([sys.executable, "-m", "evperc", "-q", "simulate",
                    "--map", str(OSM / "helsinki_buildings.geojson"),
                    "--roads", str(OSM / "helsinki_roads.geojson"), "--profile", profile,
                    "--seconds", str(seconds), "--seed", str(seed), "--out", str(out),
                    "--overwrite"], check=True, cwd=ROOT)
    (out / ".done").touch()
    return out


def loop_log(src: Path, times: int) -> Path:
    """``src``'s drive.mcap repeated ``times`` times, header stamps and log times shifted by
    the log's span + 0.1 s per repeat; /tf_static written once. Returns the folder."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from mcap_ros2.writer import Writer

    out = CACHE / f"{src.name}-x{times}"
    if (out / ".done").exists():
        return out
    out.mkdir(parents=True, exist_ok=True)
    shutil.copy(src / "map.geojson", out / "map.geojson")
    with open(src / "drive.mcap", "rb") as f:
        stats = make_reader(f).get_summary().statistics
    period = stats.message_end_time - stats.message_start_time + 100_000_000
    factory, decoders, schemas = DecoderFactory(), {}, {}
    with open(out / "drive.mcap", "wb") as sink:
        writer = Writer(sink)
        for k in range(times):
            shift = k * period
            with open(src / "drive.mcap", "rb") as f:
                for schema, channel, msg in make_reader(f).iter_messages(log_time_order=True):
                    if k and channel.topic == "/tf_static":
                        continue
                    decoder = decoders.get(channel.id)
                    if decoder is None:
                        decoder = decoders[channel.id] = factory.decoder_for(
                            channel.message_encoding, schema)
                    message = decoder(msg.data)
                    headers = ([t.header for t in message.transforms]
                               if hasattr(message, "transforms") else [message.header])
                    for header in headers:
                        ns = header.stamp.sec * 1_000_000_000 + header.stamp.nanosec + shift
                        header.stamp.sec, header.stamp.nanosec = divmod(ns, 1_000_000_000)
                    if schema.id not in schemas:
                        schemas[schema.id] = writer.register_msgdef(schema.name,
                                                                    schema.data.decode())
                    writer.write_message(channel.topic, schemas[schema.id], message,
                                         msg.log_time + shift, msg.publish_time + shift)
        writer.finish()
    (out / ".done").touch()
    return out


def config_file(name: str, text: str) -> Path:
    path = CACHE / "configs" / f"{name}.toml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


# --- one `evperc run` in a subprocess ----------------------------------------------------

def run_evperc(sim: Path, out: Path, config: Path | None = None, extra: tuple[str, ...] = (),
               env: dict[str, str] | None = None) -> dict:
    """Run ``evperc run`` on ``sim``; returns its summary plus wall_s, peak_rss_mb (VmHWM of
    the child), rss_mb_samples (VmRSS polled every 50 ms), cpu_s and bytes_per_frame."""
    cmd = [sys.executable, "-m", "evperc", "-q", "run", str(sim / "drive.mcap"),
           "--map", str(sim / "map.geojson"), "--out", str(out), "--overwrite", *extra]
    if config is not None:
        cmd += ["--config", str(config)]
    t0 = time.perf_counter()
    with tempfile.TemporaryFile() as err:
        child = subprocess.Popen(cmd, cwd=ROOT, env={**os.environ, **(env or {})},
                                 stdout=subprocess.DEVNULL, stderr=err)
        samples = []
        hwm = 0.0
        while True:
            pid, status, usage = os.wait4(child.pid, os.WNOHANG)
            if pid:
                break
            samples.append(_vm_rss_mb(child.pid))
            hwm = max(hwm, _vm_rss_mb(child.pid, "VmHWM"))
            time.sleep(0.05)
        wall = time.perf_counter() - t0
        child.returncode = os.waitstatus_to_exitcode(status)
        if child.returncode:
            err.seek(0)
            raise RuntimeError(f"{' '.join(cmd)} failed:\n{err.read().decode()[-2000:]}")
    summary = json.loads((out / "manifest.json").read_text())["summary"]
    frame_bytes = sum(p.stat().st_size for p in (out / "frames").iterdir())
    # ru_maxrss of a child also counts its parent's RSS at fork (Linux keeps the larger
    # high-water mark across exec), so under `make bench` it reported run.py's own size;
    # the child's VmHWM (peak RSS since exec), polled until it exits, is its own
    return {**summary, "wall_s": wall, "peak_rss_mb": hwm,
            "ru_maxrss_mb": usage.ru_maxrss / 1024,
            "rss_mb_samples": [s for s in samples if s], "cpu_s": usage.ru_utime + usage.ru_stime,
            "sys_s": usage.ru_stime, "minor_faults": usage.ru_minflt,
            "bytes_per_frame": frame_bytes / max(summary["frames"], 1)}


def _vm_rss_mb(pid: int, key: str = "VmRSS") -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(f"{key}:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def thread_cpu(run: dict) -> str:
    """CPU ms per frame of the main, decode and writer threads, as "m / d / w"."""
    cpu = run.get("cpu_ms_per_frame", {})
    return " / ".join(f"{cpu.get(k, float('nan')):.2f}" for k in ("main", "decode", "writer"))


def all_runs(run: dict) -> str:
    """frames/s of each of a workload's runs, as "a, b, c"."""
    return ", ".join(f"{v:.1f}" for v in run["all_frames_per_s"])


def best_run(sim: Path, out: Path, config: Path | None = None) -> dict:
    """The fastest of REPEATS runs (the machine is shared); peak RSS is the largest seen."""
    runs = [run_evperc(sim, out, config) for _ in range(REPEATS)]
    best = max(runs, key=lambda r: r["frames_per_s"])
    return {**best, "peak_rss_mb": max(r["peak_rss_mb"] for r in runs),
            "all_frames_per_s": [r["frames_per_s"] for r in runs]}


def numba_startup(sim: Path) -> tuple[float, float]:
    """Wall s of a 1 s run (10 frames) with an empty numba cache and then with it filled."""
    with tempfile.TemporaryDirectory() as cache:
        env = {"NUMBA_CACHE_DIR": cache}
        out = CACHE / "runs" / "numba"
        cold = run_evperc(sim, out, extra=("--end", "1.0"), env=env)["wall_s"]
        warm = run_evperc(sim, out, extra=("--end", "1.0"), env=env)["wall_s"]
    return cold, warm


# --- in-process: ours vs naive on the same inputs, and the output precision ---------------



def sim_pipeline(sim: Path, config_path: Path) -> Pipeline:
    """The run's pipeline on the simulated log and map in ``sim``, in memory: as `evperc run
    --config CONFIG_PATH` makes it, the sensor preset of the log's lidar (hdl64's 64 layers)
    under the file's keys, so that it replays the stored run's frames."""
    return Pipeline(RunRequest(log_path=sim / "drive.mcap", out_dir=CACHE / "unused",
                               config=load_config(config_path), map_path=sim / "map.geojson",
                               config_path=config_path, sensor_preset=True))


def in_process(sim: Path, config_path: Path, stored: Path) -> dict:
    """Replays (a) in memory: precision of the stored frames, then ours vs naive on the next
    scan with the state after PRECISION_FRAMES scans."""
    pipeline = sim_pipeline(sim, config_path)
    state = FusionState()
    scans = pipeline.scans(-1)
    run = load(stored)
    worst = {"masses": 0.0, "betp": 0.0, "zeta": 0.0}
    same_decisions = cells = 0
    out = None
    for (_, scan), saved in zip(scans, run.frames, strict=False):
        if out is None:
            out = StoredOutputs.empty(saved.decision.shape)
        pipeline.step(state, pipeline.prepare(scan), out)
        # the float32 state in memory against what the run stored (uint8 steps of 1/255)
        masses = np.moveaxis(window_order(state.pg, state.offset), 0, -1)
        betp, decision = decide(masses, pipeline.params)
        same_decisions += int((decision == saved.decision).sum())
        cells += decision.size
        for key, value in (("masses", masses), ("betp", betp),
                           ("zeta", window_order(state.zeta, state.offset))):
            worst[key] = max(worst[key], float(np.abs(value - getattr(saved, key)).max()))
        if saved.index + 1 == PRECISION_FRAMES:
            break

    _, scan = next(scans)
    t_crs = pipeline.georef.apply(scan.T_world_sensor)
    window, sp = state.window, pipeline.sensor_params
    ours_sensor = best_of(lambda: sensor_grid(scan.points, scan.planar, t_crs, window, sp), 5)
    free, occ = sensor_grid(scan.points, scan.planar, t_crs, window, sp)
    t0 = time.perf_counter()
    naive_free, naive_occ = naive.sensor_grid(scan.points, scan.planar, t_crs, window, sp)
    naive_sensor = time.perf_counter() - t0
    sensor_agree = float(((free > 0) == (naive_free > 0)).mean()
                         * ((occ > 0) == (naive_occ > 0)).mean())

    labels = pipeline.rasteriser.labels(window)
    betas, params = pipeline.betas, pipeline.params
    floats = FusedOutputs.empty(window.shape)
    pg, zeta, flags, focal = (state.pg.copy(), state.zeta.copy(), state.flags.copy(),
                              state.focal.copy())
    offset = [state.offset[0], state.offset[1]]

    def step(out: FusedOutputs | StoredOutputs) -> None:
        """the next frame, the window moved by one cell (as when driving)"""
        offset[1] = (offset[1] + 1) % window.cols
        fused_step(pg, zeta, free, occ, labels, betas, 0.1, params, out=out, flags=flags,
                   focal=focal, offset=tuple(offset), shift=(0, 1),
                   gate=open_gate(window.shape, params))

    ours_fusion, median_fusion = best_and_median(lambda: step(floats), FUSION_FRAMES)
    ours_stored, median_stored = best_and_median(lambda: step(out), FUSION_FRAMES)
    # the general kernel (any option set; the default options run the lean one), stored kind
    lean_or_general = fused._kernel
    fused._kernel = lambda floats, lean: lean_or_general(floats, False)
    try:
        step(out)  # compiles it on a first benchmark run
        general_stored, general_median = best_and_median(lambda: step(out), FUSION_FRAMES)
    finally:
        fused._kernel = lean_or_general
    # the stored kind once more from the state of the naive comparison
    pg[...], zeta[...], flags[...], focal[...] = state.pg, state.zeta, state.flags, state.focal
    fused_step(pg, zeta, free, occ, labels, betas, 0.1, params, out=floats, flags=flags,
               focal=focal, offset=state.offset, gate=open_gate(window.shape, params))
    after = np.moveaxis(window_order(pg, state.offset), 0, -1).reshape(-1, 32)
    copy_s = best_of(lambda: np.copyto(pg, state.pg), 5)
    n_cells = window.rows * window.cols
    pick = np.random.default_rng(0).choice(n_cells, NAIVE_CELLS, replace=False)
    observed = ((free > 0) | (occ > 0)).ravel()[pick]
    prior = prior_masses(labels, *betas).reshape(-1, 32)[pick]
    before = np.moveaxis(window_order(state.pg, state.offset), 0, -1).reshape(-1, 32)
    t0 = time.perf_counter()
    naive_pg, _, _, naive_decision = naive.dense_step(
        before[pick], window_order(state.zeta, state.offset).ravel()[pick], free.ravel()[pick],
        occ.ravel()[pick], prior, observed, 0.1, params)
    naive_fusion = (time.perf_counter() - t0) * n_cells / NAIVE_CELLS
    return {"points": len(scan.points), "cells": n_cells, "precision_frames": PRECISION_FRAMES,
            "decisions_equal": same_decisions / cells, "max_abs_error": worst,
            "ours_sensor_s": ours_sensor, "naive_sensor_s": naive_sensor,
            "sensor_agreement": sensor_agree, "ours_fusion_s": ours_fusion,
            "ours_stored_s": ours_stored, "naive_fusion_s": naive_fusion,
            "median_fusion_s": median_fusion, "median_stored_s": median_stored,
            "general_stored_s": general_stored, "general_median_stored_s": general_median,
            "state_copy_s": copy_s,
            "naive_decisions_equal": float((naive_decision == floats.decision.ravel()[pick]
                                            ).mean()),
            "naive_mass_max_diff": float(np.abs(naive_pg - after[pick]).max())}


def replay(sim: Path, config_path: Path) -> dict:
    """The fused step alone over the log's own frames, back to back: every scan's inputs
    (pose, window, sensor grid, labels) prepared first, then one step per frame as the run
    takes them (the window moving with the vehicle, a new scan each frame, the state
    growing), with nothing in between to evict the state from the caches. Median and 90th
    percentile over frames REPLAY_FROM on (the first frames hold few non-vacuous cells), for
    both output kinds."""
    pipeline = sim_pipeline(sim, config_path)
    inputs = [prepared for _, prepared in pipeline.inputs(-1)]
    shape = inputs[0].window.shape
    result = {"frames": len(inputs), "from": REPLAY_FROM}
    for threads in (1, 2):
        for name, out in (("float", FusedOutputs.empty(shape)),
                          ("stored", StoredOutputs.empty(shape))):
            state = FusionState()
            times = []
            for frame in inputs:
                shift = state.move_to(frame.window)
                t0 = time.perf_counter()
                fused_step(state.pg, state.zeta, frame.free, frame.occupied, frame.labels,
                           pipeline.betas, 0.1, pipeline.params, out=out, flags=state.flags,
                           focal=state.focal, offset=state.offset, shift=shift,
                           threads=threads,
                           gate=open_gate(frame.window.shape, pipeline.params))
                times.append(time.perf_counter() - t0)
            late = np.array(times[REPLAY_FROM:])
            result[f"{name}_median_s_{threads}"] = float(np.median(late))
            result[f"{name}_p90_s_{threads}"] = float(np.percentile(late, 90))
    result["non_vacuous"] = float((state.flags == 0).mean())
    return result


# --- the table ---------------------------------------------------------------------------

def _fps(ms: float) -> str:
    return f"{1e3 / ms:,.0f}" if ms > 0 else "—"


def machine() -> dict:
    load_avg = os.getloadavg()
    with open("/proc/meminfo") as f:
        mem_gb = int(f.readline().split()[1]) / 2**20
    model = next((line.split(":", 1)[1].strip()
                  for line in Path("/proc/cpuinfo").read_text().splitlines()
                  if line.startswith("model name")), "?")
    return {"cpu": model, "cores": os.cpu_count(), "ram_gb": round(mem_gb, 1),
            "load_1min": round(load_avg[0], 2)}


def collect() -> dict:
    """Every measurement, as a dict (also written to bench-out/bench_run.json)."""
    CACHE.mkdir(exist_ok=True)
    before = machine()
    sim_a = simulate("sim-hdl64-10s", "hdl64", 10)
    sim_a_long = simulate("sim-hdl64-30s", "hdl64", 30)
    sim_b = simulate("sim-ibeo4-20s", "ibeo4", 20)
    sim_c = simulate("sim-ibeo4-100s", "ibeo4", 100)
    long_c = loop_log(sim_c, LOOPS)
    w200 = config_file("window200", WINDOW_200)
    w200_chunk10 = config_file("window200-chunk10", WINDOW_200 + "[output]\nchunk_frames = 10\n")
    runs_dir = CACHE / "runs"
    results = {
        "a": best_run(sim_a, runs_dir / "a", w200),
        "a_long": best_run(sim_a_long, runs_dir / "a-long", w200),
        "a_chunk10": run_evperc(sim_a, runs_dir / "a-chunk10", w200_chunk10),
        "a_malloc": run_evperc(sim_a, runs_dir / "a-malloc", w200, env=GLIBC_DEFAULTS),
        "b": best_run(sim_b, runs_dir / "b"),
        "c_short": run_evperc(sim_c, runs_dir / "c-short"),
        "c_long": run_evperc(long_c, runs_dir / "c-long"),
    }
    cold, warm = numba_startup(sim_b)
    inproc = in_process(sim_a, w200, runs_dir / "a")
    inproc["replay"] = replay(sim_a, w200)
    shutil.rmtree(runs_dir / "c-long", ignore_errors=True)  # ~1.3 GB of frames
    shutil.rmtree(runs_dir / "a-long", ignore_errors=True)
    after = machine()
    return {"machine_before": before, "machine_after": after, "quick": QUICK, "loops": LOOPS,
            "runs": results, "numba_cold_s": cold, "numba_warm_s": warm, "in_process": inproc}


def rows_from(data: dict) -> list[dict]:
    r, ip = data["runs"], data["in_process"]
    cols = {"a": "(a) hdl64 200 m", "b": "(b) ibeo4 100 m", "c_short": "(c) 1k frames",
            "c_long": f"(c) {data['loops']}k frames"}
    rows = []
    for key, label in STAGES:
        row = {"measure": f"{label}: frames/s (ms)"}
        for run_key, col in cols.items():
            ms = r[run_key]["stage_ms_per_frame"].get(key, 0.0)
            row[col] = f"{_fps(ms)} ({ms:.2f})"
        rows.append(row)
    whole = {"measure": "whole evperc run: frames/s"}
    rss = {"measure": "peak RSS MB (VmHWM of the child; RSS polled: max)"}
    out = {"measure": "output bytes/frame"}
    cores = {"measure": "cores busy (cpu s / wall s)"}
    kernel = {"measure": "kernel (sys) CPU ms/frame; minor page faults/frame"}
    threads = {"measure": "CPU ms/frame of the frame loop: main / decode / writer thread"}
    start_up = {"measure": "start-up before the first frame, s (map, kernels, the log's "
                           "geo-reference from its GNSS fixes)"}
    for run_key, col in cols.items():
        run = r[run_key]
        whole[col] = f"{run['frames_per_s']:.1f}"
        start_up[col] = f"{run.get('start_up_s', float('nan')):.2f}"
        if "all_frames_per_s" in run:
            whole[col] += f" (runs: {all_runs(run)})"
        rss[col] = f"{run['peak_rss_mb']:.0f} ({max(run['rss_mb_samples'], default=0):.0f})"
        out[col] = f"{run['bytes_per_frame'] / 1e3:,.0f} kB"
        cores[col] = f"{run['cpu_s'] / run['wall_s']:.2f}"
        kernel[col] = (f"{1e3 * run['sys_s'] / run['frames']:.1f}; "
                       f"{run['minor_faults'] / run['frames']:,.0f}")
        threads[col] = thread_cpu(run)
    rows += [whole, start_up, rss, out, cores, kernel, threads]
    long_rss = r["c_long"]["peak_rss_mb"] / r["c_short"]["peak_rss_mb"]
    rows.append({"measure": "peak RSS, (c) long / 1k", cols["c_long"]: f"{long_rss:.3f}"})
    a_long = r["a_long"]
    rows.append({"measure": "(a) on a 30 s log (300 scans): whole run",
                 cols["a"]: f"{a_long['frames_per_s']:.1f} frames/s (runs: "
                            f"{all_runs(a_long)}); "
                            f"CPU ms/frame main / decode / writer {thread_cpu(a_long)}; "
                            f"{a_long['peak_rss_mb']:.0f} MB peak"})
    rows.append({"measure": "(a) with output.chunk_frames = 10",
                 cols["a"]: f"{r['a_chunk10']['frames_per_s']:.1f} frames/s, "
                            f"{r['a_chunk10']['peak_rss_mb']:.0f} MB peak, "
                            f"{r['a_chunk10']['bytes_per_frame'] / 1e3:,.0f} kB/frame"})
    m = r["a_malloc"]
    rows.append({"measure": "(a) with glibc's malloc thresholds (keep_freed_memory off)",
                 cols["a"]: f"{m['frames_per_s']:.1f} frames/s, sys "
                            f"{1e3 * m['sys_s'] / m['frames']:.1f} ms/frame, "
                            f"{m['minor_faults'] / m['frames']:,.0f} faults/frame, CPU "
                            f"ms/frame main / decode / writer {thread_cpu(m)}"})
    cells = f"{ip['cells']:,} cells"
    rows.append({"measure": f"in-process sensor grid, {ip['points']:,} points: ms",
                 cols["a"]: f"ours {ip['ours_sensor_s'] * 1e3:.2f}, naive per-point Python "
                            f"{ip['naive_sensor_s'] * 1e3:,.0f} (whole scan): "
                            f"{ip['naive_sensor_s'] / ip['ours_sensor_s']:,.0f}x",
                 "note": f"same cells: {ip['sensor_agreement']:.4f}"})
    rows.append({"measure": f"in-process fusion + decision + scroll, {cells}: ms",
                 cols["a"]: f"ours {ip['ours_fusion_s'] * 1e3:.2f} "
                            f"({1 / ip['ours_fusion_s']:.0f} frames/s; median of "
                            f"{FUSION_FRAMES} frames {ip['median_fusion_s'] * 1e3:.2f} ms = "
                            f"{1 / ip['median_fusion_s']:.0f}/s), naive dense pair loops "
                            f"{ip['naive_fusion_s'] * 1e3:,.0f} ({NAIVE_CELLS:,} cells, scaled): "
                            f"{ip['naive_fusion_s'] / ip['ours_fusion_s']:,.0f}x",
                 "note": f"naive decisions equal: {ip['naive_decisions_equal']:.4f}, masses "
                         f"within {ip['naive_mass_max_diff']:.1e}"})
    rows.append({"measure": f"in-process pieces, {cells}: ms",
                 cols["a"]: f"same step writing the uint8 layers as stored (the run's kernel) "
                            f"{ip['ours_stored_s'] * 1e3:.2f} "
                            f"({1 / ip['ours_stored_s']:.0f} frames/s; median "
                            f"{ip['median_stored_s'] * 1e3:.2f}); the general kernel "
                            f"(any options) {ip['general_stored_s'] * 1e3:.2f} (median "
                            f"{ip['general_median_stored_s'] * 1e3:.2f}); state copy (20 MB) "
                            f"{ip['state_copy_s'] * 1e3:.2f}"})
    rp = ip["replay"]
    for threads in (1, 2):
        rows.append({"measure": f"fused step alone over the log's frames {rp['from']}–"
                                f"{rp['frames'] - 1}, back to back, {cells}, {threads} "
                                f"thread{'s' if threads > 1 else ''}: ms",
                     cols["a"]: "; ".join(
                         f"{name} median {rp[f'{name}_median_s_{threads}'] * 1e3:.2f} "
                         f"({1 / rp[f'{name}_median_s_{threads}']:.0f} frames/s), 90 % "
                         f"{rp[f'{name}_p90_s_{threads}'] * 1e3:.2f}"
                         for name in ("float", "stored")),
                     "note": f"{rp['non_vacuous']:.0%} of the cells non-vacuous at the end"})
    naive_frame = ip["naive_sensor_s"] + ip["naive_fusion_s"]
    rows.append({"measure": "whole frame: naive (sensor + fusion) s vs our run",
                 cols["a"]: f"naive {naive_frame:.2f} s/frame; ours "
                            f"{1 / r['a']['frames_per_s']:.3f} s/frame: "
                            f"{naive_frame * r['a']['frames_per_s']:,.0f}x"})
    err = ip["max_abs_error"]
    rows.append({"measure": f"stored vs in-memory float32, {ip['precision_frames']} frames of (a)",
                 cols["a"]: f"decisions equal {ip['decisions_equal']:.6f}; max |error| masses "
                            f"{err['masses']:.5f}, betP {err['betp']:.5f}, zeta "
                            f"{err['zeta']:.5f} (1/255 = {1 / 255:.5f})"})
    rows.append({"measure": "numba start-up: 1 s of (b), empty cache vs filled (wall s)",
                 cols["b"]: f"{data['numba_cold_s']:.2f} vs {data['numba_warm_s']:.2f}: "
                            f"compile {data['numba_cold_s'] - data['numba_warm_s']:.2f} s"})
    mb, ma = data["machine_before"], data["machine_after"]
    rows.append({"measure": "machine", "note": f"{mb['cpu']}, {mb['cores']} cores, "
                 f"{mb['ram_gb']} GB; load avg (1 min) {mb['load_1min']} before, "
                 f"{ma['load_1min']} after"})
    return rows


def run() -> list[dict]:
    data = collect()
    (CACHE / "bench_run.json").write_text(json.dumps(data, indent=1))
    return rows_from(data)


if __name__ == "__main__":
    from run import print_table

    t_start = time.perf_counter()
    print_table(f"run ({'quick' if QUICK else 'full'})", run())
    print(f"\n({time.perf_counter() - t_start:.0f} s; raw figures in {CACHE / 'bench_run.json'})")
