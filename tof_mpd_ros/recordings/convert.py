"""Arrays <-> ROS 2 messages (as plain dicts to encode, decoded objects to read). No ROS import.

Encoders return ``dict`` trees that ``mcap_ros2`` serialises to CDR; decoders accept any object
with the message's attributes (``mcap_ros2`` decoded messages, rclpy messages, namespaces).

Range images (REP 118, plus a lossless variant):

* ``32FC1``: float32 metres, NaN = invalid;
* ``16UC1``: uint16 millimetres, 0 = invalid (values outside 1..65535 mm are written as 0);
* ``64FC1``: float64 metres, NaN = invalid. float32 mm -> float64 m -> float32 mm is bit-exact.

Pixel payloads and units go through the package's shared codec
(:mod:`tof_mpd_ros.image_encoding`, also used by the nodes). On reading, non-finite and
non-positive values of a float range image become NaN (REP 118 uses +-Inf for "too near/far";
a radial range <= 0 is not a measurement).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from .. import image_encoding
from ..camera import Intrinsics
from ..errors import InputError
from ..pose import pose_from_quaternion, quaternion_xyzw
from ..validation import check_array

_log = logging.getLogger(__name__)

RANGE_ENCODINGS = ("32FC1", "16UC1", "64FC1")
AMPLITUDE_ENCODINGS = ("32FC1", "64FC1", "16UC1", "mono16", "mono8", "8UC1")
_UINT16_MAX = 65535


def field(msg: Any, name: str) -> Any:
    """Attribute ``name`` of a decoded message, or key ``name`` of a dict message."""
    if isinstance(msg, dict):
        return msg[name]
    return getattr(msg, name)


# ---------------------------------------------------------------------------------- stamps


def stamp_dict(stamp_ns: int) -> dict[str, int]:
    """``builtin_interfaces/Time`` of an integer nanosecond stamp (>= 0, < 2**31 s)."""
    stamp_ns = int(stamp_ns)
    if not 0 <= stamp_ns < 2**31 * 10**9:
        raise InputError(f"stamp_ns {stamp_ns} is outside the ROS time range [0, 2**31 s)")
    return {"sec": stamp_ns // 10**9, "nanosec": stamp_ns % 10**9}


def header_dict(stamp_ns: int, frame_id: str) -> dict[str, Any]:
    return {"stamp": stamp_dict(stamp_ns), "frame_id": frame_id}


def stamp_ns_of(msg: Any) -> int:
    """Integer nanoseconds of ``msg.header.stamp``."""
    stamp = field(field(msg, "header"), "stamp")
    return int(field(stamp, "sec")) * 10**9 + int(field(stamp, "nanosec"))


# ---------------------------------------------------------------------------------- images


def image_dict(pixels: np.ndarray, encoding: str, stamp_ns: int, frame_id: str) -> dict[str, Any]:
    """``sensor_msgs/msg/Image`` (little-endian) of an (H, W) array in ``encoding``'s dtype."""
    step, data = image_encoding.array_to_image_data(np.asarray(pixels), encoding)
    height, width = np.shape(pixels)
    return {"header": header_dict(stamp_ns, frame_id), "height": height, "width": width,
            "encoding": encoding, "is_bigendian": 0, "step": step, "data": data}


def image_pixels(msg: Any, allowed: tuple[str, ...], what: str) -> tuple[np.ndarray, str]:
    """Pixels of a single-channel ``sensor_msgs/msg/Image``.

    Args:
        msg: the decoded Image.
        allowed: the encodings accepted for this topic.
        what: what the image is, for messages (``"range image"``).

    Returns:
        ((H, W) array in the encoding's dtype, native byte order, a copy; the encoding).

    Raises:
        InputError: an encoding not in ``allowed``, or a payload that does not match its size.
    """
    encoding = str(field(msg, "encoding"))
    if encoding not in allowed:
        raise InputError(f"{what}: encoding {encoding!r} is not supported here "
                         f"(expected one of {', '.join(allowed)})")
    data = field(msg, "data")
    try:
        pixels = image_encoding.image_to_array(
            encoding, int(field(msg, "height")), int(field(msg, "width")),
            int(field(msg, "step")), bool(field(msg, "is_bigendian")),
            data if isinstance(data, bytes | bytearray | memoryview) else bytes(data))
    except InputError as err:
        raise InputError(f"{what}: {err}") from err
    return pixels, encoding


