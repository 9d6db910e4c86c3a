"""Stamp pairing and the drop-oldest worker queue (no ROS needed)."""

from __future__ import annotations

import threading
from collections.abc import Callable

import pytest

from tof_mpd_ros.nodes.pairing import LatestQueueWorker, StampPairer

MS = 1_000_000


def test_pairs_within_tolerance_in_either_order() -> None:
    pairer: StampPairer[str, str] = StampPairer(tolerance_ns=2 * MS)
    assert pairer.add_left(100 * MS, "d0") is None
    assert pairer.add_right(101 * MS, "a0") == (100 * MS, "d0", "a0")
    assert pairer.add_right(133 * MS, "a1") is None
    assert pairer.add_left(134 * MS, "d1") == (133 * MS, "d1", "a1")
    assert pairer.stats.paired == 2 and pairer.stats.unmatched_dropped == 0


def test_outside_tolerance_never_pairs_and_old_unmatched_are_counted() -> None:
    pairer: StampPairer[str, str] = StampPairer(tolerance_ns=1 * MS)
    pairer.add_left(100 * MS, "d0")           # its amplitude never arrives
    assert pairer.add_right(105 * MS, "a1") is None
    assert pairer.add_left(105 * MS, "d1") == (105 * MS, "d1", "a1")
    assert pairer.stats.unmatched_dropped == 1  # d0 can no longer pair


def test_out_of_order_stamps_are_dropped_and_counted() -> None:
    pairer: StampPairer[str, str] = StampPairer(tolerance_ns=1 * MS)
    pairer.add_left(200 * MS, "d1")
    pairer.add_right(200 * MS, "a1")
    assert pairer.add_left(150 * MS, "late") is None
    assert pairer.stats.out_of_order_dropped == 1


def test_history_bounds_memory() -> None:
    pairer: StampPairer[int, int] = StampPairer(tolerance_ns=0, history=3)
    for i in range(10):
        pairer.add_left(i * MS, i)
    assert pairer.stats.unmatched_dropped == 7


def _blocked_worker(maxsize: int) -> tuple[LatestQueueWorker[int], threading.Event,
                                            list[int]]:
    """A worker that has taken item 0 and blocks on it until the returned event is set; the
    list collects what it processed."""
    started, release = threading.Event(), threading.Event()
    seen: list[int] = []

    def slow(item: int) -> None:
        started.set()
        assert release.wait(60)
        seen.append(item)

    worker: LatestQueueWorker[int] = LatestQueueWorker(slow, maxsize=maxsize)
    worker.submit(0)
    assert started.wait(60)
    return worker, release, seen


def test_worker_drops_oldest_when_consumer_is_slow() -> None:
    worker, release, seen = _blocked_worker(maxsize=2)
    for i in range(1, 6):            # queue holds 2: items 1..3 are dropped, 4 and 5 kept
        worker.submit(i)
    release.set()
    assert worker.drain(60)
    worker.stop()
    assert seen == [0, 4, 5]
    assert worker.dropped == 3 and worker.processed == 3


def test_worker_survives_a_failing_item() -> None:
    errors: list[BaseException] = []

    def process(item: int) -> None:
        if item == 1:
            raise ValueError("bad frame")

    worker: LatestQueueWorker[int] = LatestQueueWorker(process, maxsize=4, on_error=errors.append)
    for i in range(3):
        worker.submit(i)
    assert worker.drain(60)
    worker.stop()
    assert worker.processed == 2 and worker.failed == 1
    assert isinstance(errors[0], ValueError)


def test_worker_survives_an_error_handler_that_raises(capfd: pytest.CaptureFixture) -> None:
    """The corrector's handler once raised (a logging error) and the thread died for good."""
    def process(item: int) -> None:
        if item % 2:
            raise ValueError(f"bad frame {item}")

    def on_error(err: BaseException) -> None:
        raise RuntimeError(f"the handler failed on {err}")

    worker: LatestQueueWorker[int] = LatestQueueWorker(process, maxsize=8, on_error=on_error)
    for i in range(6):
        worker.submit(i)
    assert worker.drain(60)
    assert worker.alive
    worker.stop()
    assert not worker.alive
    assert worker.processed == 3 and worker.failed == 3
    err = capfd.readouterr().err
    assert err.count("the handler failed on bad frame") == 3 and "Traceback" not in err


def test_invalid_configuration_is_rejected() -> None:
    with pytest.raises(ValueError):
        StampPairer(tolerance_ns=-1)
    with pytest.raises(ValueError):
        LatestQueueWorker(lambda item: None, maxsize=0)


def test_worker_queue_resizes_while_running_dropping_the_oldest() -> None:
    worker, release, seen = _blocked_worker(maxsize=4)   # item 0 is being processed; 1..4 wait
    for i in range(1, 5):
        worker.submit(i)
    assert worker.resize(2) == 2 and worker.maxsize == 2   # 1 and 2 go, 3 and 4 stay
    assert worker.resize(3) == 0
    worker.submit(5)                 # room for it now: nothing dropped
    release.set()
    assert worker.drain(60)
    worker.stop()
    assert seen == [0, 3, 4, 5] and worker.dropped == 2
    with pytest.raises(ValueError):
        worker.resize(0)


def test_two_workers_process_side_by_side_and_finish_in_order() -> None:
    """Item 0 is held until item 1 has been processed: both are in process at once, and
    item 1's finish step still runs after item 0's."""
    one_done = threading.Event()
    in_process: list[int] = []
    finished: list[int] = []
    lock = threading.Lock()

    def process(item: int) -> Callable[[], None]:
        with lock:
            in_process.append(item)
        if item == 0:
            assert one_done.wait(60)     # item 1 completes first
        elif item == 1:
            one_done.set()
        return lambda: finished.append(item)

    worker: LatestQueueWorker[int] = LatestQueueWorker(process, maxsize=8, workers=2)
    assert worker.workers == 2
    for i in range(6):
        worker.submit(i)
    assert worker.drain(60)
    worker.stop()
    assert not worker.alive
    assert finished == list(range(6)) and worker.processed == 6 and worker.failed == 0
    assert in_process[:2] in ([0, 1], [1, 0])


def test_a_failing_item_or_finish_step_keeps_the_order_of_the_others() -> None:
    errors: list[BaseException] = []
    finished: list[int] = []

    def process(item: int) -> Callable[[], None] | None:
        if item == 2:
            raise ValueError("bad frame")
        if item == 4:
            return None                  # dropped on purpose: counted as processed
        if item == 3:
            return lambda: (_ for _ in ()).throw(RuntimeError("publisher gone"))
        return lambda: finished.append(item)

    worker: LatestQueueWorker[int] = LatestQueueWorker(process, maxsize=8, workers=3,
                                                       on_error=errors.append)
    for i in range(7):
        worker.submit(i)
    assert worker.drain(60)
    worker.stop()
    assert finished == [0, 1, 5, 6]
    assert worker.processed == 5 and worker.failed == 2
    assert sorted(type(e).__name__ for e in errors) == ["RuntimeError", "ValueError"]
    with pytest.raises(ValueError):
        LatestQueueWorker(lambda item: None, workers=0)
