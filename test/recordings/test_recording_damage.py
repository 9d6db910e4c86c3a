"""Bad recordings: truncated, corrupt, killed writers, missing files, wrong types and sizes."""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from rec_helpers import INTRINSICS, assert_frames_equal, make_frames, write_recording

from tof_mpd_ros.errors import RecordingError
from tof_mpd_ros.recordings import RecordingReader, RecordingWriter, TopicNames, convert, msgdefs

REPO = Path(__file__).resolve().parents[2]


def _chunk_ends(mcap: Path) -> list[int]:
    with open(mcap, "rb") as f:
        summary = make_reader(f).get_summary()
    return sorted(c.chunk_start_offset + c.chunk_length for c in summary.chunk_indexes)


@pytest.fixture
def recording(tmp_path):
    frames = make_frames(5)
    rec = write_recording(tmp_path / "rec", frames, range_encoding="64FC1")
    return rec, frames


@pytest.mark.parametrize("cut_fraction", [0.3, 0.55, 0.97])
def test_truncated_file_yields_every_complete_frame(recording, cut_fraction, caplog):
    rec, frames = recording
    mcap = rec / "rec_0.mcap"
    ends = _chunk_ends(mcap)
    assert len(ends) == 5  # one chunk per frame
    cut = int(mcap.stat().st_size * cut_fraction)
    mcap.write_bytes(mcap.read_bytes()[:cut])
    expected = sum(end <= cut for end in ends)
    with caplog.at_level(logging.WARNING):
        reader = RecordingReader(rec)
        back = list(reader.frames())
        info = reader.info()
    assert len(back) == expected
    assert not info.closed and len(reader) == expected
    for a, b in zip(frames, back, strict=False):
        assert_frames_equal(a, b)
    assert "was not closed" in caplog.text


def test_corrupt_bytes_in_a_chunk_raise_or_drop_that_frame(recording):
    rec, frames = recording
    mcap = rec / "rec_0.mcap"
    ends = _chunk_ends(mcap)
    data = bytearray(mcap.read_bytes())
    middle = (ends[1] + ends[2]) // 2  # inside the third chunk's compressed payload
    data[middle:middle + 16] = bytes(16)
    mcap.write_bytes(bytes(data))
    with pytest.raises(RecordingError, match=r"rec_0\.mcap: corrupt chunk at byte"):
        list(RecordingReader(rec).frames())
    reader = RecordingReader(rec, on_error="skip")
    back = list(reader.frames())
    assert [f.stamp_ns for f in back] == [frames[i].stamp_ns for i in (0, 1, 3, 4)]
    assert reader.dropped["corrupt chunk"] == 1


def test_corrupt_first_chunk_keeps_later_frames_via_the_summary(recording):
    """The first chunk declares every channel; the summary repeats them, so later chunks live."""
    rec, frames = recording
    mcap = rec / "rec_0.mcap"
    ends = _chunk_ends(mcap)
    data = bytearray(mcap.read_bytes())
    data[ends[0] - 200:ends[0] - 184] = bytes(16)
    mcap.write_bytes(bytes(data))
    reader = RecordingReader(rec, on_error="skip")
    back = list(reader.frames())
    assert [f.stamp_ns for f in back] == [f.stamp_ns for f in frames[1:]]
    for a, b in zip(frames[1:], back, strict=True):
        assert_frames_equal(a, b)
    assert dict(reader.dropped) == {"corrupt chunk": 1}


def test_corrupt_record_length_in_a_closed_file_is_an_error(recording):
    rec, _ = recording
    mcap = rec / "rec_0.mcap"
    ends = _chunk_ends(mcap)
    data = bytearray(mcap.read_bytes())
    # the record after the second chunk starts at ends[1]; its length field follows the opcode
    data[ends[1] + 1:ends[1] + 9] = (2**40).to_bytes(8, "little")
    mcap.write_bytes(bytes(data))
    with pytest.raises(RecordingError, match="runs past the end"):
        list(RecordingReader(rec, on_error="skip").frames())


