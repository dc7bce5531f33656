"""evperc.warm: the kernels' groups shared among compiling processes, the number of processes,
the child process, a failing child, and (slow) a new cache filled by the processes so that the
run's own warm-up compiles nothing. That the groups call every kernel the frame loop calls is
tests/e2e/test_run_cli.py::test_warm_up_loads_every_kernel_the_frame_loop_calls."""

from __future__ import annotations

import itertools
import logging
import os
import pickle
import subprocess
import sys
import types
from pathlib import Path

import pytest

from evperc import warm
from evperc.config import default_config
from evperc.errors import UsageError
from evperc.warm import GROUPS, PROCESSES_ENV, WarmSpec, buckets, compile_processes

ROOT = Path(__file__).resolve().parents[1]


def best_makespan(n: int) -> float:
    """The least time the slowest of ``n`` processes takes, over every assignment of the
    groups to processes (brute force: 4 groups, at most 4⁴ assignments)."""
    costs = [cost for _, cost in GROUPS.values()]
    best = float("inf")
    for assignment in itertools.product(range(n), repeat=len(costs)):
        loads = [0.0] * n
        for k, cost in zip(assignment, costs, strict=True):
            loads[k] += cost
        best = min(best, max(loads))
    return best


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_buckets_share_every_group_once_as_evenly_as_possible(n: int) -> None:
    lists = buckets(list(GROUPS), n)
    assert len(lists) == n and all(lists)
    assert sorted(g for names in lists for g in names) == sorted(GROUPS)
    makespan = max(sum(GROUPS[g][1] for g in names) for names in lists)
    assert makespan == best_makespan(n)


def test_more_processes_than_groups_get_one_group_each() -> None:
    assert sorted(map(tuple, buckets(list(GROUPS), 9))) == sorted((g,) for g in GROUPS)
    assert buckets(list(GROUPS), 0) == [sorted(GROUPS, key=lambda g: -GROUPS[g][1])]


def test_processes_follow_the_cpus_at_most_one_per_group(monkeypatch) -> None:
    monkeypatch.delenv(PROCESSES_ENV, raising=False)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    assert compile_processes() == 2
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(64)), raising=False)
    assert compile_processes() == len(GROUPS)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0}, raising=False)
    assert compile_processes() == 1


def test_a_dask_worker_compiles_in_its_own_process(monkeypatch) -> None:
    monkeypatch.delenv(PROCESSES_ENV, raising=False)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(8)), raising=False)
    fake = types.ModuleType("distributed")
    fake.get_worker = lambda: object()  # inside a task
    monkeypatch.setitem(sys.modules, "distributed", fake)
    assert compile_processes() == 1

    def outside() -> object:
        raise ValueError("No worker found")

    fake.get_worker = outside
    assert compile_processes() == 4


@pytest.mark.parametrize(("value", "expected"), [("1", 1), (" 3 ", 3), ("16", 16)])
def test_the_environment_sets_the_processes(monkeypatch, value: str, expected: int) -> None:
    monkeypatch.setenv(PROCESSES_ENV, value)
    assert compile_processes() == expected


@pytest.mark.parametrize("value", ["0", "-2", "two", "1.5"])
def test_a_bad_process_count_is_a_one_line_usage_error(monkeypatch, value: str) -> None:
    monkeypatch.setenv(PROCESSES_ENV, value)
    with pytest.raises(UsageError, match=f"^{PROCESSES_ENV}=") as err:
        compile_processes()
    assert "\n" not in str(err.value)


def child(groups: list[str], config: dict | None = None) -> subprocess.CompletedProcess:
    payload = pickle.dumps((groups, config or default_config(), True))
    return subprocess.run(warm.child_command(), input=payload, capture_output=True,
                          cwd=ROOT, timeout=600, check=False)


def test_the_child_warms_its_groups_and_refuses_unknown_ones() -> None:
    done = child(["sensor"])
    assert done.returncode == 0, done.stderr.decode()
    refused = child(["sensor", "nope"])
    assert refused.returncode == 2
    message = refused.stderr.decode().strip()
    assert "nope" in message and all(g in message for g in GROUPS)


