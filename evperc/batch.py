"""`evperc batch`: many logs, one `evperc run` each, as tasks on a Dask cluster.

Each log becomes one task running :func:`evperc.runner.run` in a worker process, writing
``ROOT/<name>/`` (see :func:`output_names`). Tasks never raise: they return a result row
(:data:`ROW_KEYS`), so one bad log does not stop the others. Idempotent: an output that is
complete is skipped, an interrupted one resumes from its checkpoint, the rest start fresh —
so rerunning a batch, or Dask rerunning a task after losing a worker, is safe.

The cluster is a :class:`distributed.LocalCluster` (one single-threaded worker process per
core: the work is numpy on whole arrays) or an existing one at ``tcp://host:8786``.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import time
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tqdm import tqdm

from evperc.errors import EvpercError, OutputError, UsageError

if TYPE_CHECKING:  # the runner (numba, numpy kernels) is imported where a task runs
    from evperc.runner import RunRequest

log = logging.getLogger(__name__)

#: the keys of a result row, in table order
ROW_KEYS = ("log", "out", "frames", "frames_per_s", "wall_time_s", "status", "poses", "preset",
            "error")
#: ``ok`` and ``resumed`` finished the run now; ``skipped`` was complete already
SUCCESS = ("ok", "resumed", "skipped")

_NAME_SEPARATOR = "--"

#: Dask sets MALLOC_TRIM_THRESHOLD_=65536 in its worker processes; that turns off glibc's
#: dynamic mmap threshold, so every large temporary array is mmapped and page-faulted
#: afresh: evperc ran 1.2-1.7x slower. Unset it (docs/performance.md, remote clusters too).
NANNY_ENVIRON = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}


@dataclass(frozen=True)
class BatchRequest:
    """What the user asked `evperc batch` to do."""

    logs: tuple[Path, ...]
    out_root: Path
    config: dict[str, Any]
    map_path: Path | None = None
    roads_path: Path | None = None
    workers: int = 2
    scheduler: str | None = None
    #: run every log afresh, replacing its output (else: skip complete, resume interrupted)
    overwrite: bool = False
    #: as :class:`evperc.runner.RunRequest`'s: the user's --config file, each log's run taking
    #: the sensor preset for its own lidar under its keys, and the preset ``config`` holds
    config_path: Path | None = None
    sensor_preset: bool = False
    preset: str | None = None


def read_log_list(list_path: Path) -> list[Path]:
    """Log paths from a list file: one per line, blank lines and ``#`` comments ignored,
    relative paths taken relative to the list file's folder."""
    try:
        text = list_path.read_text()
    except OSError as err:
        raise UsageError(f"{list_path}: cannot read the log list ({err.strerror})") from err
    logs = []
    for line in text.splitlines():
        entry = line.split("#", 1)[0].strip()
        if entry:
            path = Path(entry).expanduser()
            logs.append(path if path.is_absolute() else list_path.parent / path)
    return logs


def output_names(logs: Sequence[Path]) -> list[str]:
    """The folder name under ROOT of each log: its stem; logs sharing a stem get
    ``<stem>--<parent>`` (then ``<stem>--<grandparent>-<parent>`` …, then the file name with
    its extension) so a name depends only on the log's own path, never on the list order."""
    paths = [Path(p) for p in logs]
    names = [p.stem for p in paths]
    for stem in {n for n in names if names.count(n) > 1}:
        group = [i for i, n in enumerate(names) if n == stem]
        for depth in range(1, max(len(_folders(paths[i])) for i in group) + 2):
            candidates = {i: _suffixed(paths[i], depth) for i in group}
            if len(set(candidates.values())) == len(group):
                break
        for i, name in candidates.items():
            names[i] = name
    seen: dict[str, Path] = {}
    for name, path in zip(names, paths, strict=True):
        if name in seen:
            raise UsageError(f"{path} and {seen[name]}: both would write ROOT/{name}; rename "
                             "one of the logs or run them in two batches")
        seen[name] = path
    return names


def _folders(path: Path) -> tuple[str, ...]:
    parts = path.parent.parts
    return parts[1:] if parts and parts[0] == path.anchor else parts


def _suffixed(path: Path, depth: int) -> str:
    folders = _folders(path)
    head = path.stem if depth <= len(folders) else path.name
    tail = "-".join(folders[-depth:])
    return f"{head}{_NAME_SEPARATOR}{tail}" if tail else head


