"""Writer -> reader round trips: frames, info, metadata.yaml, topic pairing, conventions."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from rec_helpers import (
    INTRINSICS,
    MOD_FREQ,
    assert_frames_equal,
    make_frames,
    rigid,
    write_recording,
)

from tof_mpd_ros.errors import InputError, RecordingError
from tof_mpd_ros.recordings import RecordingReader, RecordingWriter, TopicNames, convert, msgdefs


def test_64fc1_round_trip_is_bit_exact_with_every_field(tmp_path):
    frames = make_frames(4)
    rec = write_recording(tmp_path / "rec", frames, range_encoding="64FC1")
    with RecordingReader(rec) as reader:
        back = list(reader.frames())
        assert len(reader) == 4
        assert not reader.dropped
    assert len(back) == 4
    for a, b in zip(frames, back, strict=True):
        assert_frames_equal(a, b)
    assert np.isnan(back[0].range_mm).sum() == np.isnan(frames[0].range_mm).sum() > 0


def test_32fc1_is_within_float32_metre_rounding_and_keeps_nans(tmp_path):
    frames = make_frames(2, pose=False)
    rec = write_recording(tmp_path / "rec", frames, range_encoding="32FC1")
    back = list(RecordingReader(rec).frames())
    for a, b in zip(frames, back, strict=True):
        assert_frames_equal(a, b, exact_range=False)
        np.testing.assert_array_equal(np.isnan(a.range_mm), np.isnan(b.range_mm))
        # float32 metres: relative error <= 2**-24 plus the mm conversion rounding
        np.testing.assert_allclose(b.range_mm, a.range_mm, rtol=1.2e-7, equal_nan=True)


def test_16uc1_rounds_to_whole_millimetres_and_zero_is_invalid(tmp_path):
    frames = make_frames(1, pose=False)
    frames[0].range_mm[0, :3] = [70000.0, 0.2, 1234.5]  # too far, too near, half way
    rec = write_recording(tmp_path / "rec", frames, range_encoding="16UC1")
    (back,) = RecordingReader(rec).frames()
    expected = np.rint(frames[0].range_mm)
    expected[0, :2] = np.nan
    np.testing.assert_array_equal(back.range_mm, expected.astype(np.float32))
    assert back.range_mm[0, 2] == 1234.0  # round half to even
    raw = next(RecordingReader(rec).messages([TopicNames().range])).message
    pixels = np.frombuffer(raw.data, dtype="<u2").reshape(12, 16)
    assert np.all((pixels == 0) == np.isnan(back.range_mm))


def test_info_and_metadata_yaml(tmp_path):
    frames = make_frames(3)
    rec = write_recording(tmp_path / "rec", frames, hand_eye=rigid(np.random.default_rng(5)),
                          range_encoding="16UC1", custom_data={"scene": "s01"})
    info = RecordingReader(rec).info()
    assert info.closed and info.message_count == 3 * 7
    assert info.count("/tof/range/image_raw") == 3 and info.count("/arm/hand_eye") == 3
    assert info.start_ns == frames[0].stamp_ns and info.duration_ns == 100_000_000
    assert info.range_convention == "radial"
    assert info.custom_data["tof_mpd_ros.mod_freq_hz"] == repr(MOD_FREQ)
    assert info.size_bytes == (rec / "rec_0.mcap").stat().st_size
    doc = yaml.safe_load((rec / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert doc["version"] == 9 and doc["storage_identifier"] == "mcap"
    assert doc["relative_file_paths"] == ["rec_0.mcap"] and doc["message_count"] == 21
    assert doc["duration"]["nanoseconds"] == 100_000_000
    assert doc["custom_data"]["tof_mpd_ros.range_convention"] == "radial"
    assert doc["custom_data"]["tof_mpd_ros.range_encoding"] == "16UC1"
    assert doc["custom_data"]["scene"] == "s01"
    topics = {t["topic_metadata"]["name"]: t for t in doc["topics_with_message_count"]}
    image = topics["/tof/range/image_raw"]["topic_metadata"]
    assert image["type_description_hash"] == msgdefs.TYPE_HASHES["sensor_msgs/msg/Image"]
    assert image["serialization_format"] == "cdr"


def test_mcap_header_channels_and_schemas_follow_the_ros2_profile(tmp_path):
    from mcap.reader import make_reader

    rec = write_recording(tmp_path / "rec", make_frames(1))
    with open(rec / "rec_0.mcap", "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
    assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
    assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
    schema = next(s for s in summary.schemas.values() if s.name == "sensor_msgs/msg/Image")
    assert schema.data.decode() == msgdefs.schema_text("sensor_msgs/msg/Image")
    assert all("offered_qos_profiles" in c.metadata for c in summary.channels.values())


def test_pose_from_tcp_and_hand_eye_when_no_exact_matrix(tmp_path):
    rng = np.random.default_rng(3)
    hand_eye, tcp = rigid(rng, 0.05), rigid(rng)
    frame = make_frames(1, pose=False)[0]
    with RecordingWriter(tmp_path / "rec") as w:
        w.write_frame(frame, tcp_pose=tcp, hand_eye=hand_eye)
    (back,) = RecordingReader(tmp_path / "rec").frames()
    np.testing.assert_allclose(back.pose, tcp @ hand_eye, atol=1e-12)


def test_inconsistent_pose_duplicate_stamp_and_other_mod_freq_are_rejected(tmp_path):
    frames = make_frames(2)
    with RecordingWriter(tmp_path / "rec") as w:
        with pytest.raises(InputError, match="tcp_pose @ hand_eye differs"):
            w.write_frame(frames[0], tcp_pose=np.eye(4), hand_eye=np.eye(4))
        w.write_frame(frames[0])
        with pytest.raises(InputError, match="already written"):
            w.write_frame(frames[0])
        frames[1].mod_freq_hz = 2 * MOD_FREQ
        with pytest.raises(InputError, match="modulation frequency"):
            w.write_frame(frames[1])
    assert len(list(RecordingReader(tmp_path / "rec").frames())) == 1


def test_refuses_to_overwrite_and_overwrite_replaces(tmp_path):
    write_recording(tmp_path / "rec", make_frames(2))
    with pytest.raises(RecordingError, match="refusing to overwrite"):
        RecordingWriter(tmp_path / "rec").open()
    write_recording(tmp_path / "rec", make_frames(1, seed=9), overwrite=True)
    assert len(RecordingReader(tmp_path / "rec")) == 1
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "a.txt").write_text("keep me")
    with pytest.raises(RecordingError, match="not a recording"):
        RecordingWriter(tmp_path / "notes", overwrite=True).open()
    assert (tmp_path / "notes" / "a.txt").exists()


def test_reads_the_mcap_file_alone_and_a_directory_without_metadata(tmp_path):
    frames = make_frames(2)
    rec = write_recording(tmp_path / "rec", frames, range_encoding="64FC1")
    by_file = list(RecordingReader(rec / "rec_0.mcap").frames())
    (rec / "metadata.yaml").unlink()
    by_dir = list(RecordingReader(rec).frames())
    for a, b, c in zip(frames, by_file, by_dir, strict=True):
        assert_frames_equal(a, b)
        assert_frames_equal(a, c)


def test_custom_topic_names_are_found_from_custom_data(tmp_path):
    topics = TopicNames(range="/cam/depth", amplitude="/cam/ir", camera_info="/cam/info")
    frames = make_frames(2)
    rec = write_recording(tmp_path / "rec", frames, topics=topics, range_encoding="64FC1")
    info = RecordingReader(rec).info()
    assert info.count("/cam/depth") == 2 and info.count("/tof/range/image_raw") == 0
    for a, b in zip(frames, RecordingReader(rec).frames(), strict=True):
        assert_frames_equal(a, b)


def _write_raw(writer, topic, msgtype, message, stamp):
    writer.write(topic, msgtype, message, stamp)


def test_static_camera_info_and_hand_eye_and_out_of_order_arrival(tmp_path):
    """Another tool: CameraInfo and hand-eye once, then images with interleaved stamps."""
    frames = make_frames(3, reference=False, pose=False)
    names, cam = TopicNames(), "cam"
    rng = np.random.default_rng(1)
    hand_eye, tcps = rigid(rng, 0.05), [rigid(rng) for _ in frames]
    t0 = frames[0].stamp_ns
    with RecordingWriter(tmp_path / "rec", range_encoding="32FC1") as w:
        _write_raw(w, names.camera_info, msgdefs.CAMERA_INFO,
                   convert.camera_info_dict(INTRINSICS, t0 - 1, cam), t0 - 1)
        _write_raw(w, names.hand_eye, msgdefs.TRANSFORM_STAMPED,
                   convert.transform_stamped_dict(hand_eye, t0 - 1, "tool0", cam), t0 - 1)
        # range images of frames 0 and 1 first, then amplitudes and poses in reverse order
        for f in frames[:2]:
            _write_raw(w, names.range, msgdefs.IMAGE,
                       convert.range_image_dict(f.range_mm, "64FC1", f.stamp_ns, cam), f.stamp_ns)
        for f, tcp in reversed(list(zip(frames, tcps, strict=True))):
            _write_raw(w, names.amplitude, msgdefs.IMAGE,
                       convert.image_dict(f.amplitude, "32FC1", f.stamp_ns, cam), f.stamp_ns)
            _write_raw(w, names.tcp_pose, msgdefs.POSE_STAMPED,
                       convert.pose_stamped_dict(tcp, f.stamp_ns, "base"), f.stamp_ns)
        _write_raw(w, names.range, msgdefs.IMAGE, convert.range_image_dict(
            frames[2].range_mm, "64FC1", frames[2].stamp_ns, cam), frames[2].stamp_ns)
    with RecordingReader(tmp_path / "rec") as reader:
        back = sorted(reader.frames(), key=lambda f: f.stamp_ns)
    assert [f.stamp_ns for f in back] == [f.stamp_ns for f in frames]
    for f, b, tcp in zip(frames, back, tcps, strict=True):
        assert b.range_mm.tobytes() == f.range_mm.tobytes()
        assert b.amplitude.tobytes() == f.amplitude.tobytes()
        np.testing.assert_allclose(b.pose, tcp @ hand_eye, atol=1e-12)
        assert b.intrinsics == INTRINSICS


def test_z_depth_recording_is_converted_to_radial(tmp_path):
    frame = make_frames(1, pose=False)[0]
    z_frame = type(frame)(INTRINSICS.radial_to_z(frame.range_mm), frame.amplitude, INTRINSICS,
                          mod_freq_hz=MOD_FREQ,
                          reference_mm=INTRINSICS.radial_to_z(frame.reference_mm),
                          stamp_ns=frame.stamp_ns)
    rec = write_recording(tmp_path / "rec", [z_frame], range_encoding="64FC1",
                          custom_data={"tof_mpd_ros.range_convention": "z"})
    reader = RecordingReader(rec)
    assert reader.info().range_convention == "z"
    (back,) = reader.frames()
    np.testing.assert_allclose(back.range_mm, frame.range_mm, rtol=1e-6, equal_nan=True)
    np.testing.assert_allclose(back.reference_mm, frame.reference_mm, rtol=1e-6,
                               equal_nan=True)
    corner = frame.range_mm[0, 0] if np.isfinite(frame.range_mm[0, 0]) else None
    if corner is not None:  # off-axis pixel: z is visibly shorter than the radial range
        assert z_frame.range_mm[0, 0] < 0.99 * corner
    # the reader can be told the convention when a recording does not say it
    (as_radial,) = RecordingReader(rec, range_convention="radial").frames()
    assert as_radial.range_mm.tobytes() == z_frame.range_mm.tobytes()


def test_messages_streams_every_topic_with_decoded_fields(tmp_path):
    frames = make_frames(2)
    points = np.random.default_rng(2).normal(size=(7, 3)).astype(np.float32)
    with RecordingWriter(tmp_path / "rec") as w:
        for f in frames:
            w.write_frame(f, sl_points=points)
    msgs = list(RecordingReader(tmp_path / "rec").messages())
    assert [m.topic for m in msgs[:6]] == ["/tof/range/image_raw", "/tof/amplitude/image_raw",
                                           "/tof/camera_info", "/sl/range/image_raw",
                                           "/sl/points", "/tof/camera_to_base"]
    cloud = next(m for m in msgs if m.topic == "/sl/points")
    assert cloud.msgtype == "sensor_msgs/msg/PointCloud2"
    np.testing.assert_array_equal(convert.points_of(cloud.message, "points"), points)
    info = next(m for m in msgs if m.topic == "/tof/camera_info").message
    assert list(info.k) == [20.5, 0.0, 7.5, 0.0, 21.25, 5.75, 0.0, 0.0, 1.0]
    assert info.header.frame_id == "tof_optical_frame" and info.width == 16
    assert all(m.log_time_ns in (frames[0].stamp_ns, frames[1].stamp_ns) for m in msgs)


def test_generic_write_errors(tmp_path):
    writer = RecordingWriter(tmp_path / "rec")
    with pytest.raises(RecordingError, match="not open"):
        writer.write("/x", msgdefs.IMAGE, {}, 0)
    with writer:
        with pytest.raises(InputError, match="no embedded definition"):
            writer.write("/x", "my_pkg/msg/Unknown", {}, 0)
        with pytest.raises(InputError, match="/x: message does not fit sensor_msgs/msg/Image"):
            writer.write("/x", msgdefs.IMAGE, {"height": "tall"}, 0)
        with pytest.raises(InputError, match="negative or too large"):
            writer.write("/x", msgdefs.IMAGE, {}, -5)
        writer.write("/x", msgdefs.IMAGE, {}, 5)
        with pytest.raises(InputError, match="already holds sensor_msgs/msg/Image"):
            writer.write("/x", msgdefs.CAMERA_INFO, {}, 6)
    assert writer.counts == {"/x": 1}
    assert RecordingReader(tmp_path / "rec").info().count("/x") == 1
