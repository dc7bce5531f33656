"""`evperc batch` on a LocalCluster of 2 workers (started once for the module): outputs equal
to direct `evperc.runner.run` calls, a broken log reported without stopping the others,
complete outputs skipped, interrupted ones resumed to the same result."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import evperc
from evperc.batch import BatchRequest, open_client, run_batch
from evperc.cli import cli
from evperc.config import load_config
from evperc.runner import RunRequest, run
from tests.batch.logs import write_street_log

N_SCANS = 6
CONFIG_TOML = "[grid]\nwindow_size_m = 20.0\n[output]\nchunk_frames = 2\ncheckpoint_frames = 1\n"


@pytest.fixture(scope="module")
def client():
    with open_client(workers=2) as dask_client:
        yield dask_client


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict:
    """Three logs (two share the stem ``drive``), the config file and its dict."""
    root = tmp_path_factory.mktemp("inputs")
    for sub in ("d1", "d2"):
        (root / sub).mkdir()
    logs = [write_street_log(root / "d1" / "drive.mcap", N_SCANS, seed=1),
            write_street_log(root / "d2" / "drive.mcap", N_SCANS, seed=2),
            write_street_log(root / "street.mcap", N_SCANS, seed=3)]
    config_path = root / "small.toml"
    config_path.write_text(CONFIG_TOML)
    return {"root": root, "logs": logs, "config_path": config_path,
            "config": load_config(config_path)}


@pytest.fixture(scope="module")
def direct(inputs, tmp_path_factory) -> dict[str, Path]:
    """Each log run in this process with the library call, the reference outputs."""
    out = tmp_path_factory.mktemp("direct")
    dirs = {}
    for log_path, name in zip(inputs["logs"], ("drive--d1", "drive--d2", "street"),
                              strict=True):
        run(RunRequest(log_path=log_path, out_dir=out / name, config=inputs["config"]))
        dirs[name] = out / name
    return dirs


def assert_same_frames(batch_dir: Path, direct_dir: Path) -> None:
    a, b = evperc.load(batch_dir), evperc.load(direct_dir)
    assert len(a) == len(b) == N_SCANS
    for fa, fb in zip(a.frames, b.frames, strict=True):
        assert fa.stamp_ns == fb.stamp_ns and fa.origin == fb.origin
        np.testing.assert_array_equal(fa.decision, fb.decision)
        np.testing.assert_array_equal(fa.masses, fb.masses)
        np.testing.assert_array_equal(fa.zeta, fb.zeta)


def request_for(inputs: dict, out_root: Path, logs=None) -> BatchRequest:
    return BatchRequest(logs=tuple(inputs["logs"] if logs is None else logs), out_root=out_root,
                        config=inputs["config"])


def test_batch_equals_direct_runs_then_rerun_skips(client, inputs, direct, tmp_path):
    rows = run_batch(request_for(inputs, tmp_path / "root"), client=client, progress=False)
    assert [r["status"] for r in rows] == ["ok", "ok", "ok"], rows  # a failed row says why
    assert [r["frames"] for r in rows] == [N_SCANS] * 3
    assert [r["error"] for r in rows] == [None] * 3
    assert [Path(r["out"]).name for r in rows] == ["drive--d1", "drive--d2", "street"]
    for name, direct_dir in direct.items():
        assert_same_frames(tmp_path / "root" / name, direct_dir)
    # the three runs really differ (the comparison above could not pass by accident)
    first = [next(evperc.load(d).frames).decision for d in direct.values()]
    assert not np.array_equal(first[0], first[1]) or not np.array_equal(first[0], first[2])

    stamps = {p: p.stat().st_mtime_ns for p in (tmp_path / "root").rglob("*") if p.is_file()}
    again = run_batch(request_for(inputs, tmp_path / "root"), client=client, progress=False)
    assert [r["status"] for r in again] == ["skipped"] * 3
    assert [r["frames"] for r in again] == [N_SCANS] * 3
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps  # nothing rewritten


def test_broken_log_fails_alone_exit_code_1(client, inputs, direct, tmp_path):
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(np.random.default_rng(0).bytes(4096))
    listing = tmp_path / "logs.txt"
    listing.write_text(f"# two good logs and a broken one\n{inputs['logs'][2]}\n\n"
                       "garbage.mcap  # relative to this file\n")
    rows_path = tmp_path / "rows.json"
    result = CliRunner().invoke(cli, [
        "batch", str(inputs["logs"][0]), "--list", str(listing), "--no-map",
        "--out", str(tmp_path / "root"), "--config", str(inputs["config_path"]),
        "--scheduler", client.scheduler.address, "--json", str(rows_path)])
    assert result.exit_code == 1, result.output
    rows = {Path(r["log"]).name: r for r in json.loads(rows_path.read_text())}
    assert set(rows) == {"drive.mcap", "street.mcap", "garbage.mcap"}
    assert rows["garbage.mcap"]["status"] == "failed"
    message = rows["garbage.mcap"]["error"]
    assert "garbage.mcap" in message and "\n" not in message and "Traceback" not in message
    assert rows["drive.mcap"]["status"] == rows["street.mcap"]["status"] == "ok"
    assert "Traceback" not in result.output
    table = result.stdout.splitlines()
    assert table[0].split() == ["log", "frames", "frames/s", "status", "poses", "preset",
                                "error"]
    assert rows["garbage.mcap"]["poses"] is None  # failed: no run, no pose check
    # the sample's 4-layer lidar takes no preset (a 64-layer one: tests/logs/test_kitti_folder.py)
    assert rows["drive.mcap"]["preset"] is None and rows["garbage.mcap"]["preset"] is None
    assert any(line.startswith("garbage.mcap") and " failed " in line for line in table)
    assert_same_frames(tmp_path / "root" / "drive", direct["drive--d1"])
    assert_same_frames(tmp_path / "root" / "street", direct["street"])


class _Interrupt(Exception):
    pass


def test_interrupted_output_is_resumed_identically(client, inputs, direct, tmp_path):
    log_path = inputs["logs"][2]
    out_dir = tmp_path / "root" / "street"

    def stop_at_fifth_frame(frame: dict) -> None:
        stop_at_fifth_frame.count += 1
        if stop_at_fifth_frame.count == 5:
            raise _Interrupt

    stop_at_fifth_frame.count = 0
    with pytest.raises(_Interrupt):
        run(RunRequest(log_path=log_path, out_dir=out_dir, config=inputs["config"]),
            on_frame=stop_at_fifth_frame)
    manifest = json.loads((out_dir / "manifest.json").read_text())
    assert manifest["complete"] is False and manifest["frame_count"] == 4
    assert (out_dir / "checkpoint_000000004.npz").is_file()

    rows = run_batch(request_for(inputs, tmp_path / "root", [log_path]), client=client,
                     progress=False)
    assert [(r["status"], r["frames"]) for r in rows] == [("resumed", N_SCANS)]
    assert_same_frames(out_dir, direct["street"])
    assert not list(out_dir.glob("checkpoint_*.npz"))


def test_output_of_other_config_is_neither_skipped_nor_resumed(client, inputs, direct,
                                                               tmp_path):
    out_dir = tmp_path / "root" / "street"
    shutil.copytree(direct["street"], out_dir)
    other = load_config(inputs["config_path"], overrides={"fusion.zeta_increment": 0.2})
    rows = run_batch(BatchRequest(logs=(inputs["logs"][2],), out_root=tmp_path / "root",
                                  config=other), client=client, progress=False)
    assert rows[0]["status"] == "failed"
    assert "another config" in rows[0]["error"] and str(out_dir) in rows[0]["error"]


def test_usage_errors_exit_2(tmp_path):
    runner = CliRunner()
    no_map_flag = runner.invoke(cli, ["batch", "a.mcap", "--out", str(tmp_path)])
    assert no_map_flag.exit_code == 2 and "--no-map" in no_map_flag.output
    both = runner.invoke(cli, ["batch", "a.mcap", "--no-map", "--out", str(tmp_path),
                               "--workers", "2", "--scheduler", "tcp://127.0.0.1:8786"])
    assert both.exit_code == 2 and "--workers" in both.output
    nothing = runner.invoke(cli, ["batch", "--no-map", "--out", str(tmp_path)])
    assert nothing.exit_code == 2 and "no logs" in nothing.output


def test_cli_starts_its_own_local_cluster(inputs, direct, tmp_path):
    result = CliRunner().invoke(cli, [
        "batch", str(inputs["logs"][2]), "--no-map", "--out", str(tmp_path / "root"),
        "--config", str(inputs["config_path"]), "--workers", "1"])
    assert result.exit_code == 0, result.output
    cells = result.stdout.splitlines()[1].split()
    assert cells[:2] == ["street.mcap", str(N_SCANS)] and cells[3] == "ok"
    assert_same_frames(tmp_path / "root" / "street", direct["street"])
