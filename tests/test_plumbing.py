"""prefetched(): order, exceptions with their type, early stops that join the thread, and the
bound on how far the producer runs ahead."""

from __future__ import annotations

import contextlib
import signal
import threading
import time

import numpy as np
import pytest

from evperc.errors import LogError
from evperc.logs.factory import open_log
from evperc.plumbing import prefetched
from tests.logs.reference import S0
from tests.mcap_writers import transform, write_ros2_mcap

WAIT_S = 10.0  # generous upper bound for a thread to reach a state; never a speed check


class Source:
    """An iterator over 0, 1, … n−1 that records how many items were pulled, whether it was
    closed, and raises ``error`` instead of yielding item ``fail_at``."""

    def __init__(self, n: int, fail_at: int | None = None, error: BaseException | None = None):
        self.n, self.fail_at, self.error = n, fail_at, error
        self.pulled = 0
        self.closed = threading.Event()
        self.pulled_changed = threading.Condition()
        self.threads: set[str] = set()

    def __iter__(self):
        try:
            for i in range(self.n):
                self.threads.add(threading.current_thread().name)
                if i == self.fail_at:
                    raise self.error
                with self.pulled_changed:
                    self.pulled += 1
                    self.pulled_changed.notify_all()
                yield i
        finally:
            self.closed.set()

    def wait_pulled(self, count: int) -> bool:
        with self.pulled_changed:
            return self.pulled_changed.wait_for(lambda: self.pulled >= count, WAIT_S)


def _threads(name: str) -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == name]


def test_items_come_in_order_from_a_named_daemon_thread():
    source = Source(500)
    seen = []
    for item in prefetched(source, depth=3, name="test-order"):
        seen.append(item)
        if len(seen) == 1:
            (thread,) = _threads("test-order")
            assert thread.daemon
    assert seen == list(range(500))
    assert source.threads == {"test-order"}
    assert source.closed.is_set()
    assert _threads("test-order") == []


def test_plain_iterables_and_empty_sources():
    assert list(prefetched([3, 1, 2], depth=1)) == [3, 1, 2]
    assert list(prefetched(iter(()), depth=2)) == []


def test_a_non_iterable_fails_in_the_consumer():
    with pytest.raises(TypeError):
        next(prefetched(42))


def test_depth_below_one_is_refused():
    with pytest.raises(ValueError, match="at least 1"):
        prefetched([1], depth=0)


@pytest.mark.parametrize("error", [LogError("log.mcap: the file ends inside a record"),
                                   KeyError("x"), ZeroDivisionError("division by zero")])
def test_producer_exception_reaches_the_consumer_in_place(error):
    source = Source(10, fail_at=4, error=error)
    seen = []
    with pytest.raises(type(error)) as caught:
        for item in prefetched(source, name="test-error"):
            seen.append(item)
    assert caught.value is error
    assert str(caught.value) == str(error)
    assert seen == [0, 1, 2, 3]  # everything before the failure, nothing after
    assert _threads("test-error") == []


@pytest.mark.parametrize("depth", [1, 2, 5])
def test_producer_never_more_than_depth_plus_one_ahead(depth):
    """``requested`` counts next() calls begun; the producer may hold ``depth`` items in the
    queue and one in hand, so pulled − requested ≤ depth + 1, and it does get that far."""
    source = Source(40)
    requested = 0
    worst = 0
    items = prefetched(source, depth=depth, name="test-bound")
    for expected in range(40):
        requested += 1
        assert next(items) == expected
        # let the producer run as far ahead as it can before checking the bound
        assert source.wait_pulled(min(requested + depth + 1, 40))
        with source.pulled_changed:
            ahead = source.pulled - requested
        worst = max(worst, ahead)
        assert ahead <= depth + 1
    assert worst == min(depth + 1, 39)
    with pytest.raises(StopIteration):
        next(items)


def test_close_stops_and_joins_the_producer():
    source = Source(10_000)
    items = prefetched(source, depth=2, name="test-close")
    assert [next(items) for _ in range(3)] == [0, 1, 2]
    assert source.wait_pulled(3 + 2 + 1)
    items.close()
    assert _threads("test-close") == []
    assert source.closed.is_set()
    assert source.pulled <= 3 + 2 + 1


def test_break_stops_the_producer():
    source = Source(10_000)
    for item in prefetched(source, depth=2, name="test-break"):
        if item == 5:
            break
    assert _threads("test-break") == []  # the loop's generator is closed as it is dropped
    assert source.closed.is_set()
    assert source.pulled <= 6 + 2 + 1


def test_consumer_exception_stops_the_producer():
    source = Source(10_000)
    with pytest.raises(RuntimeError, match="fusion failed"):
        with contextlib.closing(prefetched(source, name="test-consumer-error")) as items:
            for item in items:
                if item == 2:
                    raise RuntimeError("fusion failed")
    assert _threads("test-consumer-error") == []
    assert source.closed.is_set()