def test_a_failing_child_leaves_its_groups_to_this_process(monkeypatch, caplog) -> None:
    """Two processes: the child exits 3 at once; this process compiles its own bucket, then
    warm_up calls every group here all the same."""
    called: list[str] = []
    monkeypatch.setattr(warm, "kernels_cached", lambda: False)
    monkeypatch.setenv(PROCESSES_ENV, "2")
    monkeypatch.setattr(warm, "child_command",
                        lambda: [sys.executable, "-c", "import sys; sys.stderr.write("
                                 "'boom\\n'); sys.exit(3)"])
    monkeypatch.setitem(GROUPS, "fusion", (lambda spec: called.append("fusion"), 23.0))
    for name in ("objects", "object_passes", "sensor"):
        monkeypatch.setitem(GROUPS, name,
                            (lambda spec, name=name: called.append(name), GROUPS[name][1]))
    with caplog.at_level(logging.DEBUG, logger="evperc.warm"):
        warm.warm_up(WarmSpec(default_config(), has_map=False))
    first, second = buckets(list(GROUPS), 2)
    assert called == first + list(GROUPS)
    assert any("exited with 3 (boom)" in r.getMessage() for r in caplog.records)


@pytest.mark.slow
def test_the_processes_fill_a_new_cache_with_every_kernel_of_the_warm_up(tmp_path) -> None:
    """A new NUMBA_CACHE_DIR: not cached; compile_kernels in 2 processes fills it; then a
    fresh process's warm-up saves no new compiled code (NUMBA_DEBUG_CACHE logs each save)
    and finds the kernels cached. About a minute on 2 cores."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), PROCESSES_ENV: "2"}
    script = ("from evperc.config import default_config; from evperc import warm; "
              "print('cached before', warm.kernels_cached()); "
              "warm.{call}(warm.WarmSpec(default_config(), True)); "
              "print('cached after', warm.kernels_cached())")
    first = subprocess.run([sys.executable, "-c", script.format(call="compile_kernels")],
                           env=env, cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert first.returncode == 0, first.stderr
    assert "cached before False" in first.stdout and "cached after True" in first.stdout
    second = subprocess.run([sys.executable, "-c", script.format(call="warm_up")],
                            env={**env, "NUMBA_DEBUG_CACHE": "1"}, cwd=ROOT,
                            capture_output=True, text=True, timeout=900)
    assert second.returncode == 0, second.stderr
    assert "cached before True" in second.stdout
    assert "data loaded from" in second.stdout
    assert "data saved to" not in second.stdout


def test_kernels_are_not_cached_in_an_empty_cache_and_are_in_this_sessions(tmp_path) -> None:
    """kernels_cached() asks numba's own index of the fused kernel: a new empty
    NUMBA_CACHE_DIR has none (a process of its own: numba reads the variable at import);
    this test session has run the kernel by now, in its own cache (a run first)."""
    script = "from evperc.plumbing import kernels_cached; print(kernels_cached())"
    empty = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True,
                           text=True, timeout=300, check=True,
                           env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "empty")})
    assert empty.stdout.strip() == "False"
    warm.warm_group("fusion", WarmSpec(default_config(), has_map=True))  # compiled or loaded
    assert warm.kernels_cached()


def test_without_an_interpreter_to_start_this_process_compiles_everything(monkeypatch) -> None:
    """An embedded Python has no sys.executable: no child is started."""
    called: list[str] = []
    monkeypatch.setattr(sys, "executable", "")
    monkeypatch.setattr(subprocess, "Popen", lambda *a, **k: pytest.fail("a child started"))
    for name in list(GROUPS):
        monkeypatch.setitem(GROUPS, name,
                            (lambda spec, name=name: called.append(name), GROUPS[name][1]))
    warm.compile_in_processes(WarmSpec(default_config(), has_map=False), 4)
    assert sorted(called) == sorted(GROUPS)


def test_the_warm_up_reads_no_uninitialised_memory(monkeypatch) -> None:
    """Every group's passes on memory that ``np.empty`` left full of bytes no layer holds
    (200 in each byte, NaN floats, True bools), as a new process's allocator may: the passes
    that read a layer as data (the decision counts, the unmapped cue, the object stage) get
    layers whose values they were written to hold. It failed when the 2 × 2 frame the
    passes share came from ``np.empty`` (an intermittent "decision codes beyond 6" at a
    run's start-up, four clean-clone CI runs of 2026-12-07, in batch workers)."""
    import numpy as np

    real_empty = np.empty

    def garbage(shape, dtype=float, *args, **kwargs):
        out = real_empty(shape, dtype, *args, **kwargs)
        kind = np.dtype(dtype).kind
        out[...] = (np.nan if kind == "f" else True if kind == "b" else 200)
        return out

    monkeypatch.setattr(np, "empty", garbage)
    spec = WarmSpec(default_config(), has_map=True)
    for name in GROUPS:
        warm.warm_group(name, spec)
