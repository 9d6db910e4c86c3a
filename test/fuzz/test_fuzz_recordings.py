"""Fuzzing the recording reader: MCAP files truncated anywhere, bytes flipped, chunk lengths and
CRCs that lie, damaged metadata.yaml, and image messages whose sizes lie.

Property: :class:`RecordingError` naming the file, or frames that are valid (and, where the damage
cannot have touched them, bit-identical to the frames written).
"""

from __future__ import annotations

import functools
import math
import shutil
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from fuzz_seeds import (
    FIRST_STAMP_NS,
    INTRINSICS,
    chunk_data,
    chunk_fields,
    lz4_claiming,
    seed_frames,
    with_chunk_data,
    write_seed_recording,
    zstd_claiming,
)
from fuzz_support import (
    FUZZ,
    cut,
    flip,
    flips,
    lie_about,
    lies,
    paths_of,
    peak_allocation,
    positions,
    read_or_typed_error,
    replaced,
)
from hypothesis import example, given, settings
from hypothesis import strategies as st

from tof_mpd_ros.errors import RecordingError
from tof_mpd_ros.frame import ToFFrame
from tof_mpd_ros.recordings import RecordingReader, RecordingWriter, metadata, msgdefs
from tof_mpd_ros.recordings.convert import camera_info_dict, header_dict
from tof_mpd_ros.recordings.topics import KEY_MOD_FREQ, KEY_RANGE_CONVENTION, TopicNames

COMPRESSIONS = ("zstd", "lz4", "none")
ON_ERROR = ("raise", "skip")


@dataclass(frozen=True)
class Seed:
    """A written recording kept as bytes, so each case rebuilds a damaged copy from it."""

    mcap_name: str
    mcap: bytes
    metadata_yaml: bytes


@functools.cache
def seeds() -> dict[str, Seed]:
    """The seed recording in each compression (a function, not a fixture: Hypothesis would
    print the bytes of a fixture with every failing case)."""
    out = {}
    with tempfile.TemporaryDirectory(prefix="fuzz_seed_") as tmp:
        for compression in COMPRESSIONS:
            directory = write_seed_recording(Path(tmp) / compression, compression)
            (mcap_path,) = directory.glob("*.mcap")
            out[compression] = Seed(mcap_path.name, mcap_path.read_bytes(),
                                    (directory / metadata.METADATA_FILE).read_bytes())
    return out


@functools.cache
def intact_frames() -> dict[int, ToFFrame]:
    """The seed's frames as read back undamaged (32FC1 metres: not bit-exact to the written
    millimetres, so damaged reads are compared with these), by stamp."""
    with tempfile.TemporaryDirectory(prefix="fuzz_intact_") as tmp:
        frames = read_frames(write_seed_recording(Path(tmp) / "rec", "none"), "raise")
    assert len(frames) == len(seed_frames())
    return {f.stamp_ns: f for f in frames}


@pytest.fixture(scope="module")
def scratch() -> Iterator[Path]:
    with tempfile.TemporaryDirectory(prefix="fuzz_rec_") as tmp:
        yield Path(tmp)


def materialise(scratch: Path, seed: Seed, mcap: bytes | None = None,
                metadata_yaml: bytes | None = None) -> Path:
    """A fresh recording directory holding (possibly damaged) copies of the seed's files."""
    directory = scratch / "fuzzed_recording"
    shutil.rmtree(directory, ignore_errors=True)
    directory.mkdir()
    (directory / seed.mcap_name).write_bytes(seed.mcap if mcap is None else mcap)
    yaml_bytes = seed.metadata_yaml if metadata_yaml is None else metadata_yaml
    (directory / metadata.METADATA_FILE).write_bytes(yaml_bytes)
    return directory


def read_frames(path: Path, on_error: str) -> list[ToFFrame]:
    """What a user does with a recording: its info, then every frame."""
    with RecordingReader(path, on_error=on_error) as reader:
        reader.info()
        return list(reader.frames())