def test_ctrl_c_in_the_consumer_stops_the_producer():
    """A real SIGINT to the main thread while it consumes (blocked in the queue or not)."""
    main = threading.main_thread()
    if threading.current_thread() is not main:
        pytest.skip("signals go to the main thread")

    class Interrupting(Source):
        def __iter__(self):
            for i in super().__iter__():
                if i == 3:
                    signal.pthread_kill(main.ident, signal.SIGINT)
                yield i

    source = Interrupting(100_000)
    seen = []
    # Python's own Ctrl-C handler, whatever the test process inherited: a background job of
    # a non-interactive shell (`nohup ... &`) starts with SIGINT ignored, and Python then
    # installs no handler, so no KeyboardInterrupt would ever come
    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            with contextlib.closing(prefetched(source, name="test-sigint")) as items:
                for item in items:
                    seen.append(item)
    finally:
        signal.signal(signal.SIGINT, inherited)
    assert _threads("test-sigint") == []
    assert source.closed.is_set()
    assert seen == list(range(len(seen)))
    assert len(seen) < 1000


def test_producer_blocked_on_a_full_queue_is_released_by_close():
    source = Source(100)
    items = prefetched(source, depth=1, name="test-full")
    assert next(items) == 0
    assert source.wait_pulled(3)  # item 1 in the queue, item 2 in hand: blocked on put
    items.close()
    assert _threads("test-full") == []
    assert source.pulled == 3


def test_posed_scans_of_a_log_come_through_unchanged(tmp_path):
    """The reader's scans, prefetched, equal the scans read directly, and its skipped-scan
    counts are complete once the prefetched stream ends."""
    ms = 1_000_000
    rng = np.random.default_rng(5)
    clouds = [(S0 + t * ms, rng.normal(0, 10, (200, 3)), "base_link")
              for t in (-300, 0, 100, 100, 200, 300, 400)]
    odometry = [(S0 + t * ms, transform(x=t / 1000, yaw=t / 2000)) for t in range(-50, 451, 50)]
    path = write_ros2_mcap(tmp_path / "drive.mcap", clouds=clouds, odometry=odometry,
                           chunk_size=4096)
    direct_log = open_log(path)
    direct = list(direct_log.scans())
    log = open_log(path)
    with contextlib.closing(prefetched(log.scans(), depth=2, name="test-log")) as scans:
        got = list(scans)
    assert log.stats == direct_log.stats == {"before_pose_span": 1, "duplicate_stamp": 1}
    assert [s.stamp_ns for s in got] == [S0 + t * ms for t in (0, 100, 200, 300, 400)]
    for a, b in zip(got, direct, strict=True):
        assert a.stamp_ns == b.stamp_ns and a.frame_id == b.frame_id
        np.testing.assert_array_equal(a.points, b.points)
        np.testing.assert_array_equal(a.T_world_sensor, b.T_world_sensor)


def _busy(seconds: float) -> None:
    end = time.thread_time() + seconds
    while time.thread_time() < end:
        pass


def test_cpu_time_of_the_producer_thread_is_reported() -> None:
    """``cpu_s`` holds the producer thread's CPU time, not wall time: items that each burn
    30 ms of CPU add up; items that sleep (off the CPU) do not."""
    def burning():
        for i in range(3):
            _busy(0.03)
            yield i

    def sleeping():
        for i in range(3):
            time.sleep(0.05)
            yield i

    busy_cpu, idle_cpu = [0.0], [0.0]
    assert list(prefetched(burning(), depth=1, cpu_s=busy_cpu)) == [0, 1, 2]
    assert list(prefetched(sleeping(), depth=1, cpu_s=idle_cpu)) == [0, 1, 2]
    assert busy_cpu[0] >= 0.09
    assert idle_cpu[0] < 0.05


def test_hungry_is_set_while_the_consumer_has_nothing_queued() -> None:
    """``hungry`` tells the source that the consumer waits (or will at its next request):
    set when the consumer asks with an empty queue, clear once an item is queued for it."""
    hungry = threading.Event()
    seen: list[bool] = []
    second_checked = threading.Event()

    def source():
        seen.append(hungry.wait(WAIT_S))  # the consumer is waiting for the first item
        yield 0
        yield 1  # queued: the consumer has an item waiting
        seen.append(hungry.is_set())
        second_checked.set()
        yield 2

    items = prefetched(source(), depth=2, hungry=hungry)
    assert next(items) == 0
    assert second_checked.wait(WAIT_S)
    assert seen == [True, False]
    assert list(items) == [1, 2]
    assert hungry.is_set()  # the consumer asked again and found the queue empty