def plan(request: BatchRequest) -> list[RunRequest]:
    """One task per distinct log (duplicates dropped), paths made absolute for the workers."""
    logs = list(dict.fromkeys(Path(p).expanduser().resolve() for p in request.logs))
    if not logs:
        raise UsageError("no logs given; pass LOG.mcap paths or --list FILE")
    from evperc.runner import RunRequest

    root = Path(request.out_root).expanduser().resolve()
    config = request.config
    if config["fusion"]["threads"] == 0:  # auto: the logs running side by side use the cores
        config = {**config, "fusion": {**config["fusion"], "threads": 1}}
    return [RunRequest(log_path=path, out_dir=root / name, config=config,
                    map_path=_absolute(request.map_path),
                    roads_path=_absolute(request.roads_path), overwrite=request.overwrite,
                    config_path=_absolute(request.config_path),
                    sensor_preset=request.sensor_preset, preset=request.preset)
            for path, name in zip(logs, output_names(logs), strict=True)]


def _absolute(path: Path | None) -> Path | None:
    return Path(path).expanduser().resolve() if path is not None else None


# --- in the worker ------------------------------------------------------------------------

def process_log(task: RunRequest) -> dict[str, Any]:
    """Skip, resume or run one log; a result row, never an exception (runs on a worker)."""
    row: dict[str, Any] = dict.fromkeys(ROW_KEYS)
    row.update(log=str(task.log_path), out=str(task.out_dir))
    t0 = time.perf_counter()
    try:
        row.update(_skip_resume_or_run(task))
    except EvpercError as err:
        row.update(status="failed", error=_one_line(str(err)))
    except Exception as err:  # noqa: BLE001 - reported in the row, the batch goes on
        log.debug("%s: unexpected error", task.log_path, exc_info=True)
        row.update(status="error", error=_one_line(f"{type(err).__name__}: {err}"))
    row["wall_time_s"] = round(time.perf_counter() - t0, 3)
    if row["status"] in SUCCESS:
        from evperc.output.manifest import read_manifest

        manifest = read_manifest(task.out_dir)
        row["poses"] = _poses(manifest.get("pose_fit"))
        # the shipped preset the run's config holds: given with --preset, or taken for the
        # log's lidar (which the workers' log lines, not the user's, say)
        row["preset"] = (manifest.get("request") or {}).get("preset")
    return row


def _poses(fit: dict[str, Any] | None) -> str | None:
    """The run's pose check (the manifest's ``pose_fit``, evperc/sensor/pose_fit.py) in a
    word: ``fit``, ``MISFIT <offset> m``, ``MISFIT <turn>°``, or None (not checked)."""
    if not fit:
        return None
    if not fit["misfit"]:
        return "fit"
    if fit.get("turns"):
        return f"MISFIT {fit['yaw_deg']:+.1f}°"
    return f"MISFIT {math.hypot(*fit['offset_m']):.2f} m"


def _skip_resume_or_run(task: RunRequest) -> dict[str, Any]:
    from evperc.output.manifest import MANIFEST, read_manifest
    from evperc.runner import request_from_manifest, run

    if task.overwrite and (task.out_dir / MANIFEST).is_file():
        summary = run(task, progress=False, reuse_map=True)  # replaces the old output
        return {"frames": summary["frames"], "frames_per_s": summary["frames_per_s"],
                "status": "ok"}
    if (task.out_dir / MANIFEST).is_file():
        manifest = read_manifest(task.out_dir)
        _check_same_inputs(task, manifest)
        if manifest.get("complete"):
            return {"frames": int(manifest["frame_count"]), "status": "skipped"}
        summary = run(request_from_manifest(task.out_dir), resume=True, progress=False,
                      reuse_map=True)
        status = "resumed"
    else:
        _clear_stillborn_output(task.out_dir)
        if task.out_dir.is_dir() and any(task.out_dir.iterdir()):
            raise OutputError(f"{task.out_dir}: exists and is not an evperc output; move it "
                              "away or choose another --out")
        summary = run(task, progress=False, reuse_map=True)
        status = "ok"
    return {"frames": summary["frames"], "frames_per_s": summary["frames_per_s"],
            "status": status}