def assert_valid(frames: list[ToFFrame]) -> None:
    """Frames a caller can use: consistent shapes, float32 images, a real modulation frequency,
    and only stamps that were written (every stamp is inside a CRC-checked chunk)."""
    for frame in frames:
        assert isinstance(frame, ToFFrame)
        assert frame.range_mm.shape == frame.amplitude.shape == frame.intrinsics.shape
        assert frame.range_mm.dtype == frame.amplitude.dtype == np.float32
        assert math.isfinite(frame.mod_freq_hz) and frame.mod_freq_hz > 0
        assert frame.stamp_ns in intact_frames()


def assert_as_written(frames: list[ToFFrame], on_error: str) -> None:
    """Each frame is bit-identical to the intact one with its stamp. With ``on_error="skip"``
    a frame may lack its reference or pose (their messages were dropped and counted)."""
    assert_valid(frames)
    for frame in frames:
        intact = intact_frames()[frame.stamp_ns]
        assert frame.range_mm.tobytes() == intact.range_mm.tobytes()
        assert frame.amplitude.tobytes() == intact.amplitude.tobytes()
        for got, want in ((frame.reference_mm, intact.reference_mm), (frame.pose, intact.pose)):
            assert want is not None
            if got is None:
                assert on_error == "skip", "a part of the frame vanished without an error"
            else:
                assert got.tobytes() == want.tobytes()


def target(directory: Path, seed: Seed, as_file: bool) -> Path:
    return directory / seed.mcap_name if as_file else directory


# ------------------------------------------------------------------------------ MCAP bytes


@settings(FUZZ, max_examples=400)
@given(compression=st.sampled_from(COMPRESSIONS), at=positions,
       on_error=st.sampled_from(ON_ERROR), as_file=st.booleans())
def test_truncated_recording_reads_a_prefix_of_its_frames_or_fails_typed(
        scratch: Path, compression: str, at: int, on_error: str,
        as_file: bool) -> None:
    seed = seeds()[compression]
    directory = materialise(scratch, seed, mcap=cut(seed.mcap, at))
    path = target(directory, seed, as_file)
    frames = read_or_typed_error(lambda: read_frames(path, on_error), directory, RecordingError)
    if isinstance(frames, list):
        assert_as_written(frames, on_error)
        assert [f.stamp_ns for f in frames] == sorted(intact_frames())[:len(frames)]


@settings(FUZZ, max_examples=500)
@given(compression=st.sampled_from(COMPRESSIONS), changes=flips,
       on_error=st.sampled_from(ON_ERROR), as_file=st.booleans())
@example(compression="none", changes=[(-1290, 1)], on_error="raise", as_file=False).via(
    "regression: a flip in the summary's channel record renamed /tof/camera_to_base, and the "
    "frames came without their pose")
def test_flipped_bytes_give_the_written_frames_or_a_typed_error(
        scratch: Path, compression: str, changes: list[tuple[int, int]],
        on_error: str, as_file: bool) -> None:
    seed = seeds()[compression]
    directory = materialise(scratch, seed, mcap=flip(seed.mcap, changes))
    path = target(directory, seed, as_file)
    frames = read_or_typed_error(lambda: read_frames(path, on_error), directory, RecordingError)
    if isinstance(frames, list):
        assert_as_written(frames, on_error)


FIELD_WIDTH = {"record_length": 8, "uncompressed_size": 8, "uncompressed_crc": 4,
               "compression_length": 4, "records_length": 8}


@settings(FUZZ, max_examples=400)
@given(compression=st.sampled_from(COMPRESSIONS), chunk=st.integers(0, 7),
       name=st.sampled_from(sorted(FIELD_WIDTH)), lie=lies, on_error=st.sampled_from(ON_ERROR))
