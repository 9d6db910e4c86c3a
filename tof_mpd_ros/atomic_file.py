"""Replace a file atomically: a crash or a failed write leaves the old file or the new one, never
a mix, and no temporary file behind."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

#: suffix of the temporary file beside the target while it is written
TMP_SUFFIX = ".tmp"


def write_atomically(path: str | Path, write: Callable[[BinaryIO], object]) -> Path:
    """Write a file through ``write`` and put it at ``path`` in one rename; the package's one
    atomic-save helper (weights, checkpoints, NPZ files, ``metadata.yaml``).

    ``write`` fills ``<path>.tmp`` in the same directory (so the rename never crosses file
    systems); the data is flushed and fsync'ed before :func:`os.replace` puts it in place, so
    even a power cut after the rename cannot leave an empty or half-written file. If anything
    fails (or is interrupted), the temporary file is removed and ``path`` is untouched.

    Args:
        path: the file to create or replace.
        write: called once with the temporary file, opened for binary writing.

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        OSError: the temporary file cannot be written or renamed (callers turn it into their
            subsystem's error); whatever ``write`` raises, unchanged.
    """
    path = Path(path)
    tmp = path.with_name(path.name + TMP_SUFFIX)
    try:
        with open(tmp, "wb") as stream:
            write(stream)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):  # the write's own error is the one to report
            tmp.unlink(missing_ok=True)
        raise
    return path