def test_not_mcap_empty_file_empty_dir_and_missing_paths(tmp_path):
    (tmp_path / "x.mcap").write_bytes(b"PK\x03\x04 definitely not mcap")
    with pytest.raises(RecordingError, match=r"x\.mcap: not an MCAP file"):
        RecordingReader(tmp_path / "x.mcap").info()
    (tmp_path / "e.mcap").write_bytes(b"")
    with pytest.raises(RecordingError, match=r"e\.mcap: file is empty"):
        RecordingReader(tmp_path / "e.mcap").info()
    (tmp_path / "empty").mkdir()
    with pytest.raises(RecordingError, match=r"empty directory with neither metadata\.yaml"):
        RecordingReader(tmp_path / "empty")
    with pytest.raises(RecordingError, match="no such recording"):
        RecordingReader(tmp_path / "nope")


def test_metadata_listing_a_missing_file_or_broken_yaml(recording):
    rec, _ = recording
    (rec / "rec_0.mcap").rename(rec / "other.mcap")
    with pytest.raises(RecordingError, match="lists storage files that are missing"):
        RecordingReader(rec)
    (rec / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed")
    with pytest.raises(RecordingError, match=r"metadata\.yaml: cannot read rosbag2 metadata"):
        RecordingReader(rec)


def test_unknown_type_on_optional_topic_is_skipped_and_counted(tmp_path):
    frames = make_frames(2, reference=False, pose=False)
    with RecordingWriter(tmp_path / "rec", range_encoding="64FC1") as w:
        for f in frames:
            w.write_frame(f)
            w.write(TopicNames().reference, "std_msgs/msg/String", {"data": "oops"},
                    f.stamp_ns, schema_text="string data\n")
            w.write("/other", "my_pkg/msg/Blob", {"x": 1}, f.stamp_ns, schema_text="int32 x\n")
    reader = RecordingReader(tmp_path / "rec")
    back = list(reader.frames())
    assert len(back) == 2 and all(f.reference_mm is None for f in back)
    assert reader.dropped["wrong type on /sl/range/image_raw"] == 2
    # messages() still decodes the custom types
    blobs = [m.message.x for m in reader.messages(["/other"])]
    assert blobs == [1, 1]


def test_unknown_type_on_required_topic_is_an_error(tmp_path):
    stamp = 1_000
    with RecordingWriter(tmp_path / "rec") as w:
        w.write(TopicNames().range, "std_msgs/msg/String", {"data": "x"}, stamp,
                schema_text="string data\n")
    with pytest.raises(RecordingError, match="/tof/range/image_raw holds std_msgs/msg/String"):
        list(RecordingReader(tmp_path / "rec").frames())


def test_undecodable_schema_encoding_is_skipped_with_a_count(tmp_path):
    from mcap.writer import Writer

    path = tmp_path / "json.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="", library="test")
        schema = w.register_schema("Foo", "jsonschema", b"{}")
        channel = w.register_channel("/json", "json", schema)
        for i in range(3):
            w.add_message(channel, log_time=i, data=b"{}", publish_time=i)
        w.finish()
    reader = RecordingReader(path)
    assert list(reader.messages()) == []
    assert reader.dropped["undecodable /json (Foo, json)"] == 3
    with pytest.raises(RecordingError, match="no sensor_msgs/msg/Image messages"):
        list(reader.frames())


def _write_images(path, range_msg, amplitude_msg, stamp=5_000):
    names = TopicNames()
    with RecordingWriter(path) as w:
        w.write(names.range, msgdefs.IMAGE, range_msg, stamp)
        w.write(names.amplitude, msgdefs.IMAGE, amplitude_msg, stamp)
        w.write(names.camera_info, msgdefs.CAMERA_INFO,
                convert.camera_info_dict(INTRINSICS, stamp, "cam"), stamp)


def test_wrong_encoding_on_the_range_topic(tmp_path):
    rgb = {"header": convert.header_dict(5_000, "cam"), "height": 12, "width": 16,
           "encoding": "rgb8", "is_bigendian": 0, "step": 48, "data": bytes(12 * 48)}
    amp = convert.image_dict(np.ones((12, 16), np.float32), "32FC1", 5_000, "cam")
    _write_images(tmp_path / "rec", rgb, amp)
    with pytest.raises(RecordingError, match="encoding 'rgb8' is not supported"):
        list(RecordingReader(tmp_path / "rec").frames())
    reader = RecordingReader(tmp_path / "rec", on_error="skip")
    assert list(reader.frames()) == [] and reader.dropped["bad frame"] == 1


def test_range_amplitude_size_mismatch(tmp_path):
    rng_msg = convert.range_image_dict(np.full((12, 16), 500.0, np.float32), "32FC1", 5_000,
                                       "cam")
    amp = convert.image_dict(np.ones((10, 16), np.float32), "32FC1", 5_000, "cam")
    _write_images(tmp_path / "rec", rng_msg, amp)
    with pytest.raises(RecordingError, match=r"amplitude image is 16x10 but camera_info says "
                                             r"16x12 \(range image 16x12\)"):
        list(RecordingReader(tmp_path / "rec").frames())


def test_payload_shorter_than_its_size(tmp_path):
    rng_msg = convert.range_image_dict(np.full((12, 16), 500.0, np.float32), "32FC1", 5_000,
                                       "cam")
    rng_msg["data"] = rng_msg["data"][:-4]
    amp = convert.image_dict(np.ones((12, 16), np.float32), "32FC1", 5_000, "cam")
    _write_images(tmp_path / "rec", rng_msg, amp)
    with pytest.raises(RecordingError, match=r"frame at 5000 ns: range image: 32FC1 image"):
        list(RecordingReader(tmp_path / "rec").frames())


def test_incomplete_frames_are_dropped_and_counted(tmp_path):
    frames = make_frames(2, reference=False, pose=False)
    names = TopicNames()
    with RecordingWriter(tmp_path / "rec") as w:
        w.write_frame(frames[0])
        f = frames[1]  # a range image whose amplitude never arrives
        w.write(names.range, msgdefs.IMAGE,
                convert.range_image_dict(f.range_mm, "32FC1", f.stamp_ns, "cam"), f.stamp_ns)
    reader = RecordingReader(tmp_path / "rec")
    assert len(list(reader.frames())) == 1
    assert reader.dropped["incomplete frame (no amplitude)"] == 1


_CHILD = """
import sys
import time
from tof_mpd_ros.recordings import RecordingWriter
sys.path.insert(0, {helpers!r})
from rec_helpers import make_frames
frames = make_frames(400, seed=1)
with RecordingWriter({path!r}, range_encoding="64FC1") as w:
    for i, frame in enumerate(frames):
        w.write_frame(frame)
        print(i + 1, flush=True)
        time.sleep(0.02)
    time.sleep(3600)  # never close the recording: only the parent's SIGKILL ends this
"""


def test_sigkill_mid_recording_loses_no_flushed_frame(tmp_path):
    path = tmp_path / "killed"
    code = _CHILD.format(helpers=str(Path(__file__).parent), path=str(path))
    env = {**os.environ, "PYTHONPATH": f"{REPO}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                             env=env, cwd=tmp_path)
    flushed, deadline = 0, time.monotonic() + 300
    assert child.stdout is not None
    while flushed < 12 and time.monotonic() < deadline:
        line = child.stdout.readline()
        if not line:
            break
        flushed = int(line)
    os.kill(child.pid, signal.SIGKILL)
    child.wait(timeout=10)
    assert child.returncode == -signal.SIGKILL
    assert flushed >= 12, "child did not get going"
    reader = RecordingReader(path)
    back = list(reader.frames())
    info = reader.info()
    assert not info.closed
    assert len(back) >= flushed
    assert info.count("/tof/range/image_raw") == len(back)
    expected = make_frames(len(back), seed=1)
    for a, b in zip(expected, back, strict=True):
        assert_frames_equal(a, b)
    assert all(m.message is not None for m in reader.messages())
    assert not reader.dropped
