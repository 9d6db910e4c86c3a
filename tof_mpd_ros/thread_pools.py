"""Process-wide worker thread pools, kept for the life of the process (a frame's work is split
over the calling thread plus a pool, and starting threads per frame would cost more than the
work)."""

from __future__ import annotations

import os
import threading
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
