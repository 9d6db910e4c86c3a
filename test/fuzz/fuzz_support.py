"""Shared pieces of the fuzz tests: deterministic Hypothesis settings, a per-case hang guard, the
property every reader must keep, and byte-level mutation strategies.

The property (issue 15, item 4): a reader given damaged outside data either returns valid data or
raises the package's typed error naming the file; never another exception, never a hang.
"""

from __future__ import annotations

import signal
import time
import tracemalloc
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import TypeVar

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

from tof_mpd_ros.errors import TofMpdError

T = TypeVar("T")

# Deterministic in CI: the same cases on every run and machine, nothing remembered between runs
# (a new random case must never turn a green CI red by itself). No deadline: the machine is shared.
settings.register_profile(
    "fuzz", derandomize=True, database=None, deadline=None, print_blob=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                           HealthCheck.function_scoped_fixture])
FUZZ = settings.get_profile("fuzz")

# Only catches hangs: a case takes milliseconds, so 20 s of wall clock is far beyond any load.
CASE_LIMIT_S = 20.0


class CaseHung(BaseException):
    """Raised by the alarm; a BaseException so that no reader's ``except Exception`` hides it."""


@contextmanager
def hang_guard(limit_s: float = CASE_LIMIT_S) -> Iterator[None]:
    """Fail the case if its body runs longer than ``limit_s`` (SIGALRM, main thread).

    pytest-timeout also arms SIGALRM: its handler and remaining time are put back afterwards.
    """

    def _alarm(_signum: int, _frame: FrameType | None) -> None:
        raise CaseHung

    previous = signal.signal(signal.SIGALRM, _alarm)
    old_delay, old_interval = signal.setitimer(signal.ITIMER_REAL, limit_s)
    started = time.monotonic()
    try:
        yield
    except CaseHung:
        raise AssertionError(f"the reader ran for more than {limit_s} s (hang)") from None
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
        if old_delay:
            remaining = max(old_delay - (time.monotonic() - started), 1e-3)
            signal.setitimer(signal.ITIMER_REAL, remaining, old_interval)


def read_or_typed_error(read: Callable[[], T], path: Path,
                        error: type[TofMpdError] = TofMpdError) -> T | TofMpdError:
    """Run ``read`` under the hang guard; return its value or the typed error it raised.

    Any exception that is not ``error`` propagates and fails the test. A typed error must name
    ``path`` (the file, or the recording directory holding the file at fault) and say more.
    """
    try:
        with hang_guard():
            return read()
    except error as err:
        message = str(err)
        assert path.name in message, f"error does not name {path.name}: {message!r}"
        assert len(message) > len(str(path)) + 5, f"error names no problem: {message!r}"
        return err


def peak_allocation(call: Callable[[], object]) -> int:
    """Peak bytes Python and numpy allocated while ``call`` ran (exceptions are swallowed)."""
    tracemalloc.start()
    try:
        call()
    except Exception:  # only the memory matters here; the behaviour is tested elsewhere
        pass
    finally:
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    return peak


# ------------------------------------------------------------------------- byte mutations
# Mutations are drawn as plain values (positions are taken modulo the blob's length), so that a
# regression case can be written down as an ``@example``.

# Integers that break length and size fields: zero, one, off-by-one, sign bits, all ones.
EDGE_INTS = (0, 1, 2, 7, 8, 255, 256, 65535, 2**31 - 1, 2**31, 2**32 - 1, 2**32, 2**62,
             2**63 - 1, 2**63, 2**64 - 1)

positions = st.integers(0, 2**32)
flips = st.lists(st.tuples(positions, st.integers(1, 255)), min_size=1, max_size=4)
# A lie told by a size/length field: an edge value, or (relative) the true value off by a little.
lies = st.one_of(st.tuples(st.sampled_from(EDGE_INTS), st.just(False)),
                 st.tuples(st.integers(-64, 64), st.just(True)))


def cut(blob: bytes, at: int) -> bytes:
    """``blob`` truncated to ``at`` modulo its length (never the whole blob)."""
    return blob[:at % len(blob)]


def flip(blob: bytes, changes: list[tuple[int, int]]) -> bytes:
    """``blob`` with the byte at each position (modulo the length) XORed with its mask."""
    out = bytearray(blob)
    for where, mask in changes:
        out[where % len(out)] ^= mask
    return bytes(out)


def lie_about(blob: bytes, offset: int, width: int, lie: tuple[int, bool]) -> bytes:
    """``blob`` with the little-endian ``width``-byte field at ``offset`` replaced by the lie."""
    value, relative = lie
    if relative:
        value = max(0, int.from_bytes(blob[offset:offset + width], "little") + value)
    value %= 2 ** (8 * width)
    return blob[:offset] + value.to_bytes(width, "little") + blob[offset + width:]
