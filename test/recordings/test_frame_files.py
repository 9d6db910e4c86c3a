"""Frame files (tof_mpd_ros.recordings.frame_files): the one opener of "a recording or an NPZ",
used by every command and by the mismatch tool. An NPZ is told by its suffix in any letter case
(the mismatch tool used to take ``x.NPZ`` for a recording)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rec_helpers import make_frames, write_recording

from tof_mpd_ros.errors import MismatchError, RecordingError
from tof_mpd_ros.mismatch import load_frames
from tof_mpd_ros.recordings import count_frames, is_npz, iter_frames, write_frames


def _same(got: list, want: list) -> None:
    """The same frames (a recording's default 32FC1 metres rounds the range a little)."""
    assert len(got) == len(want)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_allclose(a.range_mm, b.range_mm, rtol=1e-6)
        np.testing.assert_allclose(a.reference_mm, b.reference_mm, rtol=1e-6)
        assert a.stamp_ns == b.stamp_ns


@pytest.mark.parametrize("name", ["frames.npz", "frames.NPZ", "frames.Npz"])
def test_an_npz_in_any_letter_case_is_written_and_read_as_an_npz(tmp_path: Path,
                                                                  name: str) -> None:
    frames = make_frames(3)
    path = tmp_path / name
    assert is_npz(path)
    assert write_frames(path, frames) == 3
    assert path.is_file()  # an NPZ, not a recording directory
    assert count_frames(path) == 3
    _same(list(iter_frames(path)), frames)
    _same(load_frames(path), frames)  # the mismatch tool opens it the same way


def test_anything_else_is_a_recording(tmp_path: Path) -> None:
    frames = make_frames(2)
    path = write_recording(tmp_path / "rec", frames)
    assert not is_npz(path) and not is_npz(tmp_path / "frames.npz.d")
    assert count_frames(path) == 2
    _same(list(iter_frames(path)), frames)
    _same(load_frames(path), frames)
    assert write_frames(tmp_path / "copy", frames) == 2
    assert (tmp_path / "copy").is_dir()


def test_a_missing_path_is_one_clear_error(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="no such file or directory"):
        next(iter_frames(tmp_path / "absent.npz"))
    with pytest.raises(MismatchError, match="no such file or directory"):
        load_frames(tmp_path / "absent.npz")
