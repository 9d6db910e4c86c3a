"""Proof of standard: the independent ``rosbags`` library reads our recordings bit-exactly."""

from __future__ import annotations

import numpy as np
import pytest
from rec_helpers import INTRINSICS, make_frames, rigid

from tof_mpd_ros.recordings import RecordingWriter, msgdefs

rosbag2 = pytest.importorskip("rosbags.rosbag2")
typesys = pytest.importorskip("rosbags.typesys")


@pytest.fixture(scope="module")
def typestore():
    return typesys.get_typestore(typesys.Stores.ROS2_JAZZY)


@pytest.fixture
def recording(tmp_path):
    frames = make_frames(3)
    rng = np.random.default_rng(7)
    hand_eye = rigid(rng, 0.05)
    points = rng.normal(size=(9, 3)).astype(np.float32)
    path = tmp_path / "rec"
    with RecordingWriter(path, range_encoding="16UC1", custom_data={"operator": "ci"}) as w:
        for f in frames:
            w.write_frame(f, tcp_pose=f.pose @ np.linalg.inv(hand_eye), hand_eye=hand_eye,
                          sl_points=points)
    return path, frames, hand_eye, points


def test_rosbags_parses_metadata_yaml(recording):
    path, frames, _, _ = recording
    with rosbag2.Reader(path) as reader:
        assert reader.message_count == 3 * 8
        assert reader.start_time == frames[0].stamp_ns
        assert reader.duration == frames[-1].stamp_ns - frames[0].stamp_ns + 1
        counts = {c.topic: c.msgcount for c in reader.connections}
        assert counts == {t: 3 for t in counts} and len(counts) == 8
        assert reader.ros_distro == "jazzy"
        custom = reader.storage.metadata.custom  # parsed from metadata.yaml custom_data
        assert custom["operator"] == "ci"
        assert custom["tof_mpd_ros.range_convention"] == "radial"
        hashes = {c.topic: c.digest for c in reader.connections}
        assert hashes["/tof/camera_info"] == msgdefs.TYPE_HASHES["sensor_msgs/msg/CameraInfo"]
        qos = reader.connections[0].ext.offered_qos_profiles[0]
        assert qos.reliability.name == "RELIABLE" and qos.durability.name == "VOLATILE"


def test_type_hashes_match_rosbags(typestore):
    for msgtype in msgdefs.known_types():
        assert msgdefs.TYPE_HASHES[msgtype] == typestore.hash_rihs01(msgtype), msgtype


def test_rosbags_decodes_every_message_bit_exactly(recording, typestore):
    path, frames, hand_eye, points = recording
    by_stamp = {f.stamp_ns: f for f in frames}
    seen: dict[str, int] = {}
    with rosbag2.Reader(path) as reader:
        for conn, log_time, raw in reader.messages():
            msg = typestore.deserialize_cdr(raw, conn.msgtype)
            seen[conn.topic] = seen.get(conn.topic, 0) + 1
            frame = by_stamp[log_time]
            if conn.topic != "/tof/camera_to_base":
                stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
                assert stamp == frame.stamp_ns
            _check(conn.topic, msg, frame, hand_eye, points)
    assert seen == dict.fromkeys(seen, 3) and len(seen) == 8


def _check(topic, msg, frame, hand_eye, points):
    from scipy.spatial.transform import Rotation

    if topic == "/tof/range/image_raw" or topic == "/sl/range/image_raw":
        src = frame.range_mm if topic.startswith("/tof") else frame.reference_mm
        assert (msg.encoding, msg.height, msg.width, msg.step) == ("16UC1", 12, 16, 32)
        expected = np.where(np.isnan(src), 0, np.rint(np.nan_to_num(src))).astype("<u2")
        assert msg.data.tobytes() == expected.tobytes()
    elif topic == "/tof/amplitude/image_raw":
        assert msg.encoding == "32FC1" and msg.data.tobytes() == frame.amplitude.tobytes()
    elif topic == "/tof/camera_info":
        k = [INTRINSICS.fx, 0, INTRINSICS.cx, 0, INTRINSICS.fy, INTRINSICS.cy, 0, 0, 1]
        assert msg.k.tolist() == k and msg.p.tolist()[:3] == k[:3]
        assert (msg.width, msg.height, msg.header.frame_id) == (16, 12, "tof_optical_frame")
    elif topic == "/arm/tcp_pose":
        tcp = frame.pose @ np.linalg.inv(hand_eye)
        p, q = msg.pose.position, msg.pose.orientation
        assert [p.x, p.y, p.z] == tcp[:3, 3].tolist()
        np.testing.assert_allclose(Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix(),
                                   tcp[:3, :3], atol=1e-12)
        assert msg.header.frame_id == "base"
    elif topic == "/arm/hand_eye":
        t = msg.transform.translation
        assert [t.x, t.y, t.z] == hand_eye[:3, 3].tolist()
        assert (msg.header.frame_id, msg.child_frame_id) == ("tool0", "tof_optical_frame")
    elif topic == "/tof/camera_to_base":
        assert msg.data.tobytes() == frame.pose.tobytes()
    elif topic == "/sl/points":
        assert [f.name for f in msg.fields] == ["x", "y", "z"] and msg.point_step == 12
        assert msg.data.tobytes() == points.astype("<f4").tobytes()
    else:
        raise AssertionError(f"unexpected topic {topic}")


def test_rosbags_reads_the_mcap_alone(recording, typestore):
    path, _, _, _ = recording
    with rosbag2.Reader(path / "rec_0.mcap") as reader:
        assert reader.message_count == 24
        assert sum(1 for _ in reader.messages()) == 24
