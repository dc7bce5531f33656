"""Command line: click commands only. Parse, call the library, report; no maths here.

Every :class:`~evperc.errors.EvpercError` becomes one line on stderr and exit code 2.
"""

from __future__ import annotations

import functools
import logging
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from evperc import __version__
from evperc.config import PRESETS
from evperc.errors import EvpercError, OutputError, UsageError

log = logging.getLogger("evperc")


def _setup_logging(verbose: int, quiet: int) -> None:
    level = logging.INFO - 10 * verbose + 10 * quiet
    logging.basicConfig(level=max(logging.DEBUG, min(logging.CRITICAL, level)),
                        format="%(levelname)s: %(message)s", stream=sys.stderr, force=True)


def user_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    """Turn user errors into ``evperc: error: <message>`` and exit code 2; Ctrl-C into exit 130."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except EvpercError as err:
            click.echo(f"evperc: error: {err}", err=True)
            sys.exit(err.exit_code)
        except KeyboardInterrupt:
            click.echo("evperc: interrupted", err=True)
            sys.exit(130)

    return wrapper


def check_map_options(map_path: Path | None, roads_path: Path | None, no_map: bool) -> None:
    """--map, --roads and --no-map of `run` and `batch`: a map, or explicitly none."""
    if map_path is None and not no_map:
        raise UsageError("give --map MAP, or --no-map for the map-less baseline")
    if map_path is not None and no_map:
        raise UsageError("--map and --no-map exclude each other")
    if roads_path is not None and map_path is None:
        raise UsageError("--roads needs --map")


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="evperc")
@click.option("-v", "--verbose", count=True, help="More log output (repeatable).")
@click.option("-q", "--quiet", count=True, help="Less log output (repeatable).")
def cli(verbose: int, quiet: int) -> None:
    """Map-aided evidential occupancy grids from logged drives (Kurdej et al. 2013)."""
    _setup_logging(verbose, quiet)


@cli.command("run")
@click.argument("log_path", metavar="LOG.mcap", type=click.Path(path_type=Path), required=False)
@click.option("--map", "map_path", type=click.Path(path_type=Path),
              help="Buildings (or one OSM-style file with buildings and highways).")
@click.option("--roads", "roads_path", type=click.Path(path_type=Path),
              help="Road surfaces or highway lines, if not in --map.")
@click.option("--no-map", is_flag=True, help="Run without a map (vacuous prior): the baseline.")
@click.option("--config", "config_path", type=click.Path(path_type=Path),
              help="TOML file overriding configs/default.toml.")
@click.option("--preset", type=click.Choice(PRESETS),
              help="Shipped config applied under --config: kurdej2013 = the paper's method "
                   "as SPEC describes it (no conservative free space, no widened buildings).")
@click.option("--out", "out_dir", type=click.Path(path_type=Path),
              help="Output directory  [default: ./evperc-out/<log stem>/]")
@click.option("--overwrite", is_flag=True, help="Replace an existing output directory.")
@click.option("--resume", "resume_dir", type=click.Path(path_type=Path),
              help="Continue the interrupted run in this directory (no other option needed).")
@click.option("--start", "start_s", type=float, help="Start, seconds from the log's start.")
@click.option("--end", "end_s", type=float, help="End, seconds from the log's start.")
@click.option("--every", type=click.IntRange(min=1), default=1, show_default=True,
              help="Use every N-th scan.")
@click.option("--lidar-topic", help="Lidar topic, if the log has several.")
@click.option("--pose-topic", help="Pose topic, if the log has several.")
@click.option("--render", "render_dir", type=click.Path(path_type=Path),
              help="Also render each frame to PNG in this directory as the run goes.")
@user_errors
def run_command(log_path: Path | None, map_path: Path | None, roads_path: Path | None,
                no_map: bool, config_path: Path | None, preset: str | None,
                out_dir: Path | None, overwrite: bool,
                resume_dir: Path | None, start_s: float | None, end_s: float | None, every: int,
                lidar_topic: str | None, pose_topic: str | None,
                render_dir: Path | None) -> None:
    """Fuse LOG.mcap with the map into evidential grids, frame by frame.

    \b
    evperc run drive.mcap --map buildings.geojson [--roads roads.geojson]
    evperc run drive.mcap --no-map
    evperc run --resume evperc-out/drive
    """
    from evperc.config import load_config
    from evperc.runner import RunRequest, request_from_manifest, run

    if resume_dir is not None:
        if (log_path is not None or map_path is not None or config_path is not None
                or preset is not None):
            raise UsageError("--resume takes the log, map and config of the interrupted run; "
                             "give no LOG, --map, --config or --preset with it")
        request = request_from_manifest(resume_dir)
        out_dir = resume_dir
    else:
        if log_path is None:
            raise UsageError("give LOG.mcap (or --resume DIR)")
        check_map_options(map_path, roads_path, no_map)
        config = load_config(config_path, preset=preset)
        out_dir = out_dir or Path("evperc-out") / log_path.stem
        request = RunRequest(log_path=log_path, out_dir=out_dir, config=config,
                             map_path=map_path, roads_path=roads_path, overwrite=overwrite,
                             start_s=start_s, end_s=end_s, every=every,
                             lidar_topic=lidar_topic, pose_topic=pose_topic)
    on_frame = None
    if render_dir is not None:
        from evperc.render.live import LiveRenderer

        on_frame = LiveRenderer(render_dir, request)
    try:
        summary = run(request, resume=resume_dir is not None, on_frame=on_frame)
    except KeyboardInterrupt:
        click.echo(f"evperc: interrupted; the frames written so far are kept, continue with "
                   f"`evperc run --resume {out_dir}`", err=True)
        sys.exit(130)
    shares = ", ".join(f"{name} {100 * share:.1f}%"
                       for name, share in summary["decision_share"].items() if share > 0)
    log.info("%d frames in %.1f s (%.1f frames/s) -> %s", summary["frames"],
             summary["wall_time_s"], summary["frames_per_s"] or 0.0, out_dir)
    log.info("cells: %s", shares)
    log.debug("ms per frame by stage: %s", ", ".join(
        f"{stage} {ms:.2f}" for stage, ms in summary.get("stage_ms_per_frame", {}).items()))


@cli.command("info")
@click.argument("log_path", metavar="LOG.mcap", type=click.Path(path_type=Path))
@click.option("--lidar-topic", help="Lidar topic, if the log has several.")
@click.option("--pose-topic", help="Pose topic, if the log has several.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@user_errors
def info_command(log_path: Path, lidar_topic: str | None, pose_topic: str | None,
                 as_json: bool) -> None:
    """Summarise LOG.mcap: topics, message counts, time span, detected lidar/pose/GNSS."""
    import json

    from evperc.io.log import open_log

    info = open_log(log_path, lidar_topic=lidar_topic, pose_topic=pose_topic,
                    strict=False).info()
    if as_json:
        click.echo(json.dumps(info, indent=2))
        return
    span = "empty" if info["duration_s"] is None else f"{info['duration_s']:.3f} s"
    click.echo(f"{info['path']}  ({'indexed' if info['indexed'] else 'no index'}"
               f"{'' if info['complete'] else ', TRUNCATED: ' + info['stopped']})")
    click.echo(f"time span: {span}")
    width = max([len(t["topic"]) for t in info["topics"]] + [5])
    click.echo(f"{'topic':<{width}}  {'messages':>8}  schema [encoding]")
    for t in info["topics"]:
        click.echo(f"{t['topic']:<{width}}  {t['messages']:>8}  {t['schema']} [{t['encoding']}]")
    for key, value in info["detected"].items():
        text = ", ".join(value) if isinstance(value, list) else value
        click.echo(f"{key.replace('_', ' ')}: {text or '-'}")
    if info.get("mean_points_per_scan") is not None:
        click.echo(f"lidar frame: {info['lidar_frame']}; mean points per scan "
                   f"{info['mean_points_per_scan']:.1f} (first {info['points_sample_scans']} "
                   "scans)")


@cli.command("render")
@click.argument("out_dir", metavar="OUT", type=click.Path(path_type=Path))
@click.option("--dest", type=click.Path(path_type=Path),
              help="Folder for DIR/frame_NNNNN.png (required unless only --gif).")
@click.option("--frames", "frames_text", metavar="A:B:STEP",
              help="Frames to draw, Python slice rules (e.g. 0:300:5)  [default: all]")
@click.option("--layers", "layers_text", default="betp,decision,trace", show_default=True,
              help="Panels: betp, decision, decision6, trace, zeta, conflict.")
@click.option("--gif", "gif_path", type=click.Path(path_type=Path),
              help="Also write an animated GIF.")
@click.option("--fps", type=float, default=10.0, show_default=True, help="GIF frame rate.")
@click.option("--compare", "compare_dir", type=click.Path(path_type=Path),
              help="Second output folder drawn beside OUT (frames matched by stamp).")
@click.option("--map", "map_path", type=click.Path(path_type=Path),
              help="Draw these map polygons as outlines.")
@click.option("--roads", "roads_path", type=click.Path(path_type=Path),
              help="Road file for --map, if separate.")
@click.option("--cell-px", type=click.IntRange(min=1), help="Pixels per cell  [default: auto]")
@click.option("--overwrite", is_flag=True, help="Replace existing frame PNGs / GIF.")
@user_errors
def render_command(out_dir: Path, dest: Path | None, frames_text: str | None, layers_text: str,
                   gif_path: Path | None, fps: float, compare_dir: Path | None,
                   map_path: Path | None, roads_path: Path | None, cell_px: int | None,
                   overwrite: bool) -> None:
    """Draw the grids of OUT (an `evperc run` folder) as PNG frames and/or a GIF."""
    from evperc.io.run_reader import load
    from evperc.render.frame import parse_layers
    from evperc.render.run_render import RenderRequest, outlines_for, parse_frames, render_run

    if dest is None and gif_path is None:
        raise UsageError("give --dest DIR for PNG frames and/or --gif FILE")
    if roads_path is not None and map_path is None:
        raise UsageError("--roads needs --map")
    layers, frames = parse_layers(layers_text), parse_frames(frames_text)
    run = load(out_dir)
    compare = load(compare_dir) if compare_dir is not None else None
    outlines = outlines_for(run, map_path, roads_path) if map_path is not None else None
    result = render_run(RenderRequest(run=run, dest=dest, gif=gif_path, frames=frames,
                                      layers=layers, fps=fps, compare=compare,
                                      outlines=outlines, cell_px=cell_px, overwrite=overwrite))
    where = " and ".join(str(p) for p in (dest, result["gif"]) if p is not None)
    log.info("%d frames rendered -> %s", result["frames"], where)


@cli.command("export")
@click.argument("out_dir", metavar="OUT", type=click.Path(path_type=Path))
@click.option("--mcap", "mcap_path", required=True, type=click.Path(path_type=Path),
              help="MCAP file to write (foxglove.Grid + foxglove.FrameTransform).")
@click.option("--frames", "frames_text", metavar="A:B:STEP",
              help="Frames to export, Python slice rules  [default: all]")
@click.option("--frame-id", default="evperc", show_default=True,
              help="Frame of the grids (the run's CRS), parent of the ego transform and of "
                   "the log's world frame.")
@click.option("--overwrite", is_flag=True, help="Replace an existing MCAP file.")
@user_errors
def export_command(out_dir: Path, mcap_path: Path, frames_text: str | None, frame_id: str,
                   overwrite: bool) -> None:
    """Export the grids of OUT to MCAP for Foxglove."""
    from evperc.io.foxglove_export import export_mcap
    from evperc.io.run_reader import load
    from evperc.render.run_render import parse_frames

    frames = parse_frames(frames_text)
    result = export_mcap(load(out_dir), mcap_path, frames=frames, frame_id=frame_id,
                         overwrite=overwrite)
    log.info("%d frames exported -> %s", result["frames"], result["path"])


@cli.command("simulate")
@click.option("--map", "map_path", required=True, type=click.Path(path_type=Path),
              help="OSM-style map: buildings, and highway lines unless --roads gives them.")
@click.option("--roads", "roads_path", type=click.Path(path_type=Path),
              help="Highway centre lines, if not in --map.")
@click.option("--out", "out_dir", required=True, type=click.Path(path_type=Path),
              help="Output folder: drive.mcap, map.geojson, truth/.")
@click.option("--profile", type=click.Choice(["ibeo4", "hdl64", "scan2d"]), default="ibeo4",
              show_default=True, help="Lidar model.")
@click.option("--seconds", type=click.FloatRange(min=0.1), default=10.0, show_default=True,
              help="Drive duration (10 scans per second).")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
@click.option("--config", "config_path", type=click.Path(path_type=Path),
              help="TOML file overriding configs/default.toml ([grid], [map], [sim]).")
@click.option("--overwrite", is_flag=True, help="Replace an existing output folder.")
@user_errors
def simulate_command(map_path: Path, roads_path: Path | None, out_dir: Path, profile: str,
                     seconds: float, seed: int, config_path: Path | None,
                     overwrite: bool) -> None:
    """Simulate a drive on a real map: MCAP log, map file and per-cell ground truth."""
    from evperc.config import load_config
    from evperc.sim.drive import SimRequest, simulate

    config = load_config(config_path)
    summary = simulate(SimRequest(map_path=map_path, out_dir=out_dir, config=config,
                                  roads_path=roads_path, profile=profile, seconds=seconds,
                                  seed=seed, overwrite=overwrite))
    log.info("%d scans, %.0f points/scan, %d agents, %d unmapped objects -> %s",
             summary["frames"], summary["points_per_scan"], summary["agents"],
             summary["unmapped_objects"], out_dir)


@cli.command("evaluate")
@click.argument("out_dir", metavar="OUT", type=click.Path(path_type=Path))
@click.option("--truth", "truth_dir", required=True, type=click.Path(path_type=Path),
              help="truth/ folder written by `evperc simulate`.")
@click.option("--compare", "compare_dir", type=click.Path(path_type=Path),
              help="Second run scored beside OUT (e.g. the --no-map baseline).")
@click.option("--json", "json_path", type=click.Path(path_type=Path),
              help="Also write the metrics as JSON.")
@click.option("--cells", type=click.Choice(["observed", "visible"]), default="observed",
              show_default=True,
              help="Score cells ever observed so far, or only those the sensor sees now.")
@user_errors
def evaluate_command(out_dir: Path, truth_dir: Path, compare_dir: Path | None,
                     json_path: Path | None, cells: str) -> None:
    """Score OUT (an `evperc run` folder) against simulated ground truth."""
    import json

    from evperc.eval.metrics import evaluate, format_report
    from evperc.io.run_reader import load
    from evperc.sim.truth import load_truth

    truth = load_truth(truth_dir)
    metrics = evaluate(load(out_dir), truth, cells=cells)
    other = (evaluate(load(compare_dir), truth, cells=cells) if compare_dir is not None
             else None)
    names = (out_dir.name or str(out_dir), compare_dir.name if compare_dir else "")
    click.echo(format_report(metrics, other, names), nl=False)
    if json_path is not None:
        doc = dict(metrics, run=str(out_dir))
        if other is not None:
            doc["compare"] = dict(other, run=str(compare_dir))
        try:
            json_path.write_text(json.dumps(doc, indent=1))
        except OSError as err:
            raise OutputError(f"{json_path}: cannot write JSON ({err.strerror})") from err


@cli.command("batch")
@click.argument("logs", metavar="LOGS...", nargs=-1, type=click.Path(path_type=Path))
@click.option("--list", "list_path", type=click.Path(path_type=Path),
              help="File with one log path per line (# comments; relative to the file).")
@click.option("--map", "map_path", type=click.Path(path_type=Path),
              help="Buildings (or one OSM-style file with buildings and highways).")
@click.option("--roads", "roads_path", type=click.Path(path_type=Path),
              help="Road surfaces or highway lines, if not in --map.")
@click.option("--no-map", is_flag=True, help="Run without a map (vacuous prior).")
@click.option("--out", "out_root", required=True, type=click.Path(path_type=Path),
              help="Root folder: each log's output goes to ROOT/<log stem>/.")
@click.option("--config", "config_path", type=click.Path(path_type=Path),
              help="TOML file overriding configs/default.toml (same for every log).")
@click.option("--preset", type=click.Choice(PRESETS),
              help="Shipped config applied under --config: kurdej2013 = the paper's method "
                   "as SPEC describes it (no conservative free space, no widened buildings).")
@click.option("--workers", type=click.IntRange(min=1),
              help="Worker processes of the local cluster  [default: number of cores]")
@click.option("--scheduler", metavar="ADDR",
              help="Use the running Dask cluster at ADDR (tcp://host:8786) instead.")
@click.option("--json", "json_path", type=click.Path(path_type=Path),
              help="Also write the result rows as JSON.")
@user_errors
def batch_command(logs: tuple[Path, ...], list_path: Path | None, map_path: Path | None,
                  roads_path: Path | None, no_map: bool, out_root: Path,
                  config_path: Path | None, preset: str | None, workers: int | None,
                  scheduler: str | None,
                  json_path: Path | None) -> None:
    """Run `evperc run` on many logs as tasks on a Dask cluster; skip finished outputs,
    resume interrupted ones. Exit code 1 if any log failed.

    \b
    evperc batch logs/*.mcap --map city.geojson --out runs/
    evperc batch --list logs.txt --no-map --out runs/ --scheduler tcp://head:8786
    """
    import json
    import os
    import time

    from evperc.batch import BatchRequest, format_table, read_log_list, run_batch, summary_line
    from evperc.config import load_config

    check_map_options(map_path, roads_path, no_map)
    if workers is not None and scheduler is not None:
        raise UsageError("--workers sizes the local cluster; the cluster at --scheduler has "
                         "its own workers, give one of the two")
    all_logs = list(logs) + (read_log_list(list_path) if list_path is not None else [])
    request = BatchRequest(logs=tuple(all_logs), out_root=out_root,
                           config=load_config(config_path, preset=preset), map_path=map_path,
                           roads_path=roads_path, workers=workers or os.cpu_count() or 1,
                           scheduler=scheduler)
    t0 = time.perf_counter()
    rows = run_batch(request)
    click.echo(format_table(rows))
    click.echo(summary_line(rows, time.perf_counter() - t0))
    if json_path is not None:
        try:
            json_path.write_text(json.dumps(rows, indent=1))
        except OSError as err:
            raise OutputError(f"{json_path}: cannot write JSON ({err.strerror})") from err
    if any(row["status"] in ("failed", "error") for row in rows):
        sys.exit(1)


def main() -> None:
    """Console-script entry point."""
    cli(prog_name="evperc")


if __name__ == "__main__":  # pragma: no cover
    main()
