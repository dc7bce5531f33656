"""Command line: click commands only. Parse, call the library, report; no maths here.

Every :class:`~evperc.errors.EvpercError` becomes one line on stderr and exit code 2.
"""

from __future__ import annotations

import functools
import logging
import sys
from pathlib import Path
from collections.abc import Callable
from typing import Any

import click

from evperc import __version__
from evperc.errors import EvpercError, UsageError

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


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="evperc")
@click.option("-v", "--verbose", count=True, help="More log output (repeatable).")
@click.option("-q", "--quiet", count=True, help="Less log output (repeatable).")
def cli(verbose: int, quiet: int) -> None:
    """Map-aided evidential occupancy grids from logged drives (Kurdej et al. 2013)."""
    _setup_logging(verbose, quiet)


@cli.command("run")
@click.argument("log_path", metavar="LOG.mcap", type=click.Path(path_type=Path))
@click.option("--map", "map_path", type=click.Path(path_type=Path),
              help="Buildings (or one OSM-style file with buildings and highways).")
@click.option("--roads", "roads_path", type=click.Path(path_type=Path),
              help="Road surfaces or highway lines, if not in --map.")
@click.option("--no-map", is_flag=True, help="Run without a map (vacuous prior): the baseline.")
@click.option("--config", "config_path", type=click.Path(path_type=Path),
              help="TOML file overriding configs/default.toml.")
@click.option("--out", "out_dir", type=click.Path(path_type=Path),
              help="Output directory  [default: ./evperc-out/<log stem>/]")
@click.option("--overwrite", is_flag=True, help="Replace an existing output directory.")
@click.option("--start", "start_s", type=float, help="Start, seconds from the log's start.")
@click.option("--end", "end_s", type=float, help="End, seconds from the log's start.")
@click.option("--every", type=click.IntRange(min=1), default=1, show_default=True,
              help="Use every N-th scan.")
@click.option("--lidar-topic", help="Lidar topic, if the log has several.")
@click.option("--pose-topic", help="Pose topic, if the log has several.")
@user_errors
def run_command(log_path: Path, map_path: Path | None, roads_path: Path | None, no_map: bool,
                config_path: Path | None, out_dir: Path | None, overwrite: bool,
                start_s: float | None, end_s: float | None, every: int,
                lidar_topic: str | None, pose_topic: str | None) -> None:
    """Fuse LOG.mcap with the map into evidential grids, frame by frame."""
    from evperc.config import load_config
    from evperc.runner import RunRequest, run

    if map_path is None and not no_map:
        raise UsageError("give --map MAP, or --no-map for the map-less baseline")
    if map_path is not None and no_map:
        raise UsageError("--map and --no-map exclude each other")
    if roads_path is not None and map_path is None:
        raise UsageError("--roads needs --map")
    config = load_config(config_path)
    out_dir = out_dir or Path("evperc-out") / log_path.stem
    request = RunRequest(log_path=log_path, out_dir=out_dir, config=config, map_path=map_path,
                         roads_path=roads_path, overwrite=overwrite, start_s=start_s,
                         end_s=end_s, every=every, lidar_topic=lidar_topic,
                         pose_topic=pose_topic)
    summary = run(request)
    shares = ", ".join(f"{name} {100 * share:.1f}%"
                       for name, share in summary["decision_share"].items() if share > 0)
    log.info("%d frames in %.1f s (%.1f frames/s) -> %s", summary["frames"],
             summary["wall_time_s"], summary["frames_per_s"] or 0.0, out_dir)
    log.info("cells: %s", shares)


def main() -> None:
    """Console-script entry point."""
    cli(prog_name="evperc")


if __name__ == "__main__":  # pragma: no cover
    main()
