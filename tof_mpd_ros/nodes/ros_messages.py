"""numpy <-> ROS message conversions shared by the nodes (sensor_msgs, geometry_msgs)."""

from __future__ import annotations

import array as array_mod

import numpy as np
from geometry_msgs.msg import Pose
from sensor_msgs.msg import CameraInfo, Image, PointCloud2, PointField
from std_msgs.msg import Header

from ..camera import Intrinsics
from ..errors import InputError
from ..image_encoding import array_to_image_data
from ..pose import pose_from_quaternion, quaternion_xyzw


def stamp_ns(msg) -> int:
    """Header stamp of a stamped message as integer nanoseconds."""
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def image_message(array: np.ndarray, encoding: str, frame_id: str = "",
                  header: Header | None = None) -> Image:
    """(H, W) array -> ``sensor_msgs/Image`` (little-endian, packed rows)."""
    step, payload = array_to_image_data(array, encoding)
    data = array_mod.array("B")  # assigning bytes would make rclpy check every byte in Python
    data.frombytes(payload)
    msg = Image(height=array.shape[0], width=array.shape[1], encoding=encoding, is_bigendian=0,
                step=step, data=data)
    if header is not None:
        msg.header = header
    else:
        msg.header.frame_id = frame_id
    return msg


#: Fields of the organized clouds the nodes publish: x, y, z (metres) and intensity, float32.
CLOUD_FIELDS = ("x", "y", "z", "intensity")
CLOUD_DTYPE = np.dtype({"names": list(CLOUD_FIELDS), "formats": ["<f4"] * len(CLOUD_FIELDS)})


def point_cloud_message(points_m: np.ndarray, intensity: np.ndarray,
                        header: Header) -> PointCloud2:
    """An organized ``sensor_msgs/PointCloud2``: one point per pixel, row-major.

    Args:
        points_m: (H, W, 3) float x, y, z in metres in ``header.frame_id``; NaN = no point.
        intensity: (H, W) float, e.g. the amplitude (any unit).
        header: stamp and frame_id of the cloud.

    Returns:
        A cloud of height H and width W with float32 fields x, y, z, intensity (16 bytes a
        point, little-endian), ``is_dense`` False (invalid points are NaN, not removed).
    """
    if points_m.ndim != 3 or points_m.shape[2] != 3 or intensity.shape != points_m.shape[:2]:
        raise InputError(f"expected (H, W, 3) points and (H, W) intensity, got "
                         f"{points_m.shape} and {intensity.shape}")
    h, w = intensity.shape
    cloud = np.empty((h, w), CLOUD_DTYPE)
    for i, name in enumerate(CLOUD_FIELDS[:3]):
        cloud[name] = points_m[..., i]
    cloud["intensity"] = intensity
    data = array_mod.array("B")  # as in image_message: no per-byte check in rclpy
    data.frombytes(cloud.tobytes())
    fields = [PointField(name=name, offset=CLOUD_DTYPE.fields[name][1],
                         datatype=PointField.FLOAT32, count=1) for name in CLOUD_FIELDS]
    return PointCloud2(header=header, height=h, width=w, fields=fields, is_bigendian=False,
                       point_step=CLOUD_DTYPE.itemsize, row_step=CLOUD_DTYPE.itemsize * w,
                       data=data, is_dense=False)


def camera_info_message(intrinsics: Intrinsics, frame_id: str = "",
                        header: Header | None = None) -> CameraInfo:
    """Pinhole ``CameraInfo`` (plumb_bob, zero distortion) of ``intrinsics``."""
    k = intrinsics
    msg = CameraInfo(width=k.width, height=k.height, distortion_model="plumb_bob",
                     d=[0.0] * 5, r=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                     k=[k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
                     p=[k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0])
    if header is not None:
        msg.header = header
    else:
        msg.header.frame_id = frame_id
    return msg


def cropped_camera_info(info: CameraInfo, crop: Intrinsics,
                        header: Header | None = None) -> CameraInfo:
    """CameraInfo of a crop of the image ``info`` describes.

    Keeps the distortion model, coefficients and rectification (a crop does not change them);
    K and P get the crop's principal point, width and height the crop's size. P's focal lengths
    and baseline term are kept; ``binning`` and ``roi`` are reset (the crop is the whole image).

    Args:
        info: CameraInfo of the full input image.
        crop: intrinsics of the crop (e.g. ``Intrinsics.crop``), pixels of the crop.
        header: header of the output (default: ``info``'s).
    """
    dx = crop.cx - float(info.k[2])
    dy = crop.cy - float(info.k[5])
    p = [float(v) for v in info.p]
    if not any(p):  # an uncalibrated P: use K with no baseline
        p = [crop.fx, 0.0, crop.cx, 0.0, 0.0, crop.fy, crop.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    else:
        p[2] += dx
        p[6] += dy
    msg = CameraInfo(width=crop.width, height=crop.height,
                     distortion_model=info.distortion_model or "plumb_bob",
                     d=[float(v) for v in info.d] if info.distortion_model else [0.0] * 5,
                     r=[float(v) for v in info.r],
                     k=[crop.fx, 0.0, crop.cx, 0.0, crop.fy, crop.cy, 0.0, 0.0, 1.0], p=p)
    msg.header = header if header is not None else info.header
    return msg


def intrinsics_of(info: CameraInfo) -> Intrinsics:
    """Intrinsics from a CameraInfo's K matrix (distortion ignored)."""
    k = info.k
    return Intrinsics(float(k[0]), float(k[4]), float(k[2]), float(k[5]), int(info.width),
                      int(info.height))


def pose_matrix(pose: Pose) -> np.ndarray:
    """``geometry_msgs/Pose`` -> (4, 4) float64 transform, metres."""
    q, t = pose.orientation, pose.position
    return pose_from_quaternion([t.x, t.y, t.z], [q.x, q.y, q.z, q.w])


def pose_message(matrix: np.ndarray) -> Pose:
    """(4, 4) transform (metres) -> ``geometry_msgs/Pose``."""
    pose = Pose()
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in matrix[:3, 3])
    x, y, z, w = quaternion_xyzw(matrix)
    pose.orientation.x, pose.orientation.y = float(x), float(y)
    pose.orientation.z, pose.orientation.w = float(z), float(w)
    return pose