def _check_same_inputs(task: RunRequest, manifest: dict[str, Any]) -> None:
    """Refuse to skip or resume an output made from another log, map or config."""
    differs = []
    if not _same_path(manifest.get("log"), task.log_path):
        differs.append(f"log {manifest.get('log')}")
    if not _same_path(manifest.get("map"), task.map_path):
        differs.append(f"map {manifest.get('map')}")
    if not _same_path(manifest.get("roads"), task.roads_path):
        differs.append(f"roads {manifest.get('roads')}")
    if _canonical(manifest.get("config")) != _canonical(_as_run(task, manifest)):
        differs.append("another config")
    if differs:
        raise OutputError(f"{task.out_dir}: holds a run of other inputs ({', '.join(differs)});"
                          " delete it to redo this log, or choose another --out")


def _as_run(task: RunRequest, manifest: dict[str, Any]) -> dict[str, Any]:
    """The config ``task`` runs with on its log: with ``sensor_preset``, the sensor preset the
    manifest's run took for the log's lidar (the same log: the same layers, the same
    preset) under the task's --config keys."""
    from evperc.config import LAYER_PRESETS, with_preset

    saved = (manifest.get("request") or {}).get("preset")
    if task.sensor_preset and saved in {name for _, _, name in LAYER_PRESETS}:
        return with_preset(task.config, saved, task.config_path)
    return task.config


def _same_path(saved: str | None, wanted: Path | None) -> bool:
    if saved is None or wanted is None:
        return saved is None and wanted is None
    saved_path = Path(saved)
    if saved_path.is_absolute():
        return saved_path.resolve() == wanted
    return wanted.parts[-len(saved_path.parts):] == saved_path.parts  # an `evperc run` path


def _canonical(config: Any) -> str:
    """The config as compared between runs: without ``fusion.threads``, which does not
    change the output (and which configs written before it existed do not have)."""
    if isinstance(config, dict) and isinstance(config.get("fusion"), dict):
        config = {**config, "fusion": {key: value for key, value in config["fusion"].items()
                                       if key != "threads"}}
    return json.dumps(config, sort_keys=True, default=str)


def _clear_stillborn_output(out_dir: Path) -> None:
    """Remove what a run killed before its first manifest leaves (config.toml, an empty
    frames/, temporary files), so the retry can start; anything else stays and the run
    refuses the folder."""
    if not out_dir.is_dir():
        return
    entries = list(out_dir.iterdir())
    frames = out_dir / "frames"
    stillborn = all(p.name == "config.toml" or p.name.endswith(".tmp")
                    or (p == frames and p.is_dir() and not any(frames.iterdir()))
                    for p in entries)
    if entries and stillborn:
        log.info("%s: removing the leftovers of a run killed before it wrote a manifest",
                 out_dir)
        for path in entries:
            path.rmdir() if path.is_dir() else path.unlink()


def _one_line(text: str) -> str:
    lines = [line.strip() for line in text.strip().splitlines() if line.strip()]
    return " ".join(lines) if lines else "(no message)"


# --- on the client ------------------------------------------------------------------------

@contextlib.contextmanager
def open_client(workers: int = 2, scheduler: str | None = None) -> Iterator[Any]:
    """A dask client: connected to ``scheduler`` (``tcp://host:port``), or to an embedded
    :class:`~distributed.LocalCluster` of ``workers`` single-threaded worker processes."""
    from distributed import Client

    for name in ("distributed", "tornado", "bokeh"):
        logging.getLogger(name).setLevel(max(logging.WARNING,
                                             logging.getLogger(name).getEffectiveLevel()))
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as err:
            raise UsageError(f"--scheduler {scheduler}: cannot connect ({err}); start "
                             "`dask scheduler` there, or omit --scheduler for a local "
                             "cluster") from err
        with client:
            _check_remote_workers(client, scheduler)
            yield client
        return
    with warnings.catch_warnings():
        # the scheduler's HTTP endpoint moves to a free port when 8787 is taken: fine here
        warnings.filterwarnings("ignore", message="Port .* is already in use")
        cluster = _local_cluster(workers)
    with cluster, Client(cluster) as client:
        yield client


