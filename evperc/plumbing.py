"""Process plumbing of a run: the decode thread's prefetch, the fused step's thread count,
glibc's malloc thresholds, whether numba's kernels are cached. Nothing here knows the
method; the runner calls it.

Prefetch: pulling the items of an iterator in a background thread, a few ahead of their
consumer.

``prefetched(reader.scans())`` lets a second core read, decompress and decode the next scans
while the main thread fuses the current one (most of the decoding releases the GIL: file reads,
zstd, CRC and the point-cloud kernel). Items come out in the source's order; the producer is
never more than ``depth + 1`` items ahead of the consumer (``depth`` in the queue, one in
hand), so memory stays bounded. An exception of the source is raised in the consumer where
the item it stopped would have come, as the same object (type and traceback kept). When the
consumer stops early (``close()``, ``break``, an exception or Ctrl-C in its loop) the producer
stops after the item it is working on, the source iterator is closed in its own thread, and
the thread is joined before ``close()`` returns.
"""

from __future__ import annotations

import ctypes
import functools
import logging
import os
import pickle
import queue
import threading
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TypeVar

log = logging.getLogger(__name__)

T = TypeVar("T")

#: seconds between the producer's checks of the stop flag while the queue is full
_POLL_S = 0.05

_ITEM, _ERROR, _DONE = range(3)


def prefetched(iterable: Iterable[T], depth: int = 2, name: str = "evperc-prefetch",
               cpu_s: list[float] | None = None,
               hungry: threading.Event | None = None) -> Iterator[T]:
    """A generator of the items of ``iterable`` in order, produced by a daemon thread named
    ``name`` into a queue of ``depth`` items. The thread starts at the first ``next()``.
    ``cpu_s``: a one-element list the thread keeps at its CPU time so far (seconds, updated
    after each item). ``hungry``: kept set while the queue holds no item (the consumer
    waits, or will at its next request), so that the source can leave work to the consumer
    where the producer is the bottleneck.

    Use it as ``with contextlib.closing(prefetched(it)) as items: for item in items: ...``
    (or call ``close()`` in a ``finally``) so that an exception leaving the loop stops the
    thread at once; otherwise that happens when the generator is garbage-collected.
    Raises ValueError when ``depth`` < 1.
    """
    if depth < 1:
        raise ValueError(f"prefetch depth must be at least 1, not {depth}")
    return _consume(iterable, depth, name, cpu_s, hungry)


def _consume(iterable: Iterable[T], depth: int, name: str,
             cpu_s: list[float] | None, hungry: threading.Event | None) -> Iterator[T]:
    items: queue.Queue[tuple[int, object]] = queue.Queue(maxsize=depth)
    stop = threading.Event()
    flag = threading.Lock()  # a test of the queue and a change of hungry, atomic
    thread = threading.Thread(target=_produce,
                              args=(iterable, items, stop, cpu_s,
                                    None if hungry is None else (hungry, flag)),
                              name=name, daemon=True)
    thread.start()
    try:
        while True:
            if hungry is not None:
                _note_hunger(items, hungry, flag)
            kind, value = items.get()
            if hungry is not None:
                _note_hunger(items, hungry, flag)
            if kind == _ITEM:
                yield value  # type: ignore[misc]
            elif kind == _ERROR:
                raise value  # type: ignore[misc]
            else:
                return
    finally:
        stop.set()
        while thread.is_alive():
            _drain(items)  # frees a producer blocked on a full queue, and the items' memory
            thread.join(_POLL_S)
        _drain(items)


def _produce(iterable: Iterable[T], items: queue.Queue, stop: threading.Event,
             cpu_s: list[float] | None = None,
             hungry: tuple[threading.Event, threading.Lock] | None = None) -> None:
    """Thread body: put each item, then a done marker, or the exception that ended the
    source; return early once ``stop`` is set, closing the source."""
    iterator = None
    try:
        iterator = iter(iterable)
        for item in iterator:
            if cpu_s is not None:
                cpu_s[0] = time.thread_time()
            if not _put(items, (_ITEM, item), stop) or stop.is_set():
                return  # before pulling (decoding) another item
            if hungry is not None:
                with hungry[1]:
                    if not items.empty():
                        hungry[0].clear()
            del item
        _put(items, (_DONE, None), stop)
    except BaseException as err:  # noqa: BLE001 - handed to the consumer, which re-raises it
        _put(items, (_ERROR, err), stop)
    finally:
        close = getattr(iterator, "close", None)
        if close is not None:
            try:
                close()
            except Exception:  # noqa: BLE001 - the consumer has stopped; nobody to tell
                log.debug("closing the prefetched iterator failed", exc_info=True)