def range_image_dict(range_mm: np.ndarray, encoding: str, stamp_ns: int,
                     frame_id: str) -> dict[str, Any]:
    """Range image message of a radial range image (REP 118 units, see the module docstring).

    Args:
        range_mm: (H, W) float32 radial range in millimetres, NaN = invalid.
        encoding: one of ``RANGE_ENCODINGS``.
    """
    if encoding not in RANGE_ENCODINGS:
        raise InputError(f"range encoding {encoding!r} is not one of {RANGE_ENCODINGS}")
    r = check_array("range_mm", range_mm, ndim=2, dtype_kind="fiu")
    if encoding == "16UC1":
        finite = np.isfinite(r)
        lost = int(np.count_nonzero(finite & ((r < 0.5) | (r >= _UINT16_MAX + 0.5))))
        if lost:
            _log.warning("16UC1: %d finite range values outside 1..65535 mm written as 0 "
                         "(invalid)", lost)
    return image_dict(image_encoding.mm_to_depth(r, encoding), encoding, stamp_ns, frame_id)


def range_mm_of(msg: Any, what: str) -> np.ndarray:
    """Range of a range image message (radial or z, as recorded).

    Returns:
        (H, W) float32 range in millimetres, NaN = invalid (16UC1 zeros, non-finite or
        non-positive floats).
    """
    pixels, encoding = image_pixels(msg, RANGE_ENCODINGS, what)
    return image_encoding.depth_to_mm(pixels, encoding)


def amplitude_of(msg: Any, what: str) -> np.ndarray:
    """(H, W) float32 amplitude (sensor units, non-finite -> NaN) of an amplitude image."""
    pixels, _ = image_pixels(msg, AMPLITUDE_ENCODINGS, what)
    return image_encoding.amplitude_to_float(pixels)


# ------------------------------------------------------------------------------ camera info