def _check_remote_workers(client: Any, scheduler: str) -> None:
    """Workers that cannot import evperc fail every task: say so once; warn about Dask's
    malloc setting that slows evperc down (see :data:`NANNY_ENVIRON`)."""
    try:
        settings = client.run(_malloc_trim_threshold)
    except Exception as err:  # noqa: BLE001 - whatever the worker raised, the fix is the same
        raise UsageError(f"--scheduler {scheduler}: workers cannot run evperc ({type(err).__name__}"
                         f": {_one_line(str(err))}); install evperc into the workers' Python "
                         "environment") from err
    if not settings:
        log.warning("--scheduler %s: the cluster has no workers yet; tasks wait for them",
                    scheduler)
    slowed = sorted(worker for worker, value in settings.items() if value is not None)
    if slowed:
        log.warning("%d worker(s) run with MALLOC_TRIM_THRESHOLD_ set (Dask's default), which "
                    "slows evperc down 1.2-1.7x; see docs/performance.md to unset it", len(slowed))


def _malloc_trim_threshold() -> str | None:
    import os

    return os.environ.get("MALLOC_TRIM_THRESHOLD_")


def _local_cluster(workers: int) -> Any:
    import dask
    from distributed import LocalCluster

    with dask.config.set(NANNY_ENVIRON):
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                            dashboard_address=None, silence_logs=logging.WARNING)


def run_batch(request: BatchRequest, client: Any = None, progress: bool = True
              ) -> list[dict[str, Any]]:
    """Run every log of ``request`` on the cluster; the result rows in the order of the logs.

    ``client`` — an open :class:`distributed.Client` to use; ``None`` opens one from
    ``request.workers`` / ``request.scheduler`` for this call."""
    tasks = plan(request)
    if client is None:
        with open_client(request.workers, request.scheduler) as own_client:
            return run_batch(request, own_client, progress)
    from distributed import as_completed

    if request.scheduler is None:  # the workers share this machine's numba cache: fill it
        # once, on every core, rather than in each worker at once (evperc.warm)
        from evperc.warm import WarmSpec, compile_kernels

        compile_kernels(WarmSpec(request.config, has_map=request.map_path is not None))
    futures = [client.submit(process_log, task, pure=False) for task in tasks]
    index = {future.key: i for i, future in enumerate(futures)}
    rows: list[dict[str, Any] | None] = [None] * len(tasks)
    bar = tqdm(as_completed(futures), total=len(futures), unit="log", desc="evperc batch",
               disable=None if progress else True)
    for future in bar:
        i = index[future.key]
        try:
            row = future.result()
        except Exception as err:  # noqa: BLE001 - e.g. KilledWorker: the worker kept dying
            row = dict.fromkeys(ROW_KEYS)
            row.update(log=str(tasks[i].log_path), out=str(tasks[i].out_dir), status="error",
                       error=_one_line(f"{type(err).__name__}: {err}"))
        rows[i] = row
        log.info("%s: %s%s", Path(row["log"]).name, row["status"],
                 f" ({row['error']})" if row["error"] else "")
    bar.close()
    return [row for row in rows if row is not None]


def format_table(rows: Sequence[dict[str, Any]]) -> str:
    """The summary table: log, frames, frames/s, status, poses (does the log's pose fit its
    scans: evperc/sensor/pose_fit.py), preset (the shipped preset the run took), error; one
    line per log."""
    header = ("log", "frames", "frames/s", "status", "poses", "preset", "error")
    cells = [(Path(r["log"]).name, _cell(r["frames"]), _cell(r["frames_per_s"]), r["status"],
              _cell(r.get("poses")), _cell(r.get("preset")), r["error"] or "") for r in rows]
    widths = [max(len(h), *(len(c[k]) for c in cells)) for k, h in enumerate(header)]
    lines = ["  ".join(v.ljust(w) for v, w in zip(line, widths, strict=True)).rstrip()
             for line in (header, *cells)]
    return "\n".join(lines)


def _cell(value: Any) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return f"{value:.1f}" if isinstance(value, float) else str(value)


def summary_line(rows: Sequence[dict[str, Any]], wall_s: float) -> str:
    """``N logs in T s: a ok, b skipped, … — F frames (X frames/s)``."""
    counts: dict[str, int] = {}
    for row in rows:
        counts[row["status"]] = counts.get(row["status"], 0) + 1
    ran = [r for r in rows if r["status"] in ("ok", "resumed")]
    frames = sum(int(r["frames"] or 0) for r in ran)
    states = ", ".join(f"{n} {s}" for s, n in sorted(counts.items()))
    rate = frames / wall_s if wall_s > 0 else 0.0
    return (f"{len(rows)} logs in {wall_s:.1f} s: {states}; {frames} frames fused "
            f"({rate:.1f} frames/s)")
