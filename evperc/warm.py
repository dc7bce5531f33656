"""The run's numba kernels loaded before its first frame — and, on a new install, compiled in
several processes at once.

A run calls some forty compiled passes; numba compiles each on its first call and caches it
on disk (``cache=True``), so a new install's first run compiles them all: about 80 s of one
core (docs/performance.md § "Compiling in several processes"). The passes fall into four
groups of about 20 s each (:data:`GROUPS`: the fused step; the sensor grid, the motion gate
and the other window passes; the object stage; the object list's passes), which need nothing
from one another: each group calls its passes on a 2 × 2 window with the argument types of
the frame loop (:func:`warm_group`). When the kernels are not cached yet (:func:`kernels_cached`),
:func:`warm_up` has ``python -m evperc.warm`` child processes compile some groups into the
cache while this process compiles one itself, then calls every group here, which loads what
the children compiled. With ``n`` processes the groups are shared as evenly as their measured
compile times allow (:func:`buckets`); ``n`` is the number of CPUs this process may use, at
most one per group, or ``EVPERC_COMPILE_PROCESSES`` (1 = everything in this process). A child
that fails costs nothing but time: whatever it did not cache is compiled here.

Child processes, not :mod:`multiprocessing`: its "spawn" start method re-runs the parent's
``__main__`` (``python -m evperc`` runs the CLI there), and "fork" copies a process whose
threads (Dask's, tqdm's) may hold locks. A child inherits the environment, so it compiles for
the same CPU (``NUMBA_CPU_NAME``, :mod:`evperc.vector_width`) into the same cache
(``NUMBA_CACHE_DIR``).
"""

from __future__ import annotations

import logging
import os
import pickle
import subprocess
import sys
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from evperc.errors import UsageError
from evperc.plumbing import kernels_cached

log = logging.getLogger(__name__)

#: the environment variable that sets the number of compiling processes
PROCESSES_ENV = "EVPERC_COMPILE_PROCESSES"


@dataclass(frozen=True)
class WarmSpec:
    """What decides the argument types of a run's compiled passes: its configuration and
    whether it has a map (the fused step then reads context labels)."""

    config: dict[str, Any]
    has_map: bool


def _window(config: dict[str, Any]) -> Any:
    """A 2 × 2 window at the run's cell size."""
    from evperc.geo.window import Window

    return Window(config["grid"]["cell_size_m"], 2, 2, 0, 0)


def _sensor_masses() -> tuple[np.ndarray, np.ndarray]:
    """A 2 × 2 sensor grid as :func:`evperc.sensor.sensor_grid` returns it (float32 m({F}),
    m({O})): one free cell, one occupied."""
    free = np.array([[0.7, 0.0], [0.0, 0.0]], np.float32)
    occupied = np.array([[0.0, 0.0], [0.0, 0.8]], np.float32)
    return free, occupied


def _stored_outputs() -> Any:
    """A 2 × 2 frame's stored layers, zeroed: every cell decided ``unknown`` (code 0). The
    passes that read a layer as data (the decision counts, the unmapped cue, the object
    stage) must get values it can hold: ``StoredOutputs.empty``'s bytes are whatever the
    allocator had, and a byte beyond the last decision code stopped a run's start-up
    ("decision codes beyond 6") when they happened not to be zeros."""
    from evperc.fusion.fused import StoredOutputs

    return StoredOutputs.empty((2, 2), np.zeros)


def _warm_sensor(spec: WarmSpec) -> None:
    """The sensor grid (with every optional layer), the motion gate, the decision counts,
    the GIL-keeping helpers, the scan's cell layers and the unmapped cue."""
    from evperc.fusion.fused import count_codes
    from evperc.fusion.gate import GateState, gate_step
    from evperc.fusion.twin import DECISION_CODES, FusionParams
    from evperc.gil_kept import warm_up_gil_kept
    from evperc.objects.stage import objects_enabled, scan_cells
    from evperc.objects.unmapped import UnmappedCue, UnmappedParams, UnmappedState, unmapped_enabled
    from evperc.sensor import SensorParams, sensor_grid

    config, tiny = spec.config, _window(spec.config)
    points = np.array([[1.0, 0.0, 0.0], [2.0, 1.0, -1.5]], np.float32)
    params = SensorParams.from_config(config["sensor"], config["grid"]["cell_size_m"])
    sensor_grid(points, False, np.eye(4), tiny, params,
                hits_out=np.empty(tiny.shape, np.bool_),
                heights_out=np.empty(tiny.shape, np.float32),
                sums_out=np.zeros((*tiny.shape, 3), np.float32),
                context=np.zeros(tiny.shape, np.uint8))  # the road's returns, if asked
    # the heights without the sums (objects.centroid = "cells"): a pass of their own
    sensor_grid(points, False, np.eye(4), tiny, params,
                heights_out=np.empty(tiny.shape, np.float32))
    free, occupied = _sensor_masses()
    gate_step(GateState.fresh(tiny.shape), free, occupied, 0.1, FusionParams.from_config(config),
              closed=np.zeros(tiny.shape, np.bool_))
    out = _stored_outputs()
    count_codes(out.decision, len(DECISION_CODES))
    warm_up_gil_kept()
    if objects_enabled(config):
        scan_cells(free, occupied, np.zeros(tiny.shape, np.float32))
        scan_cells(free, occupied, None)
    if unmapped_enabled(config):
        UnmappedCue(UnmappedParams.from_config(config), tiny.shape,
                    config["grid"]["cell_size_m"]).step(
            UnmappedState.fresh(tiny.shape), out.decision, None, 0.1)


