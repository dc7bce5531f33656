"""Command line: click commands only. Parse, call the library, report; no maths here.

Every :class:`~evperc.errors.EvpercError` becomes one line on stderr and its exit code: 2 for
bad usage or input, 1 for a run of valid input that failed (evperc/errors.py; README).
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
from evperc.config import NO_PRESET, PRESETS, preset_for_layers
from evperc.errors import EvpercError, OutputError, UsageError

log = logging.getLogger("evperc")

PRESET_HELP = ("Shipped config applied under --config: kurdej2013 = the paper's method as "
               "docs/method.md reads it (no conservative free space, widened buildings, motion "
               "gate or object list); hdl64 = for 64-layer scanners (KITTI / SemanticKITTI's "
               "HDL-64E: configs/hdl64.toml); ibeo4 = for 4-layer scanners (configs/ibeo4.toml); "
               "vlp16 = for 16-layer scanners (configs/vlp16.toml); none = the defaults alone.  "
               "[default: the sensor preset for the log's lidar when it says its layers "
               "(hdl64 for 48-128, vlp16 for 12-24), else none]")

def _setup_logging(verbose: int, quiet: int) -> None:
    """evperc's own messages from INFO (each -v one level more, each -q one less); other
    libraries' from WARNING, and their debug lines only from -vv on."""
    level = max(logging.DEBUG, min(logging.CRITICAL, logging.INFO - 10 * verbose + 10 * quiet))
    others = level if verbose >= 2 else max(level, logging.WARNING)
    logging.basicConfig(level=level, format="%(levelname)s: %(message)s", stream=sys.stderr,
                        force=True)
    logging.getLogger().handlers[0].addFilter(_LevelsFilter(level, others))


class _LevelsFilter(logging.Filter):
    """Pass evperc's records from ``own`` up, other libraries' from ``others`` up."""

    def __init__(self, own: int, others: int) -> None:
        super().__init__()
        self.own, self.others = own, others

    def filter(self, record: logging.LogRecord) -> bool:
        ours = record.name == "evperc" or record.name.startswith("evperc.")
        return record.levelno >= (self.own if ours else self.others)


def _count_verbosity(ctx: click.Context, param: click.Parameter, value: int) -> int:
    """-v / -q given after the subcommand: added to those given before it."""
    counts = ctx.find_root().meta.setdefault("evperc.verbosity", [0, 0])
    if value:
        counts[0 if param.name == "verbose" else 1] += value
        _setup_logging(*counts)
    return value


def verbosity_options(func: Callable[..., Any]) -> Callable[..., Any]:
    """-v / -q on a subcommand too (`evperc run LOG -q` as well as `evperc -q run LOG`)."""
    func = click.option("-q", "--quiet", count=True, expose_value=False,
                        callback=_count_verbosity, help="Less log output (repeatable).")(func)
    return click.option("-v", "--verbose", count=True, expose_value=False,
                        callback=_count_verbosity,
                        help="More log output (repeatable; -vv: other libraries' too).")(func)


def user_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    """Turn user errors into ``evperc: error: <message>`` and the error's exit code (2 bad
    usage or input, 1 a failed run of valid input); Ctrl-C into exit 130."""

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


def _alias(value: Path | None, alias: Path | None, name: str, old: str) -> Path | None:
    """An option given under its old name (kept working, hidden from --help)."""
    if alias is not None and value is not None:
        raise UsageError(f"{old} is the old name of {name}; give one of them")
    return value if value is not None else alias


def _run_map(run: Any) -> tuple[Path | None, Path | None]:
    """The map (and roads) the run was made with, as its manifest records them, if the files
    are still there (`render` draws their outlines without being told)."""
    paths = [run.manifest.get(key) for key in ("map", "roads")]
    if paths[0] is None:
        return None, None
    found = [Path(p) if p is not None else None for p in paths]
    missing = [str(p) for p in found if p is not None and not p.is_file()]
    if missing:
        log.info("the run's map %s is not there any more: no outlines (give --map)",
                 ", ".join(missing))
        return None, None
    log.info("map outlines from the run's map %s", found[0])
    return found[0], found[1]


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
@click.pass_context
def cli(ctx: click.Context, verbose: int, quiet: int) -> None:
    """Map-aided evidential occupancy grids from logged drives (Kurdej et al. 2013)."""
    ctx.meta["evperc.verbosity"] = [verbose, quiet]
    _setup_logging(verbose, quiet)


