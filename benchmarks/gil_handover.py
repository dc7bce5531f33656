"""What a numpy call costs the frame loop when it releases the GIL (docs/performance.md § "The
GIL's hand-overs"): each operation timed (wall and the calling thread's CPU, mean of 200
calls) while a second thread runs pure Python, as the decode thread runs the log's records;
the GIL-keeping versions of evperc.gil_kept beside them.

    python benchmarks/gil_handover.py
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np

from evperc.gil_kept import copy_layer, in_sorted, positive, sorted_copy, warm_up_gil_kept

CALLS = 200


def timed(operation: Callable[[], object]) -> tuple[float, float]:
    """(wall µs, CPU µs) per call of ``operation``, mean of CALLS."""
    wall, cpu = time.perf_counter(), time.thread_time()
    for _ in range(CALLS):
        operation()
    return (1e6 * (time.perf_counter() - wall) / CALLS, 1e6 * (time.thread_time() - cpu) / CALLS)


def spin(stop: threading.Event) -> None:
    """Pure Python until ``stop``: it takes the GIL whenever the caller releases it."""
    x = 0
    while not stop.is_set():
        x += 1


def main() -> None:
    warm_up_gil_kept()
    layer = np.zeros((400, 400), np.uint8)  # a 200 m window at 0.5 m
    occupied = np.zeros((400, 400), np.float32)
    ids = np.arange(60, dtype=np.int64)  # a frame's track ids
    few = ids[:10].copy()
    operations = {
        "copy of a layer (numpy)": lambda: layer.copy(),
        "copy of a layer (copy_layer)": lambda: copy_layer(layer),
        "layer > 0 (numpy)": lambda: occupied > 0,
        "layer > 0 (positive)": lambda: positive(occupied),
        "np.sort, 60 values": lambda: np.sort(ids),
        "sorted_copy, 60 values": lambda: sorted_copy(ids),
        "np.searchsorted, 10 in 60": lambda: np.searchsorted(ids, few),
        "in_sorted, 10 in 60": lambda: in_sorted(few, ids),
        "np.concatenate, 2 × 60 (never releases)": lambda: np.concatenate([ids, ids]),
    }
    for label, busy in (("alone", False), ("beside a thread running Python", True)):
        stop = threading.Event()

        thread = threading.Thread(target=spin, args=(stop,)) if busy else None
        if thread is not None:
            thread.start()
        try:
            print(f"\n{label}:")
            for name, operation in operations.items():
                wall, cpu = timed(operation)
                print(f"  {name:42s} wall {wall:8.1f} µs   CPU {cpu:6.1f} µs")
        finally:
            stop.set()
            if thread is not None:
                thread.join()


if __name__ == "__main__":
    main()
