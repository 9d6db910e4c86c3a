"""Fuzzing the NPZ interchange reader (:func:`load_npz`): wrong keys, dtypes, shapes, NaN/inf,
damaged bytes, and .npy headers claiming huge arrays.

Property: :class:`RecordingError` naming the file, or frames that are valid (and, for damaged
bytes, bit-identical to those saved).
"""

from __future__ import annotations

import functools
import math
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fuzz_seeds import seed_frames
from fuzz_support import (
    FUZZ,
    array_mutations,
    cut,
    flip,
    flips,
    mutate_arrays,
    npy_claiming,
    peak_allocation,
    positions,
    read_or_typed_error,
    save_arrays,
    with_member,
)
from hypothesis import example, given, settings
from hypothesis import strategies as st

from tof_mpd_ros.errors import RecordingError
from tof_mpd_ros.frame import ToFFrame
from tof_mpd_ros.recordings import load_npz
from tof_mpd_ros.recordings.npz import frames_to_arrays


@functools.cache
def seed_arrays() -> dict[str, np.ndarray]:
    return frames_to_arrays(seed_frames())


@functools.cache
def seed_file(compressed: bool) -> bytes:
    """The seed .npz as bytes (``np.savez`` like ``save_npz``, or ``savez_compressed``)."""
    with tempfile.TemporaryDirectory(prefix="fuzz_npz_seed_") as tmp:
        return save_arrays(Path(tmp) / "seed.npz", seed_arrays(), compressed).read_bytes()


@pytest.fixture(scope="module")
def scratch() -> Iterator[Path]:
    with tempfile.TemporaryDirectory(prefix="fuzz_npz_") as tmp:
        yield Path(tmp)


def assert_valid(frames: list[ToFFrame]) -> None:
    """Frames a caller can use: one camera, float32 images of its size, a real modulation
    frequency, distinct non-negative stamps, (4, 4) poses."""
    assert frames
    for frame in frames:
        assert frame.range_mm.shape == frame.amplitude.shape == frame.intrinsics.shape
        assert frame.range_mm.dtype == frame.amplitude.dtype == np.float32
        assert frame.reference_mm is None or frame.reference_mm.shape == frame.intrinsics.shape
        assert math.isfinite(frame.mod_freq_hz) and frame.mod_freq_hz > 0
        assert frame.stamp_ns >= 0
        assert frame.pose is None or frame.pose.shape == (4, 4)
    assert len({f.stamp_ns for f in frames}) == len(frames)


def assert_as_saved(frames: list[ToFFrame]) -> None:
    assert_valid(frames)
    saved = frames_to_arrays(frames)
    assert sorted(saved) == sorted(seed_arrays())
    for key, array in seed_arrays().items():
        assert saved[key].tobytes() == array.tobytes(), key


@settings(FUZZ, max_examples=500)
@given(mutations=array_mutations, compressed=st.booleans())
def test_wrong_keys_dtypes_shapes_and_values_give_valid_frames_or_a_typed_error(
        scratch: Path, mutations: list[tuple[Any, ...]], compressed: bool) -> None:
    path = save_arrays(scratch / "mutated.npz", mutate_arrays(seed_arrays(), mutations),
                       compressed)
    frames = read_or_typed_error(lambda: load_npz(path), path, RecordingError)
    if isinstance(frames, list):
        assert_valid(frames)


@settings(FUZZ, max_examples=400)
@given(how=st.sampled_from(("flip", "cut")), changes=flips, at=positions,
       compressed=st.booleans())
@example(how="flip", changes=[(6, 0x01)], at=0, compressed=False).via(
    "regression: the 'encrypted' flag of the first zip entry raised RuntimeError")
@example(how="flip", changes=[(8, 0x40)], at=0, compressed=False).via(
    "regression: an unknown zip compression method raised NotImplementedError")
def test_damaged_bytes_give_the_saved_frames_or_a_typed_error(
        scratch: Path, how: str, changes: list[tuple[int, int]], at: int,
        compressed: bool) -> None:
    blob = seed_file(compressed)
    path = scratch / "damaged.npz"
    path.write_bytes(flip(blob, changes) if how == "flip" else cut(blob, at))
    frames = read_or_typed_error(lambda: load_npz(path), path, RecordingError)
    if isinstance(frames, list):
        assert_as_saved(frames)


@pytest.mark.parametrize("shape", [(10**6, 10**6), (2**27,), (3, 2**13, 2**13)])
def test_a_header_claiming_a_huge_array_is_refused_without_allocating_it(
        scratch: Path, shape: tuple[int, ...]) -> None:
    path = save_arrays(scratch / "lying.npz", seed_arrays(), compressed=False)
    with_member(path, "range_mm.npy", npy_claiming(shape))
    with pytest.raises(RecordingError, match=r"lying\.npz"):
        load_npz(path)
    peak = peak_allocation(lambda: load_npz(path))
    assert peak < 50 * 2**20, f"{peak / 2**20:.0f} MiB allocated"
