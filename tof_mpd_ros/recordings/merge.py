"""Merge recordings made in parts (a dataset rendered in shards) into one, message for message.

Messages are copied as decoded, not rebuilt as frames, so every value stays as recorded (a frame
rebuilt from a ``32FC1`` range in metres and written again would move about 2 % of its values
by one float32 step). The inputs are merged in log-time order, each input's own order kept.
"""

from __future__ import annotations

import heapq
import shutil
from collections.abc import Iterator, Sequence
from pathlib import Path

from ..errors import InputError
from .reader import RecordedMessage, RecordingReader
from .topics import KEY_VERSION
from .writer import RecordingWriter

#: ``custom_data`` keys that may differ between the parts (the version that wrote each)
_PER_PART_KEYS = frozenset({KEY_VERSION})


def merge_recordings(out: str | Path, parts: Sequence[str | Path], *,
                     compression: str = "zstd") -> dict[str, int]:
    """Write the recording ``out`` holding every message of ``parts``, in log-time order.

    Args:
        out: the recording directory to create (must not exist).
        parts: recordings written by the same kind of writer (the same ``custom_data``:
            topics, range convention and encoding, modulation frequency).
        compression: MCAP chunk compression of ``out``.

    Returns:
        Messages written per topic.

    Raises:
        InputError: no parts, parts that disagree on ``custom_data``, or two parts holding a
            message of the same topic at the same time (they overlap).
        RecordingError: a part cannot be read, or ``out`` exists.
    """
    if not parts:
        raise InputError("nothing to merge: no recordings given")
    readers = [RecordingReader(p) for p in parts]
    try:
        custom = _common_custom_data(readers, parts)
        counts: dict[str, int] = {}
        last: dict[str, tuple[int, int]] = {}  # topic -> (log time, part) of its last message
        writer = RecordingWriter(out, compression=compression, custom_data=custom)
        try:
            with writer:
                for part, m in heapq.merge(*(_tagged(r, k) for k, r in enumerate(readers)),
                                           key=lambda x: x[1].log_time_ns):
                    seen = last.get(m.topic)
                    if seen is not None and seen[0] == m.log_time_ns and seen[1] != part:
                        raise InputError(
                            f"{parts[seen[1]]} and {parts[part]} both hold {m.topic} at "
                            f"{m.log_time_ns} ns: the parts overlap")
                    last[m.topic] = (m.log_time_ns, part)
                    writer.write(m.topic, m.msgtype, m.message, m.log_time_ns)
                    counts[m.topic] = counts.get(m.topic, 0) + 1
        except BaseException:
            shutil.rmtree(out, ignore_errors=True)  # no half-merged recording is left behind
            raise
        return counts
    finally:
        for r in readers:
            r.close()


def _tagged(reader: RecordingReader, part: int) -> Iterator[tuple[int, RecordedMessage]]:
    for m in reader.messages():
        yield part, m


def _common_custom_data(readers: Sequence[RecordingReader],
                        parts: Sequence[str | Path]) -> dict[str, str]:
    """The parts' ``custom_data`` together (without what each part may have of its own). A
    key one part lacks is no disagreement: an empty part never recorded a frame's modulation
    frequency."""
    merged: dict[str, str] = {}
    owner: dict[str, str | Path] = {}
    for reader, path in zip(readers, parts, strict=True):
        for key, value in reader.custom_data.items():
            if key in _PER_PART_KEYS:
                continue
            if key in merged and merged[key] != value:
                raise InputError(f"{path} differs from {owner[key]} in {key} ({value!r} vs "
                                 f"{merged[key]!r}): not parts of one recording")
            merged.setdefault(key, value)
            owner.setdefault(key, path)
    return merged


__all__ = ["merge_recordings"]