def test_chunk_lengths_and_crcs_that_lie_give_the_written_frames_or_a_typed_error(
        scratch: Path, compression: str, chunk: int, name: str,
        lie: tuple[int, bool], on_error: str) -> None:
    seed = seeds()[compression]
    chunks = chunk_fields(seed.mcap)
    offset = getattr(chunks[chunk % len(chunks)], name)
    damaged = lie_about(seed.mcap, offset, FIELD_WIDTH[name], lie)
    directory = materialise(scratch, seed, mcap=damaged)
    frames = read_or_typed_error(lambda: read_frames(directory, on_error), directory,
                                 RecordingError)
    if isinstance(frames, list):
        assert_as_written(frames, on_error)


CLAIMED = 2**29  # 512 MiB: an allocation that succeeds, so a reader trusting it shows in the peak


def claiming(compression: str, where: str) -> bytes:
    """The seed with its second chunk claiming CLAIMED bytes in the chunk record or in the
    compressed frame's header."""
    blob = seeds()[compression].mcap
    chunk = chunk_fields(blob)[1]
    if where == "chunk":
        return lie_about(blob, chunk.uncompressed_size, 8, (CLAIMED, False))
    claim = {"zstd": zstd_claiming, "lz4": lz4_claiming}[compression]
    return with_chunk_data(blob, chunk, claim(chunk_data(blob, chunk), CLAIMED))


@pytest.mark.parametrize(("compression", "where"), [
    ("zstd", "chunk"), ("lz4", "chunk"), ("none", "chunk"), ("zstd", "frame"), ("lz4", "frame")])
def test_a_chunk_claiming_half_a_gigabyte_is_refused_without_allocating_it(
        scratch: Path, compression: str, where: str) -> None:
    directory = materialise(scratch, seeds()[compression], mcap=claiming(compression, where))
    frames = read_or_typed_error(lambda: read_frames(directory, "raise"), directory,
                                 RecordingError)
    if isinstance(frames, list):  # an uncompressed chunk's size is never needed, so not checked
        assert_as_written(frames, "raise")
    peak = peak_allocation(lambda: read_frames(directory, "skip"))
    assert peak < 50 * 2**20, f"{peak / 2**20:.0f} MiB allocated"


# ------------------------------------------------------------------------------ metadata.yaml

yaml_scalars = st.one_of(st.none(), st.booleans(), st.integers(-(2**70), 2**70),
                         st.floats(allow_nan=True), st.text(max_size=12))
yaml_values = st.recursive(yaml_scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=3), st.dictionaries(st.text(max_size=8), inner, max_size=3)),
    max_leaves=8)


# The custom_data entries the reader interprets.
CUSTOM_KEYS = (KEY_MOD_FREQ, KEY_RANGE_CONVENTION, *TopicNames().as_custom_data())


def damage_metadata(original: bytes, how: str, where: int, value: Any,
                    changes: list[tuple[int, int]]) -> bytes:
    """metadata.yaml with its ``where``-th node (or custom_data entry) replaced by ``value``,
    or its bytes flipped, or cut."""
    if how == "flip":
        return flip(original, changes)
    if how == "cut":
        return cut(original, where)
    doc = yaml.safe_load(original)
    if how == "custom":
        doc["rosbag2_bagfile_information"]["custom_data"][
            CUSTOM_KEYS[where % len(CUSTOM_KEYS)]] = value
        return yaml.safe_dump(doc).encode()
    nodes = paths_of(doc)
    return yaml.safe_dump(replaced(doc, nodes[where % len(nodes)], value)).encode()


@settings(FUZZ, max_examples=400)
@given(how=st.sampled_from(("node", "custom", "flip", "cut")), where=positions,
       value=yaml_values, changes=flips, on_error=st.sampled_from(ON_ERROR),
       as_file=st.booleans())
@example(how="custom", where=CUSTOM_KEYS.index(KEY_MOD_FREQ), value="inf", changes=[(0, 1)],
         on_error="raise", as_file=False).via("regression: an infinite modulation frequency")