@cli.command("run")
@click.argument("log_path", metavar="LOG", type=click.Path(path_type=Path), required=False)
@click.option("--map", "map_path", type=click.Path(path_type=Path),
              help="Buildings (or one OSM-style file with buildings and highways).")
@click.option("--roads", "roads_path", type=click.Path(path_type=Path),
              help="Road surfaces or highway lines, if not in --map.")
@click.option("--no-map", is_flag=True, help="Run without a map (vacuous prior): the baseline.")
@click.option("--config", "config_path", type=click.Path(path_type=Path),
              help="TOML file overriding configs/default.toml.")
@click.option("--preset", type=click.Choice((*PRESETS, NO_PRESET)), metavar="NAME",
              help=PRESET_HELP)
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
@click.option("--point-labels", is_flag=True,
              help="Also write OUT/labels/NNNNNN.label: per input point 251 moving, 9 static, "
                   "0 unknown (SemanticKITTI-MOS).")
@verbosity_options
@user_errors
def run_command(log_path: Path | None, map_path: Path | None, roads_path: Path | None,
                no_map: bool, config_path: Path | None, preset: str | None,
                out_dir: Path | None, overwrite: bool,
                resume_dir: Path | None, start_s: float | None, end_s: float | None, every: int,
                lidar_topic: str | None, pose_topic: str | None,
                render_dir: Path | None, point_labels: bool) -> None:
    """Fuse LOG with the map into evidential grids, frame by frame. LOG: an MCAP file (ROS 2,
    ROS 1 or Foxglove messages), a ROS 1 .bag, a ROS 2 bag directory (.db3 or .mcap), or a
    KITTI odometry / SemanticKITTI sequence folder.

    \b
    evperc run drive.mcap --map buildings.geojson [--roads roads.geojson]
    evperc run drive.mcap --no-map
    evperc run semantickitti/08 --no-map --point-labels
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
            raise UsageError("give LOG (an MCAP, .bag, ROS 2 bag or KITTI sequence folder) "
                             "or --resume DIR")
        check_map_options(map_path, roads_path, no_map)
        named = preset if preset != NO_PRESET else None
        config = load_config(config_path, preset=named)
        out_dir = out_dir or Path("evperc-out") / log_path.stem
        request = RunRequest(log_path=log_path, out_dir=out_dir, config=config,
                             map_path=map_path, roads_path=roads_path, overwrite=overwrite,
                             start_s=start_s, end_s=end_s, every=every,
                             lidar_topic=lidar_topic, pose_topic=pose_topic,
                             point_labels=point_labels, config_path=config_path,
                             sensor_preset=preset is None, preset=named)
    on_frame = None
    if render_dir is not None:
        from evperc.render.live import LiveRenderer

        on_frame = LiveRenderer(render_dir, request)
    try:
        summary = run(request, resume=resume_dir is not None, on_frame=on_frame)
    except KeyboardInterrupt:
        if (out_dir / "manifest.json").is_file():
            click.echo(f"evperc: interrupted; the frames written so far are kept, continue "
                       f"with `evperc run --resume {out_dir}`", err=True)
        else:
            click.echo("evperc: interrupted before the first frame; nothing written", err=True)
        sys.exit(130)
    shares = ", ".join(f"{name} {100 * share:.1f}%"
                       for name, share in summary["decision_share"].items() if share > 0)
    log.info("%d frames in %.1f s (%.1f frames/s) -> %s", summary["frames"],
             summary["wall_time_s"], summary["frames_per_s"] or 0.0, out_dir)
    log.info("cells: %s", shares)
    log.debug("ms per frame by stage: %s", ", ".join(
        f"{stage} {ms:.2f}" for stage, ms in summary.get("stage_ms_per_frame", {}).items()))


@cli.command("info")
@click.argument("log_path", metavar="LOG", type=click.Path(path_type=Path))
@click.option("--lidar-topic", help="Lidar topic, if the log has several.")
@click.option("--pose-topic", help="Pose topic, if the log has several.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@verbosity_options
@user_errors
def info_command(log_path: Path, lidar_topic: str | None, pose_topic: str | None,
                 as_json: bool) -> None:
    """Summarise LOG (MCAP, ROS 1 .bag, ROS 2 bag directory, KITTI sequence folder): topics,
    message counts, time span, detected lidar/pose/GNSS."""
    import json

    from evperc.logs.factory import open_log

    reader = open_log(log_path, lidar_topic=lidar_topic, pose_topic=pose_topic, strict=False)
    info = reader.info()
    fits = _pose_fits(reader)
    info["pose_fit"] = None if fits[0][1] is None else fits[0][1].summary()
    info["pose_fits_later"] = [{"from_s": round(from_s, 3),
                                "pose_fit": None if fit is None else fit.summary()}
                               for from_s, fit in fits[1:]]
    if as_json:
        click.echo(json.dumps(info, indent=2))
        return
    span = "empty" if info["duration_s"] is None else f"{info['duration_s']:.3f} s"
    kind = "KITTI sequence folder" if info.get("kind") == "kitti" else (
        f"{info['kind']}, {'indexed' if info['indexed'] else 'no index'}")
    click.echo(f"{info['path']}  ({kind}"
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
    if info.get("lidar_layers") is not None:
        layers = info["lidar_layers"]
        better = preset_for_layers(layers["count"])
        click.echo(f"lidar layers: {layers['count']} ({layers['from']})"
                   + (f"; `evperc run` takes --preset {better}'s keys, tuned for such "
                      "scanners" if better else ""))
    for k, (from_s, fit) in enumerate(fits):
        where = "" if k == 0 else f" from {from_s:.1f} s"
        if fit is None:
            click.echo(f"poses against the scans{where}: not checked (no posed scans 3 m apart "
                       "in the first 200, or under 200 obstacle returns a scan)")
        elif fit.misfit:
            click.echo(f"poses against the scans{where}: DO NOT FIT: "
                       f"{fit.message(str(log_path))}")
        else:
            click.echo(f"poses against the scans{where}: fit ({fit.fit_text()})")


#: `evperc info` checks the poses from the log's start and, for a log longer than three
#: times this (s) that it can read from any time, from a third and two thirds of it too
INFO_POSE_PART_S = 30.0


def _pose_fits(reader: Any) -> list[tuple[float, Any]]:
    """`evperc run`'s pose check (:func:`evperc.sensor.pose_fit.check_poses`, the default
    sensor model) from the log's start, and from a third and two thirds of a long log that
    its source reads from any time (``seeks``; a KITTI folder skips scans by their stamps):
    ``(seconds from the log's start, fit)``, the fit None where it cannot be made (no poses,
    too little motion or too few returns; the scans counted from each start)."""
    from contextlib import closing

    from evperc.config import default_config
    from evperc.sensor import SensorParams
    from evperc.sensor.pose_fit import check_poses

    first, last = reader.start_ns, reader.end_ns
    starts: list[int | None] = [None]
    if (first is not None and last is not None
            and getattr(getattr(reader, "source", None), "seeks", True)
            and last - first >= 3 * INFO_POSE_PART_S * 1e9):
        starts += [first + (last - first) // 3, first + 2 * (last - first) // 3]
    config = default_config()
    params = SensorParams.from_config(config["sensor"], config["grid"]["cell_size_m"])
    fits: list[tuple[float, Any]] = []
    quiet = logging.getLogger("evperc")  # the reader's notes on its first scans: a run's
    level = quiet.level                   # business, not this summary's
    quiet.setLevel(max(level, logging.WARNING))
    try:
        for start in starts:
            try:
                with closing(reader.scans(start_ns=start)) as scans:
                    fit = check_poses(scans, params)
            except EvpercError:  # no pose source, no lidar topic: `info` says so above
                fit = None
            fits.append((0.0 if start is None else (start - first) * 1e-9, fit))
    finally:
        quiet.setLevel(level)
    return fits


@cli.command("render")
@click.argument("out_dir", metavar="RUN_DIR", type=click.Path(path_type=Path))
@click.option("--out", "dest", type=click.Path(path_type=Path),
              help="Folder for OUT/frame_NNNNN.png (required unless only --gif).")
@click.option("--dest", "dest_alias", type=click.Path(path_type=Path), hidden=True)
@click.option("--frames", "frames_text", metavar="A:B:STEP",
              help="Frames to draw, Python slice rules (e.g. 0:300:5)  [default: all]")
@click.option("--layers", "layers_text", default="betp,decision6,trace", show_default=True,
              help="Panels: betp, decision (free/static/moving), decision6 (each decision), "
                   "trace, zeta, conflict.")
@click.option("--gif", "gif_path", type=click.Path(path_type=Path),
              help="Also write an animated GIF.")
@click.option("--fps", type=float, default=10.0, show_default=True, help="GIF frame rate.")
@click.option("--compare", "compare_dir", type=click.Path(path_type=Path),
              help="Second run folder drawn beside RUN_DIR (frames matched by stamp).")
@click.option("--map", "map_path", type=click.Path(path_type=Path),
              help="Draw these map polygons as outlines  [default: the run's --map]")
@click.option("--roads", "roads_path", type=click.Path(path_type=Path),
              help="Road file for --map, if separate.")
@click.option("--no-map", "no_map", is_flag=True, help="Draw no map outlines.")
@click.option("--cell-px", type=click.IntRange(min=1), help="Pixels per cell  [default: auto]")
@click.option("--overwrite", is_flag=True, help="Replace existing frame PNGs / GIF.")
@verbosity_options
@user_errors
def render_command(out_dir: Path, dest: Path | None, dest_alias: Path | None,
                   frames_text: str | None, layers_text: str, gif_path: Path | None,
                   fps: float, compare_dir: Path | None, map_path: Path | None,
                   roads_path: Path | None, no_map: bool, cell_px: int | None,
                   overwrite: bool) -> None:
    """Draw the grids of RUN_DIR (an `evperc run` folder) as PNG frames and/or a GIF, with
    the outlines of the map the run used."""
    from evperc.output.reader import load
    from evperc.render.frame import parse_layers
    from evperc.render.run_render import RenderRequest, outlines_for, parse_frames, render_run

    dest = _alias(dest, dest_alias, "--out", "--dest")
    if dest is None and gif_path is None:
        raise UsageError("give --out DIR for PNG frames and/or --gif FILE")
    if roads_path is not None and map_path is None:
        raise UsageError("--roads needs --map")
    if no_map and map_path is not None:
        raise UsageError("--map and --no-map exclude each other")
    layers, frames = parse_layers(layers_text), parse_frames(frames_text)
    run = load(out_dir)
    compare = load(compare_dir) if compare_dir is not None else None
    if map_path is None and not no_map:
        map_path, roads_path = _run_map(run)
    outlines = outlines_for(run, map_path, roads_path) if map_path is not None else None
    result = render_run(RenderRequest(run=run, dest=dest, gif=gif_path, frames=frames,
                                      layers=layers, fps=fps, compare=compare,
                                      outlines=outlines, cell_px=cell_px, overwrite=overwrite))
    where = " and ".join(str(p) for p in (dest, result["gif"]) if p is not None)
    log.info("%d frames rendered -> %s", result["frames"], where)


@cli.command("export")
@click.argument("out_dir", metavar="RUN_DIR", type=click.Path(path_type=Path))
@click.option("--out", "mcap_path", type=click.Path(path_type=Path),
              help="MCAP file to write (foxglove.Grid + foxglove.FrameTransform, and "
                   "foxglove.SceneUpdate of the objects if the run lists them).")
@click.option("--mcap", "mcap_alias", type=click.Path(path_type=Path), hidden=True)
@click.option("--frames", "frames_text", metavar="A:B:STEP",
              help="Frames to export, Python slice rules  [default: all]")
@click.option("--frame-id", default="evperc", show_default=True,
              help="Frame of the grids (the run's CRS), parent of the ego transform and of "
                   "the log's world frame.")
@click.option("--overwrite", is_flag=True, help="Replace an existing MCAP file.")
@verbosity_options
@user_errors
def export_command(out_dir: Path, mcap_path: Path | None, mcap_alias: Path | None,
                   frames_text: str | None, frame_id: str, overwrite: bool) -> None:
    """Export the grids (and object list) of RUN_DIR to an MCAP file for Foxglove."""
    from evperc.output.export import export_mcap
    from evperc.output.reader import load
    from evperc.render.run_render import parse_frames

    mcap_path = _alias(mcap_path, mcap_alias, "--out", "--mcap")
    if mcap_path is None:
        raise UsageError("give --out FILE.mcap")
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
@click.option("--profile", type=click.Choice(["ibeo4", "hdl64", "vlp16", "hdl32", "scan2d"]),
              default="ibeo4", show_default=True, help="Lidar model.")
@click.option("--seconds", type=click.FloatRange(min=0.1), default=10.0, show_default=True,
              help="Drive duration (10 scans per second).")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
@click.option("--config", "config_path", type=click.Path(path_type=Path),
              help="TOML file overriding configs/default.toml ([grid], [map], [sim]).")
@click.option("--overwrite", is_flag=True, help="Replace an existing output folder.")
@verbosity_options
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
@click.argument("out_dir", metavar="RUN_DIR", type=click.Path(path_type=Path))
@click.option("--truth", "truth_dir", type=click.Path(path_type=Path),
              help="truth/ folder written by `evperc simulate`.")
@click.option("--semantickitti", "seq_dir", type=click.Path(path_type=Path),
              help="SemanticKITTI sequence folder: score RUN_DIR/labels (--point-labels) "
                   "against its labels/, as the LiDAR-MOS benchmark does.")
@click.option("--warmup", type=click.IntRange(min=0), default=2, show_default=True,
              help="With --semantickitti: the first K scans, pooled apart.")
@click.option("--compare", "compare_dir", type=click.Path(path_type=Path),
              help="Second run scored beside RUN_DIR (e.g. the --no-map baseline).")
@click.option("--json", "json_path", type=click.Path(path_type=Path),
              help="Also write the metrics as JSON.")
@click.option("--cells", type=click.Choice(["observed", "visible"]), default="observed",
              show_default=True,
              help="Score cells ever observed so far, or only those the sensor sees now.")
@click.option("--overwrite", is_flag=True, help="Replace an existing --json file.")
@verbosity_options
@user_errors
def evaluate_command(out_dir: Path, truth_dir: Path | None, seq_dir: Path | None,
                     warmup: int, compare_dir: Path | None, json_path: Path | None,
                     cells: str, overwrite: bool) -> None:
    """Score RUN_DIR (an `evperc run` folder) against simulated ground truth of its drive
    (--truth) or SemanticKITTI point labels (--semantickitti).

    With --compare, both runs must cover the same frames (same --start/--end/--every)."""
    import json

    if (truth_dir is None) == (seq_dir is None):
        raise UsageError("give one of --truth DIR (a simulated drive) or --semantickitti "
                         "SEQ_DIR")
    if json_path is not None and json_path.exists() and not overwrite:
        raise OutputError(f"{json_path}: exists; pass --overwrite to replace it")
    if seq_dir is not None:
        from evperc.eval.semantickitti import evaluate_semantickitti, format_semantickitti

        if compare_dir is not None:
            raise UsageError("--compare works with --truth; score the second run with its "
                             "own `evperc evaluate --semantickitti`")
        result = evaluate_semantickitti(out_dir, seq_dir, warmup=warmup)
        click.echo(format_semantickitti(result), nl=False)
        if json_path is not None:
            try:
                json_path.write_text(json.dumps(dict(result, run=str(out_dir),
                                                     sequence=str(seq_dir)), indent=1))
            except OSError as err:
                raise OutputError(f"{json_path}: cannot write JSON ({err.strerror})") from err
        return

    from evperc.eval.metrics import evaluate, format_report
    from evperc.output.reader import load
    from evperc.sim.truth import load_truth

    truth = load_truth(truth_dir)
    metrics = evaluate(load(out_dir), truth, cells=cells)
    other = (evaluate(load(compare_dir), truth, cells=cells) if compare_dir is not None
             else None)
    if other is not None:
        _check_same_frames(out_dir, metrics, compare_dir, other)
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


def _check_same_frames(out_dir: Path, metrics: dict[str, Any], compare_dir: Path | None,
                       other: dict[str, Any]) -> None:
    """Refuse to set side by side scores over different frames (a 20 s run beside a 10 s
    baseline compares different scenes, not the map's effect)."""
    def text(m: dict[str, Any]) -> str:
        span = m["frames_span_ns"]
        if span is None:
            return "no frame"
        return f"{m['frames_matched']} frames, stamps {span[0]}..{span[1]} ns"

    if (metrics["frames_matched"], metrics["frames_span_ns"]) != (
            other["frames_matched"], other["frames_span_ns"]):
        raise UsageError(f"{out_dir} and {compare_dir} are scored over different frames "
                         f"({text(metrics)} vs {text(other)}); run both over the same span "
                         "(the same --start, --end, --every) to compare them")


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
              help="Root folder: each log's output goes to ROOT/<log stem>/ "
                   "(ROOT/<stem>--<parent folder>/ for logs that share a stem).")