def camera_info_dict(intrinsics: Intrinsics, stamp_ns: int, frame_id: str) -> dict[str, Any]:
    """``sensor_msgs/msg/CameraInfo`` of distortion-free pinhole intrinsics."""
    fx, fy, cx, cy = (float(v) for v in (intrinsics.fx, intrinsics.fy, intrinsics.cx,
                                        intrinsics.cy))
    return {
        "header": header_dict(stamp_ns, frame_id),
        "height": intrinsics.height, "width": intrinsics.width,
        "distortion_model": "plumb_bob", "d": [0.0] * 5,
        "k": [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
        "r": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        "p": [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        "binning_x": 0, "binning_y": 0,
        "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False},
    }


def intrinsics_of(msg: Any, what: str) -> Intrinsics:
    """Pinhole intrinsics from a CameraInfo's K matrix and size (distortion is ignored)."""
    k = [float(v) for v in field(msg, "k")]
    try:
        return Intrinsics(k[0], k[4], k[2], k[5], int(field(msg, "width")),
                          int(field(msg, "height")))
    except (InputError, IndexError) as err:
        raise InputError(f"{what}: unusable intrinsics K={k}: {err}") from err


# ---------------------------------------------------------------------------------- poses


def _rigid(matrix: np.ndarray, name: str) -> tuple[list[float], list[float]]:
    """Translation and (x, y, z, w) quaternion of a 4x4 rigid transform."""
    m = check_array(name, matrix, ndim=2, shape=(4, 4), dtype_kind="fiu").astype(np.float64)
    if not np.all(np.isfinite(m)):
        raise InputError(f"{name}: transform has non-finite entries")
    return [float(v) for v in m[:3, 3]], [float(v) for v in quaternion_xyzw(m)]


def pose_stamped_dict(matrix: np.ndarray, stamp_ns: int, frame_id: str) -> dict[str, Any]:
    """``geometry_msgs/msg/PoseStamped`` of a (4, 4) float64 transform in metres."""
    t, q = _rigid(matrix, "tcp_pose")
    return {"header": header_dict(stamp_ns, frame_id),
            "pose": {"position": dict(zip("xyz", t, strict=True)),
                     "orientation": dict(zip("xyzw", q, strict=True))}}


def transform_stamped_dict(matrix: np.ndarray, stamp_ns: int, frame_id: str,
                           child_frame_id: str) -> dict[str, Any]:
    """``geometry_msgs/msg/TransformStamped``: pose of ``child_frame_id`` in ``frame_id``, m."""
    t, q = _rigid(matrix, "hand_eye")
    return {"header": header_dict(stamp_ns, frame_id), "child_frame_id": child_frame_id,
            "transform": {"translation": dict(zip("xyz", t, strict=True)),
                          "rotation": dict(zip("xyzw", q, strict=True))}}


def _xyz(obj: Any, keys: str) -> list[float]:
    return [float(field(obj, k)) for k in keys]


def matrix_of_pose(msg: Any) -> np.ndarray:
    """(4, 4) float64 transform (m) of a PoseStamped."""
    pose = field(msg, "pose")
    return pose_from_quaternion(_xyz(field(pose, "position"), "xyz"),
                                _xyz(field(pose, "orientation"), "xyzw"))


def matrix_of_transform(msg: Any) -> np.ndarray:
    """(4, 4) float64 transform (m) of a TransformStamped (child pose in the parent frame)."""
    tf = field(msg, "transform")
    return pose_from_quaternion(_xyz(field(tf, "translation"), "xyz"),
                                _xyz(field(tf, "rotation"), "xyzw"))


def matrix_array_dict(matrix: np.ndarray) -> dict[str, Any]:
    """``std_msgs/msg/Float64MultiArray`` holding a (4, 4) float64 matrix row-major, exactly."""
    m = check_array("pose", matrix, ndim=2, shape=(4, 4), dtype_kind="fiu").astype(np.float64)
    return {"layout": {"dim": [{"label": "rows", "size": 4, "stride": 16},
                               {"label": "cols", "size": 4, "stride": 4}],
                       "data_offset": 0},
            "data": [float(v) for v in m.ravel()]}


def matrix_of_array(msg: Any, what: str) -> np.ndarray:
    """(4, 4) float64 matrix of a Float64MultiArray written by :func:`matrix_array_dict`."""
    data = np.asarray(field(msg, "data"), dtype=np.float64)
    offset = int(field(field(msg, "layout"), "data_offset"))
    if data.size - offset != 16:
        raise InputError(f"{what}: expected 16 values of a 4x4 matrix, got {data.size - offset}")
    return data[offset:].reshape(4, 4).copy()


# ----------------------------------------------------------------------------- point clouds


def point_cloud_dict(points_m: np.ndarray, stamp_ns: int, frame_id: str) -> dict[str, Any]:
    """Unordered ``sensor_msgs/msg/PointCloud2`` with float32 x, y, z fields.

    Args:
        points_m: (M, 3) float points in metres in ``frame_id``.
    """
    pts = check_array("sl_points", points_m, ndim=2, shape=(3,), dtype_kind="fiu")
    data = np.ascontiguousarray(pts, dtype="<f4")
    fields = [{"name": n, "offset": 4 * i, "datatype": 7, "count": 1}  # 7 = FLOAT32
              for i, n in enumerate("xyz")]
    return {"header": header_dict(stamp_ns, frame_id), "height": 1, "width": len(data),
            "fields": fields, "is_bigendian": False, "point_step": 12,
            "row_step": 12 * len(data), "data": data.tobytes(), "is_dense": True}


def points_of(msg: Any, what: str) -> np.ndarray:
    """(M, 3) float32 x, y, z (m) of a PointCloud2 with float32 x, y, z fields."""
    offsets = {str(field(f, "name")): int(field(f, "offset")) for f in field(msg, "fields")
               if int(field(f, "datatype")) == 7}
    if not all(k in offsets for k in "xyz"):
        raise InputError(f"{what}: PointCloud2 has no float32 x, y, z fields")
    step = int(field(msg, "point_step"))
    count = int(field(msg, "width")) * int(field(msg, "height"))
    order = ">" if bool(field(msg, "is_bigendian")) else "<"
    raw = np.frombuffer(bytes(field(msg, "data")), dtype=np.uint8)
    if raw.size < step * count:
        raise InputError(f"{what}: {count} points of {step} bytes need {step * count} bytes, "
                         f"got {raw.size}")
    rows = raw[: step * count].reshape(count, step)
    cols = [rows[:, offsets[k]:offsets[k] + 4].copy().view(order + "f4")[:, 0] for k in "xyz"]
    return np.stack(cols, axis=-1).astype(np.float32)