def test_damaged_metadata_yaml_gives_valid_frames_or_a_typed_error(
        scratch: Path, how: str, where: int, value: Any,
        changes: list[tuple[int, int]], on_error: str, as_file: bool) -> None:
    seed = seeds()["zstd"]
    damaged = damage_metadata(seed.metadata_yaml, how, where, value, changes)
    directory = materialise(scratch, seed, metadata_yaml=damaged)
    path = target(directory, seed, as_file)
    frames = read_or_typed_error(lambda: read_frames(path, on_error), directory, RecordingError)
    if isinstance(frames, list):
        assert_valid(frames)


# ------------------------------------------------------------------------------ lying images

ENCODINGS = ("32FC1", "64FC1", "16UC1", "mono16", "mono8", "8UC1", "rgb8", "bgra8", "", "32FC3")
# uint32 fields of sensor_msgs/Image and CameraInfo: small, or large enough to overflow
sizes = st.one_of(st.integers(0, 8), st.sampled_from((4, 2**16, 2**30, 2**31 - 1, 2**32 - 1)))


# An Image message whose encoding, size, step and payload need not agree.
lying_images = st.fixed_dictionaries({
    "header": st.just(header_dict(FIRST_STAMP_NS, "tof")), "height": sizes, "width": sizes,
    "encoding": st.sampled_from(ENCODINGS), "is_bigendian": st.integers(0, 1), "step": sizes,
    "data": st.binary(max_size=256)})


def write_messages(directory: Path, messages: list[tuple[str, str, dict[str, Any]]]) -> Path:
    shutil.rmtree(directory, ignore_errors=True)
    with RecordingWriter(directory, compression="none") as writer:
        for topic, msgtype, message in messages:
            writer.write(topic, msgtype, message, FIRST_STAMP_NS)
    return directory


@settings(FUZZ, max_examples=300)
@given(range_image=lying_images, amplitude=lying_images, width=sizes, height=sizes,
       on_error=st.sampled_from(ON_ERROR))
def test_images_whose_sizes_lie_give_valid_frames_or_a_typed_error(
        scratch: Path, range_image: dict[str, Any], amplitude: dict[str, Any], width: int,
        height: int, on_error: str) -> None:
    info = camera_info_dict(INTRINSICS, FIRST_STAMP_NS, "tof")
    info.update(width=width, height=height)
    directory = write_messages(scratch / "lying", [
        ("/tof/range/image_raw", msgdefs.IMAGE, range_image),
        ("/tof/amplitude/image_raw", msgdefs.IMAGE, amplitude),
        ("/tof/camera_info", msgdefs.CAMERA_INFO, info)])
    frames = read_or_typed_error(lambda: read_frames(directory, on_error), directory,
                                 RecordingError)
    if isinstance(frames, list):
        for frame in frames:
            assert frame.range_mm.shape == frame.amplitude.shape == frame.intrinsics.shape
            # 2 bytes per pixel at least (16UC1): the pixels were all in the payload
            assert frame.range_mm.size * 2 <= len(range_image["data"])


def test_an_image_claiming_a_trillion_pixels_is_refused_without_allocating_them(
        scratch: Path) -> None:
    huge = {"header": header_dict(FIRST_STAMP_NS, "tof"), "height": 10**6, "width": 10**6,
            "encoding": "32FC1", "is_bigendian": 0, "step": 4 * 10**6, "data": b"\0" * 64}
    info = camera_info_dict(INTRINSICS, FIRST_STAMP_NS, "tof")
    info.update(width=10**6, height=10**6)
    directory = write_messages(scratch / "huge", [
        ("/tof/range/image_raw", msgdefs.IMAGE, huge),
        ("/tof/amplitude/image_raw", msgdefs.IMAGE, huge),
        ("/tof/camera_info", msgdefs.CAMERA_INFO, info)])
    with pytest.raises(RecordingError, match="range image"):
        read_frames(directory, "raise")
    assert peak_allocation(lambda: read_frames(directory, "raise")) < 50 * 2**20