@click.option("--overwrite", is_flag=True,
              help="Run every log afresh, replacing its output (default: skip complete "
                   "outputs, resume interrupted ones).")
@click.option("--config", "config_path", type=click.Path(path_type=Path),
              help="TOML file overriding configs/default.toml (same for every log).")
@click.option("--preset", type=click.Choice((*PRESETS, NO_PRESET)), metavar="NAME",
              help=PRESET_HELP)
@click.option("--workers", type=click.IntRange(min=1),
              help="Worker processes of the local cluster  [default: number of cores]")
@click.option("--scheduler", metavar="ADDR",
              help="Use the running Dask cluster at ADDR (tcp://host:8786) instead.")
@click.option("--json", "json_path", type=click.Path(path_type=Path),
              help="Also write the result rows as JSON.")
@verbosity_options
@user_errors
def batch_command(logs: tuple[Path, ...], list_path: Path | None, map_path: Path | None,
                  roads_path: Path | None, no_map: bool, out_root: Path,
                  overwrite: bool, config_path: Path | None, preset: str | None,
                  workers: int | None, scheduler: str | None, json_path: Path | None) -> None:
    """Run `evperc run` on many logs (any kind it reads) as tasks on a Dask cluster; skip
    finished outputs, resume interrupted ones (or, with --overwrite, redo them). Exit code 1
    if any log failed, 2 for bad usage.

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
    named = preset if preset != NO_PRESET else None
    request = BatchRequest(logs=tuple(all_logs), out_root=out_root,
                           config=load_config(config_path, preset=named), map_path=map_path,
                           roads_path=roads_path, workers=workers or os.cpu_count() or 1,
                           scheduler=scheduler, overwrite=overwrite, config_path=config_path,
                           sensor_preset=preset is None, preset=named)
    if json_path is not None and json_path.exists() and not overwrite:
        raise OutputError(f"{json_path}: exists; pass --overwrite to replace it")
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
