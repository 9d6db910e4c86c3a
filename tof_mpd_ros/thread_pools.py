"""Process-wide worker thread pools, kept for the life of the process (a frame's work is split
over the calling thread plus a pool, and starting threads per frame would cost more than the
work)."""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

_POOLS: dict[tuple[str, int], ThreadPoolExecutor] = {}
_LOCK = threading.Lock()


def _forget_after_fork() -> None:
    """In a forked child the parent's pool threads do not exist (nor does a holder of the lock)."""
    global _LOCK
    _POOLS.clear()
    _LOCK = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_after_fork)


def shared_pool(name: str, workers: int) -> ThreadPoolExecutor:
    """The pool of ``workers - 1`` threads named ``tof-mpd-<name>-N`` (the caller is the last
    worker), made on first use; the package's one registry of worker pools.

    Each ``name`` has pools of its own, so one user's tasks never wait in a queue behind
    another's (nor deadlock on a pool whose threads are waiting for them). Thread-safe.

    Args:
        name: the user, e.g. ``"correct"`` or ``"geodesic"``.
        workers: threads that share the work, the caller included; at least 2.
    """
    with _LOCK:
        pool = _POOLS.get((name, workers))
        if pool is None:
            pool = _POOLS[(name, workers)] = ThreadPoolExecutor(
                max_workers=workers - 1, thread_name_prefix=f"tof-mpd-{name}")
        return pool


def run_chunks(name: str, workers: int, kernel: Callable[..., None], n_chunks: int,
               *args: object) -> None:
    """Run ``kernel(first, stride, n_chunks, *args)`` for ``first`` in ``range(workers)`` (at
    most ``n_chunks`` of them): the caller runs ``first`` 0, ``shared_pool(name, workers)``
    the others; returns when all are done and re-raises the first error.

    For serial, GIL-free numba kernels that take every ``stride``-th of ``n_chunks`` chunks
    from ``first`` on: plain Python threads rather than numba's OpenMP ``prange``, so no OpenMP
    team exists whose idle threads could spin against torch's in the same process.
    """
    workers = max(1, min(int(workers), n_chunks))
    if workers == 1:
        kernel(0, 1, n_chunks, *args)
        return
    pool = shared_pool(name, workers)
    futures = [pool.submit(kernel, t, workers, n_chunks, *args) for t in range(1, workers)]
    try:
        kernel(0, workers, n_chunks, *args)
    finally:
        for f in futures:
            f.result()
