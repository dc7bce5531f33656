"""Conventions every command shares (issue 22 items 5, 8, 9, 10): exit codes, -v / -q on
either side of the subcommand, progress bars with totals, the "compiling kernels" notice,
one output option name (--out; the old names still accepted), no silent overwrite."""

from __future__ import annotations

import json
import logging
import re
from pathlib import Path

import pytest
from click.testing import CliRunner

import evperc.warm
from evperc.cli import cli

from .scenes import write_street_drive

SMALL = "[grid]\nwindow_size_m = 30.0\n[output]\nchunk_frames = 5\n"


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_street_drive(tmp_path_factory.mktemp("conv") / "street.mcap", n_scans=12,
                              beams=360)


@pytest.fixture(scope="module")
def run_dir(drive: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("conv_run") / "run"
    config = out.parent / "small.toml"
    config.write_text(SMALL)
    result = CliRunner().invoke(cli, ["run", str(drive), "--no-map", "--config", str(config),
                                      "--out", str(out)])
    assert result.exit_code == 0, result.output
    return out


def invoke(*args: str, env: dict[str, str] | None = None) -> object:
    return CliRunner().invoke(cli, list(args), env=env)


# --- exit codes (item 5) --------------------------------------------------------------------

def test_exit_codes(drive: Path, tmp_path: Path) -> None:
    assert invoke("run", str(drive), "--no-such-option").exit_code == 2  # click usage
    assert invoke("run", str(drive), "--out", str(tmp_path / "o")).exit_code == 2  # no map
    assert invoke("run", str(tmp_path / "none.mcap"), "--no-map").exit_code == 2  # bad input
    assert not (tmp_path / "o").exists()
    # exit code 1 (a failed run of valid input) is pinned by test_bad_input's disk-full test


def test_exit_codes_are_documented() -> None:
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    assert "Exit codes: 0 success; 2 bad usage or bad input" in readme
    assert "1 a run of valid input that failed" in readme


# --- verbosity (item 9) ---------------------------------------------------------------------

@pytest.mark.parametrize("where", ["before", "after"])
def test_quiet_and_verbose_on_either_side_of_the_subcommand(drive: Path, tmp_path: Path,
                                                            where: str) -> None:
    def args(flag: str, out: str) -> list[str]:
        tail = [str(drive), "--no-map", "--out", str(tmp_path / out)]
        return [flag, "run", *tail] if where == "before" else ["run", *tail, flag]

    quiet = invoke(*args("-q", "q"))
    assert quiet.exit_code == 0, quiet.output
    assert "INFO" not in quiet.output and "frames in" not in quiet.output
    normal = invoke(*args("-q", "n")[1:] if where == "before" else args("-q", "n")[:-1])
    assert "INFO: 12 frames in" in normal.output, normal.output
    verbose = invoke(*args("-v", "v"))
    assert verbose.exit_code == 0, verbose.output
    assert "DEBUG: ms per frame by stage" in verbose.output, verbose.output


def test_verbose_shows_evperc_debug_lines_not_other_libraries(tmp_path: Path) -> None:
    """-v: evperc's DEBUG lines; another library's DEBUG only with -vv (numba's flood the
    terminal otherwise)."""
    import evperc.cli as cli_mod

    def record(name: str, level: int) -> logging.LogRecord:
        return logging.LogRecord(name, level, __file__, 1, "x", (), None)

    for verbose, others_shown in ((1, False), (2, True)):
        cli_mod._setup_logging(verbose, 0)
        handler = logging.getLogger().handlers[0]
        assert handler.filter(record("evperc.runner", logging.DEBUG))
        assert bool(handler.filter(record("numba.core", logging.DEBUG))) is others_shown
    # by default: evperc's INFO lines, other libraries' warnings but not their INFO lines
    # (pyogrio's "GDAL signalled an error" came before evperc's own one-line error)
    cli_mod._setup_logging(0, 0)
    handler = logging.getLogger().handlers[0]
    assert handler.filter(record("evperc.geo.maps", logging.INFO))
    assert not handler.filter(record("pyogrio._io", logging.INFO))
    assert handler.filter(record("pyogrio._io", logging.WARNING))


def test_the_lidar_extrinsic_is_said_once_for_the_lidar(tmp_path: Path) -> None:
    """Not also for the GNSS antenna's frame (the sample drive's base_link) before it."""
    sample = Path(__file__).resolve().parents[2] / "sample_data"
    result = invoke("run", str(sample / "drive.mcap"), "--no-map", "--end", "0.5", "--out",
                    str(tmp_path / "o"))
    assert result.exit_code == 0, result.output
    lines = [line for line in result.output.splitlines() if "lidar extrinsic" in line]
    assert lines == [f"INFO: {sample / 'drive.mcap'}: lidar extrinsic for frame 'lidar': "
                     "static TF base_link -> lidar"], result.output


def test_render_draws_the_map_the_run_used(tmp_path: Path) -> None:
    sample = Path(__file__).resolve().parents[2] / "sample_data"
    out = tmp_path / "run"
    result = invoke("run", str(sample / "drive.mcap"), "--map", str(sample / "map.geojson"),
                    "--end", "0.5", "--out", str(out))
    assert result.exit_code == 0, result.output
    drawn = {}
    for extra in ([], ["--no-map"]):
        dest = tmp_path / f"png{len(extra)}"
        result = invoke("render", str(out), "--out", str(dest), "--frames", "4:5",
                        "--layers", "decision", *extra)
        assert result.exit_code == 0, result.output
        drawn[bool(extra)] = (dest / "frame_00004.png").read_bytes()
        assert ("map outlines from the run's map" in result.output) is (not extra)
    assert drawn[False] != drawn[True]  # the outlines are in the picture


# --- progress and compile notice (item 8) ---------------------------------------------------

def test_bars_have_totals(drive: Path, run_dir: Path, tmp_path: Path) -> None:
    env = {"EVPERC_PROGRESS": "1"}
    result = invoke("run", str(drive), "--no-map", "--out", str(tmp_path / "o"), env=env)
    assert result.exit_code == 0, result.output
    # n/total [elapsed<remaining]: the frame count, known from the index, and the time left
    assert re.search(r"street.mcap: +\d+%\|.*\| \d+/12 \[", result.output), result.output
    result = invoke("render", str(run_dir), "--out", str(tmp_path / "png"), "--frames",
                    "0:12:4", "--layers", "decision", env=env)
    assert result.exit_code == 0, result.output
    assert re.search(r"render: +\d+%.* \d+/3 \[", result.output), result.output
    result = invoke("export", str(run_dir), "--out", str(tmp_path / "g.mcap"), env=env)
    assert result.exit_code == 0, result.output
    assert re.search(r"export: +\d+%.* \d+/12 \[", result.output), result.output
    osm = Path(__file__).resolve().parents[1] / "data" / "osm"
    result = invoke("simulate", "--map", str(osm / "helsinki_buildings.geojson"), "--roads",
                    str(osm / "helsinki_roads.geojson"), "--seconds", "0.5",
                    "--out", str(tmp_path / "sim"), env=env)
    assert result.exit_code == 0, result.output
    assert re.search(r"simulate: +\d+%.* \d+/5 \[", result.output), result.output


def test_a_bad_compile_process_count_is_refused_in_one_line(drive: Path, tmp_path: Path) -> None:
    """EVPERC_COMPILE_PROCESSES is read by every run (cached kernels or not): exit 2, one
    line naming the variable, no output folder left."""
    result = invoke("run", str(drive), "--no-map", "--out", str(tmp_path / "o"),
                    env={"EVPERC_COMPILE_PROCESSES": "two"})
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if "EVPERC_COMPILE_PROCESSES" in line]
    assert len(lines) == 1 and "positive number" in lines[0], result.output
    assert "Traceback" not in result.output
    assert not (tmp_path / "o").exists()


