"""Frame files: a recording (rosbag2 directory or ``.mcap``) or an NPZ interchange file.

Everything that takes "a recording or an NPZ" (every ``tof-mpd`` command, the mismatch tool,
the benchmarks) opens it with :func:`iter_frames`, and everything that writes "the same kind"
with :func:`write_frames`, so both formats are told apart the same way everywhere: by a
``.npz`` suffix in any letter case. This is the package's one implementation of opening a
frame file.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path

from ..errors import RecordingError
from ..frame import ToFFrame
from .npz import load_npz, save_npz
from .reader import RecordingReader
from .writer import RecordingWriter


def is_npz(path: str | Path) -> bool:
    """Whether ``path`` names an NPZ interchange file (suffix ``.npz``, any case)."""
    return Path(path).suffix.lower() == ".npz"


def iter_frames(path: str | Path) -> Iterator[ToFFrame]:
    """Stream the frames of a recording (directory or ``.mcap``) or an NPZ file; the package's
    one opener of "a recording or an NPZ".

    Raises:
        RecordingError: ``path`` does not exist or cannot be read.
    """
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
    if is_npz(path):
        return len(load_npz(path))
    with RecordingReader(path) as reader:
        return len(reader)


def write_frames(path: str | Path, frames: Iterable[ToFFrame], *, overwrite: bool = False) -> int:
    """Write frames as an NPZ (``*.npz``) or a new recording directory; returns the count."""
    if is_npz(path):
        return save_npz(path, frames, overwrite=overwrite)
    count = 0
    with RecordingWriter(path, overwrite=overwrite) as writer:
        for frame in frames:
            writer.write_frame(frame)
            count += 1
    return count
