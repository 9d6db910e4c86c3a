"""tof_mpd_ros.atomic_file: the one atomic-save helper (same-directory temporary file, fsync'ed
before the rename, removed when anything fails), and the savers that use it."""

from __future__ import annotations

import os
from pathlib import Path
from typing import BinaryIO

import numpy as np
import pytest

from tof_mpd_ros.atomic_file import write_atomically
from tof_mpd_ros.errors import RecordingError


def _files(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir())


def test_writes_the_file_and_leaves_nothing_else(tmp_path: Path) -> None:
    path = tmp_path / "out.bin"
    assert write_atomically(path, lambda stream: stream.write(b"new")) == path
    assert path.read_bytes() == b"new"
    assert write_atomically(str(path), lambda stream: stream.write(b"newer")) == path
    assert path.read_bytes() == b"newer"
    assert _files(tmp_path) == ["out.bin"]


def test_the_data_is_fsynced_in_the_same_directory_before_the_rename(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    events: list[tuple[str, str]] = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd: int) -> None:
        events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}")))
        real_fsync(fd)

    def replace(src: str | Path, dst: str | Path) -> None:
        events.append(("replace", str(src)))
        real_replace(src, dst)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    write_atomically(tmp_path / "out.bin", lambda stream: stream.write(b"x"))
    tmp = str(tmp_path / "out.bin.tmp")
    assert events == [("fsync", tmp), ("replace", tmp)]


@pytest.mark.parametrize("error", [OSError(28, "No space left on device"), ValueError("bad"),
                                   KeyboardInterrupt()])
def test_a_failed_write_keeps_the_old_file_and_removes_the_temporary(
        tmp_path: Path, error: BaseException) -> None:
    path = tmp_path / "out.bin"
    path.write_bytes(b"old")

    def write(stream: BinaryIO) -> None:
        stream.write(b"half")
        raise error

    with pytest.raises(type(error)):
        write_atomically(path, write)
    assert path.read_bytes() == b"old"
    assert _files(tmp_path) == ["out.bin"]


def test_a_failed_rename_removes_the_temporary(tmp_path: Path) -> None:
    target = tmp_path / "a_directory"
    (target / "inside").mkdir(parents=True)
    with pytest.raises(OSError):
        write_atomically(target, lambda stream: stream.write(b"x"))
    assert _files(tmp_path) == ["a_directory"]


def test_save_npz_cleans_up_and_raises_its_error_when_the_write_fails(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """save_npz used to leave ``<name>.tmp`` behind on a failed write; now none of the savers
    does (weights, checkpoints, NPZ files and metadata.yaml share the helper)."""
    from tof_mpd_ros.camera import Intrinsics
    from tof_mpd_ros.frame import ToFFrame
    from tof_mpd_ros.recordings import npz

    frame = ToFFrame(np.ones((4, 5), np.float32), np.ones((4, 5), np.float32),
                     Intrinsics(4.0, 4.0, 2.0, 1.5, 5, 4), mod_freq_hz=30e6)

    def full_disk(*args: object, **kwargs: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(npz.np, "savez", full_disk)
    with pytest.raises(RecordingError, match="No space left on device"):
        npz.save_npz(tmp_path / "frames.npz", [frame])
    assert _files(tmp_path) == []
