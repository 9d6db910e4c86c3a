"""Pair depth and amplitude images by stamp, and hand work to a worker through a bounded queue.

Pure Python (no rclpy) so both pieces are unit-tested without ROS. ``message_filters`` is not
installable from PyPI, and the corrector needs only a two-topic approximate-time pairing, so this
is a small purpose-built replacement rather than a port.
"""

from __future__ import annotations

import collections
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Generic, TypeVar

T = TypeVar("T")
U = TypeVar("U")


@dataclass
class PairingStats:
    """Counters of what the pairer did with its input."""

    paired: int = 0
    unmatched_left: int = 0
    unmatched_right: int = 0
    out_of_order_dropped: int = 0
    resets: int = 0

    @property
    def unmatched_dropped(self) -> int:
        """Messages of either stream dropped without a partner."""
        return self.unmatched_left + self.unmatched_right


@dataclass
class StampPairer(Generic[T, U]):
    """Approximate-time pairing of two streams (e.g. depth and amplitude images).

    A message is matched with the closest-stamped message of the other stream within
    ``tolerance_ns``. Messages older than the newest emitted pair are out of order and dropped;
    unmatched messages are kept up to ``history`` per stream, then dropped (oldest first). Every
    drop is counted in :attr:`stats`.

    With ``reset_after`` > 0, that many out-of-order messages in a row are taken for a jump
    back in time (a recording replayed from its start, a restarted camera): the pairer forgets
    its state (counted in ``stats.resets``) and pairs from the current message on. 0 never
    resets.
    """

    tolerance_ns: int
    history: int = 8
    reset_after: int = 0
    stats: PairingStats = field(default_factory=PairingStats)
    _left: collections.deque = field(init=False)
    _right: collections.deque = field(init=False)
    _last_emitted_ns: int = field(default=-1, init=False)
    _streak: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        if self.tolerance_ns < 0 or self.history < 1 or self.reset_after < 0:
            raise ValueError("tolerance_ns must be >= 0, history >= 1 and reset_after >= 0")
        self._left = collections.deque()
        self._right = collections.deque()

    @property
    def last_emitted_ns(self) -> int:
        """Stamp (ns) of the newest message of the last emitted pair; -1 before the first."""
        return self._last_emitted_ns

    def add_left(self, stamp_ns: int, message: T) -> tuple[int, T, U] | None:
        """Add a left-stream message; returns ``(stamp_ns, left, right)`` when a pair forms."""
        return self._add(self._left, self._right, stamp_ns, message, left_first=True)

    def add_right(self, stamp_ns: int, message: U) -> tuple[int, T, U] | None:
        """Add a right-stream message; returns ``(stamp_ns, left, right)`` when a pair forms."""
        return self._add(self._right, self._left, stamp_ns, message, left_first=False)

    def _add(self, mine: collections.deque, other: collections.deque, stamp_ns: int,
             message: object, *, left_first: bool) -> tuple | None:
        if stamp_ns <= self._last_emitted_ns:
            self._streak += 1
            if not self.reset_after or self._streak < self.reset_after:
                self.stats.out_of_order_dropped += 1
                return None
            # Time went back: start again from this message; those still waiting for a partner
            # are dropped as unmatched.
            self._reset()
        else:
            self._streak = 0
        best = min(range(len(other)), key=lambda i: abs(other[i][0] - stamp_ns), default=None)
        if best is not None and abs(other[best][0] - stamp_ns) <= self.tolerance_ns:
            other_stamp, other_message = other[best]
            # Everything older than the match can no longer pair with anything newer.
            for _ in range(best):
                other.popleft()
                self._unmatched(left=not left_first)
            other.popleft()
            while mine and mine[0][0] < stamp_ns:
                mine.popleft()
                self._unmatched(left=left_first)
            self._last_emitted_ns = max(stamp_ns, other_stamp)
            self.stats.paired += 1
            pair = (message, other_message) if left_first else (other_message, message)
            return (min(stamp_ns, other_stamp), *pair)
        mine.append((stamp_ns, message))
        while len(mine) > self.history:
            mine.popleft()
            self._unmatched(left=left_first)
        return None

    def _reset(self) -> None:
        for _ in self._left:
            self._unmatched(left=True)
        for _ in self._right:
            self._unmatched(left=False)
        self._left.clear()
        self._right.clear()
        self._last_emitted_ns = -1
        self._streak = 0
        self.stats.resets += 1

    def _unmatched(self, *, left: bool) -> None:
        if left:
            self.stats.unmatched_left += 1
        else:
            self.stats.unmatched_right += 1


