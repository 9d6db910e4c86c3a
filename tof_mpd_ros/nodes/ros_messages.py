"""numpy <-> ROS message conversions shared by the nodes (sensor_msgs, geometry_msgs)."""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Pose
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header

from ..camera import Intrinsics
from ..image_encoding import array_to_image_data


def stamp_ns(msg) -> int:
    """Header stamp of a stamped message as integer nanoseconds."""
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def image_message(array: np.ndarray, encoding: str, frame_id: str = "",
                  header: Header | None = None) -> Image:
    """(H, W) array -> ``sensor_msgs/Image`` (little-endian, packed rows)."""
    step, data = array_to_image_data(array, encoding)
    msg = Image(height=array.shape[0], width=array.shape[1], encoding=encoding, is_bigendian=0,
                step=step, data=data)
    if header is not None:
        msg.header = header
    else:
        msg.header.frame_id = frame_id
    return msg


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


def intrinsics_of(info: CameraInfo) -> Intrinsics:
    """Intrinsics from a CameraInfo's K matrix (distortion ignored)."""
    k = info.k
    return Intrinsics(float(k[0]), float(k[4]), float(k[2]), float(k[5]), int(info.width),
                      int(info.height))


def pose_matrix(pose: Pose) -> np.ndarray:
    """``geometry_msgs/Pose`` -> (4, 4) float64 transform, metres."""
    q = pose.orientation
    out = np.eye(4)
    out[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    out[:3, 3] = [pose.position.x, pose.position.y, pose.position.z]
    return out


def pose_message(matrix: np.ndarray) -> Pose:
    """(4, 4) transform (metres) -> ``geometry_msgs/Pose``."""
    pose = Pose()
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in matrix[:3, 3])
    x, y, z, w = Rotation.from_matrix(matrix[:3, :3]).as_quat()
    pose.orientation.x, pose.orientation.y = float(x), float(y)
    pose.orientation.z, pose.orientation.w = float(z), float(w)
    return pose
