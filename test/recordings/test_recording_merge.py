"""Merging recordings made in parts: every message once, in time order, values untouched."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rec_helpers import make_frames

from tof_mpd_ros.errors import InputError
from tof_mpd_ros.recordings import RecordingReader, RecordingWriter
from tof_mpd_ros.recordings.merge import merge_recordings


def _write(path: Path, frames, **kw) -> Path:
    with RecordingWriter(path, **kw) as writer:
        for f in frames:
            writer.write_frame(f)
    return path


def test_interleaved_parts_merge_in_time_order_bit_for_bit(tmp_path: Path) -> None:
    """Frames dealt alternately to two parts come back as the original sequence, with the
    very float32 values (a frame rebuilt from metres and written again would not)."""
    frames = make_frames(6, seed=2)
    parts = [_write(tmp_path / "a", frames[0::2]), _write(tmp_path / "b", frames[1::2]),
             _write(tmp_path / "empty", [])]
    counts = merge_recordings(tmp_path / "merged", parts)
    assert set(counts.values()) == {6}
    with RecordingReader(tmp_path / "merged") as reader:
        merged = list(reader.frames())
        assert reader.custom_data["tof_mpd_ros.mod_freq_hz"] == repr(frames[0].mod_freq_hz)
    with RecordingReader(_write(tmp_path / "whole", frames)) as reader:
        whole = list(reader.frames())
    assert [f.stamp_ns for f in merged] == [f.stamp_ns for f in frames]
    for a, b in zip(merged, whole, strict=True):
        for field in ("range_mm", "amplitude", "reference_mm", "pose"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))


def test_overlapping_or_foreign_parts_are_refused(tmp_path: Path) -> None:
    frames = make_frames(3, seed=4)
    a = _write(tmp_path / "a", frames)
    b = _write(tmp_path / "b", frames[1:2])
    with pytest.raises(InputError, match="overlap"):
        merge_recordings(tmp_path / "m1", [a, b])
    assert not (tmp_path / "m1").exists()
    c = _write(tmp_path / "c", make_frames(2, seed=5, first_stamp=2_000_000_000_000_000_000),
               range_encoding="16UC1")
    with pytest.raises(InputError, match="range_encoding"):
        merge_recordings(tmp_path / "m2", [a, c])
    assert not (tmp_path / "m2").exists()
    with pytest.raises(InputError, match="no recordings"):
        merge_recordings(tmp_path / "m3", [])