def _note_hunger(items: queue.Queue, hungry: threading.Event, flag: threading.Lock) -> None:
    """Set ``hungry`` if the queue is empty (under ``flag``: the producer clears it only
    while an item is queued)."""
    with flag:
        if items.empty():
            hungry.set()


def _put(items: queue.Queue, entry: tuple[int, object], stop: threading.Event) -> bool:
    """Put ``entry``, waiting while the queue is full; False (not put) once ``stop`` is set."""
    while not stop.is_set():
        try:
            items.put(entry, timeout=_POLL_S)
            return True
        except queue.Full:
            continue
    return False


def _drain(items: queue.Queue) -> None:
    while True:
        try:
            items.get_nowait()
        except queue.Empty:
            return


def fusion_threads(configured: int) -> int:
    """Threads of the fused step: ``configured``, or for 0 the cores this process may use
    less the two that the decode and writer threads keep busy (at least 1). On two cores
    the run is CPU-bound already (docs/performance.md): a second fusion thread would only
    take turns with the decode thread."""
    if configured > 0:
        return configured
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, (cores or 1) - 2)


#: glibc mallopt parameters: M_MMAP_THRESHOLD (-3), M_TRIM_THRESHOLD (-1)
_MALLOC_SETTINGS = ((-3, 32 << 20), (-1, 256 << 20))


@functools.cache
def keep_freed_memory() -> bool:
    """Make glibc keep freed blocks (up to 32 MB each, 256 MB at the heap's top) for reuse
    instead of returning them to the system; True if it could (glibc only).

    Every frame allocates a few fresh megabytes (the sensor grid, the labels, the decoded
    scan) that the next frame allocates again: by default glibc hands such blocks back and
    the next frame takes a page fault for every 4 kB of them (~300 a frame of workload (a)
    in the decode thread, ~0.4 ms of its CPU). Kept, they are reused as they are; the
    working set is the same from frame to frame, so memory stays bounded. Process-wide;
    once per process. ``EVPERC_GLIBC_MALLOC_DEFAULTS=1`` leaves glibc as it is (to measure
    the difference: ``benchmarks/bench_run.py``)."""
    if os.environ.get("EVPERC_GLIBC_MALLOC_DEFAULTS") == "1":
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        applied = [libc.mallopt(option, value) == 1 for option, value in _MALLOC_SETTINGS]
        return all(applied)
    except (OSError, AttributeError):  # not glibc (macOS, musl): nothing to tune
        return False


def kernels_cached() -> bool:
    """Whether numba has cached the default run's fused kernel for this source and this CPU,
    where numba itself will look for it (``NUMBA_CACHE_DIR``, beside the module, or the
    user-wide cache when the module's folder is read-only): its cache index, read as numba
    reads it (empty when missing or written for another version of the source), holds an
    entry compiled for this CPU model. A cheap test that the next run will not compile for
    a minute (:mod:`evperc.warm`). Should numba's cache internals change, any index file
    of the kernel module counts."""
    from evperc.fusion import kernel as fused_kernel

    dispatcher = fused_kernel.step_stored_lean
    try:
        index = dispatcher._cache._cache_file._load_index()
        cpu = dispatcher.targetctx.codegen().magic_tuple()[:2]  # (triple, CPU name)
        return any(key[1][:2] == cpu for key in index)
    except (AttributeError, TypeError, IndexError, OSError, EOFError, pickle.UnpicklingError):
        here = Path(fused_kernel.__file__)
        folders = [here.parent / "__pycache__"]
        if os.environ.get("NUMBA_CACHE_DIR"):
            folders.append(Path(os.environ["NUMBA_CACHE_DIR"]))
        return any(next(folder.rglob(f"{here.stem}.*.nbi"), None) is not None
                   for folder in folders if folder.is_dir())