class LatestQueueWorker(Generic[T]):
    """A worker thread fed through a bounded drop-oldest queue.

    The subscription callback calls :meth:`submit` (never blocks); the worker calls ``process``
    on each item. When the queue is full the oldest item is dropped and counted, so a slow
    consumer sheds load instead of building latency.
    """

    def __init__(self, process: Callable[[T], None], *, maxsize: int = 2,
                 on_error: Callable[[BaseException], None] | None = None) -> None:
        if maxsize < 1:
            raise ValueError("maxsize must be >= 1")
        self._process = process
        self._on_error = on_error
        self._queue: collections.deque[T] = collections.deque()
        self._maxsize = maxsize
        self._cond = threading.Condition()
        self._stopping = False
        self._busy = False
        self.dropped = 0
        self.processed = 0
        self.failed = 0
        self._thread = threading.Thread(target=self._run, name="tof_mpd_worker", daemon=True)
        self._thread.start()

    def submit(self, item: T) -> None:
        with self._cond:
            if len(self._queue) >= self._maxsize:
                self._queue.popleft()
                self.dropped += 1
            self._queue.append(item)
            self._cond.notify()

    @property
    def maxsize(self) -> int:
        """How many items may wait; the oldest is dropped beyond."""
        return self._maxsize

    def resize(self, maxsize: int) -> int:
        """Change :attr:`maxsize` while running; returns how many waiting items were dropped
        (the oldest, when the queue holds more than the new size; also counted in
        :attr:`dropped`)."""
        if maxsize < 1:
            raise ValueError("maxsize must be >= 1")
        with self._cond:
            self._maxsize = maxsize
            n = max(0, len(self._queue) - maxsize)
            for _ in range(n):
                self._queue.popleft()
            self.dropped += n
            return n

    @property
    def alive(self) -> bool:
        """Whether the worker thread runs (it ends only after :meth:`stop`)."""
        return self._thread.is_alive()

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._stopping:
                    self._cond.wait()
                if self._stopping and not self._queue:
                    return
                item = self._queue.popleft()
                self._busy = True
            try:
                self._handle(item)
            finally:
                with self._cond:
                    self._busy = False
                    self._cond.notify_all()

    def _handle(self, item: T) -> None:
        """Process one item; nothing it raises, nor its error handler, ends the thread."""
        try:
            self._process(item)
            self.processed += 1
        except Exception as err:  # a bad frame must not kill the worker
            self.failed += 1
            self._report(err)

    def _report(self, err: Exception) -> None:
        if self._on_error is None:
            return
        try:
            self._on_error(err)
        except Exception as handler_err:  # nor may a failing report (e.g. a logging error)
            last_resort_report(f"{self._thread.name}: error handler failed on {err!r}: "
                         f"{handler_err!r}")

    def drain(self, timeout: float | None = None) -> bool:
        """Wait until the queue is empty and the worker idle; False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: not self._queue and not self._busy, timeout)

    def stop(self, timeout: float = 5.0, *, discard: bool = False) -> None:
        """Stop the thread after the queued items (or, with ``discard``, without them)."""
        with self._cond:
            if discard:
                self._queue.clear()
            self._stopping = True
            self._cond.notify_all()
        self._thread.join(timeout)


def last_resort_report(line: str) -> None:
    """One line on stderr when nothing better is left; never raises."""
    try:
        sys.stderr.write(line + "\n")
        sys.stderr.flush()
    except Exception:  # stderr closed: nothing left to tell
        pass