def _warm_fusion(spec: WarmSpec) -> None:
    """The fused step (the kernel variant the run's options pick), with labels if mapped."""
    from evperc.fusion.fused import fused_step, vacuous_state
    from evperc.fusion.twin import FusionParams

    config, tiny = spec.config, _window(spec.config)
    pg, zeta, flags, focal = vacuous_state(tiny.shape)
    free, occupied = _sensor_masses()
    betas = (config["map"]["beta_building"], config["map"]["beta_road"],
             config["map"]["beta_other"])
    labels = np.zeros(tiny.shape, np.uint8) if spec.has_map else None
    fused_step(pg, zeta, free, occupied, labels, betas, 0.1,
               FusionParams.from_config(config), out=_stored_outputs(), flags=flags,
               focal=focal, gate=np.ones(tiny.shape, np.uint8))


def _warm_objects(spec: WarmSpec) -> None:
    """The object stage's clusters, split and tracker, and the returns' centroids."""
    from evperc.objects.clusters import warm_up_return_centroids
    from evperc.objects.stage import ObjectStage, objects_enabled
    from evperc.objects.tracking import TrackerState

    config, tiny = spec.config, _window(spec.config)
    if not objects_enabled(config):
        return
    stage = ObjectStage(config, tiny.shape)
    out = _stored_outputs()
    _, occupied = _sensor_masses()
    stage.step(TrackerState(), out.decision, out.betp[4], out.conflict[0], tiny, 0,
               occupied_now=occupied > 0, near_building=np.ones(tiny.shape, np.bool_))
    if stage.needs_return_sums:
        warm_up_return_centroids()


def _warm_object_passes(spec: WarmSpec) -> None:
    """The passes after the object stage: footprints, vehicle boxes, the split's geometry,
    the decision's fills, the small groups' support and the backfill."""
    from evperc.objects.backfill import backfill_frames
    from evperc.objects.backfill import warm_up as warm_up_backfill
    from evperc.objects.boxes import BoxParams
    from evperc.objects.boxes import warm_up as warm_up_boxes
    from evperc.objects.footprint import FootprintParams
    from evperc.objects.footprint import warm_up as warm_up_footprints
    from evperc.objects.split import SplitParams
    from evperc.objects.split import warm_up as warm_up_split
    from evperc.objects.stage import (
        moving_min_cluster_cells,
        moving_needs_object,
        objects_enabled,
        unfill_small,
        unfill_unconfirmed,
    )
    from evperc.objects.support import SupportParams
    from evperc.objects.support import warm_up as warm_up_support

    config = spec.config
    if not objects_enabled(config):
        return
    warm_up_footprints(FootprintParams.from_config(config))
    warm_up_boxes(BoxParams.from_config(config))
    warm_up_split(SplitParams.from_config(config))
    needs_object = moving_needs_object(config)
    decision = _stored_outputs().decision
    if moving_min_cluster_cells(config) > 0 or needs_object:
        unfill_small(decision.copy(), np.zeros(1, np.int64), None)
    if needs_object:
        unfill_unconfirmed(decision.copy(), np.zeros(1, np.int64))
        if SupportParams.from_config(config).enabled:
            warm_up_support()
    if backfill_frames(config) > 0:
        warm_up_backfill()


#: the groups, each with its compile time on a new install (s, measured on the 2-vCPU Xeon
#: of docs/performance.md; :func:`buckets` balances by them)
GROUPS: dict[str, tuple[Callable[[WarmSpec], None], float]] = {
    "fusion": (_warm_fusion, 23.0),
    "objects": (_warm_objects, 22.0),
    "object_passes": (_warm_object_passes, 21.0),
    "sensor": (_warm_sensor, 19.0),
}


def warm_group(name: str, spec: WarmSpec) -> None:
    """Call the compiled passes of group ``name`` (a key of :data:`GROUPS`) once."""
    GROUPS[name][0](spec)


