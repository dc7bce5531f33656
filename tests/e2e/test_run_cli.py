"""`evperc run` end to end on a synthetic street drive: output, loading, resume, errors."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import evperc
from evperc.cli import cli
from evperc.config import load_config
from evperc.fusion.twin import DECISION_CODES
from evperc.runner import RunRequest, run

from .scenes import write_street_drive

SMALL = "[grid]\nwindow_size_m = 40.0\n[output]\nchunk_frames = 10\ncheckpoint_frames = 20\n"


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_street_drive(tmp_path_factory.mktemp("drive") / "street.mcap", n_scans=40)


@pytest.fixture()
def small_config(tmp_path: Path) -> Path:
    path = tmp_path / "small.toml"
    path.write_text(SMALL)
    return path


def invoke(*args: str) -> object:
    return CliRunner().invoke(cli, list(args))


def test_run_writes_a_complete_loadable_output(drive: Path, small_config: Path,
                                               tmp_path: Path) -> None:
    out = tmp_path / "out"
    result = invoke("run", str(drive), "--no-map", "--config", str(small_config),
                    "--out", str(out))
    assert result.exit_code == 0, result.output
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["complete"] is True
    assert manifest["frame_count"] == 40
    assert manifest["decision_codes"]["moving"] == 2
    # CPU of the three threads over the frame loop, per frame, and of any other thread
    cpu = manifest["summary"]["cpu_ms_per_frame"]
    assert set(cpu) == {"main", "decode", "writer", "other"}
    assert all(cpu[k] > 0 for k in ("main", "decode", "writer")) and cpu["other"] >= 0
    assert manifest["summary"]["fusion_threads"] >= 1
    assert 0 < manifest["summary"]["start_up_s"] < 60
    stages = manifest["summary"]["stage_ms_per_frame"]
    assert {"decode", "sensor", "fusion", "read", "writer_thread"} <= set(stages)
    assert all(v >= 0 for v in stages.values()) and stages["decode"] > 0
    # the main thread's stages in CPU time: its laps cover the frame loop, so they add up
    # to the thread's CPU over it (rounded to 1 µs a stage; the loop's set-up is not lapped)
    stage_cpu = manifest["summary"]["stage_cpu_ms_per_frame"]
    assert {"fusion", "read", "write"} <= set(stage_cpu) <= set(stages)
    assert all(v >= 0 for v in stage_cpu.values())
    assert 0.9 * cpu["main"] <= sum(stage_cpu.values()) <= cpu["main"] + 0.01
    assert (out / "config.toml").read_text().count("window_size_m = 40.0") == 1
    run_ = evperc.load(out)
    frames = list(run_.frames)
    assert len(frames) == 40
    # the walls at y = ±6 m are static, the street between them free
    last = frames[-1]
    x, y = last.window.cell_centres()
    wall_row = int(np.argmin(np.abs(y - 6.25)))
    near = np.abs(x - last.pose[0]) < 8
    assert np.mean(last.decision[wall_row, near] == DECISION_CODES["static"]) > 0.7
    street_row = int(np.argmin(np.abs(y - 0.25)))
    ahead = (x > last.pose[0] + 2) & (x < last.pose[0] + 10)
    assert np.mean(last.decision[street_row, ahead] == DECISION_CODES["free"]) > 0.9
    # the crossing car was decided moving somewhere at some frame
    assert any((f.decision == DECISION_CODES["moving"]).sum() >= 2 for f in frames)
    assert np.all(np.abs(last.masses.sum(axis=-1) - 1) < 0.02)


def test_default_out_dir_and_refusal_to_overwrite(drive: Path, small_config: Path,
                                                  tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    args = ["run", str(drive), "--no-map", "--config", str(small_config), "--end", "0.5"]
    assert invoke(*args).exit_code == 0
    assert (tmp_path / "evperc-out" / "street" / "manifest.json").is_file()
    again = invoke(*args)
    assert again.exit_code == 2
    assert "--overwrite" in again.output
    assert again.output.count("\n") == 1
    assert invoke(*args, "--overwrite").exit_code == 0


def test_usage_errors_are_one_line(drive: Path, tmp_path: Path) -> None:
    for args, needle in [
        (["run", str(drive)], "--no-map"),
        (["run", str(drive), "--no-map", "--map", "x.geojson"], "exclude"),
        (["run", str(tmp_path / "missing.mcap"), "--no-map", "--out", str(tmp_path / "o")],
         "missing.mcap"),
        (["run", "--resume", str(tmp_path)], "manifest"),
    ]:
        result = invoke(*args)
        assert result.exit_code == 2, (args, result.output)
        assert needle in result.output
        assert result.output.startswith("evperc: error: ")
        assert result.output.count("\n") == 1
        assert "Traceback" not in result.output


def _all_frames(out: Path) -> list:
    return list(evperc.load(out).frames)


@pytest.mark.parametrize(("checkpoint_frames", "stop_at", "committed", "on_disk", "lag"),
                         [(1, 25, 20, 2, 6), (15, 38, 20, 3, 6), (1, 25, 20, 2, 12),
                          (1, 25, 20, 2, 0)])
def test_interrupted_run_resumes_identically(drive: Path, tmp_path: Path, checkpoint_frames: int,
                                             stop_at: int, committed: int, on_disk: int,
                                             lag: int) -> None:
    """Chunks of 10 frames; a checkpoint at the first chunk end >= checkpoint_frames frames
    after the last: with 15, at frame 20 but not 30; the chunk of frames 20-29 is on disk,
    not in the manifest, and is redone by the resume. ``lag``: objects.backfill_frames (the
    frames reach the writer, and ``on_frame``, that many frames after they were fused; 12:
    longer than a chunk, so two chunk ends' states are held at once; 0: the causal run)."""
    config = load_config(overrides={"grid.window_size_m": 40.0, "output.chunk_frames": 10,
                                    "output.checkpoint_frames": checkpoint_frames,
                                    "objects.backfill_frames": lag})
    full = tmp_path / "full"
    run(RunRequest(log_path=drive, out_dir=full, config=config, map_path=None))

    part = tmp_path / "part"
    seen = []

    def stop(frame: dict) -> None:
        seen.append(frame["stamp_ns"])
        if len(seen) == stop_at:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run(RunRequest(log_path=drive, out_dir=part, config=config, map_path=None),
            on_frame=stop)
    manifest = json.loads((part / "manifest.json").read_text())
    assert manifest["complete"] is False
    assert manifest["frame_count"] == committed
    assert sum(c["frame_count"] for c in manifest["chunks"]) == committed
    assert len(list((part / "frames").glob("chunk_*.npz"))) == on_disk
    names = sorted(p.name for p in part.glob("checkpoint_*.npz"))
    assert names[-1] == f"checkpoint_{committed:09d}.npz", names  # (and the one before)
    result = invoke("run", "--resume", str(part))
    assert result.exit_code == 0, result.output
    a, b = _all_frames(full), _all_frames(part)
    assert [f.stamp_ns for f in a] == [f.stamp_ns for f in b]
    for fa, fb in zip(a, b, strict=True):
        np.testing.assert_array_equal(fa.decision, fb.decision)
        np.testing.assert_array_equal(fa.masses, fb.masses)
        np.testing.assert_array_equal(fa.zeta, fb.zeta)
        assert fa.objects.tobytes() == fb.objects.tobytes()  # the tracker resumed exactly
        np.testing.assert_array_equal(fa.object_cells, fb.object_cells)
    assert sum(len(f.objects) for f in a) > 0  # the crossing car was reported
    assert not list(part.glob("checkpoint_*.npz"))


def test_killed_process_resumes_identically(tmp_path: Path) -> None:
    """SIGKILL a real `evperc run` process part-way, then `--resume` it."""
    drive = write_street_drive(tmp_path / "long.mcap", n_scans=150, beams=360)
    config = tmp_path / "c.toml"
    config.write_text(SMALL)
    full, part = tmp_path / "full", tmp_path / "part"
    base = [sys.executable, "-m", "evperc", "-q", "run", str(drive), "--no-map", "--config",
            str(config), "--out"]
    subprocess.run([*base, str(full)], check=True, timeout=300)
    proc = subprocess.Popen([*base, str(part)], stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    manifest = part / "manifest.json"
    while time.monotonic() < deadline:
        if manifest.exists() and json.loads(manifest.read_text() or "{}").get(
                "frame_count", 0) >= 30:
            break
        time.sleep(0.005)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    state = json.loads(manifest.read_text())
    assert state["complete"] is False, "the run finished before it could be killed"
    subprocess.run([sys.executable, "-m", "evperc", "-q", "run", "--resume", str(part)],
                   check=True, timeout=300)
    a, b = _all_frames(full), _all_frames(part)
    assert len(a) == len(b) == 150
    for fa, fb in zip(a, b, strict=True):
        np.testing.assert_array_equal(fa.decision, fb.decision)
        np.testing.assert_array_equal(fa.masses, fb.masses)


def test_run_renders_as_it_goes(drive: Path, small_config: Path, tmp_path: Path) -> None:
    import imageio.v3 as iio

    out, png = tmp_path / "out", tmp_path / "png"
    result = invoke("run", str(drive), "--no-map", "--config", str(small_config), "--out",
                    str(out), "--end", "1.0", "--render", str(png))
    assert result.exit_code == 0, result.output
    pictures = sorted(png.glob("frame_*.png"))
    assert len(pictures) == len(evperc.load(out)) == 10
    image = iio.imread(pictures[-1])
    assert image.ndim == 3 and image.shape[2] == 3
    # the free street is drawn green somewhere in the decision panel
    green = (image[..., 1] > 200) & (image[..., 0] < 80) & (image[..., 2] < 80)
    assert green.sum() > 100


def test_chunks_count_each_frames_decisions(drive: Path, small_config: Path,
                                            tmp_path: Path) -> None:
    out = tmp_path / "out"
    assert invoke("run", str(drive), "--no-map", "--config", str(small_config), "--out",
                  str(out), "--end", "1.0").exit_code == 0
    manifest = json.loads((out / "manifest.json").read_text())
    frames = _all_frames(out)
    assert len(frames) == 10
    assert manifest["first_stamp_ns"] == frames[0].stamp_ns
    for frame in frames:
        want = np.bincount(frame.decision.ravel(), minlength=7)
        np.testing.assert_array_equal(frame.decision_counts, want)


def test_the_thread_that_computes_a_sensor_grid_does_not_change_the_output(
        drive: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The decode thread leaves a scan's sensor grid to the fusion thread when that one has
    no scan waiting (Pipeline.inputs, ``defer``); which thread computes it is timing, and
    must not show in the output: every grid in the decode thread and every grid in the
    fusion thread give identical frames."""
    from evperc.runner import Pipeline

    prepare = Pipeline.prepare
    outputs = {}
    for in_fusion in (False, True):
        monkeypatch.setattr(Pipeline, "prepare", lambda self, scan, sensor=True,
                            _fusion=in_fusion: prepare(self, scan, sensor=not _fusion))
        config = load_config(overrides={"grid.window_size_m": 40.0})
        out = tmp_path / f"fusion-{in_fusion}"
        summary = run(RunRequest(log_path=drive, out_dir=out, config=config), progress=False)
        assert summary["sensor_grids_in_fusion_thread"] == (40 if in_fusion else 0)
        outputs[in_fusion] = _all_frames(out)
    for a, b in zip(outputs[False], outputs[True], strict=True):
        np.testing.assert_array_equal(a.masses, b.masses)
        np.testing.assert_array_equal(a.decision, b.decision)
        np.testing.assert_array_equal(a.zeta, b.zeta)


def test_fusion_threads_do_not_change_the_output(drive: Path, tmp_path: Path) -> None:
    """fusion.threads shares the fused step's rows among threads (evperc.fusion.fused, chunks of
    16 rows; this 40 m window has 80): 1, 2 and 3 threads write the same frames, and the
    summary says how many ran (0, the default, resolves to at least one)."""
    frames = {}
    for threads in (1, 2, 3, 0):
        config = load_config(overrides={"grid.window_size_m": 40.0, "fusion.threads": threads})
        out = tmp_path / f"threads-{threads}"
        summary = run(RunRequest(log_path=drive, out_dir=out, config=config), progress=False)
        assert summary["fusion_threads"] == threads or (threads == 0
                                                        and summary["fusion_threads"] >= 1)
        frames[threads] = _all_frames(out)
    for threads in (2, 3, 0):
        for a, b in zip(frames[1], frames[threads], strict=True):
            for layer in ("masses", "betp", "conflict", "zeta", "decision"):
                np.testing.assert_array_equal(getattr(a, layer), getattr(b, layer))


@pytest.mark.parametrize(("configured", "cores", "threads"),
                         [(0, 1, 1), (0, 2, 1), (0, 3, 1), (0, 8, 6), (3, 2, 3), (1, 8, 1)])
def test_fusion_threads_auto_leaves_two_cores(configured: int, cores: int, threads: int,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """fusion.threads = 0: the cores the process may use less the decode and writer
    threads' two (on two cores a second fusion thread made the run slower:
    docs/performance.md); a configured number is kept."""
    from evperc import plumbing

    monkeypatch.setattr(plumbing.os, "sched_getaffinity", lambda pid: set(range(cores)),
                        raising=False)
    assert plumbing.fusion_threads(configured) == threads


def test_warm_up_pays_the_first_frames_one_off_costs_and_changes_nothing(
        tmp_path: Path) -> None:
    """Pipeline.warm_up_inputs (called by run before its clock starts) opens the log's
    decoders and rasterises the map tiles around the first pose; the scans prepared after it
    are those of a pipeline without it."""
    from evperc.runner import Pipeline

    root = Path(__file__).resolve().parents[2] / "sample_data"
    request = RunRequest(log_path=root / "drive.mcap", out_dir=tmp_path / "unused",
                         config=load_config(), map_path=root / "map.geojson")
    warm, cold = Pipeline(request), Pipeline(request)
    warm.warm_up_inputs()
    assert warm.rasteriser.stats["tiles_rasterised"] > 0
    assert warm.reader.source._decoders
    assert cold.rasteriser.stats["tiles_rasterised"] == 0
    warm_inputs, cold_inputs = warm.inputs(-1), cold.inputs(-1)
    for _ in range(3):
        (i, a), (j, b) = next(warm_inputs), next(cold_inputs)
        assert i == j
        for name in ("free", "occupied", "labels", "pose"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    hits = warm.rasteriser.stats["tile_hits"]
    assert hits > 0  # the first frame found its tiles ready


def test_warm_up_loads_every_kernel_the_frame_loop_calls(tmp_path: Path,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """Pipeline._warm_up (before the run's clock starts) calls each compiled pass with the
    argument types of the frame loop, so no frame loads or compiles a kernel: no numba
    function of evperc gains a signature during the run. A pass called with another array
    layout (e.g. a strided column) than in the warm-up compiles a second version on the first
    frame that meets it — 7 ms charged to the object stage of workload (a)'s first frame."""
    import sys

    from numba.core.registry import CPUDispatcher

    from evperc.runner import Pipeline

    def signatures() -> dict[str, int]:
        return {f"{name}.{attr}": len(value.signatures)
                for name, module in list(sys.modules.items()) if name.startswith("evperc")
                for attr, value in vars(module).items() if isinstance(value, CPUDispatcher)}

    after_warm_up: dict[str, int] = {}
    warm_up = Pipeline._warm_up

    def recording_warm_up(self: Pipeline) -> None:
        warm_up(self)
        after_warm_up.update(signatures())

    monkeypatch.setattr(Pipeline, "_warm_up", recording_warm_up)
    root = Path(__file__).resolve().parents[2] / "sample_data"
    run(RunRequest(log_path=root / "drive.mcap", out_dir=tmp_path / "out",
                   config=load_config(), map_path=root / "map.geojson", end_s=4.0),
        progress=False)
    assert after_warm_up  # the kernels were listed
    gained = {name: count for name, count in signatures().items()
              if count > after_warm_up.get(name, 0)}
    assert not gained, f"compiled in the frame loop, not in the warm-up: {gained}"


def test_a_decision_that_holds_no_code_names_its_frame_and_where(tmp_path: Path) -> None:
    """A frame's decision layer must hold decision codes only; one that does not (a bug: a
    buffer read before it was written, or written out of bounds) stops the run with the
    frame's stamp, how many cells, their rows and values — what a batch row then reports."""
    from evperc.output.objects import empty_objects as no_objects
    from evperc.runner import FusionState, Pipeline

    root = Path(__file__).resolve().parents[2] / "sample_data"
    pipeline = Pipeline(RunRequest(log_path=root / "drive.mcap", out_dir=tmp_path / "unused",
                                   config=load_config()))
    decision = np.full((4, 6), DECISION_CODES["free"], np.uint8)
    decision[2, 1:3] = 77
    frame = {"stamp_ns": 123, "objects": no_objects(), "object_cells": np.zeros(0, np.uint32),
             "window": None}
    with pytest.raises(ValueError, match=r"the frame stamped 123 ns: decision codes beyond 6: "
                                         r"2 of 24 cells, in rows \[2\] of \(4, 6\), "
                                         r"values \[77, 77\]"):
        pipeline.finish_frame(FusionState(), frame, decision)
