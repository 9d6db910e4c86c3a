"""Read and write "frames" files for the CLI: a recording directory or an NPZ interchange file.

Commands that take "a recording or an NPZ" and write "the same kind" go through these two
functions, so every command treats both formats alike.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path

from ..errors import RecordingError
from ..frame import ToFFrame


def is_npz(path: str | Path) -> bool:
    return Path(path).suffix.lower() == ".npz"


def iter_frames(path: str | Path) -> Iterator[ToFFrame]:
    """Stream the frames of a recording (directory or .mcap) or an NPZ file."""
    from ..recordings import RecordingReader, load_npz

    path = Path(path)
    if not path.exists():
        raise RecordingError(f"{path}: no such file or directory")
    if is_npz(path):
        yield from load_npz(path)
        return
    with RecordingReader(path) as reader:
        yield from reader.frames()


def count_frames(path: str | Path) -> int:
    """Number of frames in a recording or NPZ (cheap for recordings: from the summary)."""
    from ..recordings import RecordingReader, load_npz

    if is_npz(path):
        return len(load_npz(path))
    with RecordingReader(path) as reader:
        return len(reader)


def write_frames(path: str | Path, frames: Iterable[ToFFrame], *, overwrite: bool = False) -> int:
    """Write frames as an NPZ (``*.npz``) or a new recording directory; returns the count."""
    from ..recordings import RecordingWriter, save_npz

    if is_npz(path):
        return save_npz(path, frames, overwrite=overwrite)
    count = 0
    with RecordingWriter(path, overwrite=overwrite) as writer:
        for frame in frames:
            writer.write_frame(frame)
            count += 1
    return count
