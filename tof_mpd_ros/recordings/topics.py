"""Topic names, frame ids and the ``custom_data`` keys of a tof_mpd_ros recording."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields

# Keys of metadata.yaml ``custom_data`` (also stored in the MCAP metadata record ``tof_mpd_ros``).
KEY_PREFIX = "tof_mpd_ros."
KEY_VERSION = KEY_PREFIX + "version"
# "radial" (range along each pixel's ray, what a ToF camera measures) or "z" (REP 118 depth).
KEY_RANGE_CONVENTION = KEY_PREFIX + "range_convention"
KEY_RANGE_ENCODING = KEY_PREFIX + "range_encoding"
KEY_MOD_FREQ = KEY_PREFIX + "mod_freq_hz"
KEY_TOPIC_PREFIX = KEY_PREFIX + "topic."
MCAP_METADATA_NAME = "tof_mpd_ros"

RADIAL = "radial"
Z_DEPTH = "z"
CONVENTIONS = (RADIAL, Z_DEPTH)


@dataclass(frozen=True)
class TopicNames:
    """Topics of one recording. Range and reference images hold *radial* range.

    Attributes:
        range: ToF range, ``sensor_msgs/msg/Image`` (32FC1 m, 16UC1 mm or 64FC1 m).
        amplitude: ToF amplitude, ``sensor_msgs/msg/Image`` 32FC1 (sensor units).
        camera_info: ToF intrinsics, ``sensor_msgs/msg/CameraInfo``.
        reference: structured-light reference range, same encoding as ``range``.
        points: structured-light points, ``sensor_msgs/msg/PointCloud2`` (x y z float32, m).
        tcp_pose: arm TCP (flange) pose in the base frame, ``geometry_msgs/msg/PoseStamped``, m.
        hand_eye: flange -> camera, ``geometry_msgs/msg/TransformStamped`` (camera pose in the
            flange frame), m.
        camera_to_base: the exact 4x4 camera-to-base matrix of each frame, row-major, m,
            ``std_msgs/msg/Float64MultiArray`` (lossless; a quaternion round trip is not).
    """

    range: str = "/tof/range/image_raw"
    amplitude: str = "/tof/amplitude/image_raw"
    camera_info: str = "/tof/camera_info"
    reference: str = "/sl/range/image_raw"
    points: str = "/sl/points"
    tcp_pose: str = "/arm/tcp_pose"
    hand_eye: str = "/arm/hand_eye"
    camera_to_base: str = "/tof/camera_to_base"

    def as_custom_data(self) -> dict[str, str]:
        """``{"tof_mpd_ros.topic.range": "/tof/range/image_raw", ...}``."""
        return {KEY_TOPIC_PREFIX + k: v for k, v in asdict(self).items()}

    @classmethod
    def from_custom_data(cls, custom: Mapping[str, str]) -> TopicNames:
        """Topic names recorded in ``custom_data``; defaults for the ones not recorded."""
        names = {f.name: custom[KEY_TOPIC_PREFIX + f.name] for f in fields(cls)
                 if KEY_TOPIC_PREFIX + f.name in custom}
        return cls(**names)


@dataclass(frozen=True)
class FrameIds:
    """TF frame ids written in message headers (REP 103/105 names)."""

    camera: str = "tof_optical_frame"
    base: str = "base"
    flange: str = "tool0"
