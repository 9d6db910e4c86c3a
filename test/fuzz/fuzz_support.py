"""Shared pieces of the fuzz tests: deterministic Hypothesis settings, a per-case hang guard, the
property every reader must keep, and byte-level mutation strategies.

The property (issue 15, item 4): a reader given damaged outside data either returns valid data or
raises the package's typed error naming the file; never another exception, never a hang.
"""

from __future__ import annotations

import io
import signal
import time
import tracemalloc
import warnings
import zipfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import Any, TypeVar

import numpy as np
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


# ------------------------------------------------------------------------- document mutations


def paths_of(node: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every key path of a YAML document (dict keys and list indexes)."""
    out = [prefix]
    children = node.items() if isinstance(node, dict) else (
        enumerate(node) if isinstance(node, list) else ())
    for key, child in children:
        out += paths_of(child, (*prefix, key))
    return out


def replaced(doc: Any, where: tuple[Any, ...], value: Any) -> Any:
    """A copy of ``doc`` with the node at ``where`` replaced by ``value``."""
    if not where:
        return value
    copy = dict(doc) if isinstance(doc, dict) else list(doc)
    copy[where[0]] = replaced(doc[where[0]], where[1:], value)
    return copy


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


# ------------------------------------------------------------------------- array mutations
# Wrong keys, dtypes, shapes and values in a dict of named arrays (an .npz before saving).

DTYPES = ("int8", "uint16", "int64", "float16", "float64", "complex64", "bool", "<U3", "S2",
          "V4", "object", "datetime64[s]", ">f4")
RESHAPES = ("flat", "add_axis", "drop_axis", "empty", "transpose", "scalar", "repeat")
VALUES = (float("nan"), float("inf"), float("-inf"), 0.0, -1.0, 1e38, -1e300, 2.0**63)
NEW_KEYS = ("extra", "range_mm.npy", "metadata", "calibration/c0", "range_net/extra", "",
            "stamp_ns", "pose")

array_mutations = st.lists(st.one_of(
    st.tuples(st.just("drop"), positions),
    st.tuples(st.just("add"), st.sampled_from(NEW_KEYS), st.sampled_from(VALUES)),
    st.tuples(st.just("dtype"), positions, st.sampled_from(DTYPES)),
    st.tuples(st.just("shape"), positions, st.sampled_from(RESHAPES)),
    st.tuples(st.just("value"), positions, positions, st.sampled_from(VALUES)),
), min_size=1, max_size=3)


def mutate_arrays(arrays: dict[str, np.ndarray], mutations: list[tuple[Any, ...]]
                  ) -> dict[str, np.ndarray]:
    """A copy of ``arrays`` with each mutation applied (keys are picked modulo their count)."""
    out = dict(arrays)
    for kind, *args in mutations:
        if kind == "add":
            out[args[0]] = np.array(args[1])
            continue
        if not out:
            continue
        key = sorted(out)[args[0] % len(out)]
        if kind == "drop":
            del out[key]
        else:
            out[key] = _mutated(out[key], kind, args[1:])
    return out


def _mutated(array: np.ndarray, kind: str, args: list[Any]) -> np.ndarray:
    array = np.asarray(array)  # an object array's element may be a plain Python value
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        if kind == "dtype":
            try:
                return array.astype(args[0])
            except (TypeError, ValueError, OverflowError, RuntimeError):  # e.g. date -> <U3
                return np.zeros(array.shape, args[0])
        if kind == "shape":
            return _reshaped(array, args[0])
        out = array.copy()
        if out.size:
            try:
                out.flat[args[0] % out.size] = args[1]
            except (TypeError, ValueError, OverflowError):
                pass
        return out


def _reshaped(array: np.ndarray, how: str) -> np.ndarray:
    if how == "flat":
        return array.reshape(-1)
    if how == "add_axis":
        return array[None]
    if how == "drop_axis":
        return array[0] if array.ndim and array.shape[0] else array
    if how == "empty":
        return array.reshape(-1)[:0]
    if how == "transpose":
        return array.T
    if how == "scalar":
        return array.reshape(-1)[:1].reshape(()) if array.size else array
    return np.concatenate([array, array]) if array.ndim else array  # "repeat"


def save_arrays(path: Path, arrays: dict[str, np.ndarray], compressed: bool) -> Path:
    """``np.savez`` (or ``savez_compressed``); object arrays are pickled, as numpy does."""
    with open(path, "wb") as stream:
        (np.savez_compressed if compressed else np.savez)(stream, **arrays)
    return path


def npy_claiming(shape: tuple[int, ...], dtype: str = "<f4", payload: bytes = b"\0" * 64
                 ) -> bytes:
    """An .npy member whose header claims ``shape`` but which holds only ``payload``."""
    stream = io.BytesIO()
    header = {"descr": dtype, "fortran_order": False, "shape": shape}
    np.lib.format.write_array_header_1_0(stream, header)
    return stream.getvalue() + payload


def with_member(path: Path, name: str, content: bytes) -> Path:
    """Rewrite the .npz at ``path`` with member ``name`` (e.g. ``range_mm.npy``) replaced."""
    with zipfile.ZipFile(path) as archive:
        members = {info.filename: archive.read(info) for info in archive.infolist()}
    members[name] = content
    with zipfile.ZipFile(path, "w") as archive:
        for member, data in members.items():
            archive.writestr(member, data)
    return path