def test_a_cold_kernel_cache_is_announced(drive: Path, tmp_path: Path, monkeypatch) -> None:
    result = invoke("run", str(drive), "--no-map", "--out", str(tmp_path / "warm"))
    assert "compiling" not in result.output  # cached by now
    # as on a new install (kernels_cached on an empty cache: tests/test_warm.py), compiling
    # in this process
    monkeypatch.setattr(evperc.warm, "kernels_cached", lambda: False)
    monkeypatch.setenv("EVPERC_COMPILE_PROCESSES", "1")
    result = invoke("run", str(drive), "--no-map", "--out", str(tmp_path / "cold"))
    assert result.exit_code == 0, result.output
    assert "compiling evperc's kernels, once" in result.output, result.output


# --- output options (item 9) ----------------------------------------------------------------

def test_out_everywhere_old_names_hidden_but_accepted(run_dir: Path, tmp_path: Path) -> None:
    for command in ("render", "export"):
        text = invoke(command, "--help").output
        assert "--out" in text and "RUN_DIR" in text
        assert "--dest" not in text and "--mcap " not in text
    result = invoke("render", str(run_dir), "--dest", str(tmp_path / "a"), "--frames", "0:1")
    assert result.exit_code == 0 and (tmp_path / "a" / "frame_00000.png").is_file()
    result = invoke("export", str(run_dir), "--mcap", str(tmp_path / "a.mcap"))
    assert result.exit_code == 0 and (tmp_path / "a.mcap").is_file()
    result = invoke("render", str(run_dir), "--out", str(tmp_path / "b"), "--dest",
                    str(tmp_path / "c"))
    assert result.exit_code == 2 and "old name of --out" in result.output


def test_render_selection_of_no_frame_is_an_error(run_dir: Path, tmp_path: Path) -> None:
    result = invoke("render", str(run_dir), "--out", str(tmp_path / "p"), "--frames",
                    "300:400")
    assert result.exit_code == 2, result.output
    assert "--frames 300:400 selects none of the 12 frames" in result.output
    assert "slice(" not in result.output


def test_batch_overwrite(drive: Path, tmp_path: Path) -> None:
    args = ["batch", str(drive), "--no-map", "--out", str(tmp_path / "b"), "--workers", "1",
            "--json", str(tmp_path / "rows.json")]
    first = invoke(*args)
    assert first.exit_code == 0, first.output  # a failed log's row says why
    result = invoke(*args)
    assert result.exit_code == 2 and "pass --overwrite" in result.output
    result = invoke(*args, "--overwrite")
    assert result.exit_code == 0, result.output
    rows = json.loads((tmp_path / "rows.json").read_text())
    assert [r["status"] for r in rows] == ["ok"]  # run again, not "skipped"
    assert "(ROOT/<stem>--<parent folder>/" in invoke("batch", "--help").output
