"""Pair depth and amplitude images by stamp, and hand work to a worker through a bounded queue.

Pure Python (no rclpy) so both pieces are unit-tested without ROS. ``message_filters`` is not
installable from PyPI, and the corrector needs only a two-topic approximate-time pairing, so this
is a small purpose-built replacement rather than a port.
"""

from __future__ import annotations

import collections
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

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
    """Worker threads fed through a bounded drop-oldest queue.

    The subscription callback calls :meth:`submit` (never blocks); a worker calls ``process``
    on each item. When the queue is full the oldest item is dropped and counted, so a slow
    consumer sheds load instead of building latency.

    With ``workers`` > 1, that many items are processed at once, and ``process`` may return a
    *finish* step (a callable, e.g. publishing the result): finish steps run one at a time in
    the order their items left the queue, so the output keeps the input's order although
    the items are processed side by side. Why: a frame's correction runs its networks on
    one core far more efficiently than on two (each small operation of a 2-thread pass waits
    for a sleeping thread), so two frames at once on two cores nearly double the frames per
    second at 320×240 (docs/performance.md).
    """

    def __init__(self, process: Callable[[T], Callable[[], None] | None], *, maxsize: int = 2,
                 on_error: Callable[[BaseException], None] | None = None,
                 workers: int = 1) -> None:
        if maxsize < 1:
            raise ValueError("maxsize must be >= 1")
        if workers < 1:
            raise ValueError("workers must be >= 1")
        self._process = process
        self._on_error = on_error
        self._queue: collections.deque[T] = collections.deque()
        self._maxsize = maxsize
        self._cond = threading.Condition()
        self._stopping = False
        self._busy = 0
        self._taken = 0       # items handed to a worker so far (their order numbers)
        self._finished = 0    # items whose finish step has run (or that had none)
        self.dropped = 0
        self.processed = 0
        self.failed = 0
        self._threads = [threading.Thread(target=self._run, daemon=True,
                                          name="tof_mpd_worker" + (f"_{i}" if i else ""))
                         for i in range(workers)]
        for thread in self._threads:
            thread.start()

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

    @property
    def workers(self) -> int:
        """How many items are processed at once."""
        return len(self._threads)

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
        """Whether the worker threads run (they end only after :meth:`stop`)."""
        return all(thread.is_alive() for thread in self._threads)

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._stopping:
                    self._cond.wait()
                if self._stopping and not self._queue:
                    return
                item = self._queue.popleft()
                turn = self._taken
                self._taken += 1
                self._busy += 1
            ok = False
            try:
                ok, finish = self._attempt(self._process, item)
                self._wait_for_turn(turn)
                if ok and finish is not None:
                    ok, _ = self._attempt(finish)
            finally:   # every item takes its turn, whatever happened to it
                with self._cond:
                    self._finished += 1
                    self._busy -= 1
                    if ok:
                        self.processed += 1
                    else:
                        self.failed += 1
                    self._cond.notify_all()

    def _wait_for_turn(self, turn: int) -> None:
        """Until every item taken before item number ``turn`` has finished."""
        with self._cond:
            self._cond.wait_for(lambda: self._finished == turn)

    def _attempt(self, step: Callable[..., Any], *args: Any) -> tuple[bool, Any]:
        """``(True, step(*args))``, or ``(False, None)`` with the error reported: nothing a
        bad frame raises, nor the error handler, ends the thread."""
        try:
            return True, step(*args)
        except Exception as err:
            self._report(err)
            return False, None

    def _report(self, err: Exception) -> None:
        if self._on_error is None:
            return
        try:
            self._on_error(err)
        except Exception as handler_err:  # nor may a failing report (e.g. a logging error)
            last_resort_report(f"{threading.current_thread().name}: error handler failed on "
                               f"{err!r}: {handler_err!r}")

    def drain(self, timeout: float | None = None) -> bool:
        """Wait until the queue is empty and the workers idle; False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: not self._queue and not self._busy, timeout)

    def stop(self, timeout: float = 5.0, *, discard: bool = False) -> None:
        """Stop the threads after the queued items (or, with ``discard``, without them);
        waits up to ``timeout`` seconds in all."""
        with self._cond:
            if discard:
                self._queue.clear()
            self._stopping = True
            self._cond.notify_all()
        deadline = time.monotonic() + timeout
        for thread in self._threads:
            thread.join(max(0.0, deadline - time.monotonic()))


def last_resort_report(line: str) -> None:
    """One line on stderr when nothing better is left; never raises."""
    try:
        sys.stderr.write(line + "\n")
        sys.stderr.flush()
    except Exception:  # stderr closed: nothing left to tell
        pass
