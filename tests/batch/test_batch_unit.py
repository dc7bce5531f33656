"""The parts of `evperc batch` that need no cluster: the log list, output names, and the
worker function's handling of errors, leftovers and foreign outputs."""

from __future__ import annotations

from pathlib import Path

import pytest

from evperc.batch import format_table, output_names, process_log, read_log_list
from evperc.config import load_config
from evperc.errors import UsageError
from evperc.geo import maps
from evperc.runner import RunRequest
from tests.batch.logs import write_street_log

SAMPLE = Path(__file__).parents[2] / "sample_data"


def test_log_list_ignores_comments_and_blank_lines_relative_to_the_list(tmp_path):
    listing = tmp_path / "lists" / "logs.txt"
    listing.parent.mkdir()
    listing.write_text("# drives of monday\n\na.mcap\n  sub/b.mcap   # second\n/abs/c.mcap\n")
    assert read_log_list(listing) == [tmp_path / "lists" / "a.mcap",
                                      tmp_path / "lists" / "sub" / "b.mcap",
                                      Path("/abs/c.mcap")]


def test_missing_log_list_is_a_usage_error(tmp_path):
    with pytest.raises(UsageError, match="logs.txt: cannot read the log list"):
        read_log_list(tmp_path / "logs.txt")


def test_output_names_dedupe_shared_stems_by_parent_folder():
    logs = [Path("/data/mon/drive.mcap"), Path("/data/tue/drive.mcap"), Path("/data/x.mcap")]
    assert output_names(logs) == ["drive--mon", "drive--tue", "x"]
    # independent of order
    assert output_names(logs[::-1]) == ["x", "drive--tue", "drive--mon"]
    # same parent name: go one folder further up
    deeper = [Path("/a/day/drive.mcap"), Path("/b/day/drive.mcap")]
    assert output_names(deeper) == ["drive--a-day", "drive--b-day"]
    # same folder, same stem, other extension: the file name tells them apart
    twins = [Path("/a/drive.mcap"), Path("/a/drive.bag")]
    assert output_names(twins) == ["drive.mcap--a", "drive.bag--a"]


def test_output_name_collision_is_a_usage_error():
    with pytest.raises(UsageError, match="both would write ROOT/drive--mon"):
        output_names([Path("/d/mon/drive.mcap"), Path("/d/tue/drive.mcap"),
                      Path("/d/drive--mon.mcap")])


def test_unexpected_exception_becomes_an_error_row(tmp_path):
    log_path = write_street_log(tmp_path / "a.mcap", 2)
    row = process_log(RunRequest(log_path=log_path, out_dir=tmp_path / "out", config={}))
    assert row["status"] == "error"
    assert row["error"].startswith("KeyError: ")
    assert row["frames"] is None and row["wall_time_s"] >= 0


def test_leftovers_of_a_run_killed_before_its_manifest_are_cleared(tmp_path):
    log_path = write_street_log(tmp_path / "a.mcap", 2)
    out = tmp_path / "out"
    (out / "frames").mkdir(parents=True)
    (out / "config.toml").write_text("half")
    (out / ".manifest.json.tmp").write_text("{")
    config = load_config(overrides={"grid.window_size_m": 10.0})
    row = process_log(RunRequest(log_path=log_path, out_dir=out, config=config))
    assert (row["status"], row["frames"]) == ("ok", 2)


def test_foreign_folder_is_not_touched(tmp_path):
    log_path = write_street_log(tmp_path / "a.mcap", 2)
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    row = process_log(RunRequest(log_path=log_path, out_dir=out, config=load_config()))
    assert row["status"] == "failed" and "not an evperc output" in row["error"]
    assert (out / "notes.txt").read_text() == "mine"


def test_table_lists_every_log_with_dashes_for_missing_numbers():
    rows = [{"log": "/x/a.mcap", "frames": 30, "frames_per_s": 7.123, "status": "ok",
             "poses": "fit", "preset": "hdl64", "error": None},
            {"log": "/x/b.mcap", "frames": 16, "frames_per_s": 9.0, "status": "ok",
             "poses": "MISFIT 0.64 m", "preset": None, "error": None},
            {"log": "/x/bad.mcap", "frames": None, "frames_per_s": None, "status": "failed",
             "poses": None, "preset": None, "error": "/x/bad.mcap: no lidar topic"}]
    lines = format_table(rows).splitlines()
    assert lines[0].split() == ["log", "frames", "frames/s", "status", "poses", "preset",
                                "error"]
    assert lines[1].split() == ["a.mcap", "30", "7.1", "ok", "fit", "hdl64"]
    assert lines[2].split() == ["b.mcap", "16", "9.0", "ok", "MISFIT", "0.64", "m", "-"]
    assert lines[3].split()[:6] == ["bad.mcap", "-", "-", "failed", "-", "-"]
    assert lines[3].endswith("/x/bad.mcap: no lidar topic")


def test_a_worker_reads_the_map_once_for_many_logs(tmp_path, monkeypatch):
    """Two logs on one map in the same worker process: the map is read for the first and
    reused for the second (geo.maps.load_map_cached); both runs complete."""
    reads = []
    real = maps.load_map
    monkeypatch.setattr(maps, "_last_map", None)
    monkeypatch.setattr(maps, "load_map", lambda *a, **k: reads.append(a[0]) or real(*a, **k))
    config = load_config()
    rows = [process_log(RunRequest(log_path=SAMPLE / "drive.mcap", out_dir=tmp_path / name,
                                   config=config, map_path=SAMPLE / "map.geojson", end_s=0.5))
            for name in ("first", "second")]
    assert [row["status"] for row in rows] == ["ok", "ok"], rows
    assert rows[0]["frames"] == rows[1]["frames"] > 0
    assert len(reads) == 1


def test_batch_runs_one_fusion_thread_per_log_unless_configured(tmp_path):
    """fusion.threads = 0 (auto) would give every worker process the machine's cores less
    two; the logs of a batch already run side by side, so each gets one fusion thread. A
    configured number is kept, and the thread count is not part of the config compared
    when a batch meets an output it made before (it does not change the output)."""
    from evperc.batch import BatchRequest, _canonical, plan

    logs = (tmp_path / "a.mcap", tmp_path / "b.mcap")
    for threads, want in ((0, 1), (3, 3)):
        config = load_config(overrides={"fusion.threads": threads})
        tasks = plan(BatchRequest(logs=logs, out_root=tmp_path / "out", config=config))
        assert [task.config["fusion"]["threads"] for task in tasks] == [want, want]
    auto, two = load_config(), load_config(overrides={"fusion.threads": 2})
    assert _canonical(auto) == _canonical(two)
    assert _canonical(auto) != _canonical(load_config(overrides={"fusion.zeta_increment": 0.2}))
    del auto["fusion"]["threads"]  # a manifest written before the key existed
    assert _canonical(auto) == _canonical(two)
