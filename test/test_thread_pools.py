"""tof_mpd_ros.thread_pools: the one registry of worker pools (the correction's and the geodesic
filter's)."""

from __future__ import annotations

import os
import threading

import pytest

from tof_mpd_ros.thread_pools import shared_pool


def test_one_pool_per_user_and_size_kept_for_the_process() -> None:
    pool = shared_pool("test-a", 3)
    assert shared_pool("test-a", 3) is pool
    assert shared_pool("test-b", 3) is not pool   # users never queue behind each other
    assert shared_pool("test-a", 2) is not pool
    assert pool._max_workers == 2                 # the caller is the third worker
    name = pool.submit(lambda: threading.current_thread().name).result()
    assert name.startswith("tof-mpd-test-a")


def test_concurrent_first_use_makes_one_pool() -> None:
    got: list[object] = []
    barrier = threading.Barrier(8)

    def use() -> None:
        barrier.wait()
        got.append(shared_pool("test-race", 4))

    threads = [threading.Thread(target=use) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len({id(p) for p in got}) == 1


@pytest.mark.skipif(not hasattr(os, "fork"), reason="POSIX only")
def test_a_forked_child_gets_fresh_pools() -> None:
    """The parent's pool threads do not exist in a forked child: it must not reuse the pool."""
    parent = shared_pool("test-fork", 2)
    parent.submit(int).result()  # its thread is running
    pid = os.fork()
    if pid == 0:  # the child: exit code 0 only if it gets a new pool that runs work
        ok = False
        try:
            child = shared_pool("test-fork", 2)
            ok = child is not parent and child.submit(lambda: 7).result(timeout=10) == 7
        finally:
            os._exit(0 if ok else 1)
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0
