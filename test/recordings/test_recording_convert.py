"""Embedded message definitions and array <-> message conversions."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap_ros2._dynamic import generate_dynamic, serialize_dynamic
from rec_helpers import INTRINSICS, rigid

from tof_mpd_ros.errors import InputError
from tof_mpd_ros.recordings import convert, msgdefs


def installed_msg_file(msgtype: str) -> Path | None:
    """``<prefix>/share/<pkg>/msg/<Name>.msg`` of ``pkg/msg/Name`` where ROS installed it: an
    ament prefix (``AMENT_PREFIX_PATH``, e.g. /opt/ros/jazzy) or this interpreter's prefix (the
    ``ros`` extra's wheels install into the virtual environment); None if neither has it."""
    pkg, _, name = msgtype.split("/")
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    for prefix in (*prefixes, sys.prefix):
        path = Path(prefix) / "share" / pkg / "msg" / f"{name}.msg"
        if path.is_file():
            return path
    return None


@pytest.mark.parametrize("msgtype", msgdefs.known_types())
def test_embedded_definitions_are_the_jazzy_msg_files(msgtype):
    source = installed_msg_file(msgtype)
    if source is None:  # the only reason to skip: the ROS message packages are absent
        pytest.skip(f"{msgtype}.msg is not installed: neither an ament prefix nor {sys.prefix} "
                    "has it (the 'ros' extra or a ROS install provides it)")
    assert msgdefs.MSG_TEXT[msgtype] == source.read_text()


def test_schema_text_is_the_rosbag2_concatenation():
    text = msgdefs.schema_text(msgdefs.POSE_STAMPED)
    sections = text.split("=" * 80 + "\n")
    assert [s.splitlines()[0] for s in sections[1:]] == [
        "MSG: std_msgs/Header", "MSG: builtin_interfaces/Time", "MSG: geometry_msgs/Pose",
        "MSG: geometry_msgs/Point", "MSG: geometry_msgs/Quaternion"]
    assert sections[0].startswith("# A Pose with reference coordinate frame and timestamp")
    for msgtype in msgdefs.known_types():  # every schema parses with all its dependencies
        assert msgtype in generate_dynamic(msgtype, msgdefs.schema_text(msgtype))


def _cdr_round_trip(msgtype, message):
    text = msgdefs.schema_text(msgtype)
    return generate_dynamic(msgtype, text)[msgtype](serialize_dynamic(msgtype, text)[msgtype](
        message))


def test_64fc1_range_is_bit_exact_for_every_float32():
    rng = np.random.default_rng(0)
    bits = rng.integers(0, 2**32, size=200_000, dtype=np.uint64).astype(np.uint32)
    values = bits.view(np.float32)
    values = np.abs(values[np.isfinite(values) & (values != 0)])[: 100 * 1000]
    image = np.concatenate([values, [np.nan] * (100_000 - values.size)]).astype(np.float32)
    image = image.reshape(100, 1000)
    msg = _cdr_round_trip(msgdefs.IMAGE, convert.range_image_dict(image, "64FC1", 7, "cam"))
    assert msg.encoding == "64FC1" and msg.step == 8000
    back = convert.range_mm_of(msg, "range")
    assert back.dtype == np.float32 and back.tobytes() == image.tobytes()


def test_32fc1_stores_metres_and_16uc1_millimetres():
    mm = np.array([[1234.5, np.nan, 80000.0, 0.4]], dtype=np.float32)
    m32 = convert.range_image_dict(mm, "32FC1", 0, "cam")
    metres = np.frombuffer(m32["data"], "<f4")
    np.testing.assert_array_equal(metres, (mm[0].astype(np.float64) / 1000).astype(np.float32))
    np.testing.assert_allclose(metres, [1.2345, np.nan, 80.0, 0.0004], rtol=1e-7)
    u16 = convert.range_image_dict(mm, "16UC1", 0, "cam")
    assert np.frombuffer(u16["data"], "<u2").tolist() == [1234, 0, 0, 0]
    back = convert.range_mm_of(u16, "range")
    assert back[0, 0] == 1234.0 and np.isnan(back[0, 1:]).all()


def test_big_endian_and_padded_rows_decode():
    pixels = np.arange(6, dtype=np.float32).reshape(2, 3) + 0.5
    rows = [pixels[i].astype(">f4").tobytes() + b"\0" * 4 for i in range(2)]
    msg = {"encoding": "32FC1", "height": 2, "width": 3, "step": 16, "is_bigendian": 1,
           "data": b"".join(rows)}
    np.testing.assert_array_equal(convert.range_mm_of(msg, "range"), pixels * 1000)


def test_wrong_encodings_and_sizes_name_the_image():
    msg = {"encoding": "bgr8", "height": 1, "width": 1, "step": 3, "is_bigendian": 0,
           "data": b"\0\0\0"}
    with pytest.raises(InputError, match="range: encoding 'bgr8' is not supported"):
        convert.range_mm_of(msg, "range")
    msg = {"encoding": "32FC1", "height": 2, "width": 2, "step": 8, "is_bigendian": 0,
           "data": b"\0" * 12}
    with pytest.raises(InputError, match="amplitude: 32FC1 image 2x2"):
        convert.amplitude_of(msg, "amplitude")


def test_camera_info_round_trip_and_zero_k_is_an_error():
    msg = _cdr_round_trip(msgdefs.CAMERA_INFO, convert.camera_info_dict(INTRINSICS, 5, "cam"))
    assert convert.intrinsics_of(msg, "info") == INTRINSICS
    assert list(msg.p) == [20.5, 0, 7.5, 0, 0, 21.25, 5.75, 0, 0, 0, 1, 0]
    msg.k = [0.0] * 9
    with pytest.raises(InputError, match="info: unusable intrinsics"):
        convert.intrinsics_of(msg, "info")


def test_pose_transform_matrix_and_cloud_round_trips():
    rng = np.random.default_rng(4)
    m = rigid(rng)
    pose = _cdr_round_trip(msgdefs.POSE_STAMPED, convert.pose_stamped_dict(m, 10**9 + 5, "b"))
    assert convert.stamp_ns_of(pose) == 10**9 + 5
    np.testing.assert_allclose(convert.matrix_of_pose(pose), m, atol=1e-15)
    tf = _cdr_round_trip(msgdefs.TRANSFORM_STAMPED,
                         convert.transform_stamped_dict(m, 0, "tool0", "cam"))
    np.testing.assert_allclose(convert.matrix_of_transform(tf), m, atol=1e-15)
    exact = _cdr_round_trip(msgdefs.FLOAT64_MULTI_ARRAY, convert.matrix_array_dict(m))
    assert convert.matrix_of_array(exact, "pose").tobytes() == m.tobytes()
    pts = rng.normal(size=(5, 3)).astype(np.float32)
    cloud = _cdr_round_trip(msgdefs.POINT_CLOUD2, convert.point_cloud_dict(pts, 0, "cam"))
    assert convert.points_of(cloud, "cloud").tobytes() == pts.tobytes()
    with pytest.raises(InputError, match="non-finite"):
        convert.pose_stamped_dict(np.full((4, 4), np.nan), 0, "b")


def test_stamps_outside_ros_time_are_rejected():
    assert convert.stamp_dict(3 * 10**9 + 7) == {"sec": 3, "nanosec": 7}
    with pytest.raises(InputError, match="outside the ROS time range"):
        convert.stamp_dict(-1)
