"""Recordings written by another tool: payloads serialised by rclpy, plain mcap writer."""

from __future__ import annotations

import os
import tempfile

# Before rclpy loads: stay on loopback in a private domain, logs in a temporary directory.
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_DOMAIN_ID", "17")
os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="tof_mpd_rec_log_"))

import numpy as np
import pytest
from mcap.writer import Writer
from rec_helpers import INTRINSICS, make_frames, rigid

from tof_mpd_ros.recordings import RecordingReader, metadata, msgdefs

serialization = pytest.importorskip("rclpy.serialization")
sensor_msgs = pytest.importorskip("sensor_msgs.msg")
geometry_msgs = pytest.importorskip("geometry_msgs.msg")


def _header(msg, stamp_ns, frame_id="camera_depth_optical_frame"):
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
    msg.header.frame_id = frame_id
    return msg


def _image(pixels, encoding, stamp_ns):
    msg = _header(sensor_msgs.Image(), stamp_ns)
    msg.height, msg.width = pixels.shape
    msg.encoding, msg.is_bigendian = encoding, 0
    msg.step = pixels.shape[1] * pixels.itemsize
    msg.data = pixels.astype(pixels.dtype.newbyteorder("<")).tobytes()
    return msg


def _camera_info(stamp_ns):
    msg = _header(sensor_msgs.CameraInfo(), stamp_ns)
    i = INTRINSICS
    msg.height, msg.width, msg.distortion_model = i.height, i.width, "plumb_bob"
    msg.k = [i.fx, 0.0, i.cx, 0.0, i.fy, i.cy, 0.0, 0.0, 1.0]
    msg.p = [i.fx, 0.0, i.cx, 0.0, 0.0, i.fy, i.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    return msg


def _pose(matrix, stamp_ns):
    from scipy.spatial.transform import Rotation

    msg = _header(geometry_msgs.PoseStamped(), stamp_ns, "base_link")
    p, o = msg.pose.position, msg.pose.orientation
    p.x, p.y, p.z = (float(v) for v in matrix[:3, 3])
    o.x, o.y, o.z, o.w = (float(v) for v in Rotation.from_matrix(matrix[:3, :3]).as_quat())
    return msg


class _PlainWriter:
    """Another tool's writer: the mcap library with our schemas, payloads from rclpy."""

    def __init__(self, stream):
        self.mcap = Writer(stream)
        self.mcap.start(profile="ros2", library="other-tool")
        self.schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}

    def write(self, topic, msgtype, msg, stamp_ns):
        if msgtype not in self.schemas:
            self.schemas[msgtype] = self.mcap.register_schema(
                msgtype, "ros2msg", msgdefs.schema_text(msgtype).encode())
        if topic not in self.channels:
            self.channels[topic] = self.mcap.register_channel(topic, "cdr",
                                                              self.schemas[msgtype])
        self.mcap.add_message(self.channels[topic], log_time=stamp_ns + 1234,
                              data=serialization.serialize_message(msg), publish_time=stamp_ns)


def test_rclpy_serialised_32fc1_frames_with_tcp_pose(tmp_path):
    frames = make_frames(3, reference=False, pose=False)
    tcps = [rigid(np.random.default_rng(i)) for i in range(3)]
    path = tmp_path / "other.mcap"
    with open(path, "wb") as stream:
        w = _PlainWriter(stream)
        for f, tcp in zip(frames, tcps, strict=True):
            metres = (f.range_mm.astype(np.float64) / 1000).astype(np.float32)
            w.write("/tof/range/image_raw", msgdefs.IMAGE, _image(metres, "32FC1", f.stamp_ns),
                    f.stamp_ns)
            w.write("/tof/amplitude/image_raw", msgdefs.IMAGE,
                    _image(f.amplitude, "32FC1", f.stamp_ns), f.stamp_ns)
            w.write("/tof/camera_info", msgdefs.CAMERA_INFO, _camera_info(f.stamp_ns), f.stamp_ns)
            w.write("/arm/tcp_pose", msgdefs.POSE_STAMPED, _pose(tcp, f.stamp_ns), f.stamp_ns)
        w.mcap.finish()
    reader = RecordingReader(path)
    back = list(reader.frames())
    assert [b.stamp_ns for b in back] == [f.stamp_ns for f in frames]
    for f, b in zip(frames, back, strict=True):
        np.testing.assert_allclose(b.range_mm, f.range_mm, rtol=1.2e-7, equal_nan=True)
        np.testing.assert_array_equal(np.isnan(b.range_mm), np.isnan(f.range_mm))
        assert b.amplitude.tobytes() == f.amplitude.tobytes()
        assert b.intrinsics == INTRINSICS
        assert b.pose is None  # a TCP pose without hand-eye is not a camera pose
    msgs = list(reader.messages(["/arm/tcp_pose"]))
    assert [m.log_time_ns for m in msgs] == [f.stamp_ns + 1234 for f in frames]
    assert msgs[0].message.header.frame_id == "base_link"
    assert msgs[0].message.pose.position.x == tcps[0][0, 3]


def test_rclpy_serialised_16uc1_z_depth_is_converted_to_radial(tmp_path):
    frame = make_frames(1, reference=False, pose=False)[0]
    z_mm = INTRINSICS.radial_to_z(frame.range_mm)
    depth = np.where(np.isnan(z_mm), 0, np.rint(np.nan_to_num(z_mm))).astype(np.uint16)
    mono = np.clip(np.nan_to_num(frame.amplitude), 0, 255).astype(np.uint8)
    rec = tmp_path / "other"
    rec.mkdir()
    stamp = frame.stamp_ns
    with open(rec / "other_0.mcap", "wb") as stream:
        w = _PlainWriter(stream)
        w.write("/tof/range/image_raw", msgdefs.IMAGE, _image(depth, "16UC1", stamp), stamp)
        w.write("/tof/amplitude/image_raw", msgdefs.IMAGE, _image(mono, "mono8", stamp), stamp)
        w.write("/tof/camera_info", msgdefs.CAMERA_INFO, _camera_info(stamp), stamp)
        w.mcap.finish()
    topics = [metadata.TopicStats("/tof/range/image_raw", msgdefs.IMAGE, 1)]
    metadata.write(rec, metadata.build("other_0.mcap", topics, stamp, stamp,
                                       {"tof_mpd_ros.range_convention": "z",
                                        "tof_mpd_ros.mod_freq_hz": "20e6"}))
    (back,) = RecordingReader(rec).frames()
    assert back.mod_freq_hz == 20e6
    valid = depth > 0
    np.testing.assert_array_equal(np.isnan(back.range_mm), ~valid)
    expected = depth[valid] / INTRINSICS.z_per_radial()[valid]
    np.testing.assert_allclose(back.range_mm[valid], expected, rtol=1e-6)
    # whole-millimetre z rounding stays within 0.5 mm / cos of the true radial range
    err = np.abs(back.range_mm - frame.range_mm)[valid]
    assert err.max() <= 0.5 / INTRINSICS.z_per_radial().min() + 1e-3
    np.testing.assert_array_equal(back.amplitude, mono.astype(np.float32))