def buckets(names: Sequence[str], n: int) -> list[list[str]]:
    """``names`` shared among ``min(n, len(names))`` lists (at least one), the longest
    compile first into the list with the least so far (the order of :data:`GROUPS` breaks
    ties), so that the slowest list finishes as early as the split allows."""
    n = max(1, min(n, len(names)))
    lists: list[list[str]] = [[] for _ in range(n)]
    loads = [0.0] * n
    for name in sorted(names, key=lambda g: -GROUPS[g][1]):
        k = loads.index(min(loads))
        lists[k].append(name)
        loads[k] += GROUPS[name][1]
    return lists


def compile_processes() -> int:
    """How many processes compile a new install's kernels: ``EVPERC_COMPILE_PROCESSES``
    if set (a positive integer); else 1 in a Dask worker (its neighbours run tasks on the
    other cores); else the CPUs this process may run on, at most one per group. Raises
    :class:`UsageError` for a value that is not a positive integer."""
    value = os.environ.get(PROCESSES_ENV, "").strip()
    if value:
        try:
            n = int(value)
        except ValueError:
            n = 0
        if n < 1:
            raise UsageError(f"{PROCESSES_ENV}={value!r}: give a positive number of processes "
                             "(1 compiles in the run's own process)")
        return n
    if _in_dask_worker():
        return 1
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # macOS
        cpus = os.cpu_count() or 1
    return max(1, min(cpus, len(GROUPS)))


def _in_dask_worker() -> bool:
    distributed = sys.modules.get("distributed")  # not imported: not a worker
    if distributed is None:
        return False
    try:
        distributed.get_worker()
    except ValueError:
        return False
    return True


def child_command() -> list[str]:
    """The command of a compiling child (its groups and the :class:`WarmSpec` on stdin)."""
    return [sys.executable, "-m", "evperc.warm"]


def compile_in_processes(spec: WarmSpec, n: int) -> None:
    """Compile every group into numba's cache with ``n`` processes: this one and ``n − 1``
    children, each with a bucket of :func:`buckets`. A child that cannot start or fails is
    logged (debug) and otherwise ignored: :func:`warm_up` compiles what it left."""
    # no interpreter to start (an embedded Python): everything here
    lists = buckets(list(GROUPS), n if sys.executable else 1)
    children: list[tuple[subprocess.Popen[bytes], Any]] = []
    try:
        for groups in lists[1:]:
            # stderr to a file, not a pipe: a child must never wait on a full pipe while
            # this process compiles
            errors = tempfile.TemporaryFile()
            try:
                child = subprocess.Popen(child_command(), stdin=subprocess.PIPE,
                                         stdout=subprocess.DEVNULL, stderr=errors)
            except OSError as err:
                errors.close()
                log.debug("cannot start a compiling process (%s); compiling here", err)
                break
            children.append((child, errors))
            assert child.stdin is not None
            with child.stdin:
                child.stdin.write(pickle.dumps((groups, spec.config, spec.has_map)))
        for name in lists[0]:
            warm_group(name, spec)
        for child, errors in children:
            if child.wait() != 0:
                errors.seek(0)
                last = errors.read().decode(errors="replace").strip().splitlines()[-1:]
                log.debug("a compiling process exited with %d (%s); compiling its groups "
                          "here", child.returncode, (last or ["no message"])[0])
    finally:
        for child, errors in children:
            if child.poll() is None:  # an exception here (Ctrl-C): no orphan compiles on
                child.kill()
                child.wait()
            errors.close()


def compile_kernels(spec: WarmSpec) -> None:
    """If numba has not cached the kernels yet (:func:`kernels_cached`), compile every
    group into its cache, in :func:`compile_processes` processes (this one among them).
    ``EVPERC_COMPILE_PROCESSES`` is read (and a bad value refused) either way."""
    n = compile_processes()
    if kernels_cached():
        return
    log.info("compiling evperc's kernels, once%s (numba: about a minute of one core on a new "
             "install; cached for the next runs)", f", in {n} processes" if n > 1 else "")
    try:
        compile_in_processes(spec, n)
    except (OSError, ValueError, pickle.PicklingError) as err:
        log.debug("compiling in processes failed (%s); compiling here", err)


def warm_up(spec: WarmSpec) -> None:
    """Load every group's kernels into this process (:func:`compile_kernels` first)."""
    compile_kernels(spec)
    for name in GROUPS:
        warm_group(name, spec)


def main() -> int:
    """``python -m evperc.warm``: a compiling child (:func:`compile_in_processes`); reads
    ``(groups, config, has_map)`` pickled on stdin."""
    groups, config, has_map = pickle.loads(sys.stdin.buffer.read())
    unknown = [g for g in groups if g not in GROUPS]
    if unknown:
        print(f"evperc.warm: unknown groups {', '.join(map(str, unknown))}; the groups are "
              f"{', '.join(GROUPS)}", file=sys.stderr)
        return 2
    for name in groups:
        warm_group(name, WarmSpec(config, bool(has_map)))
    return 0


if __name__ == "__main__":
    from evperc.warm import main as _main  # the module's own names, not __main__'s copies

    sys.exit(_main())
